"""The predict run: sky + beam + MS metadata -> visibilities written in time chunks.

For every selected (FIELD_ID, DATA_DESC_ID) group of rows:

1. the sky is read for the field's phase centre (FoV crop), evaluated on the spectral
   window's channels and factorised (:func:`msleak.predict.kernels.brightness_factors`);
2. the group's times are split in chunks that fit ``memory_limit`` (times first, then
   channels when one time slot is too big);
3. per chunk: per-station coordinates from the rows' UVW
   (:func:`msleak.predict.stations.station_coordinates`), beam Jones matrices of the
   stations present towards every source plus the phase centre, the visibility matrices
   (:func:`msleak.predict.kernels.predict_gram`), rows gathered with the phase-centre
   correction J_p(s0)^-1 V_pq J_q(s0)^-H, converted to circular feeds if the MS has
   them, written, and the run state updated and flushed.

The run state (provenance, ``complete`` flag, progress) is the column keyword described in
:mod:`msleak.io.columns`; a rerun with the same settings continues an incomplete run.
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
from msleak.conventions import STOKES_CONVENTION, feed_type_from_corr_types
from msleak.errors import InputError
from msleak.io import columns as colio
from msleak.predict import kernels
from msleak.predict.sky import SkyComponents, sky_components
from msleak.predict.stations import station_coordinates

__all__ = ["predict", "predict_many", "PredictResult", "DEFAULT_MEMORY_LIMIT", "plan_chunks"]

log = logging.getLogger(__name__)

#: Default memory budget of a predict run (bytes).
DEFAULT_MEMORY_LIMIT = 2 * 1024**3


@dataclass
class PredictResult:
    """What a predict run did."""

    ms: Path
    column: str
    rows_written: int
    groups: list = field(default_factory=list)
    resumed: bool = False
    created_column: bool = False
    seconds: float = 0.0
    n_sources: dict = field(default_factory=dict)
    #: wall time (s) per stage: setup (inputs, sky, beam model), uvw, beam, kernel, write
    timings: dict = field(default_factory=dict)
    #: number of time slots predicted
    n_slots: int = 0


def plan_chunks(ntime: int, nchan: int, nstation: int, ndir: int, rows_per_time: int,
                memory_limit: float, itemsize: int, beam: bool,
                fixed_bytes: float = 0.0) -> tuple[int, int]:
    """Times and channels per chunk so that the working set stays under ``memory_limit``.

    The per-(time, channel) estimate counts the beam Jones matrices (complex128 as the
    beam models compute them, the cast copy and one temporary of the same size), the
    visibility matrices, and the gathered and written rows.

    Returns
    -------
    (ntime_chunk, nchan_chunk) : tuple of int, both >= 1
    """
    per_unit = (2 * nstation) ** 2 * itemsize + rows_per_time * 4 * (2 * itemsize + 8)
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


def _load_beam(name: str, ms: Path):
    if name == "none":
        return None
    try:
        from msleak.beam import load_beam
    except ImportError as err:  # pragma: no cover - the beam package is part of msleak
        raise InputError(f"beam model {name!r} is not available ({err})") from err
    return load_beam(name, ms)


_BEAMS: dict = {}
_BEAMS_LOCK = threading.Lock()


def _cached_beam(name: str, ms: str, token: str):
    """The beam model of ``ms`` for run ``token``, loaded once per process (any scheduler)."""
    with _BEAMS_LOCK:
        if token not in _BEAMS:
            while len(_BEAMS) >= 8:
                _BEAMS.pop(next(iter(_BEAMS)))
            _BEAMS[token] = _load_beam(name, Path(ms))
        return _BEAMS[token]


def predict(ms: str | os.PathLike, sky: str | os.PathLike, *, fov_deg: float | None = None,
            beam: str = "everybeam", column: str = "MODEL_DATA",
            centre_correction: bool = True, interpolate_frequency: bool = False,
            double: bool = False, memory_limit: float = DEFAULT_MEMORY_LIMIT,
            overwrite_data: bool = False, fields: Sequence | None = None,
            spws: Sequence | None = None, restart: bool = False,
            progress: bool | None = None, scheduler="sync", workers: int | None = None,
            _fail_after_chunks: int | None = None, _fault: tuple | None = None
            ) -> PredictResult:
    """Predict beam-corrupted visibilities of a sky into a column of a Measurement Set.

    Parameters
    ----------
    ms : path
        The Measurement Set (written in place).
    sky : path
        A FITS cube (one point source per pixel, spectrum = the cube's channels) or a
        makesourcedb text file.
    fov_deg : float, optional
        Keep the central ``fov_deg`` x ``fov_deg`` of the sky (deg).
    beam : {"everybeam", "everybeam-direct", "dipole", "none"}
        Beam model (:func:`msleak.beam.load_beam`).
    column : str
        Target column, created like DATA (tiled) if missing. DATA needs ``overwrite_data``.
    centre_correction : bool
        Remove the beam at the phase centre: V' = J_p(s0)^-1 V J_q(s0)^-H (method.md 4).
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
    PredictResult
    """
    return predict_many([ms], sky, fov_deg=fov_deg, beam=beam, column=column,
                        centre_correction=centre_correction,
                        interpolate_frequency=interpolate_frequency, double=double,
                        memory_limit=memory_limit, overwrite_data=overwrite_data,
                        fields=fields, spws=spws, restart=restart, progress=progress,
                        scheduler=scheduler, workers=workers,
                        _fail_after_chunks=_fail_after_chunks, _fault=_fault)[0]


@dataclass
class _Plan:
    """What to predict into one MS, and its run state while it is being written."""

    ms: Path
    fields_meta: list
    spw_meta: list
    ddesc: list
    groups: list
    feeds: dict
    total_rows: int
    skies: dict
    settings: dict
    settings_json: str
    beam_token: str
    result: PredictResult
    stack: contextlib.ExitStack | None = None
    table: object = None
    run_state: dict | None = None
    progress_done: dict = field(default_factory=dict)


@dataclass
class _Chunk:
    """One time chunk of one (field, data description) of one MS: the input of a task."""

    index: int
    plan: int
    key: str
    ms: str
    beam: str
    beam_token: str
    comp: SkyComponents
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
    circular: bool
    last: bool = False
    fault: tuple | None = None

    @property
    def name(self) -> str:
        return f"{Path(self.ms).name} {self.key} chunk {self.index}"


def predict_many(ms_list: Sequence[str | os.PathLike], sky: str | os.PathLike, *,
                 fov_deg: float | None = None, beam: str = "everybeam",
                 column: str = "MODEL_DATA", centre_correction: bool = True,
                 interpolate_frequency: bool = False, double: bool = False,
                 memory_limit: float = DEFAULT_MEMORY_LIMIT, overwrite_data: bool = False,
                 fields: Sequence | None = None, spws: Sequence | None = None,
                 restart: bool = False, progress: bool | None = None, scheduler="sync",
                 workers: int | None = None, _fail_after_chunks: int | None = None,
                 _fault: tuple | None = None) -> list[PredictResult]:
    """:func:`predict` into each of several Measurement Sets (e.g. one per subband).

    Every MS is checked and its sky prepared before anything is written; the time
    chunks of all MSs are then computed on ``scheduler`` and written by this process,
    MS after MS, in time order (so the resume markers stay exact). Options as
    :func:`predict`; returns one :class:`PredictResult` per MS, in the order given.
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
    sky = Path(sky)
    colio.check_column_name(column, overwrite_data=overwrite_data)
    if not sky.exists():
        raise InputError(f"sky file {sky} does not exist")
    if fov_deg is not None and not (0 < fov_deg <= 180):
        raise InputError(f"--fov must be in (0, 180] deg, got {fov_deg}")
    if memory_limit <= 0:
        raise InputError("--memory-limit must be positive")
    for p in paths:
        colio.check_writable(p)
        colio.repair_interrupted(p)  # header files a killed run may have truncated
    dtype = np.dtype(np.complex128 if double else np.complex64)
    sky_sha = _sha256(sky)
    opts = dict(fov_deg=fov_deg, beam=beam, centre_correction=centre_correction,
                interpolate_frequency=interpolate_frequency, dtype=dtype, fields=fields,
                spws=spws, column=column)
    plans = [_make_plan(p, sky, sky_sha, **opts) for p in paths]

    with open_runner(scheduler, workers, memory_limit) as runner:
        if runner.kind in ("processes", "distributed"):
            for plan in plans:
                model = _BEAMS.get(plan.beam_token)
                if type(model).__name__ == "EveryBeamDirect":
                    raise InputError("--beam everybeam-direct reads the MS main table, which "
                                     "stays locked while predict writes it; use --scheduler "
                                     "threads or sync")
        for plan in plans:  # create the columns first: no error after the first write
            with colio.open_for_writing(plan.ms) as table:
                plan.result.created_column = colio.ensure_data_column(table, column)
        setup = _time.perf_counter() - t_start
        for plan in plans:
            plan.result.timings["setup"] = setup
        bar = _progress_bar(sum(p.total_rows for p in plans), progress)
        jobs = _all_chunks(plans, runner.memory_per_task, dtype, centre_correction, beam,
                           column, restart, bar, _fault, t_start)
        chunks_done = 0
        try:
            with contextlib.closing(runner.map(_chunk_task, jobs)) as done:
                for job, (vis, timings) in done:
                    plan = plans[job.plan]
                    res = plan.result
                    tick = _time.perf_counter()
                    colio.write_rows(plan.table, column, job.rows, vis)
                    del vis
                    state = plan.run_state
                    state["rows_done"] += int(job.rows.size)
                    state["progress"][job.key] = float(job.times[-1])
                    state["updated"] = _now()
                    colio.write_run_state(plan.table, column, state)
                    _add(res.timings, "write", tick)
                    for key, value in timings.items():
                        res.timings[key] = res.timings.get(key, 0.0) + value
                    res.n_slots += int(job.times.size)
                    res.rows_written += int(job.rows.size)
                    bar.update(int(job.rows.size))
                    chunks_done += 1
                    if _fail_after_chunks is not None and chunks_done >= _fail_after_chunks:
                        raise RuntimeError("simulated failure (test hook)")
                    if job.last:
                        _finish(plan, column, t_start)
        finally:
            bar.close()
            for plan in plans:
                if plan.stack is not None:
                    plan.stack.close()
                    plan.stack = None
    return [plan.result for plan in plans]


def _make_plan(ms: Path, sky: Path, sky_sha: str, *, fov_deg, beam, centre_correction,
               interpolate_frequency, dtype, fields, spws, column) -> _Plan:
    """Read the metadata of ``ms``, select its groups and prepare the sky (no writes)."""
    from msleak.io.ms import (open_table, read_corr_types, read_data_descriptions,
                              read_fields, read_spectral_windows)

    fields_meta = read_fields(ms)
    spw_meta = read_spectral_windows(ms)
    ddesc = read_data_descriptions(ms)
    corr_types = read_corr_types(ms)

    with open_table(ms) as table:
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
    feeds = {d: feed_type_from_corr_types(corr_types[ddesc[d][1]]) for _, d in groups}
    total_rows = int(sum(np.count_nonzero((field_col == f) & (ddid_col == d)) for f, d in groups))
    del field_col, ddid_col

    # Sky for every field first: input errors (frequency mismatch, FoV) before any write.
    skies: dict[tuple[int, int], SkyComponents] = {}
    for f, d in groups:
        fmeta = fields_meta[f]
        skies[(f, d)] = sky_components(sky, spw_meta[ddesc[d][0]].freq, fmeta.ra, fmeta.dec,
                                       fov_deg=fov_deg, interpolate=interpolate_frequency)
    token = uuid.uuid4().hex
    with _BEAMS_LOCK:
        _BEAMS[token] = _load_beam(beam, ms)

    settings = {"sky": str(sky.resolve()), "sky_sha256": sky_sha,
                "fov_deg": -1.0 if fov_deg is None else float(fov_deg), "beam": beam,
                "centre_correction": bool(centre_correction and beam != "none"),
                "interpolate_frequency": bool(interpolate_frequency),
                "precision": dtype.name, "groups": [f"f{f}_d{d}" for f, d in groups],
                "msleak_version": __version__}
    return _Plan(ms=ms, fields_meta=fields_meta, spw_meta=spw_meta, ddesc=ddesc,
                 groups=groups, feeds=feeds, total_rows=total_rows, skies=skies,
                 settings=settings, settings_json=json.dumps(settings, sort_keys=True),
                 beam_token=token,
                 result=PredictResult(ms=ms, column=column, rows_written=0, groups=groups))


def _start(plan: _Plan, column: str, restart: bool, bar) -> None:
    """Open the MS for writing, decide resume or restart, and store the run state."""
    plan.stack = contextlib.ExitStack()
    table = plan.table = plan.stack.enter_context(colio.open_for_writing(plan.ms))
    colio.ensure_data_column(table, column)
    state = colio.read_run_state(table, column)
    if (state and not restart and not bool(state.get("complete", True))
            and state.get("settings_json") == plan.settings_json):
        plan.progress_done = {k: float(v) for k, v in dict(state.get("progress", {})).items()}
        plan.result.resumed = True
        log.info("%s: resuming an interrupted predict into %s (%d rows done)", plan.ms, column,
                 int(state.get("rows_done", 0)))
    else:
        state = None
    plan.run_state = {**plan.settings, "settings_json": plan.settings_json,
                      "stokes_convention": STOKES_CONVENTION,
                      "phase_convention": "V_pq = sum_s J_p B_s J_q^H exp(+2 pi i (u l + v m + "
                                          "w (n - 1))), (u, v, w) = UVW / lambda with UVW = "
                                          "antenna2 - antenna1 (MS and DP3 convention)",
                      "complete": False,
                      "rows_done": int(state.get("rows_done", 0)) if state else 0,
                      "progress": dict(plan.progress_done),
                      "started": state.get("started", _now()) if state else _now(),
                      "updated": _now()}
    colio.write_run_state(table, column, plan.run_state)
    if plan.result.resumed:
        bar.update(plan.run_state["rows_done"])


def _finish(plan: _Plan, column: str, t_start: float) -> None:
    """Mark the column complete and release the MS."""
    state = plan.run_state
    state["complete"] = True
    state["finished"] = _now()
    state["updated"] = state["finished"]
    colio.write_run_state(plan.table, column, state)
    plan.stack.close()
    plan.stack = plan.table = None
    res = plan.result
    res.seconds = _time.perf_counter() - t_start
    log.info("%s: predicted %d rows into %s in %.1f s", plan.ms, res.rows_written, column,
             res.seconds)


def _all_chunks(plans, memory_per_task, dtype, centre_correction, beam, column, restart,
                bar, fault, t_start) -> Iterator[_Chunk]:
    """The chunks of every MS in write order; each MS is opened when its turn comes and
    finished right away when nothing is left to predict."""
    index = 0
    for k, plan in enumerate(plans):
        _start(plan, column, restart, bar)
        previous = None
        for job in _plan_chunks(k, plan, memory_per_task, dtype, centre_correction, beam):
            job.index, job.fault = index, fault
            index += 1
            if previous is not None:
                yield previous
            previous = job
        if previous is None:
            _finish(plan, column, t_start)
        else:
            previous.last = True
            yield previous


def _plan_chunks(k: int, plan: _Plan, memory_per_task: float, dtype, centre_correction,
                 beam) -> Iterator[_Chunk]:
    """Time chunks of one MS (reads TIME/ANTENNA and each chunk's UVW here, in the driver)."""
    table, res = plan.table, plan.result
    has_beam = beam != "none"
    for f, d in plan.groups:
        key = f"f{f}_d{d}"
        comp = plan.skies[(f, d)]
        res.n_sources[key] = comp.ndir
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
        last = plan.progress_done.get(key)
        if last is not None:
            times = times[times > last]
        stations = np.unique(np.concatenate([a1_all, a2_all]))
        st_index = np.full(int(stations.max()) + 1, -1, dtype=np.int64)
        st_index[stations] = np.arange(stations.size)
        rows_per_time = int(math.ceil(rows_all.size / max(1, np.unique(time_all).size)))
        fixed = comp.nbytes + rows_all.size * 28
        nt_chunk, nc_chunk = plan_chunks(times.size, freq.size, stations.size, comp.ndir,
                                         rows_per_time, memory_per_task, dtype.itemsize,
                                         has_beam, fixed)
        log.info("%s field %d, data description %d: %d sources, %d stations, %d times "
                 "(%d per chunk), %d channels (%d per chunk), feeds %s", plan.ms.name, f, d,
                 comp.ndir, stations.size, times.size, nt_chunk, freq.size, nc_chunk,
                 plan.feeds[d])
        for t0 in range(0, times.size, nt_chunk):
            tchunk = times[t0:t0 + nt_chunk]
            in_chunk = (time_all >= tchunk[0]) & (time_all <= tchunk[-1])
            rows = rows_all[in_chunk]
            tick = _time.perf_counter()
            uvw = colio.read_rows(table, "UVW", rows)
            _add(res.timings, "read", tick)
            yield _Chunk(index=0, plan=k, key=key, ms=str(plan.ms), beam=beam,
                         beam_token=plan.beam_token, comp=comp, times=tchunk, freq=freq,
                         stations=stations, fmeta=fmeta, rows=rows,
                         tidx=np.searchsorted(tchunk, time_all[in_chunk]),
                         p=st_index[a1_all[in_chunk]], q=st_index[a2_all[in_chunk]], uvw=uvw,
                         centre_correction=centre_correction, dtype=dtype.name,
                         nc_chunk=nc_chunk, circular=plan.feeds[d] == "circular")


def _chunk_task(job: _Chunk, _shared=None) -> tuple[np.ndarray, dict]:
    """Visibilities (nrow, nchan, 4) of one chunk and the task's stage timings (pure
    computation on the job's arrays; the beam model is loaded once per process)."""
    if job.fault is not None:
        _simulate_fault(job)
    beam_model = _cached_beam(job.beam, job.ms, job.beam_token)
    timings: dict = {}
    vis = _predict_chunk(job.comp, beam_model, job.times, job.freq, job.stations, job.fmeta,
                         job.tidx, job.p, job.q, job.uvw, job.centre_correction,
                         np.dtype(job.dtype), job.nc_chunk, timings)
    if job.circular:
        vis = kernels.linear_to_circular(vis)
    return vis, timings


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


def _predict_chunk(comp: SkyComponents, beam_model, times: np.ndarray, freq: np.ndarray,
                   stations: np.ndarray, fmeta, tidx: np.ndarray, p: np.ndarray, q: np.ndarray,
                   uvw: np.ndarray, centre_correction: bool, dtype: np.dtype,
                   nc_chunk: int, timings: dict) -> np.ndarray:
    """Visibilities (nrow, nchan, 4) of one time chunk (linear feeds)."""
    tick = _time.perf_counter()
    xyz = station_coordinates(tidx, p, q, uvw, times.size, stations.size)
    _add(timings, "uvw", tick)
    out = np.empty((tidx.size, freq.size, 4), dtype=dtype)
    for c0 in range(0, freq.size, nc_chunk):
        c1 = min(freq.size, c0 + nc_chunk)
        jones = left = None
        tick = _time.perf_counter()
        if beam_model is not None and comp.ndir:
            ra = np.append(comp.ra, fmeta.ra)
            dec = np.append(comp.dec, fmeta.dec)
            full = beam_model.jones(times, freq[c0:c1], ra, dec, stations=stations,
                                    dtype=dtype)
            jones = full[..., :-1, :, :]
            if centre_correction:
                from msleak.beam.base import invert_2x2

                left, singular = invert_2x2(full[..., -1, :, :].astype(np.complex128))
                if singular.any():
                    log.warning("beam at the phase centre is singular for %d station/time/"
                                "channel samples; their corrected visibilities are zero",
                                int(singular.sum()))
        tick = _add(timings, "beam", tick)
        gram = kernels.predict_gram(jones, xyz, comp.lmn1, freq[c0:c1], comp.w[:, c0:c1],
                                    comp.sign[:, c0:c1], dtype=dtype)
        del jones
        out[:, c0:c1] = kernels.gather_rows(gram, tidx, p, q, jones_left=left)
        _add(timings, "kernel", tick)
    return out


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
