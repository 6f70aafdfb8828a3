"""Several skies in one predict: each column equals a run with its sky alone.

The beam is evaluated once per chunk towards the union of the skies' directions and the
per-station matrices A_p(s) are shared, so every column must equal the column a separate
single-sky run writes: to the last bit when the beam model's value for a direction does
not depend on the other directions of the call (no beam, or the per-direction test beam
here), complex64 and complex128 alike; within the documented 1e-6 of the peak for the
LOFAR beam, whose J2000 -> ITRF map is fitted over the directions of each call. Also:
the union is what the beam sees, fields of view per sky, resume of every column after an
interruption (also columns at different progress, and columns an identical run
completed), undo of a refused run on every column, the command-line pairing errors.
"""

from __future__ import annotations

import hashlib
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from casa_ms import build_ms
from ms_helpers import direct_dft, lm_to_radec, phase_centre, snapshot, table, write_sky
from msleak.cli import cli
from msleak.errors import InputError
from msleak.io import columns as colio
from msleak.verbs import predict_chunks as chunks
from msleak.verbs import predict as engine
from msleak.predict import kernels as K
from msleak.predict.chunks import plan_chunks
from faults import fail_at_time
from test_predict_kernels import _direct
from test_predict_ms import _jones_fn

NTIME = 5
#: 4 KB: one time slot per chunk, so NTIME chunks
SMALL = dict(memory_limit=4096, scheduler="sync")


class _CountingBeam:
    """A per-direction test beam (:func:`test_predict_ms._jones_fn`) that records the
    number of directions of every call."""

    name = "standin"

    def __init__(self):
        self.ndir = []

    def jones(self, time_mjd_s, freq_hz, ra, dec, *, stations=None, centre_correction=False,
              dtype=np.complex128):
        assert not centre_correction  # msleak applies J(s0)^-1 itself
        self.ndir.append(len(ra))
        return _jones_fn(stations, time_mjd_s, freq_hz, ra, dec).astype(dtype)

    def jones_factors(self, *args, **kwargs):
        return None  # not a factored beam


def _radec(ms, offsets_deg):
    """(ra, dec) of points at (dl, dm) degrees from the phase centre (SIN projection)."""
    ra, dec = lm_to_radec(*phase_centre(ms), *np.radians(offsets_deg).T)
    return list(zip(ra.tolist(), dec.tolist()))


def _skies(tmp_path, ms):
    """Sky A (5 sources, 2 of them more than 1.5 deg out) and sky B, which shares two
    of A's directions (other fluxes) and has two of its own; 7 directions in all."""
    pos = _radec(ms, [(0.3, -0.2), (-0.5, 0.4), (0.8, 0.6), (2.5, -1.8), (-2.2, 2.6),
                      (-0.9, -0.7), (1.6, 0.1)])
    rng = np.random.default_rng(5)
    flux = rng.normal(0, 1, (9, 4))
    a = [(*pos[k], *flux[k]) for k in range(5)]
    b = [(*pos[1], *flux[5]), (*pos[3], *flux[6]), (*pos[5], *flux[7]), (*pos[6], *flux[8])]
    return write_sky(tmp_path / "a.skymodel", a), write_sky(tmp_path / "b.skymodel", b), a, b


#: (sky, column, fov): A whole, B whole, A cut to 2 x 2 deg (its 3 inner sources)
def _targets(a, b):
    return [(a, "M_A", None), (b, "M_B", None), (a, "M_A2", 2.0)]


def _col(ms, name):
    with table(ms) as t:
        return t.getcol(name)


def _separate(ms, targets, **kw):
    """Each sky alone into R_<column>."""
    for sky, column, fov in targets:
        engine.predict(ms, sky, column=f"R_{column}", fov=fov, **kw)


def _together(ms, targets, **kw):
    return engine.predict(ms, [t[0] for t in targets], column=[t[1] for t in targets],
                          fov=[t[2] for t in targets], **kw)


def _perturb_uvw(ms, rows):
    """Move the UVW of ``rows`` (baselines without a common antenna) by 10 cm: the fit
    leaves them out and they are predicted per baseline, whatever the sky."""
    with table(ms, readonly=False) as t:
        for r in rows:
            t.putcell("UVW", r, t.getcell("UVW", r) + np.array([0.08, -0.04, 0.045]))


# ------------------------------------------------------------------------ same as alone
@pytest.mark.parametrize("double", [True, False])
@pytest.mark.parametrize("beam", ["none", "standin"])
def test_each_column_equals_its_sky_alone_to_the_last_bit(tmp_path, monkeypatch, double,
                                                          beam):
    ms = build_ms(tmp_path / "obs.ms", ntime=3, autocorrelations=True)
    _perturb_uvw(ms, [1, 10])  # (0, 1), (2, 3): the per-baseline path too
    a, b, _, _ = _skies(tmp_path, ms)
    targets = _targets(a, b)
    model = _CountingBeam()
    if beam == "standin":
        monkeypatch.setattr(chunks, "_load_beam", lambda name, ms_, options=None: model)
    # one chunk (serial: the threaded scheduler would cut the 3 times into two chunks)
    kw = dict(beam="everybeam" if beam == "standin" else "none", double=double,
              scheduler="sync")
    results = _together(ms, targets, **kw)
    calls_together = list(model.ndir)
    _separate(ms, targets, **kw)
    for (_, column, _), res in zip(targets, results):
        assert res.column == column and res.rows_written == _col(ms, "TIME").size
        assert res.rows_per_baseline == 2
        got, alone = _col(ms, column), _col(ms, f"R_{column}")
        assert np.abs(alone).max() > 0.1
        np.testing.assert_array_equal(got, alone)
    assert [r.n_sources["f0_d0"] for r in results] == [5, 4, 3]
    if beam == "standin":  # one beam call per chunk, towards the 7 directions + the centre
        assert calls_together == [8]
        assert model.ndir[1:] == [6, 5, 4]  # the separate runs: 5, 4, 3 directions + centre


@pytest.mark.parametrize("double", [True, False])
def test_cube_crops_in_files_share_its_sum_and_equal_their_runs_alone(tmp_path, monkeypatch,
                                                                      double):
    """The study's way: a 12 x 12 cube and its crops written by ``crop`` to their own
    files, predicted together through the per-direction test beam with the centre
    correction. The 6-pixel crop ends on a block boundary of the cube and is shared, the
    8-pixel one is not; every column equals its separate run bit for bit."""
    from ms_helpers import channel_freqs
    from msleak.adapters.sky_fits import write_cube
    from msleak.sky.cube import SkyCube, crop, make_celestial_wcs

    ms = build_ms(tmp_path / "obs.ms", ntime=3)
    freq = channel_freqs(ms)
    ra0, dec0 = np.degrees(phase_centre(ms))
    rng = np.random.default_rng(9)
    cube = SkyCube(data=rng.normal(0, 1, (2, freq.size, 12, 12)).astype(np.float32),
                   freq=freq, stokes=("Q", "U"),
                   wcs=make_celestial_wcs(12, 12, 0.3, ra0, dec0), units="Jy/pixel")
    files = [write_cube(cube, tmp_path / "sky.fits")]
    files += [write_cube(crop(cube, npix=n), tmp_path / f"sky_{n}.fits") for n in (6, 8)]
    targets = [(f, f"M{k}", None) for k, f in enumerate(files)]
    model = _CountingBeam()
    monkeypatch.setattr(chunks, "_load_beam", lambda name, ms_, options=None: model)
    seen = []
    nesting = K._nesting
    monkeypatch.setattr(K, "_nesting", lambda prepared: seen.append(nesting(prepared))
                        or seen[-1])
    results = _together(ms, targets, beam="everybeam", double=double)
    assert [r.n_sources["f0_d0"] for r in results] == [144, 36, 64]
    assert seen and all(s == ([0, 2], {1: 0}) for s in seen)
    _separate(ms, targets, beam="everybeam", double=double)
    for _, column, _ in targets:
        got, alone = _col(ms, column), _col(ms, f"R_{column}")
        assert np.abs(alone).max() > 0.1
        np.testing.assert_array_equal(got, alone)


def test_fov_per_sky_and_shared_directions_match_direct_sums(tmp_path):
    """No beam, --double: every column = the direct DFT of its sky's sources (the FoV
    keeping |l|, |m| <= 1 deg), to complex64 storage precision."""
    ms = build_ms(tmp_path / "obs.ms", ntime=3)
    a, b, src_a, src_b = _skies(tmp_path, ms)
    _together(ms, _targets(a, b), beam="none", double=True)
    inner = [s for s, (dl, dm) in zip(src_a, [(0.3, -0.2), (-0.5, 0.4), (0.8, 0.6),
                                               (2.5, -1.8), (-2.2, 2.6)])
             if abs(dl) <= 1 and abs(dm) <= 1]
    assert len(inner) == 3
    for column, sources in (("M_A", src_a), ("M_B", src_b), ("M_A2", inner)):
        want = direct_dft(ms, sources)
        got = _col(ms, column)
        assert np.abs(got - want).max() <= 1e-6 * np.abs(want).max(), column


def test_lofar_beam_columns_match_separate_runs_within_1e6(small_lofar_ms, tmp_path):
    """The LOFAR beam fits its J2000 -> ITRF map over the directions of each call: the
    Jones matrices of a direction move by ~1e-8 with the other directions, the columns
    stay within 1e-6 of the peak of separate runs. Three fields of view of one cube."""
    from msleak.adapters.sky_fits import write_cube
    from msleak.sky.cube import SkyCube, make_celestial_wcs
    from ms_helpers import channel_freqs

    freq = channel_freqs(small_lofar_ms)
    rng = np.random.default_rng(3)
    cube = SkyCube(data=rng.normal(0, 1, (2, freq.size, 10, 10)).astype(np.float32),
                   freq=freq, stokes=("Q", "U"),
                   wcs=make_celestial_wcs(10, 10, 0.5, 0.0, 60.0), units="Jy/pixel")
    sky = tmp_path / "cube.fits"
    write_cube(cube, sky)
    targets = [(sky, "M5", None), (sky, "M3", 3.0), (sky, "M2", 2.0)]
    results = _together(small_lofar_ms, targets, beam="everybeam", double=True)
    assert [r.n_sources["f0_d0"] for r in results] == [100, 36, 16]
    _separate(small_lofar_ms, targets, beam="everybeam", double=True)
    for _, column, _ in targets:
        got, alone = _col(small_lofar_ms, column), _col(small_lofar_ms, f"R_{column}")
        assert np.abs(got - alone).max() <= 1e-6 * np.abs(alone).max(), column


# ------------------------------------------------------------------------- kernel level
@pytest.mark.parametrize("dtype", [np.complex64, np.complex128])
def test_predict_grams_equals_one_sky_at_a_time_and_the_direct_sum(dtype):
    rng = np.random.default_rng(11)
    nst, nt, nch, nd = 4, 2, 3, 7
    xyz = rng.normal(0, 400, (nt, nst, 3))
    lmn1 = K.lmn_minus_one(1.0 + rng.uniform(-0.08, 0.08, nd), 0.8 + rng.uniform(-0.08, 0.08, nd),
                           1.0, 0.8)
    freq = 150e6 + 195312.5 * np.arange(nch)
    shape = (nst, nt, nch, nd, 2, 2)
    jones = rng.normal(size=shape) + 1j * rng.normal(size=shape)
    index = [np.array([5, 0, 3]), np.arange(nd), np.array([6, 2]), np.array([], dtype=int)]
    iquv = [rng.normal(size=(i.size, nch, 4)) for i in index]
    factors = [K.brightness_factors(x) for x in iquv]
    grams = K.predict_grams(jones.astype(dtype), xyz, lmn1, freq,
                            [(i, w, s) for i, (w, s) in zip(index, factors)], dtype=dtype)
    assert grams.shape == (4, nt, nch, 2 * nst, 2 * nst)
    for k, (i, (w, s)) in enumerate(zip(index, factors)):
        alone = K.predict_gram(jones[..., i, :, :].astype(dtype), xyz, lmn1[i], freq, w, s,
                               dtype=dtype)
        np.testing.assert_array_equal(grams[k], alone)
        want = _direct(jones[..., i, :, :], None, xyz, lmn1[i], freq, iquv[k])
        scale = max(np.abs(want).max(), 1.0)
        rtol = 1e-10 if dtype == np.complex128 else 2e-5
        assert np.abs(K.gram_to_matrix(grams[k]) - want).max() <= rtol * scale


def _grid_lmn1(npix, pixel_rad):
    """(l, m, n - 1) of a centred npix x npix grid (a SIN cube about the phase centre)."""
    x = (np.arange(npix) - (npix - 1) / 2) * pixel_rad
    l, m = (a.ravel() for a in np.meshgrid(x, x))
    return np.stack([l, m, -(l * l + m * m) / (1 + np.sqrt(1 - l * l - m * m))], axis=1)


def _crop_rows(npix, keep):
    """Rows of the centred keep x keep crop of an npix x npix grid, in raster order."""
    cut = (npix - keep) // 2
    return np.arange(npix * npix).reshape(npix, npix)[cut:cut + keep, cut:cut + keep].ravel()


def test_sky_blocks_square_rings_from_the_centre():
    """A 12 x 12 grid: rings of 4, 12, 20, 28, 36, 44 pixels (Chebyshev radius in
    half pixels 1, 3, .. 11); blocks of at least BLOCK_MIN = 32: (4 + 12 + 20),
    (28 + 36), 44. A centred crop's order is the grid's order restricted to it."""
    lmn1 = _grid_lmn1(12, np.radians(0.3))
    order, ends = K.sky_blocks(lmn1)
    rho = np.max(np.abs(lmn1[order, :2]), axis=1) / np.radians(0.15)
    np.testing.assert_allclose(np.diff(np.unique(np.round(rho))), 2)
    assert np.all(np.diff(np.round(rho)) >= 0)
    assert K.BLOCK_MIN == 32 and ends.tolist() == [36, 100, 144]
    for keep in (2, 6, 8, 10):
        rows = _crop_rows(12, keep)
        sub_order, sub_ends = K.sky_blocks(lmn1[rows])
        np.testing.assert_array_equal(rows[sub_order], order[:keep * keep])
        # the same blocks, the last one cut at the crop's edge
        assert sub_ends.tolist() == [e for e in (36, 100) if e < keep * keep] + [keep * keep]
    assert K.sky_blocks(np.zeros((0, 3)))[1].size == 0


@pytest.mark.parametrize("dtype", [np.complex64, np.complex128])
def test_crops_share_the_sum_of_their_cube_and_equal_it_alone(dtype, monkeypatch):
    """Crops of a 12 x 12 cube that end on a block boundary of it (6 and 10 pixels) are
    copies of the cube's sum after that block; the 8-pixel crop does not end on one and
    is computed itself. Every sky, shared or not, equals its run alone bit for bit, and
    the direct sum to rounding; another realisation on the same grid is computed itself."""
    rng = np.random.default_rng(4)
    nst, nt, nch, npix = 5, 2, 3, 12
    lmn1 = _grid_lmn1(npix, np.radians(0.3))
    xyz = rng.normal(0, 400, (nt, nst, 3))
    freq = 150e6 + 195312.5 * np.arange(nch)
    shape = (nst, nt, nch, npix * npix, 2, 2)
    jones = (rng.normal(size=shape) + 1j * rng.normal(size=shape)).astype(dtype)
    seeds = [np.zeros((npix * npix, nch, 4)) for _ in range(2)]
    for iquv in seeds:
        iquv[..., 1:3] = rng.normal(size=(npix * npix, nch, 2))
    index = [np.arange(npix * npix), _crop_rows(npix, 6), _crop_rows(npix, 10),
             _crop_rows(npix, 8), np.arange(npix * npix)]
    iquv = [seeds[0][i] for i in index[:4]] + [seeds[1]]
    factors = [K.brightness_factors(x) for x in iquv]
    seen = []
    nesting = K._nesting
    monkeypatch.setattr(K, "_nesting", lambda prepared: seen.append(nesting(prepared))
                        or seen[-1])
    grams = K.predict_grams(jones, xyz, lmn1, freq,
                            [(i, w, s) for i, (w, s) in zip(index, factors)], dtype=dtype)
    assert seen == [([0, 3, 4], {2: 0, 1: 0})]
    for k, (i, (w, s)) in enumerate(zip(index, factors)):
        alone = K.predict_gram(jones[..., i, :, :], xyz, lmn1[i], freq, w, s, dtype=dtype)
        np.testing.assert_array_equal(grams[k], alone)
        want = _direct(jones[..., i, :, :].astype(np.complex128), None, xyz, lmn1[i], freq,
                       iquv[k])
        rtol = 1e-10 if dtype == np.complex128 else 2e-5
        assert np.abs(K.gram_to_matrix(grams[k]) - want).max() <= rtol * np.abs(want).max()


def test_plan_chunks_counts_one_output_per_sky():
    """Per (time, channel): per sky the 96 x 96 matrices and the rows; the beam once
    towards the 2500 + 1 directions."""
    per_sky = 96**2 * 8 + 1176 * 4 * 24
    beam = 48 * 2501 * 4 * 40
    for nsky in (1, 3, 15):
        nt, nc = plan_chunks(390, 50, 48, 2500, 1176, 2 * 1024**3, 8, True, nsky=nsky)
        assert nc == 50 and nt * nc * (nsky * per_sky + beam) <= 2 * 1024**3
        assert (nt + 1) * nc * (nsky * per_sky + beam) > 2 * 1024**3


# ------------------------------------------------------------------ interrupt and resume
def _reference(tmp_path, ms, targets):
    ref = tmp_path / "ref.ms"
    shutil.copytree(ms, ref)
    _together(ref, targets, beam="none", **SMALL)
    return ref


def _states(ms, columns):
    with table(ms) as t:
        return {c: t.getcolkeyword(c, colio.RUN_KEYWORD) for c in columns}


def _times(ms):
    return np.unique(_col(ms, "TIME"))


def test_interrupted_run_resumes_every_column(tmp_path, monkeypatch):
    ms = build_ms(tmp_path / "obs.ms", ntime=NTIME)
    a, b, _, _ = _skies(tmp_path, ms)
    targets = _targets(a, b)
    columns = [t[1] for t in targets]
    ref = _reference(tmp_path, ms, targets)
    nrow = _col(ms, "TIME").size
    with monkeypatch.context() as m:
        fail_at_time(m, _times(ms)[2], KeyboardInterrupt())  # chunks 0 and 1 are written
        with pytest.raises(KeyboardInterrupt):
            _together(ms, targets, beam="none", **SMALL)
    for column, state in _states(ms, columns).items():
        assert not state["complete"] and state["rows_done"] == 2 * nrow // NTIME, column
        assert state["progress"]["f0_d0"] == _times(ms)[1]
    with table(ms) as t:  # a copy of every written column's header, for a killed run
        headers = {f"table.f{t.getdminfo(c)['SEQNR']}" for c in columns}
    assert len(headers) == 3
    assert headers <= {p.name for p in (ms / colio.BACKUP_DIR).iterdir()}
    results = _together(ms, targets, beam="none", **SMALL)
    assert all(r.resumed and r.rows_written == 3 * nrow // NTIME for r in results)
    for column, state in _states(ms, columns).items():
        assert state["complete"] and state["rows_done"] == nrow
        np.testing.assert_array_equal(_col(ms, column), _col(ref, column))
    assert not (ms / colio.BACKUP_DIR).exists()


def test_columns_at_different_progress_and_completed_columns(tmp_path, monkeypatch):
    """A+B interrupted after 1 slot; A alone interrupted after 4: the rerun of A+B writes
    only the rows each column lacks. Then A+B interrupted again, A finished alone: the
    rerun leaves A as it is and finishes B. Both equal the uninterrupted run."""
    ms = build_ms(tmp_path / "obs.ms", ntime=NTIME)
    a, b, _, _ = _skies(tmp_path, ms)
    targets = _targets(a, b)[:2]
    ref = _reference(tmp_path, ms, targets)
    times, nrow = _times(ms), _col(ms, "TIME").size
    for when, run in ((times[1], lambda: _together(ms, targets, beam="none", **SMALL)),
                      (times[4], lambda: engine.predict(ms, a, column="M_A", beam="none",
                                                        **SMALL))):
        with monkeypatch.context() as m:
            fail_at_time(m, when, KeyboardInterrupt())
            with pytest.raises(KeyboardInterrupt):
                run()
    states = _states(ms, ["M_A", "M_B"])
    assert [states[c]["rows_done"] for c in ("M_A", "M_B")] == [4 * nrow // NTIME, nrow // NTIME]
    res_a, res_b = _together(ms, targets, beam="none", **SMALL)
    assert res_a.resumed and res_a.rows_written == nrow // NTIME
    assert res_b.resumed and res_b.rows_written == 4 * nrow // NTIME
    for column in ("M_A", "M_B"):
        np.testing.assert_array_equal(_col(ms, column), _col(ref, column))

    with monkeypatch.context() as m:
        fail_at_time(m, times[3], KeyboardInterrupt())
        with pytest.raises(KeyboardInterrupt):
            _together(ms, targets, beam="none", **SMALL)
    assert engine.predict(ms, a, column="M_A", beam="none", **SMALL).resumed
    finished = _states(ms, ["M_A"])["M_A"]["finished"]
    res_a, res_b = _together(ms, targets, beam="none", **SMALL)
    assert res_a.skipped and res_a.rows_written == 0 and not res_a.resumed
    assert res_b.resumed and res_b.rows_written == 2 * nrow // NTIME
    states = _states(ms, ["M_A", "M_B"])
    assert states["M_A"]["finished"] == finished and states["M_B"]["complete"]
    for column in ("M_A", "M_B"):
        np.testing.assert_array_equal(_col(ms, column), _col(ref, column))
    # nothing incomplete: an identical rerun recomputes every column, as with one sky
    again = _together(ms, targets, beam="none", **SMALL)
    assert all(not r.skipped and not r.resumed and r.rows_written == nrow for r in again)


# ------------------------------------------------------------------------------ refusals
@pytest.mark.parametrize("existing", [(), ("M_A",), ("M_B",)])
def test_refusal_in_a_multisky_run_leaves_the_ms_byte_identical(tmp_path, monkeypatch,
                                                                 existing):
    """Refused at the last chunk (every earlier chunk written into every column): the
    columns the run created are gone, the existing ones hold their old values, every file
    has its old bytes."""
    ms = build_ms(tmp_path / "obs.ms", ntime=NTIME)
    a, b, _, _ = _skies(tmp_path, ms)
    targets = _targets(a, b)
    for column in existing:  # an older prediction of another sky
        engine.predict(ms, b if column == "M_A" else a, column=column, beam="none")
    before = snapshot(ms)
    seen = fail_at_time(monkeypatch, _times(ms)[-1], InputError("refused in the test"), [ms])
    with pytest.raises(InputError, match="refused in the test"):
        _together(ms, targets, beam="none", **SMALL)
    assert len(seen) == NTIME and seen[-1] == [True]
    assert snapshot(ms) == before


def test_new_columns_that_do_not_fit_together_are_refused_before_writing(tmp_path,
                                                                          monkeypatch):
    import shutil as sh

    ms = build_ms(tmp_path / "obs.ms", ntime=NTIME)
    a, b, _, _ = _skies(tmp_path, ms)
    with table(ms) as t:
        one = t.nrows() * 8 * int(np.prod(t.getcell("DATA", 0).shape)) + 1.1 * 2**20
    usage = sh.disk_usage(ms)
    monkeypatch.setattr(sh, "disk_usage",
                        lambda path: usage._replace(free=int(1.5 * one)))
    before = snapshot(ms)
    with pytest.raises(InputError, match="not enough disk space for columns M_A, M_B"):
        _together(ms, _targets(a, b)[:2], beam="none")
    assert snapshot(ms) == before
    monkeypatch.undo()
    _together(ms, _targets(a, b)[:2], beam="none")


# ------------------------------------------------------------------------ command line
def _invoke(*args):
    return CliRunner().invoke(cli, ["predict", *[str(x) for x in args]])


@pytest.mark.parametrize("case,message", [
    (("--sky", "A", "--sky", "B", "--column", "M_A"),
     "2 --sky and 1 --column given; give one --column per --sky"),
    (("--sky", "A", "--sky", "B"), "2 --sky and 0 --column given; give one --column per --sky"),
    (("--sky", "A", "--column", "M_A", "--sky", "B", "--column", "M_B", "--sky", "A",
      "--column", "M_C", "--fov", "2", "--fov", "1"),
     "--fov is given 2 times for 3 --sky; give it once (for every sky) or once per --sky"),
    (("--sky", "A", "--column", "M_A", "--sky", "B", "--column", "M_A"),
     "--column M_A is given 2 times; give every --sky its own --column"),
    (("--sky", "A", "--column", "M_A", "--sky", "B", "--column", "DATA"),
     "refusing to overwrite the DATA column; pass --overwrite-data"),
])
def test_cli_pairing_errors_exit_2_with_one_line(tmp_path, case, message):
    ms = build_ms(tmp_path / "obs.ms", ntime=2)
    a, b, _, _ = _skies(tmp_path, ms)
    before = snapshot(ms)
    args = [{"A": a, "B": b}.get(x, x) for x in case]
    r = _invoke(ms, *args, "--beam", "none")
    assert r.exit_code == 2, r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("msleak: error: "), r.output
    assert message in lines[0], r.output
    assert snapshot(ms) == before


def test_cli_two_skies_one_fov_provenance_per_column(tmp_path):
    ms = build_ms(tmp_path / "obs.ms", ntime=2)
    a, b, _, _ = _skies(tmp_path, ms)
    r = _invoke(ms, "--sky", a, "--column", "M_A", "--sky", b, "--column", "M_B", "--fov", "4",
                "--beam", "none")
    assert r.exit_code == 0, r.output
    nrow = _col(ms, "TIME").size
    assert f"wrote {nrow} rows into M_A" in r.output and f"wrote {nrow} rows into M_B" in r.output
    for column, sky in (("M_A", a), ("M_B", b)):
        state = _states(ms, [column])[column]
        assert state["complete"] and state["rows_done"] == nrow
        assert state["sky"] == str(sky.resolve()) and state["fov_deg"] == 4.0
        assert state["sky_sha256"] == hashlib.sha256(sky.read_bytes()).hexdigest()
