"""``--ionosphere spinifex`` and ``ionex:PATH``: thin-shell RMs computed offline for an MS,
against answers known in advance: the pierce points against astropy and a sphere, the field
against IGRF (ppigrf) evaluated independently, RM = e^3/(8 pi^2 eps0 m_e^2 c^3) TEC B_par,
a uniform IONEX map read back exactly, and predicting with the model equal to predicting
with the same RMs given as a CSV table. No test reaches the network (socket connections
fail)."""

from __future__ import annotations

import socket
import sys

import numpy as np
import pytest
from click.testing import CliRunner

import astropy.units as u
from astropy import constants as const
from astropy.coordinates import AltAz, EarthLocation, SkyCoord
from astropy.time import Time

from ms_helpers import one_error_line, phase_centre, table, write_sky
from msleak.adapters.ionosphere import rotation_measures
from msleak.adapters.spinifex_rm import SAMPLE_STEP_S, SHELL_HEIGHT_KM, b_along_los, \
    mean_pierce_point, parse_model_spec, pierce_points, station_rms, vertical_tec
from msleak.cli import cli
from msleak.errors import ConfigurationError, InputError
from msleak.verbs.predict import predict
from peers import require

require("spinifex", "the thin-shell ionosphere models need spinifex: pip install "
        "'msleak[ionosphere]'")

#: LOFAR CS002 and a station 3 km east of it (ITRF, m); 3C196 on 2012-12-16 near transit
STATIONS = np.array([[3826577.1, 461022.9, 5064892.8], [3826540.0, 463990.0, 5064670.0]])
RA, DEC = np.radians(123.4), np.radians(48.2)
TIMES = Time(["2012-12-16T00:30:00", "2012-12-16T02:00:00", "2012-12-16T04:30:00"],
             scale="utc").mjd * 86400.0
R_EARTH_KM = 6371.0          # spinifex's spherical Earth


@pytest.fixture(autouse=True)
def offline(monkeypatch):
    """Every socket connection fails: the models must need no network."""
    def refuse(*args, **kwargs):
        raise OSError("network use in an offline test")

    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)


def _independent_pierce(station, times):
    """Pierce point (lon, lat rad, geocentric), the unit line of sight (ITRF) and the
    airmass: astropy AltAz at the station, East-North-Up to ITRF by the station's geodetic
    longitude and latitude, and the intersection with a sphere R_EARTH_KM + shell."""
    loc = EarthLocation.from_geocentric(*station, unit=u.m)
    aa = SkyCoord(RA * u.rad, DEC * u.rad).transform_to(
        AltAz(obstime=Time(times / 86400.0, format="mjd", scale="utc"), location=loc))
    alt, az = aa.alt.rad, aa.az.rad
    lon, lat = loc.lon.rad, loc.lat.rad
    east = np.array([-np.sin(lon), np.cos(lon), 0.0])
    north = np.array([-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)])
    up = np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    d = (np.cos(alt) * np.sin(az))[:, None] * east + (np.cos(alt) * np.cos(az))[:, None] \
        * north + np.sin(alt)[:, None] * up
    p = station / 1e3
    radius = R_EARTH_KM + SHELL_HEIGHT_KM
    b = d @ p
    s = -b + np.sqrt(b ** 2 - (p @ p - radius ** 2))
    x = p + s[:, None] * d
    return (np.arctan2(x[:, 1], x[:, 0]), np.arcsin(x[:, 2] / radius), d,
            radius / np.einsum("ij,ij->i", x, d), x)


def test_pierce_points_agree_with_astropy_and_a_sphere():
    got = pierce_points(STATIONS, TIMES, RA, DEC)
    for k, station in enumerate(STATIONS):
        lon, lat, _, airmass, _ = _independent_pierce(station, TIMES)
        dlon = np.angle(np.exp(1j * (np.radians(got.lon_deg[k]) - lon)))
        assert np.abs(dlon).max() < 1e-6 and \
            np.abs(np.radians(got.lat_deg[k]) - lat).max() < 1e-6
        np.testing.assert_allclose(got.airmass[k], airmass, rtol=1e-6)
    # two stations 3 km apart pierce the shell about 3 km apart
    sep = np.hypot((got.lon_deg[1] - got.lon_deg[0]) * np.cos(np.radians(got.lat_deg[0])),
                   got.lat_deg[1] - got.lat_deg[0])
    assert np.all(np.abs(np.radians(sep) * (R_EARTH_KM + SHELL_HEIGHT_KM) - 3.0) < 0.5)


def test_field_along_the_line_of_sight_is_igrf():
    """spinifex's B_par equals ppigrf's field at the independent pierce point, turned to
    ITRF and projected on the line of sight by hand (1e-4: the pierce points differ by
    < 1e-6 rad; IGRF varies over hundreds of km)."""
    from ppigrf import igrf_gc

    got = b_along_los(pierce_points(STATIONS[:1], TIMES, RA, DEC))[0]
    lon, lat, d, _, x = _independent_pierce(STATIONS[0], TIMES)
    colat = np.pi / 2 - lat
    br, bt, bp = (c[0] for c in igrf_gc(np.linalg.norm(x, axis=1), np.degrees(colat),
                                        np.degrees(lon), Time(TIMES[0] / 86400, format="mjd")
                                        .to_datetime()))
    r_hat = np.stack([np.sin(colat) * np.cos(lon), np.sin(colat) * np.sin(lon),
                      np.cos(colat)], -1)
    t_hat = np.stack([np.cos(colat) * np.cos(lon), np.cos(colat) * np.sin(lon),
                      -np.sin(colat)], -1)
    p_hat = np.stack([-np.sin(lon), np.cos(lon), np.zeros_like(lon)], -1)
    b = (br[:, None] * r_hat + bt[:, None] * t_hat + bp[:, None] * p_hat) * 1e-9
    np.testing.assert_allclose(got, np.einsum("ij,ij->i", b, d), rtol=1e-4)
    assert np.all(got < 0)     # the northern field points down, the line of sight up


def test_rm_is_the_thin_shell_formula():
    constant = float((const.e.si ** 3 / (8 * np.pi ** 2 * const.eps0 * const.m_e ** 2
                                         * const.c ** 3)).decompose().value)
    assert constant == pytest.approx(2.63e-13, rel=2e-3)
    model = parse_model_spec("spinifex")
    pierce = pierce_points(STATIONS, TIMES, RA, DEC)
    lon, lat = mean_pierce_point(pierce)               # IRI: one column per time
    assert np.all(np.abs(lat - pierce.lat_deg.mean(0)) < 1e-3)
    tec = vertical_tec(lon, lat, TIMES, model)
    b_toward_observer = -b_along_los(pierce)
    expected = constant * tec * pierce.airmass * b_toward_observer
    np.testing.assert_allclose(station_rms(STATIONS, TIMES, RA, DEC, model), expected,
                               rtol=1e-6)
    assert np.all((tec > 1e16) & (tec < 50e16))      # a winter night: 1-50 TECU


def _write_ionex(path, day: str, tec_of_lat, maps: int = 2):
    """An IONEX file of ``maps`` TEC maps over ``day`` (00:00 to 24:00 UTC), 5 x 2.5 deg
    grid, TEC(lat) in TECU (written in units of 0.1 TECU, exponent -1)."""
    y, m, d = (int(v) for v in day.split("-"))
    lats, lons = np.arange(87.5, -87.6, -2.5), np.arange(-180.0, 180.1, 5.0)

    def line(record, label):
        return f"{record:<60}{label:<20}\n"

    out = [line("     1.0            IONOSPHERE MAPS     GPS", "IONEX VERSION / TYPE"),
           line(f"{y:6d}{m:6d}{d:6d}{0:6d}{0:6d}{0:6d}", "EPOCH OF FIRST MAP"),
           line(f"{y:6d}{m:6d}{d + 1:6d}{0:6d}{0:6d}{0:6d}", "EPOCH OF LAST MAP"),
           line(f"{86400 // (maps - 1):6d}", "INTERVAL"),
           line(f"{maps:6d}", "# OF MAPS IN FILE"), line(f"{2:6d}", "MAP DIMENSION"),
           line(f"  {450.0:6.1f}{450.0:6.1f}{0.0:6.1f}", "HGT1 / HGT2 / DHGT"),
           line(f"  {87.5:6.1f}{-87.5:6.1f}{-2.5:6.1f}", "LAT1 / LAT2 / DLAT"),
           line(f"  {-180.0:6.1f}{180.0:6.1f}{5.0:6.1f}", "LON1 / LON2 / DLON"),
           line(f"{-1:6d}", "EXPONENT"), line("", "END OF HEADER")]
    for k in range(maps):
        out += [line(f"{k + 1:6d}", "START OF TEC MAP"),
                line(f"{y:6d}{m:6d}{d:6d}{0:6d}{0:6d}{0:6d}", "EPOCH OF CURRENT MAP")]
        for lat in lats:
            out.append(line(f"  {lat:6.1f}{-180.0:6.1f}{180.0:6.1f}{5.0:6.1f}{450.0:6.1f}",
                            "LAT/LON1/LON2/DLON/H"))
            values = [f"{round(10 * tec_of_lat(lat)):5d}"] * lons.size
            out += ["".join(values[i:i + 16]) + "\n" for i in range(0, lons.size, 16)]
        out.append(line(f"{k + 1:6d}", "END OF TEC MAP"))
    out.append(line("", "END OF FILE"))
    path.write_text("".join(out))
    return path


def test_ionex_maps_are_read_and_interpolated_exactly(tmp_path):
    """TEC linear in latitude (bilinear interpolation is exact) read back at the pierce
    points to 1e-9, and the RM is the thin-shell formula with it."""
    tec_of_lat = lambda lat: 20.0 + 0.4 * lat                              # noqa: E731
    path = _write_ionex(tmp_path / "maps.inx", "2012-12-16", tec_of_lat)
    model = parse_model_spec(f"ionex:{path}")
    pierce = pierce_points(STATIONS, TIMES, RA, DEC)
    tec = vertical_tec(pierce.lon_deg, pierce.lat_deg, TIMES, model)
    np.testing.assert_allclose(tec, tec_of_lat(pierce.lat_deg) * 1e16, rtol=1e-9)
    rm = station_rms(STATIONS, TIMES, RA, DEC, model)
    np.testing.assert_allclose(rm, -2.6312e-13 * tec * pierce.airmass * b_along_los(pierce),
                               rtol=1e-4)
    assert np.all((rm > 0.05) & (rm < 5.0))


def test_model_rms_for_a_lofar_night(small_lofar_ms):
    """IRI (F10.7 = 100 sfu) on the 3C196 night: one row per station, sampled every
    SAMPLE_STEP_S over the field's times, a few tenths of rad m^-2."""
    rms = rotation_measures("spinifex", small_lofar_ms)
    with table(small_lofar_ms) as t:
        times = np.unique(t.getcol("TIME"))
    with table(f"{small_lofar_ms}/ANTENNA") as t:
        names = tuple(str(n) for n in t.getcol("NAME"))
    assert rms.label == "spinifex:iri,f107=100" and rms.stations == names
    assert rms.times[0] == times[0] and rms.times[-1] == times[-1]
    assert np.diff(rms.times).max() <= SAMPLE_STEP_S
    assert np.all((rms.rm > 0.05) & (rms.rm < 5.0))
    # the stations (< 1 km apart) see nearly the same RM, yet each its own
    assert np.ptp(rms.rm, axis=0).max() < 1e-2 * rms.rm.mean()


def test_predict_with_the_model_equals_its_table(small_lofar_ms, tmp_path):
    rms = rotation_measures("spinifex", small_lofar_ms)
    csv = tmp_path / "rm.csv"
    csv.write_text("time,station,rm\n" + "".join(
        f"{float(t)!r},{name},{float(r)!r}\n" for k, name in enumerate(rms.stations)
        for t, r in zip(rms.times, rms.rm[k])))
    ra, dec = phase_centre(small_lofar_ms)
    sky = write_sky(tmp_path / "sky.skymodel", [(ra, dec, 2.0, 0.7, -0.4, 0.0),
                                                (ra + 0.03, dec - 0.02, 1.0, -0.3, 0.5, 0.0)])
    result = CliRunner().invoke(cli, ["predict", str(small_lofar_ms), "--sky", str(sky),
                                      "--beam", "dipole", "--double", "--double-column",
                                      "--column", "M_SPX",
                                      "--ionosphere", "spinifex"])
    assert result.exit_code == 0, result.output
    table_run = predict(small_lofar_ms, sky, column=None, beam="dipole", double=True,
                        ionosphere=csv)
    plain = predict(small_lofar_ms, sky, column=None, beam="dipole", double=True)
    with table(small_lofar_ms) as t:
        got = t.getcol("M_SPX")[table_run.coords["row"].values]
    np.testing.assert_allclose(got, table_run.values, rtol=1e-12,
                               atol=1e-12 * np.abs(table_run.values).max())
    assert np.abs(got - plain.values).max() > 1e-3 * np.abs(plain.values).max()


@pytest.mark.parametrize("spec,message", [
    ("spinifex:uqr", "spinifex downloads these maps and msleak runs offline"),
    ("spinifex:tomion", "download an IONEX file yourself and give ionex:PATH"),
    ("spinifex:f107=x", "f107 must be a solar flux in sfu"),
    ("spinifex:foo", "give spinifex, spinifex:f107=SFU or ionex:PATH"),
    ("ionex:/no/such/file.inx", "no IONEX file /no/such/file.inx"),
])
def test_bad_model_specs_are_refused_in_one_line(small_lofar_ms, tmp_path, spec, message):
    with pytest.raises(InputError, match=message.replace(".", r"\.")):
        rotation_measures(spec, small_lofar_ms)
    sky = write_sky(tmp_path / "sky.skymodel", [(*phase_centre(small_lofar_ms), 1, 0, 0, 0)])
    result = CliRunner().invoke(cli, ["predict", str(small_lofar_ms), "--sky", str(sky),
                                      "--beam", "none", "--column", "M_BAD",
                                      "--ionosphere", spec])
    assert message in one_error_line(result)


def test_ionex_maps_of_another_day_are_refused(small_lofar_ms, tmp_path):
    path = _write_ionex(tmp_path / "other.inx", "2013-03-01", lambda lat: 10.0)
    with pytest.raises(InputError, match="do not cover the observation at 2012-12-1"):
        rotation_measures(f"ionex:{path}", small_lofar_ms)
    bad = tmp_path / "bad.inx"
    bad.write_text("not an IONEX file\n")
    with pytest.raises(InputError, match="not a readable IONEX file"):
        rotation_measures(f"ionex:{bad}", small_lofar_ms)


def test_missing_spinifex_names_the_extra(small_lofar_ms, monkeypatch):
    monkeypatch.setitem(sys.modules, "spinifex", None)
    with pytest.raises(ConfigurationError, match=r"pip install 'msleak\[ionosphere\]'"):
        rotation_measures("spinifex", small_lofar_ms)
