"""The MS side of ``msleak grid``: check an input MS, then chunk tasks that read its rows,
form Stokes visibilities and grid them.

Each task reads its rows through :func:`msleak.io.ms.iter_rows` from its own read-only
table and returns partial accumulators of :mod:`msleak.ps.gridding`; :func:`run_tasks`
sums them in chunk order (docs/grid.md, docs/parallel.md).
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
    correlations_to_stokes,
)
from msleak.errors import InputError
from msleak.io import ms as msio
from msleak.io.columns import read_run_state
from msleak.io.ms import iter_rows, open_table
from msleak.parallel import CASACORE_LOCK, open_runner
from msleak.ps.gridding import make_accumulator, stokes_weights

__all__ = ["AUTO_CHUNK_SAMPLES", "Input", "Spec", "check_input", "run_tasks", "rows_for_memory",
           "uvcube_dataset"]

log = logging.getLogger(__name__)

#: samples (rows x channels) per chunk task by default: big batches keep the w-gridder's
#: per-call cost (FFTs of its w-planes) small
AUTO_CHUNK_SAMPLES = 2_000_000


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
    cols: tuple
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
    cols = [*data_columns, "UVW", "FLAG", "ANTENNA1", "ANTENNA2", "TIME"]
    cols += [c for c in ("FLAG_ROW",) if c in columns] + ([wcol] if wcol else [])
    return Input(ms=str(ms), freq=freq, width=spw_meta.width,
                 layout=correlation_layout(msio.read_corr_types(ms)[pol_id]),
                 spw_id=int(spw_id), field_id=field_id, ddid=ddid,
                 field=msio.read_fields(ms)[field_id], wcol=wcol, cols=tuple(cols),
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


def _read_chunk(inp: Input, rows: np.ndarray) -> dict:
    """The gridding columns at ascending main-table ``rows`` (own read-only table)."""
    with CASACORE_LOCK:
        ((_, columns),) = list(iter_rows(inp.ms, inp.cols, rows=rows, chunk_rows=rows.size))
    return columns


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


def _stokes(inp: Input, data: list, keep: np.ndarray) -> np.ndarray:
    """(column, 4, row, chan) Stokes visibilities of the ``keep`` rows of each column; a
    Stokes parameter whose products the MS lacks is 0 here, NaN in the cube."""
    out = np.empty((len(data), 4, int(keep.sum()), inp.freq.size), np.complex128)
    for k, d in enumerate(data):
        out[k] = np.moveaxis(correlations_to_stokes(inp.layout.to_canonical(d[keep]),
                                                    inp.layout.feed), -1, 0)
    return out


def _grid_task(job: Job, spec: Spec) -> tuple[list, dict]:
    """Partial accumulators (one, or two with a split) of one chunk of rows, and counts.

    UVW, flags, weights and times are read once; every column of ``spec.columns`` is one
    visibility set of the accumulators, which share the gridding of the samples' positions.
    """
    inp = job.inp
    c = _read_chunk(inp, job.rows)
    accs = [make_accumulator(spec.gridder, spec.grid, inp.freq, epsilon=spec.epsilon,
                             nthreads=spec.nthreads or 1,
                             nsets=len(spec.columns))
            for _ in range(2 if spec.split else 1)]
    stats = dict(rows=0, samples=0, unflagged=0, in_range=0)
    for column in spec.columns:
        _check_shape(inp, column, c[column].shape)
    freq = inp.freq
    nchan = freq.size
    scale = freq / SPEED_OF_LIGHT
    cross = c["ANTENNA1"] != c["ANTENNA2"]
    if "FLAG_ROW" in c:
        cross &= ~np.asarray(c["FLAG_ROW"], bool)
    stats["rows"] += cross.size
    # The MS's UVW column holds uvw_ANTENNA2 - uvw_ANTENNA1, and visibilities follow
    # V = sum B exp(+2 pi i UVW . (l, m, n - 1)) (DP3's convention, which msleak predict
    # reproduces: tests/test_predict_dp3.py). The gridding kernels use
    # exp(-2 pi i (u l + v m + w (n - 1))), so they take u = -UVW.
    uvw = -np.asarray(c["UVW"], float)
    b_m = np.hypot(uvw[:, 0], uvw[:, 1])
    uv_min, uv_max = spec.uv_min, spec.uv_max
    keep = cross & (b_m * scale.max() >= uv_min) & (b_m * scale.min() <= uv_max)
    stats["samples"] += int(cross.sum()) * nchan
    shape = (cross.size, nchan, len(inp.layout.slots))
    wcol = inp.wcol
    if wcol == "WEIGHT_SPECTRUM":
        wcorr = c[wcol]
    elif wcol == "WEIGHT":
        wcorr = np.broadcast_to(c[wcol][:, None, :], shape)
    else:
        wcorr = np.ones(shape, np.float32)
    flags = np.asarray(c["FLAG"], bool)
    wgt_all = stokes_weights(wcorr[cross], flags[cross])
    stats["unflagged"] += int(np.count_nonzero(wgt_all))
    if not keep.any():
        return accs, stats
    wgt = stokes_weights(wcorr[keep], flags[keep])
    uvw = uvw[keep]
    b_l = b_m[keep, None] * scale[None, :]
    wgt[(b_l < uv_min) | (b_l > uv_max)] = 0.0
    stats["in_range"] += int(np.count_nonzero(wgt))
    # a sample with a non-finite visibility is dropped from its column by the accumulators
    vis = _stokes(inp, [c.pop(column) for column in spec.columns], keep)
    parts = [np.ones(uvw.shape[0], bool)]
    if spec.split:
        which = _split_index(spec.split, spec.split_times, c["TIME"][keep])
        parts = [which == 0, which == 1]
    for acc, sel in zip(accs, parts):
        if not sel.any():
            continue
        if spec.gridder == "cell":
            acc.add(uvw[sel, :1] * scale, uvw[sel, 1:2] * scale, vis[:, :, sel], wgt[sel])
        else:
            acc.add(uvw[sel], vis[:, :, sel], wgt[sel])
    for acc in accs:  # grid here, in the task, not later in the process that adds them up
        if hasattr(acc, "flush"):
            acc.flush()
    return accs, stats


def _accumulator_bytes(spec: Spec, nchan: int) -> int:
    """Bytes of one partial accumulator of ``nchan`` channels holding every column of
    ``spec`` (measured on a 1-channel one)."""
    probe = make_accumulator(spec.gridder, spec.grid, np.array([1.5e8]), epsilon=spec.epsilon,
                             nthreads=1, nsets=len(spec.columns))
    getattr(probe, "dirty", None)  # allocated on first use
    total = 0
    for obj in (probe, getattr(probe, "natural", None)):
        for value in (vars(obj).values() if obj is not None else ()):
            if isinstance(value, np.ndarray):
                total += value.nbytes
    return total * nchan


def rows_for_memory(budget: float, nchan: int, spec: Spec) -> int:
    """Rows per chunk so that a task's working set stays under ``budget`` bytes.

    Per row and channel: weights and flags as read (4 x 5 bytes) and float64 weights
    (3 x 8); per column, the column as read (4 x 8) and the Stokes visibilities, the
    gridder's copy and its buffer (3 x 4 x 16); fixed: the task's partial accumulators
    (one, or two with a split) with every column's grids.
    """
    fixed = _accumulator_bytes(spec, nchan) * (2 if spec.split else 1)
    per_row = nchan * (4 * 5 + 3 * 8 + len(spec.columns) * (4 * 8 + 3 * 4 * 16)) + 64
    rows = int((budget - fixed) // per_row)
    if rows < 1000:
        log.warning("--memory-limit %.0f MB per task leaves little beside one chunk's grids "
                    "(%.0f MB); going ahead with 1000 rows per chunk", budget / 2**20,
                    fixed / 2**20)
        return 1000
    return rows


def run_tasks(inputs: list, spec: Spec, chunk_rows: int | None, scheduler, workers,
               memory_limit: float | None, progress: bool) -> tuple[list, dict, str]:
    """Grid every input's row chunks: per input its summed accumulators (None: no rows),
    the counts, and the scheduler used."""
    totals: list = [None] * len(inputs)
    stats = dict(rows=0, samples=0, unflagged=0, in_range=0)
    with open_runner(scheduler, workers, memory_limit or 2 * 1024**3) as runner:
        nchan_max = max(i.freq.size for i in inputs)
        step = int(chunk_rows) if chunk_rows else max(1000, AUTO_CHUNK_SAMPLES // nchan_max)
        if memory_limit:
            step = max(1, min(step, rows_for_memory(runner.memory_per_task, nchan_max,
                                                     spec)))

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
            for job, (accs, st) in runner.map(_grid_task, jobs(), shared=spec):
                k = job.k
                totals[k] = accs if totals[k] is None else [
                    a.merge(b) for a, b in zip(totals[k], accs)]
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
