"""numba kernels of the fast LOFAR HBA station beam (pure functions on arrays).

:func:`station_factors_kernel` gives the array factors of the stations of one time slot:
per antenna field the field phase reference, the field (tile) array factor and the tile
(element) array factor, summed over the station's fields that share an element response,
for ITRF unit directions and channel frequencies (Hz), with phases advanced channel to
channel over a uniform band. A station's Jones matrix is the sum over groups of its factor times
the group's element Jones matrices (:mod:`msleak.beam.lofar_fast`; :func:`combine_jones`).
:func:`apply_left_inverse` applies ``J(s0)^-1`` in place; :func:`sincos` is a
branch-free polynomial sine/cosine that vectorises.

The response formula and the evaluator: docs/beam.md ("The LOFAR fast evaluator").
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from msleak.constants import SPEED_OF_LIGHT

__all__ = ["station_factors_kernel", "combine_jones", "sincos", "apply_left_inverse"]

# directions per parallel work item
_BLOCK = 32

# pi/2 in three parts (Cody-Waite range reduction)
_PIO2_1 = 1.5707963267341256
_PIO2_2 = 6.077100506506192e-11
_PIO2_3 = 2.0222662487959506e-21


@njit(inline="always", cache=True, fastmath={"contract"})
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


@njit(nogil=True, cache=True, fastmath={"contract"})
def _accumulate(acc, delta, nb, positions, weights, freq, uniform, df, zr, zi, sr, si):
    """acc[c, kl] = sum_j weights[j] exp(-2 pi i freq[c] delta[kl].positions[j] / c) for
    the ``nb`` directions of a block, summed over j in order.

    ``zr, zi, sr, si`` are scratch arrays of at least (len(positions), nb) floats; the
    innermost loops run over the block's directions (contiguous, they vectorise).
    """
    nchan = freq.size
    n = positions.shape[0]
    k = -2.0 * math.pi / SPEED_OF_LIGHT
    f0 = freq[0]
    for j in range(n):
        p0, p1, p2 = positions[j, 0], positions[j, 1], positions[j, 2]
        for kl in range(nb):
            sr[j, kl] = k * (delta[kl, 0] * p0 + delta[kl, 1] * p1 + delta[kl, 2] * p2)
    if uniform:
        # a loop of its own, without the delays' products, so that sincos vectorises
        for j in range(n):
            wj = weights[j]
            for kl in range(nb):
                tau = sr[j, kl]
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
            acc[ch, kl] = complex(ar[kl], ai[kl])


@njit(parallel=True, nogil=True, cache=True)
def station_factors_kernel(d, s0, t0, freq, uniform, df, slot_fields, slot_ptr, field_sub,
                           field_layout, field_scale, field_up, tile_pos, tile_w, layout_pos,
                           layout_w, layout_n, out):
    """Array factors of the stations of one time slot per element group, written into ``out``.

    Station ``i``'s Jones matrix is ``sum_u out[i, u] E_g(i, u)`` with ``E_g`` the element
    Jones matrices of group ``g`` (:func:`combine_jones`): ``out[i, u]`` sums the station's
    fields of its ``u``-th element group (zero where it has fewer groups).

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
    field_sub : (len(slot_fields),) int64
        Of every entry of ``slot_fields``: the index (axis 1 of ``out``) of its field's
        element group among its station's groups.
    field_layout : (nfield,) int64
        Index into ``layout_pos`` of the field's tile element layout.
    field_scale : (nfield,) float64
        1 / number of fields of the station.
    field_up : (nfield, 3) float64
        Field r axis; directions with ``d . up < 0`` are below the horizon (zero response).
    tile_pos, tile_w : (nfield, ntile, 3), (nfield, ntile) float64
        Tile positions relative to the station phase reference (the field centre's offset
        plus the tile's, m; the field phase reference factor is part of the tile array
        factor) and normalised weights (zero-padded).
    layout_pos, layout_w, layout_n : (nlayout, 2, nelem, 3), (nlayout, 2, nelem) float64,
        (nlayout, 2) int64
        Tile element layouts as a sum over two factors: the tile array factor is the
        product of the weighted sums over ``layout_pos[l, 0, :layout_n[l, 0]]`` and over
        ``layout_pos[l, 1, :layout_n[l, 1]]`` (offsets in m; no second factor where
        ``layout_n[l, 1] == 0``). A 4 x 4 tile is 4 row offsets times 4 column offsets
        (weights 1/4 each); a layout that is no product lattice is its n elements (weights 1/n)
        alone (:func:`msleak.beam.lofar_fast.lattice_factors`).
    out : (nslot, nsub, nchan, ndir) complex64 or complex128
        nsub: the most element groups of any one station (1 for LOFAR HBA).
        Output; every element is written.
    """
    ndir = d.shape[0]
    nchan = freq.size
    nslot = slot_ptr.size - 1
    nsub = out.shape[1]
    nlayout = layout_pos.shape[0]
    need = np.zeros(nlayout, np.bool_)
    for i in range(slot_fields.size):
        need[field_layout[slot_fields[i]]] = True
    nmax = max(tile_pos.shape[1], layout_pos.shape[2], 1)
    # blocks of directions, so that writes to ``out`` run along its contiguous axis
    nblock = (ndir + _BLOCK - 1) // _BLOCK
    for blk in prange(nblock):
        k0 = blk * _BLOCK
        nb = min(_BLOCK, ndir - k0)
        af = np.empty((nchan, nb), np.complex128)
        at = np.empty((nlayout, nchan, nb), np.complex128)
        sst = np.empty((nsub, nchan, nb), np.complex128)
        zr = np.empty((nmax, nb))
        zi = np.empty((nmax, nb))
        sr = np.empty((nmax, nb))
        si = np.empty((nmax, nb))
        ds = np.empty((nb, 3))
        weight = np.empty(nb)
        _tile_factors(d, k0, nb, s0, t0, need, layout_pos, layout_w, layout_n, freq,
                      uniform, df, at, af, ds, zr, zi, sr, si)
        for slot in range(nslot):
            sst[:, :, :] = 0.0
            for i in range(slot_ptr[slot], slot_ptr[slot + 1]):
                fi = slot_fields[i]
                up = field_up[fi]
                lay = field_layout[fi]
                scale = field_scale[fi]
                g = field_sub[i]
                _accumulate(af, ds, nb, tile_pos[fi], tile_w[fi], freq, uniform, df,
                            zr, zi, sr, si)
                for kl in range(nb):  # the field's weight; zero below its horizon
                    k = k0 + kl
                    above = d[k, 0] * up[0] + d[k, 1] * up[1] + d[k, 2] * up[2] >= 0.0
                    weight[kl] = scale if above else 0.0
                for c in range(nchan):
                    for kl in range(nb):
                        sst[g, c, kl] += af[c, kl] * at[lay, c, kl] * weight[kl]
            for g in range(nsub):
                for c in range(nchan):
                    for kl in range(nb):
                        out[slot, g, c, k0 + kl] = sst[g, c, kl]


@njit(parallel=True, nogil=True, cache=True)
def combine_jones(factors, slot_groups, element_jones, out):
    """``out[i, c, k] = sum_u factors[i, u, c, k] element_jones[slot_groups[i, u], c, k]``
    over the ``u`` with ``slot_groups[i, u] >= 0``.

    factors : (nslot, nsub, nchan, ndir); slot_groups : (nslot, nsub) int64;
    element_jones : (ngroup, nchan, ndir, 2, 2); out : (nslot, nchan, ndir, 2, 2).
    """
    nslot, nsub, nchan, ndir = factors.shape
    for idx in prange(nslot * nchan):
        i = idx // nchan
        c = idx % nchan
        for k in range(ndir):
            for a in range(2):
                for b in range(2):
                    v = 0j
                    for u in range(nsub):
                        g = slot_groups[i, u]
                        if g >= 0:
                            v += factors[i, u, c, k] * element_jones[g, c, k, a, b]
                    out[i, c, k, a, b] = v


@njit(inline="always", cache=True)
def _tile_factors(d, k0, nb, s0, t0, need, layout_pos, layout_w, layout_n, freq, uniform, df,
                  at, scratch, ds, zr, zi, sr, si):
    """Tile array factors ``at[layout, c, kl]`` of directions ``d[k0:k0 + nb]`` towards ``t0``,
    and their offsets ``ds[kl] = s0 - d`` from the station beam-former direction.
    ``scratch`` is (nchan, nb) complex."""
    dt = np.empty((nb, 3))
    for kl in range(nb):
        for i in range(3):
            ds[kl, i] = s0[i] - d[k0 + kl, i]
            dt[kl, i] = t0[i] - d[k0 + kl, i]
    for lay in range(layout_pos.shape[0]):
        if need[lay]:
            n0, n1 = layout_n[lay, 0], layout_n[lay, 1]
            _accumulate(at[lay], dt, nb, layout_pos[lay, 0, :n0], layout_w[lay, 0, :n0], freq,
                        uniform, df, zr, zi, sr, si)
            if n1 > 0:
                _accumulate(scratch, dt, nb, layout_pos[lay, 1, :n1], layout_w[lay, 1, :n1],
                            freq, uniform, df, zr, zi, sr, si)
                for c in range(freq.size):
                    for kl in range(nb):
                        at[lay, c, kl] *= scratch[c, kl]


@njit(parallel=True, nogil=True, cache=True)
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
