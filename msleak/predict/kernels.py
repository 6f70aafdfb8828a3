"""Measurement-equation kernels of predict: pure functions on arrays (numba + BLAS).

The kernels compute
V_pq = sum_s J_p(s) B_s J_q(s)^H exp(+2 pi i uvw_pq . (l, m, n - 1) / lambda)
with uvw_pq = x_q - x_p (antenna 2 minus antenna 1, the MS convention), factorised per
station (x_p from :mod:`msleak.predict.stations`) and evaluated as BLAS ``herk`` per
(time, channel), summed outwards in blocks of square rings (:func:`sky_blocks`). The beam
is either full Jones matrices or factors J_p = S_p E_g (:class:`JonesFactors`).
:func:`predict_grams` predicts several skies that share directions in one pass, each
exactly as if run alone; a crop of another sky of the run is that sky's partial sum. All
in the linear (X, Y) feed basis (:func:`linear_to_circular` converts); phases float64,
matrices in the output precision.

Sign convention, factorisation and sharing between skies: docs/predict.md and
docs/science.md section 4.
"""

from __future__ import annotations

import math
from typing import Sequence

import numba as nb
import numpy as np
from numba import types

from msleak.beam.base import JonesFactors
from msleak.conventions import LINEAR_TO_CIRCULAR_FEEDS
from msleak.predict._blas import HERK_SYMBOLS, register_herk, single_threaded_blas
from msleak.sky.sources import lmn

__all__ = [
    "lmn_minus_one",
    "brightness_factors",
    "sky_blocks",
    "column_layout",
    "predict_gram",
    "predict_grams",
    "scratch_bytes",
    "gram_to_matrix",
    "gather_rows",
    "linear_to_circular",
    "LINEAR_TO_CIRCULAR",
]

#: Speed of light in vacuum (m/s).

#: (RR, RL, LR, LL) = LINEAR_TO_CIRCULAR @ (XX, XY, YX, YY): kron(C, conj(C)) with C the
#: feed change of basis of :data:`msleak.conventions.LINEAR_TO_CIRCULAR_FEEDS`, which maps
#: the linear brightness matrix [[I+Q, U+iV], [U-iV, I-Q]] to the circular one
#: [[I+V, Q+iU], [Q-iU, I-V]].
LINEAR_TO_CIRCULAR = np.kron(LINEAR_TO_CIRCULAR_FEEDS, LINEAR_TO_CIRCULAR_FEEDS.conj())

register_herk()
_ARG = types.uintp  # pointer arguments of the Fortran BLAS interface (x86-64/aarch64 ABI)
_cherk = types.ExternalFunction(HERK_SYMBOLS["c"], types.void(*([_ARG] * 10)))
_zherk = types.ExternalFunction(HERK_SYMBOLS["z"], types.void(*([_ARG] * 10)))


def lmn_minus_one(ra: np.ndarray, dec: np.ndarray, ra0: float, dec0: float) -> np.ndarray:
    """Direction cosines (l, m, n - 1) of directions relative to a phase centre.

    Parameters
    ----------
    ra, dec : (ndir,) float
        Directions (rad, same frame as the phase centre).
    ra0, dec0 : float
        Phase centre (rad).

    Returns
    -------
    (ndir, 3) float64
        l (towards East), m (towards North), n - 1 (computed without cancellation). Rows
        of directions more than 90 deg from the phase centre have n - 1 < -1.
    """
    l, m, n = lmn(ra, dec, ra0, dec0)
    r2 = l * l + m * m
    nm1 = np.where(n > 0, -r2 / (1.0 + np.sqrt(np.clip(1.0 - r2, 0.0, None))), n - 1.0)
    return np.stack([l, m, nm1], axis=-1)


def brightness_factors(iquv: np.ndarray, rtol: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """Factor each linear-feed brightness matrix as B = W diag(sign) W^H.

    Parameters
    ----------
    iquv : (ndir, nchan, 4) float
        Stokes (I, Q, U, V) in Jy.
    rtol : float
        Eigenvalues smaller than ``rtol`` times the largest eigenvalue magnitude of the
        same matrix (or exactly zero) are dropped (sign 0).

    Returns
    -------
    W : (ndir, nchan, 2, 2) complex128
        Columns are eigenvectors of B = [[I+Q, U+iV], [U-iV, I-Q]] times sqrt|eigenvalue|
        (sqrt(Jy)).
    sign : (ndir, nchan, 2) int8
        +1, -1 or 0 (dropped) per column.
    """
    iquv = np.asarray(iquv, dtype=np.float64)
    i, q, u, v = (iquv[..., k] for k in range(4))
    b = np.empty(iquv.shape[:-1] + (2, 2), dtype=np.complex128)
    b[..., 0, 0] = i + q
    b[..., 0, 1] = u + 1j * v
    b[..., 1, 0] = u - 1j * v
    b[..., 1, 1] = i - q
    lam, vec = np.linalg.eigh(b)
    big = np.abs(lam).max(axis=-1, keepdims=True)
    keep = np.abs(lam) > rtol * big
    sign = np.where(keep, np.sign(lam), 0).astype(np.int8)
    w = vec * np.sqrt(np.where(keep, np.abs(lam), 0.0))[..., None, :]
    return w, sign


#: Directions whose Chebyshev radii max(|l|, |m|) differ by less than this (rad) form one
#: ring: the pixels of a square ring of a cube about the phase centre (docs/predict.md).
RING_GAP = 1e-9
#: Rings are merged, from the centre out, into blocks of at least this many directions
#: (one pair of herk calls per block; BLAS is efficient from about 32 columns).
BLOCK_MIN = 32


def sky_blocks(lmn1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Summation order of a sky's directions: outwards in square rings, in blocks.

    Parameters
    ----------
    lmn1 : (ndir, 3) float
        (l, m, n - 1) of the sky's directions.

    Returns
    -------
    order : (ndir,) int64
        Directions sorted by max(|l|, |m|), then l, then m: a function of each direction
        alone, so a centred square crop of a sky is a prefix of the sky's order.
    ends : (nblock,) int64
        End (exclusive, in ``order``) of each block: rings (radii within
        :data:`RING_GAP`) merged from the centre out until a block holds
        :data:`BLOCK_MIN` directions; the last block ends at ndir.
    """
    lmn1 = np.asarray(lmn1, dtype=np.float64).reshape(-1, 3)
    rho = np.maximum(np.abs(lmn1[:, 0]), np.abs(lmn1[:, 1]))
    order = np.lexsort((lmn1[:, 1], lmn1[:, 0], rho)).astype(np.int64)
    ring_ends = np.append(np.flatnonzero(np.diff(rho[order]) > RING_GAP) + 1, rho.size)
    ends, start = [], 0
    for end in ring_ends[ring_ends > 0]:
        if end - start >= BLOCK_MIN or end == rho.size:
            ends.append(end)
            start = end
    return order, np.asarray(ends, dtype=np.int64)


def column_layout(sign: np.ndarray, ends: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Column of Z for every (channel, direction, eigenvector): block by block, each
    block's positive columns first, then its negative ones.

    Parameters
    ----------
    sign : (ndir, nchan, 2) int8
        From :func:`brightness_factors`, directions in summation order.
    ends : (nblock,) int
        Block ends (:func:`sky_blocks`); block b owns columns 2 start_b .. 2 end_b - 1.

    Returns
    -------
    colmap : (nchan, ndir, 2) int32
        Column index in Z, or -1 for a dropped eigenvector.
    kpos, kneg : (nblock, nchan) int64
        Numbers of positive and negative columns per block and channel.
    """
    ndir, nchan = np.shape(sign)[:2]
    s = np.transpose(np.asarray(sign), (1, 0, 2)).reshape(nchan, 2 * ndir)
    ends = np.asarray(ends, dtype=np.int64)
    starts = np.concatenate([[0], ends[:-1]]).astype(np.int64)
    block = np.repeat(np.arange(ends.size), 2 * (ends - starts))  # block of every entry
    colmap = np.full(s.shape, -1, dtype=np.int32)
    counts = []
    for flags in (s > 0, s < 0):
        run = np.concatenate([np.zeros((nchan, 1), np.int64), np.cumsum(flags, axis=1)],
                             axis=1)
        before = run[:, 2 * starts]  # (nchan, nblock) columns of earlier blocks
        counts.append((run[:, 2 * ends] - before).T)
        rank = run[:, 1:] - 1 - before[:, block]
        offset = 2 * starts[block] + (counts[0].T[:, block] if len(counts) == 2 else 0)
        colmap[flags] = (offset + rank)[flags]
    kpos, kneg = (c.astype(np.int64) for c in counts)
    return colmap.reshape(nchan, ndir, 2), kpos, kneg


@nb.njit(nogil=True, cache=True)
def _start_phases(xyz, t, lmn1, freq, c0, df, regular, phase, step, geo):
    """Per-station phases exp(-2 pi i f x_p . lmn1 / c) at channel c0 and their step per
    channel (regular channels)."""
    two_pi_c = 2.0 * math.pi / 299_792_458.0
    for p in range(xyz.shape[1]):
        x0, x1, x2 = xyz[t, p, 0], xyz[t, p, 1], xyz[t, p, 2]
        for s in range(lmn1.shape[0]):
            g = -two_pi_c * (x0 * lmn1[s, 0] + x1 * lmn1[s, 1] + x2 * lmn1[s, 2])
            geo[p, s] = g
            phase[p, s] = complex(math.cos(g * freq[c0]), math.sin(g * freq[c0]))
            if regular:
                step[p, s] = complex(math.cos(g * df), math.sin(g * df))


@nb.njit(nogil=True, cache=True)
def _station_a(a, phase, p, jones, jp, jt, jc):
    """A_p(s) = phase_p(s) J_p(s) (4 entries, row-major) of station p, every direction."""
    for s in range(a.shape[0]):
        e = phase[p, s]
        a[s, 0] = e * jones[jp, jt, jc, s, 0, 0]
        a[s, 1] = e * jones[jp, jt, jc, s, 0, 1]
        a[s, 2] = e * jones[jp, jt, jc, s, 1, 0]
        a[s, 3] = e * jones[jp, jt, jc, s, 1, 1]


@nb.njit(inline="always")
def _station_rows(ptr, r, p, n2):
    """(offset in z of station p's X row of sky r's Z_r^T, the row length 2 ndir_r, the
    first column of sky r among all skies' columns); the Y row follows the X row."""
    kmax = 2 * (ptr[r + 1] - ptr[r])
    return n2 * 2 * ptr[r] + 2 * p * kmax, kmax, 2 * ptr[r]


@nb.njit(nogil=True, cache=True)
def _fill_z(z, a, p, n2, c, ptr, cdir, wcol):
    """Rows 2p, 2p+1 of every computed sky's Z_r^T = (A_p W)^T at channel c.

    Z_r^T of sky r is a C-order (2 nst, 2 ndir_r) array = Fortran (2 ndir_r, 2 nst) from
    offset 2 nst * 2 ptr[r] of z: the rows of one station are written contiguously.
    Column ``col`` (of all skies) is direction ``cdir[c, col]`` times the brightness factor
    column ``wcol[c, col]``; unused columns (``cdir < 0``) are not written."""
    for r in range(ptr.shape[0] - 1):
        row, kmax, col0 = _station_rows(ptr, r, p, n2)
        for k in range(kmax):
            s = cdir[c, col0 + k]
            if s < 0:
                continue
            w0 = wcol[c, col0 + k, 0]
            w1 = wcol[c, col0 + k, 1]
            z[row + k] = a[s, 0] * w0 + a[s, 1] * w1
            z[row + kmax + k] = a[s, 2] * w0 + a[s, 3] * w1


@nb.njit(nogil=True, cache=True)
def _element_w(m, element, jt, jc, c, cdir, wcol):
    """m[g, col] = E_g(s) wcol[c, col] for every element group g and used column."""
    for g in range(m.shape[0]):
        for col in range(m.shape[1]):
            s = cdir[c, col]
            if s < 0:
                continue
            w0 = wcol[c, col, 0]
            w1 = wcol[c, col, 1]
            m[g, col, 0] = (element[g, jt, jc, s, 0, 0] * w0
                            + element[g, jt, jc, s, 0, 1] * w1)
            m[g, col, 1] = (element[g, jt, jc, s, 1, 0] * w0
                            + element[g, jt, jc, s, 1, 1] * w1)


@nb.njit(nogil=True, cache=True)
def _fill_z_factored(z, gs, m, p, n2, c, ptr, cdir):
    """:func:`_fill_z` for J_p(s) = S_p(s) E_g(s): column ``col`` of station p is
    ``gs[s] m[col]`` with ``gs = phase_p S_p`` and ``m`` = E_g W (:func:`_element_w`)."""
    for r in range(ptr.shape[0] - 1):
        row, kmax, col0 = _station_rows(ptr, r, p, n2)
        for k in range(kmax):
            s = cdir[c, col0 + k]
            if s < 0:
                continue
            e = gs[s]
            z[row + k] = e * m[col0 + k, 0]
            z[row + kmax + k] = e * m[col0 + k, 1]


@nb.njit(nogil=True, cache=True)
def _herks(z, n2, t, c, ptr, sky, boff, bstart, kpos, kneg, sptr, snap, gram):
    """gram[sky[r], t, c] += Z+ Z+^H - Z- Z-^H of every computed sky r, block by block
    (herk('U', 'C') on column ranges of Z_r^T); after block b, copies of the sum go to the
    skies snap[sptr[b]:sptr[b + 1]] (crops whose blocks are r's first ones)."""
    uplo = np.empty(1, dtype=np.uint8)
    uplo[0] = 85  # 'U'
    trans = np.empty(1, dtype=np.uint8)
    trans[0] = 67  # 'C'
    n_arr = np.empty(1, dtype=np.int32)
    n_arr[0] = n2
    k_arr = np.empty(1, dtype=np.int32)
    lda = np.empty(1, dtype=np.int32)
    alpha32 = np.empty(1, dtype=np.float32)
    beta32 = np.ones(1, dtype=np.float32)
    alpha64 = np.empty(1, dtype=np.float64)
    beta64 = np.ones(1, dtype=np.float64)
    for r in range(ptr.shape[0] - 1):
        lda[0] = 2 * (ptr[r + 1] - ptr[r])
        base = z.ctypes.data + n2 * 2 * ptr[r] * z.itemsize
        out = gram[sky[r], t, c]
        for b in range(boff[r], boff[r + 1]):
            for sgn in range(2):
                k0 = 2 * bstart[b] + (0 if sgn == 0 else kpos[b, c])
                k_arr[0] = kpos[b, c] if sgn == 0 else kneg[b, c]
                if k_arr[0] == 0:
                    continue
                zptr = base + k0 * z.itemsize
                if gram.itemsize == 8:
                    alpha32[0] = 1.0 if sgn == 0 else -1.0
                    _cherk(uplo.ctypes.data, trans.ctypes.data, n_arr.ctypes.data,
                           k_arr.ctypes.data, alpha32.ctypes.data, zptr, lda.ctypes.data,
                           beta32.ctypes.data, out.ctypes.data, n_arr.ctypes.data)
                else:
                    alpha64[0] = 1.0 if sgn == 0 else -1.0
                    _zherk(uplo.ctypes.data, trans.ctypes.data, n_arr.ctypes.data,
                           k_arr.ctypes.data, alpha64.ctypes.data, zptr, lda.ctypes.data,
                           beta64.ctypes.data, out.ctypes.data, n_arr.ctypes.data)
            for i in range(sptr[b], sptr[b + 1]):
                gram[snap[i], t, c] = out


@nb.njit(parallel=True, nogil=True, cache=True)
def _kernel(jones, factored, scalar, element, group, xyz, lmn1, freq, regular, block, ptr,
            cdir, wcol, sky, boff, bstart, kpos, kneg, sptr, snap, gram):
    nt, nst = xyz.shape[0], xyz.shape[1]
    ndir = lmn1.shape[0]
    nchan = freq.shape[0]
    n2 = 2 * nst
    nblk = (nchan + block - 1) // block
    # lengths of the beam's station, time and channel axes (1: broadcast)
    if factored:
        nbs, nbt, nbc = scalar.shape[0], scalar.shape[1], scalar.shape[2]
    else:
        nbs, nbt, nbc = jones.shape[0], jones.shape[1], jones.shape[2]
    for it in nb.prange(nt * nblk):
        t = it // nblk
        c0 = (it - t * nblk) * block
        c1 = min(nchan, c0 + block)
        jt = t if nbt > 1 else 0
        # phases direct at c0, then multiplied by a constant step per channel when the
        # channels are regular (else evaluated per channel)
        phase = np.empty((nst, ndir), dtype=np.complex128)
        step = np.empty((nst, ndir), dtype=np.complex128)
        geo = np.empty((nst, ndir), dtype=np.float64)
        df = freq[c0 + 1] - freq[c0] if c1 - c0 > 1 else 0.0
        _start_phases(xyz, t, lmn1, freq, c0, df, regular, phase, step, geo)
        z = np.empty(n2 * 2 * ptr[ptr.shape[0] - 1], dtype=gram.dtype)
        a = np.empty((ndir if not factored else 0, 4), dtype=np.complex128)
        gs = np.empty(ndir if factored else 0, dtype=np.complex128)
        m = np.empty((element.shape[0] if factored else 0, cdir.shape[1], 2),
                     dtype=np.complex128)
        for c in range(c0, c1):
            if c > c0:
                for p in range(nst):
                    for s in range(ndir):
                        if regular:
                            phase[p, s] *= step[p, s]
                        else:
                            phase[p, s] = complex(math.cos(geo[p, s] * freq[c]),
                                                  math.sin(geo[p, s] * freq[c]))
            jc = c if nbc > 1 else 0
            if factored:
                _element_w(m, element, t if element.shape[1] > 1 else 0,
                           c if element.shape[2] > 1 else 0, c, cdir, wcol)
            for p in range(nst):
                jp = p if nbs > 1 else 0
                if factored:
                    for s in range(ndir):
                        gs[s] = phase[p, s] * scalar[jp, jt, jc, s]
                    _fill_z_factored(z, gs, m[group[p]], p, n2, c, ptr, cdir)
                else:
                    _station_a(a, phase, p, jones, jp, jt, jc)
                    _fill_z(z, a, p, n2, c, ptr, cdir, wcol)
            _herks(z, n2, t, c, ptr, sky, boff, bstart, kpos, kneg, sptr, snap, gram)


def predict_grams(jones: np.ndarray | JonesFactors | None, xyz: np.ndarray, lmn1: np.ndarray,
                  freq: np.ndarray, skies: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]],
                  dtype=np.complex64) -> np.ndarray:
    """Visibility matrices of all station pairs for several skies sharing directions.

    The per-station matrices A_p(s) = J_p(s) exp(-2 pi i x_p . (l, m, n - 1) / lambda) are
    built once per (time, channel) for every direction of ``lmn1`` and used by every sky
    that has that direction; each sky then costs its own Z = A W and Gram product, except
    a sky whose directions, factors and blocks (:func:`sky_blocks`) are the first ones of
    another sky's (a centred crop ending on a block boundary): its result is a copy of
    that sky's sum after those blocks.

    Parameters
    ----------
    jones : (nstation | 1, ntime | 1, nchan | 1, ndir, 2, 2) complex, JonesFactors or None
        Beam Jones matrices in the linear (X, Y) basis (already centre-corrected if
        wanted), or their factors J_p = S_p E_g(p) (:class:`msleak.beam.base.JonesFactors`,
        cheaper: E W is formed once per element group, not per station); size-1 axes
        broadcast. None means no beam (identity). A correction that depends only on
        station, time and channel (J_p(s0)^-1) is better applied by :func:`gather_rows`
        to the sum than here to every source.
    xyz : (ntime, nstation, 3) float64
        Per-station coordinates x_p (m) with uvw_pq = x_q - x_p (MS convention); the
        result is V_pq = sum_s J_p B_s J_q^H exp(+2 pi i uvw_pq . (l, m, n - 1) / lambda).
    lmn1 : (ndir, 3) float64
        (l, m, n - 1) of the directions (:func:`lmn_minus_one`).
    freq : (nchan,) float64
        Channel frequencies (Hz).
    skies : sequence of (index, w, sign)
        Per sky: ``index`` (ndir_k,) int, its directions as rows of ``lmn1`` (and of the
        direction axis of ``jones``); ``w``, ``sign`` of those directions from
        :func:`brightness_factors`, shapes (ndir_k, nchan, 2, 2) and (ndir_k, nchan, 2).
    dtype : complex64 or complex128
        Precision of the matrix products and of the result.

    Returns
    -------
    (nsky, ntime, nchan, 2 nstation, 2 nstation) complex
        Per sky ``G`` whose lower triangle (i >= j) is that of the Hermitian visibility
        matrix V (row/column 2 p + a is station p, feed a); the strict upper triangle is
        not set. Use :func:`gather_rows` or :func:`gram_to_matrix` to read it. A sky's
        result does not depend on the other skies.
    """
    dtype = np.dtype(dtype)
    if dtype not in (np.complex64, np.complex128):
        raise ValueError(f"dtype must be complex64 or complex128, not {dtype}")
    xyz = np.ascontiguousarray(xyz, dtype=np.float64)
    lmn1 = np.ascontiguousarray(lmn1, dtype=np.float64)
    freq = np.ascontiguousarray(freq, dtype=np.float64)
    nt, nst = xyz.shape[:2]
    nchan = freq.size
    beam = _check_jones(jones, nst, nt, nchan, lmn1.shape[0], dtype)
    packed = _pack_skies(skies, lmn1, nchan)
    gram = np.zeros((len(skies), nt, nchan, 2 * nst, 2 * nst), dtype=dtype)
    regular = _regular_spacing(freq)
    nthreads = nb.get_num_threads()
    block = max(1, min(nchan, -(-nt * nchan // (4 * nthreads)))) if regular else 1
    with single_threaded_blas():
        _kernel(*beam, xyz, lmn1, freq, regular, block, *packed, gram)
    return gram


def scratch_bytes(nstation: int, ndir: int, ndir_skies: int, nchan: int, dtype) -> int:
    """Memory :func:`predict_grams` allocates besides its result (bytes, all threads) for
    skies with ``ndir_skies`` directions in all and at most ``nchan`` channels: their
    factors in column order, and per thread the phases of ``ndir`` directions, one
    station's A matrices (or, with factored Jones, E W of one element group; add
    ``64 ndir_skies`` per thread for each further group) and their Z."""
    per_thread = (40 * nstation * ndir + 64 * ndir + 64 * ndir_skies
                  + 4 * nstation * ndir_skies * np.dtype(dtype).itemsize)
    return nb.get_num_threads() * per_thread + 80 * nchan * ndir_skies


def predict_gram(jones: np.ndarray | JonesFactors | None, xyz: np.ndarray, lmn1: np.ndarray,
                 freq: np.ndarray, w: np.ndarray, sign: np.ndarray,
                 dtype=np.complex64) -> np.ndarray:
    """:func:`predict_grams` of one sky whose directions are all of ``lmn1`` (in order).

    Returns
    -------
    (ntime, nchan, 2 nstation, 2 nstation) complex
    """
    index = np.arange(np.shape(lmn1)[0])
    return predict_grams(jones, xyz, lmn1, freq, [(index, w, sign)], dtype=dtype)[0]


def _check_jones(jones, nst: int, nt: int, nchan: int, ndir: int, dtype) -> tuple:
    """The kernel's beam arguments (jones, factored, scalar, element, group); without a
    beam, factors of the identity."""
    if jones is None:
        eye = np.zeros((1, 1, 1, ndir, 2, 2), dtype=dtype)
        eye[..., 0, 0] = eye[..., 1, 1] = 1
        jones = JonesFactors(np.ones((1, 1, 1, ndir), dtype=dtype), eye,
                             np.zeros(nst, dtype=np.int64))
    if isinstance(jones, JonesFactors):
        scalar, element = np.asarray(jones.scalar), np.asarray(jones.element)
        group = np.ascontiguousarray(jones.group, dtype=np.int64)
        if scalar.ndim != 4 or scalar.shape[3] != ndir:
            raise ValueError(f"jones.scalar has shape {scalar.shape}, expected "
                             f"(nstation, ntime, nchan, {ndir})")
        if element.ndim != 6 or element.shape[3:] != (ndir, 2, 2):
            raise ValueError(f"jones.element has shape {element.shape}, expected "
                             f"(ngroup, ntime, nchan, {ndir}, 2, 2)")
        if group.shape != (nst,) or (nst and (group.min() < 0
                                              or group.max() >= element.shape[0])):
            raise ValueError(f"jones.group must be {nst} indices into jones.element's "
                             f"{element.shape[0]} groups")
        _check_broadcast(scalar, (nst, nt, nchan), "jones.scalar")
        _check_broadcast(element, (None, nt, nchan), "jones.element")
        return np.zeros((1, 1, 1, 1, 2, 2), dtype=dtype), True, scalar, element, group
    jones_arr = np.asarray(jones)
    if jones_arr.ndim != 6 or jones_arr.shape[-2:] != (2, 2) or jones_arr.shape[3] != ndir:
        raise ValueError(f"jones has shape {jones_arr.shape}, expected "
                         f"(nstation, ntime, nchan, {ndir}, 2, 2)")
    _check_broadcast(jones_arr, (nst, nt, nchan), "jones")
    return (jones_arr, False, np.zeros((1, 1, 1, 1), dtype=dtype),
            np.zeros((1, 1, 1, 1, 2, 2), dtype=dtype), np.zeros(nst, dtype=np.int64))


def _check_broadcast(arr: np.ndarray, lengths: tuple, name: str) -> None:
    """Refuse an axis of ``arr`` whose length is neither 1 nor ``lengths`` (None: any)."""
    for axis, n in enumerate(lengths):
        if n is not None and arr.shape[axis] not in (1, n):
            raise ValueError(f"{name} axis {axis} has length {arr.shape[axis]}, "
                             f"expected 1 or {n}")


def _pack_skies(skies, lmn1: np.ndarray, nchan: int) -> tuple:
    """The kernel's arrays: the computed skies' directions, factors and column layouts in
    summation order (:func:`sky_blocks`), their blocks, and the skies that are copies of
    a computed sky's sum after one of its blocks (a crop sharing its first blocks)."""
    ndir = lmn1.shape[0]
    prepared = []
    for k, (index, wk, sign) in enumerate(skies):
        index = np.asarray(index, dtype=np.int64).reshape(-1)
        n = index.size
        if np.shape(wk) != (n, nchan, 2, 2) or np.shape(sign) != (n, nchan, 2):
            raise ValueError(f"sky {k}: w and sign must have shapes ({n}, {nchan}, 2, 2) and "
                             f"({n}, {nchan}, 2)")
        if n and (index.min() < 0 or index.max() >= ndir):
            raise ValueError(f"sky direction index out of range 0..{ndir - 1}")
        order, ends = sky_blocks(lmn1[index])
        prepared.append((index[order], np.asarray(wk)[order], np.asarray(sign)[order], ends))
    roots, parent = _nesting(prepared)
    dirs, w, sign, ends = ([prepared[r][f] for r in roots] for f in range(4))
    layouts = [column_layout(sg, e) for sg, e in zip(sign, ends)]
    boff = np.cumsum([0] + [e.size for e in ends]).astype(np.int64)
    # a nested sky is the copy of its root's sum after the root's block of its last one
    last = {k: boff[roots.index(r)] + prepared[k][3].size - 1 for k, r in parent.items()}
    nested = sorted(last, key=lambda k: (last[k], k))
    sptr = np.searchsorted([last[k] for k in nested], np.arange(boff[-1] + 1))
    ptr = np.cumsum([0] + [d.size for d in dirs]).astype(np.int64)
    # every Z column's direction and brightness factor column, per channel
    cdir = np.full((nchan, 2 * ptr[-1]), -1, dtype=np.int64)
    wcol = np.zeros((nchan, 2 * ptr[-1], 2), dtype=np.complex128)
    for r in range(len(dirs)):
        _columns(layouts[r][0], dirs[r], w[r], 2 * ptr[r], cdir, wcol)
    return (ptr, cdir, wcol,
            np.asarray(roots, dtype=np.int64), boff,
            _concat([np.concatenate([[0], e[:-1]]) for e in ends], (0,), np.int64),
            _concat([kp for _, kp, _ in layouts], (0, nchan), np.int64),
            _concat([kn for _, _, kn in layouts], (0, nchan), np.int64),
            sptr.astype(np.int64), np.asarray(nested, dtype=np.int64))


@nb.njit(nogil=True, cache=True)
def _columns(colmap, dirs, w, col0, cdir, wcol):
    """cdir[c, col0 + colmap[c, j, e]] = dirs[j] and wcol[c, ...] = w[j, c, :, e] for
    every kept eigenvector (colmap >= 0)."""
    for c in range(colmap.shape[0]):
        for j in range(colmap.shape[1]):
            for e in range(2):
                col = colmap[c, j, e]
                if col >= 0:
                    cdir[c, col0 + col] = dirs[j]
                    wcol[c, col0 + col, 0] = w[j, c, 0, e]
                    wcol[c, col0 + col, 1] = w[j, c, 1, e]


def _concat(parts: list, empty_shape: tuple, dtype) -> np.ndarray:
    """``parts`` concatenated along axis 0 as ``dtype`` (an empty array if none)."""
    return np.concatenate([np.zeros(empty_shape, dtype)] + list(parts)).astype(dtype)


def _nesting(prepared: list) -> tuple[list, dict]:
    """Skies computed (``roots``, sorted) and ``{sky: root}`` of the others: a sky whose
    directions, factors and blocks are the first ones of a larger (or an equal, earlier)
    sky's. Skies without directions are neither."""
    roots: list = []
    parent: dict = {}
    for k in sorted(range(len(prepared)), key=lambda k: (-prepared[k][0].size, k)):
        dirs, w, sign, ends = prepared[k]
        if not dirs.size:
            continue
        for r in roots:
            rd, rw, rs, rends = prepared[r]
            n = dirs.size
            if (np.array_equal(rends[:ends.size], ends) and np.array_equal(rd[:n], dirs)
                    and np.array_equal(rs[:n], sign) and np.array_equal(rw[:n], w)):
                parent[k] = r
                break
        else:
            roots.append(k)
    return sorted(roots), parent


def _regular_spacing(freq: np.ndarray) -> bool:
    """True when channel frequencies are f0 + k df to 1e-12 relative (phase recurrence)."""
    if freq.size < 3:
        return True
    lin = freq[0] + np.arange(freq.size) * ((freq[-1] - freq[0]) / (freq.size - 1))
    return bool(np.all(np.abs(freq - lin) <= 1e-12 * np.abs(freq)))


def gram_to_matrix(gram: np.ndarray) -> np.ndarray:
    """Full Hermitian visibility matrices V (ntime, nchan, 2 nst, 2 nst) from ``G``."""
    lower = np.tril(gram)  # G[i, j] = V[i, j] for i >= j
    return lower + np.conj(np.swapaxes(np.tril(gram, -1), -1, -2))


@nb.njit(parallel=True, nogil=True, cache=True)
def _gather(gram, tidx, p, q, left, have_left, out):
    nrow = tidx.shape[0]
    nchan = gram.shape[1]
    for r in nb.prange(nrow):
        t = tidx[r]
        v = np.empty((2, 2), dtype=np.complex128)
        for c in range(nchan):
            for a in range(2):
                for b in range(2):
                    i = 2 * p[r] + a
                    j = 2 * q[r] + b
                    if i >= j:
                        v[a, b] = gram[t, c, i, j]
                    else:
                        v[a, b] = np.conj(gram[t, c, j, i])
            if have_left:
                lp = left[p[r] if left.shape[0] > 1 else 0, t if left.shape[1] > 1 else 0,
                          c if left.shape[2] > 1 else 0]
                lq = left[q[r] if left.shape[0] > 1 else 0, t if left.shape[1] > 1 else 0,
                          c if left.shape[2] > 1 else 0]
                for a in range(2):
                    for b in range(2):
                        acc = 0j
                        for k in range(2):
                            for m in range(2):
                                acc += lp[a, k] * v[k, m] * np.conj(lq[b, m])
                        out[r, c, 2 * a + b] = acc
            else:
                for a in range(2):
                    for b in range(2):
                        out[r, c, 2 * a + b] = v[a, b]


@nb.njit(inline="always", cache=True)
def sandwich(a00, a01, a10, a11, s00, s01, s10, s11, b00, b01, b10, b11):
    """Entries (00, 01, 10, 11) of A S B^H for 2 x 2 matrices A, S, B given by their
    entries (B's not conjugated), for the kernels' per-direction and per-row products."""
    m00 = a00 * s00 + a01 * s10
    m01 = a00 * s01 + a01 * s11
    m10 = a10 * s00 + a11 * s10
    m11 = a10 * s01 + a11 * s11
    c00, c01, c10, c11 = np.conj(b00), np.conj(b01), np.conj(b10), np.conj(b11)
    return (m00 * c00 + m01 * c01, m00 * c10 + m01 * c11,
            m10 * c00 + m11 * c01, m10 * c10 + m11 * c11)


def gather_rows(gram: np.ndarray, tidx: np.ndarray, p: np.ndarray, q: np.ndarray,
                jones_left: np.ndarray | None = None) -> np.ndarray:
    """Visibilities of MS rows from the matrices of :func:`predict_gram`.

    Parameters
    ----------
    gram : (ntime, nchan, 2 nst, 2 nst) complex
    tidx, p, q : (nrow,) int
        Time index into ``gram`` and the station indices (ANTENNA1, ANTENNA2 mapped to
        0..nst-1) of every row; any order, autocorrelations allowed.
    jones_left : (nst | 1, ntime | 1, nchan | 1, 2, 2) complex, optional
        L_p with V'_pq = L_p V_pq L_q^H: the phase-centre correction L_p = J_p(s0)^-1
        (docs/science.md section 4), which equals applying it to every source's Jones matrix.

    Returns
    -------
    (nrow, nchan, 4) complex
        Correlations XX, XY, YX, YY (linear basis).
    """
    tidx = np.ascontiguousarray(tidx, dtype=np.int64)
    p = np.ascontiguousarray(p, dtype=np.int64)
    q = np.ascontiguousarray(q, dtype=np.int64)
    if jones_left is None:
        left = np.zeros((1, 1, 1, 2, 2), dtype=np.complex128)
    else:
        left = np.asarray(jones_left, dtype=np.complex128)
        if left.ndim != 5 or left.shape[-2:] != (2, 2):
            raise ValueError(f"jones_left has shape {left.shape}, expected "
                             "(nst, ntime, nchan, 2, 2)")
        for axis, n in ((1, gram.shape[0]), (2, gram.shape[1])):
            if left.shape[axis] not in (1, n):
                raise ValueError(f"jones_left axis {axis} has length {left.shape[axis]}, "
                                 f"expected 1 or {n}")
    out = np.empty((tidx.size, gram.shape[1], 4), dtype=gram.dtype)
    _gather(gram, tidx, p, q, left, jones_left is not None, out)
    return out


def linear_to_circular(vis: np.ndarray) -> np.ndarray:
    """Correlations (..., 4) XX, XY, YX, YY -> RR, RL, LR, LL (see ``LINEAR_TO_CIRCULAR``)."""
    return (np.asarray(vis) @ LINEAR_TO_CIRCULAR.T).astype(np.asarray(vis).dtype, copy=False)
