"""msleak simulate: MS structure, UVW against independent computations, EveryBeam, errors."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from msleak.cli import cli
from msleak.io.ms import (read_antennas, read_corr_types, read_fields, read_spectral_windows,
                          read_telescope_name, read_times, has_lofar_tables)
from msleak.telescope.layouts import lofar_hba_core, read_layout_file

pt = pytest.importorskip("casacore.tables")


def _main(ms, *cols):
    with pt.table(str(ms), ack=False) as t:
        return [t.getcol(c) for c in cols]


def test_default_layout_is_48_hba_core_fields():
    layout = lofar_hba_core()
    assert len(layout) == 48
    assert layout.names[0] == "CS001HBA0" and layout.names[-1] == "CS501HBA1"
    # core stations lie within ~2 km of each other (longest core baseline ~3.5 km)
    d = np.linalg.norm(layout.positions[:, None] - layout.positions[None], axis=-1)
    assert 2000 < d.max() < 4000
    for f in layout.fields:
        assert f.element_offsets.shape == (24, 3)
        assert f.tile_offsets.shape == (16, 3)
        np.testing.assert_allclose(f.axes @ f.axes.T, np.eye(3), atol=1e-6)
        # tiles: 4 x 4 dipoles on a 1.25 m grid, so the tile spans 3.75 m side to side
        span = np.linalg.norm(f.tile_offsets[:, None] - f.tile_offsets[None], axis=-1).max()
        assert span == pytest.approx(3.75 * np.sqrt(2), rel=1e-5)


def test_hba_tiles_are_lofarantpos_dipoles_as_an_exact_lattice():
    """Every core field's tile equals lofarantpos's dipoles minus their tile centre (which
    it rounds to float32) to 1e-6 m, every tile of the field, and is a product lattice to
    1e-12 m in its order: the fast beam then sums 4 + 4 terms per tile (docs/beam.md)."""
    import lofarantpos.db

    from msleak.beam.lofar_fast import lattice_factors

    db = lofarantpos.db.LofarAntennaDatabase()
    for f in lofar_hba_core().fields:
        tiles = np.asarray(db.antenna_pqr(f.name), dtype=float)
        dipoles = np.asarray(db.hba_dipole_pqr(f.name), dtype=float).reshape(len(tiles), 16, 3)
        pqr = f.tile_offsets @ f.axes.T
        np.testing.assert_allclose(dipoles - tiles[:, None], np.broadcast_to(pqr, dipoles.shape),
                                   rtol=0, atol=1e-6)
        a, b = lattice_factors(f.tile_offsets, tol=1e-12)
        assert len(a) == len(b) == 4


def test_rows_times_channels(small_lofar_ms):
    time, a1, a2, interval = _main(small_lofar_ms, "TIME", "ANTENNA1", "ANTENNA2", "INTERVAL")
    nant = 6
    nbl = nant * (nant - 1) // 2          # no autocorrelations by default
    times = read_times(small_lofar_ms)
    assert len(times) == 4 and len(time) == 4 * nbl
    assert np.all(a1 < a2)
    np.testing.assert_allclose(np.diff(times), 120.0, atol=1e-6)
    np.testing.assert_allclose(interval, 120.0)
    # TIME is the centre of each integration: first centre = start + interval / 2
    with pt.table(str(small_lofar_ms / "OBSERVATION"), ack=False) as t:
        t_start = t.getcell("TIME_RANGE", 0)[0]
    assert times[0] - t_start == pytest.approx(60.0, abs=1e-6)
    spw = read_spectral_windows(small_lofar_ms)
    assert len(spw) == 1
    np.testing.assert_allclose(spw[0].freq, 150e6 + 195312.5 * np.arange(4), rtol=0, atol=1e-3)
    np.testing.assert_allclose(spw[0].width, 195312.5)
    data, flag, wspec = _main(small_lofar_ms, "DATA", "FLAG", "WEIGHT_SPECTRUM")
    assert data.shape == (4 * nbl, 4, 4) and not np.any(data) and not np.any(flag)
    assert np.all(wspec == 1)


def test_autocorrelations_option(make_ms):
    ms = make_ms("auto.ms", autocorrelations=True, duration=120 / 3600)
    a1, a2 = _main(ms, "ANTENNA1", "ANTENNA2")
    assert len(a1) == 6 * 7 // 2 and np.sum(a1 == a2) == 6


def test_subtables_valid(small_lofar_ms):
    assert read_telescope_name(small_lofar_ms) == "LOFAR"
    assert [list(c) for c in read_corr_types(small_lofar_ms)] == [[9, 10, 11, 12]]
    fields = read_fields(small_lofar_ms)
    assert len(fields) == 1 and fields[0].name == "3C196"
    assert np.degrees(fields[0].ra) == pytest.approx(123.4) and \
        np.degrees(fields[0].dec) == pytest.approx(48.2)
    ants = read_antennas(small_lofar_ms)
    assert ants.names == ["CS001HBA0", "CS001HBA1", "CS002HBA0", "CS002HBA1",
                          "CS003HBA0", "CS003HBA1"]
    assert has_lofar_tables(small_lofar_ms)
    with pt.table(str(small_lofar_ms), ack=False) as t:
        assert t.getcolkeyword("UVW", "MEASINFO")["Ref"] == "J2000"
        assert t.getdminfo("DATA")["TYPE"] == "TiledColumnStMan"
        keywords = t.getkeywords()
    for sub in ("LOFAR_ANTENNA_FIELD", "LOFAR_ELEMENT_FAILURE", "LOFAR_STATION"):
        assert sub in keywords
    with pt.table(str(small_lofar_ms / "LOFAR_ANTENNA_FIELD"), ack=False) as t:
        assert t.nrows() == 6
        assert list(t.getcol("NAME")) == ["HBA0", "HBA1"] * 3
        assert t.getcell("ELEMENT_OFFSET", 0).shape == (24, 3)
        assert t.getcell("TILE_ELEMENT_OFFSET", 0).shape == (16, 3)
        assert t.getcell("ELEMENT_FLAG", 0).shape == (24, 2)
        np.testing.assert_allclose(t.getcol("POSITION"), ants.positions)
    with pt.table(str(small_lofar_ms / "ANTENNA"), ack=False) as t:
        np.testing.assert_allclose(t.getcol("LOFAR_PHASE_REFERENCE"), ants.positions)
    with pt.table(str(small_lofar_ms / "FIELD"), ack=False) as t:
        assert t.nrows() == 1
        np.testing.assert_allclose(t.getcell("LOFAR_TILE_BEAM_DIR", 0).ravel(),
                                   np.radians([123.4, 48.2]))


def test_uvw_matches_casacore_taql(small_lofar_ms):
    (uvw,) = _main(small_lofar_ms, "UVW")
    ref = pt.taql(f"select mscal.uvwj2000() as U from '{small_lofar_ms}'").getcol("U")
    assert np.abs(uvw - ref).max() < 0.01          # 1 cm
    assert np.abs(uvw).max() > 100                 # and non-trivial


def test_uvw_matches_astropy(small_lofar_ms):
    """Independent UVW: antenna positions rotated ITRS -> GCRS by astropy, projected on the
    J2000 (u, v, w) axes of the phase centre. casacore's baseline conversion to J2000 and
    astropy's position transform differ at the level of annual aberration (at most
    20.5 arcsec ~ 1e-4 rad of the baseline length); measured here: < 3e-5 |b| (< 2 cm)."""
    from astropy.coordinates import GCRS, ITRS, CartesianRepresentation
    from astropy.time import Time
    import astropy.units as u

    time, a1, a2, uvw = _main(small_lofar_ms, "TIME", "ANTENNA1", "ANTENNA2", "UVW")
    pos = read_antennas(small_lofar_ms).positions
    ra, dec = np.radians(123.4), np.radians(48.2)
    axes = np.array([[-np.sin(ra), np.cos(ra), 0.0],
                     [-np.sin(dec) * np.cos(ra), -np.sin(dec) * np.sin(ra), np.cos(dec)],
                     [np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)]])
    expected = np.zeros_like(uvw)
    for t in np.unique(time):
        obstime = Time(t / 86400.0, format="mjd", scale="utc")
        gcrs = ITRS(CartesianRepresentation(pos.T * u.m), obstime=obstime).transform_to(
            GCRS(obstime=obstime)).cartesian.xyz.to_value(u.m).T
        sel = time == t
        expected[sel] = (gcrs[a2[sel]] - gcrs[a1[sel]]) @ axes.T
    diff = np.linalg.norm(uvw - expected, axis=1)
    length = np.linalg.norm(uvw, axis=1)
    assert np.all(diff <= 1e-4 * length + 1e-3)
    assert diff.max() < 0.05                        # a few cm


def test_everybeam_loads_and_is_identity_at_centre(small_lofar_ms):
    from msleak._everybeam import import_everybeam

    eb = import_everybeam()
    tel = eb.load_telescope(str(small_lofar_ms),
                            beam_normalisation_mode=eb.BeamNormalisationMode.full)
    assert tel.nr_stations == 6
    for t in read_times(small_lofar_ms)[[0, -1]]:
        for station in range(6):
            for freq in (150e6, 150.5e6):
                jones = tel.station_response(t, station, freq)
                np.testing.assert_allclose(jones, np.eye(2), atol=1e-5)


def test_3c196_is_centred_on_transit(make_ms):
    from astropy.coordinates import EarthLocation
    from astropy.time import Time
    import astropy.units as u

    ms = make_ms("transit.ms", duration=2.0, interval=600.0, stations="CS001HBA*")
    times = read_times(ms)
    mid = Time(0.5 * (times[0] + times[-1]) / 86400.0, format="mjd", scale="utc")
    lon = EarthLocation.from_geocentric(*read_antennas(ms).positions[0], unit=u.m).lon
    lst = mid.sidereal_time("apparent", longitude=lon).to_value(u.deg)
    hour_angle = (lst - 123.4 + 180.0) % 360.0 - 180.0
    assert abs(hour_angle) < 0.1                     # within 0.1 deg (24 s of time)
    assert mid.iso.startswith("2012-12-16") or mid.iso.startswith("2012-12-17")


def test_ncp_field(make_ms):
    ms = make_ms("ncp.ms", field="ncp", duration=240 / 3600)
    f = read_fields(ms)[0]
    assert f.name == "NCP" and np.degrees(f.dec) == pytest.approx(90.0)
    (uvw,) = _main(ms, "UVW")
    assert np.all(np.isfinite(uvw))
    # at the pole w is the baseline's projection on the Earth's axis: constant in time
    ref = pt.taql(f"select mscal.uvwj2000() as U from '{ms}'").getcol("U")
    assert np.abs(uvw - ref).max() < 0.01


def test_layout_file_enu_and_itrf(tmp_path):
    enu = tmp_path / "enu.txt"
    enu.write_text("frame = enu\ntelescope = TOY\n# name e n u\nA 0 0 0\nB 100 0 0\n"
                   "C 0 200 0 12\n")
    lay = read_layout_file(enu)
    assert lay.names == ["A", "B", "C"] and lay.telescope == "TOY"
    d = np.linalg.norm(lay.positions[1] - lay.positions[0])
    assert d == pytest.approx(100.0, abs=1e-6)
    assert lay.diameters.tolist() == [30.75, 30.75, 12.0]
    itrf = tmp_path / "itrf.txt"
    itrf.write_text("".join(f"S{i} {float(x)!r} {float(y)!r} {float(z)!r}\n" for i, (x, y, z) in
                            enumerate(lay.positions)))
    lay2 = read_layout_file(itrf)
    np.testing.assert_allclose(lay2.positions, lay.positions)


def test_layout_ms_has_no_lofar_tables(tmp_path):
    layout = tmp_path / "toy.txt"
    layout.write_text("frame = enu\nA 0 0 0\nB 150 20 0\nC -40 130 1\n")
    out = tmp_path / "toy.ms"
    result = CliRunner().invoke(cli, ["simulate", str(out), "--layout", str(layout),
                                      "--phase-centre", "60,-30", "--duration", "0.1",
                                      "--nchan", "2"])
    assert result.exit_code == 0, result.output
    assert not has_lofar_tables(out)
    assert read_telescope_name(out) == "CUSTOM"
    ref = pt.taql(f"select mscal.uvwj2000() as U from '{out}'").getcol("U")
    (uvw,) = _main(out, "UVW")
    assert np.abs(uvw - ref).max() < 0.01


@pytest.mark.parametrize("args, message", [
    (["--field", "m31"], "Invalid value for '--field'"),
    (["--duration", "0"], "--duration must be positive"),
    (["--duration", "-2"], "--duration must be positive"),
    (["--interval", "0"], "--interval must be positive"),
    (["--nchan", "0"], "--nchan must be a positive integer"),
    (["--chan-width", "-1"], "--chan-width must be positive"),
    (["--stations", "RS999*"], "no LOFAR HBA core field matches"),
    (["--phase-centre", "10"], "expected 2 comma-separated numbers"),
    (["--phase-centre", "10,95"], "declination 95.0 deg is outside"),
    (["--start", "yesterday"], "is not an ISO date/time"),
    (["--duration", "0.001"], "shorter than one --interval"),
])
def test_cli_errors_exit_2_with_one_line(tmp_path, args, message):
    result = CliRunner().invoke(cli, ["simulate", str(tmp_path / "x.ms"), *args])
    assert result.exit_code == 2, result.output
    assert message in result.output
    assert "Traceback" not in result.output
    assert not (tmp_path / "x.ms").exists()


def test_cli_refuses_to_overwrite(small_lofar_ms):
    before = sorted(p.name for p in small_lofar_ms.iterdir())
    result = CliRunner().invoke(cli, ["simulate", str(small_lofar_ms), "--duration", "0.1"])
    assert result.exit_code == 2
    assert "pass --overwrite" in result.output
    assert sorted(p.name for p in small_lofar_ms.iterdir()) == before


@pytest.mark.parametrize("content, message", [
    ("A 0 0 0\n", "at least two stations"),
    ("frame = enu\nA 0 0\nB 1 1 1\n", ":2: expected 'NAME X Y Z"),
    ("frame = enu\nA 0 0 x\nB 1 1 1\n", ":2: coordinates must be numbers"),
    ("frame = polar\nA 0 0 0\nB 1 1 1\n", "frame must be 'itrf' or 'enu'"),
    ("A 0 0 0\nB 1 1 1\n", "ITRF positions must be geocentric"),
    ("colour = red\nA 0 0 0\nB 1 1 1\n", "unknown setting 'colour'"),
])
def test_bad_layout_files(tmp_path, content, message):
    layout = tmp_path / "bad.txt"
    layout.write_text(content)
    result = CliRunner().invoke(cli, ["simulate", str(tmp_path / "x.ms"), "--layout", str(layout)])
    assert result.exit_code == 2, result.output
    assert message in result.output


def test_version_and_help_on_every_command():
    runner = CliRunner()
    result = runner.invoke(cli, ["--version"])
    assert result.exit_code == 0 and "msleak" in result.output
    for name in cli.list_commands(None):
        result = runner.invoke(cli, [name, "--help"])
        assert result.exit_code == 0, (name, result.output)
        assert "Usage:" in result.output


def test_verb_equals_cli_and_writes_history(tmp_path):
    """msleak.simulate and `msleak simulate` with the same options make identical main and
    ANTENNA tables (exact), and each adds one HISTORY row saying what was simulated."""
    import msleak
    from msleak.io.ms import read_history

    options = dict(field="ncp", duration=0.1, interval=120.0, freq_min=140e6, nchan=3,
                   chan_width=1e5, stations="CS00[1-2]HBA*")
    verb = msleak.simulate(tmp_path / "verb.ms", **options)
    assert verb == tmp_path / "verb.ms"
    cli_out = tmp_path / "cli.ms"
    result = CliRunner().invoke(cli, ["simulate", str(cli_out), "--field", "ncp",
                                      "--duration", "0.1", "--interval", "120",
                                      "--freq-min", "140e6", "--nchan", "3",
                                      "--chan-width", "1e5", "--stations", "CS00[1-2]HBA*"])
    assert result.exit_code == 0, result.output
    for a, b in zip(_main(verb, "UVW", "TIME", "ANTENNA1", "ANTENNA2"),
                    _main(cli_out, "UVW", "TIME", "ANTENNA1", "ANTENNA2")):
        np.testing.assert_array_equal(a, b)
    av, ac = read_antennas(verb), read_antennas(cli_out)
    assert av.names == ac.names == ["CS001HBA0", "CS001HBA1", "CS002HBA0", "CS002HBA1"]
    np.testing.assert_array_equal(av.positions, ac.positions)
    np.testing.assert_allclose(read_spectral_windows(verb)[0].freq, 140e6 + 1e5 * np.arange(3),
                               rtol=0, atol=1e-3)
    for ms, python_call in ((verb, True), (cli_out, False)):
        (row,) = read_history(ms)
        assert row.startswith("msleak ") and "simulated 4 LOFAR stations, field NCP, 3 x 120 s" in row
        with pt.table(str(ms / "HISTORY"), ack=False) as t:
            command = t.getcell("CLI_COMMAND", 0)[0]
        # the Python call names its options; the CLI records this process's command line
        assert command.startswith("msleak.simulate(") == python_call
        assert ("duration=0.1" in command) == python_call


@pytest.mark.parametrize("kwargs, message", [
    (dict(phase_centre=(10.0,)), "phase_centre needs RA_DEG,DEC_DEG"),
    (dict(field="m31"), "unknown field 'm31'"),
    (dict(nchan=2.5), "nchan must be a positive integer"),
])
def test_verb_errors(tmp_path, kwargs, message):
    import msleak

    with pytest.raises(msleak.InputError, match=message.replace("(", r"\(")):
        msleak.simulate(tmp_path / "x.ms", **kwargs)
    assert not (tmp_path / "x.ms").exists()


def test_bad_layout_with_overwrite_keeps_the_old_ms(small_lofar_ms, tmp_path):
    """A refused --overwrite run (bad --stations) leaves the existing MS as it was."""
    before = read_times(small_lofar_ms)
    result = CliRunner().invoke(cli, ["simulate", str(small_lofar_ms), "--overwrite",
                                      "--stations", "RS999*"])
    assert result.exit_code == 2 and "no LOFAR HBA core field matches" in result.output
    np.testing.assert_array_equal(read_times(small_lofar_ms), before)
