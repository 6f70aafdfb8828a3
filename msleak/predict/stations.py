"""Per-station coordinates from a Measurement Set's own UVW column.

:func:`station_coordinates` fits, per time, station coordinates x_p (m) with
uvw_pq = x_q - x_p (p = ANTENNA1, q = ANTENNA2) by least squares over the
cross-correlation rows, and reports the rows the fit does not reproduce within
:func:`uvw_tolerance` (a phase-error bound); predict computes those rows from their own
UVW (:mod:`msleak.predict.baselines`).

The fit and the tolerance: docs/predict.md ("UVW that are not antenna-based").
"""

from __future__ import annotations

import math

import numpy as np

from msleak.constants import SPEED_OF_LIGHT

__all__ = ["station_coordinates", "uvw_tolerance", "PHASE_TOLERANCE_RAD"]

#: Largest phase error (rad) the per-station factorisation may give any source at any
#: channel: each source's term of a visibility moves by at most 1e-3 of its flux (a pure
#: phase error, its amplitude is unchanged). Float32 UVW (an MS converted from uvfits)
#: are rounded by up to 6e-8 of the baseline length, 5.7e-4 rad at 150 MHz for a 3 km
#: baseline and a source at the horizon: within it (docs/predict.md).
PHASE_TOLERANCE_RAD = 1e-3

#: Refits per time slot, each without the rows that fit worst.
_MAX_REFITS = 12

#: pseudo-inverses of baseline-graph Laplacians, keyed by the (ANTENNA1, ANTENNA2) arrays
_PINV_CACHE: dict[bytes, np.ndarray] = {}


def uvw_tolerance(freq_max_hz: float, lmn1: np.ndarray,
                  phase_rad: float = PHASE_TOLERANCE_RAD) -> float:
    """Largest |uvw_row - (x_q - x_p)| (m) giving at most ``phase_rad`` of phase error.

    Parameters
    ----------
    freq_max_hz : float
        Highest channel frequency predicted (Hz).
    lmn1 : (ndir, 3) float
        (l, m, n - 1) of the sky's directions; the farthest sets the bound.
    phase_rad : float

    Returns
    -------
    float
        phase_rad c / (2 pi freq_max r_max), r_max = max |(l, m, n - 1)|; infinite when
        every direction is the phase centre (r_max = 0: the phase does not depend on UVW).
    """
    lmn1 = np.asarray(lmn1, dtype=np.float64).reshape(-1, 3)
    reach = float(np.sqrt((lmn1 ** 2).sum(axis=1)).max()) if lmn1.size else 0.0
    if reach == 0.0:
        return math.inf
    return phase_rad * SPEED_OF_LIGHT / (2.0 * math.pi * float(freq_max_hz) * reach)


def station_coordinates(tidx: np.ndarray, p: np.ndarray, q: np.ndarray, uvw: np.ndarray,
                        ntime: int, nstation: int, *, tolerance_m: float
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Fit per-station coordinates x_p(t) to the rows' UVW (uvw_row = x_q - x_p).

    Parameters
    ----------
    tidx : (nrow,) int
        Time index (0..ntime-1) of each row.
    p, q : (nrow,) int
        Station indices (0..nstation-1) of ANTENNA1 and ANTENNA2.
    uvw : (nrow, 3) float
        The rows' UVW (m) as stored in the MS.
    ntime, nstation : int
    tolerance_m : float
        Largest |uvw_row - (x_q - x_p)| (m) of a row the coordinates stand for
        (:func:`uvw_tolerance`).

    Returns
    -------
    xyz : (ntime, nstation, 3) float64
        Station coordinates (m); stations without cross-correlations at a time get 0.
    off : (nrow,) bool
        Rows whose UVW the coordinates do not reproduce within ``tolerance_m``
        (autocorrelations: |uvw| > ``tolerance_m``; non-finite UVW); they need their own
        UVW.
    """
    tidx = np.asarray(tidx, dtype=np.int64)
    p = np.asarray(p, dtype=np.int64)
    q = np.asarray(q, dtype=np.int64)
    uvw = np.asarray(uvw, dtype=np.float64)
    xyz = np.zeros((ntime, nstation, 3))
    off = np.zeros(tidx.size, dtype=bool)
    order = np.argsort(tidx, kind="stable")
    bounds = np.searchsorted(tidx[order], np.arange(ntime + 1))
    for t in range(ntime):
        rows = order[bounds[t]:bounds[t + 1]]
        if rows.size:
            xyz[t], off[rows] = _fit_one_time(p[rows], q[rows], uvw[rows], nstation,
                                              tolerance_m)
    return xyz, off


def _fit_one_time(p, q, uvw, nstation, tolerance_m):
    """Coordinates (nstation, 3) and the rows beyond ``tolerance_m``, for one time.

    Least squares over the cross-correlations; while some fitted row is off by more than
    the tolerance, the rows off by more than half the worst (and the tolerance) are left
    out and the rest refitted. A spanning tree of rows is always fitted exactly, so only
    rows inconsistent with the others end up off."""
    use = (p != q) & np.isfinite(uvw).all(axis=1)
    x = np.zeros((nstation, 3))
    for _ in range(_MAX_REFITS):
        if not use.any():
            break
        x = _least_squares(p[use], q[use], uvw[use], nstation)
        resid = np.sqrt(((x[q] - x[p] - uvw) ** 2).sum(axis=1))
        worst = float(resid[use].max())
        if worst <= tolerance_m:
            break
        use &= resid < max(tolerance_m, 0.5 * worst)
    resid = np.sqrt(((x[q] - x[p] - uvw) ** 2).sum(axis=1))
    return x, ~(resid <= tolerance_m)


def _least_squares(p, q, uvw, nstation):
    """x minimising sum |x_q - x_p - uvw|^2, zero mean per connected group of stations."""
    # normal equations: the graph Laplacian L x = M^T uvw; its pseudo-inverse fixes the gauge
    key = p.tobytes() + q.tobytes()
    pinv = _PINV_CACHE.get(key)
    if pinv is None:
        lap = np.zeros((nstation, nstation))
        np.add.at(lap, (p, p), 1.0)
        np.add.at(lap, (q, q), 1.0)
        np.add.at(lap, (p, q), -1.0)
        np.add.at(lap, (q, p), -1.0)
        pinv = np.linalg.pinv(lap, rcond=1e-9, hermitian=True)
        if len(_PINV_CACHE) > 64:
            _PINV_CACHE.clear()
        _PINV_CACHE[key] = pinv
    rhs = np.zeros((nstation, 3))
    np.add.at(rhs, q, uvw)
    np.add.at(rhs, p, -uvw)
    return pinv @ rhs
