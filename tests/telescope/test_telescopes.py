"""HERA and MWA Measurement Sets, the beam options of every command, the analytic leakage
of symmetric crossed dipoles, and DP3 reading every telescope's MS."""

from __future__ import annotations

import csv
import importlib.resources

import astropy.units as u
import casacore.tables as pt
import numpy as np
import pytest
from astropy.coordinates import EarthLocation

from msleak.adapters.beams import beam_options
from msleak.beam.dipole import DipoleBeam
from msleak.beam.mueller import jones_to_mueller
from msleak.errors import InputError
from msleak.verbs.simulate import simulate


def _col(ms, name, table=""):
    with pt.table(f"{ms}/{table}" if table else str(ms), ack=False) as t:
        return t.getcol(name)


def _hera_reference() -> dict:
    """HERA antenna positions read straight from pyuvdata's CSV and its site."""
    from pyuvdata.telescopes import KNOWN_TELESCOPES

    site = KNOWN_TELESCOPES["HERA"]["location"]
    origin = np.array([site.x.to_value(u.m), site.y.to_value(u.m), site.z.to_value(u.m)])
    text = importlib.resources.files("pyuvdata").joinpath("data", "hera_ant_pos.csv")
    with text.open() as fh:
        rows = list(csv.DictReader(fh))
    return {r["name"]: origin + [float(r["x"]), float(r["y"]), float(r["z"])] for r in rows}


def test_hera_ms_has_pyuvdata_positions(tmp_path):
    ms = simulate(tmp_path / "hera.ms", telescope="hera", stations="HH1[0-2]?", nchan=2,
                  interval=600.0)
    names = list(_col(ms, "NAME", "ANTENNA"))
    ref = _hera_reference()
    assert len(names) == 30 and all(n.startswith("HH1") for n in names)
    np.testing.assert_allclose(_col(ms, "POSITION", "ANTENNA"), [ref[n] for n in names],
                               atol=1e-6)
    assert np.all(_col(ms, "DISH_DIAMETER", "ANTENNA") == 14.0)
    assert list(_col(ms, "TELESCOPE_NAME", "OBSERVATION")) == ["HERA"]
    times = np.unique(_col(ms, "TIME"))
    assert times.size == 6 and times[-1] - times[0] == pytest.approx(5 * 600.0)  # 1 h
    assert _col(ms, "CHAN_FREQ", "SPECTRAL_WINDOW")[0, 0] == 135e6    # inside the beam file
    # EoR0 (RA 0) at transit mid-way: the local sidereal time there is ~0 h (apparent
    # against J2000 right ascension: < 0.5 deg apart in 2020)
    site = EarthLocation.from_geocentric(*np.mean([ref[n] for n in names], axis=0), unit=u.m)
    assert site.lat.deg == pytest.approx(-30.72, abs=0.01)
    from astropy.time import Time

    lst = Time(times.mean() / 86400.0, format="mjd", scale="utc").sidereal_time(
        "apparent", longitude=site.lon).deg
    assert min(lst, 360 - lst) < 0.5


def test_mwa_ms_has_pyuvsim_layout(tmp_path):
    ms = simulate(tmp_path / "mwa.ms", telescope="mwa", stations="Tile01?", nchan=2,
                  interval=600.0)
    names = list(_col(ms, "NAME", "ANTENNA"))
    assert names == [f"Tile01{i}" for i in range(1, 9)]
    # the layout's ENU offsets, recovered from the ITRF positions in the site's frame
    text = importlib.resources.files("pyuvsim").joinpath("data", "mwa_128T_layout.csv")
    enu = {p[0]: np.array(p[3:6], float) for p in
           (line.split() for line in text.read_text().splitlines()[1:]) if len(p) == 6}
    site = EarthLocation.from_geodetic(116.67081523611111 * u.deg, -26.70331940555556 * u.deg,
                                       377.827 * u.m)
    lon, lat = site.lon.to_value(u.rad), site.lat.to_value(u.rad)
    rot = np.array([[-np.sin(lon), np.cos(lon), 0.0],
                    [-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)],
                    [np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)]])
    origin = np.array([site.x.to_value(u.m), site.y.to_value(u.m), site.z.to_value(u.m)])
    got = (_col(ms, "POSITION", "ANTENNA") - origin) @ rot.T
    np.testing.assert_allclose(got, [enu[n] for n in names], atol=1e-3)
    assert np.all(_col(ms, "DISH_DIAMETER", "ANTENNA") == 4.4)
    assert list(_col(ms, "TELESCOPE_NAME", "OBSERVATION")) == ["MWA"]
    # zenith delays over the whole observation, as cotter and Birli write them
    from msleak.io.mwa import read_mwa_delays

    assert np.all(read_mwa_delays(ms) == 0)
    times = _col(ms, "TIME")
    interval = _col(ms, "INTERVAL", "MWA_TILE_POINTING")[0]
    assert interval[0] == pytest.approx(times.min() - 300.0)
    assert interval[1] == pytest.approx(times.max() + 300.0)
    # the direction of zenith delays is the zenith mid-way: EoR0 (RA 0, Dec -27) at
    # transit is 0.3 deg from the zenith of the MWA (latitude -26.70)
    ra, dec = _col(ms, "DIRECTION", "MWA_TILE_POINTING")[0]
    zenith_to_eor0 = np.degrees(np.arccos(
        np.sin(dec) * np.sin(np.radians(-27.0)) + np.cos(dec) * np.cos(np.radians(-27.0))
        * np.cos(ra)))
    assert 0.05 < zenith_to_eor0 < 0.8
    assert np.degrees(dec) == pytest.approx(-26.70, abs=0.2)


@pytest.mark.parametrize("telescope,stations", [
    ("lofar", "CS00[1-3]HBA0"), ("ska-low", "S00[0-2]"), ("hera", "HH1[0-2]"),
    ("mwa", "Tile01[1-3]")])
def test_dp3_reads_every_telescope(tmp_path, telescope, stations):
    """DP3 copies each telescope's MS (msin -> msout, no steps): rows, UVW and antennas
    equal the original."""
    from dp3run import dp3_available, run_dp3
    from peers import missing

    if not dp3_available():
        missing("dp3", "dp3 (pip install dp3) reads every telescope's MS")
    ms = simulate(tmp_path / "in.ms", telescope=telescope, stations=stations, nchan=2,
                  duration=0.2, interval=360.0)
    out = tmp_path / "out.ms"
    run_dp3([f"msin={ms}", f"msout={out}", "steps=[]"], threads=1, cwd=tmp_path, timeout=300)
    np.testing.assert_allclose(_col(out, "UVW"), _col(ms, "UVW"), atol=1e-6)
    assert list(_col(out, "NAME", "ANTENNA")) == list(_col(ms, "NAME", "ANTENNA"))


@pytest.mark.parametrize("model,kwargs,message", [
    ("everybeam", dict(diameter=30.0), "diameter applies to beam 'dipole' only"),
    ("dipole", dict(diameter=-1.0), "diameter takes a positive value"),
    ("dipole", dict(beam_file="x.beamfits"), "beam_file applies to beam 'uvbeam' or 'hyperbeam'"),
    ("uvbeam", dict(element_model="fee"), "element_model applies to beam 'everybeam'"),
    ("none", dict(element_model="fee"), "not beam 'none'"),
])
def test_beam_options_refused(model, kwargs, message):
    with pytest.raises(InputError, match=message):
        beam_options(model, **kwargs)


def test_beam_options_passed():
    assert beam_options("hyperbeam", element_model="fee", beam_file="f.h5") == {
        "element_model": "fee", "beam_file": "f.h5"}
    assert beam_options("dipole", diameter=14) == {"diameter_m": 14.0}
    assert beam_options("everybeam") == {}


def test_symmetric_dipoles_leak_quadratically(tmp_path):
    """Crossed short dipoles (no station factor) tracking a source at the zenith, beam at
    the phase centre removed: no leakage at the centre, and at zenith angle theta the
    Q,U -> I leakage sqrt(M_IQ^2 + M_IU^2) / M_II = sin^2 theta / (1 + cos^2 theta)
    (the dipoles answer cos^2 theta to the field along the zenith-angle direction and 1
    across it), ~ theta^2 / 2."""
    site = EarthLocation.from_geodetic(21.428 * u.deg, -30.7215 * u.deg, 1050 * u.m)
    itrf = np.array([site.x.to_value(u.m), site.y.to_value(u.m), site.z.to_value(u.m)])
    t = 56329.0 * 86400.0
    from astropy.coordinates import AltAz, SkyCoord
    from astropy.time import Time

    frame = AltAz(obstime=Time(t / 86400.0, format="mjd", scale="utc"), location=site)
    zenith = SkyCoord(alt=90 * u.deg, az=0 * u.deg, frame=frame).icrs
    beam = DipoleBeam([itrf, itrf + [10.0, 0, 0]], [14.0, 14.0],
                      (zenith.ra.rad, zenith.dec.rad), (zenith.ra.rad, zenith.dec.rad),
                      factor="none")
    theta = np.radians([0.0, 1.0, 2.0, 5.0, 10.0, 20.0])
    az = np.radians(35.0)
    dirs = SkyCoord(alt=90 * u.deg - theta * u.rad, az=np.full(theta.size, az) * u.rad,
                    frame=frame).icrs
    j = beam.jones([t], [150e6], dirs.ra.rad, dirs.dec.rad, stations=[0],
                   centre_correction=True)[0, 0, 0]
    m = np.real(jones_to_mueller(j, j))   # (ndir, 4, 4), Stokes I, Q, U, V
    leak = np.hypot(m[:, 0, 1], m[:, 0, 2]) / m[:, 0, 0]
    expected = np.sin(theta) ** 2 / (1 + np.cos(theta) ** 2)
    assert leak[0] < 1e-9
    np.testing.assert_allclose(leak[1:], expected[1:], rtol=1e-3)
    np.testing.assert_allclose(leak[1:3] / theta[1:3] ** 2, 0.5, rtol=1e-3)


def test_everybeam_on_hera_and_mwa_names_their_models(tmp_path, monkeypatch):
    """EveryBeam has no HERA model and needs a downloaded file for the MWA: the one-line
    error names the msleak model that does work."""
    from click.testing import CliRunner

    from msleak.cli import cli

    monkeypatch.delenv("MWA_BEAM_FILE", raising=False)
    for tel, model in (("hera", "--beam uvbeam"), ("mwa", "--beam hyperbeam")):
        ms = simulate(tmp_path / f"{tel}.ms", telescope=tel, stations="HH1[0-2],Tile01[1-3]",
                      nchan=2, duration=0.2, interval=360.0)
        result = CliRunner().invoke(cli, ["beam", str(ms), "-o", str(tmp_path / "b.png")])
        assert result.exit_code == 2, result.output
        line = [x for x in result.stderr.splitlines() if x.strip()]
        assert len(line) == 1 and line[0].startswith("msleak: error:") and model in line[0]
