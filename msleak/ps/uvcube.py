"""Build uv-cube products (docs/products.md "uvcube") from a Measurement Set or image cubes.

This is the I/O edge of :mod:`msleak.ps`: it reads the MS in row chunks through
:mod:`msleak.io.ms` (memory bounded by ``chunk_rows``), forms Stokes visibilities with
:mod:`msleak.conventions` and hands arrays to the pure gridders of
:mod:`msleak.ps.gridding`; or it reads FITS image cubes and calls :mod:`msleak.ps.image`.
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal, Sequence

import numpy as np
import xarray as xr

from msleak.conventions import (STOKES, STOKES_CONVENTION, CorrelationLayout,
                                correlation_layout, correlations_to_stokes)
from msleak.errors import InputError
from msleak.constants import SPEED_OF_LIGHT
from msleak.ps.gridding import (DEFAULT_TAPER, GRIDDER_DESCRIPTIONS, SPEED_OF_LIGHT,
                                make_accumulator, make_grid, response_attrs, stokes_weights)

__all__ = ["grid_ms", "uvcube_dataset", "Split"]

log = logging.getLogger(__name__)

Split = Literal["even-odd", "first-second"]

#: samples (rows x channels) per chunk task by default: big batches keep the w-gridder's
#: per-call cost (FFTs of its w-planes) small
AUTO_CHUNK_SAMPLES = 2_000_000


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

    dims = ("stokes", "freq", "v", "u")
    data = {"vis": (dims, five(vis4), {"units": attrs.get("units", "Jy"),
                                       "long_name": "gridded Stokes visibility"}),
            "weight": (dims[1:], weight, {"long_name": "sum of visibility weights"})}
    for name, (hv, hw) in zip("ab", halves):
        data[f"vis_{name}"] = (dims, five(hv), {"units": attrs.get("units", "Jy")})
        data[f"weight_{name}"] = (dims[1:], hw, {})
    ds = xr.Dataset(data, coords={
        "stokes": ("stokes", list(STOKES)),
        "freq": ("freq", np.asarray(freq, float), {"units": "Hz"}),
        "v": ("v", centres, {"units": "wavelengths"}),
        "u": ("u", centres, {"units": "wavelengths"}),
    })
    ds.attrs.update({"stokes_convention": STOKES_CONVENTION, "units": "Jy"})
    ds.attrs.update(attrs)
    return ds


def _weight_column(ms, columns: list[str]) -> str:
    from msleak.io.ms import open_table

    if "WEIGHT_SPECTRUM" in columns:
        with open_table(ms) as t:
            if t.nrows() and t.iscelldefined("WEIGHT_SPECTRUM", 0):
                return "WEIGHT_SPECTRUM"
    if "WEIGHT" in columns:
        return "WEIGHT"
    return ""


def _check_complete(ms, column: str) -> None:
    """Refuse a column that an interrupted ``msleak predict`` left half written."""
    from msleak.io.columns import read_run_state
    from msleak.io.ms import open_table

    with open_table(ms) as t:
        state = read_run_state(t, column)
    if state is not None and not bool(state.get("complete", True)):
        raise InputError(f"{ms}: column {column} is incomplete (msleak predict was interrupted "
                         f"after {int(state.get('rows_done', 0))} rows); rerun that predict "
                         "command to finish it")


def _baseline_span(ms, field_id: int, ddid: int) -> tuple[float, float]:
    """Shortest and longest cross-correlation baseline sqrt(u^2 + v^2) (m) of the selection."""
    from msleak.io import ms as msio

    lo, hi = np.inf, 0.0
    for _, c in msio.iter_rows(ms, ["UVW", "ANTENNA1", "ANTENNA2"], chunk_rows=500_000,
                               field_id=field_id, ddid=ddid):
        cross = c["ANTENNA1"] != c["ANTENNA2"]
        if cross.any():
            b = np.hypot(c["UVW"][cross, 0], c["UVW"][cross, 1])
            lo, hi = min(lo, float(b.min())), max(hi, float(b.max()))
    if hi == 0.0:
        raise InputError(f"{ms}: no cross-correlation rows for FIELD_ID {field_id}, "
                         f"DATA_DESC_ID {ddid}")
    return lo, hi


@dataclass(frozen=True)
class _Input:
    """One Measurement Set to grid: its checked metadata and selected rows."""

    ms: str
    freq: np.ndarray
    width: np.ndarray
    layout: CorrelationLayout
    spw_id: int
    field: object
    wcol: str
    cols: tuple
    rows: np.ndarray
    b_lo: float
    b_hi: float


@dataclass(frozen=True)
class _Spec:
    """Settings every chunk task needs (shared by the tasks)."""

    columns: tuple[str, ...]
    gridder: str
    grid: object
    uv_min: float
    uv_max: float
    epsilon: float
    nthreads: int | None
    taper: str
    split: str | None
    split_times: np.ndarray | None


@dataclass(frozen=True)
class _Job:
    """Rows ``rows`` of input ``k``: one task."""

    index: int
    k: int
    inp: _Input
    rows: np.ndarray

    @property
    def name(self) -> str:
        return f"{Path(self.inp.ms).name} rows {int(self.rows[0])}..{int(self.rows[-1])}"


def _grid_input(ms, data_columns: Sequence[str], field_id: int, ddid: int) -> _Input:
    """Check one MS for gridding (the columns, DATA_DESC_ID, FIELD_ID, channels, baselines)."""
    from msleak.io import ms as msio

    ms = msio.check_ms(ms)
    columns = msio.column_names(ms)
    for column in data_columns:
        if column not in columns:
            raise InputError(f"{ms}: no column {column!r} (data columns: "
                             f"{', '.join(msio.data_column_names(ms)) or 'none'})")
    for column in data_columns:
        _check_complete(ms, column)
    ddids = msio.read_data_descriptions(ms)
    if not 0 <= ddid < len(ddids):
        raise InputError(f"{ms}: no DATA_DESC_ID {ddid} (the MS has {len(ddids)})")
    spw_id, pol_id = ddids[ddid]
    spw = msio.read_spectral_windows(ms)[spw_id]
    layout = correlation_layout(msio.read_corr_types(ms)[pol_id])
    fields = msio.read_fields(ms)
    if not 0 <= field_id < len(fields):
        raise InputError(f"{ms}: no FIELD_ID {field_id} (the MS has {len(fields)})")
    freq = spw.freq
    if freq.size > 1 and not np.allclose(np.diff(freq), np.diff(freq)[0], rtol=1e-6):
        raise InputError(f"{ms}: channels are not evenly spaced; the delay transform "
                         "needs a regular frequency axis")
    b_lo, b_hi = _baseline_span(ms, field_id, ddid)
    wcol = _weight_column(ms, columns)
    cols = [*data_columns, "UVW", "FLAG", "ANTENNA1", "ANTENNA2", "TIME"]
    cols += [c for c in ("FLAG_ROW",) if c in columns] + ([wcol] if wcol else [])
    with msio.open_table(ms) as table:
        sel = table.query(f"FIELD_ID=={int(field_id)} && DATA_DESC_ID=={int(ddid)}",
                          columns="")
        try:
            rows = np.asarray(sel.rownumbers(table), dtype=np.int64)
        finally:
            sel.close()
    return _Input(ms=str(ms), freq=freq, width=spw.width, layout=layout, spw_id=int(spw_id),
                  field=fields[field_id], wcol=wcol, cols=tuple(cols), rows=rows,
                  b_lo=b_lo, b_hi=b_hi)


def _read_chunk(inp: _Input, rows: np.ndarray) -> dict:
    """The gridding columns at ascending main-table ``rows`` (own read-only table)."""
    from msleak.io.ms import open_table
    from msleak.parallel import CASACORE_LOCK

    first, n = int(rows[0]), int(rows.size)
    contiguous = int(rows[-1]) - first + 1 == n
    with CASACORE_LOCK, open_table(inp.ms) as table:
        if contiguous:
            return {c: table.getcol(c, startrow=first, nrow=n) for c in inp.cols}
        sel = table.selectrows(rows.tolist())
        try:
            return {c: sel.getcol(c) for c in inp.cols}
        finally:
            sel.close()


def _split_index(split: str, times: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Half (0 or 1) of each TIME ``t`` for the ``split`` of the sorted unique ``times``."""
    if split == "even-odd":
        return np.searchsorted(times, t) % 2
    return (np.searchsorted(times, t) >= times.size // 2).astype(int)


def _check_shape(inp: _Input, column: str, shape: tuple) -> None:
    if tuple(shape[1:]) != (inp.freq.size, len(inp.layout.slots)):
        raise InputError(f"{inp.ms}: column {column} has shape "
                         f"(row, {', '.join(str(n) for n in shape[1:])}); "
                         f"expected (row, {inp.freq.size}, {len(inp.layout.slots)}) for the "
                         f"correlations {','.join(inp.layout.names)}")


def _stokes(inp: _Input, data: list, keep: np.ndarray) -> np.ndarray:
    """(column, 4, row, chan) Stokes visibilities of the ``keep`` rows of each column; a
    Stokes parameter whose products the MS lacks is 0 here, NaN in the cube."""
    out = np.empty((len(data), 4, int(keep.sum()), inp.freq.size), np.complex128)
    for k, d in enumerate(data):
        out[k] = np.moveaxis(correlations_to_stokes(inp.layout.to_canonical(d[keep]),
                                                    inp.layout.feed), -1, 0)
    return out


def _grid_task(job: _Job, spec: _Spec) -> tuple[list, dict]:
    """Partial accumulators (one, or two with a split) of one chunk of rows, and counts.

    UVW, flags, weights and times are read once; every column of ``spec.columns`` is one
    visibility set of the accumulators, which share the gridding of the samples' positions.
    """
    inp = job.inp
    c = _read_chunk(inp, job.rows)
    accs = [make_accumulator(spec.gridder, spec.grid, inp.freq, epsilon=spec.epsilon,
                             nthreads=spec.nthreads or 1, taper=spec.taper,
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


def _accumulator_bytes(spec: _Spec, nchan: int) -> int:
    """Bytes of one partial accumulator of ``nchan`` channels holding every column of
    ``spec`` (measured on a 1-channel one)."""
    probe = make_accumulator(spec.gridder, spec.grid, np.array([1.5e8]), epsilon=spec.epsilon,
                             nthreads=1, taper=spec.taper, nsets=len(spec.columns))
    getattr(probe, "dirty", None)  # allocated on first use
    total = 0
    for obj in (probe, getattr(probe, "natural", None)):
        for value in (vars(obj).values() if obj is not None else ()):
            if isinstance(value, np.ndarray):
                total += value.nbytes
    return total * nchan


def _rows_for_memory(budget: float, nchan: int, spec: _Spec) -> int:
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


def _beam_area_from_ms(ms, given, model: str, gridder: str, taper: str, cell: float,
                       freq_hz: float, field_id: int, ddid: int) -> dict:
    """Omega from the MS's beam model, unless it was given or the Airy model is asked."""
    if given or model == "airy":
        return {}
    from msleak.errors import MsleakError
    from msleak.io import ms as msio
    from msleak.ps.beam_area import ms_beam_area

    tries = ["everybeam", "dipole"] if model == "auto" else [model]
    for name in tries:
        if model == "auto" and name == "everybeam" and not msio.has_lofar_tables(ms):
            continue
        try:
            omega, how = ms_beam_area(ms, model=name, gridder=gridder, taper=taper, cell=cell,
                                      freq_hz=freq_hz, field_id=field_id, ddid=ddid)
            return {"beam_area_sr": omega, "beam_area_source": how, "beam_area_model": name,
                    "primary_beam_model": f"{name} station beam of the MS (msleak.beam) for "
                    "beam_area_sr; primary_fwhm_deg from an Airy disc of diameter cell "
                    "wavelengths"}
        except MsleakError as err:
            if model != "auto":
                raise
            log.warning("beam area: the %s beam of %s is not usable (%s); trying the next "
                        "model", name, ms, err)
    return {}   # auto and no model of the MS usable: the Airy model (already recorded)


def _column_list(column: str | Sequence[str]) -> list[str]:
    """The columns to grid: one name, or several (each once)."""
    columns = [column] if isinstance(column, str) else list(column)
    if not columns:
        raise InputError("no column given")
    for name in columns:
        if columns.count(name) > 1:
            raise InputError(f"column {name} is given twice; give each --column once")
    return columns


def _prepare(paths: list, columns: list[str], field_id: int, ddid: int, cell: float,
             uv_min: float, uv_max: float, split: str | None) -> tuple:
    """``(inputs, frequency layout, uv grid, split time steps, label)`` of checked inputs.

    Every column of every MS is checked (present, not left incomplete by predict) here,
    before anything is gridded.
    """
    from msleak.io import ms as msio
    from msleak.parallel import frequency_layout

    inputs = [_grid_input(p, columns, field_id, ddid) for p in paths]
    names = [i.ms for i in inputs]
    label = names[0] if len(names) == 1 else f"{len(names)} Measurement Sets"
    if len(set(str(Path(n).resolve()) for n in names)) < len(names):
        raise InputError("a Measurement Set is given twice")
    layout = frequency_layout([i.freq for i in inputs], names, [i.width for i in inputs])
    f0 = inputs[0].field
    for inp in inputs[1:]:
        sep = math.hypot((inp.field.ra - f0.ra) * math.cos(f0.dec), inp.field.dec - f0.dec)
        if sep > 1e-8:
            raise InputError(f"{inp.ms}: phase centre differs from {names[0]}'s by "
                             f"{math.degrees(sep) * 3600:.3g} arcsec; grid one field at a time")
    freq = layout.freq
    b_lo = min(i.b_lo for i in inputs)
    b_hi = max(i.b_hi for i in inputs)
    if b_hi * freq.max() / SPEED_OF_LIGHT < uv_min or b_lo * freq.min() / SPEED_OF_LIGHT > uv_max:
        raise InputError(
            f"{label}: no unflagged sample has a baseline in {uv_min:g}..{uv_max:g} wavelengths "
            f"(baselines span {b_lo * freq.min() / SPEED_OF_LIGHT:.4g}.."
            f"{b_hi * freq.max() / SPEED_OF_LIGHT:.4g}); widen --uv-range")
    grid = make_grid(cell, min(uv_max, b_hi * freq.max() / SPEED_OF_LIGHT))
    if grid.size > 4096:
        raise InputError(f"the uv grid would be {grid.size}^2 cells per channel; use a larger "
                         "--cell or a smaller uv maximum")
    if split not in (None, "even-odd", "first-second"):
        raise InputError(f"unknown split {split!r}: use even-odd or first-second")
    split_times = None
    if split is not None:
        split_times = np.unique(np.concatenate(
            [msio.read_times(i.ms, field_id=field_id, ddid=ddid) for i in inputs]))
        if split_times.size < 2:
            raise InputError(f"--split {split} needs at least two time steps, found "
                             f"{split_times.size}")
    return inputs, layout, grid, split_times, label


def _run_tasks(inputs: list, spec: _Spec, chunk_rows: int | None, scheduler, workers,
               memory_limit: float | None, progress: bool) -> tuple[list, dict, str]:
    """Grid every input's row chunks: per input its summed accumulators (None: no rows),
    the counts, and the scheduler used."""
    from msleak.parallel import open_runner

    totals: list = [None] * len(inputs)
    stats = dict(rows=0, samples=0, unflagged=0, in_range=0)
    with open_runner(scheduler, workers, memory_limit or 2 * 1024**3) as runner:
        nchan_max = max(i.freq.size for i in inputs)
        step = int(chunk_rows) if chunk_rows else max(1000, AUTO_CHUNK_SAMPLES // nchan_max)
        if memory_limit:
            step = max(1, min(step, _rows_for_memory(runner.memory_per_task, nchan_max,
                                                     spec)))

        def jobs():
            index = 0
            for k, inp in enumerate(inputs):
                light = replace(inp, rows=inp.rows[:0])  # tasks get their own rows only
                for start in range(0, inp.rows.size, step):
                    yield _Job(index, k, light, inp.rows[start:start + step])
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


def _check_counts(stats: dict, label: str, spec: _Spec, field_id: int, ddid: int) -> None:
    if stats["rows"] == 0:
        raise InputError(f"{label}: no cross-correlation rows for FIELD_ID {field_id}, "
                         f"DATA_DESC_ID {ddid}")
    if stats["unflagged"] == 0:
        raise InputError(f"{label}: all {stats['samples']} samples of FIELD_ID {field_id}, "
                         f"DATA_DESC_ID {ddid} are flagged (FLAG/FLAG_ROW/zero weights)")
    if stats["in_range"] == 0:
        raise InputError(f"{label}: no unflagged sample has a baseline in {spec.uv_min:g}.."
                         f"{spec.uv_max:g} wavelengths; widen --uv-range")


def _assemble(accs: list, index: int, inputs: list, layout, size: int,
              missing: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """``(vis4, weight)`` of column ``index`` on the common frequency axis, from each
    input's accumulator (None: the input had no rows)."""
    nchan = layout.freq.size
    vis4 = np.zeros((4, nchan, size, size), np.complex128)
    weight = np.zeros((nchan, size, size))
    for k, (inp, acc) in enumerate(zip(inputs, accs)):
        if acc is None:
            continue
        v, w = acc.result(index)
        o = layout.offsets[k]
        vis4[:, o:o + inp.freq.size] = v
        weight[o:o + inp.freq.size] = w
    vis4[[STOKES.index(s) for s in missing if s != "P"]] = np.nan  # P follows from U
    return vis4, weight


def _cube_attrs(inputs: list, layout, spec: _Spec, missing: list[str], n_gridded: int,
                field_id: int, ddid: int, beam_area_sr: float | None,
                beam_area_model: str) -> dict:
    """The attributes every column's uvcube shares (all but ``column``)."""
    names = [i.ms for i in inputs]
    f0 = inputs[0].field
    freq, grid, gridder = layout.freq, spec.grid, spec.gridder
    seen = response_attrs(gridder, spec.taper, grid.cell)
    attrs = {
        "cell_lambda": grid.cell, "uv_min_lambda": spec.uv_min, "uv_max_lambda": spec.uv_max,
        "units": "Jy", "source": "; ".join(names), "source_kind": "ms",
        "field_id": int(field_id), "field_name": f0.name,
        "phase_centre_ra_deg": math.degrees(f0.ra) % 360,
        "phase_centre_dec_deg": math.degrees(f0.dec),
        "spw_id": inputs[0].spw_id, "ddid": int(ddid),
        "feed_type": ",".join(sorted({i.layout.feed for i in inputs})),
        "correlations": "; ".join(sorted({",".join(i.layout.names) for i in inputs})),
        "stokes_missing": ",".join(missing),
        "gridder": gridder, "w_correction": GRIDDER_DESCRIPTIONS[gridder],
        "wgridder_epsilon": float(spec.epsilon) if gridder == "wgrid" else 0.0,
        "weighting": "natural",
        "weight_column": ",".join(sorted({i.wcol or "none (unit weights)" for i in inputs})),
        **seen,
        "beam_area_sr": float(beam_area_sr) if beam_area_sr else seen["beam_area_sr"],
        "beam_area_source": "given" if beam_area_sr else seen["beam_area_source"],
        "beam_area_model": "given" if beam_area_sr else "airy",
        **_beam_area_from_ms(names[0], beam_area_sr, beam_area_model, gridder, spec.taper,
                             grid.cell, float(freq[freq.size // 2]), field_id, ddid),
        "split": spec.split or "", "n_samples_gridded": n_gridded,
        "n_inputs": len(inputs), "freq_gaps": layout.gap_text(),
        "n_gap_channels": layout.n_gap_channels,
    }
    if len(inputs) > 1:
        attrs["spw_ids"] = ",".join(str(i.spw_id) for i in inputs)
    return attrs


def grid_ms(ms: str | os.PathLike | Sequence[str | os.PathLike], *,
            column: str | Sequence[str] = "DATA",
            cell: float = 16.0, uv_range: tuple[float, float] = (30.0, 180.0),
            gridder: str = "wgrid", split: Split | None = None, field_id: int = 0,
            ddid: int = 0, chunk_rows: int | None = None, epsilon: float = 1e-6,
            nthreads: int | None = 1, beam_area_sr: float | None = None,
            taper: str = DEFAULT_TAPER, progress: bool = False, scheduler="sync",
            workers: int | None = None, memory_limit: float | None = None,
            beam_area_model: str = "auto") -> xr.Dataset | list[xr.Dataset]:
    """Grid one column, or several in one pass, of one or several Measurement Sets into
    uvcube Datasets.

    Parameters
    ----------
    ms : path or sequence of paths
        One MS, or several (e.g. one per subband) whose channels are put on one regular
        frequency axis in frequency order (:func:`msleak.parallel.frequency_layout`):
        overlapping channels are an error; missing channels (a gap of whole channels) are
        left empty (weight 0), logged as a warning and listed in the attributes
        ``freq_gaps`` and ``n_gap_channels``. All must share the phase centre.
    column : str or sequence of str
        Any visibility column (DATA, MODEL_DATA, CORRECTED_DATA, ...), (row, chan, corr).
        Several columns are gridded in one pass: UVW, flags, weights and times are read
        once per chunk and the samples' gridding is shared; each column's cube is exactly
        the one it gets on its own (same chunks), and every column is checked before
        anything is gridded.
    cell : float
        Cell size, wavelengths.
    uv_range : (min, max)
        Baseline lengths kept, wavelengths, per channel (sqrt(u^2 + v^2)).
    gridder : {'wgrid', 'cell'}
        See :mod:`msleak.ps.gridding`.
    split : {'even-odd', 'first-second'}, optional
        Also grid two halves of the time steps into ``vis_a``/``vis_b`` (time steps of
        all the inputs together).
    field_id, ddid : int
        FIELD_ID and DATA_DESC_ID of the rows used (in every input).
    chunk_rows : int, optional
        Rows per chunk task; default: 2 million samples (rows x channels), the batch the
        wgrid gridder works best with. Memory: about chunk_rows * nchan * (44 + 224 per
        column) bytes per task, plus the task's partial grids.
    nthreads : int, optional
        Threads of the ducc0 gridder per task (None: 1). ducc0 picks its gridding kernel
        with the thread count in its cost model, so cubes made with different counts
        differ at the ``epsilon`` level (4e-7 measured); the same count on every
        scheduler keeps the cube independent of it (1e-14).
    beam_area_sr : float, optional
        Primary-beam area Omega (sr) recorded for the mK^2 Mpc^3 normalisation; default
        ``int A^2 R^2 dOmega`` with A the Airy power beam of a cell-wide station and R
        the gridder's response (:func:`~msleak.ps.gridding.response_attrs`).
    beam_area_model : {'auto', 'everybeam', 'dipole', 'airy'}
        How Omega is made when ``beam_area_sr`` is not given: from the beam model of the
        (first) MS (:func:`msleak.ps.beam_area.ms_beam_area`; ``auto`` is everybeam for an
        MS with the LOFAR tables, else dipole), or ``airy`` (an Airy disc of a cell-wide
        station, :func:`msleak.ps.gridding.beam_area_model`). Made once for all columns.
    taper : {'cos2', 'hann'}
        uv kernel of the ``wgrid`` gridder: ``cos2`` (one cell wide, response wider than
        the station beam) or the legacy ``hann`` (~1.3 deg field); see
        :mod:`msleak.ps.gridding`.
    scheduler : {'sync', 'threads', 'processes'} or str or distributed.Client
        Where the chunk tasks run (:func:`msleak.parallel.open_runner`). Each task reads
        its rows from its own read-only table; the partial grids are summed here in
        chunk order, so the result does not depend on the scheduler (up to the ducc0
        gridder's own multi-threaded summation, ~1e-13 relative).
    workers : int, optional
        Tasks at a time (default: all cores / all worker threads).
    memory_limit : float, optional
        Bytes shared by the tasks running at the same time; lowers ``chunk_rows`` if
        needed, counting every column (default: no limit beyond ``chunk_rows``).

    Returns
    -------
    xarray.Dataset, or a list of them
        The uvcube of ``column``; for a sequence of columns, one uvcube per column in
        the same order (attribute ``column`` says which).

    Raises
    ------
    InputError
        Unknown or incomplete column, a column given twice, bad selection, unsupported
        correlations, no unflagged data, no data in the uv range, overlapping inputs or
        inputs that do not share a regular frequency grid or a phase centre.
    """
    paths = [ms] if isinstance(ms, (str, os.PathLike)) else list(ms)
    if not paths:
        raise InputError("no Measurement Set given")
    columns = _column_list(column)
    uv_min, uv_max = (float(x) for x in uv_range)
    if not (0 <= uv_min < uv_max):
        raise InputError(f"uv range {uv_min}..{uv_max} wavelengths is empty: need 0 <= MIN < MAX")
    if chunk_rows is not None and chunk_rows <= 0:
        raise InputError("chunk size must be positive")
    inputs, layout, grid, split_times, label = _prepare(paths, columns, field_id, ddid, cell,
                                                        uv_min, uv_max, split)
    spec = _Spec(columns=tuple(columns), gridder=gridder, grid=grid, uv_min=uv_min,
                 uv_max=uv_max, epsilon=epsilon, nthreads=nthreads, taper=taper, split=split,
                 split_times=split_times)
    make_accumulator(gridder, grid, layout.freq[:1], epsilon=epsilon, taper=taper)  # names
    totals, stats, scheduler_text = _run_tasks(inputs, spec, chunk_rows, scheduler, workers,
                                               memory_limit, progress)
    _check_counts(stats, label, spec, field_id, ddid)
    log.info("gridded %d of %d unflagged samples of %s (uv range %g..%g wavelengths; %s)",
             stats["in_range"], stats["unflagged"], ", ".join(columns), uv_min, uv_max,
             scheduler_text)
    missing = sorted({s for i in inputs for s in i.layout.stokes_missing}, key=STOKES.index)
    if missing:
        log.warning("%s has only the correlations %s: Stokes %s are not measured and are "
                    "NaN in the cube", label, "; ".join(sorted({",".join(i.layout.names)
                                                              for i in inputs})),
                    ", ".join(missing))
    attrs = _cube_attrs(inputs, layout, spec, missing, stats["in_range"], field_id, ddid,
                        beam_area_sr, beam_area_model)

    def cube(accs, index, halves=()):
        vis4, weight = _assemble(accs, index, inputs, layout, grid.size, missing)
        return uvcube_dataset(vis4, weight, layout.freq, grid.centres,
                              {**attrs, "column": columns[index]}, halves)

    # halves first: their results grid any buffered samples once, the sums reuse them
    halves = [[_assemble([None if t is None else t[h] for t in totals], j, inputs, layout,
                         grid.size, missing) for h in range(2 if split else 0)]
              for j in range(len(columns))]
    whole = [None if t is None else t[0].merge(t[1]) if split else t[0] for t in totals]
    cubes = [cube(whole, j, halves[j]) for j in range(len(columns))]
    return cubes[0] if isinstance(column, str) else cubes
