"""casacore measures frames whose conversions do not depend on earlier conversions.

casacore's UTC -> UT1 step (used by every J2000 -> ITRF/AZEL conversion, UVW and LAST)
keeps the last UT1 - UTC value it looked up, per thread, and reuses it without
interpolation for any epoch within 0.04 d of that lookup (``MeasTable::dUT1``). A
conversion at epoch T then depends on which epoch the same thread converted before: by up
to about 1e-9 rad normally, and by a whole second of UT1 (7e-5 rad) when that epoch lies
across a leap second. :func:`set_epoch` looks UT1 up one day earlier first, so the value
at T is always looked up afresh; it costs about 30 us (docs/beam.md, "Directions in ITRF").
"""

from __future__ import annotations

__all__ = ["set_epoch"]

#: Offset (s) of the look-up that clears casacore's UT1 - UTC value: more than its 0.04 d.
_CLEAR_OFFSET_S = 86400.0


def set_epoch(dm, time_mjd_s: float) -> None:
    """Put the UTC epoch ``time_mjd_s`` (MJD seconds) into the frame of the casacore measures
    server ``dm``, with UT1 - UTC looked up at that epoch.

    Call it in the thread that converts, before each conversion (or batch of conversions
    with no other epoch converted in between by that thread).
    """
    from casacore.quanta import quantity

    dm.measure(dm.epoch("UTC", quantity(float(time_mjd_s) - _CLEAR_OFFSET_S, "s")), "UT1")
    dm.do_frame(dm.epoch("UTC", quantity(float(time_mjd_s), "s")))
