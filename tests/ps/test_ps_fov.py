"""Field of view of the default ``wgrid`` gridder: what a gridded cell sees.

Answers known in advance: the documented response R(l, m) = T(l cell) T(m cell),
T(x) = sinc(x) / (1 - x^2), for dense regular sampling (exact), its coherent mean on
LOFAR tracks, flat-spectrum power R^2 S^2 at k_par = 0 only, w-correction of far
sources, noise bounds of the kernel-weighted mean, and the Omega / primary-beam records.
"""

import math

import numpy as np
import pytest

from msleak.constants import SPEED_OF_LIGHT
from msleak.ps.gridding import (MASK_FRACTION, airy_power, beam_area_model,
                                BOX_FACTOR, gridder_response, make_accumulator, make_grid,
                                primary_fwhm_deg, response_attrs)

CELL = 16.0
F0 = 150e6
LAM = SPEED_OF_LIGHT / F0


def _t(x):
    """sinc(x) / (1 - x^2) written out independently (limit 1/2 at |x| = 1)."""
    x = float(x)
    if abs(abs(x) - 1) < 1e-9:
        return 0.5
    if abs(x) >= 2:
        return 0.0
    return 1.0 if x == 0 else math.sin(math.pi * x) / (math.pi * x) / (1 - x * x)


def _regular_uv(grid, w_planes=(0.0,)):
    """Full-period regular (u, v) sampling of the cos2 box (spacing cell / 4), in wavelengths."""
    n = BOX_FACTOR * grid.npix_image
    uu = (np.arange(n) - n // 2) * grid.cell / BOX_FACTOR
    U, V = (a.ravel() for a in np.meshgrid(uu, uu, indexing="ij"))
    return np.concatenate([np.column_stack([U, V, np.full(U.size, w)]) for w in w_planes])


def _source_vis(uvw_lambda, l, m):
    n = math.sqrt(1 - l * l - m * m)
    return np.exp(-2j * np.pi * (uvw_lambda[:, 0] * l + uvw_lambda[:, 1] * m
                                 + uvw_lambda[:, 2] * (n - 1)))


def _grid(uvw_lambda, vis, freq=np.array([F0]), wgt=None, epsilon=1e-9):
    grid = make_grid(CELL, 180.0)
    acc = make_accumulator("wgrid", grid, freq, epsilon=epsilon)
    if wgt is None:
        wgt = np.ones((uvw_lambda.shape[0], freq.size))
    acc.add(uvw_lambda * LAM, np.stack([vis] * 4)[:, :, None], wgt)
    got, weight = acc.result()
    return grid, got, weight


def _pixel(grid, deg):
    """A direction cosine on a pixel of the image box, near ``deg`` degrees."""
    return round(math.radians(deg) / grid.pixel_rad) * grid.pixel_rad


def test_documented_profile_values():
    g = make_grid(CELL, 180.0)
    for r, want in ((0.5, 0.975), (1, 0.904), (2, 0.663), (3, 0.387), (5, 0.052)):
        got = gridder_response("wgrid", math.radians(r), 0.0, g.cell) ** 2
        assert abs(got - want) < 1e-3
    assert gridder_response("wgrid", 1 / CELL, 0.0, CELL) == pytest.approx(0.5)
    assert gridder_response("wgrid", 2.01 / CELL, 0.0, CELL) == 0.0


@pytest.mark.parametrize("deg", [0.5, 1.0, 2.0, 3.0, 5.0])
def test_dense_regular_sampling_gives_documented_response(deg):
    """Source at (0.8, 0.6) x deg: every cell = R(l, m) x its w = 0 visibility (1e-6)."""
    grid = make_grid(CELL, 180.0)
    l, m = _pixel(grid, 0.8 * deg), _pixel(grid, -0.6 * deg)
    uvw = _regular_uv(grid)
    _, got, weight = _grid(uvw, _source_vis(uvw, l, m))
    c = grid.centres
    truth = _t(l * CELL) * _t(m * CELL) * np.exp(-2j * np.pi * (c[None, :] * l + c[:, None] * m))
    ok = weight[0] > 0
    assert ok.all()  # dense sampling: no cell is empty or masked
    assert np.abs(got[0, 0] - truth).max() < 1e-6
    # the old narrow-field behaviour would give < 0.02 of the visibility from 2 deg on
    assert abs(_t(l * CELL) * _t(m * CELL)) > 0.2


@pytest.mark.parametrize("deg", [3.0, 5.0])
def test_w_correction_far_source_non_coplanar(deg):
    """Regular (u, v) repeated on w planes -250, 120, 400: exact with the w-term (1e-6 of
    the visibility), > 10% off when the same samples are gridded as coplanar."""
    grid = make_grid(CELL, 180.0)
    l, m = _pixel(grid, 0.6 * deg), _pixel(grid, 0.8 * deg)
    uvw = _regular_uv(grid, (-250.0, 120.0, 400.0))
    vis = _source_vis(uvw, l, m)
    c = grid.centres
    r = _t(l * CELL) * _t(m * CELL)
    truth = r * np.exp(-2j * np.pi * (c[None, :] * l + c[:, None] * m))
    _, got, _ = _grid(uvw, vis)
    assert np.abs(got[0, 0] - truth).max() < 1e-6 * abs(r)
    flat = uvw.copy()
    flat[:, 2] = 0
    _, got0, w0 = _grid(flat, vis)
    ok = w0[0] > 0
    assert np.abs(got0[0, 0][ok] - truth[ok]).max() > 0.1 * abs(r)


def _lofar_uvw(pattern, hours, step_s):
    """-UVW (kernel convention, m) of LOFAR HBA core fields tracking 3C196."""
    from msleak.telescope.layouts import lofar_hba_core
    from msleak.telescope.uvw import antenna_uvw

    lay = lofar_hba_core(pattern)
    times = 4.9e9 + np.arange(0.0, hours * 3600, step_s)
    a = antenna_uvw(lay.positions, times, math.radians(123.4), math.radians(48.2))
    p, q = np.triu_indices(len(lay), 1)
    return -(a[:, q] - a[:, p]).reshape(-1, 3)


@pytest.fixture(scope="module")
def lofar_tracks():
    """14 HBA fields, 2 h at 120 s (sparse) and 28 fields, 6 h (denser), one channel."""
    return {"sparse": _lofar_uvw("CS00[1-7]HBA*", 2, 120.0),
            "dense": _lofar_uvw("CS0[0-2]*HBA*", 6, 120.0)}


@pytest.mark.parametrize("case", ["sparse", "dense"])
def test_lofar_tracks_follow_documented_response(lofar_tracks, case):
    """On real LOFAR tracks (non-coplanar) the cell-averaged coherent response equals R to
    0.05 + 0.04 deg (measured, sparse: 0.977/0.926/0.744/0.499/0.102 vs R
    0.987/0.951/0.816/0.629/0.257 at 0.5/1/2/3/5 deg; dense: within 0.05); no cell's
    response exceeds 2 (w-projected kernels are not strictly positive); the phase centre
    gives exactly 1 everywhere."""
    uvw_m = lofar_tracks[case]
    u = uvw_m / LAM
    b = np.hypot(u[:, 0], u[:, 1])
    wgt = ((b >= 30) & (b <= 180)).astype(float)[:, None]
    grid = make_grid(CELL, 180.0)
    c = grid.centres
    U, V = np.meshgrid(c, c)
    inside = (np.hypot(U, V) >= 30) & (np.hypot(U, V) <= 180)
    for deg in (0.0, 0.5, 1.0, 2.0, 3.0, 5.0):
        l, m = math.radians(0.8 * deg), math.radians(0.6 * deg)
        _, got, weight = _grid(u, _source_vis(u, l, m), wgt=wgt, epsilon=1e-8)
        ok = (weight[0] > 0) & inside
        assert ok.sum() > 150
        resp = got[0, 0][ok] / np.exp(-2j * np.pi * (U[ok] * l + V[ok] * m))
        r = _t(l * CELL) * _t(m * CELL)
        if deg == 0:
            np.testing.assert_allclose(resp, 1.0, atol=1e-6)
        tol = 0.05 + 0.04 * deg if case == "sparse" else 0.05
        assert abs(resp.real.mean() - r) < tol, (deg, resp.real.mean(), r)
        assert np.abs(resp).max() < 2.0


def test_flat_spectrum_source_power_follows_response_only():
    """Flat-spectrum 1 Jy source, regular sampling in wavelengths in every channel: the
    delay power is R^2 at k_par = 0 in every k_perp bin (rel 1e-5) and zero elsewhere,
    so power / R^2 does not depend on where the source is."""
    from msleak.verbs.power import power_spectrum
    from msleak.verbs.transform import transform
    from msleak.ps.uvcube import uvcube_dataset

    grid = make_grid(CELL, 180.0)
    nchan = 6
    freq = F0 + 195312.5 * np.arange(nchan)
    uvw_l = _regular_uv(grid)
    nrow = uvw_l.shape[0]
    ratios = []
    for deg in (0.5, 2.0, 4.0):
        l, m = _pixel(grid, deg), 0.0
        acc = make_accumulator("wgrid", grid, freq, epsilon=1e-9)
        for ch in range(nchan):  # the same wavelengths in every channel
            wgt = np.zeros((nrow, nchan))
            wgt[:, ch] = 1.0
            vis = np.zeros((4, nrow, nchan), complex)
            vis[0, :, ch] = _source_vis(uvw_l, l, m)
            acc.add(uvw_l * SPEED_OF_LIGHT / freq[ch], vis, wgt)
        v4, w = acc.result()
        attrs = {"cell_lambda": CELL, "uv_min_lambda": 30.0, "uv_max_lambda": 180.0,
                 **response_attrs("wgrid", CELL)}
        ps = power_spectrum(transform(uvcube_dataset(v4, w, freq, grid.centres, attrs),
                                             window="none"), bins=5)
        p = ps["power_jy2"].values[0]  # (k_par, k_perp)
        r2 = _t(l * CELL) ** 2
        np.testing.assert_allclose(p[0], r2, rtol=1e-5)
        assert np.abs(p[1:]).max() < 1e-9 * r2
        ratios.append(p[0].mean() / r2)
    np.testing.assert_allclose(ratios, 1.0, rtol=1e-5)


def test_noise_of_kernel_weighted_mean_is_bounded(lofar_tracks):
    """Complex white noise (sigma per sample) on sparse LOFAR tracks, w = 0: the variance
    of a used cell lies between sigma^2 / W (W its natural weight: the nearest-cell mean)
    and sigma^2 / (MASK_FRACTION W) (positive kernel, masked rims), 40 realisations."""
    uvw_m = lofar_tracks["sparse"].copy()
    uvw_m[:, 2] = 0.0
    u = uvw_m / LAM
    b = np.hypot(u[:, 0], u[:, 1])
    wgt = ((b >= 30) & (b <= 180)).astype(float)[:, None]
    rng = np.random.default_rng(4)
    grid = make_grid(CELL, 180.0)
    acc0 = make_accumulator("wgrid", grid, np.array([F0]), epsilon=1e-7)
    acc0.add(uvw_m, np.zeros((4, u.shape[0], 1), complex), wgt)
    vals = []
    for k in range(40):
        noise = (rng.normal(size=u.shape[0]) + 1j * rng.normal(size=u.shape[0])) / math.sqrt(2)
        acc = make_accumulator("wgrid", grid, np.array([F0]), epsilon=1e-7)
        vis = np.zeros((4, u.shape[0], 1), complex)
        vis[0, :, 0] = noise
        acc.add(uvw_m, vis, wgt)
        got, weight = acc.result()
        vals.append(got[0, 0])
    ok = weight[0] > 0
    # a cell gets each sample once (and the mirror cell its conjugate): the cell's noise
    # var over realisations, times W, is sum K^2 W / (sum K)^2 in [1, 1 / MASK_FRACTION]
    var = np.var(np.array(vals)[:, ok], axis=0) * weight[0][ok]
    assert np.median(var) > 1.0 and np.median(var) < 4.0
    assert var.max() < 1.3 / MASK_FRACTION  # 30% Monte-Carlo margin on 40 draws
    assert np.percentile(var, 2) > 0.6


def test_beam_area_and_primary_fwhm_independent_integrals():
    from scipy.optimize import brentq
    from scipy.special import j1

    # FWHM of the Airy power beam from its definition
    half = brentq(lambda t: (2 * j1(math.pi * CELL * t) / (math.pi * CELL * t)) ** 2 - 0.5,
                  1e-4, 1.0 / CELL)
    assert primary_fwhm_deg(CELL) == pytest.approx(math.degrees(2 * half), rel=1e-4)
    assert airy_power(np.array([half]), CELL)[0] == pytest.approx(0.5, rel=1e-6)
    # Omega = int A^2 R^2 in polar coordinates (a different discretisation)
    for gridder in ("wgrid", "cell"):
        r = np.linspace(1e-7, 8.0 / CELL, 4001)
        phi = np.linspace(0, 2 * np.pi, 721)[:-1]
        rr, pp = np.meshgrid(r, phi)
        x = np.pi * CELL * rr
        a = (2 * j1(x) / x) ** 2
        resp = gridder_response(gridder, rr * np.cos(pp), rr * np.sin(pp), CELL)
        omega = np.trapezoid((a ** 2 * resp ** 2 * rr).mean(axis=0) * 2 * np.pi, r)
        assert beam_area_model(gridder, CELL) == pytest.approx(omega, rel=3e-3)
    # the cell gridder's Omega now includes the station beam: well below 1 / cell^2
    assert beam_area_model("cell", CELL) < 0.5 / CELL ** 2


def test_primary_wedge_follows_beam_by_default():
    from msleak.verbs.power import power_spectrum
    from msleak.verbs.transform import transform
    from msleak.ps.uvcube import uvcube_dataset

    g = 27
    freq = F0 + 195312.5 * np.arange(8)
    rng = np.random.default_rng(1)
    vis = rng.normal(size=(4, 8, g, g)) + 1j * rng.normal(size=(4, 8, g, g))
    centres = (np.arange(g) - g // 2) * CELL
    attrs = {"cell_lambda": CELL, "uv_min_lambda": 30.0, "uv_max_lambda": 180.0,
             **response_attrs("wgrid", CELL)}
    ps = power_spectrum(transform(uvcube_dataset(vis, np.ones((8, g, g)), freq,
                                                        centres, attrs)))
    assert ps.attrs["primary_theta_deg"] == pytest.approx(primary_fwhm_deg(CELL) / 2)
    assert ps.attrs["beam_area_sr"] == pytest.approx(beam_area_model("wgrid", CELL))
