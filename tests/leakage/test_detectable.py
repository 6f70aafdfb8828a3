"""The smallest detectable L_I against answers known in advance: noise of a known rms per
uv cell added to a noiseless P_I gives L_min = 100 sqrt(3 sigma / P_P) within the sampling
error of the rms, and a leak at L_min stands at 3 sigma."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from msleak.errors import InputError
from msleak.leakage.detectable import detectable_leakage, noise_sigma_per_cell

NDELAY, NCELL = 40, 6


def _ps(p_i, p_p, p_mirror=None):
    """A PS product's 3D voxel powers: P_I, P_P (delay, cell); Q, U, V zero."""
    stokes = np.zeros((5, NDELAY, NCELL))
    stokes[0], stokes[4] = p_i, p_p
    return xr.Dataset({"power3d": (("stokes", "delay3d", "cell"), stokes),
                       "power3d_P_mirror": (("delay3d", "cell"),
                                            p_p if p_mirror is None else p_mirror)},
                      coords={"stokes": list("IQUVP")})


def test_noise_of_known_rms_gives_the_known_threshold():
    rng = np.random.default_rng(7)
    sigma = np.linspace(1.0, 4.0, NCELL)                     # noise rms per cell
    p_p = np.full((NDELAY, NCELL), 1e4)
    p_i = 1e-3 * p_p
    noisy = [_ps(p_i + sigma * rng.standard_normal((NDELAY, NCELL)), p_p) for _ in range(5)]
    ideal = _ps(p_i, p_p)
    measured = noise_sigma_per_cell(ideal, noisy)
    # the rms of n = 200 Gaussian samples scatters by 1 / sqrt(2 n) relative: 5 % is 1 sigma
    np.testing.assert_allclose(measured, sigma, rtol=4 / np.sqrt(2 * 5 * NDELAY))
    l_min = detectable_leakage(ideal, noisy, nsigma=3.0)
    assert l_min.size == 2 * NDELAY * NCELL
    expected = 100 * np.sqrt(3 * sigma / 1e4)
    # sqrt halves the rms's relative sampling error: 2.5 % is 1 sigma of the median's cell
    np.testing.assert_allclose(np.median(l_min), np.median(expected), rtol=0.1)


def test_a_leak_at_the_threshold_stands_at_nsigma():
    sigma, p_p = 2.0, 5e3
    rng = np.random.default_rng(3)
    ideal = _ps(np.zeros((NDELAY, NCELL)), np.full((NDELAY, NCELL), p_p))
    noisy = [_ps(sigma * rng.standard_normal((NDELAY, NCELL)), ideal["power3d"][4].values)
             for _ in range(3)]
    l_min = float(np.median(detectable_leakage(ideal, noisy, nsigma=3.0)))
    leaked = (l_min / 100) ** 2 * p_p                        # P_I of L_I = L_min
    assert leaked / noise_sigma_per_cell(ideal, noisy).mean() == pytest.approx(3.0, rel=0.02)


def test_voxels_without_polarized_power_are_left_out_and_shapes_must_match():
    p_p = np.full((NDELAY, NCELL), 1e4)
    p_p[:, 0] = 0.0
    ideal = _ps(np.zeros_like(p_p), p_p, p_mirror=np.full_like(p_p, 1e4))
    noisy = [_ps(np.ones_like(p_p), p_p)]
    assert detectable_leakage(ideal, noisy).size == 2 * NDELAY * NCELL - NDELAY
    other = xr.Dataset({"power3d": (("stokes", "delay3d", "cell"), np.zeros((5, 3, 2))),
                        "power3d_P_mirror": (("delay3d", "cell"), np.zeros((3, 2)))},
                       coords={"stokes": list("IQUVP")})
    with pytest.raises(InputError, match="grid both alike"):
        detectable_leakage(ideal, [other])
    with pytest.raises(InputError, match="at least one noisy"):
        detectable_leakage(ideal, [])


def test_cells_are_matched_by_their_uv_when_the_noisy_cube_has_fewer():
    rng = np.random.default_rng(11)
    p_p = np.full((NDELAY, NCELL), 1e4)
    ideal = _ps(np.zeros_like(p_p), p_p).assign_coords(
        u_cell=("cell", np.arange(NCELL) * 16.0), v_cell=("cell", np.zeros(NCELL)))
    keep = [4, 1, 2]                                   # an even/odd cube: fewer cells
    sigma = np.array([5.0, 1.0, 2.0])
    noise = sigma * rng.standard_normal((NDELAY, 3))
    noisy = xr.Dataset({"power3d": (("stokes", "delay3d", "cell"),
                                    np.stack([noise, *np.zeros((3, NDELAY, 3)),
                                              p_p[:, keep]])),
                        "power3d_P_mirror": (("delay3d", "cell"), p_p[:, keep])},
                       coords={"stokes": list("IQUVP"), "u_cell": ("cell", 16.0 * np.array(keep)),
                               "v_cell": ("cell", np.zeros(3))})
    measured = noise_sigma_per_cell(ideal, [noisy])
    np.testing.assert_allclose(measured[keep], np.sqrt(np.mean(noise ** 2, axis=0)), rtol=1e-12)
    assert np.isnan(measured[[0, 3, 5]]).all()
    assert detectable_leakage(ideal, [noisy]).size == 2 * NDELAY * 3
