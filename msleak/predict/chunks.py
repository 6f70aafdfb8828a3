"""One time chunk of a predict run, on arrays (docs/predict.md).

:func:`plan_chunks` sizes the chunks to a memory budget; :func:`predict_chunk` turns one
chunk's arrays into visibilities for each sky: per-station
coordinates from the rows' UVW, the beam towards every direction of the skies plus the
phase centre (once for all skies), the visibility matrices of every sky, rows gathered
with the phase-centre correction, rows whose UVW are not antenna-based summed from their
own UVW (:mod:`msleak.predict.baselines`), circular feeds and the MS's correlation order.
"""

from __future__ import annotations

import logging
import time as _time
from dataclasses import replace
from typing import Iterator, Sequence

import numpy as np

from msleak.beam.base import JonesFactors
from msleak.beam.base import centre_correction as centre_correction_of
from msleak.errors import InputError
from msleak.predict import kernels
from msleak.predict.baselines import predict_rows
from msleak.predict.components import SkySet
from msleak.predict.gridsky import (PIXEL_BEAM_BYTES, degrid_geometry, degrid_visibilities,
                                    worth_degridding, zenith_near)
from msleak.predict.horizon import mask_jones, visible_blocks
from msleak.predict.stations import station_coordinates, uvw_tolerance

__all__ = ["plan_chunks", "predict_chunk", "add_time", "direct_block", "LONG_CHANNELS"]

log = logging.getLogger(__name__)


#: channels per chunk a degridded sky's long chunks keep at least (:func:`plan_chunks`)
LONG_CHANNELS = 8


def plan_chunks(ntime: int, nchan: int, nstation: int, ndir: int, rows_per_time: int,
                memory_limit: float, itemsize: int, beam: bool,
                fixed_bytes: float = 0.0, nsky: int = 1, long_times: bool = False,
                subgrid_dirs: int = 0, tasks: int = 1,
                whole_channels: bool = False) -> tuple[int, int]:
    """Times and channels per chunk so that the working set stays under ``memory_limit``.

    All channels and as many times as fit, at least ``tasks`` chunks while times allow,
    their lengths balanced (ceil(ntime / n) for n chunks, the last shorter); with
    ``long_times`` (a degridded sky, whose w-layer FFTs are done once per chunk and
    channel) all times and as many channels as fit, but at least :data:`LONG_CHANNELS`
    channels (fewer times) while memory allows, since a beam model evaluates channels
    together more cheaply than one by one, and at most ntime / ``tasks`` times, so that
    the ``tasks`` chunks run at once all have work.
    With ``whole_channels`` (an all-sky sky, whose beam work per direction the channels of
    a chunk share) every chunk has every channel, one time at least, even beyond the budget
    (with a warning).

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
    if whole_channels and units < nchan:
        log.warning("memory limit %.0f MB is too small for one time slot of every channel "
                    "(needs about %.0f MB); going ahead with that", memory_limit / 2**20,
                    (nchan * per_unit + fixed_bytes) / 2**20)
        return 1, nchan
    if units < 1:
        log.warning("memory limit %.0f MB is too small for one time slot and channel "
                    "(needs about %.0f MB); going ahead with that", memory_limit / 2**20,
                    (per_unit + fixed_bytes) / 2**20)
        return 1, 1
    if long_times and not whole_channels:
        least = min(nchan, LONG_CHANNELS)
        most = -(-ntime // max(1, tasks))
        if units >= most * least:
            return most, min(nchan, units // most)
        return (units // least, least) if units >= least else (1, units)
    if units >= nchan:
        return _balanced(ntime, max(1, min(ntime, units // nchan)), tasks), nchan
    return 1, units


def _balanced(ntime: int, most: int, tasks: int) -> int:
    """Times per chunk: ceil(ntime / n) for the fewest chunks n of at most ``most`` times,
    and at least ``tasks`` of them while there are times enough, so that the tasks run at
    once share the work (30 times that fit 29 per chunk: 15 + 15, not 29 + 1)."""
    nchunk = max(-(-ntime // most), min(max(1, tasks), ntime))
    return -(-ntime // nchunk)


def predict_chunk(comp: SkySet, beam_model, times: np.ndarray, freq: np.ndarray,
                  stations: np.ndarray, fmeta, tidx: np.ndarray, p: np.ndarray, q: np.ndarray,
                  uvw: np.ndarray, centre_correction: bool, dtype: np.dtype,
                  nc_chunk: int, timings: dict, active: Sequence[int] = (0,),
                  block_bytes: float = PIXEL_BEAM_BYTES) -> tuple[list, int]:
    """Visibilities (nrow, nchan, 4) of one time chunk (linear feeds) for each sky
    ``comp.skies[k]``, k in ``active``, and the number of rows computed from their own UVW
    (not antenna-based within the tolerance).

    The beam is evaluated once towards every direction of ``comp``; skies summed pixel by
    pixel (all-sky, and pixel skies summed directly) take it block by block within
    ``block_bytes``. Adds the stage wall times to ``timings``.
    """
    tick = _time.perf_counter()
    skies = [(comp.index[k], comp.skies[k]) for k in active]
    reach = np.concatenate([comp.lmn1] + [sky.lmn1 for _, sky in skies if sky.own])
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
    direct = [(index, sky) for index, sky in skies if not sky.own]
    views = [_visible(sky, times, stations, freq, block_bytes) for _, sky in skies]
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
                if not sky.own:
                    out[fast, c0:c1] = kernels.gather_rows(next(grams), tidx[fast], p[fast],
                                                           q[fast], jones_left=left)
            del grams
        for out, view, (_, sky) in zip(outs, views, skies):
            if view is not None and not off.all():
                out[fast, c0:c1] = _pixel_direct(sky, beam_model, fmeta, times,
                                                 slice(c0, c1), freq, stations, xyz, rows,
                                                 centre_correction, dtype, view, block_bytes)
        tick = add_time(timings, "kernel", tick)
        for out, (_, sky), use, geom, close in zip(outs, skies, use_degrid, geometry, near):
            if sky.grid is not None and not off.all():
                out[fast, c0:c1] = _pixel_sky(sky, geom if use else None, close, beam_model,
                                              fmeta, times, slice(c0, c1), freq, stations,
                                              xyz, rows, centre_correction, dtype,
                                              block_bytes)
        tick = add_time(timings, "degrid", tick)
        if off.any():
            _per_baseline(outs, skies, views, jones, left, np.flatnonzero(off),
                          (tidx, p, q, uvw), slice(c0, c1), beam_model, fmeta, times, freq,
                          stations, centre_correction, dtype, block_bytes)
            add_time(timings, "per_baseline", tick)
        del jones
    return outs, int(off.sum())


def _per_baseline(outs: list, skies: list, views: list, jones, left, rows_off: np.ndarray,
                  meta: tuple, channels: slice, beam_model, fmeta, times, freq, stations,
                  centre_correction: bool, dtype, block_bytes: float) -> None:
    """Fill the rows ``rows_off`` (not antenna-based) of every sky's ``outs`` on
    ``channels``, each from its own UVW (``meta``: tidx, p, q, uvw of all rows): the union
    skies with the chunk's beam ``jones`` and correction ``left``, the others (degridded,
    all-sky with their ``views``) block by block with their own beam."""
    tidx, p, q, uvw = (m[rows_off] for m in meta)
    for out, (index, sky), view in zip(outs, skies, views):
        if not sky.own:
            out[rows_off, channels] = predict_rows(
                _directions_jones(jones, index), tidx, p, q, uvw, sky.lmn1, freq[channels],
                sky.iquv[:, channels], jones_left=left, dtype=dtype)
            continue
        out[rows_off, channels] = 0
        for t0, t1, part, sky_jones, sky_left in _own_blocks(
                sky, beam_model, fmeta, times, freq[channels], stations, centre_correction,
                dtype, view, block_bytes, expand=True):
            sel = np.flatnonzero((tidx >= t0) & (tidx < t1))
            out[rows_off[sel], channels] += predict_rows(
                _directions_jones(sky_jones, np.arange(part.ndir)), tidx[sel] - t0, p[sel],
                q[sel], uvw[sel], part.lmn1, freq[channels], part.iquv[:, channels],
                jones_left=sky_left, dtype=dtype)


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
               rows: tuple, centre_correction: bool, dtype,
               block_bytes: float = PIXEL_BEAM_BYTES) -> np.ndarray:
    """Visibilities (nrow, nchan, 4) of the antenna-based ``rows`` (tidx, p, q) for a sky
    with a pixel grid, on ``freq[channels]``: degridded with ``geometry``, except the rows
    of the times ``near`` (bool, ntime, or None: no time), which, like every row when
    ``geometry`` is None (a chunk where degridding costs more or cannot hold the leakage),
    are summed directly with their own beam."""
    tidx, p, q = rows
    if not geometry:
        return _pixel_direct(sky, beam_model, fmeta, times, channels, freq, stations, xyz,
                             rows, centre_correction, dtype, None, block_bytes)
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
                                                     q[close]), centre_correction, dtype,
                               None, block_bytes)
    return out


def _pixel_direct(sky, beam_model, fmeta, times, channels, freq, stations, xyz, rows,
                  centre_correction, dtype, view=None,
                  block_bytes: float = PIXEL_BEAM_BYTES) -> np.ndarray:
    """:func:`_pixel_sky`'s direct sum over every pixel of ``rows`` (tidx, p, q); with
    ``view`` (:func:`_visible`), an all-sky sky's sum over the pixels above its horizon."""
    tidx, p, q = rows
    out = np.zeros((tidx.size, freq[channels].size, 4), dtype=dtype)
    for t0, t1, part, jones, left in _own_blocks(sky, beam_model, fmeta, times,
                                                 freq[channels], stations,
                                                 centre_correction, dtype, view,
                                                 block_bytes):
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


def direct_block(nstation: int, nchan: int, budget: float = PIXEL_BEAM_BYTES) -> int:
    """Pixels whose full-Jones beam for one time fits ``budget`` bytes (at least 1)."""
    return max(1, int(budget // (_PIXEL_BEAM_ENTRY * max(1, nstation * nchan))) - 1)


def _pixel_blocks(sky, beam_model, fmeta, times: np.ndarray, freq: np.ndarray,
                  stations: np.ndarray, centre_correction: bool, dtype,
                  block_bytes: float) -> Iterator:
    """(t0, t1, part, Jones, correction): :func:`_beam` towards the pixels ``part`` (a
    :class:`SkyComponents` of a block of the sky's pixels, or the sky) for times
    t0..t1-1, each within ``block_bytes``, so that a long chunk planned for
    degridding never holds the beam at every pixel for all its times; the visibilities of
    the parts add up to the sky's."""
    size = direct_block(stations.size, freq.size, block_bytes)
    parts = [sky] if size >= sky.ndir else [
        replace(sky, ra=sky.ra[i:i + size], dec=sky.dec[i:i + size],
                lmn1=sky.lmn1[i:i + size], iquv=sky.iquv[i:i + size], w=sky.w[i:i + size],
                sign=sky.sign[i:i + size], grid=None) for i in range(0, sky.ndir, size)]
    for part in parts:
        per_time = _PIXEL_BEAM_ENTRY * stations.size * (part.ndir + 1) * freq.size
        block = max(1, int(block_bytes // max(1, per_time)))
        for t0 in range(0, times.size, block):
            t1 = min(times.size, t0 + block)
            yield (t0, t1, part, *_beam(beam_model, part, fmeta, times[t0:t1], freq,
                                        stations, centre_correction, dtype))


#: a block of an all-sky sky keeps at least this many directions per beam call: it has at
#: most direct_block(nstation, nchan) / HORIZON_MIN_DIRECTIONS times
HORIZON_MIN_DIRECTIONS = 256


def _visible(sky, times: np.ndarray, stations: np.ndarray, freq: np.ndarray,
             block_bytes: float):
    """:func:`msleak.predict.horizon.visible_blocks` of an all-sky sky for a chunk (None for
    other skies)."""
    if sky.horizon is None:
        return None
    most = direct_block(stations.size, freq.size, block_bytes) // HORIZON_MIN_DIRECTIONS
    return visible_blocks(sky.horizon, times, sky.ra, sky.dec, max_times=max(1, most))


def _own_blocks(sky, beam_model, fmeta, times: np.ndarray, freq: np.ndarray,
                stations: np.ndarray, centre_correction: bool, dtype, view=None,
                block_bytes: float = PIXEL_BEAM_BYTES, expand: bool = False) -> Iterator:
    """:func:`_pixel_blocks`, or for an all-sky sky with its ``view`` (:func:`_visible`):
    per block of times, the directions above the horizon at some time of the block, in
    blocks within ``block_bytes``, their beam zero at the times they are below. A block
    counts the direct kernel's scratch and, per (time, channel, direction), three
    complex128 Jones matrices per station (what full-Jones models hold while they compute),
    or, when the previous block's beam came as :class:`JonesFactors` and is not to be
    ``expand``-ed to full Jones, twice the bytes it took (the model's own temporaries)."""
    if view is None:
        yield from _pixel_blocks(sky, beam_model, fmeta, times, freq, stations,
                                 centre_correction, dtype, block_bytes)
        return
    entry = _PIXEL_BEAM_ENTRY * stations.size    # bytes per (time, channel, direction)
    kernel = kernels.scratch_bytes(stations.size, 1, 1, freq.size, dtype)  # per direction
    for t0, t1, index, mask in view:
        i = 0
        while i < index.size:
            size = max(1, int(block_bytes // (entry * freq.size * (t1 - t0) + kernel)))
            rows = index[i:i + size]
            part = replace(sky, ra=sky.ra[rows], dec=sky.dec[rows], lmn1=sky.lmn1[rows],
                           iquv=sky.iquv[rows], w=sky.w[rows], sign=sky.sign[rows],
                           horizon=None)
            jones, left = _beam(beam_model, part, fmeta, times[t0:t1], freq, stations,
                                centre_correction, dtype)
            if isinstance(jones, JonesFactors) and not expand:   # sized by what it took
                entry = max(1.0, 2 * _nbytes(jones) / (freq.size * (t1 - t0) * rows.size))
            if mask is not None:
                jones = mask_jones(jones, mask[:, i:i + size], stations.size, dtype)
            yield t0, t1, part, jones, left
            i += rows.size


def _nbytes(jones: JonesFactors) -> int:
    """Bytes of a factored beam from :func:`_beam`."""
    return int(jones.scalar.nbytes + jones.element.nbytes)


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
    return jones, (centre_correction_of(beam_model, centre, times, freq, stations)
                   if centre_correction else None)


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
