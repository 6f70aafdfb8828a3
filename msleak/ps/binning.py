"""Power-spectrum averages: cylindrical (|b| annuli x folded delay), spherical and 1D.

All functions take the unaveraged 3D power of the used uv cells of one Hermitian half,
``p3d`` of shape (stokes, delay, cell), with signed delays in fftshift order. Averages
are plain means over the 3D voxels in a bin (docs/ps.md); ``counts`` is the number
of voxels averaged (a folded delay bin counts both the +tau and the -tau voxel). For
P = Q + iU, which is not Hermitian, each voxel (u, tau) of the half stands for a pair
with its mirror (-u, -tau) (:func:`mirror_polarized_power`, :func:`pair_mean`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msleak.errors import InputError

__all__ = ["half_plane", "power_3d", "mirror_polarized_power", "pair_mean", "fold_index",
           "linear_edges", "log_edges", "Cylindrical", "cylindrical_average",
           "spherical_average", "average_1d"]


def half_plane(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Mask of the Hermitian half: ``u > 0``, or ``u == 0`` and ``v > 0``."""
    return (u > 0) | ((u == 0) & (v > 0))


def power_3d(vt: np.ndarray, vt_b: np.ndarray | None = None,
             window_norm: float = 1.0) -> np.ndarray:
    """``|V~|^2 / window_norm``, or ``Re(V~_a conj(V~_b)) / window_norm`` for two halves."""
    if vt_b is None:
        p = vt.real ** 2 + vt.imag ** 2
    else:
        p = (vt * np.conj(vt_b)).real
    return p / window_norm


def mirror_polarized_power(vt: np.ndarray, vt_b: np.ndarray | None, stokes: list,
                           window_norm: float = 1.0) -> np.ndarray | None:
    """Power of P = Q + iU in the mirrored voxel (-u, -tau) of every voxel (u, tau).

    P is not Hermitian, so the full uv plane holds two P voxels per Hermitian pair of
    Stokes I voxels. For Hermitian Q and U (a real sky; both gridders and the image path
    make them so) and a real spectral window, Q~(-u, -tau) = conj(Q~(u, tau)) whatever the
    FFT sign, hence P~(-u, -tau) = conj(Q~(u, tau) - i U~(u, tau)) and

        |P~(-u, -tau)|^2 = |Q~(u, tau) - i U~(u, tau)|^2,

    or Re(M~_a conj(M~_b)) with M~ = Q~ - i U~ for the cross-power of two halves.

    Parameters
    ----------
    vt, vt_b : (stokes, delay, cell) complex
        Delay-transformed visibilities of the cells (u, tau) (``vt_b``: second half, or
        None for the auto-power).
    stokes : list of str
        Labels of the first axis.

    Returns
    -------
    (delay, cell) float, or None when Q, U or P is not among ``stokes``.
    """
    if not {"P", "Q", "U"} <= set(stokes):
        return None
    q, u = stokes.index("Q"), stokes.index("U")
    m = vt[q] - 1j * vt[u]
    if vt_b is None:
        return power_3d(m, None, window_norm)
    return power_3d(m, vt_b[q] - 1j * vt_b[u], window_norm)


def pair_mean(p3d: np.ndarray, p_mirror: np.ndarray | None, stokes: list) -> np.ndarray:
    """``p3d`` with its P entry replaced by the mean over each pair (u, tau), (-u, -tau).

    The bin averages of P are means over both voxels of every pair (every bin holds both:
    they share |b| and |tau|). The pair mean equals P_Q + P_U of the voxel (u, tau)
    identically (Hermitian Q and U). Without ``p_mirror`` the input is returned.
    """
    if p_mirror is None:
        return p3d
    out = np.array(p3d, copy=True)
    ip = stokes.index("P")
    out[ip] = 0.5 * (p3d[ip] + p_mirror)
    return out


def fold_index(delay: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map signed delays to folded bins.

    Returns
    -------
    folded : (nfold,) float
        |delay| values, 0 first.
    index : (delay,) int
        Folded bin of every signed delay.
    """
    mag = np.abs(np.asarray(delay, dtype=float))
    scale = np.max(mag) if mag.size and np.max(mag) > 0 else 1.0
    folded, index = np.unique(np.round(mag / scale, 9), return_inverse=True)
    values = np.array([mag[index == i].mean() for i in range(folded.size)])
    return values, index.ravel()


def linear_edges(lo: float, hi: float, n: int) -> np.ndarray:
    if not (hi > lo) or n < 1:
        raise InputError(f"bad bin range {lo}..{hi} with {n} bins")
    return np.linspace(lo, hi, n + 1)


def log_edges(lo: float, hi: float, n: int) -> np.ndarray:
    if not (hi > lo > 0) or n < 1:
        raise InputError(f"bad logarithmic bin range {lo}..{hi} with {n} bins")
    return np.geomspace(lo, hi, n + 1)


@dataclass(frozen=True)
class Cylindrical:
    """A cylindrical average: ``power`` (stokes, k_par, k_perp), ``counts`` (k_par, k_perp)."""

    power: np.ndarray
    counts: np.ndarray
    folded_delay: np.ndarray
    perp_centres: np.ndarray


def _bin_of(x: np.ndarray, edges: np.ndarray) -> np.ndarray:
    idx = np.searchsorted(edges, x, side="right") - 1
    idx[(x == edges[-1])] = edges.size - 2
    idx[(x < edges[0]) | (x > edges[-1])] = -1
    return idx


def cylindrical_average(p3d: np.ndarray, delay: np.ndarray, b_cell: np.ndarray,
                        edges: np.ndarray) -> Cylindrical:
    """Average ``p3d`` (stokes, delay, cell) in |b| annuli and folded delays.

    Parameters
    ----------
    p3d : (stokes, delay, cell) float
    delay : (delay,) float, s (signed)
    b_cell : (cell,) float
        |b| of each cell (any unit; ``edges`` in the same unit).
    edges : (nbin + 1,) float

    Returns
    -------
    Cylindrical
        Empty bins hold NaN power and 0 counts; ``perp_centres`` are the arithmetic bin
        centres.
    """
    folded, fidx = fold_index(delay)
    bidx = _bin_of(np.asarray(b_cell, dtype=float), edges)
    nperp, nfold = edges.size - 1, folded.size
    ok_cell = bidx >= 0
    flat = (fidx[:, None] * nperp + bidx[None, :])[:, ok_cell].ravel()  # (delay*cell,)
    size = nfold * nperp
    counts = np.bincount(flat, minlength=size).reshape(nfold, nperp)
    power = np.empty((p3d.shape[0], nfold, nperp))
    for s in range(p3d.shape[0]):
        sums = np.bincount(flat, p3d[s][:, ok_cell].ravel(), minlength=size)
        with np.errstate(invalid="ignore", divide="ignore"):
            power[s] = np.where(counts > 0, sums.reshape(nfold, nperp) / counts, np.nan)
    return Cylindrical(power, counts, folded, 0.5 * (edges[1:] + edges[:-1]))


def spherical_average(p3d: np.ndarray, k_par_signed: np.ndarray, k_perp_cell: np.ndarray,
                      edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Average ``p3d`` (stokes, delay, cell) in shells of k = sqrt(k_perp^2 + k_par^2).

    Returns ``(power (stokes, nbin), counts (nbin,))``; empty bins are NaN.
    """
    k = np.sqrt(np.asarray(k_par_signed)[:, None] ** 2 + np.asarray(k_perp_cell)[None, :] ** 2)
    idx = _bin_of(k.ravel(), edges)
    ok = idx >= 0
    nb = edges.size - 1
    counts = np.bincount(idx[ok], minlength=nb)
    power = np.empty((p3d.shape[0], nb))
    for s in range(p3d.shape[0]):
        sums = np.bincount(idx[ok], p3d[s].ravel()[ok], minlength=nb)
        with np.errstate(invalid="ignore", divide="ignore"):
            power[s] = np.where(counts > 0, sums / counts, np.nan)
    return power, counts


def average_1d(p3d: np.ndarray, delay: np.ndarray, k_perp_cell: np.ndarray,
               k_perp_min: float, k_perp_max: float) -> tuple[np.ndarray, np.ndarray]:
    """Average over cells with k_perp in [min, max] per folded delay.

    Returns ``(power (stokes, nfold), counts (nfold,))``.
    """
    sel = (np.asarray(k_perp_cell) >= k_perp_min) & (np.asarray(k_perp_cell) <= k_perp_max)
    folded, fidx = fold_index(delay)
    nf = folded.size
    counts = np.bincount(fidx, minlength=nf) * int(sel.sum())
    power = np.empty((p3d.shape[0], nf))
    for s in range(p3d.shape[0]):
        sums = np.bincount(fidx, p3d[s][:, sel].sum(axis=1), minlength=nf)
        with np.errstate(invalid="ignore", divide="ignore"):
            power[s] = np.where(counts > 0, sums / counts, np.nan)
    return power, counts
