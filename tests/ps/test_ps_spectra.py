"""Delay transform, power spectra and cosmology against analytic answers and astropy."""

import numpy as np
import pytest
import xarray as xr

from msleak.errors import InputError
from msleak.constants import FREQ_21CM
from msleak.ps.cosmology import cosmo_at, get_cosmology
from msleak.ps.delay import delay_axis, delay_transform, spectral_window
from msleak.verbs.power import power_spectrum
from msleak.verbs.transform import transform
from msleak.ps.uvcube import uvcube_dataset

NCHAN = 50
DNU = 195312.5
FREQ = 150e6 + DNU * np.arange(NCHAN)


def _uvcube(vis4, weight=None, cell=16.0, uv=(30.0, 180.0), **attrs):
    """A uvcube Dataset from arrays (4, chan, v, u) on a grid of 2M+1 cells."""
    g = vis4.shape[-1]
    M = g // 2
    if weight is None:
        weight = np.ones(vis4.shape[1:])
    base = {"cell_lambda": cell, "uv_min_lambda": uv[0], "uv_max_lambda": uv[1],
            "fov_deg": np.degrees(1 / cell), "beam_area_sr": (1 / cell) ** 2}
    base.update(attrs)
    return uvcube_dataset(vis4, weight, FREQ[:vis4.shape[1]], np.arange(-M, M + 1) * cell, base)


def test_parseval_window_none():
    rng = np.random.default_rng(1)
    vis = rng.normal(size=(3, NCHAN, 4, 5)) + 1j * rng.normal(size=(3, NCHAN, 4, 5))
    vt, cw, norm, ok = delay_transform(vis, np.ones((NCHAN, 4, 5)), spectral_window("none", NCHAN))
    assert norm == 1.0 and ok.all()
    np.testing.assert_allclose((np.abs(vt) ** 2).sum(axis=1),
                               (np.abs(vis) ** 2).sum(axis=1) / NCHAN, rtol=1e-12)


def test_delay_axis_seconds():
    d = delay_axis(NCHAN, DNU)
    assert d[NCHAN // 2] == 0
    np.testing.assert_allclose(np.diff(d), 1 / (NCHAN * DNU), rtol=1e-12)


@pytest.mark.parametrize("window", ["none", "blackman-harris"])
def test_sinusoid_peaks_at_its_k_par(window):
    k = 7  # cycles across the band: delay k / (N dnu)
    g = 27
    spec = np.exp(2j * np.pi * k * np.arange(NCHAN) / NCHAN)
    vis4 = np.zeros((4, NCHAN, g, g), complex)
    vis4[1] = spec[:, None, None]  # Stokes Q only
    ps = power_spectrum(transform(_uvcube(vis4), window=window))
    cos = cosmo_at(0.5 * (FREQ[0] + FREQ[-1]))
    expected_kpar = cos.k_par(k / (NCHAN * DNU))
    p_q = np.nanmean(ps["power_jy2"].sel(stokes="Q").values, axis=1)
    assert abs(ps["k_par"].values[np.argmax(p_q)] - expected_kpar) < 1e-9 * expected_kpar
    np.testing.assert_allclose(ps["power_jy2"].sel(stokes="I").values, 0, atol=1e-25)
    if window == "none":  # one folded bin holds all: the mean of |V~(+tau)|^2 = 1 and
        # |V~(-tau)|^2 = 0 (a complex exponential has no negative-delay power)
        np.testing.assert_allclose(np.sort(p_q)[-2:], [0, 0.5], atol=1e-20)


@pytest.mark.parametrize("window", ["none", "blackman-harris"])
def test_white_noise_flat_at_predicted_level(window):
    rng = np.random.default_rng(5)
    g, sigma = 27, 0.3  # complex noise of variance sigma^2 per cell and channel
    vis4 = sigma / np.sqrt(2) * (rng.normal(size=(4, NCHAN, g, g))
                                 + 1j * rng.normal(size=(4, NCHAN, g, g)))
    ps = power_spectrum(transform(_uvcube(vis4), window=window))
    expected = sigma ** 2 / NCHAN  # E|V~|^2 / window_norm
    p1 = ps["power_jy2"].sel(stokes="I").values  # (k_par, k_perp)
    counts = ps["counts"].values
    mean = np.nansum(p1 * counts) / counts.sum()
    # ~ 50 x 280 voxels (correlated by the window): a few per cent
    assert abs(mean / expected - 1) < 0.05
    per_kpar = np.nansum(p1 * counts, axis=1) / counts.sum(axis=1)
    assert np.all(np.abs(per_kpar / expected - 1) < 0.3)  # flat


def test_k_perp_k_par_match_astropy():
    from astropy import constants as const
    from astropy import units as u
    from astropy.cosmology import Planck18, WMAP9

    for cosmo_ap, name in ((Planck18, "Planck18"), (WMAP9, "WMAP9")):
        nu = 155e6
        z = 1420.405751768e6 / nu - 1
        c = cosmo_at(nu, name)
        b = np.array([30.0, 100.0, 180.0])
        tau = np.array([1e-7, 2.5e-6])
        dc = cosmo_ap.comoving_distance(z)
        expect_perp = (2 * np.pi * b / dc).to_value(1 / u.Mpc)
        hz = cosmo_ap.H(z)
        expect_par = (2 * np.pi * tau * u.s * cosmo_ap.H0 * 1420.405751768e6 * u.Hz
                      * cosmo_ap.efunc(z) / (const.c * (1 + z) ** 2)).to_value(1 / u.Mpc)
        np.testing.assert_allclose(c.k_perp(b), expect_perp, rtol=1e-6)
        np.testing.assert_allclose(c.k_par(tau), expect_par, rtol=1e-6)
        # wedge slope: sin(theta) D_c H(z) / (c (1 + z)) (the same as D_c E / (D_H (1+z)))
        for theta in (90.0, 2.0):
            slope = (np.sin(np.radians(theta)) * dc * hz / (const.c * (1 + z))).decompose()
            assert abs(c.wedge_slope(theta) / slope.value - 1) < 1e-6


def test_point_source_at_centre_only_k_par_zero():
    from msleak.constants import SPEED_OF_LIGHT
    from msleak.ps.gridding import make_accumulator, make_grid

    rng = np.random.default_rng(2)
    nrow, nchan = 600, 16
    freq = FREQ[:nchan]
    grid = make_grid(16.0, 180.0)
    acc = make_accumulator("wgrid", grid, freq, epsilon=1e-8)
    uvw_m = np.column_stack([rng.uniform(-100, 100, nrow), rng.uniform(-100, 100, nrow),
                             rng.uniform(-60, 60, nrow)])  # metres: ~ +-50 wavelengths
    b = np.hypot(uvw_m[:, 0], uvw_m[:, 1])[:, None] * freq / SPEED_OF_LIGHT
    wgt = ((b > 10) & (b < 60)).astype(float)
    vis4 = np.zeros((4, nrow, nchan), complex)
    vis4[0] = 1.0
    acc.add(uvw_m, vis4, wgt)
    vis, weight = acc.result()
    ds = _uvcube(vis, weight, uv=(10.0, 60.0))
    ps = power_spectrum(transform(ds, window="none"), bins=3)
    p = ps["power_jy2"].values  # (stokes, k_par, k_perp)
    assert np.nanmin(p[0, 0]) > 0.99 and np.nanmax(p[0, 0]) < 1.01
    assert np.nanmax(p[0, 1:]) < 1e-12
    assert np.nanmax(np.abs(p[1:])) < 1e-12


def test_cross_power_removes_noise_bias():
    rng = np.random.default_rng(9)
    g = 27
    signal = np.zeros((4, NCHAN, g, g), complex)
    signal[0] = 1.0
    na, nb = (0.5 * (rng.normal(size=signal.shape) + 1j * rng.normal(size=signal.shape))
              for _ in range(2))
    ds = _uvcube(signal + 0.5 * (na + nb))
    ds["vis_a"] = (ds["vis"].dims, np.concatenate([signal + na, (signal + na)[1:2] * 0], 0))
    ds["vis_b"] = (ds["vis"].dims, np.concatenate([signal + nb, (signal + nb)[1:2] * 0], 0))
    ds["weight_a"] = ds["weight"]
    ds["weight_b"] = ds["weight"]
    dl = transform(ds, window="none")
    cross = power_spectrum(dl)
    auto = power_spectrum(dl, cross=False)
    assert cross.attrs["cross_power"] == 1
    # noise power 0.5^2 * 2 / N per half: gone in the cross-power (|mean| << that)
    level = 0.5 / NCHAN
    assert abs(np.nanmean(cross["power_jy2"].sel(stokes="I").values[1:])) < 0.05 * level
    assert np.nanmean(auto["power_jy2"].sel(stokes="I").values[1:]) > 0.3 * level


def test_mk2_normalisation_formula():
    from msleak.constants import BOLTZMANN
    from msleak.ps.cosmology import jy2_to_mk2_mpc3

    c = cosmo_at(155e6)
    lam = 299792458.0 / 155e6
    omega, bw = 0.01, 10e6
    x, y = c.dc_mpc, c.dh_mpc * (1 + c.z) ** 2 / (FREQ_21CM * c.efunc)
    expect = bw * (1e-26 * lam ** 2 / (2 * BOLTZMANN)) ** 2 * x ** 2 * y / omega * 1e6
    assert jy2_to_mk2_mpc3(c, omega, bw) == pytest.approx(expect, rel=1e-12)


def test_bad_inputs():
    with pytest.raises(InputError, match="unknown window"):
        spectral_window("kaiser-bessel-x", 10)
    with pytest.raises(InputError, match="unknown cosmology"):
        get_cosmology("Planck99")
    with pytest.raises(InputError, match="21-cm"):
        cosmo_at(2e9)
    empty = _uvcube(np.zeros((4, NCHAN, 5, 5), complex), np.zeros((NCHAN, 5, 5)))
    with pytest.raises(InputError, match="empty"):
        transform(empty)
    assert isinstance(empty, xr.Dataset)
