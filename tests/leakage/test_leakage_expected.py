"""Expected leakage (L_I^2 x P_P,obs) and the bias correction of an observed Stokes I PS."""

import numpy as np
import pytest

from msleak.errors import InputError
from msleak.leakage import (analyse, bias_correct, corrected_power, expected_leakage,
                            expected_leakage_error, expected_leakage_power,
                            spherical_from_bins)
from msleak.leakage.expected import edges_from_centres, leakage_model_error

from test_leakage_helpers import (cylindrical, gaussian_voxels, geometry, make_ps_dataset,
                                  rotated_leakage)

SHAPE = (20, 60)


def varying_model(seed=1):
    """A model PS whose leakage depends on k_perp: L_I = 100 eps(k_perp bin) exactly."""
    rng = np.random.default_rng(seed)
    k_par3d, k_perp_cell, edges = geometry(*SHAPE)
    eps_bin = np.linspace(0.005, 0.03, edges.size - 1)
    eps_cell = eps_bin[np.digitize(k_perp_cell, edges) - 1]
    v_p = gaussian_voxels(SHAPE, 2.0, rng)
    v_i = rotated_leakage(v_p, 1.0, rng) * eps_cell[None, :]
    ds = make_ps_dataset(v_i, v_p, k_par3d, k_perp_cell, edges)
    return ds, 100 * eps_bin


def observed(seed, p_i3d=None, geometry_args=SHAPE):
    rng = np.random.default_rng(seed)
    k_par3d, k_perp_cell, edges = geometry(*geometry_args)
    v_p = gaussian_voxels(geometry_args, 5.0, rng)
    v_i = gaussian_voxels(geometry_args, 0.5, rng)
    return make_ps_dataset(v_i, v_p, k_par3d, k_perp_cell, edges, power3d_i=p_i3d)


def test_expected_power_is_product():
    p = np.array([[1.0, 2.0], [3.0, -4.0]])
    L = np.array([[10.0, 1.0], [0.0, 50.0]])
    np.testing.assert_allclose(expected_leakage_power(p, L), p * (L / 100) ** 2, rtol=1e-15)
    np.testing.assert_allclose(expected_leakage_power(p, 2.0), p * 4e-4, rtol=1e-15)
    with pytest.raises(InputError, match="non-negative"):
        expected_leakage_power(p, -1.0)


def test_expected_leakage_map_mode_per_bin():
    model, L_bin = varying_model()
    res = analyse([model], ["m"], ["m.h5"])
    np.testing.assert_allclose(res["L_I"].values[0], np.broadcast_to(L_bin, res["L_I"].shape[1:]),
                               rtol=1e-12)
    obs = observed(5)
    exp = expected_leakage(res, obs, 0, 1, "auto")
    assert exp.attrs["model_mode"] == "map"
    p_p_obs = obs["power"].sel(stokes="P").values
    np.testing.assert_allclose(exp["power_leak"].values, p_p_obs * (L_bin[None, :] / 100) ** 2,
                               rtol=1e-12)
    # spherical: counts-weighted average of the 2D leakage into k shells (independent sum)
    k = np.hypot(obs["k_par"].values[:, None], obs["k_perp"].values[None, :])
    edges = edges_from_centres(obs["k"].values)
    leak2d, counts = exp["power_leak"].values, obs["counts"].values
    for j in range(edges.size - 1):
        sel = (k >= edges[j]) & (k < edges[j + 1]) & (counts > 0)
        if sel.any():
            want = (leak2d * counts)[sel].sum() / counts[sel].sum()
            assert exp["power_leak_sph"].values[j] == pytest.approx(want, rel=1e-12)


def test_expected_leakage_scalar_modes_scale_the_spherical_ps():
    model, _ = varying_model()
    model2, _ = varying_model(seed=2)
    res = analyse([model, model2], ["a", "b"], ["a.h5", "b.h5"])
    obs = observed(6)
    pp_sph = obs["power_sph"].sel(stokes="P").values
    med = expected_leakage(res, obs, 1, 2, "median")
    L1 = float(res["pareto_median"].values[1])
    assert med.attrs["L_I_model_scalar"] == L1
    np.testing.assert_allclose(med["power_leak_sph"].values, pp_sph * (L1 / 100) ** 2,
                               rtol=1e-12)
    fld = expected_leakage(res, obs, 0, 1, "field")
    Lf = 0.5 * float(res["pareto_median"].values.sum())
    np.testing.assert_allclose(fld["power_leak"].values,
                               obs["power"].sel(stokes="P").values * (Lf / 100) ** 2, rtol=1e-12)
    # the field model's relative error includes the spread of the medians
    spread = float(np.std(res["pareto_median"].values, ddof=1))
    assert fld.attrs["L_I_model_rel_error"] * Lf >= spread


def test_pairing_and_grid_errors():
    model, _ = varying_model()
    res = analyse([model, model], ["a", "b"], ["a.h5", "b.h5"])
    obs = observed(7)
    with pytest.raises(InputError, match="give 2 observed PS"):
        expected_leakage(res, obs, 0, 3, "median")
    other = observed(8, geometry_args=(12, 40))
    with pytest.raises(InputError, match="grid differs"):
        expected_leakage(res, other, 0, 2, "map")
    assert expected_leakage(res, other, 0, 2, "auto").attrs["model_mode"] == "median"
    assert expected_leakage(res, other, 0, 3, "auto").attrs["model_mode"] == "field"


def test_bias_correction_returns_the_signal():
    """Observed I = eps^2 P_P,obs + S voxel by voxel; the exact eps model removes the leakage."""
    rng = np.random.default_rng(9)
    eps = 0.02
    v_p = gaussian_voxels(SHAPE, 1.0, rng)
    model = make_ps_dataset(rotated_leakage(v_p, eps, rng), v_p)
    res = analyse([model], ["m"], ["m.h5"])
    k_par3d, k_perp_cell, edges = geometry(*SHAPE)
    v_p_obs = gaussian_voxels(SHAPE, 3.0, rng)
    signal3d = rng.exponential(0.01, SHAPE)
    p_i3d = eps**2 * np.abs(v_p_obs) ** 2 + signal3d
    obs = make_ps_dataset(gaussian_voxels(SHAPE, 1.0, rng), v_p_obs, k_par3d, k_perp_cell,
                          edges, power3d_i=p_i3d)
    for mode in ("map", "median"):
        cor = bias_correct(obs, expected_leakage(res, obs, 0, 1, mode))
        signal2d, counts, _ = cylindrical(signal3d, k_par3d, k_perp_cell, edges)
        np.testing.assert_allclose(cor["power_I_corrected"].values, signal2d, rtol=1e-9,
                                   atol=1e-15)
    # spherical (scalar model: from power_sph): the shell mean of the signal voxels
    kk = np.hypot(k_par3d[:, None], k_perp_cell[None, :])
    k_edges = edges_from_centres(obs["k"].values)
    got = cor["power_I_corrected_sph"].values
    for j in range(got.size):
        sel = (kk >= k_edges[j]) & (kk < k_edges[j + 1])
        if sel.any():
            assert got[j] == pytest.approx(signal3d[sel].mean(), rel=1e-9)


def test_correction_error_formula():
    p_i = np.array([2.0, 5.0, 1.0])
    p_p = np.array([100.0, 50.0, 10.0])
    n = np.array([4.0, 25.0, 0.0])
    L, sL = 3.0, 0.6
    leak = expected_leakage_power(p_p, L)
    leak_err = expected_leakage_error(p_p, n, L, sL)
    corr, err = corrected_power(p_i, n, leak, leak_err)
    l, sl = 0.03, 0.006
    want = np.sqrt((p_i[:2] / np.sqrt(n[:2])) ** 2 + (l**2 * p_p[:2] / np.sqrt(n[:2])) ** 2
                   + (2 * l * sl * p_p[:2]) ** 2)
    np.testing.assert_allclose(err[:2], want, rtol=1e-12)
    np.testing.assert_allclose(corr[:2], p_i[:2] - l**2 * p_p[:2], rtol=1e-12)
    assert corr[2] == 0 and err[2] == 0


def test_model_error_combines_fit_and_spread():
    assert leakage_model_error(0.3, np.array([1.0, 2.0, 3.0])) == pytest.approx(np.hypot(0.3, 1.0))
    assert leakage_model_error(0.3) == 0.3


def test_spherical_from_bins_weighted_mean():
    k_par = np.array([0.0, 0.1])
    k_perp = np.array([0.05, 0.2])
    power = np.array([[1.0, 3.0], [5.0, 7.0]])
    counts = np.array([[1.0, 2.0], [3.0, 0.0]])
    # |k| = 0.05, 0.2 / 0.112, 0.224 -> edges [0, 0.1, 0.3]: shell 0 = bin (0,0); shell 1 rest
    sph, w = spherical_from_bins(power, counts, k_par, k_perp, np.array([0.0, 0.1, 0.3]))
    assert sph[0] == pytest.approx(1.0) and w[0] == 1
    assert sph[1] == pytest.approx((3 * 2 + 5 * 3) / 5) and w[1] == 5


def test_no_leakage_model_leaves_observed_unchanged():
    """A model with P_I = 0 (degenerate fit, L_I = 0): nothing to subtract, no NaN."""
    rng = np.random.default_rng(12)
    v = gaussian_voxels(SHAPE, 1.0, rng)
    res = analyse([make_ps_dataset(np.zeros_like(v), v)], ["z"], ["z.h5"])
    assert res["fit_method"].values[0] == "degenerate"
    assert float(res["pareto_median"].values[0]) == 0.0 and float(res["peak"].values[0]) == 0.0
    obs = observed(13)
    cor = bias_correct(obs, expected_leakage(res, obs, 0, 1, "median"))
    np.testing.assert_array_equal(cor["power_I_corrected"].values,
                                  obs["power"].sel(stokes="I").values)
    for name, var in cor.data_vars.items():
        assert np.isfinite(var.values).all(), name
