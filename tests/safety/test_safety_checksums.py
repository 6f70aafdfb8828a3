"""Data safety: predict, grid, transform and ps never modify DATA, FLAG or any other
column they do not own; grid/transform/ps do not even touch the MS files; a failed or
refused predict leaves the MS as it was; a full disk gives a one-line error."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from msleak.cli import cli

#: columns predict/grid/ps must never change
PROTECTED = ("DATA", "FLAG", "FLAG_ROW", "WEIGHT_SPECTRUM", "WEIGHT", "SIGMA", "UVW", "TIME",
             "ANTENNA1", "ANTENNA2", "FIELD_ID", "DATA_DESC_ID")


def _table(path, readonly=True):
    import casacore.tables as pt

    return pt.table(str(path), readonly=readonly, ack=False)


def _column_digests(ms, columns=PROTECTED) -> dict:
    with _table(ms) as t:
        return {c: hashlib.sha256(np.ascontiguousarray(t.getcol(c)).tobytes()).hexdigest()
                for c in columns if c in t.colnames()}


def _file_digests(ms) -> dict:
    """sha256 of every file of the MS except casacore's lock files."""
    out = {}
    for path in sorted(Path(ms).rglob("*")):
        if path.is_file() and path.name != "table.lock":
            out[str(path.relative_to(ms))] = hashlib.sha256(path.read_bytes()).hexdigest()
    return out


def _randomise(ms, seed=3):
    """Non-trivial DATA, FLAG (about 10 %) and weights, so that any change would show."""
    rng = np.random.default_rng(seed)
    with _table(ms, readonly=False) as t:
        shape = t.getcol("DATA").shape
        t.putcol("DATA", (rng.normal(size=shape) + 1j * rng.normal(size=shape)).astype(np.complex64))
        t.putcol("FLAG", rng.random(shape) < 0.1)
        t.putcol("WEIGHT_SPECTRUM", rng.uniform(0.5, 2.0, shape).astype(np.float32))


def _write_sky(path, ra0, dec0):
    """A few makesourcedb point sources (I, Q, U) within 2 deg of the phase centre."""
    lines = ["format = Name, Type, Ra, Dec, I, Q, U, V"]
    offsets = [(0.0, 0.0), (0.02, 0.01), (-0.015, 0.025), (0.03, -0.02)]
    for k, (dl, dm) in enumerate(offsets):
        ra = ra0 + dl / np.cos(dec0)
        dec = dec0 + dm
        lines.append(f"s{k}, POINT, {float(ra)!r}, {float(dec)!r}, 1.0, {0.3 + 0.1 * k!r}, "
                     f"{-0.2 * k!r}, 0.0")
    path.write_text("\n".join(lines) + "\n")
    return path


def _phase_centre(ms):
    with _table(f"{ms}/FIELD") as t:
        ra, dec = t.getcell("PHASE_DIR", 0).reshape(-1)[:2]
    return float(ra), float(dec)


def _run(args):
    result = CliRunner().invoke(cli, args)
    return result


def test_chain_never_changes_data_or_flags(small_lofar_ms, tmp_path):
    ms = small_lofar_ms
    _randomise(ms)
    sky = _write_sky(tmp_path / "sky.skymodel", *_phase_centre(ms))
    before = _column_digests(ms)

    r = _run(["predict", str(ms), "--sky", str(sky), "--beam", "dipole"])
    assert r.exit_code == 0, r.output
    assert _column_digests(ms) == before
    with _table(ms) as t:
        model = t.getcol("MODEL_DATA")
    assert np.abs(model).max() > 0.1   # predict did write something

    files = _file_digests(ms)
    for column in ("DATA", "MODEL_DATA"):
        r = _run(["grid", str(ms), "--column", column, "--uv-range", "1,180",
                  "-o", str(tmp_path / f"g_{column}.h5")])
        assert r.exit_code == 0, r.output
    r = _run(["grid", str(ms), "--column", "DATA", "--gridder", "cell", "--split", "even-odd",
              "--uv-range", "1,180", "-o", str(tmp_path / "gc.h5")])
    assert r.exit_code == 0, r.output
    r = _run(["transform", str(tmp_path / "g_DATA.h5"), "-o", str(tmp_path / "d.h5")])
    assert r.exit_code == 0, r.output
    r = _run(["ps", str(tmp_path / "d.h5"), "-o", str(tmp_path / "p.h5")])
    assert r.exit_code == 0, r.output
    # reading never writes: every file of the MS is byte-identical
    assert _file_digests(ms) == files
    assert _column_digests(ms) == before


def test_refused_and_failed_predicts_leave_ms_unchanged(small_lofar_ms, tmp_path, monkeypatch):
    ms = small_lofar_ms
    _randomise(ms, seed=5)
    sky = _write_sky(tmp_path / "sky.skymodel", *_phase_centre(ms))
    files = _file_digests(ms)
    before = _column_digests(ms)
    for args in (["--column", "DATA"],                    # refuses to overwrite DATA
                 ["--column", "FLAG"],                    # metadata column
                 ["--fov", "-1"],                         # bad option
                 ["--field", "7"]):                       # no such field
        r = _run(["predict", str(ms), "--sky", str(sky), "--beam", "none", *args])
        assert r.exit_code == 2, (args, r.output)
        assert "Traceback" not in r.output
    assert _file_digests(ms) == files

    # an unexpected failure after some chunks: DATA intact, column marked incomplete
    from faults import fail_after_chunks
    from msleak.verbs import predict as engine

    with monkeypatch.context() as m, pytest.raises(RuntimeError, match="simulated failure"):
        fail_after_chunks(m, 1)
        engine.predict(ms, sky, beam="dipole", memory_limit=2048, scheduler="sync")
    assert _column_digests(ms) == before
    with _table(ms) as t:
        state = t.getcolkeyword("MODEL_DATA", "MSLEAK_PREDICT")
    assert not state["complete"] and 0 < state["rows_done"] < 60


def test_predict_over_existing_model_replaces_whole_chunks(small_lofar_ms, tmp_path,
                                                          monkeypatch):
    """An existing MODEL_DATA is replaced chunk by chunk: after a failure every row holds
    either its old or its new values (never a mix within a row), and the rows the run
    state reports as done hold the new values."""
    from faults import fail_after_chunks
    from msleak.verbs import predict as engine

    ms = small_lofar_ms
    ra0, dec0 = _phase_centre(ms)
    old_sky = _write_sky(tmp_path / "old.skymodel", ra0 + 0.01, dec0)
    new_sky = _write_sky(tmp_path / "new.skymodel", ra0, dec0)
    engine.predict(ms, old_sky, beam="none", memory_limit=2048, scheduler="sync")
    with _table(ms) as t:
        old = t.getcol("MODEL_DATA")
    ref_ms = tmp_path / "ref.ms"
    shutil.copytree(ms, ref_ms)
    engine.predict(ref_ms, new_sky, beam="none", memory_limit=2048, scheduler="sync")
    with _table(ref_ms) as t:
        new = t.getcol("MODEL_DATA")
    with monkeypatch.context() as m, pytest.raises(RuntimeError):
        fail_after_chunks(m, 2)
        engine.predict(ms, new_sky, beam="none", memory_limit=2048, scheduler="sync")
    with _table(ms) as t:
        part = t.getcol("MODEL_DATA")
        times = t.getcol("TIME")
        state = t.getcolkeyword("MODEL_DATA", "MSLEAK_PREDICT")
    is_old = np.all(part == old, axis=(1, 2))
    is_new = np.all(part == new, axis=(1, 2))
    assert np.all(is_old | is_new)
    assert is_old.any() and is_new.any()
    done = times <= state["progress"]["f0_d0"]
    assert np.all(is_new[done]) and not state["complete"]
    # the rerun completes it, equal to the uninterrupted run
    res = engine.predict(ms, new_sky, beam="none", memory_limit=2048, scheduler="sync")
    assert res.resumed
    with _table(ms) as t:
        np.testing.assert_array_equal(t.getcol("MODEL_DATA"), new)
        assert t.getcolkeyword("MODEL_DATA", "MSLEAK_PREDICT")["complete"]


# ----------------------------------------------------------------------- full disk
def _mount_tmpfs(path: Path, size_kb: int) -> bool:
    if os.geteuid() != 0 or shutil.which("mount") is None:
        return False
    path.mkdir(parents=True, exist_ok=True)
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_kb}k", "tmpfs", str(path)],
                          capture_output=True)
    return proc.returncode == 0


def _umount(path: Path) -> None:
    subprocess.run(["umount", str(path)], capture_output=True)


@pytest.fixture
def tiny_fs(tmp_path):
    """A mount point factory for tiny tmpfs file systems (skips when mounting is not
    allowed); everything is unmounted at the end."""
    mounted = []

    def make(size_kb: int) -> Path:
        mnt = tmp_path / f"fs{len(mounted)}"
        if not _mount_tmpfs(mnt, size_kb):
            pytest.skip("cannot mount a tmpfs here (needs root)")
        mounted.append(mnt)
        return mnt

    yield make
    for mnt in mounted:
        _umount(mnt)


def test_full_disk_predict_simulate_grid(tiny_fs, tmp_path, small_lofar_ms):
    """Too little space: simulate, predict and grid stop with one line (exit 2) before
    writing anything, and the MS stays readable with DATA intact."""
    mnt = tiny_fs(1200)
    params = ["--stations", "CS00[1-3]HBA*", "--duration", "0.3333", "--interval", "10",
              "--nchan", "16"]
    r = _run(["simulate", str(mnt / "big.ms"), *params])
    assert r.exit_code == 2, r.output
    assert "not enough disk space" in r.output and "Traceback" not in r.output
    assert not (mnt / "big.ms").exists()

    # an MS that fits, but its new MODEL_DATA column would not
    ms = mnt / "small.ms"
    shutil.copytree(small_lofar_ms, ms)
    _randomise(ms)
    before = _column_digests(ms)
    free = shutil.disk_usage(mnt).free
    filler = mnt / "filler"
    filler.write_bytes(b"\0" * max(0, free - 200 * 1024))
    sky = _write_sky(tmp_path / "sky.skymodel", *_phase_centre(ms))
    r = _run(["predict", str(ms), "--sky", str(sky), "--beam", "none"])
    assert r.exit_code == 2, r.output
    assert "not enough disk space for column MODEL_DATA" in r.output
    with _table(ms) as t:
        assert "MODEL_DATA" not in t.colnames()
    assert _column_digests(ms) == before

    # a product that does not fit: one line, no partial file left behind
    filler.unlink()
    filler.write_bytes(b"\0" * max(0, shutil.disk_usage(mnt).free - 8 * 1024))
    r = _run(["grid", str(ms), "--uv-range", "1,180", "--cell", "2", "-o", str(mnt / "g.h5")])
    assert r.exit_code == 2, r.output
    assert "No space left on device" in r.output and len(r.output.strip().splitlines()[-1]) < 300
    assert not (mnt / "g.h5").exists() and not (mnt / ".g.h5.partial").exists()
    assert _column_digests(ms) == before


def test_file_size_limit_product_write(small_lofar_ms, tmp_path):
    """Where no tmpfs can be mounted, RLIMIT_FSIZE stands in for a full disk: writing a
    product beyond the limit gives a one-line error (exit 2), nothing half-written."""
    out = tmp_path / "g.h5"
    code = ("import resource, sys; resource.setrlimit(resource.RLIMIT_FSIZE, (20000, 20000)); "
            "from msleak.cli import main; sys.argv = ['msleak'] + sys.argv[1:]; main()")
    proc = subprocess.run([sys.executable, "-c", code, "grid", str(small_lofar_ms),
                           "--uv-range", "1,180", "--cell", "2", "-o", str(out)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("msleak: error:") and "File too large" in last
    assert "Traceback" not in proc.stderr
    assert not out.exists() and not (tmp_path / ".g.h5.partial").exists()
