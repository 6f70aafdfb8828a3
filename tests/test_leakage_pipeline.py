"""L_I from PS products made by msleak's own delay transform and power spectrum code."""

import numpy as np
import pytest

from msleak.leakage import analyse
from msleak.ps.spectra import power_spectrum, transform_uvcube
from msleak.ps.uvcube import uvcube_dataset

NCHAN, DNU, CELL, M = 50, 195312.5, 16.0, 12
FREQ = 150e6 + DNU * np.arange(NCHAN)


def ps_from_cubes(i_cube, q_cube, u_cube):
    """PS product from (chan, v, u) Stokes I, Q, U grids over |b| = 30..180 wavelengths."""
    vis4 = np.stack([i_cube, q_cube, u_cube, np.zeros_like(i_cube)])
    attrs = {"cell_lambda": CELL, "uv_min_lambda": 30.0, "uv_max_lambda": 180.0,
             "fov_deg": 4.0, "beam_area_sr": (1 / CELL) ** 2}
    uv = uvcube_dataset(vis4, np.ones(vis4.shape[1:]), FREQ,
                        np.arange(-M, M + 1) * CELL, attrs)
    return power_spectrum(transform_uvcube(uv, window="blackman-harris"))


def gauss(rng, shape, sigma):
    return sigma * (rng.normal(size=shape) + 1j * rng.normal(size=shape)) / np.sqrt(2)


def test_rotated_polarization_leakage_through_ps():
    """Q = cos(2 chi) A, U = sin(2 chi) A (a constant polarization angle) and
    I = eps (cos(2 chi) Q + sin(2 chi) U) = eps A: the delay transform is linear per uv cell,
    so P_I = eps^2 (P_Q + P_U) = eps^2 P_P in every voxel and L_I = 100 eps in every bin."""
    rng = np.random.default_rng(40)
    shape = (NCHAN, 2 * M + 1, 2 * M + 1)
    a = gauss(rng, shape, 1.0)
    chi = 0.3
    q, u = np.cos(2 * chi) * a, np.sin(2 * chi) * a
    eps = 0.007
    ps = ps_from_cubes(eps * (np.cos(2 * chi) * q + np.sin(2 * chi) * u), q, u)
    res = analyse([ps], ["x"], ["x.h5"])
    valid = res["mask"].values[0] == 0
    assert valid.sum() > 0.5 * valid.size
    np.testing.assert_allclose(res["L_I"].values[0][valid], 100 * eps, rtol=1e-9)
    assert int(res["n_voxels"].values[0]) == ps["power3d"].shape[1] * ps["power3d"].shape[2]
    for c in ("mean", "median", "pareto_median"):
        assert float(res[c].values[0]) == pytest.approx(100 * eps, rel=1e-9)


def test_polarized_power_is_pq_plus_pu():
    """P_P of a voxel is P_Q + P_U (the mean of |P~|^2 over the voxel and its mirror), not
    |P~(u, tau)|^2 of one Hermitian half; with U = 0 and I = eps Q, L_I = 100 eps exactly."""
    rng = np.random.default_rng(42)
    shape = (NCHAN, 2 * M + 1, 2 * M + 1)
    q, u = gauss(rng, shape, 1.0), gauss(rng, shape, 1.0)
    p3d = ps_from_cubes(np.zeros_like(q), q, u)["power3d"]
    np.testing.assert_allclose(p3d.sel(stokes="P"), p3d.sel(stokes="Q") + p3d.sel(stokes="U"),
                               rtol=1e-12)
    eps = 0.003
    ps = ps_from_cubes(eps * q, q, np.zeros_like(q))
    res = analyse([ps], ["x"], ["x.h5"])
    valid = res["mask"].values[0] == 0
    np.testing.assert_allclose(res["L_I"].values[0][valid], 100 * eps, rtol=1e-9)


def test_independent_gaussian_median_through_ps():
    """Independent Gaussian I and P per cell and channel, with P one-sided (U = -i Q, as for
    Faraday-rotated emission at one sign of delay) so that P_P = |P~|^2 / 2 is exponential:
    median L_I = 100 sigma_I / sigma_P (about 9 000 voxels, correlated along delay by the
    window: 5 % tolerance)."""
    rng = np.random.default_rng(41)
    shape = (NCHAN, 2 * M + 1, 2 * M + 1)
    a = gauss(rng, shape, np.sqrt(2.0))                       # sigma_P^2 = E[P_Q + P_U] = 2
    q, u = a / np.sqrt(2), -1j * a / np.sqrt(2)
    i = gauss(rng, shape, 0.05 * np.sqrt(2))
    res = analyse([ps_from_cubes(i, q, u)], ["x"], ["x.h5"])
    assert float(res["pareto_median"].values[0]) == pytest.approx(5.0, rel=0.05)
    assert float(res["median"].values[0]) == pytest.approx(5.0, rel=0.05)
    assert float(res["mean"].values[0]) > float(res["median"].values[0])
