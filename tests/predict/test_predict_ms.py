"""`msleak predict` on small simulated Measurement Sets: answers known in advance,
an independent direct-sum DFT, column handling, provenance, errors and resume."""

from __future__ import annotations

import hashlib
import os
import stat

import numpy as np
import pytest
from click.testing import CliRunner

from msleak.beam.lofar_fast import LofarFastBeam
from msleak.cli import cli
from msleak.errors import InputError
from msleak.verbs import predict_chunks as chunks
from msleak.verbs.predict import predict as run_predict
from faults import fail_after_chunks
from ms_helpers import C, copy_spectral_window
from ms_helpers import channel_freqs as _freq
from ms_helpers import direct_dft as _direct_dft
from ms_helpers import lm_to_radec
from ms_helpers import phase_centre as _phase_centre
from ms_helpers import table as _table
from ms_helpers import write_sky as _write_sky


# ----------------------------------------------------------------------------- helpers
def _col(ms, name):
    with _table(ms) as t:
        return t.getcol(name)


def _invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _md5(ms, column):
    return hashlib.md5(np.ascontiguousarray(_col(ms, column)).tobytes()).hexdigest()


# ----------------------------------------------------------------------------- answers
@pytest.mark.parametrize("stokes,expect", [((0, 1, 0, 0), (1, 0, 0, -1)),
                                           ((0, 0, 1, 0), (0, 1, 1, 0))])
def test_point_source_at_phase_centre_no_beam(small_lofar_ms, tmp_path, stokes, expect):
    """1 Jy Q at the centre: XX = 1, YY = -1, XY = YX = 0; 1 Jy U: XY = YX = 1."""
    ra0, dec0 = _phase_centre(small_lofar_ms)
    sky = _write_sky(tmp_path / "c.skymodel", [(ra0, dec0, *stokes)])
    res = _invoke("predict", small_lofar_ms, "--sky", sky, "--beam", "none")
    assert res.exit_code == 0, res.output
    model = _col(small_lofar_ms, "MODEL_DATA")
    assert model.shape == _col(small_lofar_ms, "DATA").shape
    np.testing.assert_allclose(model, np.broadcast_to(np.array(expect, complex), model.shape),
                               atol=1e-6)


def test_off_centre_sources_match_direct_dft(make_ms, tmp_path):
    """Several polarized sources up to 5 deg off centre, autocorrelations included, rows
    shuffled: msleak --double equals a direct DFT over rows to 1e-6."""
    ms = make_ms("auto.ms", autocorrelations=True, stations="CS00[1-4]HBA*")
    shuffled = tmp_path / "shuffled.ms"
    with _table(ms) as t:
        perm = np.random.default_rng(0).permutation(t.nrows())
        ref = t.selectrows(perm.tolist())
        ref.copy(str(shuffled), deep=True)
        ref.close()
    with _table(shuffled) as t:
        a1, a2 = t.getcol("ANTENNA1"), t.getcol("ANTENNA2")
        assert np.any(a1 == a2) and np.any(np.diff(t.getcol("TIME")) < 0)
    ra0, dec0 = _phase_centre(shuffled)
    rng = np.random.default_rng(7)
    l, m = rng.uniform(-0.09, 0.09, (2, 8))
    ra, dec = lm_to_radec(ra0, dec0, l, m)
    sources = [(ra[k], dec[k], *rng.normal(0, 1, 4)) for k in range(8)]
    sky = _write_sky(tmp_path / "off.skymodel", sources)
    run_predict(shuffled, sky, beam="none", double=True, progress=False)
    model = _col(shuffled, "MODEL_DATA")
    ref = _direct_dft(shuffled, sources)
    assert np.abs(model - ref).max() <= 1e-6 * np.abs(ref).max()
    # single precision: measured error stays at the 1e-6 level of the brightest term
    run_predict(shuffled, sky, beam="none", column="MODEL_SINGLE", progress=False)
    single = _col(shuffled, "MODEL_SINGLE")
    assert np.abs(single - ref).max() <= 1e-5 * np.abs(ref).max()


def test_circular_feeds(small_lofar_ms, tmp_path):
    """RR = I + V, RL = Q + iU, LR = Q - iU, LL = I - V for a source at the centre."""
    with _table(f"{small_lofar_ms}/POLARIZATION", readonly=False) as t:
        t.putcell("CORR_TYPE", 0, np.array([5, 6, 7, 8], dtype=np.int32))
    ra0, dec0 = _phase_centre(small_lofar_ms)
    i, q, u, v = 2.0, 0.5, -0.3, 0.1
    sky = _write_sky(tmp_path / "c.skymodel", [(ra0, dec0, i, q, u, v)])
    run_predict(small_lofar_ms, sky, beam="none", progress=False)
    model = _col(small_lofar_ms, "MODEL_DATA")
    expect = np.array([i + v, q + 1j * u, q - 1j * u, i - v])
    np.testing.assert_allclose(model, np.broadcast_to(expect, model.shape), atol=1e-6)


# ----------------------------------------------------------------------------- beams
def _jones_fn(station, time, freq, ra, dec):
    """A smooth, station-dependent, non-unitary test Jones (station, time, chan, dir, 2, 2)."""
    st = np.asarray(station, float)[:, None, None, None]
    tt = (np.asarray(time, float) - 4.8e9)[None, :, None, None] / 1e4
    ff = np.asarray(freq, float)[None, None, :, None] / 1e8
    ra = np.asarray(ra, float)[None, None, None, :]
    dec = np.asarray(dec, float)[None, None, None, :]
    out = np.empty(np.broadcast_shapes(st.shape, tt.shape, ff.shape, ra.shape) + (2, 2),
                   complex)
    out[..., 0, 0] = (1 + 0.1 * st) * np.exp(1j * (3 * ra + tt + ff))
    out[..., 0, 1] = 0.2 * np.sin(5 * dec + st) + 0.05j * ff
    out[..., 1, 0] = 0.1 * np.cos(4 * ra - st * tt) - 0.03j
    out[..., 1, 1] = (0.9 - 0.05 * st) * np.exp(-1j * (2 * dec - ff * st))
    return out


class _StandInBeam:
    """Implements BeamModel.jones with :func:`_jones_fn` (no centre correction itself)."""

    name = "standin"

    def jones(self, time_mjd_s, freq_hz, ra, dec, *, stations=None, centre_correction=False,
              dtype=np.complex128):
        assert not centre_correction  # msleak applies J(s0)^-1 itself
        return _jones_fn(stations, time_mjd_s, freq_hz, ra, dec).astype(dtype)

    def jones_factors(self, *args, **kwargs):
        return None  # not a factored beam


def test_per_station_beam_and_centre_correction_match_direct_sum(small_lofar_ms, tmp_path,
                                                                 monkeypatch):
    monkeypatch.setattr(chunks, "_load_beam", lambda name, ms, options=None: _StandInBeam())
    ra0, dec0 = _phase_centre(small_lofar_ms)
    rng = np.random.default_rng(8)
    l, m = rng.uniform(-0.06, 0.06, (2, 5))
    ra, dec = lm_to_radec(ra0, dec0, l, m)
    sources = [(ra[k], dec[k], *rng.normal(0, 1, 4)) for k in range(5)]
    sky = _write_sky(tmp_path / "b.skymodel", sources)
    run_predict(small_lofar_ms, sky, beam="everybeam", double=True, progress=False,
                column="CORR")
    run_predict(small_lofar_ms, sky, beam="everybeam", double=True, progress=False,
                column="FULL", centre_correction=False)
    with _table(small_lofar_ms) as t:
        uvw, a1, a2, time = (t.getcol(c) for c in ("UVW", "ANTENNA1", "ANTENNA2", "TIME"))
    freq = _freq(small_lofar_ms)
    full = np.zeros((uvw.shape[0], freq.size, 2, 2), complex)
    for ra_s, dec_s, i, q, u, v in sources:
        l_ = np.cos(dec_s) * np.sin(ra_s - ra0)
        m_ = np.sin(dec_s) * np.cos(dec0) - np.cos(dec_s) * np.sin(dec0) * np.cos(ra_s - ra0)
        n_ = np.sin(dec_s) * np.sin(dec0) + np.cos(dec_s) * np.cos(dec0) * np.cos(ra_s - ra0)
        phase = np.exp(2j * np.pi * (uvw @ [l_, m_, n_ - 1])[:, None] * freq / C)
        b = np.array([[i + q, u + 1j * v], [u - 1j * v, i - q]])
        for r in range(uvw.shape[0]):
            jp = _jones_fn([a1[r]], [time[r]], freq, [ra_s], [dec_s])[0, 0, :, 0]
            jq = _jones_fn([a2[r]], [time[r]], freq, [ra_s], [dec_s])[0, 0, :, 0]
            full[r] += jp @ b @ np.conj(np.swapaxes(jq, -1, -2)) * phase[r, :, None, None]
    got_full = _col(small_lofar_ms, "FULL").reshape(full.shape)
    # (the column stores complex64 like DATA: 1e-6 covers its rounding)
    assert np.abs(got_full - full).max() <= 1e-6 * np.abs(full).max()
    corr = np.empty_like(full)
    for r in range(uvw.shape[0]):
        j0p = np.linalg.inv(_jones_fn([a1[r]], [time[r]], freq, [ra0], [dec0])[0, 0, :, 0])
        j0q = np.linalg.inv(_jones_fn([a2[r]], [time[r]], freq, [ra0], [dec0])[0, 0, :, 0])
        corr[r] = j0p @ full[r] @ np.conj(np.swapaxes(j0q, -1, -2))
    got = _col(small_lofar_ms, "CORR").reshape(corr.shape)
    assert np.abs(got - corr).max() <= 1e-6 * np.abs(corr).max()


def test_full_beam_source_at_centre_with_correction_equals_unbeamed(small_lofar_ms, tmp_path):
    """LOFAR beam + phase-centre correction: a source at the centre sees the identity."""
    ra0, dec0 = _phase_centre(small_lofar_ms)
    sky = _write_sky(tmp_path / "c.skymodel", [(ra0, dec0, 1.0, 0.4, -0.3, 0.05)])
    run_predict(small_lofar_ms, sky, beam="everybeam", progress=False, column="BEAMED")
    run_predict(small_lofar_ms, sky, beam="none", progress=False, column="UNBEAMED")
    beamed = _col(small_lofar_ms, "BEAMED")
    unbeamed = _col(small_lofar_ms, "UNBEAMED")
    assert np.abs(beamed - unbeamed).max() <= 1e-5 * np.abs(unbeamed).max()
    # and the beam is really applied without the correction
    run_predict(small_lofar_ms, sky, beam="everybeam", progress=False, column="RAW",
                centre_correction=False)
    assert np.abs(_col(small_lofar_ms, "RAW") - unbeamed).max() > 1e-2 * np.abs(unbeamed).max()


@pytest.mark.parametrize("centre_correction", [True, False])
def test_lofar_beam_factors_give_the_visibilities_of_its_jones(small_lofar_ms, tmp_path,
                                                               monkeypatch, centre_correction):
    """Predict uses the LOFAR beam as J_p = S_p E (array factor times element response);
    the visibilities equal those of its full Jones matrices (computed in complex128, the
    column stores complex64: one rounding apart)."""
    ra0, dec0 = _phase_centre(small_lofar_ms)
    rng = np.random.default_rng(21)
    ra, dec = lm_to_radec(ra0, dec0, *rng.uniform(-0.06, 0.06, (2, 6)))
    sky = _write_sky(tmp_path / "f.skymodel",
                     [(ra[k], dec[k], *rng.normal(0, 1, 4)) for k in range(6)])
    kw = dict(beam="everybeam", double=True, progress=False,
              centre_correction=centre_correction)
    run_predict(small_lofar_ms, sky, column="FACTORED", **kw)
    monkeypatch.setattr(LofarFastBeam, "_jones_factors", lambda self, *args: None)
    run_predict(small_lofar_ms, sky, column="FULL_JONES", **kw)
    factored, full = _col(small_lofar_ms, "FACTORED"), _col(small_lofar_ms, "FULL_JONES")
    assert np.abs(full).max() > 0.1
    assert np.abs(factored - full).max() <= 2e-7 * np.abs(full).max()


# ----------------------------------------------------------------------------- columns
def test_data_untouched_second_column_and_provenance(small_lofar_ms, tmp_path):
    with _table(small_lofar_ms, readonly=False) as t:  # non-trivial DATA and FLAG
        data = t.getcol("DATA")
        t.putcol("DATA", (np.arange(data.size).reshape(data.shape) * (1 + 2j)).astype(data.dtype))
        flag = t.getcol("FLAG")
        flag[::3] = True
        t.putcol("FLAG", flag)
    before = _md5(small_lofar_ms, "DATA"), _md5(small_lofar_ms, "FLAG")
    ra0, dec0 = _phase_centre(small_lofar_ms)
    sky = _write_sky(tmp_path / "c.skymodel", [(ra0 + 0.01, dec0, 0.0, 1.0, 0.5, 0.0)])
    assert _invoke("predict", small_lofar_ms, "--sky", sky, "--beam", "none").exit_code == 0
    res = _invoke("predict", small_lofar_ms, "--sky", sky, "--beam", "none", "--column",
                  "MODEL_B", "--double")
    assert res.exit_code == 0, res.output
    assert (_md5(small_lofar_ms, "DATA"), _md5(small_lofar_ms, "FLAG")) == before
    a, b = _col(small_lofar_ms, "MODEL_DATA"), _col(small_lofar_ms, "MODEL_B")
    assert np.abs(a).min() > 0.1  # flagged rows are predicted too
    np.testing.assert_allclose(a, b, atol=1e-5)
    with _table(small_lofar_ms) as t:
        assert t.getdminfo("MODEL_B")["TYPE"].startswith("Tiled")
        state = t.getcolkeyword("MODEL_B", "MSLEAK_PREDICT")
    assert state["complete"] and state["rows_done"] == a.shape[0]
    assert state["beam"] == "none" and state["precision"] == "complex128"
    assert state["sky"] == str(sky.resolve()) and state["msleak_version"]


def test_double_column_stores_the_complex128_values_and_refuses_a_complex64_one(
        small_lofar_ms, tmp_path):
    """--double-column creates a complex128 (DComplex) column holding bit for bit what
    predict returns in complex128; DATA keeps its type; the same run into a complex64
    column differs only by complex64 rounding; --double-column refuses an existing
    complex64 column in one line (and DATA, which keeps its type) and rewrites an
    existing complex128 one."""
    ra0, dec0 = _phase_centre(small_lofar_ms)
    sky = _write_sky(tmp_path / "c.skymodel", [(ra0 + 0.03, dec0 - 0.02, 1.0, 0.7, -0.4, 0.1),
                                               (ra0 - 0.05, dec0 + 0.01, 0.0, 0.3, 0.9, 0.0)])
    res = _invoke("predict", small_lofar_ms, "--sky", sky, "--beam", "dipole", "--column",
                  "MODEL_D", "--double-column")
    assert res.exit_code == 0, res.output
    with _table(small_lofar_ms) as t:
        assert t.getcoldesc("MODEL_D")["valueType"] == "dcomplex"
        assert t.getcoldesc("DATA")["valueType"] == "complex"
        assert t.getcolkeyword("MODEL_D", "MSLEAK_PREDICT")["precision"] == "complex128"
    stored = _col(small_lofar_ms, "MODEL_D")
    ref = run_predict(small_lofar_ms, sky, column=None, beam="dipole", double=True)
    assert stored.dtype == np.complex128 and np.abs(stored).max() > 0.1
    np.testing.assert_array_equal(stored[ref["row"].values], ref.values)
    res = _invoke("predict", small_lofar_ms, "--sky", sky, "--beam", "dipole", "--column",
                  "MODEL_S", "--double")
    assert res.exit_code == 0, res.output
    single = _col(small_lofar_ms, "MODEL_S")
    assert single.dtype == np.complex64
    diff = np.abs(single - stored).max()
    assert 0 < diff <= 2 ** -23 * np.abs(stored).max()       # one complex64 rounding
    res = _invoke("predict", small_lofar_ms, "--sky", sky, "--beam", "dipole", "--column",
                  "MODEL_S", "--double-column")
    assert res.exit_code == 2 and "MODEL_S exists as complex64" in res.output
    assert len(res.output.strip().splitlines()) == 1
    res = _invoke("predict", small_lofar_ms, "--sky", sky, "--beam", "dipole", "--column",
                  "MODEL_D", "--double-column", "--restart")
    assert res.exit_code == 0, res.output
    np.testing.assert_array_equal(_col(small_lofar_ms, "MODEL_D"), stored)
    with pytest.raises(InputError, match="double_column=True sets the type"):
        run_predict(small_lofar_ms, sky, column=None, beam="dipole", double_column=True)
    res = _invoke("predict", small_lofar_ms, "--sky", sky, "--beam", "dipole", "--column",
                  "DATA", "--overwrite-data", "--double-column")
    assert res.exit_code == 2 and "DATA keeps its type: use --double" in res.output


def test_interrupted_run_is_marked_and_resumed(small_lofar_ms, tmp_path, monkeypatch):
    ra0, dec0 = _phase_centre(small_lofar_ms)
    sky = _write_sky(tmp_path / "c.skymodel", [(ra0 + 0.02, dec0 - 0.01, 0.0, 1.0, 0.3, 0.0)])
    kw = dict(beam="none", progress=False, memory_limit=20_000)  # one time slot per chunk
    run_predict(small_lofar_ms, sky, column="REFERENCE", **kw)
    with monkeypatch.context() as m, pytest.raises(RuntimeError, match="simulated failure"):
        fail_after_chunks(m, 2)
        run_predict(small_lofar_ms, sky, **kw)
    times = _col(small_lofar_ms, "TIME")
    with _table(small_lofar_ms) as t:
        state = t.getcolkeyword("MODEL_DATA", "MSLEAK_PREDICT")
        partial = t.getcol("MODEL_DATA")
    done = times <= np.unique(times)[1]
    assert not state["complete"] and state["rows_done"] == done.sum()
    ref = _col(small_lofar_ms, "REFERENCE")
    np.testing.assert_array_equal(partial[done], ref[done])
    assert np.all(partial[~done] == 0)
    result = run_predict(small_lofar_ms, sky, **kw)
    assert result.resumed and result.rows_written == (~done).sum()
    with _table(small_lofar_ms) as t:
        assert t.getcolkeyword("MODEL_DATA", "MSLEAK_PREDICT")["complete"]
    np.testing.assert_array_equal(_col(small_lofar_ms, "MODEL_DATA"), ref)
    # other settings: no resume, everything recomputed
    again = run_predict(small_lofar_ms, sky, double=True, **kw)
    assert not again.resumed and again.rows_written == times.size


# ----------------------------------------------------------------------------- errors
def _cube(path, freq, npix=5, pixel_deg=1.0):
    from msleak.adapters.sky_fits import write_cube
    from msleak.sky.cube import SkyCube, make_celestial_wcs

    data = np.ones((2, len(freq), npix, npix), np.float32)
    cube = SkyCube(data=data, freq=np.asarray(freq, float), stokes=("Q", "U"),
                   wcs=make_celestial_wcs(npix, npix, pixel_deg, 0.0, 60.0), units="Jy/pixel")
    write_cube(cube, path)
    return path


def test_fits_cube_sky_one_source_per_pixel(small_lofar_ms, tmp_path):
    """A cube on the MS channels predicts; --fov crops it (one pixel: the centre)."""
    cube = _cube(tmp_path / "sky.fits", _freq(small_lofar_ms))
    res = _invoke("predict", small_lofar_ms, "--sky", cube, "--beam", "none", "--fov", "1")
    assert res.exit_code == 0, res.output
    model = _col(small_lofar_ms, "MODEL_DATA")
    # the central pixel is at the phase centre (cube re-centred on the field): Q = U = 1
    np.testing.assert_allclose(model, np.broadcast_to([1, 1, 1, -1], model.shape), atol=1e-5)


def _cube_at(path, freq, ra_deg, dec_deg):
    from msleak.adapters.sky_fits import write_cube
    from msleak.sky.cube import SkyCube, make_celestial_wcs

    data = np.ones((2, len(freq), 3, 3), np.float32)
    write_cube(SkyCube(data=data, freq=np.asarray(freq, float), stokes=("Q", "U"),
                       wcs=make_celestial_wcs(3, 3, 1.0, ra_deg, dec_deg), units="Jy/pixel"),
               path)
    return path


@pytest.mark.parametrize("where", ["elsewhere", "on the phase centre"])
def test_recentred_sky_is_reported(_small_lofar_ms_master, tmp_path, caplog, where):
    """A pixel sky centred away from the MS's phase centre is re-centred with one warning
    naming both centres and the MS; a sky on the phase centre (to 1 arcsec) gets none."""
    import logging

    ms = _small_lofar_ms_master
    ra, dec = np.degrees(_phase_centre(ms))
    centre = (10.0, 60.0) if where == "elsewhere" else (ra + 0.5 / 3600, dec - 0.5 / 3600)
    cube = _cube_at(tmp_path / "sky.fits", _freq(ms), *centre)
    with caplog.at_level(logging.WARNING, logger="msleak"):
        run_predict(ms, cube, column=None, beam="none")
    warned = [r.getMessage() for r in caplog.records
              if r.name == "msleak.predict.components" and r.levelno == logging.WARNING]
    if where == "elsewhere":
        assert warned == [
            f"sky {cube} is centred at RA 10.0000 deg, Dec 60.0000 deg; re-centred on the "
            f"phase centre RA {ra % 360:.4f} deg, Dec {dec:.4f} deg of {ms} (every pixel "
            "keeps its offset from the centre, docs/sky.md)"]
    else:
        assert warned == []


@pytest.mark.parametrize("case,message", [
    ("missing-sky", "does not exist"),
    ("frequency", "no sky channel"),
    ("fov", "larger than the cube"),
    ("data", "refusing to overwrite the DATA column"),
    ("flag", "holds MS metadata"),
    ("readonly", "read-only"),
    ("field", "no field"),
])
def test_bad_inputs_exit_2_with_one_line(small_lofar_ms, tmp_path, case, message):
    freq = _freq(small_lofar_ms)
    cube = _cube(tmp_path / "sky.fits", freq)
    args = ["predict", small_lofar_ms, "--sky", cube, "--beam", "none"]
    if case == "missing-sky":
        args[3] = tmp_path / "nothing.fits"
    elif case == "frequency":
        args[3] = _cube(tmp_path / "other.fits", freq + 5e6)
    elif case == "fov":
        args += ["--fov", "10"]
    elif case == "data":
        args += ["--column", "DATA"]
    elif case == "flag":
        args += ["--column", "FLAG"]
    elif case == "field":
        args += ["--field", "NOSUCHFIELD"]
    elif case == "readonly":
        for root, dirs, files in os.walk(small_lofar_ms):
            for name in dirs + files + [""]:
                path = os.path.join(root, name)
                os.chmod(path, os.stat(path).st_mode & ~(stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))
    before = _md5(small_lofar_ms, "DATA")
    res = _invoke(*args)
    if case == "readonly":
        for root, dirs, files in os.walk(small_lofar_ms):
            for name in dirs + files + [""]:
                os.chmod(os.path.join(root, name), 0o755)
    assert res.exit_code == 2, res.output
    lines = [line for line in res.output.splitlines() if line.startswith("msleak: error")]
    assert len(lines) == 1 and message in lines[0], res.output
    assert _md5(small_lofar_ms, "DATA") == before
    with _table(small_lofar_ms) as t:
        assert "MODEL_DATA" not in t.colnames()


def test_data_column_with_flag_is_allowed(small_lofar_ms, tmp_path):
    ra0, dec0 = _phase_centre(small_lofar_ms)
    sky = _write_sky(tmp_path / "c.skymodel", [(ra0, dec0, 0.0, 1.0, 0.0, 0.0)])
    res = _invoke("predict", small_lofar_ms, "--sky", sky, "--beam", "none", "--column", "DATA",
                  "--overwrite-data")
    assert res.exit_code == 0, res.output
    np.testing.assert_allclose(_col(small_lofar_ms, "DATA")[:, :, 3], -1, atol=1e-6)


def test_api_errors_are_input_errors(small_lofar_ms, tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        run_predict(small_lofar_ms, tmp_path / "none.skymodel", beam="none")
    with pytest.raises(InputError, match="no such Measurement Set"):
        run_predict(tmp_path / "none.ms", tmp_path / "none.skymodel", beam="none")
    sky = _write_sky(tmp_path / "c.skymodel", [(0.0, 0.0, 1.0, 0.0, 0.0, 0.0)])
    with pytest.raises(InputError, match="no spectral window"):
        run_predict(small_lofar_ms, sky, beam="none", spw=[3])
    with pytest.raises(InputError, match="invalid column name"):
        run_predict(small_lofar_ms, sky, beam="none", column="MODEL DATA")
    res = _invoke("predict", small_lofar_ms, "--sky", sky, "--memory-limit", "lots")
    assert res.exit_code == 2 and "memory size" in res.output


def _add_spectral_window(ms, shift_hz):
    """Append SPW 1 (channels shifted by shift_hz), DATA_DESCRIPTION 1 and a copy of every
    main-table row with DATA_DESC_ID = 1."""
    copy_spectral_window(ms, shift_hz)
    with _table(f"{ms}/DATA_DESCRIPTION", readonly=False) as t:
        t.addrows(1)
        t.putcell("SPECTRAL_WINDOW_ID", 1, 1)
        t.putcell("POLARIZATION_ID", 1, 0)
        t.putcell("FLAG_ROW", 1, False)
    with _table(ms, readonly=False) as t:
        n = t.nrows()
        t.addrows(n)
        for col in t.colnames():
            if col != "FLAG_CATEGORY" and t.iscelldefined(col, 0):
                t.putcol(col, t.getcol(col, 0, n), startrow=n, nrow=n)
        t.putcol("DATA_DESC_ID", np.ones(n, np.int32), startrow=n, nrow=n)
    return n


def test_two_spectral_windows_loop_and_select(small_lofar_ms, tmp_path):
    n = _add_spectral_window(small_lofar_ms, 10e6)
    ra0, dec0 = _phase_centre(small_lofar_ms)
    ra, dec = lm_to_radec(ra0, dec0, 0.03, -0.02)
    sources = [(ra, dec, 1.0, 0.5, -0.2, 0.1)]
    sky = _write_sky(tmp_path / "s.skymodel", sources)
    run_predict(small_lofar_ms, sky, beam="none", double=True, progress=False)
    model = _col(small_lofar_ms, "MODEL_DATA")
    with _table(small_lofar_ms) as t:
        uvw = t.getcol("UVW")
    l = np.cos(dec) * np.sin(ra - ra0)
    m = np.sin(dec) * np.cos(dec0) - np.cos(dec) * np.sin(dec0) * np.cos(ra - ra0)
    nn = np.sqrt(1 - l * l - m * m)
    corr = np.array([1.0 + 0.5, -0.2 + 0.1j, -0.2 - 0.1j, 1.0 - 0.5])
    for spw, rows in ((0, slice(0, n)), (1, slice(n, 2 * n))):
        freq = _freq(small_lofar_ms) + (10e6 if spw else 0.0)
        phase = np.exp(2j * np.pi * (uvw[rows] @ [l, m, nn - 1])[:, None] * freq / C)
        expect = phase[:, :, None] * corr
        assert np.abs(model[rows] - expect).max() <= 1e-6 * np.abs(expect).max()
    # --spw 1 only writes the rows of window 1
    res = _invoke("predict", small_lofar_ms, "--sky", sky, "--beam", "none", "--spw", "1",
                  "--column", "ONLY1")
    assert res.exit_code == 0, res.output
    only1 = _col(small_lofar_ms, "ONLY1")
    assert np.all(only1[:n] == 0)
    np.testing.assert_allclose(only1[n:], model[n:], atol=1e-5)
