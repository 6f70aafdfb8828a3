"""L_I = 100 sqrt(P_I / P_P) per bin and voxel, and its masks."""

import numpy as np
import pytest

from msleak.errors import InputError
from msleak.leakage import MASK_CODES, analyse, leakage_fraction, leakage_map, leakage_voxels

from test_leakage_helpers import gaussian_voxels, make_ps_dataset, rotated_leakage


@pytest.fixture(scope="module")
def eps_ps():
    """Stokes I = eps x rotated (Q + iU) in every voxel: L_I = 100 eps exactly."""
    rng = np.random.default_rng(11)
    v_p = gaussian_voxels((20, 60), 3.0, rng)
    return make_ps_dataset(rotated_leakage(v_p, 0.015, rng), v_p), 1.5


def test_exact_leakage_every_voxel_and_bin(eps_ps):
    ds, L_true = eps_ps
    vox = leakage_voxels(ds)
    assert vox.L.size == 2 * 20 * 60 and vox.n_masked == 0  # (u, tau) and (-u, -tau)
    np.testing.assert_allclose(vox.L, L_true, rtol=1e-12)
    m = leakage_map(ds)
    assert (m["mask"] == 0).all()
    np.testing.assert_allclose(m["L_I"].values, L_true, rtol=1e-12)


def test_exact_leakage_statistics(eps_ps):
    ds, L_true = eps_ps
    res = analyse([ds, ds.copy()], ["a", "b"], ["a.h5", "b.h5"])
    for c in ("mean", "median", "pareto_median", "peak"):
        np.testing.assert_allclose(res[c].values, L_true, rtol=1e-9)
    assert res["std"].values.max() < 1e-9 * L_true
    assert res.attrs["field_estimate"] == pytest.approx(L_true, rel=1e-9)
    assert (res["n_masked"].values == 0).all()


def test_fraction_elementwise_and_masks():
    p_i = np.array([4.0, 1.0, -1.0, 1.0, np.nan, 0.0, 9.0])
    p_p = np.array([1.0, 0.0, 4.0, -2.0, 1.0, 1.0, 1.0])
    counts = np.array([1, 1, 1, 1, 1, 1, 0])
    L, mask = leakage_fraction(p_i, p_p, counts)
    C = MASK_CODES
    assert list(mask) == [0, C["nonpositive_pp"], C["negative_pi"], C["nonpositive_pp"],
                          C["nonfinite"], 0, C["empty"]]
    np.testing.assert_allclose(L, [200.0, 0, 0, 0, 0, 0, 0])
    assert np.isfinite(L).all()
    L2, mask2 = leakage_fraction(p_i, p_p, counts, negative="clip")
    assert mask2[2] == 0 and L2[2] == 0.0


def test_bad_negative_policy():
    with pytest.raises(InputError, match="negative"):
        leakage_fraction(np.ones(2), np.ones(2), negative="abs")


def test_zero_polarized_power_voxels_masked_counted():
    rng = np.random.default_rng(3)
    v_p = gaussian_voxels((20, 60), 1.0, rng)
    v_i = rotated_leakage(v_p, 0.1, rng)
    p_p = np.abs(v_p) ** 2
    p_i = np.abs(v_i) ** 2
    p_p[3, :] = 0.0          # 60 voxels of zero polarized power
    p_i[3, :] = 0.0
    p_p[5, :7] = -1.0        # 7 negative cross-power voxels
    # the mirrored voxels (-u, -tau) take the same P power: 2 x 67 masked
    ds = make_ps_dataset(v_i, v_p, power3d_i=p_i, power3d_p=p_p)
    vox = leakage_voxels(ds)
    assert vox.masked == {"nonpositive_pp": 134}
    assert vox.L.size == 2 * 20 * 60 - 134
    np.testing.assert_allclose(vox.L, 10.0, rtol=1e-12)
    res = analyse([ds], ["x"], ["x.h5"])
    assert int(res["n_masked"].values[0]) == 134
    reasons = dict(zip(res["mask_reason"].values, res["n_masked_by_reason"].values[0]))
    assert reasons["nonpositive_pp"] == 134
    for name in res.data_vars:
        if np.issubdtype(res[name].dtype, np.floating):
            assert np.isfinite(res[name].values).all(), name


def test_k_selection_of_voxels(eps_ps):
    ds, _ = eps_ps
    all_vox = leakage_voxels(ds)
    sel = leakage_voxels(ds, k_par_range=(0.1, 10.0), k_perp_range=(0.0, 0.11))
    kpar = np.abs(ds["k_par3d"].values)[:, None]
    kperp = ds["k_perp_cell"].values[None, :]
    expected = 2 * ((kpar >= 0.1) & (kperp <= 0.11)).sum()   # a voxel and its mirror
    assert sel.n_selected == expected < all_vox.n_selected
    with pytest.raises(InputError, match="no voxel inside"):
        leakage_voxels(ds, k_par_range=(50.0, 60.0))


@pytest.mark.parametrize("drop", ["I", "P"])
def test_missing_stokes(drop):
    rng = np.random.default_rng(4)
    v = gaussian_voxels((4, 12), 1.0, rng)
    ds = make_ps_dataset(v, v, drop_stokes=drop)
    with pytest.raises(InputError, match=f"no Stokes {drop}"):
        leakage_map(ds)
    with pytest.raises(InputError, match=f"no Stokes {drop}"):
        leakage_voxels(ds)


def test_no_power3d_needs_bins():
    rng = np.random.default_rng(5)
    v = gaussian_voxels((4, 12), 1.0, rng)
    ds = make_ps_dataset(0.1 * v, v, with_power3d=False)
    with pytest.raises(InputError, match="stats_from bins"):
        leakage_voxels(ds)
    no_mirror = make_ps_dataset(0.1 * v, v, with_mirror=False)
    with pytest.raises(InputError, match="no 'power3d_P_mirror'.*stats_from bins"):
        leakage_voxels(no_mirror)
    vox = leakage_voxels(ds, source="bins")
    np.testing.assert_allclose(vox.L, 10.0, rtol=1e-12)
    assert vox.source == "bins"


def test_inputs_on_different_grids_use_the_union():
    rng = np.random.default_rng(6)
    v_a = gaussian_voxels((20, 60), 1.0, rng)
    v_b = gaussian_voxels((12, 40), 1.0, rng)
    a = make_ps_dataset(rotated_leakage(v_a, 0.01, rng), v_a)
    b = make_ps_dataset(rotated_leakage(v_b, 0.03, rng), v_b)   # fewer k_par bins
    res = analyse([a, b], ["a", "b"], ["a.h5", "b.h5"])
    assert res.sizes["k_par"] == a.sizes["k_par"]
    mask_b = res["mask"].values[1]
    outside = ~np.isin(res["k_par"].values, b["k_par"].values)
    assert outside.sum() == a.sizes["k_par"] - b.sizes["k_par"] > 0
    assert (mask_b[outside] == MASK_CODES["not_in_grid"]).all()
    assert (mask_b[~outside] == 0).all()
    np.testing.assert_allclose(res["L_I"].values[1][~outside], 3.0, rtol=1e-12)
    assert (res["L_I"].values[1][outside] == 0).all()
    np.testing.assert_allclose(res["pareto_median"].values, [1.0, 3.0], rtol=1e-9)
