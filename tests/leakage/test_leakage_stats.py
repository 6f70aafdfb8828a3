"""Voxel statistics of L_I and the Pareto (b = 1) model of W = (L_I / 100)^2."""

import numpy as np
import pytest
from scipy import integrate, stats

from msleak.errors import InputError
from msleak.leakage import (ParetoFit, analyse, fit_pareto, fit_pareto_histogram,
                            leakage_statistics, pareto_density_percent)
from msleak.leakage.stats import histogram_edges

from test_leakage_helpers import gaussian_voxels, make_ps_dataset


def model_samples(a: float, n: int, seed: int) -> np.ndarray:
    """W drawn from CDF w / (w + a^2) by inversion: w = a^2 u / (1 - u)."""
    u = np.random.default_rng(seed).uniform(size=n)
    return a**2 * u / (1.0 - u)


@pytest.mark.parametrize("a", [0.003, 0.05, 1.7])
def test_pareto_fit_recovers_a(a):
    w = model_samples(a, 100_000, seed=int(a * 1000))
    fit = fit_pareto(w)
    assert fit.method == "ml-scipy"
    assert np.sqrt(fit.median_w) == pytest.approx(a, rel=0.02)
    assert fit.median_percent == pytest.approx(100 * a, rel=0.02)
    # the model: loc = -a^2, scale = a^2
    assert fit.scale == pytest.approx(a**2, rel=0.04)
    assert fit.loc + fit.scale == pytest.approx(w.min(), rel=1e-9)


def test_ml_scipy_equals_score_root_and_is_the_maximum():
    w = model_samples(0.2, 20_000, seed=7)
    f1 = fit_pareto(w, use_scipy=True)
    f2 = fit_pareto(w, use_scipy=False)
    assert f2.method == "ml-root"
    assert f1.median_w == pytest.approx(f2.median_w, rel=1e-6)
    # the fitted parameters maximise scipy's likelihood among nearby admissible ones
    nll = stats.pareto.nnlf((1, f2.loc, f2.scale), w)
    for ds in (0.99, 1.01):
        s = f2.scale * ds
        assert stats.pareto.nnlf((1, w.min() - s, s), w) > nll


def test_histogram_fit_agrees():
    w = model_samples(0.04, 100_000, seed=8)
    L = 100 * np.sqrt(w)
    edges = histogram_edges(L, 100, 0.99)
    fh = fit_pareto_histogram(w, (edges / 100) ** 2)
    assert fh.median_percent == pytest.approx(4.0, rel=0.02)
    assert fh.median_percent == pytest.approx(fit_pareto(w).median_percent, rel=0.005)


def test_histogram_fit_moves_loc_and_scale():
    """A Pareto whose support starts above 0 (loc = -s/2): the fit must find loc and scale,
    starting from the model (loc = -scale = -median) far from them."""
    s = 0.01
    u = np.random.default_rng(12).uniform(size=100_000)
    w = -0.5 * s + s / (1 - u)
    L = 100 * np.sqrt(w)
    fh = fit_pareto_histogram(w, (histogram_edges(L, 100, 0.99) / 100) ** 2)
    assert fh.scale == pytest.approx(s, rel=0.03)
    assert fh.loc == pytest.approx(-0.5 * s, rel=0.05)
    fm = fit_pareto(w)
    assert fm.scale == pytest.approx(s, rel=0.03) and fm.loc == pytest.approx(-0.5 * s, rel=0.05)


def test_standard_error_matches_scatter():
    a, n = 0.1, 2000
    meds = [fit_pareto(model_samples(a, n, seed=100 + k)).median_percent for k in range(60)]
    predicted = fit_pareto(model_samples(a, n, seed=99)).median_err_percent
    assert predicted == pytest.approx(100 * a * np.sqrt(3 / n) / 2, rel=0.05)
    # the standard deviation of 60 estimates is known to about 9 %
    assert np.std(meds, ddof=1) == pytest.approx(predicted, rel=0.3)


def test_gaussian_voxels_statistics():
    """Independent complex Gaussian I and P: W is exactly Pareto with a = sigma_I/sigma_P."""
    rng = np.random.default_rng(21)
    n = 100_000
    sig_i, sig_p = 0.06, 2.0
    L = 100 * np.abs(gaussian_voxels(n, sig_i, rng)) / np.abs(gaussian_voxels(n, sig_p, rng))
    A = 100 * sig_i / sig_p
    st = leakage_statistics(L)
    assert st.pareto_median == pytest.approx(A, rel=0.02)
    assert st.median == pytest.approx(A, rel=0.02)
    assert st.mean > st.median
    assert st.mean == pytest.approx(A * np.pi / 2, rel=0.05)     # E[L] = pi A / 2
    assert st.peak == pytest.approx(A / np.sqrt(3), rel=0.2)     # mode of f_L
    assert st.peak_bin_width == pytest.approx(np.quantile(L, 0.99) / 100, rel=1e-12)
    assert st.hist_counts.sum() == pytest.approx(0.99 * n, abs=2)
    assert st.fit_hist.median_percent == pytest.approx(A, rel=0.02)


def test_gaussian_voxels_through_ps_product():
    rng = np.random.default_rng(22)
    shape = (100, 1000)  # 10^5 cells x delays, two P voxels each
    ds = make_ps_dataset(gaussian_voxels(shape, 0.3, rng), gaussian_voxels(shape, 10.0, rng),
                         v_p_mirror=gaussian_voxels(shape, 10.0, rng))
    res = analyse([ds], ["fov"], ["fov.h5"])
    assert int(res["n_voxels"].values[0]) == 200_000
    assert float(res["pareto_median"].values[0]) == pytest.approx(3.0, rel=0.02)
    assert float(res["median"].values[0]) == pytest.approx(3.0, rel=0.02)
    assert float(res["mean"].values[0]) > float(res["median"].values[0])


def test_density_is_the_model():
    A = 2.5
    fit = ParetoFit(loc=-(A / 100) ** 2, scale=(A / 100) ** 2, median_w=(A / 100) ** 2,
                    median_err_w=0.0, method="test", n=1)
    l = np.linspace(0.01, 30, 7)
    np.testing.assert_allclose(pareto_density_percent(l, fit),
                               2 * l * A**2 / (l**2 + A**2) ** 2, rtol=1e-10)
    total, _ = integrate.quad(lambda x: float(pareto_density_percent(np.array(x), fit)),
                              0, np.inf, limit=200)
    assert total == pytest.approx(1.0, rel=1e-6)


def test_degenerate_sample():
    fit = fit_pareto(np.full(10, 0.25))
    assert fit.method == "degenerate" and fit.median_percent == pytest.approx(50.0)


@pytest.mark.parametrize("w, msg", [([1.0], "at least 2"), ([1.0, -1.0], "non-negative"),
                                    ([1.0, np.nan], "finite")])
def test_fit_rejects_bad_samples(w, msg):
    with pytest.raises(InputError, match=msg):
        fit_pareto(np.array(w))


def test_view_histogram_cuts_the_view_only():
    """1..100: the 0.95 quantile (linear interpolation) is 95.05, so 95 values fall in the
    view's bins and 5 beyond; the edges are uniform from 0."""
    from msleak.leakage.stats import view_histogram

    values = np.arange(1.0, 101.0)
    counts, edges, beyond = view_histogram(values[::-1], bins=10, quantile=0.95)
    np.testing.assert_allclose(edges, np.linspace(0.0, 95.05, 11), rtol=1e-14)
    assert counts.sum() == 95 and beyond == 5
    np.testing.assert_array_equal(counts, np.histogram(values, edges)[0])
