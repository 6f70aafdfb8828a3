"""The time chunks of a predict run read from the MS, and the task that predicts one
(docs/predict.md).

:func:`iter_chunks` cuts the selected rows of one MS into time chunks that fit the memory
budget (it reads TIME, ANTENNA1/2 per group and each chunk's UVW, in the driver);
:func:`chunk_task` turns one chunk into visibilities for each sky through
:func:`msleak.predict.chunks.predict_chunk` (pure computation on the chunk's arrays, run on
any scheduler of :mod:`msleak.parallel`), in the MS's feeds and correlation order. The beam
model is loaded once per process (:func:`register_beam`).
"""

from __future__ import annotations

import logging
import math
import threading
import time as _time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from msleak.adapters.beams import load_beam
from msleak.conventions import CorrelationLayout
from msleak.io import columns as colio
from msleak.io.ms import iter_rows, read_used_antennas
from msleak.predict import kernels
from msleak.predict.chunks import add_time, plan_chunks, predict_chunk, direct_block
from msleak.predict.components import SkySet
from msleak.predict.gridsky import (DEGRID_BATCH, DEGRID_PIXEL_BYTES, MIN_PIXEL_BEAM_BYTES,
                                    PIXEL_BEAM_BYTES, PLAN_NSUB)
from msleak.predict.stations import PHASE_TOLERANCE_RAD, uvw_tolerance

__all__ = ["Chunk", "iter_chunks", "chunk_task", "register_beam", "registered_beam"]

log = logging.getLogger(__name__)

_BEAMS: dict = {}
_BEAMS_LOCK = threading.Lock()


@dataclass
class Chunk:
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
    block_bytes: float = PIXEL_BEAM_BYTES
    last: bool = False
    beam_options: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return f"{Path(self.ms).name} {self.key} chunk {self.index}"


def _load_beam(name: str, ms: Path, options: dict | None = None):
    options = dict(options or {})
    if name == "none" and not options.get("ionosphere"):
        return None                    # no Jones matrices at all: the kernels' fast path
    return load_beam(name, ms, **options)


def register_beam(token: str, beam: str, ms: Path, groups: list, beam_options: dict
                  ) -> dict:
    """Load the beam model of the stations in ``groups`` for run ``token`` in this process
    (with the :func:`msleak.adapters.beams.load_beam` options ``beam_options``) and return the
    options that name them (so no worker reads the main table predict writes)."""
    options = dict(beam_options)
    if beam != "none":
        options["stations"] = np.unique(np.concatenate(
            [read_used_antennas(ms, f, d) for f, d in groups]))
    with _BEAMS_LOCK:
        _BEAMS[token] = _load_beam(beam, ms, options)
    return options


def registered_beam(token: str):
    """The beam model :func:`register_beam` loaded for ``token`` in this process (or None)."""
    return _BEAMS.get(token)


def _cached_beam(name: str, ms: str, token: str, options: dict | None = None):
    """The beam model of ``ms`` for run ``token``, loaded once per process (any scheduler)."""
    with _BEAMS_LOCK:
        if token not in _BEAMS:
            while len(_BEAMS) >= 8:
                _BEAMS.pop(next(iter(_BEAMS)))
            _BEAMS[token] = _load_beam(name, Path(ms), options)
        return _BEAMS[token]


def _group_rows(ms: Path, f: int, d: int) -> tuple[np.ndarray, ...]:
    """Row numbers, TIME, ANTENNA1 and ANTENNA2 of the rows of field ``f``, data
    description ``d``."""
    parts = list(iter_rows(ms, ["TIME", "ANTENNA1", "ANTENNA2"], field_id=f, ddid=d,
                           chunk_rows=1_000_000))
    rows = np.concatenate([r for r, _ in parts]).astype(np.int64)
    return (rows, *(np.concatenate([c[name] for _, c in parts])
                    for name in ("TIME", "ANTENNA1", "ANTENNA2")))


def iter_chunks(k: int, run, memory_per_task: float, dtype, centre_correction, beam,
                tasks: int = 1) -> Iterator[Chunk]:
    """Time chunks of run ``k`` (:class:`msleak.verbs.predict_run.Run` of the MS
    ``run.plan.ms``, read through ``run.table``), after the time each active column's run
    state says it has reached; ``tasks`` chunks run at once."""
    plan = run.plan
    for f, d in plan.groups:
        key = f"f{f}_d{d}"
        comp = plan.skies[(f, d)]
        for j in run.active:
            run.results[j].n_sources[key] = comp.skies[j].ndir
        freq = plan.spw_meta[plan.ddesc[d][0]].freq
        rows_all, time_all, a1_all, a2_all = _group_rows(plan.ms, f, d)
        times = np.unique(time_all)
        rows_per_time = int(math.ceil(rows_all.size / max(1, times.size)))
        lasts = [run.states[plan.targets[j].column]["progress"].get(key)
                 for j in run.active] if run.states else [None]
        if all(last is not None for last in lasts):
            times = times[times > min(lasts)]
        stations = np.unique(np.concatenate([a1_all, a2_all]))
        st_index = np.full(int(stations.max()) + 1, -1, dtype=np.int64)
        st_index[stations] = np.arange(stations.size)
        nt_chunk, nc_chunk, block = _chunk_size(run.active, comp, times.size, freq.size,
                                                stations.size, rows_per_time, rows_all.size,
                                                memory_per_task, dtype, beam != "none",
                                                tasks)
        log.info("%s field %d, data description %d: %d sky(s) with %s sources, %d directions "
                 "in all, %d stations, %d times (%d per chunk), %d channels (%d per chunk), "
                 "feeds %s, UVW tolerance %.3g mm (%g rad at %.3f MHz)", plan.ms.name, f, d,
                 len(run.active), "/".join(str(comp.skies[j].ndir) for j in run.active),
                 comp.ndir, stations.size, times.size, nt_chunk, freq.size, nc_chunk,
                 plan.feeds[d], 1e3 * uvw_tolerance(freq.max(), comp.lmn1),
                 PHASE_TOLERANCE_RAD, freq.max() / 1e6)
        for t0 in range(0, times.size, nt_chunk):
            tchunk = times[t0:t0 + nt_chunk]
            in_chunk = (time_all >= tchunk[0]) & (time_all <= tchunk[-1])
            rows = rows_all[in_chunk]
            tick = _time.perf_counter()
            uvw = colio.read_rows(run.table, "UVW", rows)
            add_time(run.timings, "read", tick)
            yield Chunk(index=0, plan=k, key=key, ms=str(plan.ms), beam=beam,
                        beam_token=plan.beam_token, comp=comp, active=tuple(run.active),
                        times=tchunk, freq=freq, stations=stations, fmeta=plan.fields_meta[f],
                        rows=rows, tidx=np.searchsorted(tchunk, time_all[in_chunk]),
                        p=st_index[a1_all[in_chunk]], q=st_index[a2_all[in_chunk]], uvw=uvw,
                        centre_correction=centre_correction, dtype=dtype.name,
                        nc_chunk=nc_chunk, layout=plan.feeds[d], block_bytes=block,
                        beam_options=plan.beam_options)


def _chunk_size(active: list, comp: SkySet, ntime: int, nchan: int, nstation: int,
                rows_per_time: int, nrows: int, memory_per_task: float, dtype,
                has_beam: bool, tasks: int = 1) -> tuple[int, int, int]:
    """:func:`plan_chunks` for a group: the skies, the rows' metadata
    and the kernel's scratch memory are the fixed part; and the bytes of the beam blocks of
    skies summed pixel by pixel (:func:`msleak.predict.chunks.predict_chunk`)."""
    direct = [comp.skies[j] for j in active if not comp.skies[j].own]
    pixel = [comp.skies[j] for j in active if comp.skies[j].grid is not None]
    all_sky = [comp.skies[j] for j in active if comp.skies[j].horizon is not None]
    # a degridded chunk takes complex128 Jones at nsub^2 directions (one copy, built per
    # time), the sky's w-layer grids (DEGRID_PIXEL_BYTES per pixel) and transforms
    # DEGRID_BATCH subgrids at once; a pixel sky summed directly (auto's fallback; rows
    # whose UVW are not antenna-based) takes the beam at a block of its pixels for a few
    # times at once within PIXEL_BEAM_BYTES (_pixel_blocks), and the direct kernel's
    # scratch for that block. An all-sky sky's blocks (_own_blocks, scratch included) take
    # half of what the rest leaves, within [MIN_PIXEL_BEAM_BYTES, PIXEL_BEAM_BYTES], and
    # its chunks keep every channel: the beam's work per direction (coordinates, tile
    # factors) is shared by the channels of one call, so cutting channels would repeat it.
    nsub = max([s.grid.nsub or PLAN_NSUB for s in pixel], default=0)
    widest = max([min(s.ndir, direct_block(nstation, nchan)) for s in pixel
                  if s.grid.auto], default=0)
    fixed = (comp.nbytes + nrows * 28 + 128 * DEGRID_BATCH * nsub ** 2
             + DEGRID_PIXEL_BYTES * max([s.ndir for s in pixel], default=0)
             + (PIXEL_BEAM_BYTES if widest else 0)
             + kernels.scratch_bytes(nstation, max(comp.ndir, widest),
                                     sum(s.ndir for s in direct) + widest, nchan, dtype))
    block = PIXEL_BEAM_BYTES
    if all_sky:
        block = int(min(PIXEL_BEAM_BYTES,
                        max(MIN_PIXEL_BEAM_BYTES, (memory_per_task - fixed) // 2)))
        fixed += block
    return (*plan_chunks(ntime, nchan, nstation, comp.ndir, rows_per_time, memory_per_task,
                         dtype.itemsize, has_beam, fixed, nsky=len(active),
                         long_times=bool(pixel), subgrid_dirs=nsub ** 2, tasks=tasks,
                         whole_channels=bool(all_sky)), block)


def chunk_task(job: Chunk, _shared=None) -> tuple[list, dict, int]:
    """Visibilities (nrow, nchan, ncorr) of one chunk for each sky of ``job.active``, the
    task's stage timings (with, under ``"notes"``, the (sky, line) pairs the writing
    process logs: :func:`_geometry`), and the number of rows predicted per baseline (pure
    computation on the job's arrays; the beam model is loaded once per process)."""
    beam_model = _cached_beam(job.beam, job.ms, job.beam_token, job.beam_options)
    timings: dict = {}
    vis, n_per_baseline = predict_chunk(job.comp, beam_model, job.times, job.freq,
                                        job.stations, job.fmeta, job.tidx, job.p, job.q,
                                        job.uvw, job.centre_correction, np.dtype(job.dtype),
                                        job.nc_chunk, timings, job.active,
                                        job.block_bytes)
    for k, values in enumerate(vis):
        if job.layout.feed == "circular":
            values = kernels.linear_to_circular(values)
        vis[k] = job.layout.from_canonical(values)  # the MS's products, in its order
    return vis, timings, n_per_baseline


