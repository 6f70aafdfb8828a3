"""Fractional leakage L_I = 100 sqrt(P_I / P_P) per 2D bin and per 3D voxel of the full uv
plane (each cell (u, tau) of ``power3d`` and its mirror (-u, -tau) in
``power3d_P_mirror``), with the mask reason codes of :data:`MASK_CODES`; docs/leakage.md
("Masks", "Statistics") and docs/science.md."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Literal

import numpy as np
import xarray as xr

from msleak.errors import InputError

__all__ = [
    "MASK_CODES",
    "NegativePolicy",
    "leakage_fraction",
    "stokes_power",
    "voxel_power",
    "leakage_map",
    "leakage_voxels",
    "LeakageVoxels",
    "mask_summary",
    "window_leakage",
]

log = logging.getLogger(__name__)

#: reason codes of the ``mask`` arrays (0 = valid)
MASK_CODES = {
    "valid": 0,
    "empty": 1,
    "nonfinite": 2,
    "nonpositive_pp": 3,
    "negative_pi": 4,
    "not_in_grid": 5,
}

NegativePolicy = Literal["mask", "clip"]
#: the sample L_I statistics are taken from: 3D voxels or 2D (k_par, k_perp) bins
StatsFrom = Literal["voxels", "bins"]


def leakage_fraction(p_i: np.ndarray, p_p: np.ndarray, counts: np.ndarray | None = None,
                     negative: NegativePolicy = "mask") -> tuple[np.ndarray, np.ndarray]:
    """L_I = 100 sqrt(P_I / P_P) in percent, element by element, with a reason-coded mask.

    Parameters
    ----------
    p_i, p_p : ndarray, same shape (any)
        Power of Stokes I and of P = Q + iU (any common unit; only the ratio matters).
        Complex input is reduced to its real part (cross-power convention).
    counts : ndarray, optional, broadcastable to ``p_i``
        Number of 3D cells averaged in each element; elements with 0 are ``empty``.
    negative : {"mask", "clip"}
        What to do with P_I < 0 (cross-power): mask the element, or set L_I = 0.

    Returns
    -------
    L : ndarray, float64, shape of ``p_i``
        Fractional leakage in percent; 0 where masked.
    mask : ndarray, int8, shape of ``p_i``
        Reason codes, see :data:`MASK_CODES` (0 = valid).
    """
    if negative not in ("mask", "clip"):
        raise InputError(f"unknown policy for negative P_I {negative!r}: use 'mask' or 'clip'")
    p_i = np.real(np.asarray(p_i)).astype(np.float64)
    p_p = np.real(np.asarray(p_p)).astype(np.float64)
    if p_i.shape != p_p.shape:
        raise InputError(f"P_I shape {p_i.shape} differs from P_P shape {p_p.shape}")
    mask = np.zeros(p_i.shape, dtype=np.int8)
    if negative == "mask":
        mask[p_i < 0] = MASK_CODES["negative_pi"]
    # later assignments win: the most basic reason is recorded
    mask[p_p <= 0] = MASK_CODES["nonpositive_pp"]
    mask[~(np.isfinite(p_i) & np.isfinite(p_p))] = MASK_CODES["nonfinite"]
    if counts is not None:
        empty = np.broadcast_to(np.asarray(counts) <= 0, p_i.shape)
        mask[empty] = MASK_CODES["empty"]
    ok = mask == 0
    ratio = np.zeros(p_i.shape)
    ratio[ok] = np.maximum(p_i[ok], 0.0) / p_p[ok]
    return 100.0 * np.sqrt(ratio), mask


def mask_summary(mask: np.ndarray) -> dict[str, int]:
    """Number of elements per mask reason (only reasons that occur, ``valid`` excluded)."""
    names = {code: name for name, code in MASK_CODES.items()}
    codes, n = np.unique(np.asarray(mask), return_counts=True)
    return {names.get(int(c), str(int(c))): int(k) for c, k in zip(codes, n) if c != 0}


def stokes_power(ds: xr.Dataset, var: str, stokes: str, source: str = "PS product"
                 ) -> xr.DataArray:
    """``ds[var]`` at one Stokes label, with a one-line error if it is not there."""
    if var not in ds.variables:
        raise InputError(f"{source}: has no variable {var!r}")
    da = ds[var]
    if "stokes" not in da.dims:
        raise InputError(f"{source}: {var!r} has no 'stokes' dimension")
    labels = [str(s) for s in np.asarray(ds["stokes"].values).ravel()]
    if stokes in str(ds.attrs.get("stokes_missing", "")).split(","):
        raise InputError(f"{source}: Stokes {stokes} was not measured (the MS has only the "
                         f"correlations {ds.attrs.get('correlations', '?')}); leakage needs "
                         "Stokes I and P, and P needs four correlations (XX,XY,YX,YY or "
                         "RR,RL,LR,LL): use a PS product of such an MS")
    if stokes not in labels:
        raise InputError(f"{source}: no Stokes {stokes} in {var!r} (has {','.join(labels)}); "
                         f"leakage needs Stokes I and P")
    return da.isel(stokes=labels.index(stokes))


def voxel_power(ds: xr.Dataset, name: str = "PS product") -> tuple[np.ndarray, np.ndarray]:
    """P_I and P_P of every voxel of the full uv plane, each (2, delay3d, cell).

    Index 0 holds the voxels (u, tau) of ``power3d``'s cells, index 1 their mirrors
    (-u, -tau) (``power3d_P_mirror``); P_I is the same in both (Stokes I is Hermitian).
    """
    if "power3d" not in ds.variables:
        raise InputError(f"{name}: has no 'power3d' (unaveraged 3D power); rerun "
                         "`msleak ps`, or pass stats_from bins", param="stats_from")
    p_i = stokes_power(ds, "power3d", "I", name).transpose("delay3d", "cell").values
    p_p = stokes_power(ds, "power3d", "P", name).transpose("delay3d", "cell").values
    if "power3d_P_mirror" not in ds.variables:
        raise InputError(f"{name}: has no 'power3d_P_mirror' (P power of the mirrored voxels "
                         "(-u, -tau)); rerun `msleak ps` on its delay cube, or pass "
                         "stats_from bins", param="stats_from")
    p_m = ds["power3d_P_mirror"].transpose("delay3d", "cell").values
    return np.stack([p_i, p_i]), np.stack([p_p, p_m])


def leakage_map(ds: xr.Dataset, negative: NegativePolicy = "mask", source: str = "PS product"
                ) -> xr.Dataset:
    """The 2D L_I map of a PS product (``power`` (stokes, k_par, k_perp)).

    Returns
    -------
    xarray.Dataset
        ``L_I`` (k_par, k_perp) percent (0 where masked), ``mask`` (k_par, k_perp) int8,
        ``power_I`` and ``power_P`` (k_par, k_perp) in the product's units.
    """
    p_i = stokes_power(ds, "power", "I", source).transpose("k_par", "k_perp")
    p_p = stokes_power(ds, "power", "P", source).transpose("k_par", "k_perp")
    counts = None
    if "counts" in ds.variables:
        counts = ds["counts"].transpose("k_par", "k_perp").values
    L, mask = leakage_fraction(p_i.values, p_p.values, counts, negative)
    dims = ("k_par", "k_perp")
    coords = {"k_par": ds["k_par"].values, "k_perp": ds["k_perp"].values}
    units = ds["power"].attrs.get("units", ds.attrs.get("units", ""))
    out = xr.Dataset(
        {
            "L_I": (dims, L, {"units": "percent", "long_name": "fractional leakage "
                              "100 sqrt(P_I/P_P); 0 where mask != 0"}),
            "mask": (dims, mask, {"long_name": "mask reason code, 0 = valid"}),
            "power_I": (dims, np.where(np.isfinite(p_i.values), np.real(p_i.values), 0.0),
                        {"units": units}),
            "power_P": (dims, np.where(np.isfinite(p_p.values), np.real(p_p.values), 0.0),
                        {"units": units}),
        },
        coords=coords,
    )
    return out


@dataclass(frozen=True)
class LeakageVoxels:
    """Per-voxel leakage of one PS product.

    Attributes
    ----------
    L : ndarray (n_valid,)
        L_I in percent of the valid voxels inside the selection (``voxels``: both voxels
        (u, tau) and (-u, -tau) of every cell and delay of ``power3d``).
    n_selected : int
        Voxels inside the k selection (valid + masked).
    masked : dict
        Number of masked voxels per reason (see :data:`MASK_CODES`).
    source : str
        ``"voxels"`` (from ``power3d``) or ``"bins"`` (from the 2D bins).
    """

    L: np.ndarray
    n_selected: int
    masked: dict
    source: str

    @property
    def n_masked(self) -> int:
        return int(sum(self.masked.values()))


def _in_range(x: np.ndarray, rng: tuple[float, float] | None) -> np.ndarray:
    if rng is None:
        return np.ones(x.shape, dtype=bool)
    return (x >= rng[0]) & (x <= rng[1])


def leakage_voxels(ds: xr.Dataset, source: StatsFrom = "voxels",
                   negative: NegativePolicy = "mask",
                   k_par_range: tuple[float, float] | None = None,
                   k_perp_range: tuple[float, float] | None = None,
                   name: str = "PS product") -> LeakageVoxels:
    """L_I of every voxel of the full uv plane (before averaging), or of every 2D bin.

    Parameters
    ----------
    ds : xarray.Dataset
        A PS product (docs/products.md "ps").
    source : {"voxels", "bins"}
        ``voxels`` uses ``power3d`` (stokes, delay3d, cell) and ``power3d_P_mirror``
        (:func:`voxel_power`: two P voxels per cell and delay); ``bins`` the 2D ``power``.
    k_par_range, k_perp_range : (float, float), optional
        Keep only voxels with |k_par| and k_perp inside these closed ranges (Mpc^-1).
    """
    if source == "voxels":
        p_i, p_p = voxel_power(ds, name)
        kpar = np.abs(_coord(ds, ("k_par3d",), "delay3d", name))[None, :, None]
        kperp = _coord(ds, ("k_perp_cell",), "cell", name)[None, None, :]
        L, mask = leakage_fraction(p_i, p_p, None, negative)
    elif source == "bins":
        m = leakage_map(ds, negative, name)
        L, mask = m["L_I"].values, m["mask"].values
        kpar = m["k_par"].values[:, None]
        kperp = m["k_perp"].values[None, :]
    else:
        raise InputError(f"unknown statistics source {source!r}: use 'voxels' or 'bins'")
    sel = np.broadcast_to(_in_range(kpar, k_par_range) & _in_range(kperp, k_perp_range),
                          L.shape)
    n_sel = int(sel.sum())
    if n_sel == 0:
        raise InputError(f"{name}: no {source[:-1]} inside the selected k range")
    masked = mask_summary(mask[sel])
    return LeakageVoxels(L=L[sel & (mask == 0)], n_selected=n_sel, masked=masked,
                         source=source)


def _coord(ds: xr.Dataset, names: tuple[str, ...], dim: str, source: str) -> np.ndarray:
    for n in names:
        if n in ds.variables and ds[n].dims == (dim,):
            return np.asarray(ds[n].values, dtype=float)
    raise InputError(f"{source}: lacks {' or '.join(names)} along {dim!r}")


def window_leakage(ps: xr.Dataset) -> float:
    """100 sqrt(sum P_I / sum P_P) over the cylindrical bins of the EoR window, in percent.

    The window is k_par > ``wedge_slope_horizon`` k_perp (above the horizon wedge); each
    bin counts with its number of 3D cells.  NaN if the window holds no bin with power.
    """
    slope = float(ps.attrs["wedge_slope_horizon"])
    k_par = ps["k_par"].values[:, None]
    k_perp = ps["k_perp"].values[None, :]
    n = ps["counts"].transpose("k_par", "k_perp").values
    p_i = stokes_power(ps, "power_jy2", "I").transpose("k_par", "k_perp").values
    p_p = stokes_power(ps, "power_jy2", "P").transpose("k_par", "k_perp").values
    inside = (k_par > slope * k_perp) & (n > 0) & np.isfinite(p_i) & np.isfinite(p_p)
    total_p = float(np.sum(n[inside] * p_p[inside]))
    if not total_p > 0:
        return float("nan")
    return 100.0 * np.sqrt(max(float(np.sum(n[inside] * p_i[inside])), 0.0) / total_p)
