"""A dask.distributed LocalCluster (2 worker processes): same results as the serial path,
and a worker killed mid-run either recovers or fails with a one-line message leaving a
readable, resumable Measurement Set."""

from __future__ import annotations

import logging
import shutil

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

from test_parallel_local import SKY, _column, _grid, _ps, fill_data  # noqa: E402


@pytest.fixture(scope="module")
def cluster():
    import dask

    # one retry: a worker killed once is recovered from, twice is an error
    with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
        with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                      dashboard_address=None, memory_limit="1GiB",
                                      silence_logs=logging.CRITICAL) as lc:
            yield lc


@pytest.fixture
def sky(tmp_path):
    path = tmp_path / "sky.skymodel"
    path.write_text(SKY)
    return path


@pytest.fixture
def reference(small_lofar_ms, sky, tmp_path):
    """(fresh MS copy, serial MODEL_DATA of the same MS and sky)."""
    from msleak.verbs import predict as engine

    ref_ms = tmp_path / "ref.ms"
    shutil.copytree(small_lofar_ms, ref_ms)
    engine.predict(ref_ms, sky, scheduler="sync", progress=False)
    return small_lofar_ms, _column(ref_ms)[0]


def test_cluster_predict_same_model_data(cluster, reference, sky):
    from msleak.verbs import predict as engine

    ms, ref = reference
    res = engine.predict(ms, sky, scheduler=cluster.scheduler_address, memory_limit=40_000,
                         progress=False)
    got, state = _column(ms)
    assert state["complete"] and state["rows_done"] == ref.shape[0] == res.rows_written
    np.testing.assert_allclose(got, ref, rtol=0, atol=2e-7 * np.abs(ref).max())


def test_cluster_grid_same_ps(cluster, small_lofar_ms):
    fill_data(small_lofar_ms)
    ref = _grid(small_lofar_ms, scheduler="sync", split="first-second")
    with distributed.Client(cluster) as client:  # a Client object works as well
        got = _grid(small_lofar_ms, scheduler=client, split="first-second")
    for name in ("vis", "weight", "vis_a", "vis_b"):
        np.testing.assert_allclose(got[name].values, ref[name].values, rtol=1e-12,
                                   atol=1e-12 * np.abs(ref[name].values).max())
    p_ref, p_got = _ps(ref)["power"].values, _ps(got)["power"].values
    np.testing.assert_allclose(p_got, p_ref, rtol=1e-10, atol=1e-10 * np.nanmax(np.abs(p_ref)))


def test_worker_killed_once_recovers(cluster, reference, sky, tmp_path, monkeypatch):
    from faults import kill_worker_at
    from msleak.verbs import predict as engine

    ms, ref = reference
    marker = tmp_path / "killed-once"
    with monkeypatch.context() as m:
        kill_worker_at(m, 1, str(marker))
        engine.predict(ms, sky, scheduler=cluster.scheduler_address, memory_limit=40_000,
                       progress=False)
    assert marker.exists()  # a worker did die on chunk 1
    got, state = _column(ms)
    assert state["complete"]
    np.testing.assert_allclose(got, ref, rtol=0, atol=2e-7 * np.abs(ref).max())


def test_worker_killed_every_time_fails_cleanly(cluster, reference, sky, monkeypatch):
    import casacore.tables as pt
    from faults import kill_worker_at

    from msleak.errors import MsleakError
    from msleak.verbs import predict as engine
    from msleak.verbs.predict import predict

    ms, ref = reference
    with pt.table(str(ms), readonly=False, ack=False) as t:  # recognisable DATA
        data = (np.arange(t.nrows() * 16).reshape(-1, 4, 4) * (1 + 1j)).astype(np.complex64)
        t.putcol("DATA", data)
    with monkeypatch.context() as m, pytest.raises(MsleakError, match="dask worker died") as info:
        kill_worker_at(m, 2)
        engine.predict(ms, sky, scheduler=cluster.scheduler_address, memory_limit=40_000,
                       progress=False)
    assert "\n" not in str(info.value) and "rerun" in str(info.value)
    with pt.table(str(ms), ack=False) as t:  # readable, DATA intact, column incomplete
        np.testing.assert_array_equal(t.getcol("DATA"), data)
        state = dict(t.getcolkeyword("MODEL_DATA", "MSLEAK_PREDICT"))
    assert not state["complete"] and 0 < state["rows_done"] < ref.shape[0]
    res = predict(ms, sky, scheduler="sync", memory_limit=150_000, progress=False)
    assert res.resumed and res.rows_written == ref.shape[0] - state["rows_done"]
    got, state = _column(ms)
    assert state["complete"]
    np.testing.assert_allclose(got, ref, rtol=0, atol=2e-7 * np.abs(ref).max())
