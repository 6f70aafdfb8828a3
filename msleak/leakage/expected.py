"""Expected leakage P_leak = (L_I / 100)^2 P_P,obs in an observed field, the bias
correction P_I,obs - P_leak with its error, and the voxels per independent sample of a
power spectrum, on arrays; formulas in docs/leakage.md ("Expected leakage", "Bias
correction")."""

from __future__ import annotations

import numpy as np

from msleak.errors import InputError

__all__ = [
    "expected_leakage_power",
    "expected_leakage_error",
    "sample_error",
    "corrected_power",
    "leakage_model_error",
    "same_grid",
    "edges_from_centres",
    "spherical_from_bins",
    "window_correlation_length",
    "correlation_factors",
]


def expected_leakage_power(p_p_obs: np.ndarray, L_model: np.ndarray | float) -> np.ndarray:
    """P_leak = (L / 100)^2 P_P,obs, element by element (broadcasting).

    Parameters
    ----------
    p_p_obs : ndarray (...)
        Observed polarized power (any unit; the result has the same unit).
    L_model : float or ndarray broadcastable to ``p_p_obs``
        Model fractional leakage, percent.
    """
    L_model = np.asarray(L_model, dtype=np.float64)
    if np.any(~np.isfinite(L_model)) or np.any(L_model < 0):
        raise InputError("the leakage model L_I must be finite and non-negative")
    return (L_model / 100.0) ** 2 * np.real(np.asarray(p_p_obs)).astype(np.float64)


def sample_error(power: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Gaussian sample-variance error |P| / sqrt(N) of a bin average of N cells (0 if N = 0)."""
    power = np.real(np.asarray(power)).astype(np.float64)
    counts = np.broadcast_to(np.asarray(counts, dtype=np.float64), power.shape)
    out = np.zeros(power.shape)
    ok = counts > 0
    out[ok] = np.abs(power[ok]) / np.sqrt(counts[ok])
    return out


def expected_leakage_error(p_p_obs: np.ndarray, counts: np.ndarray, L_model, L_err
                           ) -> np.ndarray:
    """Standard error of P_leak: sqrt((l^2 sigma_PP)^2 + (2 l sigma_l P_P)^2).

    Parameters
    ----------
    p_p_obs, counts : ndarray (...)
        Observed polarized power and the number of cells per bin.
    L_model, L_err : float or ndarray broadcastable to ``p_p_obs``
        Model leakage and its standard error, percent.
    """
    p_p = np.real(np.asarray(p_p_obs))
    l = np.asarray(L_model, dtype=np.float64) / 100.0
    sl = np.asarray(L_err, dtype=np.float64) / 100.0
    s_pp = sample_error(p_p, counts)
    return np.sqrt((l**2 * s_pp) ** 2 + (2.0 * l * sl * p_p) ** 2)


def corrected_power(p_i_obs: np.ndarray, counts: np.ndarray, p_leak: np.ndarray,
                 leak_err: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Corrected Stokes I power P_I,obs - P_leak and its standard error.

    Parameters
    ----------
    p_i_obs, counts, p_leak, leak_err : ndarray, same shape (...)
        Observed Stokes I power, cells per bin, predicted leakage power and its error.

    Returns
    -------
    corrected, error : ndarray (...)
        Zero where ``counts`` is 0.
    """
    p_i = np.real(np.asarray(p_i_obs)).astype(np.float64)
    counts = np.broadcast_to(np.asarray(counts), p_i.shape)
    s_pi = sample_error(p_i, counts)
    corrected = np.where(counts > 0, p_i - np.asarray(p_leak), 0.0)
    error = np.where(counts > 0, np.sqrt(s_pi**2 + np.asarray(leak_err) ** 2), 0.0)
    return corrected, error


def leakage_model_error(fit_median_err: float, medians: np.ndarray | None = None) -> float:
    """Uncertainty of a scalar leakage model (percent).

    The statistical error of the fitted median combined in quadrature with the spread
    (standard deviation, ddof = 1) of the medians over the fields of view, when more than
    one is given: the spread says how much L_I depends on which field of view applies.
    """
    spread = 0.0
    if medians is not None and np.size(medians) > 1:
        spread = float(np.std(np.asarray(medians, dtype=float), ddof=1))
    return float(np.hypot(fit_median_err, spread))


def same_grid(k_par_a, k_perp_a, k_par_b, k_perp_b, rtol: float = 1e-6) -> bool:
    """True if two (k_par, k_perp) grids have the same bin centres (to ``rtol``)."""
    pairs = ((k_par_a, k_par_b), (k_perp_a, k_perp_b))
    for a, b in pairs:
        a, b = np.asarray(a, float), np.asarray(b, float)
        if a.shape != b.shape or not np.allclose(a, b, rtol=rtol, atol=0.0):
            return False
    return True


def edges_from_centres(c: np.ndarray) -> np.ndarray:
    """Bin edges halfway between increasing centres, extended by half a step at the ends."""
    c = np.asarray(c, dtype=np.float64)
    if c.size == 1:
        return np.array([c[0] * 0.5, c[0] * 1.5]) if c[0] > 0 else np.array([-0.5, 0.5])
    mid = 0.5 * (c[1:] + c[:-1])
    return np.concatenate([[c[0] - (mid[0] - c[0])], mid, [c[-1] + (c[-1] - mid[-1])]])


def spherical_from_bins(power2d: np.ndarray, counts: np.ndarray, k_par: np.ndarray,
                        k_perp: np.ndarray, k_edges: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Counts-weighted spherical average of a cylindrical PS.

    Each 2D bin (k_par, k_perp) goes, with weight ``counts``, into the spherical bin
    holding k = sqrt(k_par^2 + k_perp^2).

    Parameters
    ----------
    power2d, counts : ndarray (k_par, k_perp)
    k_par, k_perp : ndarray (k_par,), (k_perp,)   Mpc^-1
    k_edges : ndarray (nk + 1,)   Mpc^-1, increasing

    Returns
    -------
    power_sph, counts_sph : ndarray (nk,)
        Weighted means (0 where no bin falls) and the summed counts.
    """
    k = np.hypot(np.asarray(k_par)[:, None], np.asarray(k_perp)[None, :])
    idx = np.digitize(k, k_edges) - 1
    nk = len(k_edges) - 1
    ok = (idx >= 0) & (idx < nk) & (np.asarray(counts) > 0)
    wsum = np.bincount(idx[ok], weights=np.asarray(counts, float)[ok], minlength=nk)
    psum = np.bincount(idx[ok], weights=(np.asarray(counts, float) * power2d)[ok],
                       minlength=nk)
    out = np.zeros(nk)
    np.divide(psum, wsum, out=out, where=wsum > 0)
    return out, wsum


def window_correlation_length(window: np.ndarray) -> float:
    """Delay bins per independent delay for white noise through a spectral window.

    N sum w^4 / (sum w^2)^2 = sum over delay lags of the power correlation
    |sum w^2 e^(2 pi i lag n / N)|^2 / (sum w^2)^2: 1 for no window, 1.98 for Hann, 2.82
    for the 4-term Blackman-Harris (50 channels).
    """
    w = np.asarray(window, dtype=np.float64)
    return float(w.size * np.sum(w**4) / np.sum(w**2) ** 2)


def correlation_factors(p3d: np.ndarray, bin_id: np.ndarray, delay_index: np.ndarray,
                        iu: np.ndarray | None = None, iv: np.ndarray | None = None,
                        max_uv_lag: int = 3, max_delay_lag: int = 5, min_bin: int = 4
                        ) -> dict:
    """Voxels per independent sample in a 2D bin and in a spherical shell, from the data.

    The power of every voxel is standardised within its 2D bin, z = (P - mean) / std
    (bins with fewer than ``min_bin`` voxels are left out), and the correlation rho of z
    is measured between every voxel and its partners: the uv cells within
    ``max_uv_lag`` cells (same delay), the same cell at delays up to ``max_delay_lag``
    bins away, and the same cell at the opposite delay (-tau). The variance of an
    average of N voxels is then (sigma^2 / N) c with

        c_2d  = 1 + sum_uv rho + rho(-tau)                        (voxels of a 2D bin:
                                                                  uv cells at +-tau)
        c_sph = 1 + sum_uv rho + sum_delay rho + rho(-tau, far)   (spherical shells)

    so N / c is the effective number of independent cells. Partners outside the bin are
    counted as if inside (c is slightly overestimated, i.e. conservative); c < 1 (noise
    in the rho estimates) is raised to 1.

    Parameters
    ----------
    p3d : ndarray (ndelay, ncell)
        Power of every voxel (real).
    bin_id : ndarray (ndelay, ncell) int
        2D bin of every voxel (any labels; negative: not used).
    delay_index : ndarray (ndelay,) int
        Signed integer delay of every row (k of tau_k = k / (N dnu)).
    iu, iv : ndarray (ncell,) int, optional
        uv grid position of every cell, in cells; without them no uv lags are used.

    Returns
    -------
    dict
        ``c_2d``, ``c_sph`` (floats >= 1), ``rho_uv`` (sum over uv lags), ``rho_delay``
        (sum over delay lags), ``rho_mirror``.
    """
    rho = _bin_correlation(p3d, bin_id, min_bin)
    rows = {int(k): r for r, k in enumerate(np.asarray(delay_index).ravel())}
    rho_uv = 0.0
    if iu is not None and iv is not None and np.shape(p3d)[1] > 1:
        rho_uv = _uv_correlation(rho, iu, iv, max_uv_lag)
    rho_delay = 0.0
    for lag in range(1, max_delay_lag + 1):
        pairs = [(r, rows[k + lag]) for k, r in rows.items() if k + lag in rows]
        if pairs:
            ra, rb = np.array(pairs).T
            rho_delay += 2.0 * rho(ra, rb)
    mirror = np.array([(r, rows[-k], k) for k, r in rows.items() if k > 0 and -k in rows],
                      dtype=np.int64).reshape(-1, 3)
    far = mirror[2 * mirror[:, 2] > max_delay_lag]
    rho_mirror = rho(mirror[:, 0], mirror[:, 1]) if len(mirror) else 0.0
    rho_far = rho(far[:, 0], far[:, 1]) if len(far) else 0.0
    c_2d = max(1.0, 1.0 + rho_uv + rho_mirror)
    c_sph = max(1.0, 1.0 + rho_uv + rho_delay + rho_far)
    return {"c_2d": c_2d, "c_sph": c_sph, "rho_uv": rho_uv, "rho_delay": rho_delay,
            "rho_mirror": rho_mirror}


def _bin_correlation(p3d: np.ndarray, bin_id: np.ndarray, min_bin: int):
    """``rho(sel_a, sel_b)``: the mean product of the voxel powers standardised within
    their 2D bin, over the voxel pairs (sel_a[i], sel_b[i]) (0 for fewer than 10 pairs)."""
    p = np.real(np.asarray(p3d, dtype=np.complex128 if np.iscomplexobj(p3d) else float))
    b = np.asarray(bin_id)
    ok = (b >= 0) & np.isfinite(p)
    _, lab = np.unique(np.where(ok, b, -1), return_inverse=True)
    lab = lab.reshape(p.shape)
    nb = int(lab.max()) + 1
    w = ok.astype(float)
    cnt = np.bincount(lab.ravel(), weights=w.ravel(), minlength=nb)
    pz = np.where(ok, p, 0.0)
    mean = np.bincount(lab.ravel(), weights=pz.ravel(), minlength=nb) / np.maximum(cnt, 1)
    var = np.bincount(lab.ravel(), weights=(w * (pz - mean[lab]) ** 2).ravel(),
                      minlength=nb) / np.maximum(cnt - 1, 1)
    good = (cnt >= min_bin) & (var > 0)
    z = np.full(p.shape, np.nan)
    use = ok & good[lab]
    z[use] = (p[use] - mean[lab][use]) / np.sqrt(var[lab][use])
    # standardising within a bin makes two independent voxels of the same bin correlate
    # by -1/(n - 1); that bias is added back pair by pair
    bias = 1.0 / np.maximum(cnt - 1, 1)

    def rho(sel_a, sel_b) -> float:
        prod = z[sel_a] * z[sel_b] + np.where(lab[sel_a] == lab[sel_b], bias[lab[sel_a]], 0)
        prod = prod[np.isfinite(prod)]
        return float(prod.mean()) if prod.size >= 10 else 0.0

    return rho


def _uv_correlation(rho, iu: np.ndarray, iv: np.ndarray, max_uv_lag: int) -> float:
    """Sum of ``rho`` over the uv lags within ``max_uv_lag`` cells (same delay)."""
    iu = np.asarray(iu, np.int64) - int(np.min(iu))
    iv = np.asarray(iv, np.int64) - int(np.min(iv))
    span = int(iv.max()) + 2 * max_uv_lag + 1
    key = iu * span + iv
    order = np.argsort(key)
    skey = key[order]
    total = 0.0
    for du in range(0, max_uv_lag + 1):
        for dv in range(-max_uv_lag, max_uv_lag + 1):
            if (du == 0 and dv <= 0) or du * du + dv * dv > max_uv_lag**2:
                continue               # half of the lags; the other half mirrors them
            want = key + du * span + dv
            pos = np.clip(np.searchsorted(skey, want), 0, skey.size - 1)
            has = skey[pos] == want
            if has.any():
                total += 2.0 * rho((slice(None), has), (slice(None), order[pos[has]]))
    return total
