"""Writing a predict run into its columns: column creation, chunk writes and the run state
that makes an interrupted run resumable (docs/predict.md, "Interrupted runs").

Each column's run state (provenance, ``complete`` flag, progress) is its column keyword
described in :mod:`msleak.io.columns`; a rerun with the same settings continues the
incomplete columns (and skips those an identical run completed).
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import logging
import time as _time
from dataclasses import dataclass, field

import numpy as np

from msleak.conventions import STOKES_CONVENTION
from msleak.io import columns as colio
from msleak.predict.chunks import add_time
from msleak.predict.stations import PHASE_TOLERANCE_RAD
from msleak.verbs.predict_chunks import Chunk
from msleak.verbs.predict_plan import Plan, PredictResult

__all__ = ["Run", "new_run", "create_columns", "start", "write_chunk", "finish"]

log = logging.getLogger(__name__)

PHASE_CONVENTION = ("V_pq = sum_s J_p B_s J_q^H exp(+2 pi i (u l + v m + w (n - 1))), "
                    "(u, v, w) = UVW / lambda with UVW = antenna2 - antenna1 (MS and DP3 "
                    "convention)")


@dataclass
class Run:
    """The state of one MS's run while it is written: its :class:`Plan` (fixed) and what
    changes as chunks are written."""

    plan: Plan
    #: per target, what the run did (returned by the verb)
    results: list
    #: wall time (s) per stage, all the MS's columns together
    timings: dict = field(default_factory=dict)
    #: per target: the Rollback of its column
    rollbacks: list = field(default_factory=list)
    #: targets this run computes (the others are complete from an identical run)
    active: list = field(default_factory=list)
    #: column -> run state, for the active targets
    states: dict = field(default_factory=dict)
    stack: contextlib.ExitStack | None = None
    table: object = None
    n_slots: int = 0
    rows_per_baseline: int = 0
    #: skies (target indices) whose chunk note has been logged
    noted: set = field(default_factory=set)


def new_run(plan: Plan) -> Run:
    """A run of ``plan`` that has written nothing yet."""
    timings: dict = {}
    return Run(plan=plan, timings=timings,
               results=[PredictResult(ms=plan.ms, column=t.column, rows_written=0,
                                      groups=plan.groups, timings=timings)
                        for t in plan.targets])


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def create_columns(runs: list[Run], rollbacks: list) -> None:
    """Create the target columns of every MS before any is written, each with the
    :class:`~msleak.io.columns.Rollback` that undoes it (appended to ``rollbacks`` in
    creation order; each is made with the table as the previous column left it)."""
    for run in runs:
        plan = run.plan
        for target, res in zip(plan.targets, run.results):
            with colio.open_for_writing(plan.ms) as table:
                rollback = colio.Rollback(table, target.column, plan.total_rows)
                rollbacks.append(rollback)
                run.rollbacks.append(rollback)
                rollback.created = colio.ensure_data_column(table, target.column,
                                                            double=plan.double_column)
                res.created_column = rollback.created


def start(run: Run, restart: bool, bar) -> None:
    """Open the MS for writing, decide per column (resume, skip, start over) and store the
    run states.

    A run resumes when some column holds an incomplete run with the same settings; its
    columns complete from such a run are then skipped and the others start over. Without
    one (or with ``restart``) every column starts over.
    """
    plan = run.plan
    run.stack = contextlib.ExitStack()
    table = run.table = run.stack.enter_context(colio.open_for_writing(plan.ms))
    old = []
    for target, settings_json in zip(plan.targets, plan.settings_json):
        state = colio.read_run_state(table, target.column)
        old.append(state if state and state.get("settings_json") == settings_json else None)
    resume = not restart and any(s is not None and not bool(s.get("complete", True))
                                 for s in old)
    for k, target in enumerate(plan.targets):
        state = old[k] if resume else None
        if state is not None and bool(state.get("complete", True)):
            run.results[k].skipped = True
            log.info("%s: %s is complete from an identical run; left as it is", plan.ms,
                     target.column)
            continue
        run.active.append(k)
        colio.drop_noise_state(table, target.column)   # predict rewrites the column
        run.results[k].resumed = state is not None
        if state is not None:
            log.info("%s: resuming an interrupted predict into %s (%d rows done)", plan.ms,
                     target.column, int(state.get("rows_done", 0)))
        run.states[target.column] = _run_state(plan.settings[k], plan.settings_json[k], state)
    colio.write_run_state(table, run.states)
    bar.update(min(s["rows_done"] for s in run.states.values()))


def _run_state(settings: dict, settings_json: str, state: dict | None) -> dict:
    """The run state of a column: fresh, or continuing ``state``."""
    progress = {k: float(v) for k, v in dict(state.get("progress", {})).items()} if state else {}
    return {**settings, "settings_json": settings_json,
            "stokes_convention": STOKES_CONVENTION, "phase_convention": PHASE_CONVENTION,
            "complete": False,
            "rows_done": int(state.get("rows_done", 0)) if state else 0,
            "progress": progress,
            "started": state.get("started", _now()) if state else _now(),
            "updated": _now()}


def write_chunk(run: Run, job: Chunk, vis: list) -> None:
    """Write a computed chunk into the columns of its skies and flush the run states."""
    tick = _time.perf_counter()
    row_time = job.times[job.tidx]
    for k, values in zip(job.active, vis):
        _write_column(run, k, job, row_time, values)
    colio.write_run_state(run.table, run.states)
    add_time(run.timings, "write", tick)


def _write_column(run: Run, k: int, job: Chunk, row_time: np.ndarray, values: np.ndarray
                  ) -> None:
    """Write into target ``k``'s column the rows of ``job`` it does not have yet."""
    column = run.plan.targets[k].column
    state = run.states[column]
    last = state["progress"].get(job.key)
    if last is not None and last >= job.times[-1]:
        return  # an interrupted run wrote this column further than the others
    rows = job.rows
    if last is not None and row_time.min() <= last:
        keep = row_time > last
        rows, values = rows[keep], values[keep]
    run.rollbacks[k].save_rows(run.table, rows)
    colio.write_rows(run.table, column, rows, values)
    state["rows_done"] += int(rows.size)
    state["progress"][job.key] = float(job.times[-1])
    state["updated"] = _now()
    run.results[k].rows_written += int(rows.size)


def finish(run: Run, t_start: float) -> None:
    """Mark the run's columns complete and release the MS."""
    plan = run.plan
    now = _now()
    for state in run.states.values():
        state.update(complete=True, finished=now, updated=now)
    colio.write_run_state(run.table, run.states)
    run.stack.close()
    run.stack = run.table = None
    seconds = _time.perf_counter() - t_start
    for k in run.active:
        res = run.results[k]
        res.seconds, res.n_slots = seconds, run.n_slots
        res.rows_per_baseline = run.rows_per_baseline
        log.info("%s: predicted %d rows into %s in %.1f s (%d per baseline)", plan.ms,
                 res.rows_written, res.column, seconds, res.rows_per_baseline)
    if run.rows_per_baseline:
        log.warning("%s: %d rows have UVW that are not antenna-based (the per-station "
                    "factorisation would make phase errors above %g rad); they were predicted "
                    "per baseline from their own UVW (exact, slower)", plan.ms,
                    run.rows_per_baseline, PHASE_TOLERANCE_RAD)
