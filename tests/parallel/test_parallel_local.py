"""Parallel execution on one machine (threads, processes) and several Measurement Sets.

Reference answers: the serial path (``scheduler="sync"``) on the same inputs, and one MS
holding the channels of two half-band MSs (each computed independently here).
"""

from __future__ import annotations

import logging
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from msleak.cli import cli
from msleak.conventions import stokes_to_correlations
from msleak.errors import InputError

WIDTH = 195312.5
C = 299_792_458.0
# (l, m, I, Q, U) of three point sources (rad, Jy)
SOURCES = [(0.0, 0.0, 1.0, 0.2, -0.1), (0.012, -0.02, 0.5, 0.3, 0.25),
           (-0.025, 0.01, 0.3, -0.2, 0.1)]


def fill_data(ms, column="DATA"):
    """DATA = visibilities of SOURCES in the MS convention, exp(+2 pi i UVW.(l,m,n-1)/lambda)."""
    import casacore.tables as pt

    with pt.table(str(ms / "SPECTRAL_WINDOW"), ack=False) as t:
        freq = t.getcell("CHAN_FREQ", 0)
    with pt.table(str(ms), readonly=False, ack=False) as t:
        uvw = t.getcol("UVW")
        data = np.zeros((uvw.shape[0], freq.size, 4), np.complex128)
        for l, m, i, q, u in SOURCES:
            nm1 = np.sqrt(1 - l * l - m * m) - 1
            ph = np.exp(2j * np.pi * (uvw @ [l, m, nm1])[:, None] * freq[None, :] / C)
            data += ph[..., None] * stokes_to_correlations(np.array([i, q, u, 0.0]))
        t.putcol(column, data.astype(np.complex64))


SKY = ("format = Name, Type, Ra, Dec, I, Q, U, V, ReferenceFrequency='150e6', "
       "SpectralIndex='[]'\n"
       "a, POINT, 08:13:36.0, +48.13.03, 0.0, 1.0, 0.5, 0.0\n"
       "b, POINT, 08:20:00.0, +49.00.00, 0.0, -0.3, 0.7, 0.0\n"
       "c, POINT, 08:05:00.0, +47.30.00, 0.5, 0.2, -0.4, 0.0\n")


@pytest.fixture
def sky(tmp_path):
    path = tmp_path / "sky.skymodel"
    path.write_text(SKY)
    return path


def _column(ms, name="MODEL_DATA"):
    import casacore.tables as pt

    with pt.table(str(ms), ack=False) as t:
        return t.getcol(name), dict(t.getcolkeyword(name, "MSLEAK_PREDICT"))


@pytest.mark.parametrize("scheduler", ["threads", "processes"])
def test_predict_local_schedulers_match_serial(small_lofar_ms, sky, tmp_path, scheduler):
    from msleak.verbs import predict as engine

    other = tmp_path / "other.ms"
    shutil.copytree(small_lofar_ms, other)
    # a small memory limit gives several time chunks (1 or 2 slots each)
    engine.predict(small_lofar_ms, sky, scheduler="sync", memory_limit=150_000, progress=False)
    res = engine.predict(other, sky, scheduler=scheduler, workers=2, memory_limit=150_000,
                         progress=False)
    ref, _ = _column(small_lofar_ms)
    got, state = _column(other)
    assert res.rows_written == ref.shape[0] and state["complete"]
    assert state["rows_done"] == ref.shape[0]
    # chunks are independent: equal up to complex64 rounding (docs/parallel.md)
    np.testing.assert_allclose(got, ref, rtol=0, atol=2e-7 * np.abs(ref).max())
    assert np.abs(ref).max() > 0.1


def test_predict_several_ms_matches_one_by_one(make_ms, sky):
    from msleak.verbs import predict as engine

    lo = make_ms("lo.ms", nchan=3)
    hi = make_ms("hi.ms", nchan=3, freq_min=150e6 + 3 * WIDTH)
    lo_ref = make_ms("lo_ref.ms", nchan=3)
    hi_ref = make_ms("hi_ref.ms", nchan=3, freq_min=150e6 + 3 * WIDTH)
    results = engine.predict([lo, hi], sky, scheduler="threads", workers=2,
                             memory_limit=150_000, progress=False)
    assert [r.ms for r in results] == [lo, hi]
    for ms, ref_ms in ((lo, lo_ref), (hi, hi_ref)):
        engine.predict(ref_ms, sky, scheduler="sync", progress=False)
        got, state = _column(ms)
        ref, _ = _column(ref_ms)
        assert state["complete"] and state["rows_done"] == got.shape[0]
        np.testing.assert_allclose(got, ref, rtol=0, atol=2e-7 * np.abs(ref).max())


def test_predict_several_ms_interrupted_resumes(make_ms, sky, monkeypatch):
    """A failure in the second MS leaves the first complete, the second incomplete;
    rerunning finishes the second without touching the first."""
    from faults import fail_after_chunks
    from msleak.verbs import predict as engine

    a = make_ms("a.ms")
    b = make_ms("b.ms", freq_min=150e6 + 4 * WIDTH)
    ref = make_ms("ref.ms", freq_min=150e6 + 4 * WIDTH)
    engine.predict(ref, sky, scheduler="sync", progress=False)
    import casacore.tables as pt

    with pt.table(str(a), ack=False) as t:
        n_a = t.nrows()
    with monkeypatch.context() as m, pytest.raises(RuntimeError, match="simulated"):
        fail_after_chunks(m, 6)
        # chunks of one slot: 4 in a, then fail after the second of b (sync, so the failure
        # point does not depend on which thread finishes first on a loaded machine)
        # (sync gets the whole budget for one task: half of it gives the one-slot chunks
        # that threads with two workers make)
        engine.predict([a, b], sky, scheduler="sync", workers=1, memory_limit=30_000,
                       progress=False)
    got_a, state_a = _column(a)
    got_b, state_b = _column(b)
    assert state_a["complete"] and state_a["rows_done"] == n_a
    assert not state_b["complete"] and 0 < state_b["rows_done"] < got_b.shape[0]
    results = engine.predict([a, b], sky, scheduler="threads", workers=2,
                             memory_limit=60_000, progress=False)
    assert not results[0].resumed and results[0].rows_written == n_a  # complete: redone
    assert results[1].resumed and results[1].rows_written == got_b.shape[0] - state_b["rows_done"]
    got_b, state_b = _column(b)
    assert state_b["complete"]
    np.testing.assert_allclose(got_b, _column(ref)[0], rtol=0, atol=2e-7)


def _grid(ms, **kw):
    import msleak

    kw.setdefault("chunk_rows", 20)
    return msleak.grid(ms, uv_range=(20.0, 200.0), **kw)


def _ps(cube):
    from msleak.verbs.power import power_spectrum
    from msleak.verbs.transform import transform

    return power_spectrum(transform(cube, partial="zero"))


@pytest.mark.parametrize("scheduler", ["threads", "processes"])
def test_grid_local_schedulers_match_serial(small_lofar_ms, scheduler):
    fill_data(small_lofar_ms)
    ref = _grid(small_lofar_ms, scheduler="sync", split="even-odd")
    got = _grid(small_lofar_ms, scheduler=scheduler, workers=2, split="even-odd")
    for name in ("vis", "weight", "vis_a", "vis_b"):
        np.testing.assert_allclose(got[name].values, ref[name].values, rtol=1e-12,
                                   atol=1e-12 * np.abs(ref[name].values).max())
    np.testing.assert_allclose(_ps(got)["power"].values, _ps(ref)["power"].values, rtol=1e-10,
                               atol=1e-10 * np.nanmax(np.abs(_ps(ref)["power"].values)))


def test_two_subband_ms_equal_one_ms(make_ms):
    """Two MSs split in frequency give the cube and PS of one MS with both halves."""
    full = make_ms("full.ms", nchan=8)
    lo = make_ms("lo.ms", nchan=4)
    hi = make_ms("hi.ms", nchan=4, freq_min=150e6 + 4 * WIDTH)
    for ms in (full, lo, hi):
        fill_data(ms)
    ref = _grid(full, scheduler="sync")
    got = _grid([hi, lo], scheduler="threads", workers=2)  # any order
    np.testing.assert_allclose(got["freq"].values, ref["freq"].values, rtol=1e-15)
    for name in ("vis", "weight"):
        np.testing.assert_allclose(got[name].values, ref[name].values, rtol=1e-12,
                                   atol=1e-12 * np.abs(ref[name].values).max())
    assert got.attrs["n_inputs"] == 2 and got.attrs["n_gap_channels"] == 0
    p_ref, p_got = _ps(ref)["power"].values, _ps(got)["power"].values
    np.testing.assert_allclose(p_got, p_ref, rtol=1e-10, atol=1e-10 * np.nanmax(np.abs(p_ref)))
    assert np.nanmax(p_ref) > 0


def test_gap_is_reported_and_left_empty(make_ms, caplog):
    lo = make_ms("lo.ms", nchan=3)
    hi = make_ms("hi.ms", nchan=3, freq_min=150e6 + 5 * WIDTH)  # channels 3, 4 missing
    for ms in (lo, hi):
        fill_data(ms)
    with caplog.at_level(logging.WARNING, logger="msleak.parallel.multims"):
        cube = _grid([lo, hi], scheduler="sync")
    assert "2 channel(s) missing" in caplog.text
    assert cube.attrs["n_gap_channels"] == 2
    assert "150.586-150.781 MHz" in cube.attrs["freq_gaps"]
    np.testing.assert_allclose(cube["freq"].values, 150e6 + WIDTH * np.arange(8), rtol=1e-15)
    weight = cube["weight"].values
    assert not weight[3:5].any() and weight[[0, 1, 2, 5, 6, 7]].reshape(6, -1).any(axis=1).all()
    from msleak.verbs.transform import transform

    delay = transform(cube, partial="zero")
    assert delay.attrs["flagged_channels"] == 2
    assert np.isfinite(_ps(cube)["power"].values).any()


@pytest.mark.parametrize("second, message", [
    (dict(nchan=4, freq_min=150e6 + 2 * WIDTH), "overlaps"),
    (dict(nchan=4, freq_min=150e6 + 4 * WIDTH, chan_width=2 * WIDTH), "channel spacing"),
    (dict(nchan=4, freq_min=150e6 + 4.5 * WIDTH), "off the grid"),
])
def test_multi_ms_errors(make_ms, second, message):
    a = make_ms("a.ms", nchan=4)
    b = make_ms("b.ms", **second)
    with pytest.raises(InputError, match=message):
        _grid([a, b], scheduler="sync")
    result = CliRunner().invoke(cli, ["grid", str(a), str(b), "--column", "DATA", "-o",
                                      str(a.parent / "g.h5"), "--scheduler", "sync"])
    assert result.exit_code == 2, result.output
    assert message in result.output and len(result.output.strip().splitlines()) == 1


def test_cli_grid_two_ms_and_predict_two_ms(make_ms, sky, tmp_path):
    lo = make_ms("lo.ms", nchan=2)
    hi = make_ms("hi.ms", nchan=2, freq_min=150e6 + 2 * WIDTH)
    run = CliRunner().invoke(cli, ["-q", "predict", str(lo), str(hi), "--sky", str(sky),
                                   "--beam", "none", "--workers", "2"])
    assert run.exit_code == 0, run.output
    assert _column(lo)[1]["complete"] and _column(hi)[1]["complete"]
    out = tmp_path / "grid.h5"
    run = CliRunner().invoke(cli, ["-q", "grid", str(lo), str(hi), "--column", "MODEL_DATA",
                                   "--uv-range", "20,200", "-o", str(out),
                                   "--scheduler", "threads", "--memory-limit", "64MB"])
    assert run.exit_code == 0, run.output
    import xarray as xr

    with xr.open_dataset(out, engine="h5netcdf") as ds:
        assert ds.sizes["freq"] == 4 and ds.attrs["n_inputs"] == 2
        assert str(lo) in ds.attrs["source"] and str(hi) in ds.attrs["source"]


@pytest.mark.parametrize("args, message", [
    (["--scheduler", "mpi"], "use threads, processes, sync"),
    (["--workers", "0"], "--workers"),
    (["--scheduler", "tcp://127.0.0.1:9"], "cannot reach the dask scheduler"),
])
def test_cli_parallel_option_errors(small_lofar_ms, sky, args, message):
    import dask

    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        run = CliRunner().invoke(cli, ["predict", str(small_lofar_ms), "--sky", str(sky),
                                       "--beam", "none", *args])
    assert run.exit_code == 2, run.output
    assert message in run.output
    assert "Traceback" not in run.output


def test_predict_twice_same_ms_is_an_error(small_lofar_ms, sky):
    from msleak.verbs import predict as engine

    with pytest.raises(InputError, match="given twice"):
        engine.predict([small_lofar_ms, small_lofar_ms], sky, beam="none")


def test_memory_budget_is_shared_and_bounds_chunks():
    from msleak.parallel import open_runner
    from msleak.ps.gridding import make_grid
    from msleak.ps.chunks import Spec, rows_for_memory, working_set

    with open_runner("threads", 4, 8e8) as runner:
        assert runner.workers == 4 and runner.memory_per_task == pytest.approx(2e8)
    with open_runner("sync", None, 8e8) as runner:
        assert runner.workers == 1 and runner.memory_per_task == pytest.approx(8e8)
    spec = Spec(("DATA",), "wgrid", make_grid(16.0, 180.0), 30.0, 180.0, 1e-6, 1, None, None)
    nchan = 50
    # the most rows whose working set (what tasks and this process hold, checked against
    # traced allocations in tests/ps/test_grid_memory.py) fits; four tasks share the budget
    for budget in (2e8, 8e8):
        rows = rows_for_memory(budget, nchan, spec, 4)
        assert working_set(rows, nchan, spec, 4) <= budget < working_set(rows + 1, nchan,
                                                                          spec, 4)
        assert 2 * rows < rows_for_memory(budget, nchan, spec, 1)


def test_tasks_fewer_than_workers_share_the_idle_threads(monkeypatch):
    """A batch smaller than ``workers`` (one chunk, the last chunks) gives each task the
    cores the missing tasks would have had; a full batch keeps cores / workers each."""
    from msleak.parallel import open_runner
    from msleak.parallel import runner as runner_module
    from msleak.parallel.runner import task_threads

    def seen(job, shared):
        return task_threads()

    with open_runner("threads", 2, 8e8) as runner, monkeypatch.context() as m:
        m.setattr(runner_module, "cpu_count", lambda: 6)
        runner.task_threads = 3          # as on a 6-core machine: 3 threads per task
        assert [t for _, t in runner.map(seen, [0])] == [6]
        assert [t for _, t in runner.map(seen, [0, 1])] == [3, 3]
        assert [t for _, t in runner.map(seen, [0, 1, 2])] == [3, 3, 6]
