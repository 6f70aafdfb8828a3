"""casacore measures: epochs set without history, and the exact direction conversions.

casacore's UTC -> UT1 step (used by every J2000 -> ITRF/AZEL conversion, UVW and LAST)
keeps the last UT1 - UTC value it looked up, per thread, and reuses it without
interpolation for any epoch within 0.04 d of that lookup (``MeasTable::dUT1``). A
conversion at epoch T then depends on which epoch the same thread converted before: by up
to about 1e-9 rad normally, and by a whole second of UT1 (7e-5 rad) when that epoch lies
across a leap second. :func:`set_epoch` looks UT1 up one day earlier first, so the value
at T is always looked up afresh; it costs about 30 us (docs/beam.md, "Directions in ITRF").

:func:`exact_j2000_to_itrf` and :func:`itrf_to_j2000` convert directions one by one in
EveryBeam's frame (one shared, locked measures server per frame position);
:func:`hour_angle_h` gives hour angles from casacore's LAST.
"""

from __future__ import annotations

import threading

import numpy as np

__all__ = ["set_epoch", "LOFAR_FRAME_POSITION_ITRF", "exact_j2000_to_itrf", "itrf_to_j2000",
           "hour_angle_h"]

#: Offset (s) of the look-up that clears casacore's UT1 - UTC value: more than its 0.04 d.
_CLEAR_OFFSET_S = 86400.0

#: ITRF position (m) of the frame EveryBeam uses for every J2000 -> ITRF conversion (CS002LBA).
LOFAR_FRAME_POSITION_ITRF = np.array([826577.022720000, 461022.995082000, 5064892.814])


def set_epoch(dm, time_mjd_s: float) -> None:
    """Put the UTC epoch ``time_mjd_s`` (MJD seconds) into the frame of the casacore measures
    server ``dm``, with UT1 - UTC looked up at that epoch.

    Call it in the thread that converts, before each conversion (or batch of conversions
    with no other epoch converted in between by that thread).
    """
    from casacore.quanta import quantity

    dm.measure(dm.epoch("UTC", quantity(float(time_mjd_s) - _CLEAR_OFFSET_S, "s")), "UT1")
    dm.do_frame(dm.epoch("UTC", quantity(float(time_mjd_s), "s")))


class _Casacore:
    """One python-casacore measures server with the EveryBeam frame, per time."""

    def __init__(self, position_itrf=LOFAR_FRAME_POSITION_ITRF):
        from casacore.measures import measures
        from casacore.quanta import quantity

        self._q = quantity
        self.dm = measures()
        x, y, z = (float(c) for c in position_itrf)
        self.dm.do_frame(self.dm.position("ITRF", f"{x!r}m", f"{y!r}m", f"{z!r}m"))
        #: casacore's measures server is not thread-safe: hold this around set_time+convert
        self.lock = threading.Lock()

    def set_time(self, time_mjd_s: float) -> None:
        set_epoch(self.dm, time_mjd_s)

    def convert(self, ra, dec) -> np.ndarray:
        ra = np.atleast_1d(np.asarray(ra, dtype=float))
        dec = np.atleast_1d(np.asarray(dec, dtype=float))
        out = np.empty((ra.size, 3))
        dm, q = self.dm, self._q
        for i, (a, d) in enumerate(zip(ra, dec)):
            m = dm.measure(dm.direction("J2000", q(float(a), "rad"), q(float(d), "rad")), "ITRF")
            lon, lat = m["m0"]["value"], m["m1"]["value"]
            out[i] = (np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat))
        return out


_SERVERS: dict[tuple, _Casacore] = {}
_SERVERS_LOCK = threading.Lock()


def _server(position_itrf=None) -> _Casacore:
    pos = LOFAR_FRAME_POSITION_ITRF if position_itrf is None else np.asarray(position_itrf)
    key = tuple(np.round(pos, 3))
    with _SERVERS_LOCK:
        if key not in _SERVERS:
            _SERVERS[key] = _Casacore(pos)
        return _SERVERS[key]


def exact_j2000_to_itrf(time_mjd_s: float, ra, dec, position_itrf=None) -> np.ndarray:
    """ITRF unit vectors (n, 3) of J2000 directions, one casacore conversion each.

    Slow (about 200 us per direction); the reference for :class:`msleak.beam.coords.ItrfMap`.
    The frame is at ``position_itrf`` (m), EveryBeam's :data:`LOFAR_FRAME_POSITION_ITRF` by
    default.
    """
    srv = _server(position_itrf)
    with srv.lock:
        srv.set_time(time_mjd_s)
        return srv.convert(ra, dec)


def itrf_to_j2000(time_mjd_s, lon: float, lat: float, position_itrf
                  ) -> tuple[np.ndarray, np.ndarray]:
    """J2000 (ra, dec) in rad (ra as casacore gives it) of the ITRF direction (``lon``,
    ``lat``) in rad at each UTC ``time_mjd_s`` (MJD s), in the frame at ``position_itrf``
    (m), one exact casacore conversion each (a few ms)."""
    times = np.atleast_1d(np.asarray(time_mjd_s, dtype=float))
    ra, dec = np.empty(times.size), np.empty(times.size)
    srv = _server(position_itrf)
    with srv.lock:
        direction = srv.dm.direction("ITRF", srv._q(lon, "rad"), srv._q(lat, "rad"))
        for i, t in enumerate(times):
            srv.set_time(float(t))
            m = srv.dm.measure(direction, "J2000")
            ra[i], dec[i] = m["m0"]["value"], m["m1"]["value"]
    return ra, dec


def hour_angle_h(times_mjd_s, ra: float, position_itrf) -> np.ndarray:
    """Hour angle (h, in [-12, 12)) of right ascension ``ra`` at ``position_itrf`` (casacore LAST)."""
    from casacore.measures import measures
    from casacore.quanta import quantity

    dm = measures()
    x, y, z = (float(c) for c in position_itrf)
    dm.do_frame(dm.position("ITRF", f"{x!r}m", f"{y!r}m", f"{z!r}m"))
    out = []
    for t in np.atleast_1d(times_mjd_s):
        set_epoch(dm, t)
        last = dm.measure(dm.epoch("UTC", quantity(float(t), "s")), "LAST")["m0"]["value"]
        lst_h = (last % 1.0) * 24
        out.append((lst_h - np.degrees(ra) / 15 + 12) % 24 - 12)
    return np.array(out)
