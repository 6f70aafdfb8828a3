"""`msleak simulate --telescope ska-low`: an MS EveryBeam reads as an SKA-Low (OSKAR)
telescope, whose beam msleak's fast path evaluates, through predict and the refusals."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from casacore.tables import table

from msleak.adapters.beams import load_beam
from msleak.beam.ska_low import SkaLowBeam
from msleak.errors import InputError
from msleak.io.ms import read_fields, read_history, read_times
from msleak.io.phased_array import read_phased_array
from msleak.verbs.simulate import simulate

STATIONS = "S00[0-3]"


@pytest.fixture(scope="module")
def ska_ms(tmp_path_factory):
    path = tmp_path_factory.mktemp("ska") / "ska.ms"
    cmd = [sys.executable, "-m", "msleak", "simulate", str(path), "--telescope", "ska-low",
           "--stations", STATIONS, "--duration", "1", "--interval", "900", "--nchan", "3"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    return path


def test_the_ms_is_an_ska_low_observation_of_eor0(ska_ms):
    with table(str(ska_ms / "OBSERVATION"), ack=False) as t:
        assert t.getcol("TELESCOPE_NAME")[0] == "SKA-LOW"
    with table(str(ska_ms / "ANTENNA"), ack=False) as t:
        assert list(t.getcol("NAME")) == ["S000", "S001", "S002", "S003"]
        np.testing.assert_array_equal(t.getcol("DISH_DIAMETER"), 38.0)
        positions = t.getcol("POSITION")
    field = read_fields(ska_ms)[0]
    assert field.name == "EoR0"
    assert np.degrees(field.ra) == pytest.approx(0.0, abs=1e-9)
    assert np.degrees(field.dec) == pytest.approx(-27.0, abs=1e-9)
    pa = read_phased_array(ska_ms)
    np.testing.assert_array_equal(pa.positions, positions)
    assert all(len(off) == 256 for off in pa.element_offsets)
    assert "SKA-Low (approximate core)" in read_history(ska_ms)[0]


def test_everybeam_reads_it_as_an_oskar_telescope(ska_ms):
    from msleak._everybeam import import_everybeam

    eb = import_everybeam()
    telescope = eb.load_telescope(str(ska_ms))
    assert type(telescope).__name__ == "OSKAR"


def test_fast_beam_equals_everybeam_direct_and_is_identity_at_the_centre(ska_ms):
    fast = load_beam("everybeam", ska_ms)
    direct = load_beam("everybeam-direct", ska_ms)
    assert isinstance(fast, SkaLowBeam)
    times = read_times(ska_ms)[[0, -1]]
    freq = np.array([150e6, 150.390625e6])
    ra0, dec0 = fast.phase_centre
    ra = ra0 + np.radians([0.0, 3.0, -5.0, 8.0])
    dec = dec0 + np.radians([0.0, 2.0, -4.0, 6.0])
    a = fast.jones(times, freq, ra, dec)
    b = direct.jones(times, freq, ra, dec)
    assert np.abs(a - b).max() <= 1e-6 * np.abs(b).max()
    corrected = fast.jones(times, freq, [ra0], [dec0], centre_correction=True)
    np.testing.assert_allclose(corrected, np.broadcast_to(np.eye(2), corrected.shape),
                               atol=1e-10)


def test_predict_runs_through_the_ska_low_beam(ska_ms, tmp_path):
    """A 1 Jy Stokes I source at the phase centre: the corrected beam is the identity
    there, so every baseline sees XX = YY = 1 Jy and XY = YX = 0."""
    sky = tmp_path / "centre.skymodel"
    sky.write_text("FORMAT = Name, Type, Ra, Dec, I, Q, U, V\n"
                   "c, POINT, 00:00:00.000, -27.00.00.000, 1.0, 0.0, 0.0, 0.0\n")
    proc = subprocess.run([sys.executable, "-m", "msleak", "predict", str(ska_ms), "--sky",
                           str(sky), "--column", "MODEL_SKA", "--no-progress"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    with table(str(ska_ms), ack=False) as t:
        vis = t.getcol("MODEL_SKA")
    np.testing.assert_allclose(vis[..., [0, 3]], 1.0, atol=1e-5)
    np.testing.assert_allclose(vis[..., [1, 2]], 0.0, atol=1e-5)


def test_the_ncp_never_rises_at_ska_low(tmp_path):
    with pytest.raises(InputError, match="never rises"):
        simulate(tmp_path / "x.ms", telescope="ska-low", field="ncp", stations=STATIONS)
    assert not (tmp_path / "x.ms").exists()


def test_unknown_telescope_and_stations_are_refused(tmp_path):
    with pytest.raises(InputError, match="unknown telescope 'vla'"):
        simulate(tmp_path / "x.ms", telescope="vla")
    with pytest.raises(InputError, match="selects 0 station.s. of the SKA-Low core"):
        simulate(tmp_path / "x.ms", telescope="ska-low", stations="CS*")
