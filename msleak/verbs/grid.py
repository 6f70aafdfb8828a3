"""``msleak grid`` as a function: Stokes uv cubes (docs/products.md "uvcube") from MS
columns or image cubes.

:func:`grid` plans (checks the MSs, their common frequency axis and the uv grid), runs
the chunk tasks of :mod:`msleak.verbs.grid_tasks`, and describes the result (attributes,
Omega, provenance); image cubes go through :mod:`msleak.verbs.images`. See docs/grid.md.
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Sequence

import numpy as np
import xarray as xr

from msleak.constants import SPEED_OF_LIGHT
from msleak.conventions import STOKES
from msleak.errors import InputError, MsleakError
from msleak.io import ms as msio
from msleak.io.columns import read_run_state
from msleak.io.ms import open_table, read_history
from msleak.io.products import call_record, open_product, refuse_existing, save_product, stamp
from msleak.parallel import frequency_layout
from msleak.ps.beam_area import BEAM_AREA_MODELS
from msleak.ps.chunks import Input, Spec
from msleak.ps.gridding import (GRID_EPSILON, GRIDDER_DESCRIPTIONS, Gridder, make_grid,
                                 response_attrs)
from msleak.ps.uvcube import uvcube_dataset
from msleak.verbs.grid_tasks import check_input, ms_beam_area, run_tasks
from msleak.verbs.images import grid_image

__all__ = ["grid", "Split"]

log = logging.getLogger(__name__)

Split = Literal["even-odd", "first-second"]
PathLike = str | os.PathLike


def grid(ms: PathLike | Sequence[PathLike] | None = None, *,
         column: str | Sequence[str] = "DATA",
         image: PathLike | Sequence[PathLike] | None = None,
         output: PathLike | Sequence[PathLike] | None = None, overwrite: bool = False,
         cell: float = 16.0, uv_range: tuple[float, float] = (30.0, 180.0),
         gridder: Gridder = "wgrid", split: Split | None = None, field: int | str = 0,
         spw: int | str = 0, beam_area: float | None = None, beam_area_model: str = "auto",
         stokes: str | Sequence[str] | None = None, fov: float | None = None,
         beam_fwhm: float | None = None, chunk_rows: int | None = None,
         memory_limit: float | None = 2 * 1024**3, epsilon: float = GRID_EPSILON, threads: int = 1,
         scheduler="threads", workers: int | None = None,
         progress: bool = False) -> xr.Dataset | list[xr.Dataset]:
    """Grid Stokes visibilities of MS columns (or image cubes) into uv cubes.

    Parameters
    ----------
    ms : path or sequence of paths
        One MS, or several (e.g. one per subband) put on one frequency axis in frequency
        order; a gap of whole channels is left empty (weight 0, attribute ``freq_gaps``).
    column : str or sequence of str
        Visibility column(s), (row, chan, corr); several are gridded in one pass, each
        cube identical to its single-column run.
    image : path, glob or sequence of them
        Instead of ``ms``: FITS cubes (one per Stokes or with a STOKES axis), or
        per-channel images (WSClean ``NAME-0000-Q-image.fits``, ...) stacked in frequency
        order.
    output : path or sequence of paths, optional
        Where to write the cube(s) (one per column, in order); None: return only.
    overwrite : bool
        Replace existing outputs (otherwise refused before any work).
    cell : float
        Cell size, wavelengths.
    uv_range : (min, max)
        Baseline lengths sqrt(u^2 + v^2) kept, wavelengths, per channel.
    gridder : {'wgrid', 'cell'}
        w-corrected (ducc0) or nearest cell (docs/grid.md).
    split : {'even-odd', 'first-second'}, optional
        Also grid two halves of the time steps into ``vis_a``/``vis_b``.
    field : int or str
        FIELD_ID or FIELD::NAME of the rows used.
    spw : int
        Spectral window (its DATA_DESC_ID is looked up).
    beam_area : float, optional
        Omega (sr) for the mK^2 Mpc^3 normalisation; default from ``beam_area_model``
        ({'auto', 'everybeam', 'dipole', 'airy'}; with ``image``: the FoV area).
    stokes : str or sequence of str, optional
        With ``image``: the Stokes label of each file without a STOKES axis (default I).
    fov, beam_fwhm : float, optional
        With ``image``: inner field of view used and restoring-beam FWHM, degrees.
    chunk_rows, memory_limit : optional
        Rows per chunk task (default: 2 million samples) and the bytes shared by the
        tasks running at once (lowers ``chunk_rows``).
    epsilon, threads : float, int
        ducc0 accuracy and threads per task (cubes differ at ``epsilon`` between counts).
    scheduler, workers
        Where and how many chunk tasks run at once (docs/parallel.md).

    Returns
    -------
    xarray.Dataset, or a list of them (one per column for a sequence of columns)
        ``vis`` (stokes I, Q, U, V, P; freq; v; u) in Jy, ``weight`` (freq, v, u),
        optional halves, and the attributes of docs/products.md.
    """
    command = call_record(grid, dict(locals()))
    columns = [column] if isinstance(column, str) else list(column)
    outputs = _outputs(output, columns, image is not None, overwrite)
    uv = _check_settings(ms, image, cell, uv_range, beam_area_model)
    if image is not None:
        cubes = [grid_image(image, stokes=stokes, fov_deg=fov, uv_range=uv,
                            beam_fwhm_deg=beam_fwhm, beam_area_sr=beam_area)]
    else:
        plan = _plan(ms, columns, field=field, spw=spw, cell=cell, uv=uv, gridder=gridder,
                     split=split, epsilon=epsilon, threads=threads, chunk_rows=chunk_rows)
        totals, stats = _run(plan, chunk_rows, scheduler, workers, memory_limit, progress)
        cubes = _describe(plan, totals, stats, beam_area, beam_area_model)
    cubes = [stamp(ds, command) for ds in cubes]
    if outputs:
        cubes = [_write(ds, path, overwrite) for ds, path in zip(cubes, outputs)]
    return cubes if image is None and not isinstance(column, str) else cubes[0]


def _check_settings(ms, image, cell, uv_range, beam_area_model: str) -> tuple[float, float]:
    """The checked uv range; refuses a cell that is not a positive number, both or neither
    of ``ms`` and ``image``, and an unknown beam-area model."""
    uv = _uv_range(uv_range)
    if not (isinstance(cell, (int, float, np.floating)) and math.isfinite(cell) and cell > 0):
        raise InputError(f"cell must be a positive number of wavelengths, got {cell}",
                         param="cell")
    if (ms is None) == (image is None):
        raise InputError("give either a Measurement Set or image (not both)", param="image")
    if beam_area_model not in BEAM_AREA_MODELS:
        raise InputError(f"unknown beam_area_model {beam_area_model!r}: use "
                         f"{', '.join(BEAM_AREA_MODELS)}", param="beam_area_model")
    return uv


def _uv_range(uv_range) -> tuple[float, float]:
    if len(uv_range) != 2:
        raise InputError(f"uv_range needs MIN,MAX (wavelengths), got {uv_range}",
                         param="uv_range")
    uv_min, uv_max = (float(x) for x in uv_range)
    if not 0 <= uv_min < uv_max:
        raise InputError(f"uv_range {uv_min:g},{uv_max:g}: empty range; give MIN,MAX "
                         "with 0 <= MIN < MAX (wavelengths)", param="uv_range")
    return uv_min, uv_max


def _outputs(output, columns: list[str], image: bool, overwrite: bool) -> list[Path]:
    """The output paths (one per column, one for images), checked before any work."""
    if not columns:
        raise InputError("no column given")
    for name in columns:
        if columns.count(name) > 1:
            raise InputError(f"column {name} is given twice; give each column once",
                             param="column")
    if output is None:
        return []
    given = [os.fspath(output)] if isinstance(output, (str, os.PathLike)) else [
        os.fspath(p) for p in output]
    want = 1 if image else len(columns)
    if len(given) != want:
        raise InputError(f"image makes one uv cube but {len(given)} outputs are given; "
                         "give one" if image else f"{len(columns)} columns but {len(given)} "
                         "outputs given: give one output per column, in the same order")
    seen = set()
    for text in given:
        path = Path(text)
        if path.resolve() in seen:
            raise InputError(f"output {text} is given twice: give each column its own output")
        seen.add(path.resolve())
        refuse_existing(path, overwrite)
    return [Path(text) for text in given]


def _write(ds: xr.Dataset, path: Path, overwrite: bool) -> xr.Dataset:
    """Write a uvcube; returns the Dataset as written."""
    save_product(ds, path, "uvcube", overwrite=overwrite)
    return open_product(path, "uvcube")


@dataclass(frozen=True)
class _Plan:
    """Checked inputs, their common frequency axis and the settings of the chunk tasks."""

    inputs: list
    layout: object
    spec: Spec
    label: str


def _check_epsilon(epsilon: float) -> None:
    """Refuse a wgrid accuracy outside (0, 1) or finer than ducc0 has a kernel for (asked
    of ducc0 itself, with one sample: its range depends on its version)."""
    from ducc0.wgridder import vis2dirty

    if not (math.isfinite(epsilon) and 0 < epsilon < 1):
        raise InputError(f"epsilon must be a relative accuracy between 0 and 1, got "
                         f"{epsilon:g} (default 1e-6)", param="epsilon")
    try:
        vis2dirty(uvw=np.zeros((1, 3)), freq=np.array([1e8]), vis=np.ones((1, 1), np.complex128),
                  npix_x=16, npix_y=16, pixsize_x=1e-3, pixsize_y=1e-3, epsilon=epsilon,
                  do_wgridding=True)
    except RuntimeError as err:
        raise InputError(f"epsilon {epsilon:g}: this ducc0's gridder has no kernel this "
                         "accurate (its limit is near 2e-14); give a larger value (default "
                         "1e-6)", param="epsilon") from err


def _plan(ms, columns: list[str], *, field, spw, cell: float, uv: tuple,
          gridder: str, split, epsilon: float, threads: int, chunk_rows) -> _Plan:
    """Check every MS and column (before anything is gridded) and size the uv grid."""
    paths = [ms] if isinstance(ms, (str, os.PathLike)) else list(ms)
    if not paths:
        raise InputError("no Measurement Set given")
    if gridder not in GRIDDER_DESCRIPTIONS:
        raise InputError(f"unknown gridder {gridder!r}: use 'wgrid' or 'cell'")
    if split not in (None, "even-odd", "first-second"):
        raise InputError(f"unknown split {split!r}: use even-odd or first-second")
    if chunk_rows is not None and chunk_rows <= 0:
        raise InputError("chunk_rows must be positive", param="chunk_rows")
    if gridder == "wgrid":
        _check_epsilon(epsilon)
    if len({Path(p).resolve() for p in paths}) < len(paths):
        raise InputError("a Measurement Set is given twice")
    inputs = [check_input(p, columns, field, spw) for p in paths]
    names = [i.ms for i in inputs]
    label = names[0] if len(names) == 1 else f"{len(names)} Measurement Sets"
    layout = frequency_layout([i.freq for i in inputs], names, [i.width for i in inputs])
    f0 = inputs[0].field
    for inp in inputs[1:]:
        sep = math.hypot((inp.field.ra - f0.ra) * math.cos(f0.dec), inp.field.dec - f0.dec)
        if sep > 1e-8:
            raise InputError(f"{inp.ms}: phase centre differs from {names[0]}'s by "
                             f"{math.degrees(sep) * 3600:.3g} arcsec; grid one field at a time")
    uv_grid = _uv_grid(inputs, layout.freq, cell, uv, label)
    split_times = None
    if split is not None:
        split_times = np.unique(np.concatenate(
            [msio.read_times(i.ms, field_id=i.field_id, ddid=i.ddid) for i in inputs]))
        if split_times.size < 2:
            raise InputError(f"split {split} needs at least two time steps, found "
                             f"{split_times.size}", param="split")
    spec = Spec(columns=tuple(columns), gridder=gridder, grid=uv_grid, uv_min=uv[0],
                uv_max=uv[1], epsilon=epsilon, nthreads=threads, split=split,
                split_times=split_times)
    return _Plan(inputs=inputs, layout=layout, spec=spec, label=label)


def _uv_grid(inputs: list, freq: np.ndarray, cell: float, uv: tuple, label: str):
    """The uv grid holding every baseline in the uv range."""
    b_lo = min(i.b_lo for i in inputs) * freq.min() / SPEED_OF_LIGHT
    b_hi = max(i.b_hi for i in inputs) * freq.max() / SPEED_OF_LIGHT
    if b_hi < uv[0] or b_lo > uv[1]:
        raise InputError(f"{label}: no unflagged sample has a baseline in {uv[0]:g}..{uv[1]:g} "
                         f"wavelengths (baselines span {b_lo:.4g}..{b_hi:.4g}); "
                         "widen uv_range", param="uv_range")
    uv_grid = make_grid(cell, min(uv[1], b_hi))
    if uv_grid.size > 4096:
        raise InputError(f"the uv grid would be {uv_grid.size}^2 cells per channel; use a "
                         "larger cell or a smaller uv maximum", param="cell")
    return uv_grid


def _run(plan: _Plan, chunk_rows, scheduler, workers, memory_limit, progress) -> tuple:
    """Grid every chunk; per input its summed accumulators, and the counts (checked)."""
    spec = plan.spec
    totals, stats, scheduler_text = run_tasks(plan.inputs, spec, chunk_rows, scheduler,
                                              workers, memory_limit, progress)
    inp = plan.inputs[0]
    where = f"field {inp.field_id}, spectral window {inp.spw_id}"
    if stats["rows"] == 0:
        raise InputError(f"{plan.label}: no cross-correlation rows for {where}; choose "
                         "others with `field`, `spw`", param=("field", "spw"))
    if stats["unflagged"] == 0:
        raise InputError(f"{plan.label}: all {stats['samples']} samples of {where} are "
                         "flagged (FLAG/FLAG_ROW/zero weights); choose others with "
                         "`field`, `spw`", param=("field", "spw"))
    if stats["in_range"] == 0:
        raise InputError(f"{plan.label}: no unflagged sample has a baseline in "
                         f"{spec.uv_min:g}..{spec.uv_max:g} wavelengths; widen uv_range",
                         param="uv_range")
    log.info("gridded %d of %d unflagged samples of %s (uv range %g..%g wavelengths; %s)",
             stats["in_range"], stats["unflagged"], ", ".join(spec.columns), spec.uv_min,
             spec.uv_max, scheduler_text)
    if stats["rows_crossing"]:
        log.info("%d rows (baseline x time) enter or leave the uv range within the band: "
                 "their cells change abruptly in frequency there, a floor at high k_par "
                 "(docs/ps.md, 'A floor from the uv range')", stats["rows_crossing"])
    return totals, stats


def _describe(plan: _Plan, totals: list, stats: dict, beam_area, beam_area_model: str
              ) -> list[xr.Dataset]:
    """One uvcube per column, with attributes and history, from the summed accumulators."""
    inputs, spec = plan.inputs, plan.spec
    missing = sorted({s for i in inputs for s in i.layout.stokes_missing}, key=STOKES.index)
    if missing:
        log.warning("%s has only the correlations %s: Stokes %s are not measured and are "
                    "NaN in the cube", plan.label, "; ".join(sorted(
                        {",".join(i.layout.names) for i in inputs})), ", ".join(missing))
    attrs = _cube_attrs(plan, missing, stats["in_range"], beam_area, beam_area_model)
    attrs["n_rows_crossing_uv_range"] = int(stats["rows_crossing"])
    ms_history = _ms_history(inputs)
    size = spec.grid.size
    nhalves = 2 if spec.split else 0
    # halves first: their results grid any buffered samples once, the sums reuse them
    halves = [[_assemble([None if t is None else t[h] for t in totals], j, plan, size,
                         missing) for h in range(nhalves)] for j in range(len(spec.columns))]
    whole = [None if t is None else t[0].merge(t[1]) if spec.split else t[0] for t in totals]
    cubes = []
    for j, column in enumerate(spec.columns):
        vis4, weight = _assemble(whole, j, plan, size, missing)
        history = ms_history + _column_provenance(inputs, column)
        cubes.append(uvcube_dataset(vis4, weight, plan.layout.freq, spec.grid.centres,
                                    {**attrs, "column": column, "history": "\n".join(history)},
                                    halves[j]))
    return cubes


def _assemble(accs: list, index: int, plan: _Plan, size: int,
              missing: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """``(vis4, weight)`` of column ``index`` on the common frequency axis, from each
    input's accumulator (None: the input had no rows)."""
    layout = plan.layout
    nchan = layout.freq.size
    vis4 = np.zeros((4, nchan, size, size), np.complex128)
    weight = np.zeros((nchan, size, size))
    for k, (inp, acc) in enumerate(zip(plan.inputs, accs)):
        if acc is None:
            continue
        v, w = acc.result(index)
        o = layout.offsets[k]
        vis4[:, o:o + inp.freq.size] = v
        weight[o:o + inp.freq.size] = w
    vis4[[STOKES.index(s) for s in missing if s != "P"]] = np.nan  # P follows from U
    return vis4, weight


def _cube_attrs(plan: _Plan, missing: list[str], n_gridded: int, beam_area,
                beam_area_model: str) -> dict:
    """The attributes every column's uvcube shares (all but ``column`` and ``history``)."""
    inputs, spec, layout = plan.inputs, plan.spec, plan.layout
    first, f0 = inputs[0], inputs[0].field
    seen = response_attrs(spec.gridder, spec.grid.cell)
    freq_mid = float(layout.freq[layout.freq.size // 2])
    attrs = {
        "cell_lambda": spec.grid.cell, "uv_min_lambda": spec.uv_min,
        "uv_max_lambda": spec.uv_max, "units": "Jy",
        "source": "; ".join(str(Path(i.ms).resolve()) for i in inputs), "source_kind": "ms",
        "field_id": first.field_id, "field_name": f0.name,
        "phase_centre_ra_deg": math.degrees(f0.ra) % 360,
        "phase_centre_dec_deg": math.degrees(f0.dec),
        "spw_id": first.spw_id, "ddid": first.ddid,
        "feed_type": ",".join(sorted({i.layout.feed for i in inputs})),
        "correlations": "; ".join(sorted({",".join(i.layout.names) for i in inputs})),
        "stokes_missing": ",".join(missing),
        "gridder": spec.gridder, "w_correction": GRIDDER_DESCRIPTIONS[spec.gridder],
        "wgridder_epsilon": float(spec.epsilon) if spec.gridder == "wgrid" else 0.0,
        "weighting": "natural",
        "weight_column": ",".join(sorted({i.wcol or "none (unit weights)" for i in inputs})),
        **seen,
        "beam_area_sr": float(beam_area) if beam_area else seen["beam_area_sr"],
        "beam_area_source": "given" if beam_area else seen["beam_area_source"],
        "beam_area_model": "given" if beam_area else "airy",
        **_beam_area_from_ms(first, beam_area, beam_area_model, spec, freq_mid),
        "split": spec.split or "", "n_samples_gridded": n_gridded,
        "n_inputs": len(inputs), "freq_gaps": layout.gap_text(),
        "n_gap_channels": layout.n_gap_channels,
    }
    if len(inputs) > 1:
        attrs["spw_ids"] = ",".join(str(i.spw_id) for i in inputs)
    return attrs


def _ms_history(inputs: list) -> list[str]:
    """The HISTORY rows of every input MS, one line each, prefixed with the MS."""
    return [f"{Path(i.ms).resolve()} HISTORY {line}" for i in inputs
            for line in read_history(i.ms)]


def _column_provenance(inputs: list, column: str) -> list[str]:
    """The provenance msleak predict stored in ``column`` of each input (keyword
    MSLEAK_PREDICT, docs/predict.md), one line per MS."""
    lines = []
    for inp in inputs:
        with open_table(inp.ms) as t:
            state = read_run_state(t, column)
        if not state:
            continue
        when = state.get("finished") or state.get("updated", "")
        what = state.get("command") or ", ".join(
            f"{key} {state[key]}" for key in ("sky", "fov_deg", "beam", "centre_correction",
                                              "precision") if key in state)
        lines.append(f"{when} msleak {state.get('msleak_version', '?')}: predict into "
                     f"{Path(inp.ms).resolve()} column {column}: {what}")
    return lines


def _beam_area_from_ms(inp: Input, given, model: str, spec: Spec, freq_hz: float) -> dict:
    """Omega from the MS's beam model, unless it was given or the Airy model is asked."""
    if given or model == "airy":
        return {}

    tries = ["everybeam", "dipole"] if model == "auto" else [model]
    for name in tries:
        if model == "auto" and name == "everybeam" and not msio.has_lofar_tables(inp.ms):
            continue
        try:
            omega, how = ms_beam_area(inp.ms, model=name, gridder=spec.gridder,
                                      cell=spec.grid.cell, freq_hz=freq_hz,
                                      field_id=inp.field_id, ddid=inp.ddid)
            return {"beam_area_sr": omega, "beam_area_source": how, "beam_area_model": name,
                    "primary_beam_model": f"{name} station beam of the MS (msleak.beam) for "
                    "beam_area_sr; primary_fwhm_deg from an Airy disc of diameter cell "
                    "wavelengths"}
        except MsleakError as err:
            if model != "auto":
                raise
            log.warning("beam area: the %s beam of %s is not usable (%s); trying the next "
                        "model", name, inp.ms, err)
    return {}   # auto and no model of the MS usable: the Airy model (already recorded)
