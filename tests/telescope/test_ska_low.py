"""SKA-Low: the approximate layout, the PHASED_ARRAY subtable, and the fast station beam
against EveryBeam called directly on the same MS."""

from __future__ import annotations

import numpy as np
import pytest

from casa_ms import build_ms
from msleak._everybeam import everybeam_datadir, import_everybeam
from msleak.adapters.beams import ska_low_from_ms
from msleak.beam.maps import sin_grid
from msleak.beam.ska_low import (ELEMENT_MODELS, SKALA40_FREQUENCIES_HZ,
                                 check_element_model, element_frequency_sets, element_jones)
from msleak.constants import SPEED_OF_LIGHT
from msleak.errors import BeamUnavailable, InputError
from msleak.io.measures import exact_j2000_to_itrf
from msleak.io.ms import read_antennas, read_times
from msleak.io.phased_array import read_phased_array, write_phased_array
from msleak.telescope.ska_low import (SKA_LOW_CENTRE, ska_low_centre_itrf,
                                      ska_low_from_layout_file, ska_low_layout, station_axes,
                                      station_element_offsets, station_elements)

FREQ0, DF, NCHAN = 150e6, 195312.5, 4
#: elements of station 2 whose X feed is flagged (the beam former then differs per feed)
FLAGGED_X = np.arange(0, 256, 7)


def _write_layout(ms, seed=1):
    pos = read_antennas(ms).positions
    axes, offsets = station_element_offsets(pos, seed=seed)
    flags = [np.zeros((len(o), 2), bool) for o in offsets]
    flags[2][FLAGGED_X, 0] = True
    write_phased_array(ms, pos, axes, offsets, flags)
    return pos, axes, offsets, flags


@pytest.fixture(scope="module")
def ska_ms(tmp_path_factory):
    """6 approximate SKA-Low core stations of 256 elements, 2 times, 4 channels."""
    lay = ska_low_layout(n_stations=6, seed=2, core_diameter=300.0)
    ms = build_ms(tmp_path_factory.mktemp("ska") / "ska.ms", telescope="SKA-LOW",
                  enu=lay.enu, site_itrf=lay.reference, ntime=2, nchan=NCHAN,
                  freq0_hz=FREQ0, chan_width_hz=DF)
    _write_layout(ms)
    return ms


def _min_distance(xy):
    dist = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    return (dist + np.eye(len(xy)) * 1e30).min()


# -- layout ----------------------------------------------------------------------------
def test_station_elements_are_256_in_38_m_with_minimum_spacing():
    for seed in (0, 1, 7):
        e = station_elements(seed=seed)
        assert e.shape == (256, 3) and np.all(e[:, 2] == 0)
        assert np.hypot(e[:, 0], e[:, 1]).max() <= 19.0 - 0.75 + 1e-12
        assert _min_distance(e[:, :2]) >= 1.5 - 1e-12
    assert not np.allclose(station_elements(seed=0), station_elements(seed=1))
    with pytest.raises(InputError, match="do not fit"):
        station_elements(n=400, diameter=38.0, min_spacing=2.0)


def test_core_layout_is_1_km_with_40_m_separation():
    lay = ska_low_layout(seed=3)
    assert len(lay) == 224 and lay.approximate
    assert np.hypot(lay.enu[:, 0], lay.enu[:, 1]).max() <= 500.0
    assert _min_distance(lay.enu[:, :2]) >= 40.0 - 1e-9
    # ENU -> ITRF keeps distances (a rotation and a shift)
    np.testing.assert_allclose(np.linalg.norm(lay.positions - lay.reference, axis=1),
                               np.linalg.norm(lay.enu, axis=1), atol=1e-6)
    layout = lay.to_layout()
    assert layout.telescope == "SKA-LOW" and np.all(layout.diameters == 38.0)


def test_station_axes_are_the_geodetic_east_north_up():
    lon, lat = np.radians(SKA_LOW_CENTRE[0]), np.radians(SKA_LOW_CENTRE[1])
    expected = np.array([[-np.sin(lon), np.cos(lon), 0.0],
                         [-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)],
                         [np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)]])
    np.testing.assert_allclose(station_axes(ska_low_centre_itrf())[0], expected, atol=1e-9)


def test_layout_file_becomes_ska_low(tmp_path):
    lay = ska_low_layout(n_stations=3, seed=4)
    rows = [f"{n} {x!r} {y!r} {z!r}" for n, (x, y, z) in zip(lay.names, lay.positions.tolist())]
    path = tmp_path / "ska.txt"
    path.write_text("frame = itrf\n" + "\n".join(rows) + " 35.0\n")
    layout = ska_low_from_layout_file(path)
    assert layout.telescope == "SKA-LOW" and layout.names == lay.names
    np.testing.assert_array_equal(layout.positions, lay.positions)
    np.testing.assert_array_equal(layout.diameters, [38.0, 38.0, 35.0])
    # ENU without 'reference =' is placed at LOFAR: refused
    path.write_text("frame = enu\nA 0 0 0\nB 100 0 0\n")
    with pytest.raises(InputError, match="from the SKA-Low site"):
        ska_low_from_layout_file(path)


# -- PHASED_ARRAY ----------------------------------------------------------------------
def test_phased_array_round_trips_exactly(ska_ms):
    pos = read_antennas(ska_ms).positions
    axes, offsets = station_element_offsets(pos, seed=5)
    flags = [np.random.default_rng(i).uniform(size=(256, 2)) < 0.1 for i in range(len(pos))]
    write_phased_array(ska_ms, pos, axes, offsets, flags)
    back = read_phased_array(ska_ms)
    assert np.array_equal(back.positions, pos) and np.array_equal(back.axes, axes)
    assert all(np.array_equal(a, b) for a, b in zip(back.element_offsets, offsets))
    assert all(np.array_equal(a, b) for a, b in zip(back.element_flags, flags))
    _write_layout(ska_ms)  # restore the fixture's layout


def test_everybeam_reads_the_written_layout(ska_ms):
    """EveryBeam's array factor equals the analytic one of the offsets written."""
    eb = import_everybeam()
    tel = eb.load_telescope(str(ska_ms), element_response_model="oskar_dipole_cos")
    assert type(tel).__name__ == "OSKAR" and tel.nr_stations == 6
    t = read_times(ska_ms)[0]
    ra0, dec0 = np.radians(253.5), np.radians(-27.0)
    s0 = exact_j2000_to_itrf(t, ra0, dec0)[0]
    d = exact_j2000_to_itrf(t, ra0 + 0.2, dec0 - 0.1)[0]
    pa = read_phased_array(ska_ms)
    for s in (0, 2):
        on = ~pa.element_flags[s]
        phase = np.exp(-2j * np.pi * 160e6 / SPEED_OF_LIGHT * (pa.element_offsets[s] @ (s0 - d)))
        expected = (on * phase[:, None]).sum(0) / on.sum(0)
        af = np.asarray(tel.array_factor(t, np.array([s], np.uint64), np.array([160e6]), d, s0))
        np.testing.assert_allclose(np.diagonal(af.reshape(2, 2)), expected, rtol=0, atol=1e-12)


def test_read_phased_array_needs_the_table(tmp_path):
    ms = build_ms(tmp_path / "plain.ms", telescope="SKA-LOW")
    with pytest.raises(InputError, match="no PHASED_ARRAY subtable"):
        read_phased_array(ms)
    with pytest.raises(BeamUnavailable, match="no PHASED_ARRAY"):
        ska_low_from_ms(ms)
    with pytest.raises(InputError, match="one row per ANTENNA row"):
        write_phased_array(ms, np.zeros((2, 3)) + 6.4e6, np.eye(3), station_elements())


# -- the beam --------------------------------------------------------------------------
def _everybeam_direct(ms, model, times, stations, freq, ra, dec, delay):
    """EveryBeam's station_response, one call per time and direction (exact casacore);
    ``delay`` is the beam-former direction (ra, dec), rad."""
    tel = import_everybeam().load_telescope(str(ms), element_response_model=model)
    out = np.empty((len(stations), len(times), len(freq), len(ra), 2, 2), complex)
    for it, t in enumerate(times):
        d = exact_j2000_to_itrf(t, ra, dec)
        s0 = exact_j2000_to_itrf(t, *delay)[0]
        for k in range(len(ra)):
            out[:, it, :, k] = np.asarray(tel.station_response(
                np.array([t]), np.asarray(stations, np.uint64), freq, d[k], s0, s0))[0]
    return out


@pytest.mark.parametrize("model, freq", [
    ("oskar_dipole_cos", FREQ0 + DF * np.arange(NCHAN)),
    ("oskar_dipole_cos", np.array([55e6, 110e6, 230e6, 345e6])),
    ("skala40_wave", np.array([123.9e6, 124.0e6, 124.1e6, 300e6])),
])
def test_fast_beam_matches_everybeam(ska_ms, model, freq):
    beam = ska_low_from_ms(ska_ms, element_model=model)
    ra0, dec0 = beam.phase_centre
    _, _, ra, dec = sin_grid(ra0, dec0, 40.0, 5)
    ra, dec = ra.ravel(), dec.ravel()
    times = read_times(ska_ms)
    times = np.array([times[0], times[0] + 2 * 3600.0])
    stations = np.array([0, 2, 5])
    fast = beam.jones(times, freq, ra, dec, stations=stations)
    direct = _everybeam_direct(ska_ms, model, times, stations, freq, ra, dec, beam.delay_dir)
    assert np.allclose(beam.delay_dir, np.radians([253.5, -27.0]))  # casa_ms's field
    scale = np.abs(direct).max(axis=(-3, -2, -1), keepdims=True)
    # the grid's centre (the phase centre, index 12) is in the main lobe
    assert np.all(np.abs(direct[:, :, :, 12]).max(axis=(-2, -1)) > 0.5 * scale[..., 0, 0, 0])
    # msleak is zero below a station's horizon, EveryBeam's element patterns are not
    up = read_phased_array(ska_ms).axes[stations, 2]
    height = np.stack([exact_j2000_to_itrf(t, ra, dec) @ up.T for t in times])
    above = height.min(axis=(0, 2)) > 0
    assert above.sum() >= 12
    error = np.abs(fast - direct)[:, :, :, above] / scale
    assert error.max() < 1e-6  # station 2, with flagged X elements, included


def test_everybeams_own_coordinates_agree(ska_ms):
    """Against EveryBeam's (ra, dec) call, which converts directions itself (complex64)."""
    beam = ska_low_from_ms(ska_ms)
    tel = import_everybeam().load_telescope(str(ska_ms))  # EveryBeam's default model
    ra0, dec0 = beam.phase_centre
    ra, dec = ra0 + np.array([0.0, 0.1, -0.2]), dec0 + np.array([0.05, -0.1, 0.2])
    t = read_times(ska_ms)[1]
    fast = beam.jones([t], [FREQ0], ra, dec, stations=[3])[0, 0, 0]
    ref = np.array([tel.station_response(t, 3, FREQ0, float(a), float(d))
                    for a, d in zip(ra, dec)])
    assert np.abs(fast - ref).max() / np.abs(ref).max() < 1e-5


@pytest.mark.parametrize("model", ["oskar_dipole_cos", "skala40_wave"])
def test_centre_correction_gives_identity_at_phase_centre(ska_ms, model):
    beam = ska_low_from_ms(ska_ms, element_model=model)
    ra0, dec0 = beam.phase_centre
    times = read_times(ska_ms)
    freq = FREQ0 + DF * np.arange(NCHAN)
    j = beam.jones(times, freq, [ra0, ra0 + 0.3], [dec0, dec0 + 0.1], centre_correction=True)
    np.testing.assert_allclose(j[:, :, :, 0], np.broadcast_to(np.eye(2), j[:, :, :, 0].shape),
                               rtol=0, atol=1e-10)
    assert np.abs(j[:, :, :, 1] - np.eye(2)).max() > 0.01


def test_single_precision_output(ska_ms):
    beam = ska_low_from_ms(ska_ms)
    ra0, dec0 = beam.phase_centre
    args = (read_times(ska_ms), FREQ0 + DF * np.arange(NCHAN), [ra0, ra0 + 0.2], [dec0, dec0])
    j64 = beam.jones(*args, dtype=np.complex64)
    j128 = beam.jones(*args)
    assert j64.dtype == np.complex64
    np.testing.assert_allclose(j64, j128, rtol=0, atol=1e-6 * np.abs(j128).max())


def test_below_the_horizon_is_zero(ska_ms):
    beam = ska_low_from_ms(ska_ms)
    ra0, dec0 = beam.phase_centre
    j = beam.jones(read_times(ska_ms)[:1], [FREQ0], [ra0 + np.pi], [-dec0])
    assert np.all(j == 0)


# -- element models and their bands ----------------------------------------------------
def test_skala40_sets_are_those_of_the_coefficient_file():
    import h5py

    with h5py.File(everybeam_datadir() / "oskar.h5", "r") as f:
        stored = sorted(float(k) * 1e6 for k in f.keys())
    np.testing.assert_array_equal(SKALA40_FREQUENCIES_HZ, stored)


def test_skala40_set_choice_matches_everybeam():
    model = ELEMENT_MODELS["skala40_wave"]
    freq = np.array([60.9e6, 61.0e6, 123.9e6, 124.0e6, 148.9e6, 149.0e6, 195.9e6, 196.0e6])
    set_freq, chan_set = element_frequency_sets(model, freq)
    np.testing.assert_array_equal(set_freq[chan_set] / 1e6,
                                  [50, 70, 110, 137, 137, 160, 160, 230])
    resp = import_everybeam().ElementResponse.create("skala40_wave")
    one = np.zeros(1, np.int32)
    for f, s in zip(freq, set_freq[chan_set]):
        a = resp.response(one, np.array([f]), np.array([0.6]), np.array([0.4]))
        b = resp.response(one, np.array([s]), np.array([0.6]), np.array([0.4]))
        assert np.array_equal(a, b)


@pytest.mark.parametrize("name, x_column", [("oskar_dipole_cos", 1), ("skala40_wave", 0)])
def test_which_field_component_the_x_feed_takes_at_the_zenith(name, x_column):
    """Station axes E, N, U, sky columns (North, East): EveryBeam 0.9.0's dipoles put the
    X feed on the East-West axis, its SKALA4.0 coefficients on the North-South axis."""
    model = ELEMENT_MODELS[name]
    resp = import_everybeam().ElementResponse.create(name)
    d = np.array([[1e-4, 2e-4, 1.0]]) / np.linalg.norm([1e-4, 2e-4, 1.0])
    north, east = np.array([[0.0, 1.0, -2e-4]]), np.array([[1.0, 0.0, -1e-4]])
    j = np.abs(element_jones(resp, model, np.eye(3), np.array([160e6]), d, north, east)[0, 0])
    assert j[0, x_column] > 10 * j[0, 1 - x_column]
    assert j[1, 1 - x_column] > 10 * j[1, x_column]


def test_dipole_models_are_frequency_independent_in_everybeam():
    theta, phi = np.array([0.1, 0.7, 1.4]), np.array([0.3, 2.0, -1.0])
    for name in ("oskar_dipole_cos", "oskar_dipole"):
        resp = import_everybeam().ElementResponse.create(name)
        low = np.asarray(resp.response(np.full(3, 50e6), theta, phi))
        high = np.asarray(resp.response(np.full(3, 350e6), theta, phi))
        np.testing.assert_allclose(low, high, rtol=0, atol=1e-14)
        assert np.abs(low).max() > 0.1


def _one_line(err):
    assert "\n" not in str(err.value)


def test_skalow_feko_is_refused(ska_ms):
    for name in ("skalow_feko", "ska_low_feko"):
        with pytest.raises(InputError, match="broken") as err:
            ska_low_from_ms(ska_ms, element_model=name)
        _one_line(err)
    with pytest.raises(InputError, match="unknown SKA-Low element model") as err:
        check_element_model("hamaker")
    _one_line(err)


def test_out_of_band_frequencies_are_refused(ska_ms, tmp_path):
    beam = ska_low_from_ms(ska_ms, element_model="skala40_wave")
    ra0, dec0 = beam.phase_centre
    with pytest.raises(InputError, match="covers 50-320 MHz; 330 MHz") as err:
        beam.jones(read_times(ska_ms)[:1], [150e6, 330e6], [ra0], [dec0])
    _one_line(err)
    low = build_ms(tmp_path / "low.ms", telescope="SKA-LOW", freq0_hz=40e6)
    _write_layout(low)
    with pytest.raises(InputError, match="covers 50-350 MHz; 40 MHz") as err:
        ska_low_from_ms(low)
    _one_line(err)


def test_non_ska_low_ms_is_refused(tmp_path):
    ms = build_ms(tmp_path / "mwa.ms", telescope="MWA")
    with pytest.raises(BeamUnavailable, match="not 'SKA-LOW'"):
        ska_low_from_ms(ms)
