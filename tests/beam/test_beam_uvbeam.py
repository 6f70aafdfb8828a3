"""``--beam uvbeam``: HERA's UVBeam file through msleak, against pyuvdata's own interpolation
with the geometry computed here (casacore directions, astropy AltAz), and the refusals."""

from __future__ import annotations

import astropy.units as u
import numpy as np
import pytest
from astropy.coordinates import FK5, AltAz, EarthLocation, SkyCoord
from astropy.time import Time
from click.testing import CliRunner
from pyuvdata.telescopes import KNOWN_TELESCOPES

from casa_ms import build_ms
from ms_helpers import phase_centre, write_sky, one_error_line
from msleak.adapters.beams import load_beam, uvbeam_from_ms
from msleak.beam.uvbeam import UVBeamModel, frequency_weights
from msleak.cli import cli
from msleak.errors import BeamUnavailable, InputError
from msleak.io.measures import exact_j2000_to_itrf
from msleak.io.ms import column_names, read_antennas
from msleak.io.uvbeam import default_beam_file, read_beam_file

_LOC = KNOWN_TELESCOPES["HERA"]["location"]
HERA_ITRF = np.array([_LOC.x.to_value("m"), _LOC.y.to_value("m"), _LOC.z.to_value("m")])
T0 = 56329.0 * 86400.0 + 7200.0
#: one dish at the site, two ~300 m out (frame tilts ~5e-5 rad) and one 50 m out
ENU = np.array([[0.0, 0.0, 0.0], [300.0, 60.0, 1.0], [-170.0, 260.0, -0.5], [40.0, -25.0, 0.2]])
FREQ = np.array([100e6, 121.3e6, 145e6])    # the file's ends and a frequency between its nodes


def _zenith_radec(t_mjd_s, position):
    """J2000 (FK5) (ra, dec) in rad of the zenith of an ITRF position at a time."""
    loc = EarthLocation.from_geocentric(*position, unit=u.m)
    frame = AltAz(obstime=Time(t_mjd_s / 86400.0, format="mjd", scale="utc"), location=loc)
    c = SkyCoord(az=0 * u.deg, alt=90 * u.deg, frame=frame).transform_to(FK5(equinox="J2000"))
    return float(c.ra.rad), float(c.dec.rad)


@pytest.fixture(scope="module")
def hera_ms(tmp_path_factory):
    """4 HERA dishes at the HERA site, phase centre at the zenith of T0, 3 channels in the
    HERA_NicCST file's 100-145 MHz."""
    ra0, dec0 = _zenith_radec(T0, HERA_ITRF)
    return build_ms(tmp_path_factory.mktemp("hera") / "hera.ms", telescope="HERA",
                    site_itrf=HERA_ITRF, enu=ENU, dish_diameter=14.0, ra_deg=np.degrees(ra0),
                    dec_deg=np.degrees(dec0), time0_s=T0, ntime=2, nchan=3, freq0_hz=100e6,
                    chan_width_hz=22.5e6)


@pytest.fixture(scope="module")
def model(hera_ms):
    return uvbeam_from_ms(hera_ms)


def _local_vectors(ra, dec, t_mjd_s, position):
    """Unit vectors (n, 3) in the (East, North, Up) frame of ``position``, from astropy AltAz."""
    loc = EarthLocation.from_geocentric(*position, unit=u.m)
    frame = AltAz(obstime=Time(np.full(np.size(ra), t_mjd_s / 86400.0), format="mjd",
                               scale="utc"), location=loc)
    aa = SkyCoord(ra * u.rad, dec * u.rad, frame=FK5(equinox="J2000")).transform_to(frame)
    az, alt = aa.az.rad, aa.alt.rad                       # astropy: az from North through East
    return np.stack([np.cos(alt) * np.sin(az), np.cos(alt) * np.cos(az), np.sin(alt)], -1)


def _sky_basis(ra, dec, t_mjd_s, position):
    """Local directions and their (North, East) in msleak's convention (docs/beam.md): East
    is perpendicular to the direction and to the J2000 pole as both are seen (apparent,
    astropy AltAz), North completes it; East = increasing RA."""
    v = _local_vectors(ra, dec, t_mjd_s, position)
    pole = _local_vectors(np.zeros(1), np.full(1, np.pi / 2), t_mjd_s, position)[0]
    return (v, *_north_east(v, pole))


def _north_east(v, pole):
    east = np.cross(pole, v)
    east /= np.linalg.norm(east, axis=1, keepdims=True)
    return np.cross(v, east), east


def _casacore_sky_basis(ra, dec, t_mjd_s, position):
    """The same from casacore's J2000 -> ITRF directions (one exact conversion each, as
    msleak's fitted map is checked against) in the geodetic frame astropy gives."""
    lon, lat = (a.to_value(u.rad) for a in
                EarthLocation.from_geocentric(*position, unit=u.m).to_geodetic()[:2])
    enu = np.array([[-np.sin(lon), np.cos(lon), 0.0],
                    [-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)],
                    [np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)]])
    v = exact_j2000_to_itrf(t_mjd_s, ra, dec, position_itrf=position) @ enu.T
    pole = exact_j2000_to_itrf(t_mjd_s, 0.0, np.pi / 2, position_itrf=position)[0] @ enu.T
    return (v, *_north_east(v, pole))


def _expected_jones(beam, geometry, freq):
    """pyuvdata's interpolation (cubic in frequency) at the az/za of ``geometry`` (local
    direction, North, East), turned to the sky (North, East) basis."""
    v, north, east = geometry
    az = np.mod(np.arctan2(v[:, 1], v[:, 0]), 2 * np.pi)   # pyuvdata: from East through North
    za = np.arccos(v[:, 2])
    az_hat = np.stack([-np.sin(az), np.cos(az), 0 * az], -1)
    za_hat = np.stack([np.cos(za) * np.cos(az), np.cos(za) * np.sin(az), -np.sin(za)], -1)
    data, _ = beam.interp(az_array=az, za_array=za, freq_array=freq, return_basis_vector=False)
    feeds = list(beam.feed_array)
    # rows X, Y = the North-South feed, then the East-West one (both files here: y, x)
    assert np.isclose(beam.feed_angle[feeds.index("y")], 0.0)
    data = data[:, [feeds.index("y"), feeds.index("x")]]   # (basis, feed, freq, dir)
    out = np.zeros((freq.size, len(v), 2, 2), complex)
    for i, b in enumerate((north, east)):
        out[..., i] = (data[0] * np.sum(b * az_hat, -1) + data[1] * np.sum(b * za_hat, -1)
                       ).transpose(1, 2, 0)
    out[:, v[:, 2] < 0] = 0
    return out


def _field(ra0, dec0, n=7, half_deg=7.5):
    g = np.radians(np.linspace(-half_deg, half_deg, n))
    dra, ddec = np.meshgrid(g, g)
    return (ra0 + dra.ravel() / np.cos(dec0)), dec0 + ddec.ravel()


def test_jones_equal_pyuvdata_interpolation(hera_ms, model):
    """Each station sees the beam at its own az/za: equal to pyuvdata's ``UVBeam.interp``
    (cubic in frequency) turned to (North, East) by the test, with the directions converted
    by casacore one by one, to 2e-6 of the peak (at the zenith and 45 deg from it)."""
    ra0, dec0 = phase_centre(hera_ms)
    ra, dec = _field(ra0, dec0)
    times = np.array([T0, T0 + 3 * 3600.0])
    got = model.jones(times, FREQ, ra, dec)
    peak = np.abs(got).max()
    assert 0.9 < peak < 1.1                         # zenith-normalised (the file peaks at 90.8)
    for s, pos in enumerate(read_antennas(hera_ms).positions):
        for it, t in enumerate(times):
            want = _expected_jones(model.beam, _casacore_sky_basis(ra, dec, t, pos), FREQ)
            assert np.abs(got[s, it] - want).max() < 2e-6 * peak, (s, it)


def test_jones_agree_with_astropy_geometry(hera_ms, model):
    """The same with az/za and the basis from astropy's AltAz: astropy and casacore place
    directions up to 4e-6 rad (0.8 arcsec) apart, worth 3e-5 of the peak on the beam's
    flanks; within 1 deg of the zenith the file itself is ambiguous (its response vector at
    za = 0 varies by 8e-5 of the peak with azimuth), so those directions are left out."""
    ra0, dec0 = phase_centre(hera_ms)
    ra, dec = _field(ra0, dec0)
    times = np.array([T0, T0 + 3 * 3600.0])
    got = model.jones(times, FREQ, ra, dec)
    peak = np.abs(got).max()
    for s, pos in enumerate(read_antennas(hera_ms).positions):
        for it, t in enumerate(times):
            geometry = _sky_basis(ra, dec, t, pos)
            off_zenith = geometry[0][:, 2] < np.cos(np.radians(1.0))
            want = _expected_jones(model.beam, geometry, FREQ)
            assert np.abs(got[s, it] - want)[:, off_zenith].max() < 5e-5 * peak, (s, it)


def test_stations_see_their_own_horizon_frame(hera_ms, model):
    """The per-station move matters: one shared frame would differ by > 1e-4 of the peak
    for the stations 300 m out, while each station agrees with a model centred on it
    (its own frame, no first-order move) to 2e-6 of the peak."""
    ra0, dec0 = phase_centre(hera_ms)
    ra, dec = _field(ra0, dec0, n=9)
    got = model.jones([T0], FREQ, ra, dec)
    positions = read_antennas(hera_ms).positions
    peak = np.abs(got).max()
    alone = [UVBeamModel(model.beam, p[None], (ra0, dec0)).jones([T0], FREQ, ra, dec)[0]
             for p in positions]
    assert max(np.abs(got[s] - alone[s]).max() for s in range(len(positions))) < 2e-6 * peak
    assert np.abs(alone[1] - alone[0]).max() > 1e-4 * peak


def test_rows_are_north_south_then_east_west_at_the_zenith(model):
    """HERA_NicCST's y feed lies North-South (feed_angle 0), x East-West (90 deg): row X
    is y, row Y is x (msleak's IAU order), so at a station's zenith row X sees only the
    North field and row Y only the East field (cross terms are the CST model's
    cross-polarisation, 1e-4 of the main term), each with gain ~1 (zenith-normalised)."""
    feeds = list(model.beam.feed_array)
    assert np.isclose(model.beam.feed_angle[feeds.index("x")], np.pi / 2)
    assert np.isclose(model.beam.feed_angle[feeds.index("y")], 0.0)
    pos = model.positions[0]
    ra, dec = _zenith_radec(T0, pos)
    j = model.jones([T0], FREQ, [ra], [dec], stations=[0])[0, 0, :, 0]
    assert np.all(np.abs(j[:, 0, 1]) < 1e-3 * np.abs(j[:, 0, 0]))   # X: East << North
    assert np.all(np.abs(j[:, 1, 0]) < 1e-3 * np.abs(j[:, 1, 1]))   # Y: North << East
    assert np.all(np.abs(j[:, 0, 0]) > 0.9) and np.all(np.abs(j[:, 0, 0]) < 1.1)


def test_beam_is_normalised_to_its_zenith_peak(model):
    """Each file frequency is divided by the amplitude of the zenith component largest at
    100 MHz times its phase relative to 100 MHz: afterwards that component has amplitude 1
    and its 100 MHz phase at every frequency, the rest is the file divided by one number
    per frequency, and the
    interpolated zenith gain stays ~1 across the band (interpolating the raw file's
    turning phase would dip to 0.37 at 121 MHz)."""
    raw = read_beam_file(default_beam_file())
    za0 = list(raw.axis2_array).index(0.0)
    zen = raw.data_array[:, :, :, za0, :]
    b, f, a = np.unravel_index(np.argmax(np.abs(zen[:, :, 0, :])), zen[:, :, 0].shape)
    ref = zen[b, f, :, a]
    assert 60 < abs(ref[0]) < 100                   # the file's physical units
    norm = np.abs(ref) * ref / ref[0] / np.abs(ref / ref[0])
    np.testing.assert_allclose(model.beam.data_array[b, f, :, za0, a],
                               ref[0] / abs(ref[0]), rtol=1e-12)
    np.testing.assert_allclose(model.beam.data_array * norm[None, None, :, None, None],
                               raw.data_array, rtol=1e-12)
    pos = model.positions[0]
    ra, dec = _zenith_radec(T0, pos)
    band = np.linspace(100e6, 145e6, 10)
    gain = np.abs(model.jones([T0], band, [ra], [dec], stations=[0])[0, 0, :, 0, 0, 0])
    assert np.all(np.abs(gain - 1) < 2e-3)
    raw_zenith, _ = raw.interp(az_array=np.array([0.0]), za_array=np.array([0.0]),
                               freq_array=np.array([121.3e6]), return_basis_vector=False)
    assert np.abs(raw_zenith).max() < 0.5 * abs(norm[0])


def test_short_dipole_file_gives_the_projected_dipoles(tmp_path, hera_ms):
    """A beamfits of pyuvdata's analytic short dipoles (x East, y North) gives, everywhere
    above the horizon, the projections of the East and North axes on the sky basis:
    J[x] = (N . east_axis, E . east_axis), computed here with astropy."""
    from pyuvdata.analytic_beam import ShortDipoleBeam

    az = np.radians(np.arange(0, 360, 1.0))
    za = np.radians(np.arange(0, 181, 1.0))
    uvb = ShortDipoleBeam().to_uvbeam(freq_array=np.array([100e6, 120e6, 140e6, 160e6]),
                                      axis1_array=az, axis2_array=za)
    path = tmp_path / "dipole.beamfits"
    uvb.write_beamfits(str(path))
    beam = uvbeam_from_ms(hera_ms, beam_file=path)
    ra0, dec0 = phase_centre(hera_ms)
    ra, dec = _field(ra0, dec0, n=5, half_deg=55.0)
    got = beam.jones([T0 + 3600.0], [120e6], ra, dec, stations=[1])[0, 0, 0]
    v, north, east = _casacore_sky_basis(ra, dec, T0 + 3600.0, beam.positions[1])
    want = np.stack([np.stack([north[:, 1], east[:, 1]], -1),     # X = y: the North axis
                     np.stack([north[:, 0], east[:, 0]], -1)], -2)  # Y = x: the East axis
    want[v[:, 2] < 0] = 0
    assert np.any(v[:, 2] < 0) and np.any(v[:, 2] > 0.5)
    assert np.abs(got - want).max() < 1e-6


def test_identity_at_the_phase_centre(hera_ms, model):
    ra0, dec0 = phase_centre(hera_ms)
    j = model.jones([T0, T0 + 1800.0], FREQ, [ra0, ra0 + 0.05], [dec0, dec0],
                    centre_correction=True)
    np.testing.assert_allclose(j[:, :, :, 0], np.broadcast_to(np.eye(2), j[:, :, :, 0].shape),
                               atol=1e-10)
    assert np.abs(j[:, :, :, 1] - np.eye(2)).max() > 1e-3      # not the identity elsewhere


def _altaz_radec(alt_deg, az_deg, t_mjd_s, position):
    loc = EarthLocation.from_geocentric(*position, unit=u.m)
    frame = AltAz(obstime=Time(t_mjd_s / 86400.0, format="mjd", scale="utc"), location=loc)
    c = SkyCoord(az=np.asarray(az_deg) * u.deg, alt=np.asarray(alt_deg) * u.deg, frame=frame)
    c = c.transform_to(FK5(equinox="J2000"))
    return c.ra.rad, c.dec.rad


def test_zero_below_the_horizon(model):
    """Directions 1 deg below a station's horizon and the nadir give exact zeros, also
    with the phase-centre correction; 1 deg above they do not; no NaN anywhere."""
    ra, dec = _altaz_radec([-1.0, -1.0, -89.0, 1.0, 1.0], [0.0, 200.0, 0.0, 0.0, 200.0],
                           T0, model.positions[0])
    for corrected in (False, True):
        j = model.jones([T0], FREQ, ra, dec, stations=[0], centre_correction=corrected)
        assert np.all(np.isfinite(j))
        assert np.all(j[:, :, :, :3] == 0)
        assert np.all(np.abs(j[:, :, :, 3:]).max(axis=(-2, -1)) > 1e-4)


def test_frequency_weights_reproduce_pyuvdata_frequency_interpolation():
    """The channel weights are pyuvdata's cubic interpolation: applied to the file's data
    they equal ``UVBeam.interp(freq_array=...)`` on its own grid."""
    beam = read_beam_file(default_beam_file())
    freq = np.array([100e6, 107.7e6, 121.3e6, 144.99e6])
    want, _ = beam.interp(freq_array=freq, return_basis_vector=False)
    w = frequency_weights(beam.freq_array, freq)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)
    got = np.einsum("ck,abk...->abc...", w, beam.data_array)
    assert np.abs(got - want).max() < 1e-10 * np.abs(beam.data_array).max()


def test_channels_outside_the_file_refused(tmp_path):
    """150 MHz (HERA_NicCST covers 100-145 MHz): one line naming the range and the
    remedies, from the API and from `msleak predict`; the MS keeps its columns."""
    ra0, dec0 = _zenith_radec(T0, HERA_ITRF)
    ms = build_ms(tmp_path / "high.ms", telescope="HERA", site_itrf=HERA_ITRF, enu=ENU,
                  dish_diameter=14.0, ra_deg=np.degrees(ra0), dec_deg=np.degrees(dec0),
                  time0_s=T0, freq0_hz=150e6)
    with pytest.raises(InputError, match=r"covers 100-145 MHz.*150 MHz requested") as err:
        load_beam("uvbeam", ms)
    assert "\n" not in str(err.value) and "--freq-min" in str(err.value)
    before = column_names(ms)
    sky = write_sky(tmp_path / "s.skymodel", [(ra0 + 0.02, dec0 + 0.01, 1.0, 0.3, 0.2, 0.0)])
    line = one_error_line(CliRunner().invoke(
        cli, ["predict", str(ms), "--sky", str(sky), "--beam", "uvbeam"]))
    assert "covers 100-145 MHz" in line and "--beam-file" in line
    assert column_names(ms) == before


def test_jones_outside_the_file_refused(hera_ms, model):
    ra0, dec0 = phase_centre(hera_ms)
    with pytest.raises(InputError, match=r"covers 100-145 MHz.*99.9 MHz requested"):
        model.jones([T0], [99.9e6, 120e6], [ra0], [dec0])


def test_power_and_unreadable_files_refused(tmp_path, hera_ms):
    beam = read_beam_file(default_beam_file())
    beam.efield_to_power()
    power = tmp_path / "power.beamfits"
    beam.write_beamfits(str(power))
    with pytest.raises(InputError, match="a power beam, not an E-field beam") as err:
        uvbeam_from_ms(hera_ms, beam_file=power)
    assert "`beam_file=PATH`" in str(err.value) and "\n" not in str(err.value)
    junk = tmp_path / "junk.beamfits"
    junk.write_bytes(b"\x00not a beam\x01" * 50)
    with pytest.raises(InputError, match="UVBeam cannot read it") as err:
        uvbeam_from_ms(hera_ms, beam_file=junk)
    assert "\n" not in str(err.value)
    line = one_error_line(CliRunner().invoke(
        cli, ["beam", str(hera_ms), "-o", str(tmp_path / "b.png"), "--beam", "uvbeam",
              "--beam-file", str(power)]))
    assert "power beam" in line



def test_missing_packages_name_the_extra(monkeypatch, hera_ms):
    """Without pyuvdata, or (for the default file) pyuvsim: one line naming the extra."""
    import importlib.resources

    import msleak.io.uvbeam as io_uvbeam

    monkeypatch.setattr(io_uvbeam, "UVBeam", None)
    with pytest.raises(BeamUnavailable, match=r"needs the Python package pyuvdata; "
                                              r"pip install 'msleak\[hera\]'"):
        load_beam("uvbeam", hera_ms)
    monkeypatch.undo()

    def no_pyuvsim(package):
        raise ModuleNotFoundError(f"No module named {package!r}")

    monkeypatch.setattr(importlib.resources, "files", no_pyuvsim)
    with pytest.raises(BeamUnavailable, match=r"comes with pyuvsim.*pip install"):
        load_beam("uvbeam", hera_ms)
