"""numba kernels of the LOFAR HBA station beam with element gain errors (pure functions).

With a complex gain per tile element and feed the X and Y station beams differ and the
tile factor differs from tile to tile, so the station factor is no longer a station sum
times a tile sum: :func:`gain_factors_kernel` sums every element of every tile,
``AF_p = sum_t sum_e W[p, t, e] exp(-2 pi i f ((s0 - d).x_t + (t0 - d).e_e) / c)`` per feed
``p``, as the tile phasors (one per tile) times the element phasors (one per element of
the tile layout) weighted by ``W``. :func:`combine_feed_jones` scales the element Jones
matrices' rows (feeds) by them. The model without gains keeps
:mod:`msleak.beam.lofar_kernels`.

The formula and its cost: docs/beam.md ("Beam-model errors").
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from msleak.beam.lofar_kernels import sincos
from msleak.constants import SPEED_OF_LIGHT

__all__ = ["gain_factors_kernel", "combine_feed_jones"]

# directions per parallel work item
_BLOCK = 32


@njit(nogil=True, cache=True, fastmath={"contract"})
def _phasors(out, delta, nb, positions, freq, uniform, df, zr, zi, sr, si):
    """out[j, c, kl] = exp(-2 pi i freq[c] delta[kl].positions[j] / c) for the ``nb``
    directions of a block; ``zr, zi, sr, si`` are scratch arrays of ``nb`` floats."""
    nchan = freq.size
    k = -2.0 * math.pi / SPEED_OF_LIGHT
    for j in range(positions.shape[0]):
        p0, p1, p2 = positions[j, 0], positions[j, 1], positions[j, 2]
        for kl in range(nb):
            tau = k * (delta[kl, 0] * p0 + delta[kl, 1] * p1 + delta[kl, 2] * p2)
            if uniform:
                s, c = sincos(tau * freq[0])
                zr[kl] = c
                zi[kl] = s
                s, c = sincos(tau * df)
                sr[kl] = c
                si[kl] = s
            else:
                sr[kl] = tau
        for ch in range(nchan):
            for kl in range(nb):
                if uniform:
                    a = zr[kl]
                    b = zi[kl]
                    out[j, ch, kl] = complex(a, b)
                    zr[kl] = a * sr[kl] - b * si[kl]
                    zi[kl] = a * si[kl] + b * sr[kl]
                else:
                    s, c = sincos(sr[kl] * freq[ch])
                    out[j, ch, kl] = complex(c, s)


@njit(parallel=True, nogil=True, cache=True)
def gain_factors_kernel(d, s0, t0, freq, uniform, df, slot_fields, slot_ptr, field_sub,
                        field_layout, field_scale, field_up, tile_pos, layout_pos, weights,
                        out):
    """Per-feed array factors of the stations of one time slot per element group.

    Station ``i``'s Jones matrix is ``sum_u diag(out[i, u, 0], out[i, u, 1]) E_g(i, u)``
    (:func:`combine_feed_jones`), ``out[i, u, p]`` the sum over the station's fields of its
    ``u``-th element group of ``AF_p`` (module docstring) times the field's weight.

    Parameters
    ----------
    d : (ndir, 3) float64
        ITRF unit directions.
    s0, t0 : (3,) float64
        Station and tile beam-former directions (ITRF unit vectors).
    freq : (nchan,) float64
        Hz; if ``uniform``, ``freq[c] = freq[0] + c * df``.
    slot_fields, slot_ptr, field_sub, field_layout, field_scale, field_up
        As :func:`msleak.beam.lofar_kernels.station_factors_kernel`.
    tile_pos : (nfield, ntile, 3) float64
        Tile positions relative to the station phase reference (m, zero-padded).
    layout_pos : (nlayout, nelem, 3) float64
        Tile element offsets (m) of each layout (zero-padded).
    weights : (nfield, 2, ntile, nelem) complex128
        Per feed (X, Y), tile and element: tile weight x element gain / number of
        elements (zero for a failed tile and for padding).
    out : (nslot, nsub, 2, nchan, ndir) complex64 or complex128
        Output; every element is written.
    """
    ndir = d.shape[0]
    nchan = freq.size
    nslot = slot_ptr.size - 1
    nsub = out.shape[1]
    nlayout, nelem = layout_pos.shape[0], layout_pos.shape[1]
    ntile = tile_pos.shape[1]
    need = np.zeros(nlayout, np.bool_)
    for i in range(slot_fields.size):
        need[field_layout[slot_fields[i]]] = True
    nblock = (ndir + _BLOCK - 1) // _BLOCK
    for blk in prange(nblock):
        k0 = blk * _BLOCK
        nb = min(_BLOCK, ndir - k0)
        ds = np.empty((nb, 3))
        dt = np.empty((nb, 3))
        for kl in range(nb):
            for i in range(3):
                ds[kl, i] = s0[i] - d[k0 + kl, i]
                dt[kl, i] = t0[i] - d[k0 + kl, i]
        zr = np.empty(nb)
        zi = np.empty(nb)
        sr = np.empty(nb)
        si = np.empty(nb)
        elem = np.empty((nlayout, nelem, nchan, nb), np.complex128)
        for lay in range(nlayout):
            if need[lay]:
                _phasors(elem[lay], dt, nb, layout_pos[lay], freq, uniform, df, zr, zi, sr, si)
        tile = np.empty((ntile, nchan, nb), np.complex128)
        acc = np.empty((nchan, nb), np.complex128)
        sst = np.empty((nsub, 2, nchan, nb), np.complex128)
        weight = np.empty(nb)
        for slot in range(nslot):
            sst[:] = 0.0
            for i in range(slot_ptr[slot], slot_ptr[slot + 1]):
                fi = slot_fields[i]
                up = field_up[fi]
                lay = field_layout[fi]
                g = field_sub[i]
                for kl in range(nb):  # the field's weight; zero below its horizon
                    k = k0 + kl
                    above = d[k, 0] * up[0] + d[k, 1] * up[1] + d[k, 2] * up[2] >= 0.0
                    weight[kl] = field_scale[fi] if above else 0.0
                _phasors(tile, ds, nb, tile_pos[fi], freq, uniform, df, zr, zi, sr, si)
                for p in range(2):
                    for e in range(nelem):
                        acc[:, :] = 0.0
                        for t in range(ntile):
                            w = weights[fi, p, t, e]
                            if w != 0:
                                for c in range(nchan):
                                    for kl in range(nb):
                                        acc[c, kl] += w * tile[t, c, kl]
                        for c in range(nchan):
                            for kl in range(nb):
                                sst[g, p, c, kl] += acc[c, kl] * elem[lay, e, c, kl] * weight[kl]
            for g in range(nsub):
                for p in range(2):
                    for c in range(nchan):
                        for kl in range(nb):
                            out[slot, g, p, c, k0 + kl] = sst[g, p, c, kl]


@njit(parallel=True, nogil=True, cache=True)
def combine_feed_jones(factors, slot_groups, element_jones, out):
    """``out[i, c, k, a, b] = sum_u factors[i, u, a, c, k] element_jones[g, c, k, a, b]``,
    ``g = slot_groups[i, u]``, over the ``u`` with ``g >= 0``: row ``a`` (feed) of each
    element Jones matrix scaled by that feed's array factor.

    factors : (nslot, nsub, 2, nchan, ndir); slot_groups : (nslot, nsub) int64;
    element_jones : (ngroup, nchan, ndir, 2, 2); out : (nslot, nchan, ndir, 2, 2).
    """
    nslot, nsub, _, nchan, ndir = factors.shape
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
                            v += factors[i, u, a, c, k] * element_jones[g, c, k, a, b]
                    out[i, c, k, a, b] = v
