"""Errors of correlated voxels: block bootstrap, KS goodness of fit, effective cell counts."""

import csv

import numpy as np
import pytest

from msleak.errors import InputError
from msleak.leakage import analyse, fit_pareto, leakage_statistics
from msleak.leakage.analysis import voxel_groups
from msleak.leakage.bootstrap import (_weighted_order_median, _weighted_pareto_median,
                                     bootstrap_errors, cell_groups)
from msleak.leakage.expected import (correlation_factors, sample_error,
                                     window_correlation_length)
from msleak.leakage.stats import pareto_ks
from msleak.verbs.leakage_files import write_stats_csv, write_stats_md

from test_leakage_helpers import gaussian_voxels, make_ps_dataset


def model_w(a, n, rng):
    u = rng.uniform(size=n)
    return a**2 * u / (1.0 - u)


def test_weighted_resample_statistics_equal_explicit_repetition():
    """The vectorised weighted median and Pareto fit equal np.median and fit_pareto of the
    explicitly repeated sample."""
    rng = np.random.default_rng(3)
    x = np.sort(100 * np.sqrt(model_w(0.04, 3001, rng)))
    wts = rng.integers(0, 3, size=(4, x.size))
    med = _weighted_order_median(x, np.cumsum(wts, axis=1))
    w = (x / 100) ** 2
    pmed = _weighted_pareto_median(w, wts.astype(float), 0.04**2)
    for r in range(4):
        rep = np.repeat(x, wts[r])
        assert med[r] == np.median(rep)
        ref = fit_pareto((rep / 100) ** 2, use_scipy=False).median_w
        assert pmed[r] == pytest.approx(ref, rel=1e-10)


def test_iid_bootstrap_matches_asymptotic_errors():
    rng = np.random.default_rng(4)
    a, n = 0.05, 10_000
    L = 100 * np.sqrt(model_w(a, n, rng))
    b = bootstrap_errors(L, None, n_boot=200, seed=1)
    # asymptotic: fit (A/2) sqrt(3/n); data median A / sqrt(n) (density 1/(4 a^2) of W)
    assert b.pareto_median == pytest.approx(100 * a * np.sqrt(3 / n) / 2, rel=0.2)
    assert b.median == pytest.approx(100 * a / np.sqrt(n), rel=0.2)
    assert b.n_groups == n and b.n_boot == 200
    # same seed, same answer
    assert bootstrap_errors(L, None, n_boot=200, seed=1) == b


def test_repeated_values_inflate_errors_by_sqrt_k_and_match_realisations():
    """Each independent value repeated k times: n_eff = n / k, so the errors grow by
    sqrt(k); the bootstrap over groups matches the scatter over realisations."""
    a, G, k = 0.05, 2000, 5
    rng = np.random.default_rng(5)
    groups = np.repeat(np.arange(G), k)
    fits, meds, means, boots = [], [], [], []
    for r in range(200):
        L = 100 * np.sqrt(np.repeat(model_w(a, G, rng), k))
        fits.append(fit_pareto((L / 100) ** 2).median_percent)
        meds.append(np.median(L))
        means.append(L.mean())
        if r < 4:
            boots.append(bootstrap_errors(L, groups, n_boot=200, seed=r))
    iid = 100 * a * np.sqrt(3 / (G * k)) / 2
    boot_fit = np.mean([b.pareto_median for b in boots])
    assert boot_fit / iid == pytest.approx(np.sqrt(k), rel=0.2)
    assert boot_fit == pytest.approx(np.std(fits, ddof=1), rel=0.25)
    assert np.mean([b.median for b in boots]) == pytest.approx(np.std(meds, ddof=1),
                                                                rel=0.25)
    # the mean of L has infinite variance under the model: only a loose check
    assert np.mean([b.mean for b in boots]) == pytest.approx(np.std(means, ddof=1), rel=0.5)
    st = leakage_statistics(L, groups=groups, n_boot=200, seed=9)
    assert st.n_eff == pytest.approx(G, rel=0.4)
    assert st.pareto_median_err > 1.5 * st.fit.median_err_percent


def test_delay_correlated_voxels_through_analyse():
    """Voxels correlated along delay (amplitudes summed over 8 neighbouring delays, like
    a spectral window): the cell bootstrap error matches the scatter over realisations,
    the iid error is too small."""
    shape = (30, 150)

    def smooth(v):
        return sum(np.roll(v, j, axis=0) for j in range(8))

    fits, errs, iid = [], [], []
    for r in range(60):
        rng = np.random.default_rng(100 + r)
        ds = make_ps_dataset(smooth(gaussian_voxels(shape, 0.03, rng)),
                             smooth(gaussian_voxels(shape, 1.0, rng)))
        res = analyse([ds], ["x"], ["x.h5"], n_boot=200 if r < 4 else 0,
                      bootstrap_block=1, seed=r)
        fits.append(float(res["pareto_median"].values[0]))
        if r < 4:
            errs.append(float(res["pareto_median_err"].values[0]))
            iid.append(float(res["pareto_median_err_iid"].values[0]))
    scatter = np.std(fits, ddof=1)
    assert np.mean(errs) == pytest.approx(scatter, rel=0.3)
    assert np.mean(iid) < 0.7 * scatter


def test_voxel_and_its_mirror_are_drawn_together():
    """The mirror voxel (-u, -tau) shares its cell's group. If the mirrors duplicate their
    cells' voxels exactly, every statistic and bootstrap error (same seed) equals that of
    the cells' voxels alone; drawing the two voxels of a pair apart would shrink the
    errors by about sqrt(2), as if the duplicates were independent."""
    rng = np.random.default_rng(12)
    shape = (30, 150)
    v_i, v_p = gaussian_voxels(shape, 0.03, rng), gaussian_voxels(shape, 1.0, rng)
    ds = make_ps_dataset(v_i, v_p)                       # mirror power = cell's P power
    groups = voxel_groups(ds, block=1).reshape((2,) + shape)
    assert (groups[0] == groups[1]).all()
    res = analyse([ds], ["x"], ["x.h5"], bootstrap_block=1, seed=5)
    L_half = 100 * np.abs(v_i) / np.abs(v_p)
    cells = np.broadcast_to(np.arange(shape[1]), shape).ravel()
    st = leakage_statistics(L_half.ravel(), groups=cells, n_boot=200, seed=5)
    assert int(res["n_voxels"].values[0]) == 2 * L_half.size
    for name in ("median", "pareto_median", "mean", "median_err", "pareto_median_err",
                 "mean_err"):
        assert float(res[name].values[0]) == pytest.approx(getattr(st, name), rel=1e-8), name
    L2 = np.concatenate([L_half.ravel()] * 2)
    apart = bootstrap_errors(L2, np.concatenate([cells, cells + shape[1]]), 200, seed=5)
    assert apart.median < 0.85 * st.median_err


def test_cell_groups_blocks():
    u = np.array([0, 16, 32, 48, 0, 16]) * 1.0
    v = np.array([0, 0, 0, 0, -16, -16]) * 1.0
    assert len(np.unique(cell_groups(u, v, 16.0, 1))) == 6
    g = cell_groups(u, v, 16.0, 2)
    assert g[0] == g[1] and g[2] == g[3] and g[0] != g[2] and g[4] == g[5] != g[0]
    with pytest.raises(InputError, match="block"):
        cell_groups(u, v, 16.0, 0)


def test_ks_uniform_for_the_model_and_tiny_for_a_mixture():
    rng = np.random.default_rng(7)
    p = []
    for _ in range(20):
        w = model_w(0.03, 5000, rng)
        p.append(pareto_ks(w, fit_pareto(w))[1])
    # fitted parameters make p conservative (Lilliefors): no small values, spread out
    assert min(p) > 0.01 and np.median(p) > 0.3
    n = 5400
    a = np.where(rng.uniform(size=n) < 0.5, 0.02, 0.06)      # a^2 varies by 9
    w = model_w(1.0, n, rng) * a**2                           # W = a^2 x standard Pareto
    D, p_mix, p_eff = pareto_ks(w, fit_pareto(w), n_eff=n / 5)
    assert D > 0.04 and p_mix < 1e-10 and p_eff < p[0] and p_eff < 1e-2
    # D is the largest CDF difference: checked against a direct evaluation
    from scipy import stats
    f = fit_pareto(w)
    assert D == pytest.approx(stats.kstest(w, "pareto", args=(1, f.loc, f.scale)).statistic,
                              rel=1e-12)


def test_stats_table_has_the_new_columns(tmp_path):
    rng = np.random.default_rng(8)
    ds = make_ps_dataset(gaussian_voxels((20, 60), 0.05, rng), gaussian_voxels((20, 60), 1, rng))
    res = analyse([ds], ["a"], ["a.h5"])
    rows = list(csv.DictReader(open(write_stats_csv(res, tmp_path / "s.csv"))))
    for col in ("label", "mean", "median", "std", "peak", "pareto_median", "n_voxels",
                "pareto_median_err", "median_err", "mean_err", "pareto_median_err_iid",
                "ks_d", "ks_p", "ks_p_eff", "n_eff", "n_groups"):
        assert col in rows[0]
    assert float(rows[0]["pareto_median_err"]) == pytest.approx(
        float(res["pareto_median_err"].values[0]), rel=1e-5)
    assert int(rows[0]["n_groups"]) == 60            # the 60 cells, all delays together
    assert "KS D" in write_stats_md(res, tmp_path / "stats.md").read_text()


# ------------------------------------------------------------------ effective cell counts

def _grid(nu=20, nv=20):
    iu = np.repeat(np.arange(nu), nv)
    iv = np.tile(np.arange(nv), nu)
    return iu, iv


def test_correlation_factors_known_duplications():
    rng = np.random.default_rng(11)
    nd = 40
    iu, iv = _grid()
    k = np.arange(nd) - nd // 2
    bins = np.abs(k)[:, None] * 100 + (iu // 4)[None, :]       # pairs never straddle bins
    p = rng.exponential(size=(nd, iu.size))
    r = correlation_factors(p, bins, k, iu, iv)
    assert r["c_2d"] == pytest.approx(1.0, abs=0.1) and r["c_sph"] == pytest.approx(1.0, abs=0.1)
    dup_delay = p.copy()
    dup_delay[1::2] = dup_delay[0::2]                           # pairs of equal delays
    assert correlation_factors(dup_delay, bins, k, iu, iv)["c_sph"] == pytest.approx(2.0,
                                                                                     abs=0.15)
    dup_u = p.copy()
    odd = iu % 2 == 1
    dup_u[:, odd] = p[:, np.nonzero(~odd)[0]]                  # cell (2j+1, v) = (2j, v)
    r = correlation_factors(dup_u, bins, k, iu, iv)
    assert r["c_2d"] == pytest.approx(2.0, abs=0.2)


def test_effective_counts_match_scatter_of_bin_means():
    """Amplitudes smoothed over neighbouring uv cells: the bin mean scatters as
    |P| / sqrt(counts / c_2d) over realisations, not as |P| / sqrt(counts)."""
    nd = 8
    iu, iv = _grid(24, 24)
    k = np.arange(nd) - nd // 2
    bins = np.abs(k)[:, None] * 100 + (iu // 12)[None, :] * 10 + (iv // 12)[None, :]
    sel = bins == bins[5, 0]
    means, cs = [], []
    for r in range(300):
        rng = np.random.default_rng(200 + r)
        a = gaussian_voxels((nd, 24, 24), 1.0, rng)
        a = a + np.roll(a, 1, axis=1) + np.roll(a, 1, axis=2)   # uv correlation
        p = (np.abs(a) ** 2).reshape(nd, -1)
        means.append(p[sel].mean())
        if r < 20:
            cs.append(correlation_factors(p, bins, k, iu, iv)["c_2d"])
    c = np.mean(cs)
    predicted = sample_error(np.mean(means), sel.sum() / c)
    assert c > 1.5
    assert np.std(means, ddof=1) == pytest.approx(float(predicted), rel=0.25)


def test_window_correlation_length():
    from scipy.signal import windows

    assert window_correlation_length(np.ones(50)) == pytest.approx(1.0)
    # Hann: N sum w^4 / (sum w^2)^2 -> 35/18 for large N
    assert window_correlation_length(windows.hann(2001, sym=False)) == pytest.approx(
        35 / 18, rel=1e-3)
