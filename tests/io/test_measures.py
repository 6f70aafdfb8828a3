"""casacore conversions that do not depend on what the same thread converted before.

casacore reuses the last UT1 - UTC it looked up for any epoch within 0.04 d
(msleak/io/measures.py); every msleak conversion sets its epoch through
:func:`msleak.io.measures.set_epoch`, which looks UT1 up afresh. Known answers: the same
conversion after two different histories, equal to 1e-12 rad (casacore keeps one more,
process-wide cache of series coefficients for 0.04 d, worth about 1e-13 rad).
"""

from __future__ import annotations

import numpy as np
import pytest

from msleak.beam.coords import radec_to_unit
from msleak.io.measures import exact_j2000_to_itrf, hour_angle_h, set_epoch
from msleak.telescope.uvw import antenna_uvw

DAY = 86400.0
RA = np.array([0.5, 2.1, 4.0])
DEC = np.array([1.2, 0.9, -0.3])
#: 2021-10-11 06:00 UTC, and 10 min after the leap second at the end of 2016
T_PLAIN = 59500.25 * DAY
T_LEAP = 57754.0 * DAY + 600.0
LOFAR = np.array([3826577.462, 461022.624, 5064892.526])
TOL = 1e-12


def _plain_itrf(dm, t):
    """J2000 -> ITRF as python-casacore is usually called (do_frame only), unit vectors."""
    from casacore.quanta import quantity

    dm.do_frame(dm.epoch("UTC", quantity(t, "s")))
    out = []
    for a, d in zip(RA, DEC):
        m = dm.measure(dm.direction("J2000", f"{float(a)!r}rad", f"{float(d)!r}rad"), "ITRF")
        out.append(radec_to_unit(m["m0"]["value"], m["m1"]["value"]))
    return np.array(out)


def _angle(a, b):
    return float(np.max(np.linalg.norm(np.asarray(a) - np.asarray(b), axis=-1)))


@pytest.mark.parametrize("t", [T_PLAIN, T_LEAP], ids=["plain", "after-leap-second"])
def test_plain_casacore_depends_on_history_and_set_epoch_does_not(t):
    """The control: converting 30 min earlier first moves casacore's answer at T (by about
    4e-10 rad; by a second of UT1, 7e-5 rad, across a leap second); with set_epoch the
    answer at T is the same after either history."""
    from casacore.measures import measures

    dm = measures()
    dm.do_frame(dm.position("ITRF", *[f"{float(x)!r}m" for x in LOFAR]))
    after_earlier = [_plain_itrf(dm, e) for e in (t - 2 * DAY, t - 1800.0, t)][-1]
    after_far = [_plain_itrf(dm, e) for e in (t - 2 * DAY, t - DAY, t)][-1]
    moved = _angle(after_earlier, after_far)
    assert moved > 1e-11, ("casacore no longer reuses UT1 - UTC between epochs: "
                           "msleak.io.measures.set_epoch's extra look-up can go")
    if t == T_LEAP:
        assert moved > 1e-5
    results = []
    for history in (t - 1800.0, t + 1200.0, t - DAY):
        _plain_itrf(dm, t + 2 * DAY)  # so that the history's own look-up is fresh
        _plain_itrf(dm, history)
        set_epoch(dm, t)
        out = []
        for a, d in zip(RA, DEC):
            m = dm.measure(dm.direction("J2000", f"{float(a)!r}rad", f"{float(d)!r}rad"), "ITRF")
            out.append(radec_to_unit(m["m0"]["value"], m["m1"]["value"]))
        results.append(np.array(out))
    assert _angle(results[0], results[2]) < TOL and _angle(results[1], results[2]) < TOL
    assert _angle(after_far, results[2]) < TOL


@pytest.mark.parametrize("t", [T_PLAIN, T_LEAP], ids=["plain", "after-leap-second"])
def test_msleak_conversions_do_not_depend_on_history(t):
    """Directions (the beam's ITRF anchors), UVW and the hour angle at T after a
    conversion 30 min earlier equal those after one a day earlier."""
    positions = LOFAR + np.array([[0.0, 0.0, 0.0], [300.0, -200.0, 50.0]])

    def far():  # this thread's UT1 - UTC look-up far from t: the history's own is fresh
        exact_j2000_to_itrf(t + 2 * DAY, RA, DEC)

    runs = []
    for history in (t - 1800.0, t - DAY):
        far()
        exact_j2000_to_itrf(history, RA, DEC)
        itrf = exact_j2000_to_itrf(t, RA, DEC)
        far()
        antenna_uvw(positions, [history], 1.0, 0.8)
        uvw = antenna_uvw(positions, [t], 1.0, 0.8)
        far()
        hour_angle_h([history], 1.0, LOFAR)
        ha = hour_angle_h([t], 1.0, LOFAR)
        runs.append((itrf, uvw, ha))
    (itrf0, uvw0, ha0), (itrf1, uvw1, ha1) = runs
    assert _angle(itrf0, itrf1) < TOL
    np.testing.assert_allclose(uvw0, uvw1, rtol=0, atol=TOL * 400.0)
    np.testing.assert_allclose(ha0, ha1, rtol=0, atol=TOL * 12 / np.pi)


def test_predict_twice_in_one_process_is_bit_identical(tmp_path):
    """msleak.predict with the LOFAR beam on a 2 h MS (60 slots), twice in this thread
    (``scheduler="sync"``; casacore's UT1 - UTC value is per thread) with another epoch
    converted in between: the visibilities are identical."""
    from ms_helpers import phase_centre, write_sky
    from msleak.io.ms import read_times
    from msleak.verbs.predict import predict
    from msleak.verbs.simulate import simulate

    ms = simulate(tmp_path / "a.ms", field="3c196", stations="CS00[1-4]HBA*", duration=2.0,
                  interval=120.0, nchan=4, freq_min=150e6, chan_width=195312.5)
    ra0, dec0 = phase_centre(ms)
    sky = write_sky(tmp_path / "sky.skymodel",
                    [(ra0 + 0.05, dec0 + 0.02, 1.0, 0.4, -0.3, 0.0),
                     (ra0 - 0.06, dec0 - 0.04, 2.0, -0.2, 0.6, 0.0)])
    first = predict(ms, sky, column=None, scheduler="sync").values
    exact_j2000_to_itrf(float(read_times(ms)[0]) + 900.0, RA, DEC)
    second = predict(ms, sky, column=None, scheduler="sync").values
    assert np.abs(first).max() > 0.1
    np.testing.assert_array_equal(first, second)
