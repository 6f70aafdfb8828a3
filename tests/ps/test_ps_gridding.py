"""Gridders of msleak.ps.gridding against answers known in advance and brute-force sums."""

import numpy as np
import pytest

from msleak.errors import InputError
from msleak.constants import SPEED_OF_LIGHT
from msleak.ps.gridding import CellAccumulator, make_accumulator, make_grid, stokes_weights

FREQ = np.array([150e6])
LAM = SPEED_OF_LIGHT / FREQ[0]


def _grid_one(gridder, uvw_lambda, vis4, wgt, freq=FREQ, epsilon=1e-10):
    grid = make_grid(16.0, 180.0)
    acc = make_accumulator(gridder, grid, freq, epsilon=epsilon)
    scale = freq / SPEED_OF_LIGHT
    uvw_m = uvw_lambda * SPEED_OF_LIGHT / freq[0]
    if gridder == "cell":
        acc.add(uvw_m[:, :1] * scale, uvw_m[:, 1:2] * scale, vis4, wgt)
    else:
        acc.add(uvw_m, vis4, wgt)
    return grid, acc


@pytest.mark.parametrize("gridder", ["cell", "wgrid"])
def test_one_visibility_lands_in_its_cell_and_conjugate_in_mirror(gridder):
    vis4 = np.array([0.7 + 0.3j, -0.2 + 0.1j, 0.05j, 0.4]).reshape(4, 1, 1)
    grid, acc = _grid_one(gridder, np.array([[3 * 16.0, -2 * 16.0, 0.0]]), vis4,
                          np.array([[2.5]]))
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


def _kernel_bruteforce(grid, u, v, w):
    """The ``wgrid`` kernel of one sample on the output grid, summed directly:
    ``K(v_c, u_c) = sum_pix R exp(2 pi i ((u - u_c) l + (v - v_c) m + w (n - 1)))`` over the
    4 / cell box, R = T(l cell) T(m cell), T(x) = sinc(x) / (1 - x^2) (the Fourier
    transform of the one-cell cos^2 uv kernel; 1/2 at |x| = 1)."""
    n, dl = 4 * grid.npix_image, grid.pixel_rad
    x = (np.arange(n) - n // 2) * dl
    t = x * grid.cell
    with np.errstate(divide="ignore", invalid="ignore"):
        r1 = np.where(np.isclose(np.abs(t), 1.0), 0.5, np.sinc(t) / (1 - t * t))
    l, m = np.meshgrid(x, x, indexing="ij")
    nn = np.sqrt(1.0 - l * l - m * m) - 1.0
    c = grid.centres
    ex_u = np.exp(2j * np.pi * np.outer(u - c, x))  # (u_c, l)
    ex_v = np.exp(2j * np.pi * np.outer(v - c, x))  # (v_c, m)
    ph = np.exp(2j * np.pi * w * nn) * np.outer(r1, r1)  # (l, m)
    return np.einsum("al,lm,bm->ba", ex_u, ph, ex_v)


def test_wgrid_agrees_with_brute_force_kernel_sum():
    """N(u_c) = 1/2 sum_k w_k [V_k K_{w_k}(u_k - u_c) + conj(V_k) K_{-w_k}(-u_k - u_c)]."""
    rng = np.random.default_rng(7)
    n = 5
    uvw = np.column_stack([rng.uniform(-150, 150, n), rng.uniform(-150, 150, n),
                           rng.uniform(-300, 300, n)])
    vis = (rng.normal(size=n) + 1j * rng.normal(size=n))
    wgt = rng.uniform(0.5, 2, n)
    grid, acc = _grid_one("wgrid", uvw, np.stack([vis] * 4)[:, :, None], wgt[:, None],
                          epsilon=1e-9)
    num, den = acc.numerators()
    expect_n = np.zeros((grid.size, grid.size), complex)
    expect_d = np.zeros_like(expect_n)
    for k in range(n):
        kp = _kernel_bruteforce(grid, *uvw[k])
        km = _kernel_bruteforce(grid, *(-uvw[k]))
        expect_n += 0.5 * wgt[k] * (vis[k] * kp + np.conj(vis[k]) * km)
        expect_d += 0.5 * wgt[k] * (kp + km)
    scale = np.abs(expect_d).max()
    assert np.abs(num[0, 0] - expect_n).max() < 1e-7 * scale
    assert np.abs(den[0] - expect_d).max() < 1e-7 * scale


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


def test_wgrid_channels_at_once_give_the_same_sums():
    """Gridding several channels at once (two buffered blocks, three sets, one sample
    non-finite in one set, flagged samples) adds exactly what one channel at a time does."""
    rng = np.random.default_rng(11)
    nrow, nchan, nsets = 400, 7, 3
    freq = 150e6 + 195312.5 * np.arange(nchan)
    grid = make_grid(16.0, 120.0)
    uvw = rng.uniform(-200, 200, (nrow, 3)) * [1, 1, 0.2]
    vis = rng.normal(size=(nsets, 4, nrow, nchan)) + 1j * rng.normal(size=(nsets, 4, nrow, nchan))
    vis[1, 2, 5, 3] = np.nan
    wgt = rng.uniform(0.5, 2, (nrow, nchan)) * (rng.uniform(size=(nrow, nchan)) > 0.1)
    sums = []
    for threads in (1, 3, 16):
        acc = make_accumulator("wgrid", grid, freq, nsets=nsets, channel_threads=threads)
        acc.add(uvw[:150], vis[:, :, :150], wgt[:150])
        acc.add(uvw[150:], vis[:, :, 150:], wgt[150:])
        sums.append([np.concatenate([num, den[None]]) for num, den in
                     (acc.numerators(k) for k in range(nsets))])
    assert np.count_nonzero(sums[0][0]) > 0
    for other in sums[1:]:
        for a, b in zip(sums[0], other):
            assert np.array_equal(a, b)
