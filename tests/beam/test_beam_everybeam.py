"""The LOFAR beam: msleak's fast evaluator against EveryBeam, correction, physics, the NCP."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from msleak.adapters.beams import load_beam
from msleak.adapters.everybeam import EveryBeamDirect
from msleak.beam import jones_to_mueller, leakage
from msleak.beam.coords import itrf_map, radec_to_unit
from msleak.beam.lofar_fast import LofarFastBeam
from msleak.beam.maps import sin_grid
from msleak.errors import InputError
from msleak.io.measures import exact_j2000_to_itrf
from msleak.io.ms import read_spectral_windows, read_times

pytest.importorskip("everybeam")


@pytest.fixture(scope="module")
def lofar_mss(tmp_path_factory):
    """3C196 and NCP LOFAR MSs (CS001-CS003 HBA0/HBA1, 2 h, 4 channels), built once."""
    from msleak.verbs.simulate import simulate

    root = tmp_path_factory.mktemp("beam_ms")
    common = dict(duration=2.0, interval=3600.0, freq_min=150e6, nchan=4,
                  chan_width=195312.5, stations="CS00[1-3]HBA*")
    return {"3c196": simulate(root / "3c196.ms", field="3c196", **common),
            "ncp": simulate(root / "ncp.ms", field="ncp", **common)}


@pytest.fixture(scope="module")
def beams(lofar_mss):
    return {name: (load_beam("everybeam", ms), EveryBeamDirect(ms))
            for name, ms in lofar_mss.items()}


def _grid(beam, fov=15.0, npix=7):
    ra0, dec0 = beam.phase_centre
    _, _, ra, dec = sin_grid(ra0, dec0, fov, npix)
    return ra.ravel(), dec.ravel()


def _max_rel(a, b):
    """max |a - b| / max |b| per (station, time, channel), the worst of those."""
    scale = np.abs(b).max(axis=(-3, -2, -1), keepdims=True)
    return float((np.abs(a - b) / scale).max())


@pytest.mark.parametrize("field", ["3c196", "ncp"])
def test_fast_evaluator_matches_everybeam(beams, lofar_mss, field):
    fast, direct = beams[field]
    assert isinstance(fast, LofarFastBeam)
    ra, dec = _grid(fast)
    t = read_times(lofar_mss[field])
    times = np.array([t[0], t[-1], t[0] + 5 * 3600.0])
    freq = np.concatenate([read_spectral_windows(lofar_mss[field])[0].freq, [125e6, 175e6]])
    stations = np.array([0, 3, 5])
    jf = fast.jones(times, freq, ra, dec, stations=stations)
    jd = direct.jones(times, freq, ra, dec, stations=stations)
    assert jf.shape == (3, 3, 6, ra.size, 2, 2)
    assert np.all(np.abs(jd).max(axis=(-3, -2, -1)) > 0.1)
    assert _max_rel(jf, jd) < 1e-5


def test_coordinates_match_everybeams_own_conversion(beams):
    """Against EveryBeam's (ra, dec) call, which converts directions itself (complex64)."""
    fast, direct = beams["3c196"]
    ra, dec = _grid(fast, npix=3)
    t = 4.86234e9
    jf = fast.jones([t], [150e6], ra, dec, stations=[1])[0, 0, 0]
    ref = np.array([direct.telescope.station_response(t, 1, 150e6, float(a), float(d))
                    for a, d in zip(ra, dec)])
    assert np.abs(jf - ref).max() / np.abs(ref).max() < 1e-5


def test_fitted_itrf_map_matches_casacore():
    ra0, dec0 = np.radians(123.4), np.radians(48.2)
    _, _, ra, dec = sin_grid(ra0, dec0, 15.0, 5)
    u = radec_to_unit(ra.ravel(), dec.ravel())
    for t in (4.86234e9, 4.86234e9 + 7e6):
        fitted = itrf_map(t, u)(u)
        exact = exact_j2000_to_itrf(t, ra.ravel(), dec.ravel())
        assert np.linalg.norm(fitted - exact, axis=1).max() < 1e-8


def _arc_and_pole():
    """21 directions at dec -15 deg over 90 deg of RA, and the NCP: their mean is 0.76
    long, so that one cap about it would have to reach 98 deg."""
    ra = np.append(np.radians(np.linspace(0, 90, 21)), 0.0)
    return ra, np.append(np.full(21, np.radians(-15)), np.pi / 2)


def test_itrf_map_of_wide_sets_covers_them_and_the_pole():
    """Directions spread over more than 80 deg from their mean (the widest cap fitted on
    its own) take the whole-sphere map, within 1e-6 rad of casacore everywhere; a set
    holding the pole maps the pole through the same map as the directions beside it."""
    ra, dec = _arc_and_pole()
    u = radec_to_unit(ra, dec - np.append(np.zeros(21), 1e-8))
    t = 4.86234e9
    fitted = itrf_map(t, u)
    assert fitted.covers(np.array([0.0, 0.0, 1.0]))
    exact = exact_j2000_to_itrf(t, ra, dec)
    assert np.linalg.norm(fitted(u) - exact, axis=1).max() < 1e-6
    # the pole's image and the direction 1e-8 rad beside it: 1e-8 rad apart, as on the sky
    gap = np.linalg.norm(fitted.pole() - fitted(u[-1]))
    assert gap == pytest.approx(1e-8, rel=1e-3)


def test_ncp_beam_at_the_pole_does_not_depend_on_the_other_directions(beams):
    """The beam towards the NCP (its sky basis defined 1e-8 rad from the pole) is the same
    evaluated alone or with directions far from it: the centre correction of each block
    of an all-sky sky rests on it."""
    fast, _ = beams["ncp"]
    times, freq = [4.86234e9], [150e6]
    alone = fast.jones(times, freq, [0.0], [np.pi / 2])[..., 0, :, :]
    with_arc = fast.jones(times, freq, *_arc_and_pole())[..., -1, :, :]
    assert np.abs(with_arc - alone).max() < 1e-6 * np.abs(alone).max()


@pytest.mark.parametrize("field", ["3c196", "ncp"])
def test_jones_factors_multiply_to_the_jones_matrices(beams, lofar_mss, field):
    """Every HBA field has the one element response: J_p = S_p E, as :meth:`jones` gives."""
    fast, direct = beams[field]
    ra, dec = _grid(fast)
    times = read_times(lofar_mss[field])[:2]
    freq = read_spectral_windows(lofar_mss[field])[0].freq
    factors = fast.jones_factors(times, freq, ra, dec)
    assert factors.element.shape[0] == 1 and not factors.group.any()
    jones = fast.jones(times, freq, ra, dec)
    np.testing.assert_allclose(factors.full(), jones, rtol=0, atol=1e-12 * np.abs(jones).max())
    assert _max_rel(factors.full(), direct.jones(times, freq, ra, dec)) < 1e-5


def test_stations_with_fields_of_two_element_groups(beams):
    """A station whose fields are in two groups has no factors, and its Jones matrix sums
    the groups: with both groups the same response it equals the one-group result."""
    fast, _ = beams["ncp"]
    ra, dec = _grid(fast, npix=3)
    times, freq = [4.86234e9], [150e6, 152e6]
    joined = copy.copy(fast)  # stations 0 and 1 as the two fields of station 0
    joined._field_station = np.where(fast._field_station == 1, 0, fast._field_station)
    joined._field_scale = np.where(joined._field_station == 0, 0.5, fast._field_scale)
    split = copy.copy(joined)  # the same, station 1's old field in a second, equal group
    split._group_axes = fast._group_axes * 2
    split._group_response = fast._group_response * 2
    split._field_group = np.where(fast._field_station == 1, 1, fast._field_group)
    assert joined.jones_factors(times, freq, ra, dec, stations=[0, 2]) is not None
    assert split.jones_factors(times, freq, ra, dec, stations=[0, 2]) is None
    one = joined.jones(times, freq, ra, dec, stations=[0, 2])
    two = split.jones(times, freq, ra, dec, stations=[0, 2])
    np.testing.assert_allclose(two, one, rtol=0, atol=1e-12 * np.abs(one).max())
    both = fast.jones(times, freq, ra, dec, stations=[0, 1])
    np.testing.assert_allclose(one[0], both.mean(axis=0), rtol=0,
                               atol=1e-12 * np.abs(one).max())


def test_one_element_group_per_station_factors_like_one_group(beams):
    """Every field in its own group (as remote stations are): factors per station's own
    group, not per group of the array, and the same Jones matrices as with one group."""
    fast, _ = beams["3c196"]
    ra, dec = _grid(fast, npix=3)
    times, freq = [4.86234e9], [150e6, 152e6]
    own = copy.copy(fast)
    nfield = fast._field_group.size
    own._group_axes = fast._group_axes * nfield
    own._group_response = fast._group_response * nfield
    own._field_group = np.arange(nfield)
    factors = own.jones_factors(times, freq, ra, dec)
    assert factors.scalar.shape == (fast.n_stations, 1, 2, ra.size)
    assert factors.element.shape[0] == nfield
    np.testing.assert_array_equal(factors.group, fast._field_station.argsort(kind="stable"))
    one = fast.jones(times, freq, ra, dec)
    np.testing.assert_allclose(factors.full(), one, rtol=0, atol=1e-12 * np.abs(one).max())
    np.testing.assert_allclose(own.jones(times, freq, ra, dec), one, rtol=0,
                               atol=1e-12 * np.abs(one).max())


def test_phase_centre_correction(beams):
    fast, _ = beams["3c196"]
    ra0, dec0 = fast.phase_centre
    ra, dec = _grid(fast, npix=3)
    times, freq = [4.86234e9, 4.86235e9], [150e6, 152e6]
    raw = fast.jones(times, freq, ra, dec)
    j0 = fast.jones_centre(times, freq)
    corrected = fast.jones(times, freq, np.append(ra, ra0), np.append(dec, dec0),
                           centre_correction=True)
    np.testing.assert_allclose(corrected[..., -1, :, :],
                               np.broadcast_to(np.eye(2), corrected[..., -1, :, :].shape),
                               atol=1e-10)
    expected = np.linalg.inv(j0)[..., None, :, :] @ raw
    np.testing.assert_allclose(corrected[..., :-1, :, :], expected, atol=1e-10)


def test_station_beam_fwhm_at_150_mhz(beams, lofar_mss):
    fast, _ = beams["3c196"]
    ra0, dec0 = fast.phase_centre
    t = float(np.median(read_times(lofar_mss["3c196"])))
    offsets = np.radians(np.linspace(-5, 5, 201))
    widths = []
    for axis in range(2):  # cuts along l and m
        ll, mm = (offsets, 0 * offsets) if axis == 0 else (0 * offsets, offsets)
        nn = np.sqrt(1 - ll ** 2 - mm ** 2)
        dec = np.arcsin(mm * np.cos(dec0) + nn * np.sin(dec0))
        ra = ra0 + np.arctan2(ll, nn * np.cos(dec0) - mm * np.sin(dec0))
        j = fast.jones([t], [150e6], ra, dec, stations=[2], centre_correction=True)[0, 0, 0]
        power = np.real(jones_to_mueller(j)[:, 0, 0])
        inside = offsets[power >= 0.5]
        widths.append(np.degrees(inside.max() - inside.min()))
    assert all(3.5 < w < 5.5 for w in widths), widths


def test_leakage_grows_away_from_the_centre(beams, lofar_mss):
    fast, _ = beams["3c196"]
    ra0, dec0 = fast.phase_centre
    t = read_times(lofar_mss["3c196"])[0]
    pa = np.radians(np.arange(0, 360, 30))
    means = []
    for radius in (0.0, 1.0, 3.0, 6.0):
        r = np.radians(radius)
        ll, mm = np.sin(r) * np.sin(pa), np.sin(r) * np.cos(pa)
        nn = np.sqrt(1 - ll ** 2 - mm ** 2)
        dec = np.arcsin(mm * np.cos(dec0) + nn * np.sin(dec0))
        ra = ra0 + np.arctan2(ll, nn * np.cos(dec0) - mm * np.sin(dec0))
        j = fast.jones([t], [150e6], ra, dec, centre_correction=True)[:, 0, 0]
        means.append(np.mean(leakage(np.real(jones_to_mueller(j)))))
    assert means[0] < 1e-9
    assert means[0] < means[1] < means[2] < means[3]
    assert means[3] < 0.5


def test_ncp_pixel_is_finite_and_consistent(beams, lofar_mss):
    fast, direct = beams["ncp"]
    t = read_times(lofar_mss["ncp"])[:1]
    a, b = 0.3, 1.9
    ra = np.array([a, b, a])
    dec = np.array([np.pi / 2, np.pi / 2, np.pi / 2 - 1e-7])
    jf = fast.jones(t, [150e6], ra, dec)[:, 0, 0]
    jd = direct.jones(t, [150e6], ra, dec)[:, 0, 0]
    assert np.all(np.isfinite(jf)) and np.abs(jf).max() > 0.1
    assert np.abs(jf - jd).max() / np.abs(jd).max() < 1e-5
    # the limit along the meridian: continuous with a point 0.02" below the pole
    assert np.abs(jf[:, 0] - jf[:, 2]).max() / np.abs(jf[:, 2]).max() < 1e-5
    # only the basis differs between RA a and b at the pole: (N, E) turns by b - a, so
    # J(b) = J(a) R with R the rotation taking the basis at a to the one at b
    c, s = np.cos(b - a), np.sin(b - a)
    rot = np.array([[c, s], [-s, c]])
    np.testing.assert_allclose(jf[:, 1], jf[:, 0] @ rot, atol=1e-6)


@pytest.mark.parametrize("model", ["everybeam", "everybeam-direct"])
def test_below_horizon_is_zero_not_nan(beams, model):
    beam = beams["3c196"][0 if model == "everybeam" else 1]
    j = beam.jones([4.86234e9], [150e6], [1.0, 2.0], [np.radians(-60), np.radians(-89.9)])
    assert np.all(j == 0)


def test_everybeam_without_lofar_tables_names_dipole(make_ms, tmp_path):
    layout = tmp_path / "array.txt"
    layout.write_text("frame = enu\ntelescope = MYARRAY\nA 0 0 0\nB 100 20 0\nC -50 80 0\n")
    ms = make_ms("custom.ms", layout=str(layout), stations=None)
    for model in ("everybeam", "everybeam-direct"):
        with pytest.raises(InputError, match="`beam='dipole'`"):
            load_beam(model, ms)


def _rotation(seed):
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q


def test_lattice_factors_split_a_tile_and_only_a_lattice():
    """A rotated 4 x 4 tile of 1.25 m splits into 4 + 4 offsets that add up to every
    element; 2 rows of 8 irregular columns into 2 + 8 (8 regular ones would be 4 + 4); anything that is not a product in the given order
    (shuffled, one element moved by 1e-6 m, 16 random points, 7 points) is left whole."""
    from msleak.beam.lofar_fast import lattice_factors

    xy = 1.25 * (np.arange(4) - 1.5)
    plane = np.stack(np.meshgrid(xy, xy, indexing="ij"), axis=-1).reshape(16, 2)
    tile = np.c_[plane, np.zeros(16)] @ _rotation(1).T + [0.3, -0.2, 0.1]
    a, b = lattice_factors(tile)
    assert a.shape == b.shape == (4, 3)
    np.testing.assert_allclose((a[:, None] + b[None]).reshape(16, 3), tile, rtol=0, atol=1e-12)
    columns = np.array([0.0, 1.0, 3.0, 6.0, 10.0, 15.0, 21.0, 28.0])
    rect = np.c_[np.repeat([0.0, 2.0], 8), np.tile(columns, 2), np.zeros(16)]
    a, b = lattice_factors(rect @ _rotation(2).T)
    assert (len(a), len(b)) == (2, 8)
    moved = tile.copy()
    moved[5, 0] += 1e-6
    rng = np.random.default_rng(3)
    for bad in (tile[rng.permutation(16)], moved, rng.normal(size=(16, 3)), tile[:7]):
        assert lattice_factors(bad) is None


@pytest.mark.parametrize("field", ["3c196", "ncp"])
def test_tile_factor_split_into_rows_and_columns_equals_the_element_sum(beams, lofar_mss,
                                                                        field, monkeypatch):
    """The simulated MS's tiles are lattices, summed as rows times columns; the Jones
    matrices equal those of the 16-element sum (the beam built with no lattice found) to
    1e-12, at regular and irregular channels."""
    from msleak.beam import lofar_fast

    fast, _ = beams[field]
    assert (fast._layout_n == 4).all()
    monkeypatch.setattr(lofar_fast, "lattice_factors", lambda offsets: None)
    whole = load_beam("everybeam", lofar_mss[field])
    assert (whole._layout_n[:, 0] == 16).all() and not whole._layout_n[:, 1].any()
    ra, dec = _grid(fast)
    for freq in ([150e6, 152e6, 154e6], [120e6, 151e6, 188e6]):
        split = fast.jones([4.86234e9], freq, ra, dec)
        ref = whole.jones([4.86234e9], freq, ra, dec)
        np.testing.assert_allclose(split, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
