"""Gridding of Stokes visibilities onto square uv cells, one channel at a time.

Two gridders share one geometry (:class:`UVGrid`): cells of ``cell`` wavelengths centred
on integer multiples of ``cell``, ``u`` and ``v`` from ``-M cell`` to ``+M cell``.

``cell``  (nearest cell, no w-correction)
    Every sample (baseline, time, channel) adds ``w V`` and ``w`` to the cell nearest to
    its ``(u, v)`` in wavelengths, and ``w conj(V)`` and ``w`` to the mirrored cell
    nearest to ``(-u, -v)`` (both Hermitian halves). The cell value is the weighted mean
    ``sum w V / sum w`` (natural weighting). Exact; agrees with a brute-force loop.

``wgrid`` (w-corrected, the default)
    Per channel, ducc0's wgridder makes the w-corrected dirty image
    ``D(l, m) = sum_k w_k Re[V_k exp(+2 pi i (u_k l + v_k m + w_k (n - 1)))]`` of an
    ``N x N`` box of pixels of ``1 / (N cell)`` rad (so the box spans ``1 / cell`` rad,
    3.58 deg for 16 wavelengths), and of unit visibilities (the w-corrected PSF at the
    phase centre). Both are multiplied by an image-domain taper ``A(l, m)`` (default Hann,
    :func:`image_taper`) and FFT'd, giving at each cell centre ``u_c``
    ``N(u_c) = sum_k w_k V_k K_k(u_k - u_c)`` and ``Ntilde(u_c) = sum_k w_k K_k(u_k - u_c)``
    with the w-projection kernel ``K_k(du) = sum_pix A exp(2 pi i (du l + w_k (n - 1)))``
    (a real image means each sample also enters conjugated at ``-u``). The cell value is
    the kernel-weighted mean ``N / Ntilde``. For a dense sampling of the uv plane it is the
    ``w = 0`` visibility at the cell centre of the sky times ``A`` (w-corrected); a point
    source at the phase centre gives exactly its flux in every cell. Cells that no sample
    falls into (natural weight 0) stay empty. Trade-off: the Hann kernel (about 2 cells
    wide) correlates neighbouring cells and narrows the effective field to ``A`` (Omega =
    int A^2 = (3/8)^2 / cell^2), but keeps the estimator stable in sparsely sampled
    cells; ``taper='none'`` keeps the whole box with a sinc-like kernel whose negative
    lobes amplify noise in edge cells (up to 30x measured on LOFAR coverage).

Sign convention of the visibilities: ``V = sum B exp(-2 pi i (u l + v m + w (n - 1)))``
(design.md) with (u, v, w) = uvw_p - uvw_q, i.e. minus the MS's UVW column (which holds
uvw_q - uvw_p); :func:`msleak.ps.uvcube.grid_ms` negates UVW accordingly
(docs/conventions.md).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from msleak.errors import InputError

__all__ = [
    "SPEED_OF_LIGHT", "Gridder", "UVGrid", "make_grid", "stokes_weights",
    "CellAccumulator", "WGridAccumulator", "make_accumulator",
    "wgrid_kernel_bruteforce", "GRIDDER_DESCRIPTIONS", "Taper", "image_taper",
    "taper_area_sr",
]

log = logging.getLogger(__name__)

SPEED_OF_LIGHT = 299_792_458.0  # m/s
Gridder = Literal["wgrid", "cell"]
Taper = Literal["hann", "none"]


def image_taper(name: Taper, n: int) -> np.ndarray:
    """Image-domain taper A (n, n) of the ``wgrid`` gridder, 1 at the phase centre.

    ``hann``: ``cos^2(pi l / L) cos^2(pi m / L)`` over the box of side L = n pixels (zero
    with zero slope at the box edge, so the uv kernel is compact and positive in its
    core: [1/4, 1/2, 1/4] at whole-cell offsets); ``none``: 1 (box; sinc-like kernel).
    """
    if name == "none":
        return np.ones((n, n))
    if name != "hann":
        raise InputError(f"unknown taper {name!r}: use 'hann' or 'none'")
    x = (np.arange(n) - n // 2) / n
    a = np.cos(np.pi * x) ** 2
    return np.outer(a, a)


def taper_area_sr(name: Taper, grid: "UVGrid") -> float:
    """``int A^2 dOmega`` (sr) of the taper over the box (the Omega it implies)."""
    a = image_taper(name, grid.npix_image)
    return float(np.sum(a ** 2) * grid.pixel_rad ** 2)

GRIDDER_DESCRIPTIONS = {
    "cell": "nearest cell, natural weighting, no w-correction",
    "wgrid": "w-corrected (ducc0 wgridder, exact w-gridding to epsilon) dirty images of a "
             "1/cell rad box, FFT to the uv plane, normalised by the FFT of the w-corrected "
             "PSF (kernel-weighted mean per cell)",
}


@dataclass(frozen=True)
class UVGrid:
    """Square uv grid: ``2 M + 1`` cells of ``cell`` wavelengths per axis, centred on 0."""

    cell: float
    M: int

    @property
    def size(self) -> int:
        return 2 * self.M + 1

    @property
    def centres(self) -> np.ndarray:
        """Cell centres (size,), wavelengths."""
        return np.arange(-self.M, self.M + 1) * self.cell

    @property
    def npix_image(self) -> int:
        """Side of the (even, >= 32) image box used by the ``wgrid`` gridder."""
        n = max(32, 2 * (self.M + 2))
        return n + (n % 2)

    @property
    def pixel_rad(self) -> float:
        """Pixel size of the image box, rad (the box spans ``1 / cell`` rad)."""
        return 1.0 / (self.npix_image * self.cell)


def make_grid(cell: float, uv_max: float) -> UVGrid:
    """The grid that holds every cell a baseline up to ``uv_max`` wavelengths touches."""
    if not (cell > 0 and np.isfinite(cell)):
        raise InputError(f"cell size must be a positive number of wavelengths, got {cell}")
    if not uv_max > 0:
        raise InputError(f"the uv range maximum must be positive, got {uv_max}")
    return UVGrid(float(cell), int(math.ceil(uv_max / cell)) + 1)


def stokes_weights(weight: np.ndarray, flags: np.ndarray) -> np.ndarray:
    """Weight of a Stokes sample from the weights of its four correlations.

    Parameters
    ----------
    weight : (row, chan, corr) float
        Per-correlation weights (inverse variances, WEIGHT_SPECTRUM or WEIGHT broadcast).
    flags : (row, chan, corr) bool
        True where a correlation is flagged; a sample with any flagged correlation is
        dropped for every Stokes parameter (each mixes two correlations).

    Returns
    -------
    (row, chan) float64
        ``4 / sum_c (1 / w_c)`` (harmonic mean of the correlation weights, which equals
        ``w`` when all four are ``w``), 0 where flagged or any weight <= 0.
    """
    weight = np.asarray(weight, dtype=np.float64)
    bad = np.asarray(flags, dtype=bool).any(axis=-1) | (weight <= 0).any(axis=-1)
    with np.errstate(divide="ignore"):
        inv = np.where(weight > 0, 1.0 / np.where(weight > 0, weight, 1.0), np.inf).sum(-1)
    out = np.where(bad, 0.0, 4.0 / inv)
    return np.where(np.isfinite(out), out, 0.0)


class CellAccumulator:
    """Nearest-cell accumulation of ``sum w V`` and ``sum w`` over row chunks.

    Parameters
    ----------
    grid : UVGrid
    nchan : int
    nstokes : int
        Number of real-sky Stokes parameters gridded (I, Q, U, V: 4).
    """

    def __init__(self, grid: UVGrid, nchan: int, nstokes: int = 4):
        g = grid.size
        self.grid = grid
        self.nchan = nchan
        self.sum_wv = np.zeros((nstokes, nchan, g, g), dtype=np.complex128)
        self.sum_w = np.zeros((nchan, g, g), dtype=np.float64)

    def _indices(self, u_lambda, v_lambda, wgt):
        g, M, cell = self.grid.size, self.grid.M, self.grid.cell
        iu = np.rint(u_lambda / cell).astype(np.int64)
        iv = np.rint(v_lambda / cell).astype(np.int64)
        ok = (wgt > 0) & (np.abs(iu) <= M) & (np.abs(iv) <= M)
        chan = np.broadcast_to(np.arange(u_lambda.shape[1])[None, :], u_lambda.shape)
        flat = (chan * g + (iv + M)) * g + (iu + M)
        mirror = (chan * g + (M - iv)) * g + (M - iu)
        return ok, flat, mirror

    def add(self, u_lambda: np.ndarray, v_lambda: np.ndarray, vis: np.ndarray,
            wgt: np.ndarray) -> None:
        """Add samples.

        Parameters
        ----------
        u_lambda, v_lambda : (row, chan) float
            Coordinates in wavelengths.
        vis : (stokes, row, chan) complex
            Stokes visibilities, Jy.
        wgt : (row, chan) float
            Natural weights; 0 drops a sample (flagged or outside the uv range).
        """
        ok, flat, mirror = self._indices(u_lambda, v_lambda, wgt)
        size = self.sum_w.size
        idx = np.concatenate([flat[ok], mirror[ok]])
        w = wgt[ok]
        ww = np.concatenate([w, w])
        self.sum_w += np.bincount(idx, ww, minlength=size).reshape(self.sum_w.shape)
        for s in range(self.sum_wv.shape[0]):
            x = vis[s][ok] * w
            re = np.concatenate([x.real, x.real])
            im = np.concatenate([x.imag, -x.imag])
            self.sum_wv[s] += (np.bincount(idx, re, minlength=size)
                               + 1j * np.bincount(idx, im, minlength=size)
                               ).reshape(self.sum_w.shape)

    def result(self) -> tuple[np.ndarray, np.ndarray]:
        """``(vis (stokes, chan, v, u) complex, weight (chan, v, u))``, weighted means."""
        with np.errstate(invalid="ignore", divide="ignore"):
            vis = np.where(self.sum_w > 0, self.sum_wv / self.sum_w, 0.0)
        return vis, self.sum_w.copy()

    def merge(self, other: "CellAccumulator") -> "CellAccumulator":
        out = CellAccumulator(self.grid, self.nchan, self.sum_wv.shape[0])
        out.sum_wv = self.sum_wv + other.sum_wv
        out.sum_w = self.sum_w + other.sum_w
        return out


class WGridAccumulator:
    """w-corrected gridding through ducc0 dirty images, accumulated over row chunks.

    Holds, per channel, the dirty images of the Stokes visibilities and of unit
    visibilities (the PSF), plus nearest-cell natural weights (for the ``weight``
    output and the empty-cell mask). See the module docstring for the estimator.

    Parameters
    ----------
    grid : UVGrid
    freq : (chan,) float
        Channel frequencies, Hz.
    nstokes : int
    epsilon : float
        ducc0 accuracy (relative, on the dirty image).
    nthreads : int
    """

    def __init__(self, grid: UVGrid, freq: np.ndarray, nstokes: int = 4,
                 epsilon: float = 1e-6, nthreads: int = 1, taper: Taper = "hann"):
        n = grid.npix_image
        self.taper = taper
        self.taper_image = image_taper(taper, n)
        self.grid = grid
        self.freq = np.asarray(freq, dtype=np.float64)
        self.nchan = self.freq.size
        self.epsilon = float(epsilon)
        self.nthreads = int(nthreads)
        self.dirty = np.zeros((nstokes + 1, self.nchan, n, n), dtype=np.float64)
        self.natural = CellAccumulator(grid, self.nchan, nstokes=0)

    def add(self, uvw_m: np.ndarray, vis: np.ndarray, wgt: np.ndarray) -> None:
        """Add samples.

        Parameters
        ----------
        uvw_m : (row, 3) float
            uvw in metres as in the MS.
        vis : (stokes, row, chan) complex
            Stokes visibilities, Jy.
        wgt : (row, chan) float
            Natural weights; 0 drops a sample.
        """
        try:
            from ducc0.wgridder import vis2dirty
        except ImportError as err:  # pragma: no cover - ducc0 is a dependency
            raise ImportError("the wgrid gridder needs ducc0 (pip install ducc0)") from err
        uvw_m = np.ascontiguousarray(uvw_m, dtype=np.float64)
        scale = self.freq / SPEED_OF_LIGHT
        self.natural.add(uvw_m[:, :1] * scale, uvw_m[:, 1:2] * scale,
                         np.zeros((0,) + wgt.shape, complex), wgt)
        n, dl = self.grid.npix_image, self.grid.pixel_rad
        for c in range(self.nchan):
            sel = np.flatnonzero(wgt[:, c] > 0)
            if sel.size == 0:
                continue
            uvw = uvw_m[sel]
            w = np.ascontiguousarray(wgt[sel, c:c + 1], dtype=np.float64)
            kw = dict(uvw=uvw, freq=self.freq[c:c + 1], wgt=w, npix_x=n, npix_y=n,
                      pixsize_x=dl, pixsize_y=dl, epsilon=self.epsilon, do_wgridding=True,
                      flip_w=True, divide_by_n=False, nthreads=self.nthreads)
            for s in range(self.dirty.shape[0] - 1):
                v = np.ascontiguousarray(vis[s, sel, c:c + 1], dtype=np.complex128)
                self.dirty[s, c] += vis2dirty(vis=v, **kw)
            self.dirty[-1, c] += vis2dirty(vis=np.ones((sel.size, 1), np.complex128), **kw)

    def numerators(self) -> tuple[np.ndarray, np.ndarray]:
        """``(N (stokes, chan, v, u), Ntilde (chan, v, u))``, complex, on the output grid."""
        g, n = self.grid.size, self.grid.npix_image
        lo = n // 2 - self.grid.M
        # D[ix, iy] with l = (ix - n/2) dl: F[u_c] = sum D exp(-2 pi i (u_c l + v_c m))
        f = np.fft.fftshift(np.fft.fft2(np.fft.ifftshift(self.dirty * self.taper_image,
                                                         axes=(-2, -1))),
                            axes=(-2, -1))
        f = f[..., lo:lo + g, lo:lo + g]
        f = np.swapaxes(f, -1, -2)  # (..., u, v) -> (..., v, u)
        return f[:-1], f[-1]

    def result(self) -> tuple[np.ndarray, np.ndarray]:
        """``(vis (stokes, chan, v, u) complex, weight (chan, v, u))``."""
        num, den = self.numerators()
        weight = self.natural.sum_w.copy()
        ok = weight > 0
        with np.errstate(invalid="ignore", divide="ignore"):
            vis = np.where(ok, num / np.where(ok, den, 1.0), 0.0)
        return vis, weight

    def merge(self, other: "WGridAccumulator") -> "WGridAccumulator":
        out = WGridAccumulator(self.grid, self.freq, self.dirty.shape[0] - 1,
                               self.epsilon, self.nthreads, self.taper)
        out.dirty = self.dirty + other.dirty
        out.natural = self.natural.merge(other.natural)
        return out


def make_accumulator(gridder: Gridder, grid: UVGrid, freq: np.ndarray, *,
                     epsilon: float = 1e-6, nthreads: int = 1, taper: Taper = "hann"):
    """A fresh accumulator of the named gridder."""
    if gridder == "cell":
        return CellAccumulator(grid, len(freq))
    if gridder == "wgrid":
        return WGridAccumulator(grid, freq, epsilon=epsilon, nthreads=nthreads, taper=taper)
    raise InputError(f"unknown gridder {gridder!r}: use 'wgrid' or 'cell'")


def wgrid_kernel_bruteforce(grid: UVGrid, u: float, v: float, w: float,
                            taper: Taper = "hann") -> np.ndarray:
    """Direct evaluation of the ``wgrid`` kernel of one sample on the output grid.

    Returns ``K(v_c, u_c) = sum_pix exp(2 pi i ((u - u_c) l + (v - v_c) m + w (n - 1)))``,
    shape (size, size), for tests and documentation (slow: O(npix^2 size^2)).
    """
    n, dl = grid.npix_image, grid.pixel_rad
    x = (np.arange(n) - n // 2) * dl
    l, m = np.meshgrid(x, x, indexing="ij")
    nn = np.sqrt(1.0 - l * l - m * m) - 1.0
    c = grid.centres
    ex_u = np.exp(2j * np.pi * np.outer(u - c, x))  # (u_c, l)
    ex_v = np.exp(2j * np.pi * np.outer(v - c, x))  # (v_c, m)
    ph = np.exp(2j * np.pi * w * nn) * image_taper(taper, n)  # (l, m)
    return np.einsum("al,lm,bm->ba", ex_u, ph, ex_v)
