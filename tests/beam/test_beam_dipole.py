"""The analytic dipole beam against an independent astropy projection; station factors."""

from __future__ import annotations

import numpy as np
import pytest

from msleak.adapters.beams import load_beam
from msleak.beam.dipole import DipoleBeam, dipole_jones, station_factor
from msleak.errors import InputError

C = 299792458.0
# a LOFAR-like site and 3C196 on 2012-12-16
SITE_ITRF = np.array([3826577.1, 461022.9, 5064892.8])
T_MJD_S = 56277.9 * 86400.0
RA0, DEC0 = np.radians(123.4), np.radians(48.2)


def _astropy_projection(ra, dec, t_mjd_s, site_itrf, *, basis, step=1e-6):
    """J = [[x.n, x.e], [y.n, y.e]] with X along local north, Y along local east, from
    astropy AltAz positions (ENU).  ``basis``: 'pole' = EveryBeam's convention
    east = normalize(pole x d), north = d x east, with the J2000 pole converted like d;
    'meridian' = the true local celestial north/east by finite differences in Dec/RA."""
    from astropy import units as u
    from astropy.coordinates import AltAz, EarthLocation, SkyCoord
    from astropy.time import Time
    loc = EarthLocation.from_geocentric(*site_itrf, unit=u.m)
    frame = AltAz(obstime=Time(t_mjd_s / 86400.0, format="mjd", scale="utc"), location=loc)

    def enu(a, d):
        aa = SkyCoord(a * u.rad, d * u.rad, frame="fk5").transform_to(frame)
        az, alt = aa.az.rad, aa.alt.rad
        return np.stack([np.cos(alt) * np.sin(az), np.cos(alt) * np.cos(az), np.sin(alt)], -1)

    base = enu(ra, dec)
    if basis == "pole":
        pole = enu(np.array([0.0]), np.array([np.pi / 2]))[0]
        east = np.cross(pole, base)
        east /= np.linalg.norm(east, axis=-1, keepdims=True)
        north = np.cross(base, east)
    else:
        north = enu(ra, dec + step) - enu(ra, dec - step)
        east = enu(ra + step / np.cos(dec), dec) - enu(ra - step / np.cos(dec), dec)
        north /= np.linalg.norm(north, axis=-1, keepdims=True)
        east /= np.linalg.norm(east, axis=-1, keepdims=True)
    x, y = np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0])   # ENU north, east
    j = np.stack([np.stack([north @ x, east @ x], -1), np.stack([north @ y, east @ y], -1)], -2)
    j[base[:, 2] < 0] = 0
    return j


def test_dipole_projection_matches_astropy():
    beam = DipoleBeam([SITE_ITRF], [30.0], (RA0, DEC0), (RA0, DEC0), factor="none")
    ra = RA0 + np.radians([0.0, 20.0, -35.0, 60.0, 150.0])
    dec = np.radians([48.2, 10.0, 70.0, -5.0, 30.0])
    j = beam.jones([T_MJD_S], [150e6], ra, dec)[0, 0, 0]
    assert np.abs(j.imag).max() == 0
    # same basis convention: directions agree to ~0.3" (casacore vs astropy), so 1e-5
    np.testing.assert_allclose(j.real, _astropy_projection(ra, dec, T_MJD_S, SITE_ITRF,
                                                           basis="pole"), atol=1e-5)
    # EveryBeam's basis differs from the true local meridian by the differential aberration
    # of the pole and the direction (at most ~v/c = 1e-4 rad)
    np.testing.assert_allclose(j.real, _astropy_projection(ra, dec, T_MJD_S, SITE_ITRF,
                                                           basis="meridian"), atol=1e-4)


def test_dipole_is_zero_below_the_horizon():
    beam = DipoleBeam([SITE_ITRF], [30.0], (RA0, DEC0), (RA0, DEC0))
    j = beam.jones([T_MJD_S], [150e6], [0.0, 1.0], [np.radians(-70), np.radians(-89.99)])
    assert np.all(j == 0)


def test_airy_and_gaussian_station_factors():
    from scipy.special import jn_zeros

    d, f = 30.0, 150e6
    first_null = np.arcsin(jn_zeros(1, 1)[0] * C / (np.pi * d * f))
    airy = station_factor("airy", np.array([0.0, first_null]), np.array([f]), d)[0]
    np.testing.assert_allclose(airy, [1.0, 0.0], atol=1e-12)
    fwhm = 1.02 * C / (f * d)
    gauss = station_factor("gaussian", np.array([0.0, fwhm / 2]), np.array([f]), d)[0]
    np.testing.assert_allclose(gauss ** 2, [1.0, 0.5], rtol=1e-12)
    with pytest.raises(InputError, match="unknown station factor"):
        station_factor("cosine", np.zeros(1), np.array([f]), d)


def test_ground_plane_factor_at_zenith():
    enu = np.eye(3)          # rows east, north, up in a toy frame
    d, north, east = enu[2:3], enu[1:2], enu[0:1]   # the zenith; sky north/east = local
    f, h = np.array([120e6, 150e6]), 0.5
    j = dipole_jones(d, north, east, enu, f, ground_plane_height_m=h)
    g = 2 * np.sin(2 * np.pi * f * h / C)
    np.testing.assert_allclose(j[:, 0], g[:, None, None] * np.eye(2), atol=1e-15)


def test_dipole_from_ms_and_centre_correction(small_lofar_ms):
    beam = load_beam("dipole", small_lofar_ms, factor="gaussian", diameter_m=30.75)
    ra0, dec0 = beam.phase_centre
    j = beam.jones([4.86234e9], [150e6], [ra0, ra0 + 0.05], [dec0, dec0],
                   centre_correction=True)
    np.testing.assert_allclose(j[:, 0, 0, 0], np.broadcast_to(np.eye(2), (beam.n_stations, 2, 2)),
                               atol=1e-12)
    assert np.all(np.abs(j[:, 0, 0, 1]) < 1)


def test_dipole_bad_options(small_lofar_ms):
    with pytest.raises(InputError, match="takes no option"):
        load_beam("dipole", small_lofar_ms, diameter=3)
    with pytest.raises(InputError, match="diameter must be positive"):
        load_beam("dipole", small_lofar_ms, diameter_m=-1)
    with pytest.raises(InputError, match="unknown beam"):
        load_beam("airy", small_lofar_ms)
