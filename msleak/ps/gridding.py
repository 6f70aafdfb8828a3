"""Gridding of Stokes visibilities onto square uv cells, one channel at a time.

Two gridders share one geometry (:class:`UVGrid`): ``wgrid`` (w-corrected through ducc0's
wgridder, a one-cell ``cos^2`` kernel, :class:`WGridAccumulator`) and ``cell`` (nearest
cell, :class:`CellAccumulator`). What a cell measures, the responses R and Omega: docs/grid.md.
The kernels take u = -UVW of the MS (docs/conventions.md).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from msleak.constants import SPEED_OF_LIGHT
from msleak.errors import InputError

__all__ = [
    "Gridder", "UVGrid", "make_grid", "stokes_weights",
    "CellAccumulator", "WGridAccumulator", "make_accumulator", "GRIDDER_DESCRIPTIONS",
    "MASK_FRACTION", "BOX_FACTOR", "response_profile", "gridder_response", "image_taper",
    "airy_power", "primary_fwhm_deg", "beam_area_model", "response_attrs",
]

log = logging.getLogger(__name__)

Gridder = Literal["wgrid", "cell"]
#: a ``wgrid`` cell is used only if its kernel-weighted weight is at least this
#: fraction of its natural weight (its samples are not all on the cell's rim)
MASK_FRACTION = 0.05
#: width of the ``wgrid`` image box in units of ``1 / cell`` rad (where its response ends)
BOX_FACTOR = 4


def _check_gridder(gridder: str) -> None:
    if gridder not in ("wgrid", "cell"):
        raise InputError(f"unknown gridder {gridder!r}: use 'wgrid' or 'cell'")


def response_profile(gridder: Gridder, x: np.ndarray) -> np.ndarray:
    """One-axis image-domain amplitude response at ``x = l * cell`` (dense sampling).

    ``wgrid``: ``sinc(x) / (1 - x^2)`` for |x| < 2 (0.5 at |x| = 1), else 0 (the Fourier
    transform of the one-cell ``cos^2`` uv kernel); ``cell`` (nearest cell): ``sinc(x)``.
    """
    _check_gridder(gridder)
    x = np.asarray(x, dtype=float)
    if gridder == "cell":
        return np.sinc(x)
    ax = np.abs(x)
    near = np.abs(ax - 1.0) < 1e-6
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.sinc(x) / (1.0 - x * x)
    return np.where(ax >= 2.0, 0.0, np.where(near, 0.5, t))


def gridder_response(gridder: Gridder, l: np.ndarray, m: np.ndarray,
                     cell: float) -> np.ndarray:
    """Amplitude response ``R(l, m)`` (direction cosines) of a gridder (docs/grid.md)."""
    return (response_profile(gridder, np.asarray(l) * cell)
            * response_profile(gridder, np.asarray(m) * cell))


def image_taper(n: int) -> np.ndarray:
    """``R`` (n, n) of ``wgrid`` on its box of ``n`` pixels (``BOX_FACTOR / cell`` rad), 1
    at pixel ``n // 2`` (the phase centre); zero at the box edge."""
    x = (np.arange(n) - n // 2) / n * BOX_FACTOR
    a = response_profile("wgrid", x)
    return np.outer(a, a)


def airy_power(theta: np.ndarray, diameter: float) -> np.ndarray:
    """Power beam ``(2 J1(x) / x)^2``, ``x = pi D theta``, of a uniformly illuminated disc
    of ``diameter`` wavelengths (theta in rad); FWHM 1.029 / D rad, first null 1.22 / D."""
    from scipy.special import j1

    x = np.pi * diameter * np.asarray(theta, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.where(x == 0, 1.0, 2.0 * j1(x) / np.where(x == 0, 1.0, x))
    return a * a


def primary_fwhm_deg(diameter: float) -> float:
    """FWHM (deg) of :func:`airy_power` for an aperture of ``diameter`` wavelengths."""
    return math.degrees(1.02899 / diameter)


def beam_area_model(gridder: Gridder, cell: float, diameter: float | None = None) -> float:
    """``Omega = int A^2 R^2 dOmega`` (sr): A = :func:`airy_power` of an aperture of
    ``diameter`` wavelengths (default ``cell``: the cell is the station diameter), R the
    gridder's response (:func:`gridder_response`), small-angle (flat-sky) integral."""
    d = float(diameter or cell)
    half = 8.0 / min(cell, d)
    x = np.linspace(-half, half, 1201)
    l, m = np.meshgrid(x, x)
    f = (airy_power(np.hypot(l, m), d) * gridder_response(gridder, l, m, cell)) ** 2
    return float(f.sum() * (x[1] - x[0]) ** 2)


def response_attrs(gridder: Gridder, cell: float) -> dict:
    """uvcube attributes describing what the gridded cells see (docs/grid.md)."""
    x = np.linspace(0, 2, 20001)
    half_power = float(x[np.argmax(response_profile(gridder, x) ** 2 < 0.5)])
    return {
        "taper": "cos2" if gridder == "wgrid" else "none (nearest cell: sinc x sinc response)",
        "fov_deg": math.degrees(2 * half_power / cell),
        "fov_definition": "full width at half power of the gridder's response R^2 on an axis",
        "primary_fwhm_deg": primary_fwhm_deg(cell),
        "primary_beam_model": "Airy disc of diameter cell wavelengths (the station diameter)",
        "beam_area_sr": beam_area_model(gridder, cell),
        "beam_area_source": "int A^2 R^2 dOmega: A Airy power beam of a cell-wide aperture, "
                            "R the gridder's response",
    }


GRIDDER_DESCRIPTIONS = {
    "cell": "nearest cell, natural weighting, no w-correction",
    "wgrid": "w-corrected (ducc0 wgridder, exact w-gridding to epsilon) dirty images of a "
             "box of several station beams, times the gridder response, FFT read at the cell "
             "centres, normalised by the same for the w-corrected PSF (kernel-weighted mean "
             "per cell)",
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
        """Pixels (even, >= 32) across ``1 / cell`` rad; the ``wgrid`` box has
        :data:`BOX_FACTOR` times as many pixels of the same size."""
        n = max(32, 2 * (self.M + 2))
        return n + (n % 2)

    @property
    def pixel_rad(self) -> float:
        """Pixel size of the ``wgrid`` image box, rad (``npix_image`` pixels span ``1 / cell``)."""
        return 1.0 / (self.npix_image * self.cell)


def make_grid(cell: float, uv_max: float) -> UVGrid:
    """The grid that holds every cell a baseline up to ``uv_max`` wavelengths touches."""
    if not (cell > 0 and np.isfinite(cell)):
        raise InputError(f"cell size must be a positive number of wavelengths, got {cell}")
    if not uv_max > 0:
        raise InputError(f"the uv range maximum must be positive, got {uv_max}")
    return UVGrid(float(cell), int(math.ceil(uv_max / cell)) + 1)


def stokes_weights(weight: np.ndarray, flags: np.ndarray) -> np.ndarray:
    """Weight of a Stokes sample from the weights of its correlations (four, or two).

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
        ``n / sum_c (1 / w_c)`` over the ``n`` correlations (their harmonic mean, which
        equals ``w`` when all are ``w``), 0 where flagged or any weight <= 0.
    """
    weight = np.asarray(weight, dtype=np.float64)
    bad = np.asarray(flags, dtype=bool).any(axis=-1) | (weight <= 0).any(axis=-1)
    with np.errstate(divide="ignore"):
        inv = np.where(weight > 0, 1.0 / np.where(weight > 0, weight, 1.0), np.inf).sum(-1)
    out = np.where(bad, 0.0, weight.shape[-1] / inv)
    return np.where(np.isfinite(out), out, 0.0)


class CellAccumulator:
    """Nearest-cell accumulation of ``sum w V`` and ``sum w`` over row chunks, for one or
    several visibility sets (e.g. MS columns) on the same samples.

    Parameters
    ----------
    grid : UVGrid
    nchan : int
    nstokes : int
        Number of real-sky Stokes parameters gridded per set (I, Q, U, V: 4).
    nsets : int
        Visibility sets sharing the samples' coordinates and weights; each sample's cell
        is found once for all of them.

    Attributes
    ----------
    sum_wv : (set * stokes, chan, v, u) complex
        ``sum w V``, set-major (plane ``k * nstokes + s``).
    sum_w : (set, chan, v, u) float
    """

    def __init__(self, grid: UVGrid, nchan: int, nstokes: int = 4, nsets: int = 1):
        g = grid.size
        self.grid = grid
        self.nchan = nchan
        self.nstokes = int(nstokes)
        self.nsets = int(nsets)
        self.sum_wv = np.zeros((self.nsets * self.nstokes, nchan, g, g), dtype=np.complex128)
        self.sum_w = np.zeros((self.nsets, nchan, g, g), dtype=np.float64)

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
            wgt: np.ndarray, good: np.ndarray | None = None) -> None:
        """Add samples.

        Parameters
        ----------
        u_lambda, v_lambda : (row, chan) float
            Coordinates in wavelengths.
        vis : (stokes, row, chan) or (set, stokes, row, chan) complex
            Stokes visibilities, Jy.
        wgt : (row, chan) float
            Natural weights, shared by the sets; 0 drops a sample (flagged or outside
            the uv range).
        good : (set, row, chan) bool, optional
            False drops a sample from one set only. Default: a sample is dropped from a
            set when one of its Stokes visibilities there is not finite.
        """
        vis = np.reshape(vis, (self.nsets, self.nstokes) + np.shape(wgt))
        if good is None:
            good = np.isfinite(vis).all(axis=1)
        ok, flat, mirror = self._indices(u_lambda, v_lambda, wgt)
        size, shape = self.sum_w[0].size, self.sum_w.shape[1:]
        idx = np.concatenate([flat[ok], mirror[ok]])
        w_ok = wgt[ok]
        for k in range(self.nsets):
            keep = good[k][ok]
            w = np.where(keep, w_ok, 0.0)
            self.sum_w[k] += np.bincount(idx, np.concatenate([w, w]),
                                         minlength=size).reshape(shape)
            for s in range(self.nstokes):
                x = np.where(keep, vis[k, s][ok], 0.0) * w
                re = np.concatenate([x.real, x.real])
                im = np.concatenate([x.imag, -x.imag])
                self.sum_wv[k * self.nstokes + s] += (
                    np.bincount(idx, re, minlength=size)
                    + 1j * np.bincount(idx, im, minlength=size)).reshape(shape)

    def result(self, index: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """``(vis (stokes, chan, v, u) complex, weight (chan, v, u))`` of set ``index``,
        weighted means."""
        sum_w = self.sum_w[index]
        sum_wv = self.sum_wv[index * self.nstokes:(index + 1) * self.nstokes]
        with np.errstate(invalid="ignore", divide="ignore"):
            vis = np.where(sum_w > 0, sum_wv / sum_w, 0.0)
        return vis, sum_w.copy()

    def merge(self, other: "CellAccumulator") -> "CellAccumulator":
        out = CellAccumulator(self.grid, self.nchan, self.nstokes, self.nsets)
        out.sum_wv = self.sum_wv + other.sum_wv
        out.sum_w = self.sum_w + other.sum_w
        return out


class WGridAccumulator:
    """w-corrected gridding through ducc0 dirty images, accumulated over row chunks.

    Buffers samples and grids them (per channel, into dirty images of the Stokes
    visibilities and of unit visibilities) when ``buffer_samples`` (row x channel)
    samples are waiting, when merged or when the result is asked for; also keeps
    nearest-cell natural weights (the ``weight`` output and the empty-cell mask). The
    estimator: docs/grid.md. Several visibility sets (e.g. MS columns) on
    the same samples share the buffering, the per-channel sample selection and, where
    their weights agree, the dirty image of unit visibilities; each set's images are
    exactly those of the set gridded alone.

    Parameters
    ----------
    grid : UVGrid
    freq : (chan,) float
        Channel frequencies, Hz.
    nstokes : int
        Stokes parameters per set.
    epsilon : float
        ducc0 accuracy (relative, on the dirty image).
    nthreads : int
    buffer_samples : int
        Samples (rows x channels) buffered before gridding (~100 bytes each per set).
    nsets : int
        Visibility sets gridded together.
    """

    def __init__(self, grid: UVGrid, freq: np.ndarray, nstokes: int = 4,
                 epsilon: float = 1e-6, nthreads: int = 1, buffer_samples: int = 2_000_000,
                 nsets: int = 1):
        self.factor = BOX_FACTOR
        n = self.factor * grid.npix_image
        self.taper_image = image_taper(n)
        self.grid = grid
        self.freq = np.asarray(freq, dtype=np.float64)
        self.nchan = self.freq.size
        self.nstokes = int(nstokes)
        self.epsilon = float(epsilon)
        self.nthreads = int(nthreads)
        self.buffer_samples = int(buffer_samples)
        self.nsets = int(nsets)
        self._npix = n
        self._dirty: np.ndarray | None = None  # allocated at the first flush
        self.natural = CellAccumulator(grid, self.nchan, nstokes=0, nsets=self.nsets)
        self._buffer: list = []
        self._nbuffer = 0

    @property
    def npix(self) -> int:
        return self._npix

    @property
    def dirty(self) -> np.ndarray:
        """(set, stokes + 1, chan, n, n) dirty images (the last one of each set: unit
        visibilities)."""
        if self._dirty is None:
            n = self._npix
            self._dirty = np.zeros((self.nsets, self.nstokes + 1, self.nchan, n, n),
                                   dtype=np.float64)
        return self._dirty

    @dirty.setter
    def dirty(self, value: np.ndarray) -> None:
        self._dirty = value

    def add(self, uvw_m: np.ndarray, vis: np.ndarray, wgt: np.ndarray) -> None:
        """Add samples.

        Parameters
        ----------
        uvw_m : (row, 3) float
            uvw in metres, kernel sign convention (minus the MS's UVW).
        vis : (stokes, row, chan) or (set, stokes, row, chan) complex
            Stokes visibilities, Jy; a sample with a non-finite one is dropped from its set.
        wgt : (row, chan) float
            Natural weights, shared by the sets; 0 drops a sample.
        """
        uvw_m = np.asarray(uvw_m, dtype=np.float64)
        wgt = np.asarray(wgt, dtype=np.float64)
        vis = np.reshape(np.asarray(vis, np.complex128), (self.nsets, self.nstokes) + wgt.shape)
        good = np.isfinite(vis).all(axis=1)
        scale = self.freq / SPEED_OF_LIGHT
        self.natural.add(uvw_m[:, :1] * scale, uvw_m[:, 1:2] * scale, vis[:, :0], wgt, good)
        keep = (wgt > 0).any(axis=1)
        if not keep.any():
            return
        self._buffer.append((uvw_m[keep], vis[:, :, keep], wgt[keep], good[:, keep]))
        self._nbuffer += int(keep.sum()) * self.nchan
        if self._nbuffer >= self.buffer_samples:
            self.grid_buffer()

    def flush(self) -> None:
        """End-of-task hook: grid the buffer if it holds at least a quarter of
        ``buffer_samples``; smaller buffers travel with the accumulator and are gridded
        with others (merge, result), since each ducc0 call has a fixed cost (docs/grid.md)."""
        if self._nbuffer >= self.buffer_samples // 4:
            self.grid_buffer()

    def grid_buffer(self) -> None:
        """Grid the buffered samples into the dirty images."""
        if not self._buffer:
            return
        try:
            from ducc0.wgridder import vis2dirty
        except ImportError as err:  # pragma: no cover - ducc0 is a dependency
            raise ImportError("the wgrid gridder needs ducc0 (pip install ducc0)") from err
        uvw_m = np.concatenate([b[0] for b in self._buffer])
        vis = np.concatenate([b[1] for b in self._buffer], axis=2)
        wgt = np.concatenate([b[2] for b in self._buffer])
        good = np.concatenate([b[3] for b in self._buffer], axis=1)
        self._buffer, self._nbuffer = [], 0
        n, dl = self.npix, self.grid.pixel_rad
        for c in range(self.nchan):
            plans: list = []  # (rows, ducc0 arguments, unit-visibility image) per row set
            for k in range(self.nsets):
                rows = np.flatnonzero((wgt[:, c] > 0) & good[k, :, c])
                if rows.size == 0:
                    continue
                plan = next((p for p in plans if np.array_equal(p[0], rows)), None)
                if plan is None:
                    kw = dict(uvw=np.ascontiguousarray(uvw_m[rows]), freq=self.freq[c:c + 1],
                              wgt=np.ascontiguousarray(wgt[rows, c:c + 1]), npix_x=n,
                              npix_y=n, pixsize_x=dl, pixsize_y=dl, epsilon=self.epsilon,
                              do_wgridding=True, flip_w=True, divide_by_n=False,
                              nthreads=self.nthreads)
                    psf = vis2dirty(vis=np.ones((rows.size, 1), np.complex128), **kw)
                    plan = (rows, kw, psf)
                    plans.append(plan)
                _, kw, psf = plan
                for s in range(self.nstokes):
                    v = np.ascontiguousarray(vis[k, s, rows, c:c + 1])
                    self.dirty[k, s, c] += vis2dirty(vis=v, **kw)
                self.dirty[k, -1, c] += psf

    def numerators(self, index: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """``(N (stokes, chan, v, u), Ntilde (chan, v, u))`` of set ``index``, complex, on
        the output grid (unnormalised: one sample of weight w at a cell centre gives
        Ntilde = w sum(R) / 2 there)."""
        self.grid_buffer()
        g, n, M = self.grid.size, self.npix, self.grid.M
        # D[ix, iy] with l = (ix - n/2) dl: F[u] = sum D exp(-2 pi i (u l + v m)) on a grid
        # of cell / factor wavelengths; the cell centres are every factor-th point
        f = np.fft.fftshift(np.fft.fft2(np.fft.ifftshift(self.dirty[index] * self.taper_image,
                                                         axes=(-2, -1))),
                            axes=(-2, -1))
        idx = n // 2 + self.factor * np.arange(-M, M + 1)
        f = f[..., idx, :][..., idx]
        assert f.shape[-1] == g
        f = np.swapaxes(f, -1, -2)  # (..., u, v) -> (..., v, u)
        return f[:-1], f[-1]

    def result(self, index: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """``(vis (stokes, chan, v, u) complex, weight (chan, v, u))`` of set ``index``;
        weight is the natural weight of the used cells (0: empty or masked)."""
        num, den = self.numerators(index)
        natural = self.natural.sum_w[index]
        kernel_weight = 2.0 * den.real / self.taper_image.sum()
        ok = (natural > 0) & (kernel_weight >= MASK_FRACTION * natural)
        n_masked = int(((natural > 0) & ~ok).sum())
        if n_masked:
            log.info("wgrid: %d of %d (cell, channel) samples left empty: their samples sit "
                     "on the cell rim (kernel weight < %g of natural weight)", n_masked,
                     int((natural > 0).sum()), MASK_FRACTION)
        with np.errstate(invalid="ignore", divide="ignore"):
            vis = np.where(ok, num / np.where(ok, den, 1.0), 0.0)
        return vis, np.where(ok, natural, 0.0)

    def merge(self, other: "WGridAccumulator") -> "WGridAccumulator":
        out = WGridAccumulator(self.grid, self.freq, self.nstokes, self.epsilon,
                               self.nthreads, self.buffer_samples, self.nsets)
        if self._dirty is not None or other._dirty is not None:
            out.dirty = (self._dirty if self._dirty is not None else 0.0) + (
                other._dirty if other._dirty is not None else 0.0)
        out.natural = self.natural.merge(other.natural)
        out._buffer = self._buffer + other._buffer
        out._nbuffer = self._nbuffer + other._nbuffer
        if out._nbuffer >= out.buffer_samples:
            out.grid_buffer()
        return out


def make_accumulator(gridder: Gridder, grid: UVGrid, freq: np.ndarray, *,
                     epsilon: float = 1e-6, nthreads: int = 1, nsets: int = 1):
    """A fresh accumulator of the named gridder for ``nsets`` visibility sets."""
    if gridder == "cell":
        return CellAccumulator(grid, len(freq), nsets=nsets)
    if gridder == "wgrid":
        return WGridAccumulator(grid, freq, epsilon=epsilon, nthreads=nthreads, nsets=nsets)
    raise InputError(f"unknown gridder {gridder!r}: use 'wgrid' or 'cell'")

