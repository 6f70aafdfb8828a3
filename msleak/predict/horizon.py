"""The horizon of an all-sky sky: which directions predict sums at each time
(docs/predict.md, "All-sky HEALPix skies").

A :class:`Horizon` says that a direction contributes at time t only if its elevation,
seen from the array centre, is at least ``min_elevation`` then. :func:`visible_blocks`
cuts a chunk's times into short blocks and gives, per block, the directions above that
elevation at some time of the block and, where some of them are below it at other times
of the block, the mask of (time, direction) pairs that count; :func:`mask_jones` zeroes
the beam of the others, so that their contribution is exactly zero. Directions below the
horizon at every time of a block are never evaluated.

Elevation: arcsin(s . z(t)), with s the J2000 direction and z(t) the J2000 direction of
the geodetic zenith of the array centre at time t (one exact casacore conversion per time,
:func:`msleak.beam.coords.zenith_j2000`): a geometric elevation, without aberration
(about 20 arcsec) or refraction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from msleak.beam.base import JonesFactors
from msleak.beam.coords import radec_to_unit, zenith_j2000

__all__ = ["Horizon", "HORIZON_SPAN_S", "visible_blocks", "mask_jones"]

#: longest time span (s) of one block of :func:`visible_blocks`: the sky turns by 2.5 deg,
#: so a block evaluates the beam at about 1.5 % more directions than any one of its times
HORIZON_SPAN_S = 600.0


@dataclass(frozen=True)
class Horizon:
    """Per-time culling of an all-sky sky.

    Attributes
    ----------
    min_elevation : float
        rad; directions below it at a time contribute nothing at that time.
    site : (3,) tuple of float
        ITRF position (m) of the array centre, whose geodetic zenith defines elevation.
    """

    min_elevation: float
    site: tuple


def visible_blocks(horizon: Horizon, times: np.ndarray, ra: np.ndarray, dec: np.ndarray,
                   max_times: int, max_span_s: float = HORIZON_SPAN_S) -> list:
    """The directions above the horizon, block of times by block of times.

    Parameters
    ----------
    times : (ntime,) UTC MJD s, increasing
    ra, dec : (ndir,) J2000, rad
    max_times : int
        Most times per block (at least 1); a block also spans at most ``max_span_s``.

    Returns
    -------
    list of (t0, t1, index, mask)
        Times t0..t1-1; ``index`` (nvis,) the directions at or above ``min_elevation``
        at some time of the block; ``mask`` (t1 - t0, nvis) bool, which of them are at
        those times, or None when all are at all times.
    """
    zra, zdec = zenith_j2000(np.asarray(times, dtype=float),
                             np.asarray(horizon.site, dtype=float))
    zenith, units = radec_to_unit(zra, zdec), radec_to_unit(ra, dec)
    least = math.sin(horizon.min_elevation)
    blocks, t0 = [], 0
    while t0 < times.size:
        t1 = t0 + 1
        while (t1 < times.size and t1 - t0 < max(1, max_times)
               and times[t1] - times[t0] <= max_span_s):
            t1 += 1
        up = zenith[t0:t1] @ units.T >= least          # (t1 - t0, ndir)
        index = np.flatnonzero(up.any(axis=0))
        mask = up[:, index]
        blocks.append((t0, t1, index, None if mask.all() else mask))
        t0 = t1
    return blocks


def mask_jones(jones, mask: np.ndarray, nstation: int, dtype):
    """The beam ``jones`` (full (nst|1, nt, nchan|1, ndir, 2, 2), :class:`JonesFactors`, or
    None for no beam) with the (time, direction) pairs where ``mask`` (nt, ndir) is False
    set to exactly zero (without a beam: the identity where True, zero elsewhere). The
    arrays of ``jones`` are zeroed in place where they cover every time."""
    mask = np.asarray(mask, dtype=bool)
    if jones is None:
        eye = np.zeros((1, 1, 1, mask.shape[1], 2, 2), dtype=dtype)
        eye[..., 0, 0] = eye[..., 1, 1] = 1
        return JonesFactors(mask[None, :, None, :].astype(dtype), eye,
                            np.zeros(nstation, dtype=np.int64))
    if isinstance(jones, JonesFactors):
        element = jones.element
        if not np.all(np.isfinite(element)):     # 0 x inf below the horizon would be NaN
            element = np.nan_to_num(element, nan=0.0, posinf=0.0, neginf=0.0)
        return JonesFactors(_zeroed(jones.scalar, mask[None, :, None, :]), element,
                            jones.group)
    return _zeroed(jones, mask[None, :, None, :, None, None])


def _zeroed(values: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """``values`` set to exactly zero where ``keep`` (broadcast against it; time axis 1)
    is False: in place when ``values`` has every time and may be written, else a copy."""
    if values.shape[1] == keep.shape[1] and values.flags.writeable:
        np.copyto(values, 0, where=~keep)
        return values
    return np.where(keep, values, 0).astype(values.dtype, copy=False)
