"""Gridding of Stokes visibilities onto square uv cells, one channel at a time.

Two gridders share one geometry (:class:`UVGrid`): ``wgrid`` (w-corrected through ducc0's
wgridder, a one-cell ``cos^2`` kernel, :class:`WGridAccumulator`) and ``cell`` (nearest
cell, :class:`CellAccumulator`). What a cell measures, the responses R and Omega: docs/grid.md.
The kernels take u = -UVW of the MS (docs/conventions.md).
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from msleak.constants import SPEED_OF_LIGHT
from msleak.errors import InputError

__all__ = [
    "GRID_EPSILON",
    "Gridder", "UVGrid", "make_grid", "stokes_weights",
    "CellAccumulator", "WGridAccumulator", "make_accumulator", "accumulator_bytes",
    "GRIDDER_DESCRIPTIONS",
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
#: relative accuracy of the w-corrected gridder (ducc0) unless asked otherwise
GRID_EPSILON = 1e-6


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
    weight : (row, chan, corr) or (row, 1, corr) float
        Per-correlation weights (inverse variances: WEIGHT_SPECTRUM, or WEIGHT for every
        channel).
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


def _stokes(corr: np.ndarray, to_stokes: np.ndarray) -> np.ndarray:
    """(stokes, ...) complex128 ``to_stokes @ corr`` of correlations (..., corr); numpy's
    own loops, not BLAS, whose threads would compete with the gridder's."""
    return np.einsum("...c,sc->s...", corr, to_stokes)


def _hermitian_sum(idx: np.ndarray, x: np.ndarray, size: int) -> np.ndarray:
    """(size,) complex sums of ``x`` at the first half of the flat cells ``idx`` and of
    its conjugate at the second half (the mirror cells)."""
    re = np.concatenate([x.real, x.real])
    im = np.concatenate([x.imag, -x.imag])
    return np.bincount(idx, re, minlength=size) + 1j * np.bincount(idx, im, minlength=size)


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
    to_stokes : (stokes, corr) complex, optional
        Given: :meth:`add` takes correlations and forms the Stokes visibilities
        ``corr @ to_stokes.T`` one set at a time.

    Attributes
    ----------
    sum_wv : (set * stokes, chan, v, u) complex
        ``sum w V``, set-major (plane ``k * nstokes + s``).
    sum_w : (set, chan, v, u) float
    """

    def __init__(self, grid: UVGrid, nchan: int, nstokes: int = 4, nsets: int = 1,
                 to_stokes: np.ndarray | None = None):
        g = grid.size
        self.grid = grid
        self.nchan = nchan
        self.nstokes = int(nstokes)
        self.nsets = int(nsets)
        self.to_stokes = None if to_stokes is None else np.asarray(to_stokes, np.complex128)
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
            Stokes visibilities, Jy; with ``to_stokes``: correlations (set, row, chan,
            corr).
        wgt : (row, chan) float
            Natural weights, shared by the sets; 0 drops a sample (flagged or outside
            the uv range).
        good : (set, row, chan) bool, optional
            False drops a sample from one set only. Default: a sample is dropped from a
            set when one of its Stokes visibilities there is not finite.
        """
        if self.to_stokes is None:
            vis = np.reshape(vis, (self.nsets, self.nstokes) + np.shape(wgt))
        else:
            vis = np.reshape(vis, (self.nsets,) + np.shape(wgt) + (-1,))
        ok, flat, mirror = self._indices(u_lambda, v_lambda, wgt)
        idx = np.concatenate([flat[ok], mirror[ok]])
        del flat, mirror
        w_ok = wgt[ok]
        for k in range(self.nsets):
            self._add_set(k, vis[k], None if good is None else good[k], ok, idx, w_ok)

    def _add_set(self, k: int, vis: np.ndarray, good: np.ndarray | None, ok: np.ndarray,
                 idx: np.ndarray, w_ok: np.ndarray) -> None:
        """Add set ``k`` (its visibilities as :meth:`add` takes them) at the cells ``idx``
        of its ``ok`` samples (and their mirrors), of weights ``w_ok``."""
        if self.to_stokes is not None:
            vis = _stokes(vis, self.to_stokes)
        keep = (np.isfinite(vis).all(axis=0) if good is None else good)[ok]
        w = np.where(keep, w_ok, 0.0)
        size, shape = self.sum_w[0].size, self.sum_w.shape[1:]
        self.sum_w[k] += np.bincount(idx, np.concatenate([w, w]), minlength=size).reshape(shape)
        for s in range(self.nstokes):
            self.sum_wv[k * self.nstokes + s] += _hermitian_sum(
                idx, np.where(keep, vis[s][ok], 0.0) * w, size).reshape(shape)

    def result(self, index: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """``(vis (stokes, chan, v, u) complex, weight (chan, v, u))`` of set ``index``,
        weighted means."""
        sum_w = self.sum_w[index]
        sum_wv = self.sum_wv[index * self.nstokes:(index + 1) * self.nstokes]
        with np.errstate(invalid="ignore", divide="ignore"):
            vis = np.where(sum_w > 0, sum_wv / sum_w, 0.0)
        return vis, sum_w.copy()

    def merge(self, other: "CellAccumulator") -> "CellAccumulator":
        """Add ``other``'s sums to this accumulator (in place) and return it."""
        self.sum_wv += other.sum_wv
        self.sum_w += other.sum_w
        return self


class WGridAccumulator:
    """w-corrected gridding through ducc0 dirty images, accumulated over row chunks.

    Buffers samples and grids them when ``buffer_samples`` (row x channel) samples are
    waiting, when merged or when the result is asked for: per channel, the dirty images of
    the Stokes visibilities and of unit visibilities are tapered, Fourier transformed and
    read at the cell centres one by one, and only those cell values are summed. Also keeps
    nearest-cell natural weights (the ``weight`` output and the empty-cell mask). The
    estimator: docs/grid.md. Several visibility sets (e.g. MS columns) on the same samples
    share the buffering, the per-channel sample selection and, where their weights agree,
    the image of unit visibilities; each set's sums are exactly those of the set gridded
    alone.

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
        Samples (rows x channels) buffered before gridding: 8 bytes each for the weights,
        per set the visibilities as given and 1 byte of validity, 24 per row for uvw.
    nsets : int
        Visibility sets gridded together.
    channel_threads : int
        Channels gridded at once (each with its own ``nthreads`` ducc0 calls); the sums
        do not depend on it. Settable as the attribute ``channel_threads``.
    to_stokes : (stokes, corr) complex, optional
        Given: :meth:`add` takes correlations, which wait in the buffer as given (e.g.
        complex64, half the size of complex128 Stokes visibilities) and become the Stokes
        visibilities ``corr @ to_stokes.T`` channel by channel when gridded.
    """

    def __init__(self, grid: UVGrid, freq: np.ndarray, nstokes: int = 4,
                 epsilon: float = GRID_EPSILON, nthreads: int = 1, buffer_samples: int = 2_000_000,
                 nsets: int = 1, channel_threads: int = 1,
                 to_stokes: np.ndarray | None = None):
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
        self.channel_threads = int(channel_threads)
        self._takes_correlations = to_stokes is not None
        # Stokes visibilities are kept as (set, row, chan, stokes) views, "correlations"
        # whose Stokes visibilities are themselves
        self._to_stokes = (np.eye(self.nstokes, dtype=np.complex128) if to_stokes is None
                           else np.asarray(to_stokes, np.complex128))
        self._npix = n
        self._centres = n // 2 + self.factor * np.arange(-grid.M, grid.M + 1)
        self._cells: np.ndarray | None = None  # allocated at the first gridding
        self.natural = CellAccumulator(grid, self.nchan, nstokes=0, nsets=self.nsets)
        self._buffer: list = []
        self._nbuffer = 0

    @property
    def npix(self) -> int:
        return self._npix

    def add(self, uvw_m: np.ndarray, vis: np.ndarray, wgt: np.ndarray) -> None:
        """Add samples.

        Parameters
        ----------
        uvw_m : (row, 3) float
            uvw in metres, kernel sign convention (minus the MS's UVW).
        vis : (stokes, row, chan) or (set, stokes, row, chan) complex
            Stokes visibilities, Jy; with ``to_stokes``: correlations (set, row, chan,
            corr). A sample with a non-finite one is dropped from its set (with
            ``to_stokes``, an invertible matrix, a non-finite correlation makes a Stokes
            visibility non-finite).
        wgt : (row, chan) float
            Natural weights, shared by the sets; 0 drops a sample.

        The rows with a weight wait in the buffer until gridded; when every row has one,
        the arrays wait as given (uvw and weights in float64, Stokes visibilities in
        complex128: not copied), so leave them unchanged.
        """
        uvw_m = np.asarray(uvw_m, dtype=np.float64)
        wgt = np.asarray(wgt, dtype=np.float64)
        vis = self._as_correlations(vis, wgt.shape)
        good = np.empty((self.nsets,) + wgt.shape, bool)
        for k in range(self.nsets):
            good[k] = np.isfinite(vis[k]).all(axis=-1)
        scale = self.freq / SPEED_OF_LIGHT
        self.natural.add(uvw_m[:, :1] * scale, uvw_m[:, 1:2] * scale,
                         np.empty((self.nsets, 0) + wgt.shape, np.complex128), wgt, good)
        keep = (wgt > 0).any(axis=1)
        if not keep.any():
            return
        if not keep.all():
            uvw_m, vis, wgt, good = uvw_m[keep], vis[:, keep], wgt[keep], good[:, keep]
        self._buffer.append((uvw_m, vis, wgt, good))
        self._nbuffer += int(keep.sum()) * self.nchan
        if self._nbuffer >= self.buffer_samples:
            self.grid_buffer()

    def _as_correlations(self, vis, shape: tuple) -> np.ndarray:
        """``vis`` as given to :meth:`add`, viewed as (set, row, chan, corr)."""
        if self._takes_correlations:
            return np.reshape(np.asarray(vis), (self.nsets,) + shape + (-1,))
        vis = np.reshape(np.asarray(vis, np.complex128), (self.nsets, self.nstokes) + shape)
        return np.moveaxis(vis, 1, -1)

    def flush(self) -> None:
        """End-of-task hook: grid the buffer if it holds at least a quarter of
        ``buffer_samples``; smaller buffers travel with the accumulator and are gridded
        with others (merge, result), since each ducc0 call has a fixed cost (docs/grid.md)."""
        if self._nbuffer >= self.buffer_samples // 4:
            self.grid_buffer()

    def grid_buffer(self) -> None:
        """Grid the buffered samples into the cell sums, channel by channel, up to
        ``channel_threads`` channels at once (the buffer is not copied: each ducc0 call
        gathers its channel's samples)."""
        if not self._buffer:
            return
        try:
            from ducc0.wgridder import vis2dirty
        except ImportError as err:  # pragma: no cover - ducc0 is a dependency
            raise ImportError("the wgrid gridder needs ducc0 (pip install ducc0)") from err
        buffer, self._buffer, self._nbuffer = self._buffer, [], 0
        if self._cells is None:
            g = self.grid.size
            self._cells = np.zeros((self.nsets, self.nstokes + 1, self.nchan, g, g),
                                   np.complex128)
        threads = max(1, min(self.channel_threads, self.nchan))
        one = functools.partial(self._grid_channel, vis2dirty, buffer)
        if threads == 1:
            for c in range(self.nchan):
                one(c)
            return
        from concurrent.futures import ThreadPoolExecutor

        # ducc0 and the FFTs release the GIL; each channel adds to its own cells only
        with ThreadPoolExecutor(threads, thread_name_prefix="msleak-wgrid") as pool:
            list(pool.map(one, range(self.nchan)))

    def _grid_channel(self, vis2dirty, buffer: list, c: int) -> None:
        """Add channel ``c`` of the buffered blocks to the cell sums (``vis2dirty``: ducc0's)."""
        n, dl = self.npix, self.grid.pixel_rad
        plans: list = []  # (row masks of the buffered blocks, ducc0 arguments, PSF cells)
        weighted = [wgt[:, c] > 0 for _, _, wgt, _ in buffer]
        for k in range(self.nsets):
            masks = [w & good[k, :, c] for w, (_, _, _, good) in zip(weighted, buffer)]
            if not any(m.any() for m in masks):
                continue
            plan = next((p for p in plans if all(map(np.array_equal, p[0], masks))), None)
            if plan is None:
                w = np.concatenate([b[2][m, c] for b, m in zip(buffer, masks)])
                kw = dict(uvw=np.concatenate([b[0][m] for b, m in zip(buffer, masks)]),
                          freq=self.freq[c:c + 1], wgt=w.reshape(-1, 1), npix_x=n,
                          npix_y=n, pixsize_x=dl, pixsize_y=dl, epsilon=self.epsilon,
                          do_wgridding=True, flip_w=True, divide_by_n=False,
                          nthreads=self.nthreads)
                psf = vis2dirty(vis=np.ones((w.size, 1), np.complex128), **kw)
                plan = (masks, kw, self._at_cells(psf))
                plans.append(plan)
            _, kw, psf = plan
            corr = np.concatenate([b[1][k, m, c] for b, m in zip(buffer, masks)])
            stokes = _stokes(corr, self._to_stokes)
            for s in range(self.nstokes):
                self._cells[k, s, c] += self._at_cells(
                    vis2dirty(vis=stokes[s].reshape(-1, 1), **kw))
            self._cells[k, -1, c] += psf

    def _at_cells(self, image: np.ndarray) -> np.ndarray:
        """(v, u) complex: the Fourier transform of the tapered (n, n) dirty ``image`` at
        the cell centres."""
        # D[ix, iy] with l = (ix - n/2) dl: F[u] = sum D exp(-2 pi i (u l + v m)) on a grid
        # of cell / factor wavelengths; the cell centres are every factor-th point
        f = np.fft.fftshift(np.fft.fft2(np.fft.ifftshift(image * self.taper_image)))
        return f[np.ix_(self._centres, self._centres)].T

    def numerators(self, index: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """``(N (stokes, chan, v, u), Ntilde (chan, v, u))`` of set ``index``, complex, on
        the output grid (unnormalised: one sample of weight w at a cell centre gives
        Ntilde = w sum(R) / 2 there)."""
        self.grid_buffer()
        g = self.grid.size
        f = (np.zeros((self.nstokes + 1, self.nchan, g, g), np.complex128)
             if self._cells is None else self._cells[index].copy())
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
        """Move ``other``'s sums and buffered samples into this accumulator (``other`` is
        left without them) and return it."""
        if other._cells is not None:
            if self._cells is None:
                self._cells = other._cells
            else:
                self._cells += other._cells
        self.natural.merge(other.natural)
        self._buffer += other._buffer
        self._nbuffer += other._nbuffer
        other._cells, other._buffer, other._nbuffer = None, [], 0
        if self._nbuffer >= self.buffer_samples:
            self.grid_buffer()
        return self


def make_accumulator(gridder: Gridder, grid: UVGrid, freq: np.ndarray, *,
                     epsilon: float = GRID_EPSILON, nthreads: int = 1, nsets: int = 1,
                     buffer_samples: int = 2_000_000, channel_threads: int = 1,
                     to_stokes: np.ndarray | None = None):
    """A fresh accumulator of the named gridder for ``nsets`` visibility sets, taking
    correlations when ``to_stokes`` is given (``epsilon``, ``nthreads``,
    ``buffer_samples`` and ``channel_threads``: ``wgrid`` only)."""
    if gridder == "cell":
        return CellAccumulator(grid, len(freq), nsets=nsets, to_stokes=to_stokes)
    if gridder == "wgrid":
        return WGridAccumulator(grid, freq, epsilon=epsilon, nthreads=nthreads, nsets=nsets,
                                buffer_samples=buffer_samples,
                                channel_threads=channel_threads, to_stokes=to_stokes)
    raise InputError(f"unknown gridder {gridder!r}: use 'wgrid' or 'cell'")


def accumulator_bytes(gridder: Gridder, grid: UVGrid, nchan: int, nsets: int = 1) -> int:
    """Bytes of the arrays an accumulator of ``nsets`` sets and ``nchan`` channels holds
    once it has gridded: complex128 cells per Stokes parameter (and, for ``wgrid``, of
    unit visibilities), float64 natural weights; for ``wgrid`` also its float64 taper of
    the image box."""
    _check_gridder(gridder)
    if gridder == "cell":
        return nsets * nchan * grid.size ** 2 * (4 * 16 + 8)
    return (nsets * nchan * grid.size ** 2 * (5 * 16 + 8)
            + 8 * (BOX_FACTOR * grid.npix_image) ** 2)

