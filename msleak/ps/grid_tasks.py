"""The MS side of ``msleak grid``: check an input MS, then chunk tasks that read its rows,
form Stokes visibilities and grid them.

Each task reads its rows through :func:`msleak.io.ms.iter_rows` from its own read-only
table and returns partial accumulators of :mod:`msleak.ps.gridding`; :func:`run_tasks`
sums them in chunk order, with chunks sized by :func:`rows_for_memory` (docs/grid.md,
docs/parallel.md).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Sequence

import numpy as np
import xarray as xr

from msleak.constants import SPEED_OF_LIGHT
from msleak.conventions import (
    STOKES,
    STOKES_CONVENTION,
    CorrelationLayout,
    correlation_layout,
    correlations_to_stokes_matrix,
)
from msleak.errors import InputError
from msleak.io import ms as msio
from msleak.io.columns import read_run_state
from msleak.io.ms import iter_rows, open_table
from msleak.parallel import CASACORE_LOCK, cpu_count, open_runner
from msleak.ps.gridding import (BOX_FACTOR, WGridAccumulator, accumulator_bytes,
                                make_accumulator, stokes_weights)

__all__ = ["AUTO_CHUNK_SAMPLES", "Input", "Spec", "check_input", "run_tasks", "rows_for_memory",
           "plan_chunks", "working_set", "uvcube_dataset"]

log = logging.getLogger(__name__)

#: samples (rows x channels) per chunk task by default: big batches keep the w-gridder's
#: per-call cost (FFTs of its w-planes) small
AUTO_CHUNK_SAMPLES = 2_000_000
#: fewest rows per chunk the memory planning chooses (it runs fewer chunks at once first)
MIN_CHUNK_ROWS = 1000
#: samples (rows x channels) whose weights or canonical correlations are formed at a time
BLOCK_SAMPLES = 65_536


@dataclass(frozen=True)
class Input:
    """One Measurement Set to grid: its checked metadata and selected rows."""

    ms: str
    freq: np.ndarray
    width: np.ndarray
    layout: CorrelationLayout
    spw_id: int
    field_id: int
    ddid: int
    field: object
    wcol: str
    cols: tuple  # the columns every chunk reads besides the visibility columns
    vis_dtype: np.dtype  # complex64, or complex128 if a visibility column holds doubles
    rows: np.ndarray
    b_lo: float
    b_hi: float


@dataclass(frozen=True)
class Spec:
    """Settings every chunk task needs (shared by the tasks)."""

    columns: tuple[str, ...]
    gridder: str
    grid: object
    uv_min: float
    uv_max: float
    epsilon: float
    nthreads: int | None
    split: str | None
    split_times: np.ndarray | None
    #: rows per chunk task (set by :func:`run_tasks`); the ``wgrid`` accumulators of a chunk
    #: (one, or two with a split) buffer up to ``chunk_rows x channels`` samples together
    #: before they grid them
    chunk_rows: int = 0
    #: bytes of one correlation as read and buffered: 8 (complex64) or 16 (complex128; set
    #: by :func:`run_tasks` from the inputs)
    corr_bytes: int = 8


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
        raise InputError(f"--spw {spw!r} is not a spectral-window id (0, 1, ...)")
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
    """Refuse a column that an interrupted ``msleak predict`` left half written."""
    with open_table(ms) as t:
        state = read_run_state(t, column)
    if state is not None and not bool(state.get("complete", True)):
        raise InputError(f"{ms}: column {column} is incomplete (msleak predict was interrupted "
                         f"after {int(state.get('rows_done', 0))} rows); rerun that predict "
                         "command to finish it")


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
                         f"window {spw_id}; choose others with --field, --spw")
    return lo, hi


def _read_chunk(inp: Input, rows: np.ndarray, columns: Sequence[str]) -> dict:
    """``columns`` at ascending main-table ``rows`` (own read-only table)."""
    with CASACORE_LOCK:
        ((_, got),) = list(iter_rows(inp.ms, columns, rows=rows, chunk_rows=rows.size))
    return got


def _split_index(split: str, times: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Half (0 or 1) of each TIME ``t`` for the ``split`` of the sorted unique ``times``."""
    if split == "even-odd":
        return np.searchsorted(times, t) % 2
    return (np.searchsorted(times, t) >= times.size // 2).astype(int)


def _check_shape(inp: Input, column: str, shape: tuple) -> None:
    if tuple(shape[1:]) != (inp.freq.size, len(inp.layout.slots)):
        raise InputError(f"{inp.ms}: column {column} has shape "
                         f"(row, {', '.join(str(n) for n in shape[1:])}); "
                         f"expected (row, {inp.freq.size}, {len(inp.layout.slots)}) for the "
                         f"correlations {','.join(inp.layout.names)}")


def _blocks(nrow: int, nchan: int) -> list[slice]:
    """Row slices of :data:`BLOCK_SAMPLES` samples covering ``nrow`` rows."""
    step = max(1, BLOCK_SAMPLES // nchan)
    return [slice(start, start + step) for start in range(0, nrow, step)]


def _correlations_into(out: np.ndarray, inp: Input, data: np.ndarray,
                       rows: np.ndarray) -> None:
    """Fill ``out`` (row, chan, 4) with the correlations of ``rows`` of one column (row,
    chan, corr) in canonical order, block by block; a product the MS lacks is 0 (its
    Stokes parameters are 0 here, NaN in the cube)."""
    for b in _blocks(rows.size, inp.freq.size):
        out[b] = inp.layout.to_canonical(data[rows[b]])


def _weighted_rows(inp: Input, spec: Spec, c: dict, stats: dict) -> tuple:
    """The rows of chunk ``c`` to grid: indices, kernel uvw (row, 3) in metres and natural
    weights (row, chan), 0 outside the uv range; updates the counts ``stats``. Frees
    FLAG and the weight column of ``c``."""
    scale = inp.freq / SPEED_OF_LIGHT
    nchan = scale.size
    cross = c["ANTENNA1"] != c["ANTENNA2"]
    if "FLAG_ROW" in c:
        cross &= ~np.asarray(c["FLAG_ROW"], bool)
    stats["rows"] += cross.size
    stats["samples"] += int(cross.sum()) * nchan
    uvw = np.asarray(c["UVW"], float)
    b_m = np.hypot(uvw[:, 0], uvw[:, 1])
    uv_min, uv_max = spec.uv_min, spec.uv_max
    keep = cross & (b_m * scale.max() >= uv_min) & (b_m * scale.min() <= uv_max)
    wcol = inp.wcol
    nrow, ncorr = cross.size, len(inp.layout.slots)
    if wcol == "WEIGHT_SPECTRUM":
        wcorr = c.pop(wcol)
    elif wcol == "WEIGHT":  # one weight per correlation, for every channel
        wcorr = c.pop(wcol)[:, None, :]
    else:
        wcorr = np.ones((nrow, 1, ncorr), np.float32)
    flags = c.pop("FLAG")
    wgt = np.empty((nrow, nchan))
    for b in _blocks(nrow, nchan):
        wgt[b] = stokes_weights(wcorr[b], flags[b])
    del wcorr, flags
    stats["unflagged"] += int(np.count_nonzero((wgt != 0) & cross[:, None]))
    wgt = wgt[keep]
    b_l = b_m[keep, None] * scale[None, :]
    outside = (b_l < uv_min) | (b_l > uv_max)
    wgt[outside] = 0.0
    stats["in_range"] += int(np.count_nonzero(wgt))
    used = (wgt > 0).any(axis=1)
    # rows whose baseline enters or leaves the uv range within the band (docs/ps.md)
    stats["rows_crossing"] += int(np.count_nonzero(outside[used].any(axis=1)))
    rows = np.flatnonzero(keep)[used]
    # The MS's UVW column holds uvw_ANTENNA2 - uvw_ANTENNA1, and visibilities follow
    # V = sum B exp(+2 pi i UVW . (l, m, n - 1)) (DP3's convention, which msleak predict
    # reproduces: tests/test_predict_dp3.py). The gridding kernels use
    # exp(-2 pi i (u l + v m + w (n - 1))), so they take u = -UVW.
    return rows, -uvw[rows], wgt[used]


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
    rows, uvw, wgt = _weighted_rows(inp, spec, c, stats)
    parts: list = [slice(None)]  # the rows of each accumulator
    if spec.split:
        which = _split_index(spec.split, spec.split_times, c["TIME"][rows])
        parts = [np.flatnonzero(which == 0), np.flatnonzero(which == 1)]
    del c
    vis = [np.empty((len(spec.columns), rows[p].size, nchan, 4), inp.vis_dtype)
           for p in parts]
    for k, column in enumerate(spec.columns):
        data = _read_chunk(inp, job.rows, [column])[column]
        _check_shape(inp, column, data.shape)
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


#: bytes per sample (row x channel) that a chunk task holds throughout: float64 weights
#: (and, per column, its correlations as read, 4 x ``corr_bytes``, and 1 of validity)
WEIGHT_SAMPLE_BYTES = 8
#: ... while it adds them up: coordinates, nearest-cell indices and weighted sums
ADD_SAMPLE_BYTES = 96
#: ... and for the ``cell`` gridder one column's complex128 Stokes visibilities and their
#: selections
CELL_ADD_SAMPLE_BYTES = 96
#: bytes per row a task holds: UVW as read and in float64, antennas, TIME, masks, indices
ROW_BYTES = 96
#: bytes per row of one channel's samples gathered for ducc0 (uvw, weights, correlations,
#: Stokes, unit visibilities; and 1 per column: their selection)
GATHER_ROW_BYTES = 160
#: bytes per pixel of the ``wgrid`` image box: a ducc0 call's image, its transforms and
#: ducc0's own grid
IMAGE_PIXEL_BYTES = 128


def working_set(rows: int, nchan: int, spec: Spec, tasks: int = 1) -> int:
    """Bytes that ``tasks`` chunk tasks of ``rows`` rows and ``nchan`` channels at once and
    this process (which sums their results) hold at most together.

    A task holds, per sample (``rows x nchan``), :data:`WEIGHT_SAMPLE_BYTES` and the
    correlations of every column (4 ``corr_bytes`` + 1), plus the larger of: one column
    as read with the block being reordered (:data:`BLOCK_SAMPLES`, twice 4 ``corr_bytes``),
    and :data:`ADD_SAMPLE_BYTES` (+ :data:`CELL_ADD_SAMPLE_BYTES`); :data:`ROW_BYTES` per
    row; its partial accumulators (:func:`~msleak.ps.gridding.accumulator_bytes`, two
    with a split) and, for ``wgrid``, :data:`GATHER_ROW_BYTES` per row and
    :data:`IMAGE_PIXEL_BYTES` per pixel of the image box. This process holds the summed
    accumulators and, for ``wgrid``, up to 1.25 chunks of samples buffered from chunks
    with few weighted ones (weights and correlations as above, 24 bytes of uvw per row)
    with the gathers and images of a call.
    """
    ncol, corr = len(spec.columns), 4 * spec.corr_bytes
    accs = accumulator_bytes(spec.gridder, spec.grid, nchan, ncol) * (2 if spec.split else 1)
    samples = rows * nchan
    held = samples * (WEIGHT_SAMPLE_BYTES + ncol * (corr + 1))
    convert = samples * corr + min(samples, BLOCK_SAMPLES) * 2 * corr
    add = samples * (ADD_SAMPLE_BYTES + (CELL_ADD_SAMPLE_BYTES if spec.gridder == "cell"
                                         else 0))
    task = held + max(convert, add) + rows * ROW_BYTES + accs
    here = accs
    if spec.gridder == "wgrid":
        call = (rows * (GATHER_ROW_BYTES + ncol)
                + IMAGE_PIXEL_BYTES * (BOX_FACTOR * spec.grid.npix_image) ** 2)
        task += call
        here += call + (held + rows * 24) * 5 // 4
    return tasks * task + here


def rows_for_memory(budget: float, nchan: int, spec: Spec, tasks: int = 1) -> int:
    """The most rows per chunk for which :func:`working_set` of ``tasks`` tasks at once
    stays within ``budget`` bytes (0: none)."""
    lo, hi = 0, 1024
    while working_set(hi, nchan, spec, tasks) <= budget:
        lo, hi = hi, 2 * hi
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if working_set(mid, nchan, spec, tasks) <= budget else (lo, mid)
    return lo


def plan_chunks(budget: float, nchan: int, spec: Spec, tasks: int) -> tuple[int, int]:
    """Rows per chunk and chunks at once within ``budget`` bytes: ``tasks`` chunks at once
    if each can have :data:`MIN_CHUNK_ROWS` rows, else fewer; one chunk of
    :data:`MIN_CHUNK_ROWS` rows at a time, with a warning, if even that does not fit."""
    for n in range(tasks, 0, -1):
        rows = rows_for_memory(budget, nchan, spec, n)
        if rows >= MIN_CHUNK_ROWS:
            return rows, n
    log.warning("--memory-limit %.0f MB is less than the grids and one chunk of %d rows "
                "need (%.0f MB); going ahead with that", budget / 2**20, MIN_CHUNK_ROWS,
                working_set(MIN_CHUNK_ROWS, nchan, spec) / 2**20)
    return MIN_CHUNK_ROWS, 1


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


def uvcube_dataset(vis4: np.ndarray, weight: np.ndarray, freq: np.ndarray,
                   centres: np.ndarray, attrs: dict,
                   halves: Sequence[tuple[np.ndarray, np.ndarray]] = ()) -> xr.Dataset:
    """Assemble a uvcube Dataset from I, Q, U, V grids; P = Q + iU is added.

    Parameters
    ----------
    vis4 : (4, chan, v, u) complex
        Gridded I, Q, U, V (Jy).
    weight : (chan, v, u) float
    freq : (chan,) Hz
    centres : (n,) cell centres, wavelengths (same for u and v)
    attrs : dict
        Attributes of the product.
    halves : up to two ``(vis4, weight)`` pairs stored as ``vis_a``/``vis_b`` and
        ``weight_a``/``weight_b``.
    """
    def five(v4):
        return np.concatenate([v4, (v4[1] + 1j * v4[2])[None]], axis=0)

    units = attrs.get("units", "Jy")
    dims = ("stokes", "freq", "v", "u")
    wattrs = {"units": "1", "long_name": "sum of the visibility weights"}
    data = {"vis": (dims, five(vis4), {"units": units,
                                       "long_name": "gridded Stokes visibility"}),
            "weight": (dims[1:], weight, wattrs)}
    for name, (hv, hw) in zip("ab", halves):
        data[f"vis_{name}"] = (dims, five(hv), {"units": units,
                                                "long_name": f"gridded Stokes visibility, "
                                                             f"time half {name}"})
        data[f"weight_{name}"] = (dims[1:], hw, wattrs)
    ds = xr.Dataset(data, coords={
        "stokes": ("stokes", list(STOKES), {"long_name": "Stokes parameter (P = Q + iU)"}),
        "freq": ("freq", np.asarray(freq, float), {"units": "Hz", "long_name": "frequency"}),
        "v": ("v", centres, {"units": "1", "long_name": "v of the cell centre, wavelengths"}),
        "u": ("u", centres, {"units": "1", "long_name": "u of the cell centre, wavelengths"}),
    })
    ds.attrs.update({"stokes_convention": STOKES_CONVENTION, "units": "Jy"})
    ds.attrs.update(attrs)
    return ds
