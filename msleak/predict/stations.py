"""Per-station coordinates from a Measurement Set's own UVW column.

The factorised predict needs, for every time, station coordinates x_p (m) with

    uvw_pq = x_q - x_p      (p = ANTENNA1, q = ANTENNA2 of the row)

so that exp(+2 pi i uvw_pq . s / lambda) = exp(-2 pi i x_p . s / lambda) exp(+2 pi i x_q . s / lambda)
(the MS convention: antenna 2 minus antenna 1; see :mod:`msleak.predict.kernels` for the
sign of the phase). Such x_p exist for any MS whose UVW were computed from antenna
positions (casacore, CASA, DP3, msleak simulate). The coordinates are fitted by least
squares over all cross-correlation rows of one time (the gauge, a common offset per
connected group of stations, cancels in every baseline) and the fit residual is checked,
so a UVW column that is not antenna-based is refused instead of silently mispredicted.
"""

from __future__ import annotations

import numpy as np

from msleak.errors import InputError

__all__ = ["station_coordinates", "UVW_TOLERANCE_M"]

#: Largest accepted |uvw_row - (x_q - x_p)| (m): 0.1 mm is a phase error below 1e-3 rad
#: up to 500 MHz even at the horizon.
UVW_TOLERANCE_M = 1e-4

#: pseudo-inverses of baseline-graph Laplacians, keyed by the (ANTENNA1, ANTENNA2) arrays
_PINV_CACHE: dict[bytes, np.ndarray] = {}


def station_coordinates(tidx: np.ndarray, p: np.ndarray, q: np.ndarray, uvw: np.ndarray,
                        ntime: int, nstation: int, *,
                        tolerance_m: float = UVW_TOLERANCE_M) -> np.ndarray:
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
        Largest accepted residual (m).

    Returns
    -------
    (ntime, nstation, 3) float64
        Station coordinates (m); stations without cross-correlations at a time get 0.

    Raises
    ------
    InputError
        If the UVW of some time are not the differences of per-station coordinates.
    """
    tidx = np.asarray(tidx, dtype=np.int64)
    p = np.asarray(p, dtype=np.int64)
    q = np.asarray(q, dtype=np.int64)
    uvw = np.asarray(uvw, dtype=np.float64)
    xyz = np.zeros((ntime, nstation, 3))
    cross = p != q
    order = np.argsort(tidx, kind="stable")
    bounds = np.searchsorted(tidx[order], np.arange(ntime + 1))
    worst = 0.0
    for t in range(ntime):
        rows = order[bounds[t]:bounds[t + 1]]
        rows = rows[cross[rows]]
        if rows.size == 0:
            continue
        pt, qt = p[rows], q[rows]
        # normal equations of uvw_row = x_q - x_p: the graph Laplacian L x = M^T uvw;
        # its pseudo-inverse fixes the gauge (zero mean per connected group)
        key = pt.tobytes() + qt.tobytes()
        pinv = _PINV_CACHE.get(key)
        if pinv is None:
            lap = np.zeros((nstation, nstation))
            np.add.at(lap, (pt, pt), 1.0)
            np.add.at(lap, (qt, qt), 1.0)
            np.add.at(lap, (pt, qt), -1.0)
            np.add.at(lap, (qt, pt), -1.0)
            pinv = np.linalg.pinv(lap, rcond=1e-9, hermitian=True)
            if len(_PINV_CACHE) > 64:
                _PINV_CACHE.clear()
            _PINV_CACHE[key] = pinv
        rhs = np.zeros((nstation, 3))
        np.add.at(rhs, qt, uvw[rows])
        np.add.at(rhs, pt, -uvw[rows])
        x = pinv @ rhs
        resid = np.abs(x[qt] - x[pt] - uvw[rows]).max()
        worst = max(worst, float(resid))
        xyz[t] = x
    if worst > tolerance_m:
        raise InputError(
            f"the MS UVW column is not antenna-based (baseline UVW differ from differences of "
            f"per-station coordinates by up to {worst:.3g} m > {tolerance_m:g} m); msleak's "
            "factorised predict needs UVW computed from antenna positions")
    return xyz
