"""The MWA tile beam through mwa_hyperbeam (``--beam hyperbeam``) and the MWA_TILE_POINTING
subtable, against hyperbeam's own calls with the sky basis built here from casacore
AZELGEO directions."""

from __future__ import annotations

import logging

import h5py
import mwa_hyperbeam
import numpy as np
import pytest

from casa_ms import build_ms
from msleak.adapters.beams import mwa_from_ms
from msleak.errors import BeamUnavailable, InputError
from msleak.io.ms import open_table, read_antennas
from msleak.io.mwa import read_mwa_delays, write_mwa_tile_pointing

C = 299792458.0
T0 = 56329.0 * 86400.0          # casa_ms default start: EoR-like field near the zenith
FREQ0, DF, NCHAN = 150e6, 195312.5, 4
#: a FEE file made here: spherical-wave modes up to n = 2 at two coarse channels
FEE_FREQS = (149760000, 151040000)


def _mc_delays(az, za):
    """M&C-order delays (row 0 the northern row, West to East) pointing at (az, za)."""
    col, row = np.arange(16) % 4, np.arange(16) // 4
    east, north = (col - 1.5) * 1.1, (1.5 - row) * 1.1
    d = (east * np.sin(za) * np.sin(az) + north * np.sin(za) * np.cos(az)) / (C * 435e-12)
    return np.round(d - d.min()).astype(int)


def _azel(ra, dec, t, position):
    """casacore AZELGEO (az, el) in rad of J2000 directions at an ITRF position."""
    from casacore.measures import measures

    dm = measures()
    dm.do_frame(dm.position("ITRF", *[f"{float(c)!r}m" for c in position]))
    dm.do_frame(dm.epoch("UTC", f"{float(t)!r}s"))
    out = []
    for a, d in zip(np.atleast_1d(ra), np.atleast_1d(dec)):
        m = dm.measure(dm.direction("J2000", f"{float(a)!r}rad", f"{float(d)!r}rad"), "AZELGEO")
        out.append((m["m0"]["value"], m["m1"]["value"]))
    return np.array(out).T


def _enu(az, el):
    return np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], -1)


def _expected(call, ra, dec, t, position):
    """msleak-convention Jones (ndir, 2, 2) from ``call(az, za) -> (4,)`` hyperbeam Jones:
    rows (NS, EW), columns (North, East) with East = pole x d, North = d x East, the J2000
    pole and the directions in the local frame from casacore; zero below the horizon."""
    az, el = _azel(ra, dec, t, position)
    d = _enu(az, el)
    pole = _enu(*_azel([0.0], [np.pi / 2], t, position))[0]
    east = np.cross(pole, d)
    east /= np.linalg.norm(east, axis=-1, keepdims=True)
    north = np.cross(d, east)
    za = np.pi / 2 - el
    e_theta = np.stack([np.cos(za) * np.sin(az), np.cos(za) * np.cos(az), -np.sin(za)], -1)
    e_phi = np.stack([np.cos(az), -np.sin(az), np.zeros_like(az)], -1)
    out = np.zeros((len(az), 2, 2), complex)
    for k in np.flatnonzero(el > 0):
        h = np.asarray(call(az[k], za[k])).reshape(2, 2)
        rot = np.array([[e_theta[k] @ north[k], e_theta[k] @ east[k]],
                        [e_phi[k] @ north[k], e_phi[k] @ east[k]]])
        out[k] = h[::-1] @ rot
    return out


@pytest.fixture(scope="module")
def mwa_ms(tmp_path_factory):
    return build_ms(tmp_path_factory.mktemp("mwa") / "mwa.ms", telescope="MWA", ntime=2,
                    nchan=NCHAN, freq0_hz=FREQ0, chan_width_hz=DF)


@pytest.fixture(scope="module")
def fee_file(tmp_path_factory):
    """A small FEE coefficients file in hyperbeam's format (random modes, n <= 2)."""
    rng = np.random.default_rng(3)
    m = [mm for n in (1, 2) for mm in range(-n, n + 1)]
    n = [nn for nn in (1, 2) for _ in range(-nn, nn + 1)]
    path = tmp_path_factory.mktemp("fee") / "fee_small.h5"
    with h5py.File(path, "w") as f:
        f["modes"] = np.array([[1] * len(m) + [2] * len(m), m + m, n + n], np.int8)
        for freq in FEE_FREQS:
            for pol in "XY":
                for k in range(1, 17):
                    f[f"{pol}{k}_{freq}"] = np.stack([rng.uniform(0.5, 1.0, 2 * len(m)),
                                                      rng.uniform(-180, 180, 2 * len(m))])
    return path


def _field_directions(ra0, dec0):
    """25 directions within 7.5 deg of the phase centre and 4 far out (to za ~ 70 deg)."""
    g = np.radians(np.linspace(-7.5, 7.5, 5))
    dra, ddec = np.meshgrid(g, g)
    ra = np.concatenate([ra0 + dra.ravel() / np.cos(dec0), ra0 + np.radians([40, -50, 0, 0])])
    dec = np.concatenate([dec0 + ddec.ravel(), dec0 + np.radians([0, 10, 40, -42])])
    return ra, dec


# -- 1. Jones against hyperbeam in an independently built basis ---------------------------
def test_analytic_equals_hyperbeam_in_the_sky_basis(mwa_ms):
    beam = mwa_from_ms(mwa_ms)
    centre = read_antennas(mwa_ms).positions[:5].mean(axis=0)
    ra, dec = _field_directions(*beam.phase_centre)
    t, f = T0 + 1800.0, FREQ0 + DF
    got = beam.jones([t], [f], ra, dec)
    assert got.shape == (5, 1, 1, ra.size, 2, 2)
    ref = mwa_hyperbeam.AnalyticBeam()
    lat = np.arcsin(centre[2] / np.linalg.norm(centre))
    want = _expected(lambda a, z: ref.calc_jones(a, z, f, [0] * 16, [1.0] * 16, lat, True),
                     ra, dec, t, centre)
    assert np.all(np.abs(want[-2:]) > 0)           # far directions are above the horizon
    peak = np.abs(want).max()
    for s in range(5):                             # one frame for every tile
        assert np.abs(got[s, 0, 0] - want).max() < 1e-6 * peak   # measured 3e-8


def test_fee_equals_hyperbeam_in_the_sky_basis(mwa_ms, fee_file):
    beam = mwa_from_ms(mwa_ms, element_model="fee", beam_file=fee_file)
    centre = read_antennas(mwa_ms).positions[:5].mean(axis=0)
    ra, dec = _field_directions(*beam.phase_centre)
    t = T0 + 600.0
    got = beam.jones([t], [FREQ0, FREQ0 + 3 * DF], ra, dec, stations=[2])
    ref = mwa_hyperbeam.FEEBeam(str(fee_file))
    for c, freq in enumerate((FEE_FREQS[0], FEE_FREQS[1])):   # nearest file frequency
        want = _expected(lambda a, z: ref.calc_jones(a, z, freq, [0] * 16, [1.0] * 16, True),
                         ra, dec, t, centre)
        assert np.abs(got[0, 0, c] - want).max() < 1e-6 * np.abs(want).max()  # 3e-8


def test_sky_basis_agrees_with_hyperbeams_parallactic_rotation(tmp_path, fee_file):
    """hyperbeam's own ``latitude_rad`` + ``iau_order`` output: rows (NS, EW), columns
    (North, East) of the pole of date; at J2000.0 that pole is the J2000 one to ~1e-4 rad
    (nutation, aberration), so both conversions agree to that, and a wrong row order,
    column order or sign would differ by order one."""
    t = 51544.5 * 86400.0
    ms = build_ms(tmp_path / "j2000.ms", time0_s=t, nchan=1, freq0_hz=FREQ0, ntime=1)
    centre = read_antennas(ms).positions[:5].mean(axis=0)
    beam = mwa_from_ms(ms, element_model="fee", beam_file=fee_file)
    ra, dec = _field_directions(*_zenith_radec(t, centre))
    got = beam.jones([t], [FREQ0], ra, dec, stations=[0])[0, 0, 0]
    az, el = _azel(ra, dec, t, centre)
    assert np.all(el > 0)
    ref = mwa_hyperbeam.FEEBeam(str(fee_file))
    own = ref.calc_jones_array(az, np.pi / 2 - el, FREQ0, [0] * 16, [1.0] * 16, True,
                               _geodetic_latitude(centre), True).reshape(-1, 2, 2)
    peak = np.abs(own).max()
    assert np.abs(got - own).max() < 1e-3 * peak                # measured 1.4e-4
    # the comparison can fail: hyperbeam's (theta, phi) columns are far from (North, East)
    raw = ref.calc_jones_array(az, np.pi / 2 - el, FREQ0, [0] * 16, [1.0] * 16, True)
    assert np.abs(raw.reshape(-1, 2, 2)[:, ::-1] - own).max() > 0.1 * peak


def _geodetic_latitude(position):
    from casacore.measures import measures

    dm = measures()
    pos = dm.measure(dm.position("ITRF", *[f"{float(c)!r}m" for c in position]), "WGS84")
    return pos["m1"]["value"]


def _zenith_radec(t, position):
    """J2000 (ra, dec) of the zenith at ``position`` (casacore)."""
    from casacore.measures import measures

    dm = measures()
    dm.do_frame(dm.position("ITRF", *[f"{float(c)!r}m" for c in position]))
    dm.do_frame(dm.epoch("UTC", f"{float(t)!r}s"))
    m = dm.measure(dm.direction("AZELGEO", "0rad", f"{np.pi / 2!r}rad"), "J2000")
    return m["m0"]["value"] % (2 * np.pi), m["m1"]["value"]


# -- 2. the dipoles at the zenith --------------------------------------------------------
def test_zenith_dipoles_see_north_and_east(mwa_ms):
    """Zenith delays, a direction at the zenith: the N-S dipole (row 0) sees only the sky
    North component and the E-W one only East, both with the same positive gain; the
    only mixing is the small angle between local North and msleak's North (towards the
    J2000 pole; precession since J2000, aberration), which casacore gives here."""
    beam = mwa_from_ms(mwa_ms)
    centre = read_antennas(mwa_ms).positions[:5].mean(axis=0)
    t = T0 + 900.0
    ra_z, dec_z = _zenith_radec(t, centre)
    j = beam.jones([t], [FREQ0], [ra_z], [dec_z], stations=[0])[0, 0, 0, 0]
    # local azimuth of North = d x normalize(pole x d) at the zenith d (ENU (0, 0, 1) by
    # construction; casacore's az/el of the exact zenith can be NaN)
    d = np.array([0.0, 0.0, 1.0])
    pole = _enu(*_azel([0.0], [np.pi / 2], t, centre))[0]
    north = np.cross(d, np.cross(pole, d))
    psi = np.arctan2(north[0], north[1])
    assert abs(np.sin(psi)) < 5e-3
    g = j[0, 0] / np.cos(psi)
    assert abs(g.imag) < 1e-9 * abs(g) and g.real > 0.99     # norm_to_zenith: ~1
    rotation = np.array([[np.cos(psi), -np.sin(psi)], [np.sin(psi), np.cos(psi)]])
    assert np.abs(j / g - rotation).max() < 1e-6


# -- 3. the phase-centre correction ------------------------------------------------------
def test_centre_correction_is_the_identity_at_the_phase_centre(mwa_ms):
    beam = mwa_from_ms(mwa_ms)
    ra0, dec0 = beam.phase_centre
    j = beam.jones([T0, T0 + 3600.0], [FREQ0, FREQ0 + DF], [ra0, ra0 + 0.1], [dec0, dec0],
                   centre_correction=True)
    centre = j[..., 0, :, :]
    np.testing.assert_allclose(centre, np.broadcast_to(np.eye(2), centre.shape), atol=1e-10)
    raw = beam.jones([T0, T0 + 3600.0], [FREQ0, FREQ0 + DF], [ra0, ra0 + 0.1], [dec0, dec0])
    expected = np.linalg.inv(raw[..., 0, :, :]) @ raw[..., 1, :, :]
    np.testing.assert_allclose(j[..., 1, :, :], expected, atol=1e-12)


# -- 4. refusals ---------------------------------------------------------------------------
def test_fee_without_a_file_is_refused_in_one_line(mwa_ms, monkeypatch):
    monkeypatch.delenv("MWA_BEAM_FILE", raising=False)
    with pytest.raises(InputError) as err:
        mwa_from_ms(mwa_ms, element_model="fee")
    text = str(err.value)
    assert "\n" not in text
    for word in ("`beam_file=PATH`", "MWA_BEAM_FILE", "download",
                 "mwa_full_embedded_element_pattern.h5"):
        assert word in text


def test_fee_file_from_the_environment(mwa_ms, fee_file, monkeypatch):
    monkeypatch.setenv("MWA_BEAM_FILE", str(fee_file))
    beam = mwa_from_ms(mwa_ms, element_model="fee")
    assert beam.band == (FEE_FREQS[0], FEE_FREQS[1])
    monkeypatch.setenv("MWA_BEAM_FILE", str(mwa_ms / "table.dat"))
    with pytest.raises(InputError, match="not a readable MWA FEE beam file"):
        mwa_from_ms(mwa_ms, element_model="fee")


def test_unknown_element_model_and_stray_file_are_refused(mwa_ms, fee_file):
    with pytest.raises(InputError, match="unknown MWA element model 'hamaker'; use one of "
                                         "analytic, fee"):
        mwa_from_ms(mwa_ms, element_model="hamaker")
    with pytest.raises(InputError, match="reads no file"):
        mwa_from_ms(mwa_ms, beam_file=fee_file)


def test_channels_outside_the_band_are_refused(tmp_path, mwa_ms, fee_file):
    low = build_ms(tmp_path / "low.ms", freq0_hz=60e6, nchan=2)
    with pytest.raises(InputError, match=r"covers 70-300 MHz .*60 MHz requested"):
        mwa_from_ms(low)
    beam = mwa_from_ms(mwa_ms)
    with pytest.raises(InputError, match="320 MHz requested"):
        beam.jones([T0], [150e6, 320e6], [0.0], [0.0])
    high = build_ms(tmp_path / "high.ms", freq0_hz=152e6, nchan=2)
    with pytest.raises(InputError, match=r"covers 149.76-151.04 MHz \(the file's band\)"):
        mwa_from_ms(high, element_model="fee", beam_file=fee_file)


def test_missing_hyperbeam_names_the_extra(mwa_ms, monkeypatch):
    import msleak.beam.mwa as mwa

    monkeypatch.setattr(mwa, "mwa_hyperbeam", None)
    with pytest.raises(BeamUnavailable, match=r"pip install 'msleak\[mwa\]'"):
        mwa_from_ms(mwa_ms)


def test_cli_refusals_are_one_line(mwa_ms, tmp_path, monkeypatch):
    from click.testing import CliRunner

    from msleak.cli import cli

    monkeypatch.delenv("MWA_BEAM_FILE", raising=False)
    runner = CliRunner()
    cases = [(["--element-model", "fee"], "--beam-file"),
             (["--element-model", "hamaker"], "use one of analytic, fee")]
    for extra, words in cases:
        result = runner.invoke(cli, ["beam", str(mwa_ms), "-o", str(tmp_path / "b.png"),
                                      "--beam", "hyperbeam", *extra])
        assert result.exit_code == 2, result.output
        lines = [s for s in result.output.splitlines() if s.strip()]
        assert len(lines) == 1 and lines[0].startswith("msleak: error: ") and words in lines[0]


# -- 5. MWA_TILE_POINTING ------------------------------------------------------------------
def test_tile_pointing_round_trip(tmp_path, caplog):
    ms = build_ms(tmp_path / "p.ms", nchan=1)
    with caplog.at_level(logging.INFO, logger="msleak.io.mwa"):
        assert np.array_equal(read_mwa_delays(ms), np.zeros(16))
    assert "no MWA_TILE_POINTING table" in caplog.text
    delays = _mc_delays(0.3, np.radians(25))
    delays[5] = 32                                        # a dead dipole
    write_mwa_tile_pointing(ms, (T0 - 60, T0 + 300), delays, direction=(1.0, -0.5))
    assert np.array_equal(read_mwa_delays(ms), delays)
    with open_table(ms) as t:
        assert t.getkeyword("MWA_TILE_POINTING").endswith("/MWA_TILE_POINTING")
    with open_table(ms / "MWA_TILE_POINTING") as t:
        assert t.nrows() == 1
        np.testing.assert_array_equal(t.getcell("INTERVAL", 0), [T0 - 60, T0 + 300])
        np.testing.assert_array_equal(t.getcell("DIRECTION", 0), [1.0, -0.5])
        assert t.getcolkeyword("INTERVAL", "MEASINFO")["Ref"] == "UTC"
    for bad in ([0] * 15, [0] * 15 + [33], [0.5] * 16):
        with pytest.raises(InputError, match="16 integers from 0 to 32"):
            write_mwa_tile_pointing(ms, (T0, T0), bad)
    with open_table(ms / "MWA_TILE_POINTING", readonly=False) as t:
        t.putcell("DELAYS", 0, np.full(16, 40, np.int32))
    with pytest.raises(InputError, match="MWA_TILE_POINTING: MWA dipole delays must be"):
        read_mwa_delays(ms)


def test_tile_pointing_as_cotter_writes_it(tmp_path):
    ms = build_ms(tmp_path / "c.ms", nchan=1, mwa_tile_pointing=True)
    assert np.array_equal(read_mwa_delays(ms), np.zeros(16))


def test_delays_steer_the_beam_to_their_direction(tmp_path):
    """M&C delays for az 0 (North), za 20 deg: hyperbeam's analytic beam with the rows
    reordered (docs/mwa.md), and the tile's peak within 1 deg of that direction."""
    ms = build_ms(tmp_path / "n.ms", nchan=1, ntime=1)
    delays = _mc_delays(0.0, np.radians(20))
    write_mwa_tile_pointing(ms, (T0, T0), delays)
    beam = mwa_from_ms(ms)
    centre = read_antennas(ms).positions[:5].mean(axis=0)
    # a grid of directions around the zenith, 1 deg steps to za 40 deg
    za_g, az_g = np.meshgrid(np.radians(np.arange(0.5, 40, 1.0)),
                             np.radians(np.arange(0, 360, 2.0)))
    ra, dec = _radec_of_azel(az_g.ravel(), np.pi / 2 - za_g.ravel(), T0, centre)
    j = beam.jones([T0], [FREQ0], ra, dec, stations=[0])[0, 0, 0]
    ref = mwa_hyperbeam.AnalyticBeam()
    lat = _geodetic_latitude(centre)
    flipped = delays.reshape(4, 4)[::-1].ravel().tolist()
    want = _expected(lambda a, z: ref.calc_jones(a, z, FREQ0, flipped, [1.0] * 16, lat, True),
                     ra, dec, T0, centre)
    assert np.abs(j - want).max() < 1e-6 * np.abs(want).max()
    power = np.sum(np.abs(j) ** 2, axis=(-2, -1))
    az, el = _azel([ra[np.argmax(power)]], [dec[np.argmax(power)]], T0, centre)
    peak = _enu(az, el)[0]
    assert np.degrees(np.arccos(peak @ _enu(np.array(0.0), np.radians(70.0)))) < 1.0
    zenith = mwa_from_ms(build_ms(tmp_path / "z.ms", nchan=1, ntime=1))
    assert np.abs(zenith.jones([T0], [FREQ0], ra, dec, stations=[0])[0, 0, 0] - j).max() > 0.1


def _radec_of_azel(az, el, t, position):
    from casacore.measures import measures

    dm = measures()
    dm.do_frame(dm.position("ITRF", *[f"{float(c)!r}m" for c in position]))
    dm.do_frame(dm.epoch("UTC", f"{float(t)!r}s"))
    out = [dm.measure(dm.direction("AZELGEO", f"{float(a)!r}rad", f"{float(e)!r}rad"), "J2000")
           for a, e in zip(az, el)]
    return (np.array([m["m0"]["value"] for m in out]) % (2 * np.pi),
            np.array([m["m1"]["value"] for m in out]))


# -- 6. the horizon ------------------------------------------------------------------------
def test_zero_not_nan_below_the_horizon(mwa_ms):
    beam = mwa_from_ms(mwa_ms)
    ra0, dec0 = beam.phase_centre
    ra = np.array([ra0, ra0 + np.pi, ra0 + np.pi / 2 + 0.3, 0.0])
    dec = np.array([dec0, -dec0, 0.0, np.pi / 2])        # the NCP is below the MWA horizon
    for correction in (False, True):
        j = beam.jones([T0], [FREQ0], ra, dec, centre_correction=correction)
        assert np.all(np.isfinite(j))
        assert np.all(j[..., 1:, :, :] == 0)
        if correction:   # the identity at the phase centre (its off-diagonal may be 0)
            np.testing.assert_allclose(j[..., 0, :, :], np.broadcast_to(
                np.eye(2), j[..., 0, :, :].shape), atol=1e-10)
        else:
            assert np.all(np.abs(j[..., 0, :, :]) > 0)


# -- one frame for all tiles -----------------------------------------------------------
def test_array_centre_frame_against_each_tiles_own_frame(tmp_path):
    """Tiles 1.5 km either side of the centre (the extent of the MWA Phase I): the beam
    of the centre frame against hyperbeam in each tile's own frame over a 15 deg field."""
    enu = np.array([[-1500.0, 0.0, 0.0], [1500.0, 0.0, 0.0], [0.0, 1500.0, 0.0]])
    ms = build_ms(tmp_path / "wide.ms", nchan=1, ntime=1, enu=enu)
    beam = mwa_from_ms(ms)
    ra, dec = _field_directions(*beam.phase_centre)
    ra, dec = ra[:25], dec[:25]
    j = beam.jones([T0], [FREQ0], ra, dec)[:, 0, 0]
    ref = mwa_hyperbeam.AnalyticBeam()
    worst = 0.0
    for s, position in enumerate(read_antennas(ms).positions):
        want = _expected(lambda a, z: ref.calc_jones(a, z, FREQ0, [0] * 16, [1.0] * 16, -0.47,
                                                     True), ra, dec, T0, position)
        worst = max(worst, np.abs(j[s] - want).max() / np.abs(want).max())
    assert 1e-5 < worst < 1e-3          # measured 5.7e-4 (docs/mwa.md)
