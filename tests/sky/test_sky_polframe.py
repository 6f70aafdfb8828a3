"""Polarization frame of sky cubes: Q, U referred to the local North of every pixel."""

import math

import numpy as np
import pytest
from click.testing import CliRunner

from msleak.cli import cli
from msleak.adapters.sky_fits import read_cube, write_cube
from msleak.adapters.skymodel import read_skymodel
from msleak.sky import (ForegroundParams, SkyCube, generate_foreground_cube,
                        make_celestial_wcs, recentre, sources_from_cube)
from msleak.sky.cube import rotate_polarization, y_axis_position_angle

D2R = math.pi / 180


def sin_pixel_to_radec(x, y, npix, pix_deg, ra0, dec0):
    """SIN deprojection (LONPOLE 180, reference at the grid centre), written here."""
    ref = (npix - 1) / 2
    l_ = -(x - ref) * pix_deg * D2R
    m_ = (y - ref) * pix_deg * D2R
    n_ = np.sqrt(1 - l_**2 - m_**2)
    d0, a0 = dec0 * D2R, ra0 * D2R
    dec = np.arcsin(m_ * np.cos(d0) + n_ * np.sin(d0))
    ra = a0 + np.arctan2(l_, n_ * np.cos(d0) - m_ * np.sin(d0))
    return ra, dec


def great_circle_pa(ra1, dec1, ra2, dec2):
    """Position angle (North through East) at point 1 of the great circle to point 2."""
    da = ra2 - ra1
    return np.arctan2(np.sin(da) * np.cos(dec2),
                      np.cos(dec1) * np.sin(dec2) - np.sin(dec1) * np.cos(dec2) * np.cos(da))


def psi_independent(npix, pix_deg, ra0, dec0, h=1e-3):
    """PA of the image +y direction at every pixel: mean of the great circles towards
    y + h and (reversed) y - h, second-order accurate."""
    y, x = np.mgrid[0:npix, 0:npix].astype(float)
    ra, dec = sin_pixel_to_radec(x, y, npix, pix_deg, ra0, dec0)
    up = great_circle_pa(ra, dec, *sin_pixel_to_radec(x, y + h, npix, pix_deg, ra0, dec0))
    down = great_circle_pa(ra, dec, *sin_pixel_to_radec(x, y - h, npix, pix_deg, ra0, dec0))
    return np.angle(np.exp(1j * up) - np.exp(1j * down)), ra, dec


def wrap_pi(a):
    """Angle differences of polarization (defined mod pi) into (-pi/2, pi/2]."""
    return (a + np.pi / 2) % np.pi - np.pi / 2


@pytest.mark.parametrize("ra0,dec0", [(123.4, 48.2), (0.0, 90.0), (250.0, -30.0),
                                      (40.0, 88.0), (10.0, 0.0)])
def test_psi_from_wcs_matches_spherical_trigonometry(ra0, dec0):
    npix, pix = 50, 0.3
    psi = y_axis_position_angle(make_celestial_wcs(npix, npix, pix, ra0, dec0), (npix, npix))
    ref, _, _ = psi_independent(npix, pix, ra0, dec0)
    assert np.abs(np.angle(np.exp(1j * (psi - ref)))).max() < 1e-7


def test_psi_size_at_3c196_and_near_the_pole():
    npix, pix = 50, 0.3
    psi = y_axis_position_angle(make_celestial_wcs(npix, npix, pix, 123.4, 48.2), (npix, npix))
    # the referee's numbers: +-10.6 deg in the corners of the 15 deg cube on 3C196
    assert np.degrees(np.abs(psi).max()) == pytest.approx(10.6, abs=0.1)
    assert np.degrees(psi[0, 0]) == pytest.approx(-np.degrees(psi[0, -1]), abs=1e-6)
    ncp = y_axis_position_angle(make_celestial_wcs(npix, npix, pix, 0.0, 90.0), (npix, npix))
    assert np.degrees(np.abs(ncp).max()) > 178.0           # every angle around the pole


def regular_field_cube(ra0, dec0, npix, fov=15.0, b=(1.0, 0.0, 0.0)):
    """No random field, no Faraday rotation: the +y-referred angle is the same everywhere
    (B along East: E vector along +y, chi = 0)."""
    params = ForegroundParams(b_regular_ug=b, b_random_rms_ug=0.0, ne_mean_cm3=0.0,
                              ne_sigma_ln=0.0, ncr_sigma_ln=0.0, ncells_los=4)
    return generate_foreground_cube(npix=npix, fov_deg=fov, nchan=2, seed=1, params=params,
                                    phase_centre=(ra0 * D2R, dec0 * D2R))


def test_uniform_field_along_y_has_chi_zero_at_the_centre():
    npix = 21
    cube = regular_field_cube(123.4, 48.2, npix)
    assert cube.meta["POLFRAME"] == "LOCAL-NORTH"
    p = cube.data[0, 0] + 1j * cube.data[1, 0]
    chi = 0.5 * np.angle(p)
    c = npix // 2
    assert abs(chi[c, c]) < 1e-10
    # elsewhere the local-North angle is the position angle of +y
    psi, _, _ = psi_independent(npix, 15.0 / npix, 123.4, 48.2)
    assert np.abs(wrap_pi(chi - psi)).max() < 1e-7
    assert np.degrees(np.abs(wrap_pi(chi)).max()) > 5.0      # the rotation is not trivial


def test_regular_field_at_the_ncp_turns_with_right_ascension():
    npix, ra0 = 21, 30.0
    cube = regular_field_cube(ra0, 90.0, npix)
    p = cube.data[0, 0] + 1j * cube.data[1, 0]
    chi = 0.5 * np.angle(p)
    _, ra, dec = psi_independent(npix, 15.0 / npix, ra0, 90.0)
    turn = wrap_pi(chi - (ra - ra0 * D2R))
    c = npix // 2
    # along the image axes the angle turns exactly with RA ...
    on_axes = np.zeros((npix, npix), bool)
    on_axes[c, :] = on_axes[:, c] = True
    on_axes[c, c] = False                                   # the pole pixel itself
    assert np.abs(turn[on_axes]).max() < 1e-7
    # ... and elsewhere up to the SIN projection's shear (0.5 deg at 10 deg radius)
    assert np.degrees(np.abs(turn).max()) < 0.6
    # pixels around the pole hold perpendicular polarization angles
    ring = np.hypot(*np.mgrid[-c:c + 1, -c:c + 1]) == 5
    assert np.degrees(np.abs(wrap_pi(chi[ring] - chi[ring][0])).max()) > 89.0


@pytest.mark.parametrize("start,via", [((0.0, 90.0), (123.4, 48.2)),
                                       ((123.4, 48.2), (250.0, -30.0)),
                                       ((123.4, 48.2), (0.0, 90.0))])
def test_recentring_twice_returns_the_original(start, via):
    rng = np.random.default_rng(4)
    npix = 16
    cube = SkyCube(data=rng.normal(size=(2, 3, npix, npix)), freq=150e6 + np.arange(3) * 1e5,
                   stokes=("Q", "U"), wcs=make_celestial_wcs(npix, npix, 0.9, *start))
    moved = recentre(cube, via[0] * D2R, via[1] * D2R)
    back = recentre(moved, start[0] * D2R, start[1] * D2R)
    assert np.abs(back.data - cube.data).max() < 1e-10
    # the angle from the image +y axis travels with the grid; |P| is unchanged
    p0 = cube.data[0] + 1j * cube.data[1]
    p1 = moved.data[0] + 1j * moved.data[1]
    psi0, _, _ = psi_independent(npix, 0.9, *start)
    psi1, _, _ = psi_independent(npix, 0.9, *via)
    np.testing.assert_allclose(p1 * np.exp(-2j * psi1), p0 * np.exp(-2j * psi0), atol=1e-7)
    assert not np.allclose(p1, p0, atol=1e-3)


def test_recentring_a_q_only_cube_creates_u():
    npix = 8
    cube = SkyCube(data=np.ones((1, 1, npix, npix)), freq=np.array([150e6]), stokes=("Q",),
                   wcs=make_celestial_wcs(npix, npix, 1.0, 123.4, 48.2))
    moved = recentre(cube, 0.0, 60 * D2R)
    assert moved.stokes == ("Q", "U")
    np.testing.assert_allclose(np.hypot(*moved.data[:, 0]), 1.0, rtol=1e-12)
    # a pure Stokes I cube is not touched
    i_cube = SkyCube(data=np.ones((1, 1, npix, npix)), freq=np.array([150e6]), stokes=("I",),
                     wcs=cube.wcs)
    assert np.array_equal(recentre(i_cube, 0.0, 60 * D2R).data, i_cube.data)


def test_sources_and_makesourcedb_export_carry_local_north(tmp_path):
    npix = 7
    out, sm = tmp_path / "sky.fits", tmp_path / "sky.skymodel"
    res = CliRunner().invoke(cli, [
        "sky", str(out), "--seed", "3", "--npix", str(npix), "--fov", "15", "--nchan", "1",
        "--phase-centre", "0,90", "--b-regular", "1,0,0", "--b-random-rms", "0",
        "--ne-mean", "0", "--ne-sigma", "0", "--ncr-sigma", "0", "--ncells-los", "4",
        "--skymodel", str(sm), "--skymodel-channel", "0"])
    assert res.exit_code == 0, res.output
    psi, ra, dec = psi_independent(npix, 15.0 / npix, 0.0, 90.0)
    src = read_skymodel(sm)
    chi = 0.5 * np.arctan2(src.stokes_ref[:, 2], src.stokes_ref[:, 1])
    assert np.abs(wrap_pi(chi - psi.ravel())).max() < 1e-6
    np.testing.assert_allclose(src.ra, np.mod(ra.ravel(), 2 * np.pi), atol=1e-9)
    # the same from the FITS cube: sources_from_cube passes the cube's Q, U unchanged
    cube = read_cube(out)
    assert cube.meta["POLFRAME"] == "LOCAL-NORTH"
    s2 = sources_from_cube(cube)
    chi2 = 0.5 * np.arctan2(s2.stokes[:, 0, 2], s2.stokes[:, 0, 1])
    chi_cube = 0.5 * np.arctan2(cube.data[1, 0], cube.data[0, 0]).ravel()
    assert np.abs(wrap_pi(chi2 - chi_cube)).max() < 1e-12
    assert np.abs(wrap_pi(chi2 - psi.ravel())).max() < 1e-6


def test_cube_is_read_as_written(tmp_path):
    # reading never turns Q, U: a local-North cube comes back as it was written
    npix = 9
    wcs = make_celestial_wcs(npix, npix, 1.5, 123.4, 48.2)
    data = np.zeros((2, 1, npix, npix))
    data[0] = 2.0                                           # Q = 2 along image +y
    old = SkyCube(data=data, freq=np.array([150e6]), stokes=("Q", "U"), wcs=wcs, units="K")
    psi, _, _ = psi_independent(npix, 1.5, 123.4, 48.2)
    new = rotate_polarization(old, psi)
    new.meta["POLFRAME"] = "LOCAL-NORTH"
    again = read_cube(write_cube(new, tmp_path / "new.fits"))
    np.testing.assert_allclose(again.data, new.data, atol=1e-5)
