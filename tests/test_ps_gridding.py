"""Gridders of msleak.ps.gridding against answers known in advance and brute-force sums."""

import numpy as np
import pytest

from msleak.errors import InputError
from msleak.constants import SPEED_OF_LIGHT
from msleak.ps.gridding import (CellAccumulator, image_taper,
                                make_accumulator, make_grid, stokes_weights,
                                wgrid_kernel_bruteforce)

FREQ = np.array([150e6])
LAM = SPEED_OF_LIGHT / FREQ[0]


def _grid_one(gridder, uvw_lambda, vis4, wgt, freq=FREQ, epsilon=1e-10, taper="cos2"):
    grid = make_grid(16.0, 180.0)
    acc = make_accumulator(gridder, grid, freq, epsilon=epsilon, taper=taper)
    scale = freq / SPEED_OF_LIGHT
    uvw_m = uvw_lambda * SPEED_OF_LIGHT / freq[0]
    if gridder == "cell":
        acc.add(uvw_m[:, :1] * scale, uvw_m[:, 1:2] * scale, vis4, wgt)
    else:
        acc.add(uvw_m, vis4, wgt)
    return grid, acc


@pytest.mark.parametrize("gridder, taper", [("cell", "cos2"), ("wgrid", "cos2"),
                                           ("wgrid", "hann")])
def test_one_visibility_lands_in_its_cell_and_conjugate_in_mirror(gridder, taper):
    vis4 = np.array([0.7 + 0.3j, -0.2 + 0.1j, 0.05j, 0.4]).reshape(4, 1, 1)
    grid, acc = _grid_one(gridder, np.array([[3 * 16.0, -2 * 16.0, 0.0]]), vis4,
                          np.array([[2.5]]), taper=taper)
    vis, weight = acc.result()
    M = grid.M
    # cell (u = +3, v = -2) is vis[..., v index, u index]
    np.testing.assert_allclose(vis[:, 0, M - 2, M + 3], vis4[:, 0, 0], atol=1e-9)
    np.testing.assert_allclose(vis[:, 0, M + 2, M - 3], np.conj(vis4[:, 0, 0]), atol=1e-9)
    assert weight[0, M - 2, M + 3] == 2.5 and weight[0, M + 2, M - 3] == 2.5
    assert np.count_nonzero(weight) == 2
    assert np.count_nonzero(np.abs(vis) > 1e-12) <= 2 * 4


def test_cell_gridder_equals_brute_force_loop():
    rng = np.random.default_rng(3)
    nrow, nchan = 300, 3
    freq = 150e6 + 1e6 * np.arange(nchan)
    grid = make_grid(10.0, 60.0)
    u = rng.uniform(-70, 70, (nrow, nchan))
    v = rng.uniform(-70, 70, (nrow, nchan))
    vis = rng.normal(size=(4, nrow, nchan)) + 1j * rng.normal(size=(4, nrow, nchan))
    wgt = rng.uniform(0, 2, (nrow, nchan)) * (rng.uniform(size=(nrow, nchan)) > 0.2)
    acc = CellAccumulator(grid, nchan)
    acc.add(u[:100], v[:100], vis[:, :100], wgt[:100])  # two chunks
    acc.add(u[100:], v[100:], vis[:, 100:], wgt[100:])
    got, gw = acc.result()
    g = grid.size
    sw = np.zeros((4, nchan, g, g), complex)
    ww = np.zeros((nchan, g, g))
    for r in range(nrow):
        for c in range(nchan):
            if wgt[r, c] <= 0:
                continue
            iu, iv = int(np.rint(u[r, c] / 10)), int(np.rint(v[r, c] / 10))
            if abs(iu) > grid.M or abs(iv) > grid.M:
                continue
            for sgn, val in ((1, vis[:, r, c]), (-1, np.conj(vis[:, r, c]))):
                sw[:, c, grid.M + sgn * iv, grid.M + sgn * iu] += wgt[r, c] * val
                ww[c, grid.M + sgn * iv, grid.M + sgn * iu] += wgt[r, c]
    np.testing.assert_allclose(gw, ww, rtol=1e-12)
    expect = np.where(ww > 0, sw / np.where(ww > 0, ww, 1), 0)
    np.testing.assert_allclose(got, expect, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("taper", ["cos2", "hann"])
def test_wgrid_agrees_with_brute_force_kernel_sum(taper):
    """N(u_c) = 1/2 sum_k w_k [V_k K_{w_k}(u_k - u_c) + conj(V_k) K_{-w_k}(-u_k - u_c)]."""
    rng = np.random.default_rng(7)
    n = 5
    uvw = np.column_stack([rng.uniform(-150, 150, n), rng.uniform(-150, 150, n),
                           rng.uniform(-300, 300, n)])
    vis = (rng.normal(size=n) + 1j * rng.normal(size=n))
    wgt = rng.uniform(0.5, 2, n)
    grid, acc = _grid_one("wgrid", uvw, np.stack([vis] * 4)[:, :, None], wgt[:, None],
                          epsilon=1e-9, taper=taper)
    num, den = acc.numerators()
    expect_n = np.zeros((grid.size, grid.size), complex)
    expect_d = np.zeros_like(expect_n)
    for k in range(n):
        kp = wgrid_kernel_bruteforce(grid, *uvw[k], taper=taper)
        km = wgrid_kernel_bruteforce(grid, *(-uvw[k]), taper=taper)
        expect_n += 0.5 * wgt[k] * (vis[k] * kp + np.conj(vis[k]) * km)
        expect_d += 0.5 * wgt[k] * (kp + km)
    scale = np.abs(expect_d).max()
    assert np.abs(num[0, 0] - expect_n).max() < 1e-7 * scale
    assert np.abs(den[0] - expect_d).max() < 1e-7 * scale


def _far_source_samples(grid, l0_pix, m0_pix, w_planes):
    """Regular full-period uv sampling repeated at several w (non-coplanar baselines)."""
    n, dl = grid.npix_image, grid.pixel_rad
    l0, m0 = l0_pix * dl, m0_pix * dl
    n0 = np.sqrt(1 - l0 ** 2 - m0 ** 2)
    uu = (np.arange(n) - n // 2) * grid.cell
    U, V = (a.ravel() for a in np.meshgrid(uu, uu, indexing="ij"))
    uvw = np.concatenate([np.column_stack([U, V, np.full(U.size, w)]) for w in w_planes])
    vis = np.exp(-2j * np.pi * (uvw[:, 0] * l0 + uvw[:, 1] * m0 + uvw[:, 2] * (n0 - 1)))
    return uvw, vis, l0, m0


def test_w_correction_far_source_non_coplanar_legacy_hann():
    """Legacy ``hann`` kernel (1/cell box); the default kernel: tests/test_ps_fov.py."""
    grid = make_grid(16.0, 180.0)
    n = grid.npix_image
    # source 12 and -5 pixels off centre (1.3 deg, 0.6 deg): w (n - 1) up to 0.13 turns
    uvw, vis, l0, m0 = _far_source_samples(grid, 12, -5, (-250.0, 120.0, 400.0))
    taper = image_taper("hann", n)[n // 2 + 12, n // 2 - 5]
    c = grid.centres
    truth = taper * np.exp(-2j * np.pi * (c[None, :] * l0 + c[:, None] * m0))
    vis4 = np.stack([vis] * 4)[:, :, None]
    ones = np.ones((vis.size, 1))
    _, acc = _grid_one("wgrid", uvw, vis4, ones, epsilon=1e-9, taper="hann")
    got, w = acc.result()
    ok = w[0] > 0
    assert ok.sum() > 500
    amp = abs(taper)  # |truth| in every cell (0.114: the Hann taper at the source)
    err_corrected = np.abs(got[0, 0][ok] - truth[ok]).max() / amp
    assert err_corrected < 1e-6
    # the same samples gridded as if coplanar (w ignored) are visibly wrong
    flat = uvw.copy()
    flat[:, 2] = 0
    _, acc0 = _grid_one("wgrid", flat, vis4, ones, epsilon=1e-9, taper="hann")
    got0, _ = acc0.result()
    assert np.abs(got0[0, 0][ok] - truth[ok]).max() / amp > 0.1


def test_point_source_at_phase_centre_is_flux_in_every_cell():
    rng = np.random.default_rng(11)
    nrow = 400
    uvw = np.column_stack([rng.uniform(-180, 180, nrow), rng.uniform(-180, 180, nrow),
                           rng.uniform(-200, 200, nrow)])
    vis4 = np.zeros((4, nrow, 1), complex)
    vis4[0] = 2.0  # 2 Jy Stokes I at the phase centre
    _, acc = _grid_one("wgrid", uvw, vis4, rng.uniform(0.5, 1.5, (nrow, 1)), epsilon=1e-8)
    got, w = acc.result()
    ok = w[0] > 0
    np.testing.assert_allclose(got[0, 0][ok], 2.0, atol=1e-6)
    assert np.abs(got[1:, 0][:, ok]).max() < 1e-9


def test_stokes_weights_harmonic_mean_and_flags():
    w = np.array([[[1.0, 1.0, 1.0, 1.0], [1.0, 2.0, 4.0, 4.0], [1.0, 1.0, 1.0, 1.0],
                   [1.0, 0.0, 1.0, 1.0]]])
    f = np.zeros(w.shape, bool)
    f[0, 2, 1] = True
    got = stokes_weights(w, f)
    np.testing.assert_allclose(got[0], [1.0, 4 / (1 + 0.5 + 0.25 + 0.25), 0.0, 0.0])


def test_bad_grid_parameters():
    with pytest.raises(InputError, match="cell size"):
        make_grid(0.0, 100.0)
    with pytest.raises(InputError, match="unknown gridder"):
        make_accumulator("nearest", make_grid(16, 100), FREQ)
    with pytest.raises(InputError, match="unknown taper"):
        image_taper("gauss", 32)
    with pytest.raises(InputError, match="'none' was removed"):
        make_accumulator("wgrid", make_grid(16, 100), FREQ, taper="none")
