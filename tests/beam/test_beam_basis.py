"""The Q,U basis of beam maps: the phase centre's (North, East) basis parallel-transported
to every pixel (``--basis tangent``, the default) against each pixel's own North."""

from __future__ import annotations

import numpy as np
import pytest
from astropy.coordinates import SkyCoord
import astropy.units as u
from click.testing import CliRunner

from msleak.beam.coords import basis_rotation, transport_angle
from msleak.cli import cli


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def test_transport_angle_zero_at_centre_meridian_and_equator():
    assert transport_angle(1.0, 0.4, np.array([1.0]), np.array([0.4]))[0] == pytest.approx(0, abs=1e-15)
    # along the phase centre's meridian the North stays the North
    dec = np.radians(np.linspace(-60, 80, 15))
    assert np.abs(transport_angle(1.0, 0.4, np.full(15, 1.0), dec)).max() < 1e-12
    # along the equator too (a great circle through the centre, perpendicular to North)
    ra = np.radians(np.linspace(-80, 80, 17))
    assert np.abs(transport_angle(0.0, 0.0, ra, np.zeros(17))).max() < 1e-12


def test_transport_angle_at_the_pole_is_the_ra_difference():
    """From the NCP (limit along the meridian ra0), the carried North keeps its angle to
    each meridian: psi = ra - ra0."""
    rng = np.random.default_rng(3)
    ra = rng.uniform(0, 2 * np.pi, 50)
    dec = np.radians(rng.uniform(70, 89.9, 50))
    psi = transport_angle(0.7, np.pi / 2, ra, dec)
    assert np.abs(_wrap(psi - (ra - 0.7))).max() < 1e-9


def test_transport_angle_equals_position_angles_from_astropy():
    """Parallel transport keeps the angle to the great circle: psi = PA(s -> s0) + 180 deg
    - PA(s0 -> s), position angles from astropy."""
    rng = np.random.default_rng(4)
    ra0, dec0 = 2.1, 0.85
    ra = ra0 + rng.uniform(-0.3, 0.3, 40)
    dec = dec0 + rng.uniform(-0.3, 0.3, 40)
    c0 = SkyCoord(ra0 * u.rad, dec0 * u.rad)
    c = SkyCoord(ra * u.rad, dec * u.rad)
    expected = c.position_angle(c0).rad + np.pi - c0.position_angle(c).rad
    assert np.abs(_wrap(transport_angle(ra0, dec0, ra, dec) - expected)).max() < 1e-9


def test_basis_rotation_is_a_rotation():
    r = basis_rotation(np.array([0.0, 0.3, -1.2]))
    assert np.allclose(r @ np.swapaxes(r, -1, -2), np.eye(2), atol=1e-15)
    assert np.allclose(np.linalg.det(r), 1.0)
    assert np.array_equal(r[0], np.eye(2))


def test_ncp_polarized_beam_has_no_null_in_the_main_lobe(make_ms, tmp_path):
    """NCP field: in the tangent-plane basis the polarized beam is 0 dB at the centre and
    above -4 dB wherever the Stokes-I beam M00 is above half power, at every hour angle;
    in each pixel's local basis the same map has deep nulls there (the basis turning
    about the pole), so the test tells the two apart."""
    import xarray as xr

    ms = make_ms("ncp.ms", field="ncp", stations="CS00[1-2]HBA*", duration=12.0,
                 interval=3600.0, nchan=2)
    out = {}
    for basis in ("tangent", "local"):
        r = CliRunner().invoke(cli, ["beam", str(ms), "-o", str(tmp_path / f"{basis}.png"),
                                     "--npix", "41", "--basis", basis])
        assert r.exit_code == 0, r.output
        with xr.open_dataset(tmp_path / f"{basis}.h5", engine="h5netcdf") as ds:
            out[basis] = ds.load()
    tan, loc = out["tangent"], out["local"]
    assert tan.attrs["qu_basis"] == "tangent" and loc.attrs["qu_basis"] == "local"
    assert tan.sizes["hour_angle"] == 5
    centre = (tan.sizes["m"] // 2, tan.sizes["l"] // 2)
    m00 = tan["mueller"].values[..., 0, 0]
    lobe = m00 >= 0.5
    assert lobe.sum(axis=(1, 2)).min() > 20   # the half-power lobe is resolved
    pb_tan = tan["polarized_beam_db"].values
    pb_loc = loc["polarized_beam_db"].values
    for k in range(tan.sizes["hour_angle"]):
        assert pb_tan[k][centre] == pytest.approx(0.0, abs=1e-6)
        assert pb_tan[k][lobe[k]].min() > -4.0
        assert pb_loc[k][lobe[k]].min() < -20.0
    # the basis is a Q,U frame only: Stokes I and the leakage do not depend on it
    np.testing.assert_allclose(tan["mueller"].values[..., 0, 0], loc["mueller"].values[..., 0, 0],
                               rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(tan["leakage"].values, loc["leakage"].values, rtol=1e-9,
                               atol=1e-15)
