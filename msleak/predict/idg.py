"""Image-domain gridding (IDG) degridder: visibilities of a pixel sky through per-station,
per-time beams at a cost that does not grow with the number of sky pixels.

The quantity is the one of :mod:`msleak.predict.kernels` (MS convention,
uvw_pq = x_q - x_p)::

    V_pq(t, nu) = sum_s J_p(s) B_s J_q(s)^H exp(+2 pi i (u l + v m + w (n - 1)))

for a sky on a regular (l, m) grid (pixel (y, x) at l = (x - cx) dl, m = (y - cy) dl),
computed as in van der Tol, Veenboer & Offringa (2018, A&A 616, A27):

* per channel the sky, divided by the taper T, is Fourier transformed once onto a grid of
  ``PAD`` x npix cells (cell du = 1 / (PAD npix dl) wavelengths);
* per baseline, channel and chunk of consecutive times, the nsub x nsub cells around the
  chunk's uv centre (u0, v0) are cut out and transformed back to an nsub x nsub
  "subgrid image" covering the padded field (:func:`subgrid_directions`);
* per time, that image is multiplied by T, by the phase
  exp(+2 pi i ((u - u0) l + (v - v0) m + w (n - 1))) and by that time's beams
  (J_p S J_q^H), and summed (a direct Fourier transform over nsub^2 pixels).

This is exact when the product h(l, m) = T x phase x beams, seen as a function on the
padded field, holds only the nsub x nsub lowest Fourier modes; the error is the part of
its spectrum outside them, amplified by 1 / T at the sky's edge.

Accuracy parameter ``epsilon`` (choice of the taper). T(l, m) = phi(2 l / P) phi(2 m / P)
with P = PAD npix dl the padded field and phi(z) = exp(beta (sqrt(1 - z^2) - 1)) the
"exponential of semicircle" function (the kernel of ducc0 and FINUFFT, here used in the
image domain). Its Fourier series holds, to a level exp(-beta), the modes
|k| <= beta / pi (the width of phi's spectrum), and the sky, inside |z| <= 1 / PAD, is
divided by at most 1 / phi(1 / PAD) = exp(beta (1 - sqrt(1 - 1 / PAD^2))). With PAD = 2
the error is about exp(-0.866 beta), so beta = ln(1 / epsilon) / 0.866 (:func:`taper_beta`)
and the taper needs :func:`taper_halfwidth` = beta / pi + 1 cells on each side of the
visibility's offset from the subgrid centre. PAD = 2 keeps the one FFT per channel small
((2 npix)^2) and the amplification moderate (exp(0.134 beta), 8.5 at epsilon = 1e-6);
docs/predict.md gives the measured accuracy.

W-stacking (van der Tol et al. 2018, w-layers). The rest of the nsub cells hold the
offsets |u - u0|, |v - v0| of the chunk's times and the w-term, whose local frequency on
the subgrid field is at most |w| (P / 2) / n_corner cycles per radian, i.e.
|w| P^2 / (2 n_corner) cells. Of the free cells,
F = nsub / 2 - 1 - taper_halfwidth - support - 0.5 per side (``support``: the beams',
below), half go to the w-term: the rows of a channel are split into w-layers of width
dw = F n_corner / (P^2 / 2) wavelengths (:func:`w_layer_width`), layer k holding the rows
with round(w / dw) = k. Per layer and channel the sky divided by T and multiplied by
exp(+2 pi i w_k (n - 1)), w_k = k dw, evaluated exactly at the sky pixels, is Fourier
transformed (one FFT per layer and channel), and the subgrid holds only the residual
w - w_k (at most F / 2 cells). When all |w| < dw / 2 there is one layer, w_k = 0. A
chunk (rows of one baseline and one layer) is extended by one time while
taper_halfwidth + support + 0.5 + max |u - u0| + max |w - w_k| P^2 / (2 n_corner)
<= nsub / 2 - 1 (in cells, each axis). ``nsub`` too small for the taper and the beams
(F <= 0) is refused.
The beams' own spectrum widens h: ``support`` cells per side (measured by the caller,
:func:`msleak.predict.gridsky.beam_support`) are kept free for it like the taper's, in the
w-layer width and in the chunks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import ducc0
import numba as nb
import numpy as np

from msleak.constants import SPEED_OF_LIGHT
from msleak.predict.kernels import sandwich
from msleak.predict.options import DegridOptions

__all__ = ["PAD", "taper_beta", "taper_halfwidth", "taper_1d", "w_layer_width",
           "subgrid_directions", "rotate_columns", "degrid"]

#: Padding of the sky grid: the uv grid has PAD x npix cells per axis.
PAD = 2
#: ln(1 / error) per unit beta: the taper's spectral tail exp(-beta) times the largest
#: correction 1 / T = exp(beta (1 - sqrt(1 - 1 / PAD^2))) inside the sky.
_DECAY = math.sqrt(1.0 - 1.0 / PAD**2)


def taper_beta(epsilon: float) -> float:
    """Shape parameter beta of the taper for a requested relative accuracy ``epsilon``
    (0 < epsilon < 1)."""
    if not 0.0 < epsilon < 1.0:
        raise ValueError(f"epsilon must be in (0, 1), not {epsilon}")
    return math.log(1.0 / epsilon) / _DECAY


def taper_halfwidth(epsilon: float) -> float:
    """Cells of the uv grid the taper's spectrum occupies on each side (beta / pi + 1)."""
    return taper_beta(epsilon) / math.pi + 1.0


def w_layer_width(nsub: int, npix: int, dl: float, epsilon: float,
                  support: float = 0.0) -> float:
    """Width dw (wavelengths) of the w-layers of :func:`degrid` (module docstring).

    Parameters
    ----------
    nsub : int
        Subgrid size.
    npix : int
        Sky size (pixels per axis).
    dl : float
        Sky pixel size (direction cosine).
    epsilon : float
        Requested relative accuracy.
    support : float
        Cells the beams' spectrum takes on each side (:func:`degrid`'s ``support``).

    Returns
    -------
    float
        dw such that a residual |w - w_k| <= dw / 2 takes half of the subgrid's cells
        left by the taper. Refuses (ValueError) an ``nsub`` with no cell left.
    """
    free = nsub / 2 - 1.0 - taper_halfwidth(epsilon) - support - 0.5
    if free <= 0.0:
        need = 2 * math.ceil(taper_halfwidth(epsilon) + support + 2.5)
        what = f" and the beam's {support:.1f} cells" if support else ""
        verb = "need" if support else "needs"
        raise ValueError(f"epsilon {epsilon:g}{what} {verb} nsub >= {need}, not {nsub}")
    big_p = PAD * npix * dl
    return free / _w_cells(big_p)


def _w_cells(big_p: float) -> float:
    """Subgrid cells per wavelength of w: P^2 / (2 n_corner), n at the padded field's corner."""
    return big_p * big_p / 2.0 / math.sqrt(max(1e-12, 1.0 - big_p * big_p / 2.0))


def _phi(z: np.ndarray, beta: float) -> np.ndarray:
    """exp(beta (sqrt(1 - z^2) - 1)) for |z| <= 1."""
    return np.exp(beta * (np.sqrt(np.clip(1.0 - z * z, 0.0, None)) - 1.0))


def taper_1d(nsub: int, beta: float) -> np.ndarray:
    """The taper along one axis of an nsub-pixel subgrid (pixel j at
    z = 2 (j - nsub / 2) / nsub of the padded field's half-width)."""
    return _phi((np.arange(nsub) - nsub // 2) * 2.0 / nsub, beta)


def subgrid_directions(nsub: int, npix: int, dl: float) -> np.ndarray:
    """Directions at which the beams are given to :func:`degrid`.

    Parameters
    ----------
    nsub : int
        Subgrid size (even, >= 8).
    npix : int
        Sky size (pixels per axis).
    dl : float
        Sky pixel size (direction cosine, i.e. rad at the phase centre).

    Returns
    -------
    (nsub * nsub, 3) float64
        (l, m, n - 1) of the subgrid pixels, pixel (jy, jx) at row jy * nsub + jx with
        l = (jx - nsub / 2) P / nsub, m = (jy - nsub / 2) P / nsub, P = PAD npix dl (the
        padded field, twice the sky's width).
    """
    if nsub < 8 or nsub % 2:
        raise ValueError(f"nsub must be even and >= 8, not {nsub}")
    step = PAD * npix * dl / nsub
    if (nsub / 2) * step * math.sqrt(2.0) >= 1.0:
        raise ValueError("the padded field (twice the sky's width) must stay within "
                         "the horizon: reduce npix * dl")
    j = (np.arange(nsub) - nsub // 2) * step
    m, l = np.meshgrid(j, j, indexing="ij")
    r2 = l * l + m * m
    nm1 = -r2 / (1.0 + np.sqrt(1.0 - r2))
    return np.stack([l.ravel(), m.ravel(), nm1.ravel()], axis=-1)


class _SkyGrids:
    """The uv grids of one channel's sky, one per w-layer: F[k_v, k_u] =
    sum_(y, x) B'(y, x) exp(+2 pi i (k_u x + k_v y) / G) of the brightness matrix entries
    (00, 01, 10, 11) divided by the taper and multiplied by the w-layer's phase
    exp(+2 pi i w_k (n - 1)) (G = PAD npix). One (4, G, G) buffer is reused."""

    def __init__(self, iquv: np.ndarray, beta: float, centre: float, dl: float):
        npix = iquv.shape[0]
        self.npix, self.g = npix, PAD * npix
        t1 = _phi(2.0 * (np.arange(npix) - centre) / self.g, beta)  # z = 2 (x - cx) dl / P
        scale = 1.0 / np.outer(t1, t1)
        i, q, u, v = (iquv[..., k] * scale for k in range(4))
        self.entries = np.stack([i + q, u + 1j * v, u - 1j * v, i - q])
        ax = (np.arange(npix) - centre) * dl
        r2 = ax[:, None] ** 2 + ax[None, :] ** 2
        self.nm1 = -r2 / (1.0 + np.sqrt(1.0 - r2))
        self.buffer = np.empty((4, self.g, self.g), dtype=np.complex128)

    def layer(self, w_k: float) -> np.ndarray:
        """The (4, G, G) grids of w-layer ``w_k`` (overwritten by the next call)."""
        n, out = self.npix, self.buffer
        out[:, n:, :] = 0.0
        out[:, :n, n:] = 0.0
        if w_k == 0.0:
            out[:, :n, :n] = self.entries
        else:
            np.multiply(self.entries, np.exp((2j * np.pi * w_k) * self.nm1),
                        out=out[:, :n, :n])
        threads = nb.get_num_threads()
        # rows n.. are zero: transform along u for the sky's rows only, then along v
        ducc0.fft.c2c(out[:, :n, :], axes=(2,), forward=False, out=out[:, :n, :],
                      nthreads=threads)
        return ducc0.fft.c2c(out, axes=(1,), forward=False, out=out, nthreads=threads)


@nb.njit(cache=True, nogil=True)
def _plan_chunks(uc, vc, wc, base, nsub, hw, wfac):
    """Greedy chunks of consecutive rows (sorted by baseline, then time): a row joins the
    current chunk while the chunk's uv spread, the taper and the w-term fit in nsub."""
    n = uc.shape[0]
    starts = np.empty(n + 1, dtype=np.int64)
    k0u = np.empty(n, dtype=np.int64)
    k0v = np.empty(n, dtype=np.int64)
    limit = nsub / 2 - 1.0
    nch = 0
    r = 0
    while r < n:
        starts[nch] = r
        umin = umax = uc[r]
        vmin = vmax = vc[r]
        wmax = abs(wc[r])
        e = r + 1
        while e < n and base[e] == base[r]:
            a, b = min(umin, uc[e]), max(umax, uc[e])
            c, d = min(vmin, vc[e]), max(vmax, vc[e])
            ww = max(wmax, abs(wc[e]))
            need = hw + 0.5 + ww * wfac
            if (b - a) / 2 + need > limit or (d - c) / 2 + need > limit:
                break
            umin, umax, vmin, vmax, wmax = a, b, c, d, ww
            e += 1
        k0u[nch] = int(round((umin + umax) / 2))
        k0v[nch] = int(round((vmin + vmax) / 2))
        nch += 1
        r = e
    starts[nch] = n
    return starts[:nch + 1], k0u[:nch], k0v[:nch]


@nb.njit(cache=True, nogil=True)
def _cut(grid, k0u, k0v, centre, nsub, out):
    """out[c, e] = (-1)^(kx + ky) F_e(k0 + k) for the nsub x nsub cells of chunk c, with
    F(k) = grid[k mod G] exp(-2 pi i (k_u + k_v) cx / G) (the sky's centre offset)."""
    g = grid.shape[1]
    h = nsub // 2
    fu = np.empty(nsub, dtype=np.complex128)
    fv = np.empty(nsub, dtype=np.complex128)
    for c in range(k0u.shape[0]):
        for i in range(nsub):
            sign = -1.0 if i % 2 else 1.0
            a = -2.0 * math.pi * ((k0u[c] + i - h) * centre / g)
            fu[i] = sign * complex(math.cos(a), math.sin(a))
            b = -2.0 * math.pi * ((k0v[c] + i - h) * centre / g)
            fv[i] = sign * complex(math.cos(b), math.sin(b))
        for iy in range(nsub):
            kv = (k0v[c] + iy - h) % g
            for ix in range(nsub):
                ku = (k0u[c] + ix - h) % g
                f = fv[iy] * fu[ix]
                for e in range(4):
                    out[c, e, iy, ix] = f * grid[e, kv, ku]


@nb.njit(fastmath=True, cache=True, inline="always")
def _cis(g):
    """cos g + i sin g to about 1e-14 (plus 1e-16 |g| from the reduction): g reduced to
    [-pi, pi], Taylor series of half the angle to the 20th power, then the double angle;
    unlike libm's sin and cos, a loop of it vectorizes (7 times faster measured)."""
    x = g - 2.0 * math.pi * math.floor(g * (0.5 / math.pi) + 0.5)
    h = 0.5 * x
    h2 = h * h
    s = h * (1.0 - h2 / 6.0 * (1.0 - h2 / 20.0 * (1.0 - h2 / 42.0 * (1.0 - h2 / 72.0 * (
        1.0 - h2 / 110.0 * (1.0 - h2 / 156.0 * (1.0 - h2 / 210.0 * (1.0 - h2 / 272.0 * (
            1.0 - h2 / 342.0)))))))))
    c = 1.0 - h2 / 2.0 * (1.0 - h2 / 12.0 * (1.0 - h2 / 30.0 * (1.0 - h2 / 56.0 * (
        1.0 - h2 / 90.0 * (1.0 - h2 / 132.0 * (1.0 - h2 / 182.0 * (1.0 - h2 / 240.0 * (
            1.0 - h2 / 306.0))))))))
    return complex(c * c - s * s, 2.0 * s * c)


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def _subgrid_dft(sub, starts, k0u, k0v, rows, uvw, du, lmn1, taper, jones, has_beam,
                 left, has_left, p, q, tidx, c, out):
    """out[row, c] = L_p (sum_j taper_j phase_j J_p(j) S_j J_q(j)^H) L_q^H for the rows of
    every chunk (S_j: the chunk's subgrid image, phase with the offsets from the chunk's
    centre; L: ``left`` if ``has_left``)."""
    nsub = sub.shape[2]
    npx = nsub * nsub
    nbs, nbt, nbc = jones.shape[0], jones.shape[1], jones.shape[2]
    jc = c if nbc > 1 else 0
    lbs, lbt, lbc = left.shape[0], left.shape[1], left.shape[2]
    lc = c if lbc > 1 else 0
    for ch in nb.prange(k0u.shape[0]):
        ex = np.empty(nsub, dtype=np.complex128)
        ey = np.empty(nsub, dtype=np.complex128)
        tw = np.empty(npx, dtype=np.complex128)
        for r in range(starts[ch], starts[ch + 1]):
            row = rows[r]
            uu = uvw[row, 0] - k0u[ch] * du
            vv = uvw[row, 1] - k0v[ch] * du
            ww = 2.0 * math.pi * uvw[row, 2]
            for j in range(nsub):
                ex[j] = _cis(2.0 * math.pi * uu * lmn1[j, 0])
                ey[j] = _cis(2.0 * math.pi * vv * lmn1[j * nsub, 1])
            for j in range(npx):  # taper x w-term, in a loop of its own (vectorized)
                tw[j] = taper[j] * _cis(ww * lmn1[j, 2])
            jt = tidx[row] if nbt > 1 else 0
            jp = p[row] if nbs > 1 else 0
            jq = q[row] if nbs > 1 else 0
            acc0 = acc1 = acc2 = acc3 = 0j
            for iy in range(nsub):
                for ix in range(nsub):
                    j = iy * nsub + ix
                    f = tw[j] * ex[ix] * ey[iy]
                    s00 = sub[ch, 0, iy, ix]
                    s01 = sub[ch, 1, iy, ix]
                    s10 = sub[ch, 2, iy, ix]
                    s11 = sub[ch, 3, iy, ix]
                    if has_beam:  # J_p S J_q^H
                        s00, s01, s10, s11 = sandwich(
                            jones[jp, jt, jc, j, 0, 0], jones[jp, jt, jc, j, 0, 1],
                            jones[jp, jt, jc, j, 1, 0], jones[jp, jt, jc, j, 1, 1],
                            s00, s01, s10, s11,
                            jones[jq, jt, jc, j, 0, 0], jones[jq, jt, jc, j, 0, 1],
                            jones[jq, jt, jc, j, 1, 0], jones[jq, jt, jc, j, 1, 1])
                    acc0 += f * s00
                    acc1 += f * s01
                    acc2 += f * s10
                    acc3 += f * s11
            if has_left:
                lt = tidx[row] if lbt > 1 else 0
                lp = p[row] if lbs > 1 else 0
                lq = q[row] if lbs > 1 else 0
                acc0, acc1, acc2, acc3 = sandwich(
                    left[lp, lt, lc, 0, 0], left[lp, lt, lc, 0, 1], left[lp, lt, lc, 1, 0],
                    left[lp, lt, lc, 1, 1], acc0, acc1, acc2, acc3,
                    left[lq, lt, lc, 0, 0], left[lq, lt, lc, 0, 1], left[lq, lt, lc, 1, 0],
                    left[lq, lt, lc, 1, 1])
            out[row, c, 0, 0] = acc0
            out[row, c, 0, 1] = acc1
            out[row, c, 1, 0] = acc2
            out[row, c, 1, 1] = acc3


def _per_station(name: str, array, nst: int, nt: int, nchan: int, tail: tuple) -> tuple:
    """(``array`` (nst | 1, nt | 1, nchan | 1, *tail) as complex128 for the kernels,
    whether it is given); None gives a size-1 placeholder; refuses a wrong shape."""
    if array is None:
        return np.zeros((1, 1, 1) + tuple(1 if n > 2 else n for n in tail),
                        dtype=np.complex128), False
    array = np.ascontiguousarray(array, dtype=np.complex128)
    if array.shape[3:] != tail or any(
            array.shape[a] not in (1, n) for a, n in enumerate((nst, nt, nchan))):
        raise ValueError(f"{name} has shape {array.shape}, expected ({nst} | 1, {nt} | 1, "
                         f"{nchan} | 1, {', '.join(map(str, tail))})")
    return array, True


@nb.njit(parallel=True, cache=True, nogil=True)
def rotate_columns(jones, rot, out):
    """out[i, j] = jones[i, j] @ rot[j] for Jones matrices (n, ndir, 2, 2) and real
    rotations (ndir, 2, 2) (a loop of 2 x 2 products, far faster than numpy's matmul on
    stacks of 2 x 2 matrices)."""
    for i in nb.prange(jones.shape[0]):
        for j in range(jones.shape[1]):
            for a in range(2):
                x0, x1 = jones[i, j, a, 0], jones[i, j, a, 1]
                out[i, j, a, 0] = x0 * rot[j, 0, 0] + x1 * rot[j, 1, 0]
                out[i, j, a, 1] = x0 * rot[j, 0, 1] + x1 * rot[j, 1, 1]


def _subgrid_taper(nsub: int, beta: float) -> np.ndarray:
    """(nsub^2,) taper at the subgrid pixels times (-1)^(jx + jy) / nsub^2 (the centring
    and normalisation of the subgrid's FFT)."""
    t1 = taper_1d(nsub, beta)
    odd = np.arange(nsub) % 2
    sign = 1 - 2 * (odd[:, None] ^ odd[None, :])
    return (np.outer(t1, t1) * sign / nsub**2).ravel()


def degrid(brightness: np.ndarray, dl: float, freq: np.ndarray, xyz: np.ndarray,
           tidx: np.ndarray, p: np.ndarray, q: np.ndarray, jones: np.ndarray | None, *,
           nsub: int = 32, epsilon: float = DegridOptions.epsilon, support: float = 0.0,
           jones_left: np.ndarray | None = None, centre: float | None = None,
           batch: int = 4096) -> np.ndarray:
    """Visibilities of a pixel sky by image-domain gridding (see the module docstring).

    Parameters
    ----------
    brightness : (nchan, npix, npix, 4) float
        Stokes (I, Q, U, V) in Jy per pixel, pixel [c, y, x] at l = (x - cx) dl (East),
        m = (y - cy) dl (North), SIN projection.
    dl : float
        Pixel size (direction cosine).
    freq : (nchan,) float
        Channel frequencies (Hz).
    xyz : (ntime, nstation, 3) float
        Per-station coordinates (m), uvw_pq = x_q - x_p (MS convention).
    tidx, p, q : (nrow,) int
        Time index into ``xyz`` and stations of every row.
    jones : (nstation | 1, ntime | 1, nchan | 1, nsub * nsub, 2, 2) complex or None
        Beam Jones matrices (linear feeds) at :func:`subgrid_directions` (nsub, npix, dl);
        size-1 axes broadcast. None: no beam.
    nsub : int
        Subgrid size (even); larger allows longer chunks and wider w-layers (fewer FFTs).
    epsilon : float
        Requested relative accuracy (sets the taper, module docstring).
    support : float
        Cells of the uv grid (1 / P wavelengths) the spectrum of the beam products
        J_p J_q^H takes on each side; they are kept free of the chunk's uv spread and
        w-term like the taper's (module docstring).
    jones_left : (nstation | 1, ntime | 1, nchan | 1, 2, 2) complex, optional
        L_p with V'_pq = L_p V_pq L_q^H (the phase-centre correction J_p(s0)^-1), applied
        to each visibility instead of to the Jones matrix of every direction.
    centre : float, optional
        Pixel index cx = cy of l = m = 0 (default (npix - 1) / 2: the centre of the grid,
        CRPIX = (npix + 1) / 2 as `msleak sky` writes).
    batch : int
        Chunks transformed at once (memory: 64 nsub^2 bytes per chunk).

    Returns
    -------
    (nrow, nchan, 2, 2) complex128
        Visibility matrices [[XX, XY], [YX, YY]] of every row and channel.
    """
    iquv = np.asarray(brightness, dtype=np.float64)
    freq = np.atleast_1d(np.asarray(freq, dtype=np.float64))
    nchan, npix = iquv.shape[0], iquv.shape[1]
    if iquv.shape != (nchan, npix, npix, 4) or freq.shape != (nchan,):
        raise ValueError(f"brightness must be (nchan, npix, npix, 4) with nchan = "
                         f"{freq.size} channels, not {iquv.shape}")
    lmn1 = subgrid_directions(nsub, npix, dl)
    xyz = np.asarray(xyz, dtype=np.float64)
    tidx, p, q = (np.ascontiguousarray(a, dtype=np.int64) for a in (tidx, p, q))
    nst, nt = xyz.shape[1], xyz.shape[0]
    jones, has_beam = _per_station("jones", jones, nst, nt, nchan, (nsub * nsub, 2, 2))
    left, has_left = _per_station("jones_left", jones_left, nst, nt, nchan, (2, 2))
    cx = (npix - 1) / 2.0 if centre is None else float(centre)
    dw = w_layer_width(nsub, npix, dl, epsilon, support)
    beta = taper_beta(epsilon)
    kernel = _Kernel(beta=beta, hw=taper_halfwidth(epsilon) + support, big_p=PAD * npix * dl,
                     lmn1=lmn1, taper=_subgrid_taper(nsub, beta), jones=jones,
                     has_beam=has_beam, left=left, has_left=has_left, p=p, q=q, tidx=tidx, nsub=nsub, batch=batch)
    uvw_m = xyz[tidx, q] - xyz[tidx, p]
    base = p * (q.max(initial=0) + 1) + q
    out = np.empty((tidx.size, nchan, 2, 2), dtype=np.complex128)
    for c in range(nchan):
        uvw = uvw_m * (freq[c] / SPEED_OF_LIGHT)
        layer = np.rint(uvw[:, 2] / dw).astype(np.int64)
        uvw[:, 2] -= layer * dw  # the residual w - w_k the subgrids hold
        order = np.lexsort((tidx, base, layer))
        bounds = np.flatnonzero(np.diff(layer[order])) + 1
        grids = _SkyGrids(iquv[c], kernel.beta, cx, dl)
        for rows in np.split(order, bounds):
            if rows.size:
                kernel.run(grids.layer(layer[rows[0]] * dw), uvw, rows, base[rows], cx, c,
                           out)
        del grids
    return out


@dataclass
class _Kernel:
    """The constants of one :func:`degrid` call; :meth:`run` chunks, cuts and sums the
    subgrids of one w-layer of one channel."""

    beta: float
    hw: float
    big_p: float
    lmn1: np.ndarray
    taper: np.ndarray
    jones: np.ndarray
    has_beam: bool
    left: np.ndarray
    has_left: bool
    p: np.ndarray
    q: np.ndarray
    tidx: np.ndarray
    nsub: int
    batch: int

    def run(self, grid: np.ndarray, uvw: np.ndarray, rows: np.ndarray, base: np.ndarray,
            cx: float, c: int, out: np.ndarray) -> None:
        """Fill out[rows, c] from the layer's uv ``grid``; ``uvw`` (wavelengths) holds the
        residual w of every row, ``rows`` are sorted by baseline (``base``), then time."""
        nsub, big_p = self.nsub, self.big_p
        wfac = _w_cells(big_p)
        cells = uvw[rows] * big_p
        starts, k0u, k0v = _plan_chunks(cells[:, 0], cells[:, 1], uvw[rows, 2], base, nsub,
                                        self.hw, wfac)
        for b0 in range(0, k0u.size, self.batch):
            b1 = min(k0u.size, b0 + self.batch)
            sub = np.empty((b1 - b0, 4, nsub, nsub), dtype=np.complex128)
            _cut(grid, k0u[b0:b1], k0v[b0:b1], cx, nsub, sub)
            ducc0.fft.c2c(sub, axes=(2, 3), forward=True, out=sub,
                          nthreads=nb.get_num_threads())
            _subgrid_dft(sub, starts[b0:b1 + 1], k0u[b0:b1], k0v[b0:b1], rows, uvw,
                         1.0 / big_p, self.lmn1, self.taper, self.jones, self.has_beam,
                         self.left, self.has_left, self.p, self.q, self.tidx, c, out)
