"""The arithmetic of ``msleak grid``'s chunk tasks: what a task needs (:class:`Input`,
:class:`Spec`), the rows it grids and their weights, and the memory model that sizes the
chunks (:func:`working_set`, :func:`plan_chunks`; docs/grid.md "Memory", docs/parallel.md).
The tasks themselves, which read the MS, are :mod:`msleak.verbs.grid_tasks`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from msleak.constants import SPEED_OF_LIGHT
from msleak.conventions import CorrelationLayout
from msleak.errors import InputError
from msleak.ps.gridding import BOX_FACTOR, accumulator_bytes, stokes_weights

__all__ = ["AUTO_CHUNK_SAMPLES", "MIN_CHUNK_ROWS", "BLOCK_SAMPLES", "Input", "Spec",
           "split_index", "check_shape", "blocks", "weighted_rows", "working_set",
           "rows_for_memory", "plan_chunks"]

log = logging.getLogger(__name__)

#: samples (rows x channels) per chunk task by default: big batches keep the w-gridder's
#: per-call cost (FFTs of its w-planes) small
AUTO_CHUNK_SAMPLES = 2_000_000
#: fewest rows per chunk the memory planning chooses (it runs fewer chunks at once first)
MIN_CHUNK_ROWS = 1000
#: samples (rows x channels) whose weights or canonical correlations are formed at a time
BLOCK_SAMPLES = 65_536


@dataclass(frozen=True)
class Input:
    """One Measurement Set to grid: its checked metadata and selected rows."""

    ms: str
    freq: np.ndarray
    width: np.ndarray
    layout: CorrelationLayout
    spw_id: int
    field_id: int
    ddid: int
    field: object
    wcol: str
    cols: tuple  # the columns every chunk reads besides the visibility columns
    vis_dtype: np.dtype  # complex64, or complex128 if a visibility column holds doubles
    rows: np.ndarray
    b_lo: float
    b_hi: float


@dataclass(frozen=True)
class Spec:
    """Settings every chunk task needs (shared by the tasks)."""

    columns: tuple[str, ...]
    gridder: str
    grid: object
    uv_min: float
    uv_max: float
    epsilon: float
    nthreads: int | None
    split: str | None
    split_times: np.ndarray | None
    #: rows per chunk task (set by :func:`run_tasks`); the ``wgrid`` accumulators of a chunk
    #: (one, or two with a split) buffer up to ``chunk_rows x channels`` samples together
    #: before they grid them
    chunk_rows: int = 0
    #: bytes of one correlation as read and buffered: 8 (complex64) or 16 (complex128; set
    #: by :func:`run_tasks` from the inputs)
    corr_bytes: int = 8


def split_index(split: str, times: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Half (0 or 1) of each TIME ``t`` for the ``split`` of the sorted unique ``times``."""
    if split == "even-odd":
        return np.searchsorted(times, t) % 2
    return (np.searchsorted(times, t) >= times.size // 2).astype(int)


def check_shape(inp: Input, column: str, shape: tuple) -> None:
    if tuple(shape[1:]) != (inp.freq.size, len(inp.layout.slots)):
        raise InputError(f"{inp.ms}: column {column} has shape "
                         f"(row, {', '.join(str(n) for n in shape[1:])}); "
                         f"expected (row, {inp.freq.size}, {len(inp.layout.slots)}) for the "
                         f"correlations {','.join(inp.layout.names)}")


def blocks(nrow: int, nchan: int, size: int = BLOCK_SAMPLES) -> list[slice]:
    """Row slices of ``size`` samples (default :data:`BLOCK_SAMPLES`) covering ``nrow``
    rows."""
    step = max(1, size // nchan)
    return [slice(start, start + step) for start in range(0, nrow, step)]


def weighted_rows(inp: Input, spec: Spec, c: dict, stats: dict) -> tuple:
    """The rows of chunk ``c`` to grid: indices, kernel uvw (row, 3) in metres and natural
    weights (row, chan), 0 outside the uv range; updates the counts ``stats``. Frees
    FLAG and the weight column of ``c``."""
    scale = inp.freq / SPEED_OF_LIGHT
    nchan = scale.size
    cross = c["ANTENNA1"] != c["ANTENNA2"]
    if "FLAG_ROW" in c:
        cross &= ~np.asarray(c["FLAG_ROW"], bool)
    stats["rows"] += cross.size
    stats["samples"] += int(cross.sum()) * nchan
    uvw = np.asarray(c["UVW"], float)
    b_m = np.hypot(uvw[:, 0], uvw[:, 1])
    uv_min, uv_max = spec.uv_min, spec.uv_max
    keep = cross & (b_m * scale.max() >= uv_min) & (b_m * scale.min() <= uv_max)
    wcol = inp.wcol
    nrow, ncorr = cross.size, len(inp.layout.slots)
    if wcol == "WEIGHT_SPECTRUM":
        wcorr = c.pop(wcol)
    elif wcol == "WEIGHT":  # one weight per correlation, for every channel
        wcorr = c.pop(wcol)[:, None, :]
    else:
        wcorr = np.ones((nrow, 1, ncorr), np.float32)
    flags = c.pop("FLAG")
    wgt = np.empty((nrow, nchan))
    for b in blocks(nrow, nchan):
        wgt[b] = stokes_weights(wcorr[b], flags[b])
    del wcorr, flags
    stats["unflagged"] += int(np.count_nonzero((wgt != 0) & cross[:, None]))
    wgt = wgt[keep]
    b_l = b_m[keep, None] * scale[None, :]
    outside = (b_l < uv_min) | (b_l > uv_max)
    wgt[outside] = 0.0
    stats["in_range"] += int(np.count_nonzero(wgt))
    used = (wgt > 0).any(axis=1)
    # rows whose baseline enters or leaves the uv range within the band (docs/ps.md)
    stats["rows_crossing"] += int(np.count_nonzero(outside[used].any(axis=1)))
    rows = np.flatnonzero(keep)[used]
    # The MS's UVW column holds uvw_ANTENNA2 - uvw_ANTENNA1, and visibilities follow
    # V = sum B exp(+2 pi i UVW . (l, m, n - 1)) (DP3's convention, which msleak predict
    # reproduces: tests/peers/test_predict_dp3.py). The gridding kernels use
    # exp(-2 pi i (u l + v m + w (n - 1))), so they take u = -UVW.
    return rows, -uvw[rows], wgt[used]


#: bytes per sample (row x channel) that a chunk task holds throughout: float64 weights
#: (and, per column, its correlations as read, 4 x ``corr_bytes``, and 1 of validity)
WEIGHT_SAMPLE_BYTES = 8
#: ... while it adds them up: coordinates, nearest-cell indices and weighted sums
ADD_SAMPLE_BYTES = 96
#: ... and for the ``cell`` gridder one column's complex128 Stokes visibilities and their
#: selections
CELL_ADD_SAMPLE_BYTES = 96
#: bytes per row a task holds: UVW as read and in float64, antennas, TIME, masks, indices
ROW_BYTES = 96
#: bytes per row of one channel's samples gathered for ducc0 (uvw, weights, correlations,
#: Stokes, unit visibilities; and 1 per column: their selection)
GATHER_ROW_BYTES = 160
#: bytes per pixel of the ``wgrid`` image box: a ducc0 call's image, its transforms and
#: ducc0's own grid
IMAGE_PIXEL_BYTES = 128


def working_set(rows: int, nchan: int, spec: Spec, tasks: int = 1) -> int:
    """Bytes that ``tasks`` chunk tasks of ``rows`` rows and ``nchan`` channels at once and
    this process (which sums their results) hold at most together.

    A task holds, per sample (``rows x nchan``), :data:`WEIGHT_SAMPLE_BYTES` and the
    correlations of every column (4 ``corr_bytes`` + 1), plus the larger of: one column
    as read with the block being reordered (:data:`BLOCK_SAMPLES`, twice 4 ``corr_bytes``),
    and :data:`ADD_SAMPLE_BYTES` (+ :data:`CELL_ADD_SAMPLE_BYTES`); :data:`ROW_BYTES` per
    row; its partial accumulators (:func:`~msleak.ps.gridding.accumulator_bytes`, two
    with a split) and, for ``wgrid``, :data:`GATHER_ROW_BYTES` per row and
    :data:`IMAGE_PIXEL_BYTES` per pixel of the image box. This process holds the summed
    accumulators and, for ``wgrid``, up to 1.25 chunks of samples buffered from chunks
    with few weighted ones (weights and correlations as above, 24 bytes of uvw per row)
    with the gathers and images of a call.
    """
    ncol, corr = len(spec.columns), 4 * spec.corr_bytes
    accs = accumulator_bytes(spec.gridder, spec.grid, nchan, ncol) * (2 if spec.split else 1)
    samples = rows * nchan
    held = samples * (WEIGHT_SAMPLE_BYTES + ncol * (corr + 1))
    convert = samples * corr + min(samples, BLOCK_SAMPLES) * 2 * corr
    add = samples * (ADD_SAMPLE_BYTES + (CELL_ADD_SAMPLE_BYTES if spec.gridder == "cell"
                                         else 0))
    task = held + max(convert, add) + rows * ROW_BYTES + accs
    here = accs
    if spec.gridder == "wgrid":
        call = (rows * (GATHER_ROW_BYTES + ncol)
                + IMAGE_PIXEL_BYTES * (BOX_FACTOR * spec.grid.npix_image) ** 2)
        task += call
        here += call + (held + rows * 24) * 5 // 4
    return tasks * task + here


def rows_for_memory(budget: float, nchan: int, spec: Spec, tasks: int = 1) -> int:
    """The most rows per chunk for which :func:`working_set` of ``tasks`` tasks at once
    stays within ``budget`` bytes (0: none)."""
    lo, hi = 0, 1024
    while working_set(hi, nchan, spec, tasks) <= budget:
        lo, hi = hi, 2 * hi
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if working_set(mid, nchan, spec, tasks) <= budget else (lo, mid)
    return lo


def plan_chunks(budget: float, nchan: int, spec: Spec, tasks: int) -> tuple[int, int]:
    """Rows per chunk and chunks at once within ``budget`` bytes: ``tasks`` chunks at once
    if each can have :data:`MIN_CHUNK_ROWS` rows, else fewer; one chunk of
    :data:`MIN_CHUNK_ROWS` rows at a time, with a warning, if even that does not fit."""
    for n in range(tasks, 0, -1):
        rows = rows_for_memory(budget, nchan, spec, n)
        if rows >= MIN_CHUNK_ROWS:
            return rows, n
    log.warning("--memory-limit %.0f MB is less than the grids and one chunk of %d rows "
                "need (%.0f MB); going ahead with that", budget / 2**20, MIN_CHUNK_ROWS,
                working_set(MIN_CHUNK_ROWS, nchan, spec) / 2**20)
    return MIN_CHUNK_ROWS, 1
