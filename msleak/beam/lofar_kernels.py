"""numba kernels of the fast LOFAR HBA station beam (pure functions on arrays).

:func:`station_jones_kernel` gives the station Jones matrices of one time slot: per
antenna field the field phase reference, the field (tile) array factor and the tile
(element) array factor times the element Jones matrices that
:mod:`msleak.beam.lofar_fast` computes, for ITRF unit directions and channel frequencies
(Hz), with phases advanced channel to channel over a uniform band.
:func:`apply_left_inverse` applies ``J(s0)^-1`` in place; :func:`sincos` is a
branch-free polynomial sine/cosine that vectorises.

The response formula and the evaluator: docs/beam.md ("The LOFAR fast evaluator").
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from msleak.constants import SPEED_OF_LIGHT

__all__ = ["station_jones_kernel", "sincos", "apply_left_inverse"]

# directions per parallel work item
_BLOCK = 32

# pi/2 in three parts (Cody-Waite range reduction)
_PIO2_1 = 1.5707963267341256
_PIO2_2 = 6.077100506506192e-11
_PIO2_3 = 2.0222662487959506e-21


@njit(inline="always", fastmath={"contract"})
def sincos(x):
    """(sin x, cos x) to ~2e-16 absolute for |x| < 1e4, branch-free so that loops vectorise.

    Range reduction to ``|r| <= pi/4`` by multiples of pi/2 (three-part constant), Taylor
    polynomials of degree 17/18 (truncation below 1e-17 there), quadrant by arithmetic.
    """
    n = np.floor(x * 0.6366197723675814 + 0.5)
    r = ((x - n * _PIO2_1) - n * _PIO2_2) - n * _PIO2_3
    r2 = r * r
    s = r * (1.0 + r2 * (-1.0 / 6 + r2 * (1.0 / 120 + r2 * (-1.0 / 5040 + r2 * (
        1.0 / 362880 + r2 * (-1.0 / 39916800 + r2 * (1.0 / 6227020800 + r2 * (
            -1.0 / 1307674368000 + r2 * (1.0 / 355687428096000)))))))))
    c = 1.0 + r2 * (-0.5 + r2 * (1.0 / 24 + r2 * (-1.0 / 720 + r2 * (1.0 / 40320 + r2 * (
        -1.0 / 3628800 + r2 * (1.0 / 479001600 + r2 * (-1.0 / 87178291200 + r2 * (
            1.0 / 20922789888000 + r2 * (-1.0 / 6402373705728000)))))))))
    q = np.int64(n) & 3
    sw = np.float64(q & 1)
    sgs = 1.0 - 2.0 * np.float64(q >> 1)
    sgc = 1.0 - 2.0 * np.float64(((q + 1) >> 1) & 1)
    return sgs * (s + sw * (c - s)), sgc * (c + sw * (s - c))


@njit(cache=True, fastmath={"contract"})
def _accumulate(acc, delta, nb, positions, weights, freq, uniform, df, zr, zi, sr, si):
    """acc[kl, c] = sum_j weights[j] exp(-2 pi i freq[c] delta[kl].positions[j] / c) for
    the ``nb`` directions of a block, summed over j in order.

    ``zr, zi, sr, si`` are scratch arrays of at least (len(positions), nb) floats; the
    innermost loops run over the block's directions (contiguous, they vectorise).
    """
    nchan = freq.size
    n = positions.shape[0]
    k = -2.0 * math.pi / SPEED_OF_LIGHT
    f0 = freq[0]
    for j in range(n):
        p0, p1, p2, wj = positions[j, 0], positions[j, 1], positions[j, 2], weights[j]
        for kl in range(nb):
            tau = k * (delta[kl, 0] * p0 + delta[kl, 1] * p1 + delta[kl, 2] * p2)
            sr[j, kl] = tau  # the delay, kept for the non-uniform band
            if uniform:
                s, c = sincos(tau * f0)
                zr[j, kl] = c * wj
                zi[j, kl] = s * wj
                s, c = sincos(tau * df)
                sr[j, kl] = c
                si[j, kl] = s
    ar = np.empty(nb)
    ai = np.empty(nb)
    for ch in range(nchan):
        ar[:] = 0.0
        ai[:] = 0.0
        for j in range(n):
            if uniform:
                for kl in range(nb):
                    a = zr[j, kl]
                    b = zi[j, kl]
                    ar[kl] += a
                    ai[kl] += b
                    zr[j, kl] = a * sr[j, kl] - b * si[j, kl]
                    zi[j, kl] = a * si[j, kl] + b * sr[j, kl]
            else:
                wj = weights[j]
                for kl in range(nb):
                    s, c = sincos(sr[j, kl] * freq[ch])
                    ar[kl] += c * wj
                    ai[kl] += s * wj
        for kl in range(nb):
            acc[kl, ch] = complex(ar[kl], ai[kl])


@njit(parallel=True, cache=True)
def station_jones_kernel(d, s0, t0, freq, uniform, df, slot_fields, slot_ptr, field_group,
                         field_layout, field_scale, field_refpos, field_up, tile_pos, tile_w,
                         layout_pos, layout_w, element_jones, out):
    """Station Jones matrices of one time slot, written into ``out``.

    Parameters
    ----------
    d : (ndir, 3) float64
        ITRF unit directions.
    s0, t0 : (3,) float64
        Station and tile beam-former directions (ITRF unit vectors).
    freq : (nchan,) float64
        Hz; if ``uniform``, ``freq[c] = freq[0] + c * df``.
    slot_fields, slot_ptr : int64 arrays
        The fields of output station ``i`` are ``slot_fields[slot_ptr[i]:slot_ptr[i + 1]]``.
    field_group : (nfield,) int64
        Index into ``element_jones`` of the field's element response.
    field_layout : (nfield,) int64
        Index into ``layout_pos`` of the field's tile element layout.
    field_scale : (nfield,) float64
        1 / number of fields of the station.
    field_refpos : (nfield, 3) float64
        Field centre minus station phase reference, m.
    field_up : (nfield, 3) float64
        Field r axis; directions with ``d . up < 0`` are below the horizon (zero response).
    tile_pos, tile_w : (nfield, ntile, 3), (nfield, ntile) float64
        Tile offsets (m) and normalised weights (zero-padded).
    layout_pos, layout_w : (nlayout, nelem, 3), (nlayout, nelem) float64
        Tile element offsets (m) and weights (1/16).
    element_jones : (ngroup, nchan, ndir, 2, 2) complex128
        Element Jones matrices, already in the sky (North, East) basis.
    out : (nslot, nchan, ndir, 2, 2) complex64 or complex128
        Output; every element is written.
    """
    ndir = d.shape[0]
    nchan = freq.size
    nslot = slot_ptr.size - 1
    nlayout = layout_pos.shape[0]
    need = np.zeros(nlayout, np.bool_)
    for i in range(slot_fields.size):
        need[field_layout[slot_fields[i]]] = True
    nmax = max(tile_pos.shape[1], layout_pos.shape[1], 1)
    one = np.ones(1)
    # blocks of directions, so that writes to ``out`` run along its contiguous axis
    nblock = (ndir + _BLOCK - 1) // _BLOCK
    for blk in prange(nblock):
        k0 = blk * _BLOCK
        nb = min(_BLOCK, ndir - k0)
        af = np.empty((nb, nchan), np.complex128)
        wf = np.empty((nb, nchan), np.complex128)
        at = np.empty((nlayout, nb, nchan), np.complex128)
        sst = np.empty((nb, nchan), np.complex128)
        extra = np.empty((nchan, nb, 2, 2), np.complex128)
        zr = np.empty((nmax, nb))
        zi = np.empty((nmax, nb))
        sr = np.empty((nmax, nb))
        si = np.empty((nmax, nb))
        ds = np.empty((nb, 3))
        _tile_factors(d, k0, nb, s0, t0, need, layout_pos, layout_w, freq, uniform, df,
                      at, ds, zr, zi, sr, si)
        for slot in range(nslot):
            g0 = field_group[slot_fields[slot_ptr[slot]]]
            sst[:, :] = 0.0
            mixed = False
            for i in range(slot_ptr[slot], slot_ptr[slot + 1]):
                fi = slot_fields[i]
                if field_group[fi] != g0 and not mixed:
                    extra[:, :, :, :] = 0.0
                    mixed = True
                up = field_up[fi]
                lay = field_layout[fi]
                scale = field_scale[fi]
                g = field_group[fi]
                _accumulate(af, ds, nb, tile_pos[fi], tile_w[fi], freq, uniform, df,
                            zr, zi, sr, si)
                _accumulate(wf, ds, nb, field_refpos[fi:fi + 1], one, freq, uniform, df,
                            zr, zi, sr, si)
                for kl in range(nb):
                    k = k0 + kl
                    if d[k, 0] * up[0] + d[k, 1] * up[1] + d[k, 2] * up[2] < 0.0:
                        continue
                    if g == g0:
                        for c in range(nchan):
                            sst[kl, c] += af[kl, c] * at[lay, kl, c] * wf[kl, c] * scale
                    else:
                        for c in range(nchan):
                            s = af[kl, c] * at[lay, kl, c] * wf[kl, c] * scale
                            for a in range(2):
                                for b in range(2):
                                    extra[c, kl, a, b] += s * element_jones[g, c, k, a, b]
            _write_slot(out[slot], element_jones[g0], sst, extra, mixed, k0, nb)


@njit(inline="always")
def _tile_factors(d, k0, nb, s0, t0, need, layout_pos, layout_w, freq, uniform, df, at, ds,
                  zr, zi, sr, si):
    """Tile array factors ``at[layout, kl]`` of directions ``d[k0:k0 + nb]`` towards ``t0``,
    and their offsets ``ds[kl] = s0 - d`` from the station beam-former direction."""
    dt = np.empty((nb, 3))
    for kl in range(nb):
        for i in range(3):
            ds[kl, i] = s0[i] - d[k0 + kl, i]
            dt[kl, i] = t0[i] - d[k0 + kl, i]
    for lay in range(layout_pos.shape[0]):
        if need[lay]:
            _accumulate(at[lay], dt, nb, layout_pos[lay], layout_w[lay], freq, uniform, df,
                        zr, zi, sr, si)


@njit(inline="always")
def _write_slot(out, element_jones, sst, extra, mixed, k0, nb):
    """``out[c, k] = sst[kl, c] E[c, k] (+ extra[c, kl] for mixed element groups)``."""
    for c in range(out.shape[0]):
        for kl in range(nb):
            k = k0 + kl
            s = sst[kl, c]
            for a in range(2):
                for b in range(2):
                    v = s * element_jones[c, k, a, b]
                    if mixed:
                        v += extra[c, kl, a, b]
                    out[c, k, a, b] = v


@njit(parallel=True, cache=True)
def apply_left_inverse(inv, jones):
    """``jones[s, t, c, d] = inv[s, t, c] @ jones[s, t, c, d]`` in place.

    inv : (nstation, ntime, nchan, 2, 2); jones : (nstation, ntime, nchan, ndir, 2, 2).
    """
    ns, nt, nc, nd = jones.shape[:4]
    for idx in prange(ns * nt * nc):
        s = idx // (nt * nc)
        t = (idx // nc) % nt
        c = idx % nc
        a = inv[s, t, c, 0, 0]
        b = inv[s, t, c, 0, 1]
        g = inv[s, t, c, 1, 0]
        h = inv[s, t, c, 1, 1]
        for k in range(nd):
            j00 = jones[s, t, c, k, 0, 0]
            j01 = jones[s, t, c, k, 0, 1]
            j10 = jones[s, t, c, k, 1, 0]
            j11 = jones[s, t, c, k, 1, 1]
            jones[s, t, c, k, 0, 0] = a * j00 + b * j10
            jones[s, t, c, k, 0, 1] = a * j01 + b * j11
            jones[s, t, c, k, 1, 0] = g * j00 + h * j10
            jones[s, t, c, k, 1, 1] = g * j01 + h * j11
