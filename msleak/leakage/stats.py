"""Statistics of the voxel distribution of L_I and its Pareto (b = 1) model: mean, median,
histogram peak, maximum-likelihood and histogram fits of W = (L_I / 100)^2, the
Kolmogorov-Smirnov distance of the fit, and the per-field estimate. The model, the fit
and measurements of both are in docs/leakage.md ("Pareto model", "Fit") and
docs/science.md."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy import stats
from scipy.optimize import brentq, minimize

from msleak.errors import InputError
from msleak.leakage.bootstrap import BootstrapErrors, bootstrap_errors

__all__ = [
    "ParetoFit",
    "LeakageStatistics",
    "BootstrapErrors",
    "bootstrap_errors",
    "pareto_ks",
    "fit_pareto",
    "fit_pareto_histogram",
    "histogram_edges",
    "view_histogram",
    "leakage_statistics",
    "pareto_density_percent",
    "field_estimate",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ParetoFit:
    """Pareto (shape 1) model of W = (L_I / 100)^2.

    Attributes
    ----------
    loc, scale : float
        ``scipy.stats.pareto`` parameters (b = 1), dimensionless (units of W).
    median_w : float
        Model median of W, loc + 2 scale.
    median_err_w : float
        Its asymptotic standard error under the model, scale sqrt(3 / n).
    method : str
        ``"ml-scipy"``, ``"ml-root"`` (score-equation root), ``"histogram"`` or
        ``"degenerate"`` (half or more of the values equal: scale = 0, the model does not
        apply and the median of the model equals the sample minimum).
    n : int
        Number of samples used.
    """

    loc: float
    scale: float
    median_w: float
    median_err_w: float
    method: str
    n: int

    @property
    def median_percent(self) -> float:
        """Median L_I of the model, 100 sqrt(median of W), percent."""
        return 100.0 * float(np.sqrt(max(self.median_w, 0.0)))

    @property
    def median_err_percent(self) -> float:
        """Standard error of :attr:`median_percent` (delta method), percent."""
        if self.median_w <= 0:
            return 0.0
        return 100.0 * self.median_err_w / (2.0 * np.sqrt(self.median_w))


def _check_w(w: np.ndarray) -> np.ndarray:
    w = np.asarray(w, dtype=np.float64).ravel()
    if w.size < 2:
        raise InputError(f"a Pareto fit needs at least 2 valid voxels, got {w.size}")
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise InputError("W = P_I / P_P must be finite and non-negative for the Pareto fit")
    return w


def _score(s: float, d: np.ndarray) -> float:
    """sum s / (d + s) / n - 1/2: the scaled profile score (zero at the MLE)."""
    return float(np.mean(s / (d + s))) - 0.5


def fit_pareto(w: np.ndarray, use_scipy: bool = True) -> ParetoFit:
    """Maximum-likelihood Pareto (b = 1) fit of loc and scale to a sample of W.

    Parameters
    ----------
    w : ndarray (n,)
        Samples of W = P_I / P_P (>= 0, finite).
    use_scipy : bool
        Try ``scipy.stats.pareto.fit(w, fb=1)`` first (verified against the score
        equation); if False, or if scipy's answer fails the check, solve the score
        equation directly.

    Returns
    -------
    ParetoFit
    """
    w = _check_w(w)
    n = w.size
    wmin = float(w.min())
    d = w - wmin
    n0 = int(np.count_nonzero(d == 0))
    if 2 * n0 >= n:
        log.warning("%d of %d values of W equal its minimum: the Pareto model does not apply "
                    "(degenerate fit, median = minimum)", n0, n)
        return ParetoFit(wmin, 0.0, wmin, 0.0, "degenerate", n)
    s0 = float(np.median(d))
    if use_scipy:
        try:
            _, loc, scale = stats.pareto.fit(w, fb=1, loc=wmin - s0, scale=s0)
            loc, scale = float(loc), float(scale)
            ok = (np.isfinite(loc) and np.isfinite(scale) and scale > 0
                  and abs(loc + scale - wmin) <= 1e-9 * max(scale, abs(wmin))
                  and abs(_score(scale, d)) < 1e-6)
        except Exception as err:  # noqa: BLE001 - any optimiser failure -> root finder
            log.debug("scipy pareto.fit failed (%s); solving the score equation", err)
            ok = False
        if ok:
            return ParetoFit(loc, scale, loc + 2 * scale, scale * np.sqrt(3.0 / n),
                             "ml-scipy", n)
        log.debug("scipy pareto.fit did not reach the MLE; solving the score equation")
    # score(s) increases from n0/n - 1/2 < 0 (s -> 0) to 1/2 (s -> inf): bracket the root
    lo = hi = s0 if s0 > 0 else float(d[d > 0].min())
    while _score(lo, d) > 0:
        lo /= 10.0
    while _score(hi, d) < 0:
        hi *= 10.0
    s = float(brentq(_score, lo, hi, args=(d,), xtol=1e-14 * hi, rtol=1e-13, maxiter=500))
    return ParetoFit(wmin - s, s, wmin + s, s * np.sqrt(3.0 / n), "ml-root", n)


def fit_pareto_histogram(w: np.ndarray, edges_w: np.ndarray) -> ParetoFit:
    """Binned maximum-likelihood fit of the Pareto (b = 1) model to a histogram of W.

    The expected count of bin j is n (F(e_{j+1}) - F(e_j)) with n the total number of
    samples (values outside the edges count in n, so a truncated histogram is fitted
    correctly); the Poisson deviance of the counts is minimised over (loc, scale) with
    Nelder-Mead, which copes with the kink of the likelihood where the support edge
    loc + scale crosses a bin edge (a gradient method stalls there).

    Parameters
    ----------
    w : ndarray (n,)
        Samples of W.
    edges_w : ndarray (nbin + 1,)
        Increasing bin edges in W.
    """
    w = _check_w(w)
    n = w.size
    counts, _ = np.histogram(w, edges_w)
    med = float(np.median(w))
    if med <= 0:
        raise InputError("the median of W is 0: no histogram fit possible")

    def params(p):
        scale = float(np.exp(p[1])) * med
        return p[0] * med - scale, scale  # p[0]: support edge loc + scale in units of med

    def deviance(p):
        loc, scale = params(p)
        expected = np.maximum(n * np.diff(stats.pareto.cdf(edges_w, 1, loc=loc,
                                                           scale=scale)), 1e-300)
        safe = np.maximum(counts, 1)
        return 2.0 * float(np.sum(expected - counts
                                  + np.where(counts > 0, counts * np.log(safe / expected), 0)))

    res = minimize(deviance, x0=[0.0, 0.0], method="Nelder-Mead",
                   options={"xatol": 1e-8, "fatol": 1e-9, "maxiter": 4000,
                            "initial_simplex": [[0.0, 0.0], [0.05, 0.0], [0.0, 0.05]]})
    if not res.success:
        raise InputError(f"the histogram Pareto fit did not converge ({res.message})")
    loc, scale = params(res.x)
    return ParetoFit(loc, scale, loc + 2 * scale, scale * np.sqrt(3.0 / n), "histogram", n)


def pareto_ks(w: np.ndarray, fit: ParetoFit, n_eff: float | None = None
              ) -> tuple[float, float, float]:
    """Kolmogorov-Smirnov distance of a sample of W from its fitted Pareto model.

    Parameters
    ----------
    w : ndarray (n,)
        Samples of W = (L_I / 100)^2.
    fit : ParetoFit
        The model (loc, scale; b = 1).
    n_eff : float, optional
        Effective number of independent samples for a second p-value.

    Returns
    -------
    D : float
        sup |F_sample - F_model|.
    p : float
        p-value of D for n independent samples (scipy.stats.kstwo). Two biases act in
        opposite directions: correlated voxels make D fluctuate more than for n
        independent ones (p too small), parameters fitted to the same sample make it
        fluctuate less (p too large, Lilliefors). Read p as a warning sign only; D
        itself is the size of the misfit.
    p_eff : float
        The same for ``n_eff`` samples (NaN if not given).
    """
    w = np.sort(np.asarray(w, dtype=np.float64).ravel())
    n = w.size
    if fit.scale <= 0 or n == 0:
        return 0.0, 1.0, float("nan") if n_eff is None else 1.0
    cdf = stats.pareto.cdf(w, 1, loc=fit.loc, scale=fit.scale)
    i = np.arange(1, n + 1)
    D = float(max(np.max(i / n - cdf), np.max(cdf - (i - 1) / n)))
    p = float(stats.kstwo.sf(D, n))
    p_eff = float("nan")
    if n_eff is not None:
        ne = int(max(1, round(min(n_eff, n))))
        p_eff = float(stats.kstwo.sf(D, ne))
    return D, p, p_eff


def histogram_edges(L: np.ndarray, bins: int = 100, upper_quantile: float = 0.99,
                    upper: float | None = None) -> np.ndarray:
    """Uniform L_I bin edges from 0 to ``upper`` (default: the ``upper_quantile`` of L)."""
    if bins < 2:
        raise InputError(f"need at least 2 histogram bins, got {bins}")
    if upper is None:
        upper = float(np.quantile(L, upper_quantile)) if np.size(L) else 0.0
    if not np.isfinite(upper) or upper <= 0:
        upper = float(np.max(L)) if np.size(L) and np.max(L) > 0 else 1.0
    return np.linspace(0.0, upper, bins + 1)


def view_histogram(L: np.ndarray, bins: int = 100, quantile: float = 0.95
                   ) -> tuple[np.ndarray, np.ndarray, int]:
    """The histogram a figure shows of a heavy-tailed sample: ``bins`` uniform bins from
    0 to the ``quantile`` of ``L``, and how many values lie beyond (the statistics use
    every value; only the view is cut).

    Returns
    -------
    counts : ndarray (bins,)
    edges : ndarray (bins + 1,)
    n_beyond : int
        Values above ``edges[-1]``.
    """
    L = np.asarray(L, dtype=np.float64).ravel()
    edges = histogram_edges(L, bins, quantile)
    counts, _ = np.histogram(L, edges)
    return counts, edges, int(np.count_nonzero(L > edges[-1]))


@dataclass(frozen=True)
class LeakageStatistics:
    """Statistics of one input's voxel L_I distribution (percent unless stated).

    ``peak`` is the centre of the fullest bin of ``hist_counts`` over ``hist_edges``
    (``bins`` uniform bins from 0 to the ``upper_quantile`` of L_I); ``peak_bin_width``
    is the bin width. ``fit`` is the maximum-likelihood model, ``fit_hist`` the histogram
    fit (for comparison; ``None`` if it failed). ``boot`` holds the block-bootstrap
    errors, ``ks_d``, ``ks_p`` and ``ks_p_eff`` the Kolmogorov-Smirnov test of the model
    (:func:`pareto_ks`) and ``n_eff`` the effective number of independent voxels.
    """

    mean: float
    median: float
    std: float
    peak: float
    peak_bin_width: float
    fit: ParetoFit
    fit_hist: ParetoFit | None
    hist_counts: np.ndarray
    hist_edges: np.ndarray
    n: int
    boot: BootstrapErrors | None = None
    ks_d: float = 0.0
    ks_p: float = 1.0
    ks_p_eff: float = 1.0
    n_eff: float = 0.0

    @property
    def pareto_median(self) -> float:
        return self.fit.median_percent

    @property
    def pareto_median_err(self) -> float:
        """Bootstrap error of the fitted median (the asymptotic one without bootstrap)."""
        if self.boot is None or self.boot.n_boot == 0:
            return self.fit.median_err_percent
        return self.boot.pareto_median

    @property
    def median_err(self) -> float:
        return 0.0 if self.boot is None else self.boot.median

    @property
    def mean_err(self) -> float:
        return 0.0 if self.boot is None else self.boot.mean


def leakage_statistics(L: np.ndarray, bins: int = 100, upper_quantile: float = 0.99,
                       use_scipy: bool = True, groups: np.ndarray | None = None,
                       n_boot: int = 200, seed: int = 0) -> LeakageStatistics:
    """Mean, median, standard deviation, histogram peak and Pareto fit of L_I voxels,
    with block-bootstrap errors and a Kolmogorov-Smirnov test of the model.

    Parameters
    ----------
    L : ndarray (n,)
        Valid L_I values in percent (masked voxels already removed).
    bins, upper_quantile : int, float
        Histogram binning for the peak: ``bins`` uniform bins on [0, quantile].
    groups : ndarray (n,), optional
        Bootstrap group (uv cell or block of cells) of every voxel; default: each voxel
        alone (iid bootstrap), which underestimates the errors of correlated voxels.
    n_boot, seed : int
        Bootstrap resamples (0: none; the errors are then the asymptotic iid ones for the
        fit and 0 for the rest) and their seed.
    """
    L = np.asarray(L, dtype=np.float64).ravel()
    if L.size < 2:
        raise InputError(f"only {L.size} valid voxel(s): cannot compute statistics")
    edges = histogram_edges(L, bins, upper_quantile)
    counts, _ = np.histogram(L, edges)
    k = int(np.argmax(counts))
    w = (L / 100.0) ** 2
    fit = fit_pareto(w, use_scipy=use_scipy)
    fit_hist = None
    if fit.method != "degenerate":
        try:
            fit_hist = fit_pareto_histogram(w, (edges / 100.0) ** 2)
        except Exception as err:  # noqa: BLE001 - the comparison fit is optional
            log.warning("histogram Pareto fit failed: %s", err)
    peak = float(0.5 * (edges[k] + edges[k + 1]))
    if np.ptp(L) <= 1e-12 * np.max(np.abs(L)):
        peak = float(np.median(L))  # one value (to rounding): the histogram has no shape
    boot = bootstrap_errors(L, groups, n_boot, seed,
                            scale_hint=fit.scale if fit.scale > 0 else None)
    n_eff = float(L.size)
    if boot.n_boot and boot.pareto_median > 0 and fit.median_err_percent > 0:
        n_eff = min(float(L.size), L.size * (fit.median_err_percent / boot.pareto_median) ** 2)
    ks_d, ks_p, ks_p_eff = pareto_ks(w, fit, n_eff)
    if fit.method != "degenerate" and ks_p_eff < 1e-3:
        log.warning("the Pareto model does not describe the L_I distribution (KS D = %.3g, "
                    "p = %.2g for %d effective voxels): prefer the data median", ks_d,
                    ks_p_eff, round(n_eff))
    return LeakageStatistics(
        mean=float(L.mean()), median=float(np.median(L)), std=float(L.std(ddof=1)),
        peak=peak, peak_bin_width=float(edges[1] - edges[0]),
        fit=fit, fit_hist=fit_hist, hist_counts=counts, hist_edges=edges, n=L.size,
        boot=boot, ks_d=ks_d, ks_p=ks_p, ks_p_eff=ks_p_eff, n_eff=n_eff)


def pareto_density_percent(l: np.ndarray, fit: ParetoFit) -> np.ndarray:
    """Model probability density of L_I (per percent) at ``l`` (percent), shape of ``l``.

    f_L(l) = f_W(w) dw/dl with w = (l / 100)^2, dw/dl = 2 l / 100^2.
    """
    l = np.asarray(l, dtype=np.float64)
    if fit.scale <= 0:
        return np.zeros_like(l)
    w = (l / 100.0) ** 2
    return stats.pareto.pdf(w, 1, loc=fit.loc, scale=fit.scale) * 2.0 * l / 100.0**2


def field_estimate(medians: np.ndarray) -> tuple[float, float]:
    """Per-field estimate: the mean of the medians over fields of view, and their spread.

    Returns
    -------
    mean, std : float
        Mean of ``medians`` and their standard deviation (ddof = 1; 0 for one value).
    """
    m = np.asarray(medians, dtype=np.float64)
    return float(m.mean()), float(m.std(ddof=1)) if m.size > 1 else 0.0
