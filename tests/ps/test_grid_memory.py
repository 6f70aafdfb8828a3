"""Memory planning of ``msleak grid``: what the accumulators, a chunk task and a whole run
allocate (numpy arrays, traced with tracemalloc) on a small real-writer MS, against the
model ``msleak.ps.chunks.working_set`` that sizes the chunks from ``--memory-limit``.

Known answers, counted here from the array shapes: an accumulator holds its cells
(complex128 per Stokes parameter, and per unit-visibility image for ``wgrid``), float64
natural weights and the float64 taper of the ``wgrid`` box; a chunk task holds at least
its float64 weights and the correlations of every column (4 x 8 bytes a sample, 4 x 16 for
a double-precision column). The model must lie between what is traced and twice that, and
a run with a memory limit must stay within it while one without would not.
"""

from __future__ import annotations

import logging
import tracemalloc

import numpy as np
import pytest

from casa_ms import build_ms
from msleak.ps.chunks import Spec, plan_chunks, rows_for_memory, working_set
from msleak.ps.gridding import BOX_FACTOR, accumulator_bytes, make_accumulator, make_grid
from msleak.verbs import grid_tasks
from msleak.verbs.grid_tasks import Job, check_input, run_tasks

COLUMNS = ("DATA", "MODEL_A", "MODEL_B")
NCHAN = 16
#: 28 antennas within 60 m: baselines up to ~150 m, 75 wavelengths at 150 MHz
ENU = np.random.default_rng(3).uniform(-60.0, 60.0, (28, 3)) * [1.0, 1.0, 0.0]
UV = (1.0, 100.0)  # every cross-correlation row has weight: the model's worst case


@pytest.fixture(scope="module")
def ms(tmp_path_factory):
    """378 baselines x 16 times x 16 channels, random visibilities in three complex64
    columns and DOUBLE_A, a complex128 column holding MODEL_A."""
    import casacore.tables as pt

    path = build_ms(tmp_path_factory.mktemp("mem") / "mem.ms", enu=ENU, ntime=16,
                    nchan=NCHAN, extra_columns=COLUMNS)
    rng = np.random.default_rng(11)
    with pt.table(str(path), readonly=False, ack=False) as t:
        shape = (t.nrows(), NCHAN, 4)
        for name in COLUMNS:
            t.putcol(name, (rng.normal(size=shape) + 1j * rng.normal(size=shape))
                     .astype(np.complex64))
        t.putcol("FLAG", rng.random(shape) < 0.02)
        t.addcols(pt.maketabdesc(pt.makearrcoldesc("DOUBLE_A", 0j, valuetype="dcomplex",
                                                   ndim=2, shape=[NCHAN, 4], options=4)))
        t.putcol("DOUBLE_A", t.getcol("MODEL_A").astype(np.complex128))
    return path


def _spec(columns, gridder="wgrid", split=None, chunk_rows=0, corr_bytes=8, inp=None):
    split_times = None
    if split:
        import casacore.tables as pt

        with pt.table(inp.ms, ack=False) as t:
            split_times = np.unique(t.getcol("TIME"))
    return Spec(tuple(columns), gridder, make_grid(16.0, UV[1]), UV[0], UV[1], 1e-6, 1, split,
                split_times, chunk_rows=chunk_rows, corr_bytes=corr_bytes)


@pytest.mark.parametrize("gridder", ["wgrid", "cell"])
def test_accumulator_holds_what_accumulator_bytes_counts(gridder):
    """The arrays an accumulator keeps once it has gridded (its buffer is empty then)."""
    grid = make_grid(16.0, 100.0)
    freq = 150e6 + 195312.5 * np.arange(NCHAN)
    for nsets in (1, 3):
        g, n = grid.size, BOX_FACTOR * grid.npix_image
        planes = 5 if gridder == "wgrid" else 4
        count = nsets * NCHAN * g * g * (planes * 16 + 8) + (8 * n * n if gridder == "wgrid"
                                                             else 0)
        assert accumulator_bytes(gridder, grid, NCHAN, nsets) == count
        acc = make_accumulator(gridder, grid, freq, nsets=nsets)
        uvw = np.array([[40.0, -25.0, 1.0]])
        vis, wgt = np.ones((nsets, 4, 1, NCHAN), complex), np.ones((1, NCHAN))
        if gridder == "wgrid":
            acc.add(uvw, vis, wgt)
            acc.grid_buffer()
        else:
            scale = freq / 299_792_458.0
            acc.add(uvw[:, :1] * scale, uvw[:, 1:2] * scale, vis, wgt)
        held = sum(value.nbytes for obj in (acc, getattr(acc, "natural", None))
                   for value in vars(obj or object).values()
                   if isinstance(value, np.ndarray))
        assert count <= held <= count + 1024, (nsets, held, count)


@pytest.mark.parametrize("gridder, columns, split", [
    ("wgrid", COLUMNS[:1], None), ("wgrid", COLUMNS, None), ("wgrid", COLUMNS, "even-odd"),
    ("cell", COLUMNS, None), ("wgrid", ("DOUBLE_A", "MODEL_B"), None)])
def test_chunk_task_within_model(ms, gridder, columns, split):
    """One task gridding all rows (several conversion blocks): what it allocates at its
    peak lies between the weights and correlations it must hold and the model's share of a
    task, and the model is less than twice the peak."""
    inp = check_input(ms, columns, 0, 0)
    corr_bytes = inp.vis_dtype.itemsize
    assert corr_bytes == (16 if "DOUBLE_A" in columns else 8)
    rows = inp.rows.size
    spec = _spec(columns, gridder, split, chunk_rows=rows, corr_bytes=corr_bytes, inp=inp)
    samples = rows * NCHAN
    assert samples > grid_tasks.BLOCK_SAMPLES
    tracemalloc.start()
    accs, stats = grid_tasks._grid_task(Job(0, 0, inp, inp.rows), spec)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert stats["in_range"] > 0.9 * stats["samples"]  # nearly every sample is held
    must_hold = samples * (8 + len(columns) * 4 * corr_bytes)
    model = working_set(rows, NCHAN, spec, 2) - working_set(rows, NCHAN, spec, 1)
    assert must_hold < peak <= model < 2 * peak, (peak, model, must_hold)


def test_double_precision_column_grids_like_its_complex64_copy(ms):
    """DOUBLE_A holds MODEL_A's complex64 values in complex128: the same cube, bit for bit."""
    import msleak

    a, d = msleak.grid(ms, column=["MODEL_A", "DOUBLE_A"], uv_range=UV, chunk_rows=2000,
                       scheduler="sync", beam_area_model="airy")
    assert np.array_equal(a["vis"].values, d["vis"].values)
    assert np.array_equal(a["weight"].values, d["weight"].values)


def _traced_peak(inp, spec, limit):
    """Peak traced bytes of gridding every chunk, two at a time, with ``limit`` (None: no
    limit)."""
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        run_tasks([inp], spec, None, "threads", 2, limit, False)
        return tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()


def test_run_stays_within_memory_limit(ms, monkeypatch):
    """Limits that allow two chunks of 1000 rows, or one of 1200, at a time: the traced
    peak of the run (after a first run has imported and cached what it needs) stays within
    each, in as many chunks as planned; one chunk of every row, without a limit, would
    exceed the second."""
    inp = check_input(ms, COLUMNS, 0, 0)
    spec = _spec(COLUMNS, inp=inp)
    run_tasks([check_input(ms, COLUMNS[:1], 0, 0)], _spec(COLUMNS[:1], inp=inp), None,
              "threads", 2, None, False)
    chunks = []
    task = grid_tasks._grid_task
    monkeypatch.setattr(grid_tasks, "_grid_task",
                        lambda job, spec: chunks.append(job.rows.size) or task(job, spec))
    for rows, tasks in ((1000, 2), (1200, 1)):
        limit = working_set(rows, NCHAN, spec, tasks)
        assert plan_chunks(limit, NCHAN, spec, 2) == (rows, tasks)
        chunks.clear()
        peak = _traced_peak(inp, spec, limit)
        assert len(chunks) == -(-inp.rows.size // rows) > 4 and max(chunks) == rows
        assert peak <= limit, (rows, tasks, peak, limit)
    chunks.clear()
    unlimited = _traced_peak(inp, spec, None)
    assert chunks == [inp.rows.size] and unlimited > limit


def test_plan_runs_fewer_chunks_before_going_below_1000_rows(ms, caplog):
    inp = check_input(ms, COLUMNS, 0, 0)
    spec = _spec(COLUMNS, inp=inp)
    one, two = (working_set(1000, NCHAN, spec, n) for n in (1, 2))
    assert one < two
    assert rows_for_memory(two, NCHAN, spec, 2) == 1000
    assert plan_chunks(two, NCHAN, spec, 2) == (1000, 2)
    rows, tasks = plan_chunks(two - 1, NCHAN, spec, 2)
    assert tasks == 1 and rows >= 1000 and working_set(rows, NCHAN, spec, 1) <= two - 1
    with caplog.at_level(logging.WARNING, logger="msleak.ps.chunks"):
        assert plan_chunks(one - 1, NCHAN, spec, 2) == (1000, 1)
    assert "is less than the grids and one chunk of 1000 rows need" in caplog.text
