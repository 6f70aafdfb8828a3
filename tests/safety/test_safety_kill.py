"""Interruptions: ``msleak predict`` and ``msleak simulate`` killed with SIGKILL at
several moments, and two msleak processes writing one MS at the same time.

After every kill the MS must open in casacore with DATA unchanged; the target column is
either absent, marked incomplete (MSLEAK_PREDICT keyword, rows up to the recorded
progress already final) or complete; rerunning the same command must finish the job with
the result of an uninterrupted run. The kill moments are fractions of the measured
length of an uninterrupted run plus one random moment, and kills after a given number of
rows reported by the progress bar (so that some kills surely land mid-run).
"""

from __future__ import annotations

import hashlib
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

#: 40 time slots of 10 s, 6 HBA fields, 4 channels: ~4 s of predict, one slot per chunk
KILL_MS = dict(duration=40 * 10 / 3600, interval=10.0)
PREDICT_ARGS = ["--beam", "dipole", "--memory-limit", "4KB"]


def _table(path, readonly=True):
    import casacore.tables as pt

    return pt.table(str(path), readonly=readonly, ack=False)


def _digest(ms, column="DATA"):
    with _table(ms) as t:
        return hashlib.sha256(np.ascontiguousarray(t.getcol(column)).tobytes()).hexdigest()


def _env():
    env = dict(os.environ)
    env.setdefault("NUMBA_CACHE_DIR", str(Path(sys.prefix) / "numba-cache"))
    env["PYTHONUNBUFFERED"] = "1"
    return env


def _predict_cmd(ms, sky, *extra):
    return [sys.executable, "-m", "msleak", "predict", str(ms), "--sky", str(sky),
            *PREDICT_ARGS, *extra]


def _write_sky(path, ra0, dec0, shift=0.0):
    lines = ["format = Name, Type, Ra, Dec, I, Q, U, V"]
    for k, (dl, dm) in enumerate([(0.0, 0.0), (0.03, 0.01), (-0.02, 0.03)]):
        ra = ra0 + (dl + shift) / np.cos(dec0)
        lines.append(f"s{k}, POINT, {float(ra)!r}, {float(dec0 + dm)!r}, 1.0, 0.4, -0.3, 0.0")
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def kill_env(tmp_path_factory):
    from msleak.verbs import predict as engine
    from msleak.verbs.simulate import simulate

    root = tmp_path_factory.mktemp("kill")
    master = simulate(root / "master.ms", field="3c196", freq_min=150e6, nchan=4,
                      chan_width=195312.5, stations="CS00[1-3]HBA*", **KILL_MS)
    rng = np.random.default_rng(11)
    with _table(master, readonly=False) as t:
        shape = t.getcol("DATA").shape
        t.putcol("DATA", (rng.normal(size=shape) + 1j * rng.normal(size=shape)).astype(np.complex64))
    with _table(f"{master}/FIELD") as t:
        ra0, dec0 = (float(x) for x in t.getcell("PHASE_DIR", 0).reshape(-1)[:2])
    sky = _write_sky(root / "new.skymodel", ra0, dec0)
    old_sky = _write_sky(root / "old.skymodel", ra0, dec0, shift=0.01)
    # a copy with an existing MODEL_DATA of another sky (replaced by the kill runs)
    with_old = root / "with_old.ms"
    shutil.copytree(master, with_old)
    engine.predict(with_old, old_sky, beam="none")
    ref = root / "ref.ms"
    shutil.copytree(master, ref)
    start = time.monotonic()
    proc = subprocess.run(_predict_cmd(ref, sky), env=_env(), capture_output=True, text=True,
                          timeout=300)
    seconds = time.monotonic() - start
    assert proc.returncode == 0, proc.stderr
    with _table(ref) as t:
        reference = t.getcol("MODEL_DATA")
    return dict(root=root, master=master, with_old=with_old, sky=sky, seconds=seconds,
                reference=reference, data_digest=_digest(master))


def _kill_after_seconds(cmd, delay):
    proc = subprocess.Popen(cmd, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        proc.wait(timeout=delay)
        return "finished"
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        return "killed"


def _kill_after_rows(cmd, rows):
    """Kill once the progress bar reports at least ``rows`` rows written."""
    proc = subprocess.Popen(cmd + ["--progress"], env=_env(), stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    buf = b""
    try:
        while True:
            ch = proc.stderr.read(1)
            if not ch:
                proc.wait()
                return "finished"
            buf = (buf + ch)[-200:]
            found = re.findall(rb"(\d+)/(\d+) \[", buf)
            if found and int(found[-1][0]) >= rows:
                proc.send_signal(signal.SIGKILL)
                proc.wait()
                return "killed"
    finally:
        proc.stderr.close()


def _assert_same(actual, expected):
    """Equal to complex64 precision (runs may chunk differently: 1-ulp differences)."""
    scale = float(np.abs(expected).max()) if expected.size else 1.0
    np.testing.assert_allclose(actual, expected, rtol=0, atol=1e-6 * scale)


def _check_after_kill(ms, env) -> str:
    """Invariants of an interrupted MS; returns the state seen.

    casacore rewrites a storage manager's header file in place at every flush, so a kill
    during a flush can truncate it and the main table then does not open; msleak keeps a
    copy while it writes and the next predict puts it back (``repair_interrupted``).
    """
    from msleak.io import columns as colio

    prefix = ""
    try:
        _table(ms).close()
    except RuntimeError:
        assert (Path(ms) / colio.BACKUP_DIR).is_dir(), "no header backup to repair from"
        assert colio.repair_interrupted(ms)
        prefix = "repaired, "
    return prefix + _check_state(ms, env)


def _check_state(ms, env) -> str:
    with _table(ms) as t:                      # casacore opens it
        assert t.nrows() == env["reference"].shape[0]
        names = t.colnames()
        state = (t.getcolkeyword("MODEL_DATA", "MSLEAK_PREDICT")
                 if "MODEL_DATA" in names and "MSLEAK_PREDICT" in t.colkeywordnames("MODEL_DATA")
                 else None)
        model = t.getcol("MODEL_DATA") if "MODEL_DATA" in names else None
        times = t.getcol("TIME")
    assert _digest(ms) == env["data_digest"], "DATA changed"
    if state is None:
        return "no column"
    if Path(str(state.get("sky", ""))).name != env["sky"].name:
        return "old run"
    if state["complete"]:
        _assert_same(model, env["reference"])
        return "complete"
    done = times <= state["progress"].get("f0_d0", -np.inf)
    # what the run state reports as done is final
    _assert_same(model[done], env["reference"][done])
    assert state["rows_done"] == int(done.sum())
    return "incomplete"


def test_predict_sigkill_then_rerun(kill_env, tmp_path):
    env = kill_env
    seed = int(os.environ.get("MSLEAK_KILL_SEED", random.SystemRandom().randrange(10**6)))
    rnd = random.Random(seed)
    total = env["reference"].shape[0]
    T = env["seconds"]
    points = [("time", 0.5 * T), ("time", rnd.uniform(0.3, 0.95) * T),
              ("rows", total // 4), ("rows", (2 * total) // 3)]
    outcomes = []
    for k, (kind, when) in enumerate(points):
        source = env["master"] if k % 2 == 0 else env["with_old"]
        ms = tmp_path / f"k{k}.ms"
        shutil.copytree(source, ms)
        cmd = _predict_cmd(ms, env["sky"])
        how = (_kill_after_seconds(cmd, when) if kind == "time"
               else _kill_after_rows(cmd, when))
        seen = _check_after_kill(ms, env)
        # the same command again finishes the job
        proc = subprocess.run(cmd, env=_env(), capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
        assert ("resumed run" in proc.stderr) == seen.endswith("incomplete"), proc.stderr
        assert _check_after_kill(ms, env) == "complete"
        outcomes.append((kind, round(when, 2), how, seen))
    print(f"kill seed {seed}, uninterrupted run {T:.1f} s:", outcomes)
    assert sum(1 for *_, seen in outcomes if seen.endswith("incomplete")) >= 2, (seed, outcomes)


def test_truncated_header_is_repaired_by_rerun(small_lofar_ms, tmp_path, monkeypatch):
    """The state a kill during a flush can leave: the column's header file truncated, the
    MS unreadable. grid refuses the half-written column; the predict rerun restores the
    header, resumes and gives the uninterrupted result; the backup is then removed."""
    from click.testing import CliRunner
    from faults import fail_after_chunks

    from msleak.cli import cli
    from msleak.io import columns as colio
    from msleak.verbs import predict as engine

    ms = small_lofar_ms
    with _table(f"{ms}/FIELD") as t:
        ra0, dec0 = (float(x) for x in t.getcell("PHASE_DIR", 0).reshape(-1)[:2])
    sky = _write_sky(tmp_path / "sky.skymodel", ra0, dec0)
    ref = tmp_path / "ref.ms"
    shutil.copytree(ms, ref)
    engine.predict(ref, sky, **_api_args())
    data = _digest(ms)
    with monkeypatch.context() as m, pytest.raises(RuntimeError, match="simulated failure"):
        fail_after_chunks(m, 1)
        engine.predict(ms, sky, **_api_args())
    r = CliRunner().invoke(cli, ["grid", str(ms), "--column", "MODEL_DATA", "-o",
                                 str(tmp_path / "g.h5")])
    assert r.exit_code == 2 and "incomplete" in r.output and "rerun" in r.output, r.output
    assert (ms / colio.BACKUP_DIR).is_dir()
    with _table(ms) as t:
        seq = t.getdminfo("MODEL_DATA")["SEQNR"]
    header = ms / f"table.f{seq}"
    header.write_bytes(header.read_bytes()[:40])          # what a kill mid-flush leaves
    with pytest.raises(RuntimeError):
        _table(ms).close()
    res = engine.predict(ms, sky, **_api_args())
    assert res[0].resumed if isinstance(res, list) else res.resumed
    with _table(ms) as t, _table(ref) as r_:
        _assert_same(t.getcol("MODEL_DATA"), r_.getcol("MODEL_DATA"))
        assert t.getcolkeyword("MODEL_DATA", "MSLEAK_PREDICT")["complete"]
    assert _digest(ms) == data
    assert not (ms / colio.BACKUP_DIR).exists()


def test_two_writers_wait_for_each_other(kill_env, tmp_path):
    """A second predict into the same MS waits for the first (the write lock is held for
    the whole run) instead of interleaving chunks; both finish and the MS holds the
    result of the one that finished last."""
    env = kill_env
    ms = tmp_path / "shared.ms"
    shutil.copytree(env["with_old"], ms)
    first = subprocess.Popen(_predict_cmd(ms, env["sky"]) + ["--progress"], env=_env(),
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    # start the second one once the first is writing
    buf = b""
    while not re.search(rb"\d+/\d+ \[", buf):
        ch = first.stderr.read(1)
        assert ch, "first predict ended early"
        buf += ch
    with open(tmp_path / "old.skymodel", "w") as fh:
        fh.write((env["root"] / "old.skymodel").read_text())
    second = subprocess.run(_predict_cmd(ms, tmp_path / "old.skymodel"), env=_env(),
                            capture_output=True, text=True, timeout=300)
    rest = first.stderr.read()
    first.stderr.close()
    assert first.wait(timeout=300) == 0, rest.decode(errors="replace")[-500:]
    assert second.returncode == 0, second.stderr
    # the first one finished before the second wrote anything: the final column is the
    # second's sky, complete, and equal to an uninterrupted prediction of that sky
    from msleak.verbs import predict as engine

    ref = tmp_path / "ref_old.ms"
    shutil.copytree(env["master"], ref)
    engine.predict(ref, tmp_path / "old.skymodel", **_api_args())
    with _table(ms) as t, _table(ref) as r:
        state = t.getcolkeyword("MODEL_DATA", "MSLEAK_PREDICT")
        assert state["complete"] and state["sky"].endswith("old.skymodel")
        np.testing.assert_allclose(t.getcol("MODEL_DATA"), r.getcol("MODEL_DATA"),
                                   rtol=1e-6, atol=1e-6)
    assert _digest(ms) == env["data_digest"]


def _wait_for(proc, marker: bytes) -> bytes:
    buf = b""
    while marker not in buf:
        ch = proc.stderr.read(1)
        assert ch, f"process ended before printing {marker!r}: {buf[-300:]!r}"
        buf += ch
    return buf


def _api_args():
    return dict(beam="dipole", memory_limit=4096, scheduler="sync")


def test_simulate_sigkill_and_interrupt(tmp_path):
    """A killed or interrupted simulate leaves OUT behind; rerunning without --overwrite
    says so in one line, with --overwrite it gives the same MS as a clean run."""
    out = tmp_path / "sim.ms"
    # -v: the "creating ..." progress message tells when the tables are being made; 12 h of
    # 10 s slots (393 k rows, about 1 s to write even on a fast machine) so that the
    # interrupt always lands while the MS is being written
    args = [sys.executable, "-m", "msleak", "-v", "simulate", str(out), "--stations",
            "CS00[1-7]HBA*", "--duration", "12", "--interval", "10", "--nchan", "8"]
    # a shell starts background jobs with SIGINT ignored, and Python then installs no
    # KeyboardInterrupt handler: give the child the default disposition, as a terminal does
    proc = subprocess.Popen(args, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    buf = _wait_for(proc, b"creating")       # the tables are being made from here on
    time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    err = (buf + proc.stderr.read()).decode(errors="replace")
    proc.stderr.close()
    rc = proc.wait()
    assert rc == 130, f"simulate was not interrupted (exit {rc}): {err[-300:]}"
    assert "rerun with --overwrite" in err and "Traceback" not in err

    again = subprocess.run(args, env=_env(), capture_output=True, text=True, timeout=300)
    assert again.returncode == 2
    assert again.stderr.strip().splitlines()[-1].startswith("msleak: error:")
    assert "--overwrite" in again.stderr.strip().splitlines()[-1]

    killed = subprocess.Popen(args + ["--overwrite"], env=_env(), stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE)
    _wait_for(killed, b"creating")
    time.sleep(0.5)
    killed.send_signal(signal.SIGKILL)
    killed.wait()
    killed.stderr.close()
    assert out.exists()
    done = subprocess.run(args + ["--overwrite"], env=_env(), capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    clean = tmp_path / "clean.ms"
    subprocess.run(args[:5] + [str(clean)] + args[6:], env=_env(), check=True,
                   capture_output=True, timeout=300)
    with _table(out) as a, _table(clean) as b:
        for column in ("UVW", "TIME", "ANTENNA1", "ANTENNA2", "DATA", "FLAG"):
            np.testing.assert_array_equal(a.getcol(column), b.getcol(column))
