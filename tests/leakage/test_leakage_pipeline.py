"""L_I from PS products made by msleak's own delay transform and power spectrum code."""

import numpy as np
import pytest

from msleak.leakage import analyse, leakage_voxels
from msleak.verbs.power import power_spectrum
from msleak.verbs.transform import transform
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
    return power_spectrum(transform(uv, window="blackman-harris"))


def gauss(rng, shape, sigma):
    return sigma * (rng.normal(size=shape) + 1j * rng.normal(size=shape)) / np.sqrt(2)


def hermitian(cube):
    """A Hermitian uv cube (chan, v, u) of the same variance: the visibilities of a real
    sky, c(-u, -v) = conj(c(u, v)) (the grid is symmetric about its centre cell)."""
    return (cube + np.conj(cube[:, ::-1, ::-1])) / np.sqrt(2)


def test_rotated_polarization_leakage_through_ps():
    """Q = cos(2 chi) A, U = sin(2 chi) A (a constant polarization angle, A Hermitian) and
    I = eps (cos(2 chi) Q + sin(2 chi) U) = eps A: P~(u, tau) = e^(2 i chi) A~(u, tau) and
    P~(-u, -tau) = e^(2 i chi) conj(A~(u, tau)), so P_I = eps^2 P_P in both voxels of every
    pair, and L_I = 100 eps in every voxel and bin."""
    rng = np.random.default_rng(40)
    shape = (NCHAN, 2 * M + 1, 2 * M + 1)
    a = hermitian(gauss(rng, shape, 1.0))
    chi = 0.3
    q, u = np.cos(2 * chi) * a, np.sin(2 * chi) * a
    eps = 0.007
    ps = ps_from_cubes(eps * (np.cos(2 * chi) * q + np.sin(2 * chi) * u), q, u)
    res = analyse([ps], ["x"], ["x.h5"])
    valid = res["mask"].values[0] == 0
    assert valid.sum() > 0.5 * valid.size
    np.testing.assert_allclose(res["L_I"].values[0][valid], 100 * eps, rtol=1e-9)
    np.testing.assert_allclose(leakage_voxels(ps).L, 100 * eps, rtol=1e-9)
    n_cells, n_delays = ps["power3d"].shape[2], ps["power3d"].shape[1]
    assert int(res["n_voxels"].values[0]) == 2 * n_cells * n_delays
    for c in ("mean", "median", "pareto_median"):
        assert float(res[c].values[0]) == pytest.approx(100 * eps, rel=1e-9)


def test_mirror_voxel_is_the_mirrored_cell_and_bins_average_the_pair():
    """For Hermitian Q, U: power3d_P_mirror at (u, tau) equals |P~|^2 read from the delay
    cube at the mirrored cell (-u, -v) and delay -tau (index computed here), power3d P is
    |P~(u, tau)|^2 there, and the P bins average both: P_Q + P_U."""
    rng = np.random.default_rng(42)
    shape = (NCHAN, 2 * M + 1, 2 * M + 1)
    q, u = hermitian(gauss(rng, shape, 1.0)), hermitian(gauss(rng, shape, 0.5))
    vis4 = np.stack([np.zeros_like(q), q, u, np.zeros_like(q)])
    attrs = {"cell_lambda": CELL, "uv_min_lambda": 30.0, "uv_max_lambda": 180.0,
             "fov_deg": 4.0, "beam_area_sr": (1 / CELL) ** 2}
    uv = uvcube_dataset(vis4, np.ones(vis4.shape[1:]), FREQ,
                        np.arange(-M, M + 1) * CELL, attrs)
    dl = transform(uv, window="blackman-harris")
    ps = power_spectrum(dl)
    scale = ps.attrs["jy2_to_mk2_mpc3"] / dl.attrs["window_norm"]
    p_vis = dl["vis"].sel(stokes="P").values                      # (delay, v, u)
    iu = np.rint(ps["u_cell"].values / CELL).astype(int) + M
    iv = np.rint(ps["v_cell"].values / CELL).astype(int) + M
    j = np.arange(NCHAN)
    j_mirror = (NCHAN - j) % NCHAN      # fftshift order, even N: tau_j = (j - N/2) / B
    np.testing.assert_allclose(dl["delay"].values[j_mirror][1:], -dl["delay"].values[1:])
    direct = np.abs(p_vis[j_mirror][:, 2 * M - iv, 2 * M - iu]) ** 2 * scale
    np.testing.assert_allclose(ps["power3d_P_mirror"].values, direct, rtol=1e-10)
    np.testing.assert_allclose(ps["power3d"].sel(stokes="P").values,
                               np.abs(p_vis[:, iv, iu]) ** 2 * scale, rtol=1e-10)
    # the two voxels of a pair differ (P is not Hermitian): the check above is not trivial
    assert np.median(np.abs(ps["power3d_P_mirror"].values
                            / ps["power3d"].sel(stokes="P").values - 1)) > 0.1
    pb = ps["power"].sel(stokes=["P", "Q", "U"]).values
    np.testing.assert_allclose(pb[0], pb[1] + pb[2], rtol=1e-10)
    assert "power3d_P_mirror" in ps.attrs["P_power_definition"]


def test_independent_gaussian_median_through_ps():
    """Independent Hermitian Gaussian I, Q, U cubes, E|I|^2 / E|Q + iU|^2 = r^2: P~ of every
    voxel of the full plane is circular Gaussian, so W = P_I / P_P is a ratio of
    exponentials and the medians are 100 r. The symmetric P_Q + P_U (Gamma of shape 2)
    instead gives CDF 1 - (1 + w / (2 r^2))^-2 and median 100 r sqrt(2 (sqrt 2 - 1)).
    39 200 cell-delays, window none (independent delays): bootstrap error of the medians
    0.4 %."""
    rng = np.random.default_rng(41)
    nchan, r = 200, 0.05
    freq = 150e6 + DNU * np.arange(nchan)
    shape = (nchan, 2 * M + 1, 2 * M + 1)
    i = hermitian(gauss(rng, shape, r))
    q, u = (hermitian(gauss(rng, shape, np.sqrt(0.5))) for _ in range(2))
    vis4 = np.stack([i, q, u, np.zeros_like(i)])
    attrs = {"cell_lambda": CELL, "uv_min_lambda": 30.0, "uv_max_lambda": 180.0,
             "fov_deg": 4.0, "beam_area_sr": (1 / CELL) ** 2}
    uv = uvcube_dataset(vis4, np.ones(vis4.shape[1:]), freq, np.arange(-M, M + 1) * CELL,
                        attrs)
    ps = power_spectrum(transform(uv, window="none"))
    res = analyse([ps], ["x"], ["x.h5"], n_boot=0)
    assert float(res["pareto_median"].values[0]) == pytest.approx(100 * r, rel=0.02)
    assert float(res["median"].values[0]) == pytest.approx(100 * r, rel=0.02)
    assert float(res["mean"].values[0]) > float(res["median"].values[0])
    p3 = ps["power3d"]
    w_sym = p3.sel(stokes="I").values / (p3.sel(stokes="Q").values + p3.sel(stokes="U").values)
    factor = np.sqrt(2 * (np.sqrt(2) - 1))
    assert 100 * np.sqrt(np.median(w_sym)) == pytest.approx(100 * r * factor, rel=0.02)


def test_cross_power_mirror_is_the_mirrored_cross_power():
    """With two halves (cross-power) the mirror voxel's P power is
    Re(P~_a(-u, -tau) conj(P~_b(-u, -tau))) read from the delay cube, and the P bins
    average both voxels: Re(Q~_a conj Q~_b) + Re(U~_a conj U~_b)."""
    rng = np.random.default_rng(43)
    shape = (NCHAN, 2 * M + 1, 2 * M + 1)
    halves = []
    for _ in range(2):
        q, u = hermitian(gauss(rng, shape, 1.0)), hermitian(gauss(rng, shape, 1.0))
        halves.append((np.stack([np.zeros_like(q), q, u, np.zeros_like(q)]),
                       np.ones(shape)))
    vis4 = 0.5 * (halves[0][0] + halves[1][0])
    attrs = {"cell_lambda": CELL, "uv_min_lambda": 30.0, "uv_max_lambda": 180.0,
             "fov_deg": 4.0, "beam_area_sr": (1 / CELL) ** 2}
    uv = uvcube_dataset(vis4, np.ones(shape), FREQ, np.arange(-M, M + 1) * CELL, attrs,
                        halves)
    dl = transform(uv, window="hann")
    ps = power_spectrum(dl, cross=True)
    scale = ps.attrs["jy2_to_mk2_mpc3"] / dl.attrs["window_norm"]
    pa, pb = (dl[n].sel(stokes="P").values for n in ("vis_a", "vis_b"))
    iu = np.rint(ps["u_cell"].values / CELL).astype(int) + M
    iv = np.rint(ps["v_cell"].values / CELL).astype(int) + M
    jm = (NCHAN - np.arange(NCHAN)) % NCHAN
    direct = (pa[jm][:, 2 * M - iv, 2 * M - iu]
              * np.conj(pb[jm][:, 2 * M - iv, 2 * M - iu])).real * scale
    np.testing.assert_allclose(ps["power3d_P_mirror"].values, direct, rtol=1e-9,
                               atol=1e-12 * np.abs(direct).max())
    pb2 = ps["power"].sel(stokes=["P", "Q", "U"]).values
    np.testing.assert_allclose(pb2[0], pb2[1] + pb2[2], rtol=1e-9,
                               atol=1e-12 * np.abs(pb2).max())
