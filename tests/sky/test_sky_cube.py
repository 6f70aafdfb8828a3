"""Cube geometry, units, FITS I/O and voxel sources."""

import math

import numpy as np
import pytest
from astropy.io import fits

from msleak.errors import InputError
from msleak.adapters.sky_fits import read_cube, write_cube
from msleak.sky import (PointSources, SkyCube, convert_units, crop, crop_npix_for_fov,
                        make_celestial_wcs, pixel_solid_angle, recentre, sources_from_cube)
from msleak.sky.cube import kelvin_to_jansky


def toy_cube(npix=10, nchan=3, pixel_deg=0.3, ra=30.0, dec=60.0, units="K", seed=0):
    rng = np.random.default_rng(seed)
    data = rng.normal(size=(2, nchan, npix, npix))
    freq = 150e6 + np.arange(nchan) * 195312.5
    return SkyCube(data=data, freq=freq, stokes=("Q", "U"),
                   wcs=make_celestial_wcs(npix, npix, pixel_deg, ra, dec), units=units)


def test_crop_sizes_default_cube():
    # rule: nearest integer of the cube's parity (documented in docs/sky.md)
    assert [crop_npix_for_fov(f, 0.3, 50) for f in (15, 9, 4)] == [50, 30, 14]
    cube = toy_cube(npix=50, nchan=1)
    assert crop(cube, fov_deg=15).npix == (50, 50)
    # the paper's crops of the 15 deg cube, by pixel count
    for n in (28, 16):
        c = crop(cube, npix=n)
        assert c.npix == (n, n)
        k = (50 - n) // 2
        assert np.array_equal(c.data, cube.data[:, :, k:k + n, k:k + n])
        # the cropped pixels keep their sky positions
        ra1, dec1 = c.wcs.all_pix2world([0.0], [0.0], 0)
        ra2, dec2 = cube.wcs.all_pix2world([float(k)], [float(k)], 0)
        assert np.allclose([ra1, dec1], [ra2, dec2], atol=1e-12)
    with pytest.raises(InputError, match="larger than the cube"):
        crop(cube, fov_deg=16)
    with pytest.raises(InputError, match="parity"):
        crop(cube, npix=27)


@pytest.mark.parametrize("ra,dec", [(0.0, 90.0), (123.4, 48.2), (250.0, -30.0), (10.0, 0.0)])
def test_wcs_round_trip(ra, dec):
    w = make_celestial_wcs(50, 50, 0.3, ra, dec)
    y, x = np.mgrid[0:50, 0:50].astype(float)
    a, d = w.all_pix2world(x, y, 0)
    x2, y2 = w.all_world2pix(a, d, 0)
    assert np.abs(x2 - x).max() < 1e-8 and np.abs(y2 - y).max() < 1e-8


@pytest.mark.parametrize("ra0,dec0", [(0.0, 90.0), (123.4, 48.2), (300.0, -45.0)])
def test_voxel_sources_at_direction_cosines(ra0, dec0):
    npix, pix = 16, 0.5
    cube = toy_cube(npix=npix, ra=10.0, dec=20.0, pixel_deg=pix)
    src = sources_from_cube(recentre(cube, math.radians(ra0), math.radians(dec0)))
    assert len(src) == npix * npix
    l_, m_, n_ = src.lmn(math.radians(ra0), math.radians(dec0))
    # SIN: pixel offsets from the reference are the direction cosines, RA to the left
    y, x = np.mgrid[0:npix, 0:npix]
    ref = (npix - 1) / 2
    l_exp = -(x - ref).ravel() * math.radians(pix)
    m_exp = (y - ref).ravel() * math.radians(pix)
    assert np.abs(l_ - l_exp).max() < 1e-12
    assert np.abs(m_ - m_exp).max() < 1e-12
    assert np.allclose(n_, np.sqrt(1 - l_exp**2 - m_exp**2), atol=1e-12)


def test_ncp_orientation_matches_lm_convention():
    # Dec0 = 90 exactly: +m points to RA0 + 180 deg, +l (east, to the left) to RA0 + 90 deg
    cube = toy_cube(npix=5, ra=0.0, dec=90.0, pixel_deg=1.0)
    src = sources_from_cube(cube)
    ra = np.degrees(src.ra).reshape(5, 5)
    dec = np.degrees(src.dec).reshape(5, 5)
    assert math.isclose(ra[4, 2], 180.0, abs_tol=1e-9)     # top centre: +m
    assert math.isclose(ra[2, 0], 90.0, abs_tol=1e-9)      # left centre: +l
    assert math.isclose(ra[0, 2] % 360, 0.0, abs_tol=1e-9)  # bottom centre: -m
    assert math.isclose(dec[4, 2], math.degrees(math.acos(math.radians(2.0))), abs_tol=1e-9)


def test_pixel_solid_angle_and_kelvin_to_jansky_against_astropy():
    import astropy.units as u

    cube = toy_cube(npix=50, pixel_deg=0.3, nchan=3)
    omega = pixel_solid_angle(cube.wcs, cube.npix)
    y, x = np.mgrid[0:50, 0:50]
    d = math.radians(0.3)
    l_ = (x - 24.5) * d
    m_ = (y - 24.5) * d
    assert np.allclose(omega, d * d / np.sqrt(1 - l_**2 - m_**2), rtol=1e-4)
    jy = convert_units(cube, "Jy/pixel")
    for c, f in enumerate(cube.freq):
        for (iy, ix) in [(0, 0), (24, 30), (49, 2)]:
            temp = cube.data[0, c, iy, ix] * u.K
            ref = temp.to(u.Jy, equivalencies=u.brightness_temperature(
                f * u.Hz, beam_area=omega[iy, ix] * u.sr))
            assert math.isclose(jy.data[0, c, iy, ix], ref.value, rel_tol=1e-10)
    back = convert_units(jy, "K")
    assert np.allclose(back.data, cube.data, rtol=1e-12, atol=0)
    # 1 K over 1 sr at 150 MHz: 2 k nu^2 / c^2 in Jy
    assert math.isclose(kelvin_to_jansky(np.ones((1, 1, 1)), [150e6], 1.0)[0, 0, 0],
                        2 * 1.380649e-23 * 150e6**2 / 299792458.0**2 / 1e-26, rel_tol=1e-12)


def test_fits_round_trip(tmp_path):
    cube = toy_cube(npix=8, nchan=4, ra=123.4, dec=48.2)
    cube = SkyCube(cube.data, cube.freq, cube.stokes, cube.wcs, "K", {"SEED": 7})
    path = write_cube(cube, tmp_path / "c.fits")
    back = read_cube(path)
    assert back.stokes == ("Q", "U") and back.units == "K"
    assert np.allclose(back.freq, cube.freq, rtol=0, atol=1e-6)
    assert np.allclose(back.data, cube.data, rtol=1e-6, atol=1e-6)   # float32 on disk
    assert back.meta["SEED"] == 7
    assert fits.getheader(path)["CTYPE1"] == "RA---SIN"
    with pytest.raises(InputError, match="exists"):
        write_cube(cube, path)


def test_read_foreign_cube(tmp_path):
    # TAN projection, MHz frequencies, no STOKES axis, Jy/pixel, a degenerate 4th axis
    data = np.arange(3 * 5 * 6, dtype=np.float32).reshape(1, 3, 5, 6)  # (deg., freq, y, x)
    h = fits.Header()
    for k, (ct, cr, cv, cd, cu) in enumerate([("RA---TAN", 3.5, 50.0, -0.1, "deg"),
                                              ("DEC--TAN", 3.0, 40.0, 0.1, "deg"),
                                              ("FREQ", 1.0, 140.0, 0.5, "MHz"),
                                              ("TIME", 1.0, 0.0, 1.0, "s")], start=1):
        h[f"CTYPE{k}"], h[f"CRPIX{k}"], h[f"CRVAL{k}"], h[f"CDELT{k}"], h[f"CUNIT{k}"] = \
            ct, cr, cv, cd, cu
    h["BUNIT"] = "Jy/pixel"
    path = tmp_path / "foreign.fits"
    fits.PrimaryHDU(data=data, header=h).writeto(path)
    cube = read_cube(path, stokes="Q")
    assert cube.stokes == ("Q",) and cube.units == "Jy/pixel"
    assert np.allclose(cube.freq, [140e6, 140.5e6, 141e6])
    assert np.array_equal(cube.data[0], data[0])
    src = sources_from_cube(cube)
    assert np.allclose(src.stokes[:, :, 1], data[0].reshape(3, 30).T)
    assert np.all(src.stokes[:, :, [0, 2, 3]] == 0)


def write_bad(tmp_path, kind):
    path = tmp_path / f"{kind}.fits"
    data = np.ones((2, 3, 4), dtype=np.float32)
    h = fits.Header()
    h["CTYPE1"], h["CTYPE2"], h["CTYPE3"] = "RA---SIN", "DEC--SIN", "FREQ"
    h["CDELT1"], h["CDELT2"], h["CDELT3"], h["CRVAL3"] = -0.3, 0.3, 1e5, 1.5e8
    h["BUNIT"] = "K"
    if kind == "nofreq":
        h["CTYPE3"] = "VELO-LSR"
    if kind == "nan":
        data[0, 1, 2] = np.nan
    if kind == "jybeam":
        h["BUNIT"] = "Jy/beam"
    fits.PrimaryHDU(data=data, header=h).writeto(path)
    return path


@pytest.mark.parametrize("kind,match", [("nofreq", "no FREQ axis"), ("nan", "NaN"),
                                        ("jybeam", "Jy/beam")])
def test_bad_cubes(tmp_path, kind, match):
    with pytest.raises(InputError, match=match):
        read_cube(write_bad(tmp_path, kind))


def test_not_fits(tmp_path):
    p = tmp_path / "x.fits"
    p.write_text("hello")
    with pytest.raises(InputError, match="not a readable FITS"):
        read_cube(p)


def test_at_frequencies_tabulated():
    cube = toy_cube(npix=3, nchan=4, units="Jy/pixel")
    src = sources_from_cube(cube)
    f = cube.freq
    got = src.at_frequencies(f[[2, 0]] * (1 + 1e-8))
    assert np.array_equal(got[:, 0, 1], cube.data[0, 2].ravel())
    assert np.array_equal(got[:, 1, 2], cube.data[1, 0].ravel())
    with pytest.raises(InputError, match="interpolate_frequency"):
        src.at_frequencies([f[0] + 1000.0])
    mid = 0.25 * f[1] + 0.75 * f[2]
    lin = src.at_frequencies([mid], interpolate=True)[:, 0, 1]
    assert np.allclose(lin, 0.25 * cube.data[0, 1].ravel() + 0.75 * cube.data[0, 2].ravel(),
                       rtol=1e-12, atol=1e-14)
    with pytest.raises(InputError, match="outside"):
        src.at_frequencies([f[-1] + 1e6], interpolate=True)


def test_recentre_keeps_polarized_intensity_and_moves_reference():
    cube = toy_cube()
    moved = recentre(cube, math.radians(123.4), math.radians(90.0))
    # Q, U turn with the local North (tests/sky/test_sky_polframe.py); |P| is kept
    np.testing.assert_allclose(np.hypot(*moved.data), np.hypot(*cube.data), rtol=1e-12)
    assert np.allclose(moved.wcs.wcs.crval, [123.4, 90.0])
    same = recentre(cube, math.radians(30.0), math.radians(60.0))
    np.testing.assert_allclose(same.data, cube.data, atol=1e-12)


def test_parametric_point_sources():
    src = PointSources.parametric([0.0], [0.5], 2.0, 0.3, 0.4, 0.1, ref_freq=150e6,
                                  spectral_index=[-0.7], rotation_measure=5.0)
    f = np.array([120e6, 150e6, 180e6])
    s = src.at_frequencies(f)
    i = 2.0 * (f / 150e6) ** -0.7
    lam2, lam02 = (299792458.0 / f) ** 2, (299792458.0 / 150e6) ** 2
    p = (0.3 + 0.4j) / 2.0 * i * np.exp(2j * 5.0 * (lam2 - lam02))
    assert np.allclose(s[0, :, 0], i, rtol=1e-12)
    assert np.allclose(s[0, :, 1] + 1j * s[0, :, 2], p, rtol=1e-12, atol=1e-15)
    assert np.allclose(s[0, :, 3], 0.1)
    with pytest.raises(InputError, match="I != 0"):
        PointSources.parametric([0.0], [0.5], 0.0, 0.3, 0.4, ref_freq=150e6,
                                rotation_measure=5.0)
