"""The predict run: skies + beam + MS metadata -> visibilities written in time chunks.

A run predicts one or more skies, each into its own column. For every selected
(FIELD_ID, DATA_DESC_ID) group of rows:

1. each sky is read for the field's phase centre (its FoV crop), evaluated on the
   spectral window's channels and factorised
   (:func:`msleak.predict.kernels.brightness_factors`); the union of the skies'
   directions is formed (:func:`msleak.predict.sky.sky_set`);
2. the group's times are split in chunks that fit ``memory_limit`` (times first, then
   channels when one time slot is too big), counting one output per sky;
3. per chunk: per-station coordinates from the rows' UVW
   (:func:`msleak.predict.stations.station_coordinates`), beam Jones matrices of the
   stations present towards every direction of the union plus the phase centre (once for
   all skies), the visibility matrices of every sky
   (:func:`msleak.predict.kernels.predict_grams`), rows gathered with the phase-centre
   correction J_p(s0)^-1 V_pq J_q(s0)^-H (rows whose UVW the station coordinates do not
   reproduce are summed from their own UVW, :mod:`msleak.predict.baselines`), converted
   to circular feeds if the MS has them, put in the MS's correlation order (only XX, YY
   or RR, LL when it stores just those), written into each sky's column, and the run
   states updated and flushed.

Each column's run state (provenance, ``complete`` flag, progress) is its column keyword
described in :mod:`msleak.io.columns`; a rerun with the same settings continues the
incomplete columns (and skips those an identical run completed).
Everything that can refuse the input is checked before the first write; a refusal found
while running (an :class:`~msleak.errors.MsleakError` other than a lost worker) puts every
MS back as it was (:class:`msleak.io.columns.Rollback`), while an interruption (Ctrl-C,
a kill, a lost worker, an unexpected failure) keeps what was written for a rerun.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import hashlib
import json
import logging
import math
import os
import sys
import threading
import time as _time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from msleak import __version__
from msleak.conventions import STOKES_CONVENTION, CorrelationLayout, correlation_layout
from msleak.errors import InputError, MsleakError
from msleak.io import columns as colio
from msleak.predict import kernels
from msleak.predict.baselines import predict_rows
from msleak.predict.sky import SkySet, sky_components, sky_set
from msleak.predict.stations import PHASE_TOLERANCE_RAD, station_coordinates, uvw_tolerance

__all__ = ["predict", "predict_many", "PredictResult", "DEFAULT_MEMORY_LIMIT", "plan_chunks"]

log = logging.getLogger(__name__)

#: Default memory budget of a predict run (bytes).
DEFAULT_MEMORY_LIMIT = 2 * 1024**3


@dataclass
class PredictResult:
    """What a predict run did for one column of one MS."""

    ms: Path
    column: str
    rows_written: int
    groups: list = field(default_factory=list)
    resumed: bool = False
    created_column: bool = False
    #: the column was complete from an identical run and left as it was
    skipped: bool = False
    seconds: float = 0.0
    #: directions with flux of this column's sky, per group
    n_sources: dict = field(default_factory=dict)
    #: wall time (s) per stage of the run on this MS, all its columns together (the same
    #: dict for each): setup (inputs, skies, beam model), read, uvw, beam, kernel,
    #: per_baseline, write
    timings: dict = field(default_factory=dict)
    #: number of time slots predicted
    n_slots: int = 0
    #: rows predicted from their own UVW (not antenna-based within the tolerance)
    rows_per_baseline: int = 0


def plan_chunks(ntime: int, nchan: int, nstation: int, ndir: int, rows_per_time: int,
                memory_limit: float, itemsize: int, beam: bool,
                fixed_bytes: float = 0.0, nsky: int = 1) -> tuple[int, int]:
    """Times and channels per chunk so that the working set stays under ``memory_limit``.

    The per-(time, channel) estimate counts the beam Jones matrices towards the ``ndir``
    directions of all skies (complex128 as the beam models compute them, the cast copy
    and one temporary of the same size) and, for each of the ``nsky`` skies, its
    visibility matrices and its gathered and written rows.

    Returns
    -------
    (ntime_chunk, nchan_chunk) : tuple of int, both >= 1
    """
    per_unit = nsky * ((2 * nstation) ** 2 * itemsize + rows_per_time * 4 * (2 * itemsize + 8))
    if beam:
        per_unit += nstation * (ndir + 1) * 4 * (2 * 16 + itemsize)
    avail = memory_limit - fixed_bytes
    units = int(avail // per_unit) if avail > 0 else 0
    if units < 1:
        log.warning("memory limit %.0f MB is too small for one time slot and channel "
                    "(needs about %.0f MB); going ahead with that", memory_limit / 2**20,
                    (per_unit + fixed_bytes) / 2**20)
        return 1, 1
    if units >= nchan:
        return max(1, min(ntime, units // nchan)), nchan
    return 1, units


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _select_ids(values: Sequence | None, names: list[str], what: str, present: np.ndarray
                ) -> list[int]:
    """FIELD/SPW selection by id or name; default all ids present in the main table."""
    present = sorted(int(v) for v in np.unique(present))
    if not values:
        return present
    out = []
    for v in values:
        text = str(v).strip()
        if text.lstrip("-").isdigit():
            idx = int(text)
        elif text in names:
            idx = names.index(text)
        else:
            raise InputError(f"no {what} {text!r} in the MS (available: "
                             f"{', '.join(f'{i}:{n}' if n else str(i) for i, n in enumerate(names))})")
        if not 0 <= idx < len(names):
            raise InputError(f"no {what} {idx} in the MS (ids 0..{len(names) - 1})")
        if idx not in present:
            raise InputError(f"{what} {idx} has no rows in the MS (present: "
                             f"{', '.join(map(str, present))})")
        out.append(idx)
    return sorted(set(out))


def _load_beam(name: str, ms: Path, options: dict | None = None):
    if name == "none":
        return None
    try:
        from msleak.beam import load_beam
    except ImportError as err:  # pragma: no cover - the beam package is part of msleak
        raise InputError(f"beam model {name!r} is not available ({err})") from err
    return load_beam(name, ms, **(options or {}))


_BEAMS: dict = {}
_BEAMS_LOCK = threading.Lock()


def _cached_beam(name: str, ms: str, token: str, options: dict | None = None):
    """The beam model of ``ms`` for run ``token``, loaded once per process (any scheduler);
    ``options`` name its stations, so no worker reads the main table predict writes."""
    with _BEAMS_LOCK:
        if token not in _BEAMS:
            while len(_BEAMS) >= 8:
                _BEAMS.pop(next(iter(_BEAMS)))
            _BEAMS[token] = _load_beam(name, Path(ms), options)
        return _BEAMS[token]


def predict(ms: str | os.PathLike, sky: str | os.PathLike | Sequence[str | os.PathLike], *,
            fov_deg: float | None | Sequence[float | None] = None, beam: str = "everybeam",
            column: str | Sequence[str] = "MODEL_DATA", centre_correction: bool = True,
            interpolate_frequency: bool = False, double: bool = False,
            memory_limit: float = DEFAULT_MEMORY_LIMIT, overwrite_data: bool = False,
            fields: Sequence | None = None, spws: Sequence | None = None,
            restart: bool = False, progress: bool | None = None, scheduler="sync",
            workers: int | None = None, diameter_m: float | None = None,
            _fail_after_chunks: int | None = None, _fault: tuple | None = None
            ) -> PredictResult | list[PredictResult]:
    """Predict beam-corrupted visibilities of one or several skies into columns of an MS.

    Parameters
    ----------
    ms : path
        The Measurement Set (written in place).
    sky : path or sequence of paths
        A FITS cube (one point source per pixel, spectrum = the cube's channels) or a
        makesourcedb text file. Several skies are predicted in one pass, each into its own
        column: per chunk the beam is evaluated once towards the union of their directions
        (directions with exactly the same (ra, dec) counted once: crops of one cube, cubes
        on the same pixel grid); each column equals a run with its sky alone (to the bit
        or, with the everybeam and dipole models, to 2e-7: docs/predict.md).
    fov_deg : float or sequence of float, optional
        Keep the central ``fov_deg`` x ``fov_deg`` of the sky (deg): one value for every
        sky, or one per sky (None: all of it).
    beam : {"everybeam", "everybeam-direct", "dipole", "none"}
        Beam model (:func:`msleak.beam.load_beam`) of the stations in the selected rows.
    diameter_m : float, optional
        ``dipole`` beam: station diameter (m) of its Airy factor instead of DISH_DIAMETER.
    column : str or sequence of str
        Target column of each sky (one per sky, all different), created like DATA (tiled)
        if missing. DATA needs ``overwrite_data``.
    centre_correction : bool
        Remove the beam at the phase centre: V' = J_p(s0)^-1 V J_q(s0)^-H.
    interpolate_frequency : bool
        Interpolate a tabulated sky linearly to the MS channels instead of requiring a
        match.
    double : bool
        complex128 arithmetic (default complex64; phases are always float64).
    memory_limit : float
        Working-set budget (bytes), shared by the tasks that run at the same time.
    fields, spws : sequence of int or str, optional
        FIELD ids or names, SPECTRAL_WINDOW ids; default all present.
    restart : bool
        Ignore the progress of an interrupted run and start over.
    progress : bool, optional
        Progress bar on stderr; default when stderr is a terminal.
    scheduler : {"sync", "threads", "processes"} or str or distributed.Client
        Where the time chunks are computed (:func:`msleak.parallel.open_runner`); the
        chunks are written by this process in time order. "sync": the serial path.
    workers : int, optional
        Chunks computed at the same time (default: all cores / all worker threads).

    Returns
    -------
    PredictResult, or a list of them (one per sky, in order) when ``sky`` is a sequence
    """
    results = predict_many([ms], sky, fov_deg=fov_deg, beam=beam, column=column,
                           centre_correction=centre_correction,
                           interpolate_frequency=interpolate_frequency, double=double,
                           memory_limit=memory_limit, overwrite_data=overwrite_data,
                           fields=fields, spws=spws, restart=restart, progress=progress,
                           scheduler=scheduler, workers=workers, diameter_m=diameter_m,
                           _fail_after_chunks=_fail_after_chunks, _fault=_fault)
    return results[0] if isinstance(sky, (str, os.PathLike)) else results


@dataclass(frozen=True)
class _Target:
    """One sky of a run and the column it is predicted into."""

    sky: Path
    column: str
    fov_deg: float | None
    sha256: str


@dataclass
class _Plan:
    """What to predict into one MS, and its run states while it is being written."""

    ms: Path
    fields_meta: list
    spw_meta: list
    ddesc: list
    groups: list
    feeds: dict
    total_rows: int
    targets: list
    skies: dict
    settings: list
    settings_json: list
    beam_token: str
    results: list
    timings: dict
    beam_options: dict = field(default_factory=dict)
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


@dataclass
class _Chunk:
    """One time chunk of one (field, data description) of one MS: the input of a task."""

    index: int
    plan: int
    key: str
    ms: str
    beam: str
    beam_token: str
    comp: SkySet
    active: tuple
    times: np.ndarray
    freq: np.ndarray
    stations: np.ndarray
    fmeta: object
    rows: np.ndarray
    tidx: np.ndarray
    p: np.ndarray
    q: np.ndarray
    uvw: np.ndarray
    centre_correction: bool
    dtype: str
    nc_chunk: int
    layout: CorrelationLayout
    last: bool = False
    fault: tuple | None = None
    beam_options: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return f"{Path(self.ms).name} {self.key} chunk {self.index}"


def predict_many(ms_list: Sequence[str | os.PathLike],
                 sky: str | os.PathLike | Sequence[str | os.PathLike], *,
                 fov_deg: float | None | Sequence[float | None] = None,
                 beam: str = "everybeam", column: str | Sequence[str] = "MODEL_DATA",
                 centre_correction: bool = True, interpolate_frequency: bool = False,
                 double: bool = False, memory_limit: float = DEFAULT_MEMORY_LIMIT,
                 overwrite_data: bool = False, fields: Sequence | None = None,
                 spws: Sequence | None = None, restart: bool = False,
                 progress: bool | None = None, scheduler="sync", workers: int | None = None,
                 diameter_m: float | None = None, _fail_after_chunks: int | None = None,
                 _fault: tuple | None = None) -> list[PredictResult]:
    """:func:`predict` into each of several Measurement Sets (e.g. one per subband).

    Every MS is checked and its skies prepared before anything is written; the time
    chunks of all MSs are then computed on ``scheduler`` and written by this process,
    MS after MS, in time order (so the resume markers stay exact). Options as
    :func:`predict`; returns one :class:`PredictResult` per MS and sky: MS by MS in the
    order given, the skies of each in the order given.
    """
    from msleak.io.ms import check_ms
    from msleak.parallel import open_runner

    t_start = _time.perf_counter()
    paths = [check_ms(m) for m in ms_list]
    if not paths:
        raise InputError("no Measurement Set given")
    seen: dict[Path, Path] = {}
    for p in paths:
        if p.resolve() in seen:
            raise InputError(f"{p} is given twice")
        seen[p.resolve()] = p
    targets = _targets(sky, column, fov_deg, overwrite_data)
    if memory_limit <= 0:
        raise InputError("--memory-limit must be positive")
    for p in paths:
        colio.check_writable(p)
        colio.repair_interrupted(p)  # header files a killed run may have truncated
    dtype = np.dtype(np.complex128 if double else np.complex64)
    if diameter_m is not None and (beam != "dipole" or not diameter_m > 0):
        raise InputError("--diameter takes a positive station diameter (m) and applies to "
                         "--beam dipole only")
    opts = dict(beam=beam, centre_correction=centre_correction,
                interpolate_frequency=interpolate_frequency, dtype=dtype, fields=fields,
                spws=spws, diameter_m=diameter_m)
    plans = [_make_plan(p, targets, **opts) for p in paths]

    with open_runner(scheduler, workers, memory_limit) as runner:
        if runner.kind in ("processes", "distributed"):
            for plan in plans:
                model = _BEAMS.get(plan.beam_token)
                if type(model).__name__ == "EveryBeamDirect":
                    raise InputError("--beam everybeam-direct reads the MS main table, which "
                                     "stays locked while predict writes it; use --scheduler "
                                     "threads or sync")
        _run(plans, runner, dtype, centre_correction, beam, restart, progress, t_start,
             _fail_after_chunks, _fault)
    return [res for plan in plans for res in plan.results]


def _run(plans: list, runner, dtype, centre_correction: bool, beam: str, restart: bool,
         progress, t_start: float, fail_after_chunks, fault) -> None:
    """Create the columns, compute and write every chunk; undo the run if it is refused."""
    from msleak.parallel.runner import WorkerLost

    rollbacks: list[colio.Rollback] = []
    try:
        _create_columns(plans, rollbacks)
        setup = _time.perf_counter() - t_start
        for plan in plans:
            plan.timings["setup"] = setup
        bar = _progress_bar(sum(p.total_rows for p in plans), progress)
        jobs = _all_chunks(plans, runner.memory_per_task, dtype, centre_correction, beam,
                           restart, bar, fault, t_start)
        try:
            _write_chunks(runner, jobs, plans, bar, t_start, fail_after_chunks)
        finally:
            bar.close()
            for plan in plans:
                if plan.stack is not None:
                    plan.stack.close()
                    plan.stack = None
    except MsleakError as err:
        if not isinstance(err, WorkerLost):  # a refusal: undo; a lost worker: resumable
            for rollback in reversed(rollbacks):  # each puts back the table it found
                rollback.restore()
        raise
    finally:
        for rollback in rollbacks:
            rollback.close()


def _targets(sky, column, fov_deg, overwrite_data: bool) -> list[_Target]:
    """The run's skies with their columns and fields of view, matched in order and checked."""
    skies = [Path(sky)] if isinstance(sky, (str, os.PathLike)) else [Path(s) for s in sky]
    columns = [column] if isinstance(column, str) else list(column)
    fovs = list(fov_deg) if np.ndim(fov_deg) == 1 else [fov_deg]
    if not skies:
        raise InputError("no sky given; pass --sky SKY")
    if len(columns) != len(skies):
        raise InputError(f"{len(skies)} --sky and {len(columns)} --column given; give one "
                         "--column per --sky (they are matched in order)")
    if len(fovs) == 1:
        fovs = fovs * len(skies)
    if len(fovs) != len(skies):
        raise InputError(f"--fov is given {len(fovs)} times for {len(skies)} --sky; give it "
                         "once (for every sky) or once per --sky (matched in order)")
    for name in columns:
        colio.check_column_name(name, overwrite_data=overwrite_data)
    for name in columns:
        if columns.count(name) > 1:
            raise InputError(f"--column {name} is given {columns.count(name)} times; give "
                             "every --sky its own --column")
    for fov in fovs:
        if fov is not None and not (0 < fov <= 180):
            raise InputError(f"--fov must be in (0, 180] deg, got {fov}")
    digests: dict[Path, str] = {}
    for path in skies:
        if not path.exists():
            raise InputError(f"sky file {path} does not exist")
        if path.is_dir():
            raise InputError(f"sky {path} is a directory, not a FITS cube or makesourcedb file")
        if path not in digests:
            digests[path] = _sha256(path)
    return [_Target(sky=s, column=c, fov_deg=None if f is None else float(f),
                    sha256=digests[s]) for s, c, f in zip(skies, columns, fovs)]


def _create_columns(plans: list, rollbacks: list) -> None:
    """Create the target columns of every MS before any is written, each with the
    :class:`~msleak.io.columns.Rollback` that undoes it (appended to ``rollbacks`` in
    creation order; each is made with the table as the previous column left it)."""
    for plan in plans:
        for target, res in zip(plan.targets, plan.results):
            with colio.open_for_writing(plan.ms) as table:
                rollback = colio.Rollback(table, target.column, plan.total_rows)
                rollbacks.append(rollback)
                plan.rollbacks.append(rollback)
                rollback.created = colio.ensure_data_column(table, target.column)
                res.created_column = rollback.created


def _write_chunks(runner, jobs, plans: list, bar, t_start: float,
                  fail_after_chunks: int | None) -> None:
    """Compute the chunks on ``runner`` and write them in order, updating the run states."""
    chunks_done = 0
    with contextlib.closing(runner.map(_chunk_task, jobs)) as done:
        for job, (vis, timings, n_per_baseline) in done:
            plan = plans[job.plan]
            tick = _time.perf_counter()
            row_time = job.times[job.tidx]
            for k, values in zip(job.active, vis):
                _write_column(plan, k, job, row_time, values)
            del vis
            colio.write_run_state(plan.table, plan.states)
            _add(plan.timings, "write", tick)
            plan.rows_per_baseline += n_per_baseline
            for key, value in timings.items():
                plan.timings[key] = plan.timings.get(key, 0.0) + value
            plan.n_slots += int(job.times.size)
            bar.update(int(job.rows.size))
            chunks_done += 1
            if fail_after_chunks is not None and chunks_done >= fail_after_chunks:
                raise RuntimeError("simulated failure (test hook)")
            if job.last:
                _finish(plan, t_start)


def _write_column(plan: _Plan, k: int, job: _Chunk, row_time: np.ndarray,
                  values: np.ndarray) -> None:
    """Write into target ``k``'s column the rows of ``job`` it does not have yet."""
    column = plan.targets[k].column
    state = plan.states[column]
    last = state["progress"].get(job.key)
    if last is not None and last >= job.times[-1]:
        return  # an interrupted run wrote this column further than the others
    rows = job.rows
    if last is not None and row_time.min() <= last:
        keep = row_time > last
        rows, values = rows[keep], values[keep]
    plan.rollbacks[k].save_rows(plan.table, rows)
    colio.write_rows(plan.table, column, rows, values)
    state["rows_done"] += int(rows.size)
    state["progress"][job.key] = float(job.times[-1])
    state["updated"] = _now()
    plan.results[k].rows_written += int(rows.size)


def _make_plan(ms: Path, targets: list, *, beam, centre_correction, interpolate_frequency,
               dtype, fields, spws, diameter_m) -> _Plan:
    """Read the metadata of ``ms``, select its groups and prepare the skies (no writes)."""
    from msleak.io.ms import (open_table, read_corr_types, read_data_descriptions,
                              read_fields, read_spectral_windows, read_used_antennas)

    fields_meta = read_fields(ms)
    spw_meta = read_spectral_windows(ms)
    ddesc = read_data_descriptions(ms)
    corr_types = read_corr_types(ms)

    with open_table(ms) as table:
        new = [t.column for t in targets if not colio.check_data_column(table, t.column)]
        if len(new) > 1:
            _check_space(table, new)
        field_col = table.getcol("FIELD_ID")
        ddid_col = table.getcol("DATA_DESC_ID")
    field_ids = _select_ids(fields, [f.name for f in fields_meta], "field", field_col)
    spw_present = np.unique([ddesc[d][0] for d in np.unique(ddid_col)])
    spw_ids = _select_ids(spws, [s.name for s in spw_meta], "spectral window", spw_present)
    groups = []
    for f in field_ids:
        for d in sorted(int(x) for x in np.unique(ddid_col[field_col == f])):
            if ddesc[d][0] in spw_ids:
                groups.append((f, d))
    if not groups:
        raise InputError(f"{ms}: no rows match the field / spectral-window selection")
    feeds = {d: correlation_layout(corr_types[ddesc[d][1]]) for _, d in groups}
    for d in sorted({d for _, d in groups if not feeds[d].full}):
        log.warning("%s: data description %d has only the correlations %s; predict computes "
                    "the full coherency and writes those two (the cross hands are not "
                    "stored)", ms, d, ",".join(feeds[d].names))
    total_rows = int(sum(np.count_nonzero((field_col == f) & (ddid_col == d)) for f, d in groups))
    del field_col, ddid_col
    _check_rows(ms, groups)

    # Skies for every field first: input errors (frequency mismatch, FoV) before any write.
    skies: dict[tuple[int, int], SkySet] = {}
    for f, d in groups:
        fmeta, freq = fields_meta[f], spw_meta[ddesc[d][0]].freq
        comps: dict = {}
        for t in targets:
            if (t.sky, t.fov_deg) not in comps:
                comps[(t.sky, t.fov_deg)] = sky_components(
                    t.sky, freq, fmeta.ra, fmeta.dec, fov_deg=t.fov_deg,
                    interpolate=interpolate_frequency)
        skies[(f, d)] = sky_set([comps[(t.sky, t.fov_deg)] for t in targets])
    token = uuid.uuid4().hex
    beam_options = {} if beam == "none" else {"stations": np.unique(np.concatenate(
        [read_used_antennas(ms, f, d) for f, d in groups]))}
    if diameter_m is not None:
        beam_options["diameter_m"] = float(diameter_m)
    with _BEAMS_LOCK:
        _BEAMS[token] = _load_beam(beam, ms, beam_options)

    common = {"beam": beam, "centre_correction": bool(centre_correction and beam != "none"),
              "interpolate_frequency": bool(interpolate_frequency),
              "precision": dtype.name, "groups": [f"f{f}_d{d}" for f, d in groups],
              "diameter_m": -1.0 if diameter_m is None else float(diameter_m),
              "msleak_version": __version__}
    settings = [{"sky": str(t.sky.resolve()), "sky_sha256": t.sha256,
                 "fov_deg": -1.0 if t.fov_deg is None else t.fov_deg, **common}
                for t in targets]
    timings: dict = {}
    return _Plan(ms=ms, fields_meta=fields_meta, spw_meta=spw_meta, ddesc=ddesc,
                 groups=groups, feeds=feeds, total_rows=total_rows, targets=targets,
                 skies=skies, settings=settings,
                 settings_json=[json.dumps(s, sort_keys=True) for s in settings],
                 beam_token=token, beam_options=beam_options, timings=timings,
                 results=[PredictResult(ms=ms, column=t.column, rows_written=0, groups=groups,
                                        timings=timings) for t in targets])


def _check_space(table, columns: list[str]) -> None:
    """Refuse new columns that fit on the disk one by one but not together."""
    cell_bytes = 8 * int(np.prod(table.getcell("DATA", 0).shape)) if table.nrows() else 0
    colio.check_free_space(table.name(), len(columns) * (table.nrows() * cell_bytes
                                                         + 1.1 * 2**20),
                           f"columns {', '.join(columns)}")


def _check_rows(ms: Path, groups: list) -> None:
    """Refuse rows predict cannot compute (TIME or UVW not finite), before any write."""
    from msleak.io.ms import iter_rows

    for f, d in groups:
        for rows, cols in iter_rows(ms, ["TIME", "UVW"], field_id=f, ddid=d,
                                    chunk_rows=1_000_000):
            bad = ~(np.isfinite(cols["TIME"]) & np.isfinite(cols["UVW"]).all(axis=1))
            if bad.any():
                raise InputError(
                    f"{ms}: {int(bad.sum())} rows of field {f}, data description {d} have a "
                    f"TIME or UVW that is not a finite number (first: row {int(rows[bad][0])}); "
                    "delete them first (TaQL: DELETE FROM <ms> WHERE NOT (isfinite(TIME) && "
                    "all(isfinite(UVW)))) or leave that field or spectral window out with "
                    "--field / --spw")


def _start(plan: _Plan, restart: bool, bar) -> None:
    """Open the MS for writing, decide per column (resume, skip, start over) and store the
    run states.

    A run resumes when some column holds an incomplete run with the same settings; its
    columns complete from such a run are then skipped and the others start over. Without
    one (or with ``restart``) every column starts over.
    """
    plan.stack = contextlib.ExitStack()
    table = plan.table = plan.stack.enter_context(colio.open_for_writing(plan.ms))
    old = []
    for target, settings_json in zip(plan.targets, plan.settings_json):
        state = colio.read_run_state(table, target.column)
        old.append(state if state and state.get("settings_json") == settings_json else None)
    resume = not restart and any(s is not None and not bool(s.get("complete", True))
                                 for s in old)
    for k, target in enumerate(plan.targets):
        state = old[k] if resume else None
        if state is not None and bool(state.get("complete", True)):
            plan.results[k].skipped = True
            log.info("%s: %s is complete from an identical run; left as it is", plan.ms,
                     target.column)
            continue
        plan.active.append(k)
        plan.results[k].resumed = state is not None
        if state is not None:
            log.info("%s: resuming an interrupted predict into %s (%d rows done)", plan.ms,
                     target.column, int(state.get("rows_done", 0)))
        plan.states[target.column] = _run_state(plan.settings[k], plan.settings_json[k], state)
    colio.write_run_state(table, plan.states)
    bar.update(min(s["rows_done"] for s in plan.states.values()))


def _run_state(settings: dict, settings_json: str, state: dict | None) -> dict:
    """The run state of a column: fresh, or continuing ``state``."""
    progress = {k: float(v) for k, v in dict(state.get("progress", {})).items()} if state else {}
    return {**settings, "settings_json": settings_json,
            "stokes_convention": STOKES_CONVENTION,
            "phase_convention": "V_pq = sum_s J_p B_s J_q^H exp(+2 pi i (u l + v m + "
                                "w (n - 1))), (u, v, w) = UVW / lambda with UVW = "
                                "antenna2 - antenna1 (MS and DP3 convention)",
            "complete": False,
            "rows_done": int(state.get("rows_done", 0)) if state else 0,
            "progress": progress,
            "started": state.get("started", _now()) if state else _now(),
            "updated": _now()}


def _finish(plan: _Plan, t_start: float) -> None:
    """Mark the run's columns complete and release the MS."""
    now = _now()
    for state in plan.states.values():
        state.update(complete=True, finished=now, updated=now)
    colio.write_run_state(plan.table, plan.states)
    plan.stack.close()
    plan.stack = plan.table = None
    seconds = _time.perf_counter() - t_start
    for k in plan.active:
        res = plan.results[k]
        res.seconds, res.n_slots = seconds, plan.n_slots
        res.rows_per_baseline = plan.rows_per_baseline
        log.info("%s: predicted %d rows into %s in %.1f s (%d per baseline)", plan.ms,
                 res.rows_written, res.column, seconds, res.rows_per_baseline)
    if plan.rows_per_baseline:
        log.warning("%s: %d rows have UVW that are not antenna-based (the per-station "
                    "factorisation would make phase errors above %g rad); they were predicted "
                    "per baseline from their own UVW (exact, slower)", plan.ms,
                    plan.rows_per_baseline, PHASE_TOLERANCE_RAD)


def _all_chunks(plans, memory_per_task, dtype, centre_correction, beam, restart, bar, fault,
                t_start) -> Iterator[_Chunk]:
    """The chunks of every MS in write order; each MS is opened when its turn comes and
    finished right away when nothing is left to predict."""
    index = 0
    for k, plan in enumerate(plans):
        _start(plan, restart, bar)
        previous = None
        for job in _plan_chunks(k, plan, memory_per_task, dtype, centre_correction, beam):
            job.index, job.fault = index, fault
            index += 1
            if previous is not None:
                yield previous
            previous = job
        if previous is None:
            _finish(plan, t_start)
        else:
            previous.last = True
            yield previous


def _plan_chunks(k: int, plan: _Plan, memory_per_task: float, dtype, centre_correction,
                 beam) -> Iterator[_Chunk]:
    """Time chunks of one MS (reads TIME/ANTENNA and each chunk's UVW here, in the driver)."""
    table = plan.table
    for f, d in plan.groups:
        key = f"f{f}_d{d}"
        comp = plan.skies[(f, d)]
        for j in plan.active:
            plan.results[j].n_sources[key] = comp.skies[j].ndir
        fmeta = plan.fields_meta[f]
        freq = plan.spw_meta[plan.ddesc[d][0]].freq
        sel = table.query(f"FIELD_ID=={f} && DATA_DESC_ID=={d}", columns="TIME,ANTENNA1,ANTENNA2")
        try:
            rows_all = np.asarray(sel.rownumbers(table), dtype=np.int64)
            time_all = sel.getcol("TIME")
            a1_all = sel.getcol("ANTENNA1")
            a2_all = sel.getcol("ANTENNA2")
        finally:
            sel.close()
        times = np.unique(time_all)
        lasts = [plan.states[plan.targets[j].column]["progress"].get(key) for j in plan.active]
        if all(last is not None for last in lasts):
            times = times[times > min(lasts)]
        stations = np.unique(np.concatenate([a1_all, a2_all]))
        st_index = np.full(int(stations.max()) + 1, -1, dtype=np.int64)
        st_index[stations] = np.arange(stations.size)
        rows_per_time = int(math.ceil(rows_all.size / max(1, np.unique(time_all).size)))
        nt_chunk, nc_chunk = _chunk_size(plan, comp, times.size, freq.size, stations.size,
                                         rows_per_time, rows_all.size, memory_per_task, dtype,
                                         beam != "none")
        log.info("%s field %d, data description %d: %d sky(s) with %s sources, %d directions "
                 "in all, %d stations, %d times (%d per chunk), %d channels (%d per chunk), "
                 "feeds %s, UVW tolerance %.3g mm (%g rad at %.3f MHz)", plan.ms.name, f, d,
                 len(plan.active), "/".join(str(comp.skies[j].ndir) for j in plan.active),
                 comp.ndir, stations.size, times.size, nt_chunk, freq.size, nc_chunk,
                 plan.feeds[d], 1e3 * uvw_tolerance(freq.max(), comp.lmn1),
                 PHASE_TOLERANCE_RAD, freq.max() / 1e6)
        for t0 in range(0, times.size, nt_chunk):
            tchunk = times[t0:t0 + nt_chunk]
            in_chunk = (time_all >= tchunk[0]) & (time_all <= tchunk[-1])
            rows = rows_all[in_chunk]
            tick = _time.perf_counter()
            uvw = colio.read_rows(table, "UVW", rows)
            _add(plan.timings, "read", tick)
            yield _Chunk(index=0, plan=k, key=key, ms=str(plan.ms), beam=beam,
                         beam_token=plan.beam_token, comp=comp, active=tuple(plan.active),
                         times=tchunk, freq=freq, stations=stations, fmeta=fmeta, rows=rows,
                         tidx=np.searchsorted(tchunk, time_all[in_chunk]),
                         p=st_index[a1_all[in_chunk]], q=st_index[a2_all[in_chunk]], uvw=uvw,
                         centre_correction=centre_correction, dtype=dtype.name,
                         nc_chunk=nc_chunk, layout=plan.feeds[d],
                         beam_options=plan.beam_options)


def _chunk_size(plan: _Plan, comp: SkySet, ntime: int, nchan: int, nstation: int,
                rows_per_time: int, nrows: int, memory_per_task: float, dtype,
                has_beam: bool) -> tuple[int, int]:
    """:func:`plan_chunks` for a group: the skies, the rows' metadata and the kernel's
    scratch memory are the fixed part."""
    ndir_skies = sum(comp.skies[j].ndir for j in plan.active)
    fixed = (comp.nbytes + nrows * 28
             + kernels.scratch_bytes(nstation, comp.ndir, ndir_skies, dtype))
    return plan_chunks(ntime, nchan, nstation, comp.ndir, rows_per_time, memory_per_task,
                       dtype.itemsize, has_beam, fixed, nsky=len(plan.active))


def _chunk_task(job: _Chunk, _shared=None) -> tuple[list, dict, int]:
    """Visibilities (nrow, nchan, ncorr) of one chunk for each sky of ``job.active``, the
    task's stage timings, and the number of rows predicted per baseline (pure computation
    on the job's arrays; the beam model is loaded once per process)."""
    if job.fault is not None:
        _simulate_fault(job)
    beam_model = _cached_beam(job.beam, job.ms, job.beam_token, job.beam_options)
    timings: dict = {}
    vis, n_per_baseline = _predict_chunk(job.comp, beam_model, job.times, job.freq, job.stations, job.fmeta,
                         job.tidx, job.p, job.q, job.uvw, job.centre_correction,
                         np.dtype(job.dtype), job.nc_chunk, timings, job.active)
    for k, values in enumerate(vis):
        if job.layout.feed == "circular":
            values = kernels.linear_to_circular(values)
        vis[k] = job.layout.from_canonical(values)  # the MS's products, in its order
    return vis, timings, n_per_baseline


def _simulate_fault(job: _Chunk) -> None:
    """Test hook: ``fault = (chunk index, marker path or None)`` kills the dask worker
    running that chunk (once if a marker path is given, else every time)."""
    index, marker = job.fault
    if job.index != index or (marker and Path(marker).exists()):
        return
    if marker:
        Path(marker).touch()
    try:
        from distributed import get_worker

        get_worker()
    except (ImportError, ValueError):
        raise RuntimeError("simulated failure (test hook)") from None
    os._exit(70)


def _predict_chunk(comp: SkySet, beam_model, times: np.ndarray, freq: np.ndarray,
                   stations: np.ndarray, fmeta, tidx: np.ndarray, p: np.ndarray, q: np.ndarray,
                   uvw: np.ndarray, centre_correction: bool, dtype: np.dtype,
                   nc_chunk: int, timings: dict, active: Sequence[int] = (0,)
                   ) -> tuple[list, int]:
    """Visibilities (nrow, nchan, 4) of one time chunk (linear feeds) for each sky
    ``comp.skies[k]``, k in ``active``, and the number of rows computed from their own UVW
    (not antenna-based within the tolerance).

    The beam is evaluated once towards every direction of ``comp``. Adds the stage wall
    times to ``timings``.
    """
    tick = _time.perf_counter()
    xyz, off = station_coordinates(tidx, p, q, uvw, times.size, stations.size,
                                   tolerance_m=uvw_tolerance(freq.max(), comp.lmn1))
    fast = np.flatnonzero(~off) if off.any() else slice(None)
    _add(timings, "uvw", tick)
    skies = [(comp.index[k], comp.skies[k]) for k in active]
    outs = [np.empty((tidx.size, freq.size, 4), dtype=dtype) for _ in skies]
    for c0 in range(0, freq.size, nc_chunk):
        c1 = min(freq.size, c0 + nc_chunk)
        tick = _time.perf_counter()
        jones, left = _beam(beam_model, comp, fmeta, times, freq[c0:c1], stations,
                            centre_correction, dtype)
        tick = _add(timings, "beam", tick)
        if not off.all():
            grams = kernels.predict_grams(
                jones, xyz, comp.lmn1, freq[c0:c1],
                [(index, sky.w[:, c0:c1], sky.sign[:, c0:c1]) for index, sky in skies],
                dtype=dtype)
            for out, gram in zip(outs, grams):
                out[fast, c0:c1] = kernels.gather_rows(gram, tidx[fast], p[fast], q[fast],
                                                       jones_left=left)
            del grams
        tick = _add(timings, "kernel", tick)
        if off.any():
            for out, (index, sky) in zip(outs, skies):
                out[off, c0:c1] = predict_rows(
                    None if jones is None else jones[..., index, :, :], tidx[off], p[off],
                    q[off], uvw[off], sky.lmn1, freq[c0:c1], sky.iquv[:, c0:c1],
                    jones_left=left, dtype=dtype)
            _add(timings, "per_baseline", tick)
        del jones
    return outs, int(off.sum())


def _beam(beam_model, comp: SkySet, fmeta, times: np.ndarray, freq: np.ndarray,
          stations: np.ndarray, centre_correction: bool, dtype) -> tuple:
    """Jones (nst, nt, nchan, ndir, 2, 2) towards every direction of ``comp`` and the
    correction J(s0)^-1 (nst, nt, nchan, 2, 2) or None, from one beam call with the phase
    centre appended; (None, None) without a beam or without directions."""
    if beam_model is None or not comp.ndir:
        return None, None
    full = beam_model.jones(times, freq, np.append(comp.ra, fmeta.ra),
                            np.append(comp.dec, fmeta.dec), stations=stations, dtype=dtype)
    left = None
    if centre_correction:
        from msleak.beam.base import invert_2x2

        left, singular = invert_2x2(full[..., -1, :, :].astype(np.complex128))
        if singular.any():
            log.warning("beam at the phase centre is singular for %d station/time/channel "
                        "samples; their corrected visibilities are zero", int(singular.sum()))
    return full[..., :-1, :, :], left


def _add(timings: dict, key: str, since: float) -> float:
    """Add the time since ``since`` to ``timings[key]``; returns now."""
    now = _time.perf_counter()
    timings[key] = timings.get(key, 0.0) + now - since
    return now


class _NoBar:
    def update(self, n: int) -> None:
        pass

    def close(self) -> None:
        pass


def _progress_bar(total: int, enabled: bool | None):
    if enabled is None:
        enabled = sys.stderr.isatty()
    if not enabled:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, unit="row", desc="predict", file=sys.stderr, dynamic_ncols=True)
