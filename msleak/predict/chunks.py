"""The time chunks of a predict run: what a task gets, and the task itself (docs/predict.md).

:func:`iter_chunks` cuts the selected rows of one MS into time chunks that fit the memory
budget (it reads TIME, ANTENNA1/2 per group and each chunk's UVW, in the driver);
:func:`chunk_task` turns one chunk into visibilities for each sky (pure computation on
the chunk's arrays, run on any scheduler of :mod:`msleak.parallel`): per-station
coordinates from the rows' UVW, the beam towards every direction of the skies plus the
phase centre (once for all skies), the visibility matrices of every sky, rows gathered
with the phase-centre correction, rows whose UVW are not antenna-based summed from their
own UVW (:mod:`msleak.predict.baselines`), circular feeds and the MS's correlation order.
"""

from __future__ import annotations

import logging
import math
import threading
import time as _time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from msleak.adapters.beams import load_beam
from msleak.beam.base import JonesFactors, centre_inverse
from msleak.conventions import CorrelationLayout
from msleak.io import columns as colio
from msleak.io.ms import iter_rows, read_used_antennas
from msleak.predict import kernels
from msleak.predict.baselines import predict_rows
from msleak.predict.components import SkySet
from msleak.errors import InputError
from msleak.predict.gridsky import (DEGRID_BATCH, DEGRID_PIXEL_BYTES,
                                   PIXEL_BEAM_BYTES, PLAN_NSUB, degrid_geometry,
                                   degrid_visibilities, worth_degridding, zenith_near)
from msleak.predict.stations import PHASE_TOLERANCE_RAD, station_coordinates, uvw_tolerance

__all__ = ["Chunk", "iter_chunks", "chunk_task", "register_beam", "add_time", "plan_chunks"]

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
    last: bool = False
    beam_options: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return f"{Path(self.ms).name} {self.key} chunk {self.index}"


#: channels per chunk a degridded sky's long chunks keep at least (:func:`plan_chunks`)
LONG_CHANNELS = 8


def plan_chunks(ntime: int, nchan: int, nstation: int, ndir: int, rows_per_time: int,
                memory_limit: float, itemsize: int, beam: bool,
                fixed_bytes: float = 0.0, nsky: int = 1, long_times: bool = False,
                subgrid_dirs: int = 0, tasks: int = 1) -> tuple[int, int]:
    """Times and channels per chunk so that the working set stays under ``memory_limit``.

    All channels and as many times as fit; with ``long_times`` (a degridded sky, whose
    w-layer FFTs are done once per chunk and channel) all times and as many channels as
    fit, but at least :data:`LONG_CHANNELS` channels (fewer times) while memory allows,
    since a beam model evaluates channels together more cheaply than one by one, and at
    most ntime / ``tasks`` times, so that the ``tasks`` chunks run at once all have work.

    The per-(time, channel) estimate counts the beam Jones matrices towards the ``ndir``
    directions of all skies (complex128 as the beam models compute them, the cast copy
    and one temporary of the same size), those towards the ``subgrid_dirs`` directions of
    degridded skies (one complex128 copy, 80 bytes per station and direction) and, for
    each of the ``nsky`` skies, its visibility matrices and its gathered and written rows.

    Returns
    -------
    (ntime_chunk, nchan_chunk) : tuple of int, both >= 1
    """
    per_unit = nsky * ((2 * nstation) ** 2 * itemsize + rows_per_time * 4 * (2 * itemsize + 8))
    if beam:
        per_unit += nstation * (ndir + 1) * 4 * (2 * 16 + itemsize)
        per_unit += nstation * subgrid_dirs * 80  # degrid's complex128 Jones, built per time
    avail = memory_limit - fixed_bytes
    units = int(avail // per_unit) if avail > 0 else 0
    if units < 1:
        log.warning("memory limit %.0f MB is too small for one time slot and channel "
                    "(needs about %.0f MB); going ahead with that", memory_limit / 2**20,
                    (per_unit + fixed_bytes) / 2**20)
        return 1, 1
    if long_times:
        least = min(nchan, LONG_CHANNELS)
        most = -(-ntime // max(1, tasks))
        if units >= most * least:
            return most, min(nchan, units // most)
        return (units // least, least) if units >= least else (1, units)
    if units >= nchan:
        return max(1, min(ntime, units // nchan)), nchan
    return 1, units


def _load_beam(name: str, ms: Path, options: dict | None = None):
    if name == "none":
        return None
    return load_beam(name, ms, **(options or {}))


def register_beam(token: str, beam: str, ms: Path, groups: list, beam_options: dict
                  ) -> dict:
    """Load the beam model of the stations in ``groups`` for run ``token`` in this process
    (with the :func:`msleak.beam.load_beam` options ``beam_options``) and return the
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


def iter_chunks(k: int, plan, memory_per_task: float, dtype, centre_correction, beam,
                tasks: int = 1) -> Iterator[Chunk]:
    """Time chunks of plan ``k`` (the MS ``plan.ms``, read through ``plan.table``), after
    the time each active column's run state says it has reached; ``tasks`` chunks run at
    once."""
    for f, d in plan.groups:
        key = f"f{f}_d{d}"
        comp = plan.skies[(f, d)]
        for j in plan.active:
            plan.results[j].n_sources[key] = comp.skies[j].ndir
        freq = plan.spw_meta[plan.ddesc[d][0]].freq
        rows_all, time_all, a1_all, a2_all = _group_rows(plan.ms, f, d)
        times = np.unique(time_all)
        rows_per_time = int(math.ceil(rows_all.size / max(1, times.size)))
        lasts = [plan.states[plan.targets[j].column]["progress"].get(key)
                 for j in plan.active] if plan.states else [None]
        if all(last is not None for last in lasts):
            times = times[times > min(lasts)]
        stations = np.unique(np.concatenate([a1_all, a2_all]))
        st_index = np.full(int(stations.max()) + 1, -1, dtype=np.int64)
        st_index[stations] = np.arange(stations.size)
        nt_chunk, nc_chunk = _chunk_size(plan, comp, times.size, freq.size, stations.size,
                                         rows_per_time, rows_all.size, memory_per_task, dtype,
                                         beam != "none", tasks)
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
            uvw = colio.read_rows(plan.table, "UVW", rows)
            add_time(plan.timings, "read", tick)
            yield Chunk(index=0, plan=k, key=key, ms=str(plan.ms), beam=beam,
                        beam_token=plan.beam_token, comp=comp, active=tuple(plan.active),
                        times=tchunk, freq=freq, stations=stations, fmeta=plan.fields_meta[f],
                        rows=rows, tidx=np.searchsorted(tchunk, time_all[in_chunk]),
                        p=st_index[a1_all[in_chunk]], q=st_index[a2_all[in_chunk]], uvw=uvw,
                        centre_correction=centre_correction, dtype=dtype.name,
                        nc_chunk=nc_chunk, layout=plan.feeds[d],
                        beam_options=plan.beam_options)


def _chunk_size(plan, comp: SkySet, ntime: int, nchan: int, nstation: int,
                rows_per_time: int, nrows: int, memory_per_task: float, dtype,
                has_beam: bool, tasks: int = 1) -> tuple[int, int]:
    """:func:`plan_chunks` for a group: the skies, the rows' metadata
    and the kernel's scratch memory are the fixed part."""
    direct = [comp.skies[j] for j in plan.active if comp.skies[j].grid is None]
    pixel = [comp.skies[j] for j in plan.active if comp.skies[j].grid is not None]
    # a degridded chunk takes complex128 Jones at nsub^2 directions (one copy, built per
    # time), the sky's w-layer grids (DEGRID_PIXEL_BYTES per pixel) and transforms
    # DEGRID_BATCH subgrids at once; a pixel sky summed directly (auto's
    # fallback; rows whose UVW are not antenna-based) takes the beam at a block of its
    # pixels for a few times at once within PIXEL_BEAM_BYTES (_pixel_blocks), and the
    # direct kernel's scratch for that block
    nsub = max([s.grid.nsub or PLAN_NSUB for s in pixel], default=0)
    widest = max([min(s.ndir, _direct_block(nstation, nchan)) for s in pixel
                  if s.grid.auto], default=0)
    fixed = (comp.nbytes + nrows * 28 + 128 * DEGRID_BATCH * nsub ** 2
             + DEGRID_PIXEL_BYTES * max([s.ndir for s in pixel], default=0)
             + (PIXEL_BEAM_BYTES if widest else 0)
             + kernels.scratch_bytes(nstation, max(comp.ndir, widest),
                                     sum(s.ndir for s in direct) + widest, nchan, dtype))
    return plan_chunks(ntime, nchan, nstation, comp.ndir, rows_per_time, memory_per_task,
                       dtype.itemsize, has_beam, fixed, nsky=len(plan.active),
                       long_times=bool(pixel), subgrid_dirs=nsub ** 2, tasks=tasks)


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
                                        job.nc_chunk, timings, job.active)
    for k, values in enumerate(vis):
        if job.layout.feed == "circular":
            values = kernels.linear_to_circular(values)
        vis[k] = job.layout.from_canonical(values)  # the MS's products, in its order
    return vis, timings, n_per_baseline


def predict_chunk(comp: SkySet, beam_model, times: np.ndarray, freq: np.ndarray,
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
    skies = [(comp.index[k], comp.skies[k]) for k in active]
    reach = np.concatenate([comp.lmn1] + [sky.lmn1 for _, sky in skies if sky.grid])
    xyz, off = station_coordinates(tidx, p, q, uvw, times.size, stations.size,
                                   tolerance_m=uvw_tolerance(freq.max(), reach))
    fast = np.flatnonzero(~off) if off.any() else slice(None)
    add_time(timings, "uvw", tick)
    rows = (tidx[fast], p[fast], q[fast])
    plans = [_geometry(sky.grid, beam_model, times, freq, stations, centre_correction)
             if sky.grid is not None and not off.all() else (None, None, "")
             for _, sky in skies]
    geometry, near = [g for g, _, _ in plans], [n for _, n, _ in plans]
    notes = [(k, note) for k, (_, _, note) in zip(active, plans) if note]
    if notes:  # reported once per sky by the process that writes (engine)
        timings.setdefault("notes", []).extend(notes)
    use_degrid = [g is not None and worth_degridding(sky.grid, g, xyz, *rows, freq)
                  for g, (_, sky) in zip(geometry, skies)]
    direct = [(index, sky) for index, sky in skies if sky.grid is None]
    outs = [np.empty((tidx.size, freq.size, 4), dtype=dtype) for _ in skies]
    for c0 in range(0, freq.size, nc_chunk):
        c1 = min(freq.size, c0 + nc_chunk)
        tick = _time.perf_counter()
        jones, left = _beam(beam_model, comp, fmeta, times, freq[c0:c1], stations,
                            centre_correction, dtype)
        tick = add_time(timings, "beam", tick)
        if not off.all() and direct:
            grams = iter(kernels.predict_grams(
                jones, xyz, comp.lmn1, freq[c0:c1],
                [(index, sky.w[:, c0:c1], sky.sign[:, c0:c1]) for index, sky in direct],
                dtype=dtype))
            for out, (_, sky) in zip(outs, skies):
                if sky.grid is None:
                    out[fast, c0:c1] = kernels.gather_rows(next(grams), tidx[fast], p[fast],
                                                           q[fast], jones_left=left)
            del grams
        tick = add_time(timings, "kernel", tick)
        for out, (_, sky), use, geom, close in zip(outs, skies, use_degrid, geometry, near):
            if sky.grid is not None and not off.all():
                out[fast, c0:c1] = _pixel_sky(sky, geom if use else None, close, beam_model,
                                              fmeta, times, slice(c0, c1), freq, stations,
                                              xyz, rows, centre_correction, dtype)
        tick = add_time(timings, "degrid", tick)
        if off.any():
            for out, (index, sky) in zip(outs, skies):
                if sky.grid is None:
                    out[off, c0:c1] = predict_rows(
                        _directions_jones(jones, index), tidx[off], p[off], q[off], uvw[off],
                        sky.lmn1, freq[c0:c1], sky.iquv[:, c0:c1], jones_left=left,
                        dtype=dtype)
                    continue
                rows_off = np.flatnonzero(off)
                out[rows_off, c0:c1] = 0
                for t0, t1, part, sky_jones, sky_left in _pixel_blocks(
                        sky, beam_model, fmeta, times, freq[c0:c1], stations,
                        centre_correction, dtype):
                    sel = rows_off[(tidx[rows_off] >= t0) & (tidx[rows_off] < t1)]
                    out[sel, c0:c1] += predict_rows(
                        _directions_jones(sky_jones, np.arange(part.ndir)), tidx[sel] - t0,
                        p[sel], q[sel], uvw[sel], part.lmn1, freq[c0:c1],
                        part.iquv[:, c0:c1], jones_left=sky_left, dtype=dtype)
            add_time(timings, "per_baseline", tick)
        del jones
    return outs, int(off.sum())


def _geometry(grid, beam_model, times, freq, stations, centre_correction) -> tuple:
    """(:class:`Geometry` or None, ``near`` or None, note) of a degridded sky for one chunk
    (:func:`msleak.predict.gridsky.degrid_geometry`). With ``method="auto"`` a beam that
    cannot be degridded does not refuse: the times ``near`` (bool, ntime) at which the
    zenith is over the padded field are summed directly and the others degridded if the
    beam allows it there, else (geometry None) the whole chunk is summed directly; the
    note (one line, else "") says which and why."""
    try:
        return degrid_geometry(grid, beam_model, times, freq, stations,
                               centre_correction), None, ""
    except InputError as err:
        if not grid.auto:
            raise
        reason = getattr(err, "reason", str(err))
    near = zenith_near(grid, times)
    result, what = (None, None), "predicted directly"
    if near is not None and near.any() and not near.all():
        try:
            result = (degrid_geometry(grid, beam_model, times[~near], freq, stations,
                                      centre_correction), near)
            what = (f"{int(near.sum())} of {near.size} times, those with the zenith over the "
                    "field, predicted directly")
        except InputError:
            pass
    return (*result, f"degrid {grid.npix} x {grid.npix} pixels: {reason}; {what} "
                     "(--method auto)")


def _pixel_sky(sky, geometry, near, beam_model, fmeta, times: np.ndarray,
               channels: slice, freq: np.ndarray, stations: np.ndarray, xyz: np.ndarray,
               rows: tuple, centre_correction: bool, dtype) -> np.ndarray:
    """Visibilities (nrow, nchan, 4) of the antenna-based ``rows`` (tidx, p, q) for a sky
    with a pixel grid, on ``freq[channels]``: degridded with ``geometry``, except the rows
    of the times ``near`` (bool, ntime, or None: no time), which, like every row when
    ``geometry`` is None (a chunk where degridding costs more or cannot hold the leakage),
    are summed directly with their own beam."""
    tidx, p, q = rows
    if not geometry:
        return _pixel_direct(sky, beam_model, fmeta, times, channels, freq, stations, xyz,
                             rows, centre_correction, dtype)
    if near is None:
        return degrid_visibilities(sky.grid, geometry, channels, beam_model, times,
                                   freq[channels], stations, xyz, *rows, centre_correction)
    out = np.empty((tidx.size, freq[channels].size, 4), dtype=dtype)
    direct = near[tidx]
    far = np.flatnonzero(~direct)
    out[far] = degrid_visibilities(sky.grid, geometry, channels, beam_model, times,
                                   freq[channels], stations, xyz, tidx[far], p[far], q[far],
                                   centre_correction)
    close = np.flatnonzero(direct)
    keep = np.flatnonzero(near)                   # the near times, renumbered 0..
    renumber = np.cumsum(near) - 1
    out[close] = _pixel_direct(sky, beam_model, fmeta, times[keep], channels, freq,
                               stations, xyz[keep], (renumber[tidx[close]], p[close],
                                                     q[close]), centre_correction, dtype)
    return out


def _pixel_direct(sky, beam_model, fmeta, times, channels, freq, stations, xyz, rows,
                  centre_correction, dtype) -> np.ndarray:
    """:func:`_pixel_sky`'s direct sum over every pixel of ``rows`` (tidx, p, q)."""
    tidx, p, q = rows
    out = np.zeros((tidx.size, freq[channels].size, 4), dtype=dtype)
    for t0, t1, part, jones, left in _pixel_blocks(sky, beam_model, fmeta, times,
                                                   freq[channels], stations,
                                                   centre_correction, dtype):
        grams = kernels.predict_grams(jones, xyz[t0:t1], part.lmn1, freq[channels],
                                      [(np.arange(part.ndir), part.w[:, channels],
                                        part.sign[:, channels])], dtype=dtype)
        sel = np.flatnonzero((tidx >= t0) & (tidx < t1))
        out[sel] += kernels.gather_rows(grams[0], tidx[sel] - t0, p[sel], q[sel],
                                        jones_left=left)
    return out


#: bytes of the beam per direction, station and channel while a pixel sky is summed
#: directly (three complex128 copies of a 2 x 2 matrix)
_PIXEL_BEAM_ENTRY = 3 * 16 * 4


def _direct_block(nstation: int, nchan: int) -> int:
    """Pixels whose beam for one time fits :data:`PIXEL_BEAM_BYTES` (at least 1)."""
    return max(1, int(PIXEL_BEAM_BYTES // (_PIXEL_BEAM_ENTRY * max(1, nstation * nchan))) - 1)


def _pixel_blocks(sky, beam_model, fmeta, times: np.ndarray, freq: np.ndarray,
                  stations: np.ndarray, centre_correction: bool, dtype) -> Iterator:
    """(t0, t1, part, Jones, correction): :func:`_beam` towards the pixels ``part`` (a
    :class:`SkyComponents` of a block of the sky's pixels, or the sky) for times
    t0..t1-1, each within :data:`PIXEL_BEAM_BYTES`, so that a long chunk planned for
    degridding never holds the beam at every pixel for all its times; the visibilities of
    the parts add up to the sky's."""
    size = _direct_block(stations.size, freq.size)
    parts = [sky] if size >= sky.ndir else [
        replace(sky, ra=sky.ra[i:i + size], dec=sky.dec[i:i + size],
                lmn1=sky.lmn1[i:i + size], iquv=sky.iquv[i:i + size], w=sky.w[i:i + size],
                sign=sky.sign[i:i + size], grid=None) for i in range(0, sky.ndir, size)]
    for part in parts:
        per_time = _PIXEL_BEAM_ENTRY * stations.size * (part.ndir + 1) * freq.size
        block = max(1, int(PIXEL_BEAM_BYTES // max(1, per_time)))
        for t0 in range(0, times.size, block):
            t1 = min(times.size, t0 + block)
            yield (t0, t1, part, *_beam(beam_model, part, fmeta, times[t0:t1], freq,
                                        stations, centre_correction, dtype))


def _beam(beam_model, comp: SkySet, fmeta, times: np.ndarray, freq: np.ndarray,
          stations: np.ndarray, centre_correction: bool, dtype) -> tuple:
    """Jones (nst, nt, nchan, ndir, 2, 2) towards every direction of ``comp``, as
    :class:`JonesFactors` when the model gives them, and the correction J(s0)^-1
    (nst, nt, nchan, 2, 2) or None, from one beam call with the phase centre appended;
    (None, None) without a beam or without directions."""
    if beam_model is None or not comp.ndir:
        return None, None
    ra, dec = np.append(comp.ra, fmeta.ra), np.append(comp.dec, fmeta.dec)
    factors = beam_model.jones_factors(times, freq, ra, dec, stations=stations, dtype=dtype)
    if factors is None:
        full = beam_model.jones(times, freq, ra, dec, stations=stations, dtype=dtype)
        jones, centre = full[..., :-1, :, :], full[..., -1, :, :]
    else:
        jones = JonesFactors(factors.scalar[..., :-1], factors.element[..., :-1, :, :],
                             factors.group)
        centre = factors.full(-1)
    return jones, centre_inverse(centre) if centre_correction else None


def _directions_jones(jones, index: np.ndarray) -> np.ndarray | None:
    """The Jones matrices (nst, nt, nchan, len(index), 2, 2) of directions ``index``."""
    if jones is None:
        return None
    if isinstance(jones, JonesFactors):
        return jones.full(index)
    return jones[..., index, :, :]


def add_time(timings: dict, key: str, since: float) -> float:
    """Add the time since ``since`` to ``timings[key]``; returns now."""
    now = _time.perf_counter()
    timings[key] = timings.get(key, 0.0) + now - since
    return now
