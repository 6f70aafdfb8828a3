"""The smallest leakage an observation's thermal noise lets one detect (docs/paper.md, "The
instrument's budget").

The noisy power spectra are even/odd cross powers of the sky plus noise; their difference
from the noiseless spectrum of the same sky is what the noise adds to P_I, zero on average,
with a scatter that depends on the uv cell (how many samples it holds) and not on the delay
(the noise is white across the band). Pooled over the delays and the noise realisations,
it gives the noise's rms sigma_I per cell; a voxel's leaked P_I is detected at ``nsigma``
when it exceeds ``nsigma sigma_I``, i.e. when its L_I exceeds
``L_min = 100 sqrt(nsigma sigma_I / P_P)`` (P_P the noiseless sky's polarized power there).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import xarray as xr

from msleak.errors import InputError
from msleak.leakage.fraction import voxel_power

__all__ = ["detectable_leakage", "noise_sigma_per_cell"]


def noise_sigma_per_cell(ideal: xr.Dataset, noisy: Sequence[xr.Dataset]) -> np.ndarray:
    """rms (cell,) over delays and realisations of P_I(noisy) - P_I(ideal) of each uv cell
    of ``ideal`` (``power3d`` units); cells are matched by their (u, v) (``u_cell``,
    ``v_cell``; an even/odd cube keeps only the cells both halves fill), NaN where no noisy
    spectrum has the cell."""
    return _sigma(ideal, voxel_power(ideal, "noiseless PS")[0][0], noisy)


def _sigma(ideal: xr.Dataset, p_i0: np.ndarray, noisy: Sequence[xr.Dataset]) -> np.ndarray:
    """:func:`noise_sigma_per_cell` with the noiseless P_I (delay, cell) ``p_i0`` given."""
    if not noisy:
        raise InputError("detectable leakage needs at least one noisy power spectrum")
    cells0 = _cells(ideal, p_i0.shape[1])
    total = np.zeros(p_i0.shape[1])
    count = np.zeros(p_i0.shape[1])
    for k, ds in enumerate(noisy):
        p_i = voxel_power(ds, f"noisy PS {k + 1}")[0][0]
        index = [cells0.get(c, -1) for c in _cells(ds, p_i.shape[1])]
        if p_i.shape[0] != p_i0.shape[0] or min(index, default=0) < 0:
            raise InputError(f"noisy PS {k + 1} has {p_i.shape} (delay, cell) voxels, not "
                             f"within the noiseless one's {p_i0.shape}: grid both alike")
        delta = p_i - p_i0[:, index]
        good = np.isfinite(delta)
        np.add.at(total, index, (np.where(good, delta, 0.0) ** 2).sum(axis=0))
        np.add.at(count, index, good.sum(axis=0))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(np.where(count > 0, total / count, np.nan))


def _cells(ds: xr.Dataset, ncell: int) -> dict:
    """{(u, v) of a cell: its index} (u_cell, v_cell in wavelengths; by index without)."""
    if "u_cell" in ds.variables and "v_cell" in ds.variables:
        uv = zip(np.round(ds["u_cell"].values, 6), np.round(ds["v_cell"].values, 6))
        return {(float(u), float(v)): k for k, (u, v) in enumerate(uv)}
    return {k: k for k in range(ncell)}


def detectable_leakage(ideal: xr.Dataset, noisy: Sequence[xr.Dataset],
                       nsigma: float = 3.0) -> np.ndarray:
    """L_min (%) of every voxel of ``ideal`` with polarized power, (n,) flat: the L_I whose
    leaked P_I stands ``nsigma`` times above the noise's rms in its uv cell
    (:func:`noise_sigma_per_cell`). Voxels as in the L_I statistics (both (u, tau) and
    (-u, -tau) of every cell and delay)."""
    if not nsigma > 0:
        raise InputError(f"nsigma must be positive, got {nsigma}", param="nsigma")
    p_i, p_p = voxel_power(ideal, "noiseless PS")
    sigma = _sigma(ideal, p_i[0], noisy)
    with np.errstate(divide="ignore", invalid="ignore"):
        l_min = 100.0 * np.sqrt(nsigma * sigma[None, None, :] / p_p)
    return l_min[(p_p > 0) & np.isfinite(l_min)]
