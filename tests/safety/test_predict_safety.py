"""A refused predict leaves every Measurement Set exactly as it was; an interrupted one stays
resumable.

Refusals that can be found before writing (non-finite TIME/UVW in any chunk, an unusable
existing column in a later MS) are found before anything is created. A refusal that only
shows while running is forced here at the LAST time chunk (the chunk computation is
monkeypatched to raise an InputError there, after every earlier chunk was written); the
MS must then have the same column list, table and column keywords, and the same bytes in
every file (casacore's lock file aside) as before the command.
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from casa_ms import build_ms
from ms_helpers import phase_centre, snapshot, table, write_sky
from msleak.cli import cli
from msleak.errors import InputError
from msleak.io import columns as colio
from faults import fail_after_chunks, fail_at_time
from msleak.verbs import predict as engine

NTIME = 5
#: 4 KB: one time slot per chunk, so NTIME chunks
API = dict(beam="none", memory_limit=4096, scheduler="sync")


def _sky(tmp_path, ms, name="sky.skymodel", shift=0.0):
    ra0, dec0 = phase_centre(ms)
    return write_sky(tmp_path / name, [(ra0 + 0.02 + shift, dec0 + 0.01, 1.0, 0.3, -0.2, 0.0),
                                       (ra0 - 0.01, dec0 - 0.03 + shift, 2.0, 0.1, 0.4, 0.0)])


def _last_time(ms):
    with table(ms) as t:
        return float(t.getcol("TIME").max())


@pytest.fixture
def ms(tmp_path):
    return build_ms(tmp_path / "obs.ms", ntime=NTIME)


def test_refusal_at_last_chunk_new_column(ms, tmp_path, monkeypatch):
    sky = _sky(tmp_path, ms)
    before = snapshot(ms)
    assert "MODEL_DATA" not in before[0]
    seen = fail_at_time(monkeypatch, _last_time(ms), InputError("refused in the test"), [ms])
    with pytest.raises(InputError, match="refused in the test"):
        engine.predict(ms, sky, **API)
    # NTIME chunks were computed, the first ones written (the run's header backup existed)
    assert len(seen) == NTIME and seen[-1] == [True]
    assert snapshot(ms) == before


def test_refusal_at_last_chunk_existing_column(ms, tmp_path, monkeypatch):
    engine.predict(ms, _sky(tmp_path, ms, "old.skymodel", shift=0.01), **API)
    with table(ms) as t:
        old = t.getcol("MODEL_DATA")
    assert np.abs(old).max() > 0.5
    before = snapshot(ms)
    seen = fail_at_time(monkeypatch, _last_time(ms), InputError("refused in the test"), [ms])
    with pytest.raises(InputError, match="refused in the test"):
        engine.predict(ms, _sky(tmp_path, ms), **API)
    assert len(seen) == NTIME and seen[-1] == [True]
    assert snapshot(ms) == before
    with table(ms) as t:
        np.testing.assert_array_equal(t.getcol("MODEL_DATA"), old)


def test_refused_rerun_keeps_an_interrupted_run_resumable(ms, tmp_path, monkeypatch):
    """Interrupted (state incomplete, backup kept), then a refused rerun: still the
    interrupted state, and a normal rerun resumes it to the uninterrupted result."""
    sky = _sky(tmp_path, ms)
    ref = tmp_path / "ref.ms"
    shutil.copytree(ms, ref)
    engine.predict(ref, sky, **API)
    with monkeypatch.context() as m, pytest.raises(RuntimeError, match="simulated failure"):
        fail_after_chunks(m, 2)
        engine.predict(ms, sky, **API)
    before = snapshot(ms)
    assert (ms / colio.BACKUP_DIR).is_dir()
    with monkeypatch.context() as m:
        fail_at_time(m, _last_time(ms), InputError("refused in the test"))
        with pytest.raises(InputError, match="refused in the test"):
            engine.predict(ms, sky, **API)
    assert snapshot(ms) == before
    res = engine.predict(ms, sky, **API)
    assert res.resumed
    with table(ms) as t, table(ref) as r:
        np.testing.assert_array_equal(t.getcol("MODEL_DATA"), r.getcol("MODEL_DATA"))
    assert not (ms / colio.BACKUP_DIR).exists()


@pytest.mark.parametrize("interrupt", ["ctrl-c", "worker-lost"])
def test_interruption_at_last_chunk_stays_resumable(ms, tmp_path, monkeypatch, interrupt):
    from msleak.parallel.runner import WorkerLost

    sky = _sky(tmp_path, ms)
    error = KeyboardInterrupt() if interrupt == "ctrl-c" else WorkerLost("worker lost (test)")
    with monkeypatch.context() as m:
        fail_at_time(m, _last_time(ms), error)
        with pytest.raises(type(error)):
            engine.predict(ms, sky, **API)
    with table(ms) as t:
        state = t.getcolkeyword("MODEL_DATA", "MSLEAK_PREDICT")
        nrow = t.nrows()
    assert not state["complete"]
    assert state["rows_done"] == nrow * (NTIME - 1) // NTIME
    assert (ms / colio.BACKUP_DIR).is_dir()
    res = engine.predict(ms, sky, **API)
    assert res.resumed and res.rows_written == nrow // NTIME


def test_refusal_in_second_ms_undoes_the_first(tmp_path, monkeypatch):
    """Two MSs: the first MS is complete when the second is refused at its last
    chunk; both are put back."""
    one = build_ms(tmp_path / "one.ms", ntime=NTIME)
    two = build_ms(tmp_path / "two.ms", ntime=NTIME, time0_s=56329.0 * 86400.0 + 3600.0)
    engine.predict(one, _sky(tmp_path, one, "old.skymodel", shift=0.01), **API)
    before = [snapshot(one), snapshot(two)]
    seen = fail_at_time(monkeypatch, _last_time(two), InputError("refused in the test"),
                    [one, two])
    with pytest.raises(InputError, match="refused in the test"):
        engine.predict([one, two], _sky(tmp_path, one), **API)
    assert len(seen) == 2 * NTIME and seen[-1] == [False, True]
    assert [snapshot(one), snapshot(two)] == before


def test_nonfinite_uvw_in_last_chunk_refused_before_writing(ms, tmp_path):
    sky = _sky(tmp_path, ms)
    with table(ms, readonly=False) as t:
        last = int(np.flatnonzero(t.getcol("TIME") == t.getcol("TIME").max())[2])
        t.putcell("UVW", last, np.array([np.nan, 1.0, 2.0]))
    before = snapshot(ms)
    r = CliRunner().invoke(cli, ["predict", str(ms), "--sky", str(sky), "--beam", "none",
                                 "--memory-limit", "4KB"])
    assert r.exit_code == 2, r.output
    line = r.output.strip().splitlines()[-1]
    assert line.startswith("msleak: error:") and f"first: row {last}" in line, line
    assert "--field / --spw" in line
    assert snapshot(ms) == before


def test_unusable_column_in_second_ms_refused_before_writing(tmp_path):
    import casacore.tables as pt

    one = build_ms(tmp_path / "one.ms", ntime=2)
    two = build_ms(tmp_path / "two.ms", ntime=2)
    with table(two, readonly=False) as t:  # a MODEL_DATA of another cell shape than DATA
        t.addcols(pt.makearrcoldesc("MODEL_DATA", 0j, ndim=2, shape=[2, 4], options=4))
    before = [snapshot(one), snapshot(two)]
    with pytest.raises(InputError, match="exists with another shape"):
        engine.predict([one, two], _sky(tmp_path, one), **API)
    assert [snapshot(one), snapshot(two)] == before
