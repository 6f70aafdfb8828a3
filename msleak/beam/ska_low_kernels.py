"""numba kernel of the fast SKA-Low station beam (a pure function on arrays).

EveryBeam 0.9.0 evaluates an SKA-Low (OSKAR-type) station as one beam former over
identical elements (``BeamFormerIdenticalAntennas``): for an ITRF direction ``d``,
channel frequency ``f`` and beam-former (delay) direction ``s0``::

    J(d, f) = diag(AF_x, AF_y) E(d, f)

    AF_p = sum_j w_pj exp(-2 pi i f (s0 - d).x_j / c),   w_pj = [feed p of element j
                                                          unflagged] / (number unflagged)

with ``x_j`` the element offsets as EveryBeam sees them (ITRF offsets projected on the
station axes and back, i.e. ``A^T A x``) and ``E`` the element Jones matrix in the sky
(North, East) basis (docs/ska_low.md).  The kernel evaluates ``AF`` and the product for
all stations, channels and directions of one time slot.  Over a uniformly spaced band
each element's phasor is advanced from channel to channel by one complex multiplication;
sines and cosines use the branch-free :func:`msleak.beam.lofar_kernels.sincos`, which
vectorises.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from msleak.beam.lofar_kernels import sincos
from msleak.constants import SPEED_OF_LIGHT

__all__ = ["ska_low_station_kernel"]

_BLOCK = 16


@njit(nogil=True, cache=True, fastmath={"reassoc", "contract"})
def _array_factor(tau, n, wx, wy, wxi, wyi, freq, uniform, df, zr, zi, sr, si, afx, afy):
    """afx[c], afy[c] = sum_j w_j exp(i tau_j freq[c]) for the X and Y weights
    w = (wx + i wxi), (wy + i wyi).

    ``zr, zi, sr, si`` are scratch arrays of at least ``n`` floats.
    """
    nchan = freq.size
    if uniform:
        for j in range(n):
            zi[j], zr[j] = sincos(tau[j] * freq[0])
            si[j], sr[j] = sincos(tau[j] * df)
        for c in range(nchan):
            xr = 0.0
            xi = 0.0
            yr = 0.0
            yi = 0.0
            for j in range(n):
                a = zr[j]
                b = zi[j]
                xr += wx[j] * a - wxi[j] * b
                xi += wx[j] * b + wxi[j] * a
                yr += wy[j] * a - wyi[j] * b
                yi += wy[j] * b + wyi[j] * a
                zr[j] = a * sr[j] - b * si[j]
                zi[j] = a * si[j] + b * sr[j]
            afx[c] = complex(xr, xi)
            afy[c] = complex(yr, yi)
    else:
        for c in range(nchan):
            xr = 0.0
            xi = 0.0
            yr = 0.0
            yi = 0.0
            for j in range(n):
                b, a = sincos(tau[j] * freq[c])
                xr += wx[j] * a - wxi[j] * b
                xi += wx[j] * b + wxi[j] * a
                yr += wy[j] * a - wyi[j] * b
                yi += wy[j] * b + wyi[j] * a
            afx[c] = complex(xr, xi)
            afy[c] = complex(yr, yi)


@njit(parallel=True, nogil=True, cache=True)
def ska_low_station_kernel(d, s0, freq, uniform, df, positions, weights, weights_im, nelem,
                           up, station_group, chan_set, element_jones, out):
    """Station Jones matrices of one time slot, written into ``out``.

    Parameters
    ----------
    d : (ndir, 3) float64
        ITRF unit directions.
    s0 : (3,) float64
        Beam-former (delay) direction, ITRF unit vector.
    freq : (nchan,) float64
        Hz; if ``uniform``, ``freq[c] = freq[0] + c * df``.
    positions : (nstation, nelem_max, 3) float64
        Element offsets (m) of each output station, zero-padded.
    weights, weights_im : (nstation, 2, nelem_max) float64
        Per feed (X, Y) and element the real and imaginary parts of the beam-former weight
        (normalised, zero-padded; complex with element gain errors).
    nelem : (nstation,) int64
        Number of elements of each station.
    up : (nstation, 3) float64
        Station Up axes; directions with ``d . up < 0`` get zero.
    station_group : (nstation,) int64
        Index into ``element_jones`` of the station's element response.
    chan_set : (nchan,) int64
        Index into ``element_jones`` of the channel's element response frequency.
    element_jones : (ngroup, nset, ndir, 2, 2) complex128
        Element Jones matrices in the sky (North, East) basis.
    out : (nstation, nchan, ndir, 2, 2) complex64 or complex128
        Output; every element is written.
    """
    nst = positions.shape[0]
    ndir = d.shape[0]
    nchan = freq.size
    nmax = positions.shape[1]
    k = -2.0 * math.pi / SPEED_OF_LIGHT
    nblock = (ndir + _BLOCK - 1) // _BLOCK
    for job in prange(nst * nblock):
        s = job // nblock
        k0 = (job % nblock) * _BLOCK
        g = station_group[s]
        n = nelem[s]
        tau = np.empty(nmax)
        zr = np.empty(nmax)
        zi = np.empty(nmax)
        sr = np.empty(nmax)
        si = np.empty(nmax)
        afx = np.empty(nchan, np.complex128)
        afy = np.empty(nchan, np.complex128)
        for kd in range(k0, min(k0 + _BLOCK, ndir)):
            if d[kd, 0] * up[s, 0] + d[kd, 1] * up[s, 1] + d[kd, 2] * up[s, 2] < 0.0:
                for c in range(nchan):
                    for a in range(2):
                        for b in range(2):
                            out[s, c, kd, a, b] = 0.0
                continue
            dx = s0[0] - d[kd, 0]
            dy = s0[1] - d[kd, 1]
            dz = s0[2] - d[kd, 2]
            for j in range(n):
                tau[j] = k * (dx * positions[s, j, 0] + dy * positions[s, j, 1]
                              + dz * positions[s, j, 2])
            _array_factor(tau, n, weights[s, 0], weights[s, 1], weights_im[s, 0],
                          weights_im[s, 1], freq, uniform, df, zr, zi, sr, si, afx, afy)
            for c in range(nchan):
                e = chan_set[c]
                for b in range(2):
                    out[s, c, kd, 0, b] = afx[c] * element_jones[g, e, kd, 0, b]
                    out[s, c, kd, 1, b] = afy[c] * element_jones[g, e, kd, 1, b]
