"""Beam-model errors (``msleak predict --beam-errors``): zero errors leave the beam unchanged
bit for bit; failed tiles and station rotations, drawn per station from a seed, equal
EveryBeam's own beam of an MS whose LOFAR_ANTENNA_FIELD holds the same errors
(ELEMENT_FLAG, COORDINATE_AXES and the element offsets turned)."""

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


def test_lofar_refuses_gain_errors(lofar_ms):
    with pytest.raises(InputError, match="element gain errors .* are modelled for SKA-Low"):
        load_beam("everybeam", lofar_ms, beam_errors="amplitude=0.02")


def test_beam_errors_need_a_fast_path(tmp_path):
    from casa_ms import build_ms

    ms = build_ms(tmp_path / "mwa.ms")              # an MWA MS: EveryBeam directly
    with pytest.raises(InputError, match="beam errors are modelled for LOFAR HBA and SKA-Low"):
        load_beam("everybeam", ms, beam_errors="failed=0.1")
