"""The MS side of ``msleak grid``: check an input MS, run the chunk tasks that read its
rows, form Stokes visibilities and grid them, and Omega from the MS's beam model.

Each task reads its rows through :func:`msleak.io.ms.iter_rows` from its own read-only
table and returns partial accumulators of :mod:`msleak.ps.gridding`; :func:`run_tasks`
sums them in chunk order, with chunks sized by :func:`msleak.ps.chunks.plan_chunks`
(docs/grid.md, docs/parallel.md).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from msleak.adapters.beams import load_beam
from msleak.beam.maps import sin_grid
from msleak.constants import SPEED_OF_LIGHT
from msleak.conventions import correlation_layout, correlations_to_stokes_matrix
from msleak.errors import BeamUnavailable
from msleak.errors import InputError
from msleak.io import ms as msio
from msleak.io.columns import read_noise_state, read_run_state
from msleak.io.ms import iter_rows, open_table
from msleak.parallel import CASACORE_LOCK, cpu_count, open_runner
from msleak.ps.beam_area import beam_area_from_jones
from msleak.ps.chunks import (AUTO_CHUNK_SAMPLES, BLOCK_SAMPLES, MIN_CHUNK_ROWS, Input, Spec,
                              blocks, check_shape, plan_chunks, split_index, weighted_rows)
from msleak.ps.gridding import WGridAccumulator, make_accumulator

__all__ = ["Job", "check_input", "run_tasks", "ms_beam_area"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Job:
    """Rows ``rows`` of input ``k``: one task."""

    index: int
    k: int
    inp: Input
    rows: np.ndarray

    @property
    def name(self) -> str:
        return f"{Path(self.inp.ms).name} rows {int(self.rows[0])}..{int(self.rows[-1])}"


def check_input(ms, data_columns: Sequence[str], field, spw) -> Input:
    """Check one MS for gridding (columns, field, spectral window, channels, baselines)."""
    ms = msio.check_ms(ms)
    columns = msio.column_names(ms)
    for column in data_columns:
        if column not in columns:
            raise InputError(f"{ms}: no column {column!r} (data columns: "
                             f"{', '.join(msio.data_column_names(ms)) or 'none'})")
    for column in data_columns:
        _check_complete(ms, column)
    field_id = msio.resolve_field(ms, field)
    ddid = msio.resolve_spw(ms, _spw_id(spw))
    spw_id, pol_id = msio.read_data_descriptions(ms)[ddid]
    spw_meta = msio.read_spectral_windows(ms)[spw_id]
    freq = spw_meta.freq
    if freq.size > 1 and not np.allclose(np.diff(freq), np.diff(freq)[0], rtol=1e-6):
        raise InputError(f"{ms}: channels are not evenly spaced; the delay transform "
                         "needs a regular frequency axis")
    rows = msio.select_rows(ms, field_id=field_id, ddid=ddid)
    b_lo, b_hi = _baseline_span(ms, rows, field_id, spw_id)
    wcol = _weight_column(ms, columns)
    cols = ["UVW", "FLAG", "ANTENNA1", "ANTENNA2", "TIME"]
    cols += [c for c in ("FLAG_ROW",) if c in columns] + ([wcol] if wcol else [])
    with open_table(ms) as t:
        double = any(t.getcoldesc(c).get("valueType") == "dcomplex" for c in data_columns)
    return Input(ms=str(ms), freq=freq, width=spw_meta.width,
                 layout=correlation_layout(msio.read_corr_types(ms)[pol_id]),
                 spw_id=int(spw_id), field_id=field_id, ddid=ddid,
                 field=msio.read_fields(ms)[field_id], wcol=wcol, cols=tuple(cols),
                 vis_dtype=np.dtype(np.complex128 if double else np.complex64),
                 rows=rows, b_lo=b_lo, b_hi=b_hi)


def _spw_id(spw) -> int:
    text = str(spw).strip()
    if not text.isdigit():
        raise InputError(f"spw {spw!r} is not a spectral-window id (0, 1, ...)", param="spw")
    return int(text)


def _weight_column(ms, columns: list[str]) -> str:
    if "WEIGHT_SPECTRUM" in columns:
        with open_table(ms) as t:
            if t.nrows() and t.iscelldefined("WEIGHT_SPECTRUM", 0):
                return "WEIGHT_SPECTRUM"
    if "WEIGHT" in columns:
        return "WEIGHT"
    return ""


def _check_complete(ms, column: str) -> None:
    """Refuse a column that an interrupted ``msleak predict`` or ``msleak noise`` left half
    written."""
    with open_table(ms) as t:
        states = (("predict", read_run_state(t, column)), ("noise", read_noise_state(t, column)))
    for verb, state in states:
        if state is not None and not bool(state.get("complete", True)):
            raise InputError(f"{ms}: column {column} is incomplete (msleak {verb} was "
                             f"interrupted after {int(state.get('rows_done', 0))} rows); "
                             f"rerun that {verb} command to finish it")


def _baseline_span(ms, rows: np.ndarray, field_id: int, spw_id: int) -> tuple[float, float]:
    """Shortest and longest cross-correlation baseline sqrt(u^2 + v^2) (m) of ``rows``."""
    lo, hi = np.inf, 0.0
    if rows.size:
        for _, c in msio.iter_rows(ms, ["UVW", "ANTENNA1", "ANTENNA2"], rows=rows,
                                   chunk_rows=500_000):
            cross = c["ANTENNA1"] != c["ANTENNA2"]
            if cross.any():
                b = np.hypot(c["UVW"][cross, 0], c["UVW"][cross, 1])
                lo, hi = min(lo, float(b.min())), max(hi, float(b.max()))
    if hi == 0.0:
        raise InputError(f"{ms}: no cross-correlation rows for field {field_id}, spectral "
                         f"window {spw_id}; choose others with `field`, `spw`",
                         param=("field", "spw"))
    return lo, hi


def _read_chunk(inp: Input, rows: np.ndarray, columns: Sequence[str]) -> dict:
    """``columns`` at ascending main-table ``rows`` (own read-only table)."""
    with CASACORE_LOCK:
        ((_, got),) = list(iter_rows(inp.ms, columns, rows=rows, chunk_rows=rows.size))
    return got


def _correlations_into(out: np.ndarray, inp: Input, data: np.ndarray,
                       rows: np.ndarray) -> None:
    """Fill ``out`` (row, chan, 4) with the correlations of ``rows`` of one column (row,
    chan, corr) in canonical order, block by block; a product the MS lacks is 0 (its
    Stokes parameters are 0 here, NaN in the cube)."""
    for b in blocks(rows.size, inp.freq.size, BLOCK_SAMPLES):
        out[b] = inp.layout.to_canonical(data[rows[b]])


def _grid_task(job: Job, spec: Spec) -> tuple[list, dict]:
    """Partial accumulators (one, or two with a split) of one chunk of rows, and counts.

    UVW, flags, weights and times are read once, then the columns one after another, each
    keeping the correlations of the rows that carry weight; every column is one visibility
    set of the accumulators, which share the gridding of the samples' positions and form
    the Stokes visibilities.
    """
    inp = job.inp
    nchan = inp.freq.size
    halves = 2 if spec.split else 1
    accs = [make_accumulator(spec.gridder, spec.grid, inp.freq, epsilon=spec.epsilon,
                             nthreads=spec.nthreads or 1, nsets=len(spec.columns),
                             buffer_samples=spec.chunk_rows * nchan // halves,
                             to_stokes=correlations_to_stokes_matrix(inp.layout.feed))
            for _ in range(halves)]
    stats = dict(rows=0, samples=0, unflagged=0, in_range=0, rows_crossing=0)
    c = _read_chunk(inp, job.rows, inp.cols)
    rows, uvw, wgt = weighted_rows(inp, spec, c, stats)
    parts: list = [slice(None)]  # the rows of each accumulator
    if spec.split:
        which = split_index(spec.split, spec.split_times, c["TIME"][rows])
        parts = [np.flatnonzero(which == 0), np.flatnonzero(which == 1)]
    del c
    vis = [np.empty((len(spec.columns), rows[p].size, nchan, 4), inp.vis_dtype)
           for p in parts]
    for k, column in enumerate(spec.columns):
        data = _read_chunk(inp, job.rows, [column])[column]
        check_shape(inp, column, data.shape)
        for out, p in zip(vis, parts):
            _correlations_into(out[k], inp, data, rows[p])
        del data
    scale = inp.freq / SPEED_OF_LIGHT
    # a sample with a non-finite visibility is dropped from its column by the accumulators
    for acc, p, v in zip(accs, parts, vis):
        if v.shape[1] == 0:
            continue
        if spec.gridder == "cell":
            acc.add(uvw[p, :1] * scale, uvw[p, 1:2] * scale, v, wgt[p])
        else:
            acc.add(uvw[p], v, wgt[p])
        if hasattr(acc, "flush"):  # grid here, in the task, not later in the process that
            acc.flush()            # adds them up
    return accs, stats


def run_tasks(inputs: list, spec: Spec, chunk_rows: int | None, scheduler, workers,
               memory_limit: float | None, progress: bool) -> tuple[list, dict, str]:
    """Grid every input's row chunks: per input its summed accumulators (None: no rows),
    the counts, and the scheduler used."""
    totals: list = [None] * len(inputs)
    stats = dict(rows=0, samples=0, unflagged=0, in_range=0, rows_crossing=0)
    with open_runner(scheduler, workers, memory_limit or 2 * 1024**3) as runner:
        nchan_max = max(i.freq.size for i in inputs)
        spec = replace(spec, corr_bytes=max(i.vis_dtype.itemsize for i in inputs))
        step = int(chunk_rows) if chunk_rows else max(MIN_CHUNK_ROWS,
                                                      AUTO_CHUNK_SAMPLES // nchan_max)
        tasks = runner.workers
        if memory_limit:
            fit, tasks = plan_chunks(runner.memory_per_task * runner.workers, nchan_max, spec,
                                     runner.workers)
            step = min(step, fit)
            if tasks < runner.workers:
                log.info("--memory-limit: %d chunk(s) of %d rows at a time", tasks, step)
        spec = replace(spec, chunk_rows=step)

        def jobs():
            index = 0
            for k, inp in enumerate(inputs):
                light = replace(inp, rows=inp.rows[:0])  # tasks get their own rows only
                for start in range(0, inp.rows.size, step):
                    yield Job(index, k, light, inp.rows[start:start + step])
                    index += 1

        njobs = sum(-(-i.rows.size // step) for i in inputs)
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=njobs, desc="grid", unit="chunk", leave=False)
        try:
            for job, (accs, st) in runner.map(_grid_task, jobs(), shared=spec,
                                              window=tasks):
                k = job.k
                if totals[k] is None:
                    # what the tasks leave buffered is gridded here, as many channels at
                    # once as tasks run at once (no more memory than they hold)
                    for acc in accs:
                        if isinstance(acc, WGridAccumulator):
                            acc.channel_threads = min(tasks, cpu_count())
                    totals[k] = accs
                else:
                    totals[k] = [a.merge(b) for a, b in zip(totals[k], accs)]
                del accs  # not kept while the next chunks run
                for key, value in st.items():
                    stats[key] += value
                if bar is not None:
                    bar.update(1)
        finally:
            if bar is not None:
                bar.close()
        return totals, stats, runner.describe()


def ms_beam_area(ms: str | Path, *, model: str, gridder: str, cell: float,
                 freq_hz: float | None = None, field_id: int = 0, ddid: int = 0,
                 half_width_deg: float = 12.0, npix: int = 97) -> tuple[float, str]:
    """Omega (sr) from the beam model of ``ms`` and a description of how it was made.

    The beam is that of the stations in the rows of ``field_id`` and ``ddid`` (the rows
    grid reads) about that field's phase centre. ``freq_hz``: where to evaluate it (default
    the middle channel of ``ddid``; grid passes the centre of its whole frequency axis, so
    several subband MSs give one Omega).

    Raises
    ------
    InputError
        Also when the model cannot describe the MS (:class:`~msleak.beam.BeamUnavailable`);
        the message then names grid's parameters.
    """
    if model not in ("everybeam", "dipole"):
        raise InputError(f"beam-area model {model!r} is not one read from the MS")
    field = msio.read_fields(ms)[field_id]
    times = msio.read_times(ms, field_id=field_id, ddid=ddid)
    if times.size == 0:
        raise InputError(f"{ms}: no rows, so no time at which to evaluate the beam")
    spw_id = msio.read_data_descriptions(ms)[ddid][0]
    freq = msio.read_spectral_windows(ms)[spw_id].freq
    t_mid = times[times.size // 2]
    f_mid = float(freq[freq.size // 2]) if freq_hz is None else float(freq_hz)
    l_deg, m_deg, ra, dec = sin_grid(field.ra, field.dec, 2 * half_width_deg, npix)
    try:
        beam = load_beam(model, ms, field_id=field_id, ddid=ddid)
    except BeamUnavailable as err:
        others = "`beam_area_model='dipole'`, " if model != "dipole" else ""
        raise BeamUnavailable(err.reason, setting=err.setting,
                              remedy=f"use {others}`beam_area_model='airy'` or "
                                     "`beam_area=SR`",
                              param=("beam_area_model", "beam_area")) from err
    jones = beam.jones(np.array([t_mid]), np.array([f_mid]), ra.ravel(), dec.ravel())
    centre = beam.jones_centre(np.array([t_mid]), np.array([f_mid]))
    omega = beam_area_from_jones(jones, centre, l_deg, m_deg, gridder, cell)
    if omega is None:
        raise InputError(f"{ms}: the {model} beam is zero at the phase centre")
    how = (f"int A^2 R^2 dOmega: A the {model} station power beam of the MS (mean M00 over "
           f"stations at {f_mid / 1e6:.3f} MHz, mid-observation), R the gridder's response")
    log.info("beam area from the %s beam: %.3e sr", model, omega)
    return omega, how
