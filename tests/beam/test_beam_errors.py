"""Beam-model errors (``msleak predict --beam-errors``): zero errors leave the beam unchanged
bit for bit; failed tiles and station rotations, drawn per station from a seed, equal
EveryBeam's own beam of an MS whose LOFAR_ANTENNA_FIELD holds the same errors
(ELEMENT_FLAG, COORDINATE_AXES and the element offsets turned); LOFAR's element gains per
feed equal a numpy sum over every element of every tile, and a gain common to all elements
scales the Jones matrix (SKA-Low's gains: identities)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from ms_helpers import table
from msleak.adapters.beams import beam_options, load_beam, read_lofar_array
from msleak.beam.errors import BeamErrors, perturb_lofar, rotation_about
from msleak.beam.maps import sin_grid
from msleak.errors import InputError
from msleak.io.ms import read_spectral_windows, read_times

ERRORS = BeamErrors(failed=0.25, rotation_deg=3.0, seed=11)


@pytest.fixture(scope="module")
def lofar_ms(tmp_path_factory):
    from msleak.verbs.simulate import simulate

    return simulate(tmp_path_factory.mktemp("errors") / "ncp.ms", field="3c196",
                    duration=1.0, interval=3600.0, freq_min=150e6, nchan=2,
                    chan_width=195312.5, stations="CS00[1-3]HBA*")


def _directions(beam, fov=12.0, npix=5):
    ra0, dec0 = beam.phase_centre
    _, _, ra, dec = sin_grid(ra0, dec0, fov, npix)
    return ra.ravel(), dec.ravel()


def _inputs(ms):
    return read_times(ms)[:1], read_spectral_windows(ms)[0].freq


def test_zero_errors_leave_the_beam_unchanged_bit_for_bit(lofar_ms):
    plain = load_beam("everybeam", lofar_ms)
    zero = load_beam("everybeam", lofar_ms, beam_errors="failed=0,rotation=0,seed=5")
    times, freq = _inputs(lofar_ms)
    ra, dec = _directions(plain)
    np.testing.assert_array_equal(zero.jones(times, freq, ra, dec),
                                  plain.jones(times, freq, ra, dec))
    array = read_lofar_array(lofar_ms)
    assert perturb_lofar(array, BeamErrors()) is array


def test_errors_are_drawn_per_station_from_the_seed(lofar_ms):
    array = read_lofar_array(lofar_ms)
    one, again = perturb_lofar(array, ERRORS), perturb_lofar(array, ERRORS)
    other = perturb_lofar(array, BeamErrors(failed=0.25, rotation_deg=3.0, seed=12))
    for s0, s1, s2, s3 in zip(array.stations, one.stations, again.stations, other.stations):
        for f0, f1, f2, f3 in zip(s0.fields, s1.fields, s2.fields, s3.fields):
            np.testing.assert_array_equal(f1.tile_enabled, f2.tile_enabled)
            assert (~f1.tile_enabled).sum() == (~f0.tile_enabled).sum() + round(
                0.25 * f0.tile_enabled.size)
            assert not np.array_equal(f1.axes, f3.axes)
            # a rigid rotation about the normal: the normal and all lengths are kept
            np.testing.assert_allclose(f1.axes[2], f0.axes[2], atol=1e-12)
            np.testing.assert_allclose(np.linalg.norm(f1.tile_offsets, axis=1),
                                       np.linalg.norm(f0.tile_offsets, axis=1), rtol=1e-12)
        turn = s1.fields[0].axes[0] @ s0.fields[0].axes[1]
        assert abs(turn) < np.sin(np.radians(6 * 3.0))        # within 6 sigma


def test_rotation_about_an_axis():
    turn = rotation_about(np.array([0.0, 0.0, 2.0]), np.pi / 2)
    np.testing.assert_allclose(turn @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(turn @ turn.T, np.eye(3), atol=1e-15)


def _write_errors(ms, array) -> None:
    """Write the fields of ``array`` into LOFAR_ANTENNA_FIELD, row by row as read."""
    with table(f"{ms}/LOFAR_ANTENNA_FIELD", readonly=False) as t:
        rows = {}
        for row in range(t.nrows()):
            rows.setdefault(int(t.getcell("ANTENNA_ID", row)), []).append(row)
        for k, station in enumerate(array.stations):
            for row, field in zip(rows[k], station.fields):
                t.putcell("COORDINATE_AXES", row, field.axes)
                t.putcell("ELEMENT_OFFSET", row, field.tile_offsets)
                t.putcell("TILE_ELEMENT_OFFSET", row, field.element_offsets)
                flags = np.repeat(~field.tile_enabled[:, None], 2, axis=1)
                t.putcell("ELEMENT_FLAG", row, flags.reshape(t.getcell("ELEMENT_FLAG",
                                                                       row).shape))


def test_errors_equal_everybeam_with_the_same_errors_in_the_ms(lofar_ms, tmp_path):
    pytest.importorskip("everybeam")
    from msleak.adapters.everybeam import EveryBeamDirect

    copy = shutil.copytree(lofar_ms, tmp_path / "errors.ms")
    _write_errors(copy, perturb_lofar(read_lofar_array(lofar_ms), ERRORS))
    fast = load_beam("everybeam", lofar_ms, beam_errors=ERRORS)
    direct = EveryBeamDirect(copy)
    plain = load_beam("everybeam", lofar_ms)
    times, freq = _inputs(lofar_ms)
    ra, dec = _directions(fast)
    jf, jd, jp = (b.jones(times, freq, ra, dec) for b in (fast, direct, plain))
    scale = np.abs(jd).max(axis=(-3, -2, -1), keepdims=True)
    assert float((np.abs(jf - jd) / scale).max()) < 1e-5
    assert float((np.abs(jp - jd) / scale).max()) > 1e-2    # the errors matter


@pytest.mark.parametrize("kwargs,message", [
    (dict(beam="dipole", beam_errors="failed=0.1"), "beam_errors applies to `beam=.everybeam.` "),
    (dict(beam="everybeam", beam_errors="failed=1.5"), "failed must be a fraction in"),
    (dict(beam="everybeam", beam_errors="broken=1"), "give failed=FRACTION, rotation=DEG"),
    (dict(beam="everybeam", beam_errors="seed=x"), "seed 'x' is not a number"),
    (dict(beam="everybeam", beam_errors="rotation=-1"), "rotation must be a non-negative"),
])
def test_bad_settings_refused(kwargs, message):
    with pytest.raises(InputError, match=message):
        beam_options(kwargs["beam"], beam_errors=kwargs["beam_errors"])


def test_predict_takes_the_errors(lofar_ms, tmp_path):
    from click.testing import CliRunner

    from msleak.cli import cli
    from msleak.verbs.predict import predict

    ms = shutil.copytree(lofar_ms, tmp_path / "p.ms")
    ra0, dec0 = load_beam("everybeam", ms).phase_centre
    sky = tmp_path / "s.skymodel"
    sky.write_text("format = Name, Type, Ra, Dec, I, Q, U, V\n"
                   f"a, POINT, {ra0 + 0.05!r}, {dec0 + 0.03!r}, 1.0, 0.4, 0.2, 0.0\n")
    result = CliRunner().invoke(cli, ["predict", str(ms), "--sky", str(sky), "--column", "E",
                                      "--beam-errors", "failed=0.25,rotation=3,seed=11"])
    assert result.exit_code == 0, result.output
    plain = predict(ms, str(sky), column=None, double=True).values
    with table(ms) as t:
        written = t.getcol("E")
    direct = predict(ms, str(sky), column=None, double=True, beam_errors=ERRORS).values
    order = np.argsort(predict(ms, str(sky), column=None).coords["row"].values)
    np.testing.assert_allclose(written, direct[order], rtol=0, atol=1e-6 * np.abs(direct).max())
    assert np.abs(direct - plain).max() > 1e-3 * np.abs(plain).max()


# -- SKA-Low ----------------------------------------------------------------------------
SKA_ERRORS = BeamErrors(failed=0.2, rotation_deg=4.0, seed=3)


@pytest.fixture(scope="module")
def ska_ms(tmp_path_factory):
    """4 approximate SKA-Low stations of 256 elements, 1 time, 2 channels."""
    from casa_ms import build_ms
    from msleak.io.ms import read_antennas
    from msleak.io.phased_array import write_phased_array
    from msleak.telescope.ska_low import ska_low_layout, station_element_offsets

    lay = ska_low_layout(n_stations=4, seed=2, core_diameter=300.0)
    ms = build_ms(tmp_path_factory.mktemp("ska_err") / "ska.ms", telescope="SKA-LOW",
                  enu=lay.enu, site_itrf=lay.reference, ntime=1, nchan=2, freq0_hz=150e6)
    pos = read_antennas(ms).positions
    axes, offsets = station_element_offsets(pos, seed=1)
    write_phased_array(ms, pos, axes, offsets, [np.zeros((len(o), 2), bool) for o in offsets])
    return ms


def _ska_jones(beam, ms):
    ra0, dec0 = beam.phase_centre
    _, _, ra, dec = sin_grid(ra0, dec0, 30.0, 5)
    return beam.jones(read_times(ms)[:1], read_spectral_windows(ms)[0].freq, ra.ravel(),
                      dec.ravel())


def test_ska_low_zero_errors_bit_for_bit(ska_ms):
    plain = load_beam("everybeam", ska_ms)
    zero = load_beam("everybeam", ska_ms, beam_errors="amplitude=0,phase=0,seed=4")
    np.testing.assert_array_equal(_ska_jones(zero, ska_ms), _ska_jones(plain, ska_ms))


def test_ska_low_failures_and_rotation_equal_everybeam(ska_ms, tmp_path):
    pytest.importorskip("everybeam")
    from msleak.beam.errors import perturb_phased_array
    from msleak.io.measures import exact_j2000_to_itrf
    from msleak.io.ms import read_antennas
    from msleak.io.phased_array import read_phased_array, write_phased_array
    from msleak._everybeam import import_everybeam

    copy = shutil.copytree(ska_ms, tmp_path / "ska_err.ms")
    array, gains = perturb_phased_array(read_phased_array(ska_ms), SKA_ERRORS)
    assert gains is None
    write_phased_array(copy, read_antennas(copy).positions, array.axes,
                       array.element_offsets, array.element_flags)
    fast = load_beam("everybeam", ska_ms, beam_errors=SKA_ERRORS)
    ra0, dec0 = fast.phase_centre
    _, _, ra, dec = sin_grid(ra0, dec0, 30.0, 5)
    ra, dec = ra.ravel(), dec.ravel()
    t = read_times(ska_ms)[:1]
    freq = read_spectral_windows(ska_ms)[0].freq
    jf = fast.jones(t, freq, ra, dec)
    tel = import_everybeam().load_telescope(str(copy), element_response_model="oskar_dipole_cos")
    d = exact_j2000_to_itrf(t[0], ra, dec)
    s0 = exact_j2000_to_itrf(t[0], *fast.delay_dir)[0]
    stations = np.arange(jf.shape[0], dtype=np.uint64)
    jd = np.stack([np.asarray(tel.station_response(t, stations, freq, d[k], s0, s0))[0]
                   for k in range(ra.size)], axis=2)                    # (st, chan, dir)
    scale = np.abs(jd).max(axis=(-3, -2, -1), keepdims=True)
    assert float((np.abs(jf[:, 0] - jd) / scale).max()) < 1e-6
    plain = _ska_jones(load_beam("everybeam", ska_ms), ska_ms)[:, 0]
    assert float((np.abs(plain - jd) / scale).max()) > 1e-2


def test_ska_low_gains_are_complex_beam_former_weights(ska_ms):
    """J(G) = J(Re G) + i J(Im G) (the weights enter linearly), and a gain common to every
    element scales each feed's row of the Jones matrix."""
    from msleak.beam.ska_low import SkaLowBeam
    from msleak.io.ms import read_antennas, read_beam_directions
    from msleak.io.phased_array import read_phased_array

    array = read_phased_array(ska_ms)
    directions = read_beam_directions(ska_ms, 0)
    names = read_antennas(ska_ms).names
    rng = np.random.default_rng(9)
    gains = [1 + 0.3 * (rng.standard_normal((len(o), 2)) + 1j * rng.standard_normal((len(o), 2)))
             for o in array.element_offsets]

    def beam(g):
        return SkaLowBeam(array, directions.phase, directions.delay, names, element_gains=g)

    full = _ska_jones(beam(gains), ska_ms)
    re = _ska_jones(beam([g.real for g in gains]), ska_ms)
    im = _ska_jones(beam([g.imag for g in gains]), ska_ms)
    np.testing.assert_allclose(full, re + 1j * im, rtol=0, atol=1e-12 * np.abs(full).max())
    common = np.array([0.9 * np.exp(0.3j), 1.1 * np.exp(-0.2j)])
    scaled = _ska_jones(beam([np.tile(common, (len(o), 1)) for o in array.element_offsets]),
                        ska_ms)
    plain = _ska_jones(beam(None), ska_ms)
    np.testing.assert_allclose(scaled, common[:, None] * plain, rtol=0,
                               atol=1e-12 * np.abs(plain).max())


def test_ska_low_gain_errors_are_drawn_as_stated():
    from msleak.beam.errors import perturb_phased_array
    from msleak.io.phased_array import PhasedArray

    n = 20000
    array = PhasedArray(positions=np.zeros((1, 3)), axes=np.eye(3)[None],
                        element_offsets=[np.zeros((n, 3))],
                        element_flags=[np.zeros((n, 2), bool)])
    _, gains = perturb_phased_array(array, BeamErrors(amplitude=0.05, phase_deg=3.0, seed=1))
    g = gains[0]
    assert np.std(np.abs(g)) == pytest.approx(0.05, rel=0.03)
    assert np.degrees(np.std(np.angle(g))) == pytest.approx(3.0, rel=0.03)


def test_beam_errors_need_a_fast_path(tmp_path):
    from casa_ms import build_ms

    ms = build_ms(tmp_path / "mwa.ms")              # an MWA MS: EveryBeam directly
    with pytest.raises(InputError, match="beam errors are modelled for LOFAR HBA and SKA-Low"):
        load_beam("everybeam", ms, beam_errors="failed=0.1")


# -- LOFAR element gains ----------------------------------------------------------------
GAINS = BeamErrors(failed=0.25, rotation_deg=3.0, amplitude=0.1, phase_deg=10.0, seed=4)


def _with_gains(array, gain):
    """``array`` with ``gain(field)`` -> (ntile, nelem, 2) as every field's element gains."""
    from dataclasses import replace

    return replace(array, stations=tuple(
        replace(s, fields=tuple(replace(f, element_gains=gain(f)) for f in s.fields))
        for s in array.stations))


def _brute_jones(array, time, freq, ra, dec, corrected=False):
    """Station Jones (nstation, nchan, ndir, 2, 2) of ``array`` as a plain numpy sum over
    every element of every tile: sum over fields of diag(AF_x, AF_y) E / nfield, with
    AF_p = sum_t sum_e (w_t g_tep / nelem) exp(-2 pi i f ((s0 - d).x_t + (t0 - d).e_e) / c),
    x_t the tile position from the station phase reference, w_t = enabled / number enabled;
    ``corrected``: J(s0)^-1 J with s0 the phase centre (appended as the last direction)."""
    from msleak._everybeam import import_everybeam
    from msleak.beam.coords import clip_pole, itrf_map, radec_to_unit, sky_basis
    from msleak.beam.lofar_fast import element_jones
    from msleak.constants import SPEED_OF_LIGHT

    if corrected:
        ra, dec = np.append(ra, array.phase_centre[0]), np.append(dec, array.phase_centre[1])
    u = radec_to_unit(ra, clip_pole(dec))
    s0u = radec_to_unit(*array.delay_dir)
    t0u = radec_to_unit(*array.tile_beam_dir)
    fitmap = itrf_map(time, np.vstack([u, s0u, t0u]))
    d, s0, t0 = fitmap(u), fitmap(s0u), fitmap(t0u)
    north, east = sky_basis(d, fitmap.pole())
    k = -2j * np.pi * np.asarray(freq)[:, None, None, None] / SPEED_OF_LIGHT
    out = []
    for station in array.stations:
        jones = 0
        for f in station.fields:
            resp = import_everybeam().ElementResponse.create("hamaker", station.name)
            e = element_jones(resp, f.axes, np.asarray(freq), d, north, east)
            x = f.origin - station.phase_reference + f.tile_offsets       # (ntile, 3)
            delay = ((s0 - d) @ x.T)[:, :, None] + ((t0 - d) @ f.element_offsets.T)[:, None]
            w = f.tile_enabled / f.tile_enabled.sum()
            g = np.ones((len(x), len(f.element_offsets), 2)) if f.element_gains is None \
                else f.element_gains
            af = np.einsum("cdte,tep,t->pcd", np.exp(k * delay[None]), g, w) / g.shape[1]
            above = (d @ f.axes[2] >= 0)[None, :, None, None]
            jones = jones + above * np.stack([af[0, ..., None] * e[..., 0, :],
                                              af[1, ..., None] * e[..., 1, :]], axis=-2)
        out.append(jones / len(station.fields))
    out = np.array(out)
    if corrected:
        out = np.linalg.inv(out[:, :, -1:]) @ out[:, :, :-1]
    return out


# a band that is not uniform: the kernels' other branch
FREQS = {"uniform": np.array([150e6, 150.2e6, 150.4e6]),
         "irregular": np.array([150e6, 151.3e6, 155e6])}


@pytest.mark.parametrize("level", ["element", "tile"])
@pytest.mark.parametrize("band", ["uniform", "irregular"])
def test_lofar_gains_equal_a_sum_over_every_element(lofar_ms, level, band):
    from dataclasses import replace

    from msleak.beam.lofar_fast import LofarFastBeam

    array = perturb_lofar(read_lofar_array(lofar_ms), replace(GAINS, level=level))
    times, freq = read_times(lofar_ms)[:1], FREQS[band]
    ra, dec = _directions(LofarFastBeam(array))
    fast = LofarFastBeam(array).jones(times, freq, ra, dec)[:, 0]
    brute = _brute_jones(array, times[0], freq, ra, dec)
    scale = np.abs(brute).max(axis=(-4, -3, -2, -1), keepdims=True)
    assert float((np.abs(fast - brute) / scale).max()) < 1e-10
    # the sum itself against the model without gains (its own kernels)
    plain_array = _with_gains(array, lambda f: None)
    plain = LofarFastBeam(plain_array).jones(times, freq, ra, dec)[:, 0]
    brute_plain = _brute_jones(plain_array, times[0], freq, ra, dec)
    assert float((np.abs(plain - brute_plain) / scale).max()) < 1e-10
    assert float((np.abs(fast - plain) / scale).max()) > 1e-2       # the gains matter
    if level == "tile":      # one gain per tile and feed
        g = array.stations[0].fields[0].element_gains
        np.testing.assert_array_equal(g, np.repeat(g[:, :1], g.shape[1], axis=1))


def test_lofar_zero_gain_errors_bit_for_bit(lofar_ms):
    plain = load_beam("everybeam", lofar_ms)
    zero = load_beam("everybeam", lofar_ms, beam_errors="amplitude=0,phase=0,level=tile,seed=3")
    times, freq = _inputs(lofar_ms)
    ra, dec = _directions(plain)
    np.testing.assert_array_equal(zero.jones(times, freq, ra, dec),
                                  plain.jones(times, freq, ra, dec))
    array = read_lofar_array(lofar_ms)
    assert perturb_lofar(array, BeamErrors(amplitude=0.0, phase_deg=0.0, seed=3)) is array


def test_lofar_common_gain_scales_the_jones_matrix(lofar_ms):
    """The same gain on every element scales J exactly; a common gain per feed scales that
    feed's row; the centre-corrected beam (what the visibilities see) is unchanged."""
    from msleak.beam.lofar_fast import LofarFastBeam

    array = perturb_lofar(read_lofar_array(lofar_ms), BeamErrors(failed=0.25, seed=2))
    times, freq = _inputs(lofar_ms)
    plain = LofarFastBeam(array)
    ra, dec = _directions(plain)
    j = plain.jones(times, freq, ra, dec)
    jc = plain.jones(times, freq, ra, dec, centre_correction=True)
    for common in ([0.8 * np.exp(0.4j)] * 2, [0.9 * np.exp(0.3j), 1.1 * np.exp(-0.2j)]):
        common = np.array(common)
        beam = LofarFastBeam(_with_gains(array, lambda f: np.broadcast_to(
            common, (len(f.tile_offsets), len(f.element_offsets), 2))))
        np.testing.assert_allclose(beam.jones(times, freq, ra, dec), common[:, None] * j,
                                   rtol=0, atol=1e-12 * np.abs(j).max())
        np.testing.assert_allclose(beam.jones(times, freq, ra, dec, centre_correction=True),
                                   jc, rtol=0, atol=1e-12 * np.abs(jc).max())


def test_lofar_x_only_gains_leak_q_into_i_and_v(lofar_ms):
    """Gains on the X dipoles only make the X and Y station beams differ: a pure-Q sky
    leaks into I and V beyond the element beam's own leakage; the same gains on X and Y
    (one draw for both) change no leakage fraction, as they only scale the beam."""
    from msleak.beam import jones_to_mueller
    from msleak.beam.lofar_fast import LofarFastBeam

    array = perturb_lofar(read_lofar_array(lofar_ms), GAINS)
    times, freq = _inputs(lofar_ms)
    x_only = _with_gains(array, lambda f: np.stack(
        [f.element_gains[..., 0], np.ones(f.element_gains.shape[:2])], axis=-1))
    both = _with_gains(array, lambda f: f.element_gains[..., :1].repeat(2, axis=-1))
    plain = _with_gains(array, lambda f: None)
    ra, dec = _directions(LofarFastBeam(array))

    def mueller(a):
        j = LofarFastBeam(a).jones(times, freq, ra, dec, centre_correction=True)[:, 0]
        return jones_to_mueller(j[0], j[2])             # baseline CS001HBA0-CS002HBA0

    m_plain, m_both, m_x = mueller(plain), mueller(both), mueller(x_only)
    for row in (0, 3):                                   # Q -> I and Q -> V, per unit I
        leak = {name: m[..., row, 1] / m[..., 0, 0] for name, m in
                (("plain", m_plain), ("both", m_both), ("x", m_x))}
        np.testing.assert_allclose(leak["both"], leak["plain"], rtol=0, atol=1e-10)
        # measured: Q -> I 0.18 vs 0.011, Q -> V 0.54 vs 4.5e-4 over 12 deg
        assert np.abs(leak["x"] - leak["plain"]).max() > 10 * np.abs(leak["plain"]).max()
    # quantitatively: the same Mueller matrix from the numpy sum over every element
    jb = _brute_jones(x_only, times[0], freq, ra, dec, corrected=True)
    m_brute = jones_to_mueller(jb[0], jb[2])
    np.testing.assert_allclose(m_x, m_brute, rtol=0, atol=1e-10 * np.abs(m_brute).max())


def test_lofar_gains_are_drawn_per_station_and_keep_the_other_draws(lofar_ms):
    from dataclasses import replace

    array = read_lofar_array(lofar_ms)
    one, again = perturb_lofar(array, GAINS), perturb_lofar(array, GAINS)
    other = perturb_lofar(array, replace(GAINS, seed=5))
    without = perturb_lofar(array, replace(GAINS, amplitude=0.0, phase_deg=0.0))
    g = np.concatenate([f.element_gains.ravel() for s in one.stations for f in s.fields])
    for s1, s2, s3, s4 in zip(one.stations, again.stations, other.stations, without.stations):
        for f1, f2, f3, f4 in zip(s1.fields, s2.fields, s3.fields, s4.fields):
            np.testing.assert_array_equal(f1.element_gains, f2.element_gains)
            assert not np.array_equal(f1.element_gains, f3.element_gains)
            assert f4.element_gains is None      # failures and rotation as without gains
            np.testing.assert_array_equal(f1.tile_enabled, f4.tile_enabled)
            np.testing.assert_array_equal(f1.axes, f4.axes)
    # 6 fields x 24 tiles x 16 elements x 2 feeds: the rms within 5 % (about 5 sigma)
    assert np.std(np.abs(g)) == pytest.approx(0.1, rel=0.05)
    assert np.degrees(np.std(np.angle(g))) == pytest.approx(10.0, rel=0.05)


def test_predict_with_lofar_gains_is_the_summed_beam(lofar_ms, tmp_path):
    """msleak predict of a pure-Q point source with gain errors: every row equals
    J_p(s0)^-1 J_p B J_q^H J_q(s0)^-H of the numpy sum over every element, times a phase."""
    from msleak.verbs.predict import predict

    ra0, dec0 = load_beam("everybeam", lofar_ms).phase_centre
    sky = tmp_path / "q.skymodel"
    ra, dec = ra0 + 0.06, dec0 - 0.04
    sky.write_text("format = Name, Type, Ra, Dec, I, Q, U, V\n"
                   f"q, POINT, {ra!r}, {dec!r}, 0.0, 1.0, 0.0, 0.0\n")
    errors = BeamErrors(amplitude=0.1, phase_deg=10.0, seed=4)
    vis = predict(lofar_ms, str(sky), column=None, double=True, beam_errors=errors)
    with table(lofar_ms) as t:
        rows = vis.coords["row"].values
        a1, a2 = t.getcol("ANTENNA1")[rows], t.getcol("ANTENNA2")[rows]
    freq, times = read_spectral_windows(lofar_ms)[0].freq, read_times(lofar_ms)
    assert times.size == 1
    array = perturb_lofar(read_lofar_array(lofar_ms), errors)
    jc = _brute_jones(array, times[0], freq, [ra], [dec], corrected=True)
    b = np.diag([1.0, -1.0])
    model = jc[a1, :, 0] @ b @ np.conj(np.swapaxes(jc[a2, :, 0], -1, -2))  # (row, chan, 2, 2)
    model = model.reshape(*model.shape[:2], 4)
    v = vis.values
    phasor = np.sum(v * np.conj(model), axis=-1) / np.sum(np.abs(model) ** 2, axis=-1)
    np.testing.assert_allclose(np.abs(phasor), 1.0, rtol=0, atol=1e-6)
    np.testing.assert_allclose(v, phasor[..., None] * model, rtol=0,
                               atol=1e-6 * np.abs(model).max())
    # the gains change the Q -> I leakage of the element beam alone
    j0 = _brute_jones(_with_gains(array, lambda f: None), times[0], freq, [ra], [dec],
                      corrected=True)
    plain = (j0[a1, :, 0] @ b @ np.conj(np.swapaxes(j0[a2, :, 0], -1, -2))).reshape(v.shape)
    leak, leak0 = (model[..., 0] + model[..., 3]) / 2, (plain[..., 0] + plain[..., 3]) / 2
    assert np.abs(leak - leak0).max() > np.abs(leak0).max()    # 7.6e-4 vs 3.0e-4


def test_ska_low_refuses_tile_level_gains(ska_ms):
    with pytest.raises(InputError, match="SKA-Low stations have no tiles"):
        load_beam("everybeam", ska_ms, beam_errors="amplitude=0.02,level=tile")


def test_bad_gain_level_refused():
    with pytest.raises(InputError, match="beam_errors: level must be one of element, tile"):
        BeamErrors.parse("amplitude=0.02,level=dipole")


def test_lofar_gains_of_the_wrong_shape_refused(lofar_ms):
    from msleak.beam.lofar_fast import LofarFastBeam

    array = _with_gains(read_lofar_array(lofar_ms), lambda f: np.ones((3, 16, 2)))
    with pytest.raises(InputError, match=r"element gains of field HBA0 have shape \(3, 16, 2\), "
                                         r"not \(24, 16, 2\)"):
        LofarFastBeam(array)
