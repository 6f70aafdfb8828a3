"""Faults injected into a predict run with pytest's monkeypatch: a failure after some
chunks were written, an error raised by the chunk holding a given time, and a dask worker
killed while it computes a given chunk."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from msleak.io import columns as colio
from msleak.verbs import predict_chunks as chunks
from msleak.verbs import predict_run as runstate
from msleak.verbs.predict_chunks import chunk_task

__all__ = ["fail_after_chunks", "fail_at_time", "kill_worker_at"]


def fail_after_chunks(monkeypatch, n: int) -> None:
    """Raise ``RuntimeError("simulated failure")`` once ``n`` chunks are written (their run
    states flushed), as an unexpected failure would."""
    original = runstate.write_chunk
    written = [0]

    def write_chunk(plan, job, vis):
        original(plan, job, vis)
        written[0] += 1
        if written[0] >= n:
            raise RuntimeError("simulated failure (test)")

    monkeypatch.setattr(runstate, "write_chunk", write_chunk)


class _KillingTask:
    """The chunk task, except that the process computing chunk ``index`` exits (once if
    ``marker`` names a file, which is then created, else every time)."""

    def __init__(self, index: int, marker: str | None):
        self.index, self.marker, self.__name__ = index, marker, "chunk_task"

    def __call__(self, job, shared=None):
        if job.index == self.index and not (self.marker and Path(self.marker).exists()):
            if self.marker:
                Path(self.marker).touch()
            os._exit(70)
        return chunk_task(job, shared)


def kill_worker_at(monkeypatch, index: int, marker: str | None = None) -> None:
    """Make the dask worker that computes chunk ``index`` die (run on worker processes:
    the task is pickled by reference to this module)."""
    monkeypatch.setattr(chunks, "chunk_task", _KillingTask(index, marker))


def fail_at_time(monkeypatch, when: float, error: BaseException, watch=()) -> list:
    """Make the chunk holding TIME ``when`` raise ``error``. Returns a list that gets, for
    every chunk computed, whether each MS of ``watch`` held a header backup at that moment
    (it does once the run has written a chunk into it)."""
    original = chunks.predict_chunk
    seen: list = []

    def patched(comp, beam_model, times, *args, **kwargs):
        seen.append([(Path(m) / colio.BACKUP_DIR).is_dir() for m in watch])
        if np.any(times == when):
            raise error
        return original(comp, beam_model, times, *args, **kwargs)

    monkeypatch.setattr(chunks, "predict_chunk", patched)
    return seen
