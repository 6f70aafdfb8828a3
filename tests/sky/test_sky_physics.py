"""Physics of the foreground generator: Burn slab, RM synthesis, spectral slopes, seeds."""

import math

import numpy as np
import pytest

from msleak.errors import InputError
from msleak.sky import ForegroundParams, generate_foreground_cube, polarized_brightness
from msleak.sky.fields import gaussian_random_field, solenoidal_vector_field, wavenumbers

C = 299_792_458.0


def burn(p0, chi0, F, freq):
    """Burn (1966), written here independently of msleak."""
    lam2 = (C / freq) ** 2
    x = F * lam2
    return p0 * np.exp(2j * (chi0 + x / 2)) * np.sin(x) / x


@pytest.mark.parametrize("b_par", [0.05, 0.3, -0.2])
def test_uniform_slab_through_generator_matches_burn(b_par):
    # uniform medium: no random field, no log-normal fluctuations
    params = ForegroundParams(b_regular_ug=(0.0, 2.0, b_par), b_random_rms_ug=0.0,
                              ne_sigma_ln=0.0, ncr_sigma_ln=0.0, ncells_los=40,
                              ne_mean_cm3=0.01, depth_pc=1000.0, p_rms_k=2.0)
    cube = generate_foreground_cube(npix=4, nchan=50, seed=3, params=params)
    freq = cube.freq
    F = 0.812 * 0.01 * b_par * 1000.0
    # chi0: B along north -> E vector along east -> 90 deg (IAU angle from north via east)
    shape = burn(1.0, math.pi / 2, F, freq) * (freq / 150e6) ** -params.beta
    ref = burn(1.0, math.pi / 2, F, np.array([150e6]))[0]
    expected = shape * (2.0 / abs(ref))        # normalisation: |P(150 MHz)| = 2 K
    # Q, U are referred to the local North of each pixel: turn them back to the image +y
    # axis, over which the slab is uniform (psi from the WCS is tested in test_sky_polframe)
    from msleak.sky.cube import y_axis_position_angle

    psi = y_axis_position_angle(cube.wcs, cube.npix)
    p = (cube.data[0] + 1j * cube.data[1]) * np.exp(-2j * psi)   # (nchan, y, x)
    err = np.abs(p - expected[:, None, None]).max() / np.abs(expected).max()
    assert err < 1e-3
    # the depolarization is real (not a trivial constant) for the larger rotation
    if abs(F) > 1:
        assert np.ptp(np.abs(expected)) > 0.1 * np.abs(expected).max()


def test_slab_any_number_of_cells_kernel():
    freq = np.linspace(115e6, 190e6, 64)
    F, chi0 = 3.7, 0.3
    for nz in (1, 7, 128):
        amp = np.full((nz, 1, 1), 1.0 / nz)
        chi = np.full((nz, 1, 1), chi0)
        dphi = np.full((nz, 1, 1), F / nz)
        p = polarized_brightness(amp, chi, dphi, freq)[:, 0, 0]
        assert np.abs(p - burn(1.0, chi0, F, freq)).max() < 1e-3


def rm_synthesis_peak(p, freq, phis):
    lam2 = (C / freq) ** 2
    l0 = lam2.mean()
    fd = np.exp(-2j * np.outer(phis, lam2 - l0)) @ p / lam2.size
    return phis[np.argmax(np.abs(fd))]


@pytest.mark.parametrize("phi0", [-8.3, 2.1, 11.7])
def test_rm_synthesis_recovers_faraday_thin_screen(phi0):
    # emission only in the far cell, a rotating but non-emitting screen in front of it
    freq = 150e6 + np.arange(50) * 195312.5
    nz = 20
    amp = np.zeros((nz, 1, 1))
    amp[-1] = 1.5
    chi = np.full((nz, 1, 1), 0.4)
    dphi = np.zeros((nz, 1, 1))
    dphi[:-1] = phi0 / (nz - 1)
    p = polarized_brightness(amp, chi, dphi, freq)[:, 0, 0]
    lam2 = (C / freq) ** 2
    resolution = 2 * math.sqrt(3) / np.ptp(lam2)     # FWHM of the RMSF, ~7 rad/m^2
    peak = rm_synthesis_peak(p, freq, np.arange(-40, 40, 0.01))
    assert abs(peak - phi0) < resolution / 2
    assert abs(peak - phi0) < 0.05                   # noise-free: essentially exact


def fit_slope(fields, cell, kmin_frac=0.1, kmax_frac=0.6):
    """Least-squares slope of log sum_i |f_i,k|^2 against log k over all modes."""
    fields = np.atleast_1d(fields).reshape(-1, *np.shape(fields)[-3:])
    power = sum(np.abs(np.fft.rfftn(f)) ** 2 for f in fields)
    kz, ky, kx = wavenumbers(fields.shape[1:], cell)
    k = np.sqrt(kz**2 + ky**2 + kx**2)
    knyq = min(np.pi / c for c in cell)
    m = (k > kmin_frac * knyq) & (k < kmax_frac * knyq)
    return np.polyfit(np.log(k[m]), np.log(power[m]), 1)[0]


@pytest.mark.parametrize("alpha", [3.0, 11 / 3])
@pytest.mark.parametrize("cell", [(1.0, 1.0, 1.0), (10.0, 5.0, 5.0)])
def test_random_field_slopes(alpha, cell):
    rng = np.random.default_rng(11)
    g = gaussian_random_field((48, 48, 48), cell, alpha, rng)
    assert abs(g.mean()) < 1e-12 and abs(g.std() - 1) < 1e-12
    assert abs(fit_slope(g, cell) + alpha) < 0.1
    b = solenoidal_vector_field((48, 48, 48), cell, alpha, rng)
    # the power of the vector field (a single component vanishes for k along its axis)
    assert abs(fit_slope(b, cell) + alpha) < 0.1
    # divergence-free: k . B_k = 0 for every mode
    kz, ky, kx = wavenumbers((48, 48, 48), cell)
    div = kz * np.fft.rfftn(b[0]) + ky * np.fft.rfftn(b[1]) + kx * np.fft.rfftn(b[2])
    assert np.abs(div).max() < 1e-8 * np.abs(np.fft.rfftn(b[0])).max()


def small_params(**kw):
    return ForegroundParams(ncells_los=16, **kw)


def test_same_seed_same_cube_bit_for_bit():
    a = generate_foreground_cube(npix=12, nchan=5, seed=42, params=small_params())
    b = generate_foreground_cube(npix=12, nchan=5, seed=42, params=small_params())
    c = generate_foreground_cube(npix=12, nchan=5, seed=43, params=small_params())
    assert np.array_equal(a.data, b.data)
    assert not np.allclose(a.data, c.data)
    assert a.meta["SEED"] == 42
    # unseeded: the recorded entropy reproduces the cube
    d = generate_foreground_cube(npix=12, nchan=5, seed=None, params=small_params())
    e = generate_foreground_cube(npix=12, nchan=5, seed=d.meta["SEED"], params=small_params())
    assert np.array_equal(d.data, e.data)


def test_calibration_targets_default_physics():
    cube = generate_foreground_cube(npix=24, nchan=3, seed=0, params=ForegroundParams())
    p0 = cube.data[0, 0] + 1j * cube.data[1, 0]       # channel 0 is 150 MHz
    assert math.isclose(np.sqrt(np.mean(np.abs(p0) ** 2)), 3.0, rel_tol=1e-9)
    assert 2.0 < cube.meta["PHISTD"] < 10.0            # Faraday depths of order +-10
    assert cube.meta["PHIMIN"] < -3 and cube.meta["PHIMAX"] > 3


@pytest.mark.parametrize("kw,match", [
    (dict(depth_pc=-1.0), "depth"),
    (dict(ncells_los=1), "ncells"),
    (dict(electron_index=0.5), "electron_index"),
    (dict(b_random_rms_ug=-1.0), "b_random"),
    (dict(p_rms_k=0.0), "p_rms"),
])
def test_bad_parameters(kw, match):
    with pytest.raises(InputError, match=match):
        generate_foreground_cube(npix=4, nchan=2, seed=1, params=ForegroundParams(**kw))
