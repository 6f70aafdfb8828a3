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
from typing import Literal, Sequence

import numpy as np
import xarray as xr

from msleak.conventions import (STOKES, STOKES_CONVENTION, correlations_to_stokes,
                                feed_type_from_corr_types)
from msleak.errors import InputError
from msleak.ps.gridding import (GRIDDER_DESCRIPTIONS, SPEED_OF_LIGHT, make_accumulator,
                                make_grid, stokes_weights, taper_area_sr)

__all__ = ["grid_ms", "uvcube_dataset", "Split"]

log = logging.getLogger(__name__)

Split = Literal["even-odd", "first-second"]


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


def grid_ms(ms: str | os.PathLike, *, column: str = "DATA", cell: float = 16.0,
            uv_range: tuple[float, float] = (30.0, 180.0), gridder: str = "wgrid",
            split: Split | None = None, field_id: int = 0, ddid: int = 0,
            chunk_rows: int = 20_000, epsilon: float = 1e-6, nthreads: int = 1,
            beam_area_sr: float | None = None, taper: str = "hann",
            progress: bool = False) -> xr.Dataset:
    """Grid one column of a Measurement Set into a uvcube Dataset.

    Parameters
    ----------
    ms : path
    column : str
        Any visibility column (DATA, MODEL_DATA, CORRECTED_DATA, ...), (row, chan, corr).
    cell : float
        Cell size, wavelengths.
    uv_range : (min, max)
        Baseline lengths kept, wavelengths, per channel (sqrt(u^2 + v^2)).
    gridder : {'wgrid', 'cell'}
        See :mod:`msleak.ps.gridding`.
    split : {'even-odd', 'first-second'}, optional
        Also grid two halves of the time steps into ``vis_a``/``vis_b``.
    field_id, ddid : int
        FIELD_ID and DATA_DESC_ID of the rows used.
    chunk_rows : int
        Rows read at a time (memory ~ chunk_rows * nchan * 100 bytes).
    beam_area_sr : float, optional
        Primary-beam area Omega (sr) recorded for the mK^2 Mpc^3 normalisation; default
        the area the gridder sees: ``int A^2 dOmega`` of the ``wgrid`` taper, or
        ``1 / cell^2`` for the ``cell`` gridder (its sinc^2 response integrates to that).
    taper : {'hann', 'none'}
        Image-domain taper of the ``wgrid`` gridder (see :func:`~msleak.ps.gridding.image_taper`).

    Raises
    ------
    InputError
        Unknown column, bad selection, unsupported correlations, no unflagged data, or no
        data in the uv range.
    """
    from msleak.io import ms as msio

    ms = msio.check_ms(ms)
    uv_min, uv_max = (float(x) for x in uv_range)
    if not (0 <= uv_min < uv_max):
        raise InputError(f"uv range {uv_min}..{uv_max} wavelengths is empty: need 0 <= MIN < MAX")
    columns = msio.column_names(ms)
    if column not in columns:
        data_cols = [c for c in columns if c.endswith("DATA")]
        raise InputError(f"{ms}: no column {column!r} (data columns: {', '.join(data_cols)})")
    ddids = msio.read_data_descriptions(ms)
    if not 0 <= ddid < len(ddids):
        raise InputError(f"{ms}: no DATA_DESC_ID {ddid} (the MS has {len(ddids)})")
    spw_id, pol_id = ddids[ddid]
    spw = msio.read_spectral_windows(ms)[spw_id]
    feed = feed_type_from_corr_types(msio.read_corr_types(ms)[pol_id])
    fields = msio.read_fields(ms)
    if not 0 <= field_id < len(fields):
        raise InputError(f"{ms}: no FIELD_ID {field_id} (the MS has {len(fields)})")
    freq = spw.freq
    if freq.size > 1 and not np.allclose(np.diff(freq), np.diff(freq)[0], rtol=1e-6):
        raise InputError(f"{ms}: channels are not evenly spaced; the delay transform "
                         "needs a regular frequency axis")
    b_lo, b_hi = _baseline_span(ms, field_id, ddid)
    if b_hi * freq.max() / SPEED_OF_LIGHT < uv_min or b_lo * freq.min() / SPEED_OF_LIGHT > uv_max:
        raise InputError(
            f"{ms}: no unflagged sample has a baseline in {uv_min:g}..{uv_max:g} wavelengths "
            f"(baselines span {b_lo * freq.min() / SPEED_OF_LIGHT:.4g}.."
            f"{b_hi * freq.max() / SPEED_OF_LIGHT:.4g}); widen --uv-range")
    grid = make_grid(cell, min(uv_max, b_hi * freq.max() / SPEED_OF_LIGHT))
    if grid.size > 4096:
        raise InputError(f"the uv grid would be {grid.size}^2 cells per channel; use a larger "
                         "--cell or a smaller uv maximum")
    wcol = _weight_column(ms, columns)
    cols = [column, "UVW", "FLAG", "ANTENNA1", "ANTENNA2", "TIME"]
    cols += [c for c in ("FLAG_ROW",) if c in columns] + ([wcol] if wcol else [])

    split_of_time = None
    if split is not None:
        times = msio.read_times(ms, field_id=field_id, ddid=ddid)
        if times.size < 2:
            raise InputError(f"--split {split} needs at least two time steps, found {times.size}")
        if split == "even-odd":
            def split_of_time(t):
                return np.searchsorted(times, t) % 2
        elif split == "first-second":
            def split_of_time(t):
                return (np.searchsorted(times, t) >= times.size // 2).astype(int)
        else:
            raise InputError(f"unknown split {split!r}: use even-odd or first-second")

    def new_acc():
        return make_accumulator(gridder, grid, freq, epsilon=epsilon, nthreads=nthreads,
                                taper=taper)

    accs = [new_acc(), new_acc()] if split else [new_acc()]
    stats = dict(rows=0, samples=0, unflagged=0, in_range=0)
    scale = freq / SPEED_OF_LIGHT
    chunks = msio.iter_rows(ms, cols, chunk_rows=chunk_rows, field_id=field_id, ddid=ddid)
    if progress:
        from tqdm import tqdm

        chunks = tqdm(chunks, desc="grid", unit="chunk", leave=False)
    for _, c in chunks:
        cross = c["ANTENNA1"] != c["ANTENNA2"]
        if "FLAG_ROW" in c:
            cross &= ~np.asarray(c["FLAG_ROW"], bool)
        stats["rows"] += cross.size
        data = c[column]
        nrow, nchan, ncorr = data.shape
        if ncorr != 4 or nchan != freq.size:
            raise InputError(f"{ms}: column {column} has shape (row, {nchan}, {ncorr}); "
                             f"expected (row, {freq.size}, 4)")
        # The MS's UVW column holds uvw_ANTENNA2 - uvw_ANTENNA1, and visibilities follow
        # V = sum B exp(+2 pi i UVW . (l, m, n - 1)) (DP3's convention, which msleak predict
        # reproduces: tests/test_predict_dp3.py). The gridding kernels use
        # exp(-2 pi i (u l + v m + w (n - 1))), so they take u = -UVW.
        uvw = -np.asarray(c["UVW"], float)
        b_m = np.hypot(uvw[:, 0], uvw[:, 1])
        keep = cross & (b_m * scale.max() >= uv_min) & (b_m * scale.min() <= uv_max)
        stats["samples"] += int(cross.sum()) * nchan
        if wcol == "WEIGHT_SPECTRUM":
            wcorr = c[wcol]
        elif wcol == "WEIGHT":
            wcorr = np.broadcast_to(c[wcol][:, None, :], data.shape)
        else:
            wcorr = np.ones(data.shape, np.float32)
        flags = np.asarray(c["FLAG"], bool)
        wgt_all = stokes_weights(wcorr[cross], flags[cross])
        stats["unflagged"] += int(np.count_nonzero(wgt_all))
        if not keep.any():
            continue
        wgt = stokes_weights(wcorr[keep], flags[keep])
        uvw = uvw[keep]
        b_l = b_m[keep, None] * scale[None, :]
        wgt[(b_l < uv_min) | (b_l > uv_max)] = 0.0
        stats["in_range"] += int(np.count_nonzero(wgt))
        vis = np.moveaxis(correlations_to_stokes(data[keep], feed), -1, 0)  # (4, row, chan)
        vis = np.where(np.isfinite(vis), vis, 0.0)
        wgt[~np.isfinite(data[keep]).all(axis=-1)] = 0.0
        parts = [np.ones(uvw.shape[0], bool)] if not split else None
        if split:
            which = split_of_time(c["TIME"][keep])
            parts = [which == 0, which == 1]
        for acc, sel in zip(accs, parts):
            if not sel.any():
                continue
            if gridder == "cell":
                acc.add(uvw[sel, :1] * scale, uvw[sel, 1:2] * scale, vis[:, sel], wgt[sel])
            else:
                acc.add(uvw[sel], vis[:, sel], wgt[sel])
    if stats["rows"] == 0:
        raise InputError(f"{ms}: no cross-correlation rows for FIELD_ID {field_id}, "
                         f"DATA_DESC_ID {ddid}")
    if stats["unflagged"] == 0:
        raise InputError(f"{ms}: all {stats['samples']} samples of FIELD_ID {field_id}, "
                         f"DATA_DESC_ID {ddid} are flagged (FLAG/FLAG_ROW/zero weights)")
    if stats["in_range"] == 0:
        raise InputError(f"{ms}: no unflagged sample has a baseline in {uv_min:g}..{uv_max:g} "
                         "wavelengths; widen --uv-range")
    log.info("gridded %d of %d unflagged samples (uv range %g..%g wavelengths)",
             stats["in_range"], stats["unflagged"], uv_min, uv_max)
    full = accs[0] if not split else accs[0].merge(accs[1])
    vis4, weight = full.result()
    halves = [a.result() for a in accs] if split else []
    fov_rad = 1.0 / grid.cell
    area = taper_area_sr(taper, grid) if gridder == "wgrid" else fov_rad ** 2
    attrs = {
        "cell_lambda": grid.cell, "uv_min_lambda": uv_min, "uv_max_lambda": uv_max,
        "units": "Jy", "source": str(ms), "source_kind": "ms", "column": column,
        "field_id": int(field_id), "field_name": fields[field_id].name,
        "phase_centre_ra_deg": math.degrees(fields[field_id].ra) % 360,
        "phase_centre_dec_deg": math.degrees(fields[field_id].dec),
        "spw_id": int(spw_id), "ddid": int(ddid), "feed_type": feed,
        "gridder": gridder, "w_correction": GRIDDER_DESCRIPTIONS[gridder],
        "wgridder_epsilon": float(epsilon) if gridder == "wgrid" else 0.0,
        "weighting": "natural", "weight_column": wcol or "none (unit weights)",
        "fov_deg": math.degrees(fov_rad),
        "taper": taper if gridder == "wgrid" else "none (nearest cell: sinc x sinc response)",
        "beam_area_sr": float(beam_area_sr) if beam_area_sr else area,
        "beam_area_source": ("given" if beam_area_sr else
                             "int A^2 dOmega of the gridder's image-domain response"),
        "split": split or "", "n_samples_gridded": stats["in_range"],
    }
    return uvcube_dataset(vis4, weight, freq, grid.centres, attrs, halves)
