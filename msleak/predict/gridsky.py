"""Pixel skies predicted by image-domain gridding (:mod:`msleak.predict.idg`) instead of
the direct sum (docs/predict.md, "Image-domain gridding").

A FITS cube, sky Dataset or SkyCube re-centred on the phase centre is a regular (l, m)
grid; :func:`pixel_grid` recognises it and refers its Q, U to one smooth basis: the phase
centre's (North, East) basis parallel-transported to every pixel
(:func:`msleak.beam.coords.transport_angle`). The local North basis of the direct path
turns by 360 deg around a celestial pole, so a beam given in it is not smooth across a
field at the pole, and the degridder samples the beam only at nsub x nsub directions.
:func:`degrid_visibilities` evaluates the beam at those directions (plus the phase centre
for the centre correction), turns its columns into the same transported basis and folds
J(s0)^-1 into it: J' = J(s0)^-1 J(s) R(psi), B' = R^T B R, so J' B' J'^H equals the
direct path's J(s0)^-1 J B J^H J(s0)^-H.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from msleak.beam.base import centre_correction as correction_of
from msleak.beam.coords import (basis_rotation, lm_to_radec, radec_to_unit, transport_angle,
                                 zenith_j2000)
from msleak.constants import SPEED_OF_LIGHT
from msleak.errors import InputError
from msleak.predict import idg
from msleak.predict.kernels import lmn_minus_one

__all__ = ["PixelGrid", "Geometry", "DegridRefused", "pixel_grid", "choose_method",
           "worth_degridding", "beam_support", "zenith_pass", "zenith_near", "subgrid_size",
           "degrid_geometry", "degrid_visibilities",
           "AUTO_MIN_PIXELS", "FALLBACK_MAX_PIXELS", "DEFAULT_NSUB", "FREE_CELLS",
           "PLAN_NSUB", "PIXEL_BEAM_BYTES", "DEGRID_BATCH", "DEGRID_PIXEL_BYTES",
           "CONTRACT_MARGIN"]

#: ``method="auto"`` degrids pixel skies with at least this many pixels (docs/predict.md)
AUTO_MIN_PIXELS = 6400
#: ``method="auto"`` predicts a chunk of a pixel sky directly where cheaper only below
#: this many pixels (larger skies are always degridded: no beam at every pixel is planned)
FALLBACK_MAX_PIXELS = 4 * AUTO_MIN_PIXELS
#: smallest subgrid size chosen (w-layers serve any |w|)
DEFAULT_NSUB = 32
#: uv cells per side a chosen subgrid keeps, beyond the taper and the beam, for a chunk's
#: uv spread and w residual (docs/predict.md, "Subgrid size from the beam")
FREE_CELLS = 4.0
#: subgrid size the memory planner assumes when it is chosen from the beam (a larger one
#: is degridded a few times at a time, :func:`degrid_visibilities`)
PLAN_NSUB = 48
#: memory of a degridded sky per pixel besides the chunk's (bytes): the w-layer grids and
#: the sky's brightness entries (:class:`msleak.predict.idg._SkyGrids`), one channel of
#: the transported sky
DEGRID_PIXEL_BYTES = 480
#: beam at every pixel of a pixel sky summed directly: at most this many bytes at once
PIXEL_BEAM_BYTES = 512 * 2**20
#: an all-sky sky's beam blocks take at least this many bytes, whatever the memory limit
MIN_PIXEL_BEAM_BYTES = 64 * 2**20
#: directions per axis at which the beam's spectrum is measured
_PROBE = 64
#: part of the beam's spectrum's norm below which a slowly decaying floor ends the
#: measurement (:func:`beam_support`)
_FLOOR = 1e-3
#: subgrids transformed at once by a chunk task (memory: 128 nsub^2 bytes each, FFT included)
DEGRID_BATCH = 512
#: cost of one uv-grid cell of a w-layer's FFT, in pixels of one visibility of the
#: direct sum (docs/predict.md)
_FFT_COST = 18.0
#: largest deviation of a pixel from the fitted (l, m) grid, in pixels
_GRID_RTOL = 1e-6

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PixelGrid:
    """A pixel sky on a regular (l, m) grid about the phase centre.

    Attributes
    ----------
    iquv : (nchan, npix, npix, 4) float64
        Stokes (I, Q, U, V) in Jy per pixel on the MS channels, Q, U in each pixel's local
        (North, East) basis; pixel [c, y, x] at l = (x - centre) dl (East),
        m = (y - centre) dl (North).
    psi : (npix, npix) float64
        Angle (rad, towards East) from each pixel's local North to the phase centre's
        North parallel-transported there (:func:`msleak.beam.coords.transport_angle`).
    dl : float
        Pixel size (direction cosine).
    centre : float
        Pixel index of l = m = 0 on both axes.
    ra0, dec0 : float
        Phase centre (rad).
    epsilon : float
        Requested accuracy of the degridder.
    nsub : int or None
        Subgrid size; None: :data:`DEFAULT_NSUB` (or what epsilon's taper needs).
    auto : bool
        Chosen by ``method="auto"``: a chunk for which the direct sum is cheaper (few
        rows spanning many w-layers) is predicted directly (:func:`worth_degridding`).
    site : (3,) tuple of float or None
        ITRF position (m) of the array's centre: the beam is also probed when the zenith
        is nearest the field (:func:`degrid_geometry`); None: it is not (the zenith is
        then not looked for).
    site_spread : float
        Largest angle (rad) between a used station's zenith and the site's.
    stokes : tuple of int
        The Stokes parameters (0..3 for I, Q, U, V) the sky has flux in.
    """

    iquv: np.ndarray
    psi: np.ndarray
    dl: float
    centre: float
    ra0: float
    dec0: float
    epsilon: float
    nsub: int | None
    auto: bool = False
    site: tuple | None = None
    site_spread: float = 0.0
    stokes: tuple = (0, 1, 2, 3)

    @property
    def npix(self) -> int:
        return int(self.iquv.shape[1])

    @property
    def nbytes(self) -> int:
        return int(self.iquv.nbytes + self.psi.nbytes)

    def transported(self, channels: slice) -> np.ndarray:
        """``iquv[channels]`` with Q, U in the transported basis: B' = R^T B R,
        R = :func:`msleak.beam.coords.basis_rotation` (psi)."""
        iquv = np.array(self.iquv[channels])
        rot = basis_rotation(self.psi)                                    # (y, x, 2, 2)
        q, u = iquv[..., 1], iquv[..., 2]
        qu = np.stack([np.stack([q, u], -1), np.stack([u, -q], -1)], -2)  # (c, y, x, 2, 2)
        turned = np.einsum("yxba,cyxbd,yxde->cyxae", rot, qu, rot)
        iquv[..., 1], iquv[..., 2] = turned[..., 0, 0], turned[..., 0, 1]
        return iquv


def _axis_fit(values: np.ndarray, axis: int) -> tuple[float, float] | None:
    """(step, index of zero) of ``values`` (ny, nx) linear along ``axis`` and constant
    across it, or None."""
    n = values.shape[axis]
    if n < 2:
        return None
    idx = np.arange(n, dtype=float).reshape((-1, 1) if axis == 0 else (1, -1))
    step = float(np.mean(np.diff(values, axis=axis)))
    if step == 0.0:
        return None
    zero = float(np.mean(idx - values / step))
    if np.max(np.abs(values / step - (idx - zero))) > _GRID_RTOL:
        return None
    return step, zero


def pixel_grid(ra: np.ndarray, dec: np.ndarray, iquv: np.ndarray, shape: tuple[int, int],
               ra0: float, dec0: float, *, epsilon: float, nsub: int | None,
               site=None, site_spread: float = 0.0) -> PixelGrid | None:
    """The pixels of a cube as a :class:`PixelGrid`, or None when they are not a square
    regular (l, m) grid with the same centre index on both axes.

    Parameters
    ----------
    ra, dec : (ny * nx,) rad
        Pixel directions, y-major (:func:`msleak.sky.sources.sources_from_cube`).
    iquv : (ny * nx, nchan, 4) Jy
        Stokes I, Q, U, V on the MS channels, Q and U in each pixel's local (North, East)
        basis.
    shape : (ny, nx)
    ra0, dec0 : phase centre, rad
    site : (3,) array, optional
        ITRF position (m) of the array's centre (:attr:`PixelGrid.site`).
    site_spread : float
        :attr:`PixelGrid.site_spread` (rad).
    """
    ny, nx = shape
    if ny != nx:
        return None
    lmn1 = lmn_minus_one(ra, dec, ra0, dec0)
    l_, m_ = lmn1[:, 0].reshape(ny, nx), lmn1[:, 1].reshape(ny, nx)
    fit_l, fit_m = _axis_fit(l_, 1), _axis_fit(m_, 0)
    if fit_l is None or fit_m is None or np.any(lmn1[:, 2] <= -1.0):
        return None
    (sx, cx), (sy, cy) = fit_l, fit_m
    if sx < 0:
        cx = nx - 1 - cx
    if sy < 0:
        cy = ny - 1 - cy
    if not (math.isclose(abs(sx), abs(sy), rel_tol=_GRID_RTOL) and abs(cx - cy) < _GRID_RTOL):
        return None
    flip = (slice(None, None, -1 if sy < 0 else 1), slice(None, None, -1 if sx < 0 else 1))
    psi = transport_angle(ra0, dec0, ra, dec).reshape(ny, nx)[flip]
    cube = np.transpose(np.asarray(iquv, dtype=np.float64).reshape(ny, nx, -1, 4),
                        (2, 0, 1, 3))[(slice(None),) + flip]
    stokes = tuple(int(k) for k in np.flatnonzero(np.any(cube != 0, axis=(0, 1, 2))))
    return PixelGrid(iquv=np.ascontiguousarray(cube), psi=np.ascontiguousarray(psi),
                     dl=abs(sx), centre=0.5 * (cx + cy),
                     ra0=float(ra0), dec0=float(dec0), epsilon=float(epsilon), nsub=nsub,
                     site=None if site is None else tuple(float(c) for c in site),
                     site_spread=float(site_spread), stokes=stokes)


def choose_method(method: str, grid: PixelGrid | None, npixels: int, label: str,
                  is_cube: bool) -> str:
    """``direct`` or ``degrid`` for one sky (refuses ``degrid`` where it cannot run)."""
    if method == "degrid":
        if not is_cube:
            raise InputError(f"method degrid needs a pixel sky (FITS cube, sky Dataset, "
                             f"SkyCube); {label} is a list of point sources: use method "
                             "direct or auto", param="method")
        if grid is None:
            raise InputError(f"method degrid: the pixels of {label} are not a square "
                             "regular SIN grid about the phase centre; use method direct",
                             param="method")
        _check_field(grid, label)
        return "degrid"
    if method == "direct" or grid is None or npixels < AUTO_MIN_PIXELS:
        return "direct"
    try:
        _check_field(grid, label)
    except InputError:
        return "direct"
    return "degrid"


@dataclass(frozen=True)
class Geometry:
    """Subgrid size and the uv cells per side the beam products take (``support`` of
    :func:`msleak.predict.idg.degrid`) for one sky and chunk."""

    nsub: int
    support: float


def worth_degridding(grid: PixelGrid, geometry: Geometry, xyz: np.ndarray,
                     tidx: np.ndarray, p: np.ndarray, q: np.ndarray,
                     freq: np.ndarray) -> bool:
    """Whether degridding these rows is cheaper than the direct sum: always with
    ``method="degrid"`` and for skies of :data:`FALLBACK_MAX_PIXELS` pixels or more;
    with "auto" while the modelled costs per channel (in units of one pixel of one
    visibility of the direct sum) favour it::

        nrow npix^2 >= nrow nsub^2 AUTO_MIN_PIXELS / 32^2 + (layers - 1) (2 npix)^2 18

    The first term is the measured break-even without w-layers, the second the extra
    FFTs of the w-layers the rows span (:func:`msleak.predict.idg.w_layer_width`), 18
    the measured cost of an FFT cell in pixels of the direct sum (docs/predict.md)."""
    if not grid.auto or grid.npix ** 2 >= FALLBACK_MAX_PIXELS:
        return True
    nsub = geometry.nsub
    dw = idg.w_layer_width(nsub, grid.npix, grid.dl, grid.epsilon, geometry.support)
    w = (xyz[tidx, q, 2] - xyz[tidx, p, 2]) * float(np.max(freq)) / SPEED_OF_LIGHT
    layers = 1 if w.size == 0 else int(np.rint(w.max() / dw) - np.rint(w.min() / dw)) + 1
    degrid = (tidx.size * nsub ** 2 * AUTO_MIN_PIXELS / DEFAULT_NSUB ** 2
              + (layers - 1) * (idg.PAD * grid.npix) ** 2 * _FFT_COST)
    return tidx.size * grid.npix ** 2 >= degrid


def _check_field(grid: PixelGrid, label: str) -> None:
    try:
        idg.subgrid_directions(grid.nsub or DEFAULT_NSUB, grid.npix, grid.dl)
    except ValueError as err:
        raise InputError(f"method degrid: {label}: {err} (fov), or use method "
                         "direct", param=("method", "fov")) from None


def subgrid_size(grid: PixelGrid, support: float = 0.0) -> int:
    """The subgrid size for a beam whose products take ``support`` uv cells per side:
    ``grid.nsub`` (refused when too small for ``grid.epsilon``'s taper and the beam), or
    the smallest even size >= :data:`DEFAULT_NSUB` that leaves :data:`FREE_CELLS` per
    side beyond them; any |w| fits through w-layers."""
    if grid.nsub is not None:
        try:
            idg.w_layer_width(grid.nsub, grid.npix, grid.dl, grid.epsilon, support)
        except ValueError as err:
            raise InputError(f"nsub {grid.nsub}: {err}", param="nsub") from None
        return grid.nsub
    need = 1.5 + idg.taper_halfwidth(grid.epsilon) + support + FREE_CELLS
    return max(DEFAULT_NSUB, 2 * math.ceil(need))


class DegridRefused(InputError):
    """Degridding cannot meet the accuracy asked of a chunk; ``reason`` says why (one
    line, no remedy), the message adds the remedy."""

    def __init__(self, reason: str):
        super().__init__(f"method degrid: {reason}; use method direct", param="method")
        self.reason = reason


def beam_support(grid: PixelGrid, beam_model, time: float, freq: float,
                 stations: np.ndarray, centre_correction: bool) -> tuple[float, float]:
    """uv cells per side (of 1 / P, P the padded field) that the beam products take,
    measured at one time and frequency, and the part of the Jones spectrum's norm left
    beyond them (largest over stations); (0, 0) without a beam.

    Per station, the Jones matrices J' that :func:`degrid_visibilities` uses are taken at
    64 x 64 directions across the padded field, multiplied by the degridder's taper T and
    Fourier transformed. With t(r) the part of the spectrum's norm outside the square of
    half-width r, r_p is the smallest r with t(r) <= epsilon, or where t, below 1e-3,
    has reached a slowly decaying floor (t(r) <= 10 t(r + 4)). T alone, measured the same
    way, takes r_T cells, so J'_p takes r_p - r_T, and a product of two stations twice the
    largest of those.

    The leakage contract: the Stokes I and V a sky's Stokes parameters
    (:attr:`PixelGrid.stokes`) give through each station with itself and with the next
    (:func:`_stokes_response`) must each have t(r) <= epsilon / :data:`CONTRACT_MARGIN`
    at some r_L, with no floor allowed; their products take r_L - r_T cells (r_T at the
    same threshold), and the support is the larger of the two. A beam that is not finite,
    whose Jones spectrum comes within 4 cells of the probe's 32, or whose I or V
    response never reaches that threshold within them (EveryBeam's LOFAR element
    response and UVBeam's (az, za) grid near the zenith, docs/predict.md), is refused
    (:class:`DegridRefused`)."""
    if beam_model is None:
        return 0.0, 0.0
    jones, left = _subgrid_jones(grid, beam_model, _PROBE, np.array([time]),
                                 np.array([freq]), stations, centre_correction)
    jones = jones[:, 0, 0] if left is None else left[:, 0, 0, None] @ jones[:, 0, 0]
    if not np.all(np.isfinite(jones)):
        raise DegridRefused("the beam is not a finite number at some of the probed directions")
    t1 = idg.taper_1d(_PROBE, idg.taper_beta(grid.epsilon))
    taper = np.outer(t1, t1)[None, :, :, None]
    taper_tail = _spectral_tail(taper)[0]
    r_taper = int(np.argmax(taper_tail <= grid.epsilon))
    tail = _spectral_tail(jones.reshape(-1, _PROBE, _PROBE, 4) * taper)
    ahead = np.append(tail[:, 4:], np.zeros((len(tail), 4)), axis=1)
    done = (tail <= grid.epsilon) | ((tail <= _FLOOR) & (tail <= 10.0 * ahead))
    r_p = np.argmax(done, axis=1)                # a station with no response: r_p = 0
    worst = float(np.nanmax(tail[np.arange(len(tail)), r_p], initial=0.0))
    r = int(np.max(r_p))
    limit = _PROBE // 2 - 4
    if r >= limit:
        left_at = float(np.nanmax(tail[:, limit], initial=0.0))
        raise DegridRefused(f"the beam has structure finer than {_PROBE} directions across "
                            f"the padded {np.degrees(idg.PAD * grid.npix * grid.dl):.1f} deg "
                            f"field resolve ({left_at:.1e} of it left)")
    r_leak, leak_left = _stokes_reach(jones, grid, taper, limit)
    if r_leak is None:
        raise DegridRefused(f"the beam's Stokes I and V response keeps {leak_left:.1e} of its "
                            f"spectrum beyond any subgrid, above epsilon {grid.epsilon:g} / "
                            f"{CONTRACT_MARGIN:g}")
    r_taper_leak = int(np.argmax(taper_tail <= grid.epsilon / CONTRACT_MARGIN))
    return max(2.0 * max(0, r - r_taper), float(max(0, r_leak - r_taper_leak))), worst


#: a Stokes response whose rms is at most this part of the station's mean Jones power is
#: rounding (:func:`_stokes_reach`)
_ROUNDING = 1e-12
#: the Stokes I and V responses must leave at most epsilon / CONTRACT_MARGIN of their
#: spectrum beyond the subgrid: degridded Stokes I and V were measured up to 3.4 times
#: the part left (docs/predict.md, "The leakage contract")
CONTRACT_MARGIN = 4.0
#: brightness matrices of unit Stokes I, Q, U, V (linear feeds, docs/conventions.md)
_STOKES_B = np.array([[[1, 0], [0, 1]], [[1, 0], [0, -1]], [[0, 1], [1, 0]],
                      [[0, 1j], [-1j, 0]]], dtype=np.complex128)


def _stokes_response(jones: np.ndarray, stokes: tuple) -> np.ndarray:
    """(nst, ndir, 2, len(stokes), 2): the Stokes I (index 0 of axis 2) and V (1) of
    J_p B_k J_q^H for unit Stokes ``k`` in ``stokes``, with q = p (last axis 0) and q the
    next station (1), from Jones (nst, ndir, 2, 2)."""
    other = np.roll(np.arange(len(jones)), -1)
    out = np.empty((len(jones), jones.shape[1], 2, len(stokes), 2), np.complex128)
    for i, k in enumerate(stokes):
        for j, right in enumerate((jones, jones[other])):
            c = jones @ _STOKES_B[k] @ np.conj(np.swapaxes(right, -1, -2))
            out[:, :, 0, i, j] = 0.5 * (c[..., 0, 0] + c[..., 1, 1])
            out[:, :, 1, i, j] = -0.5j * (c[..., 0, 1] - c[..., 1, 0])
    return out


def _stokes_reach(jones: np.ndarray, grid: PixelGrid, taper: np.ndarray, limit: int
                  ) -> tuple[int | None, float]:
    """(r_L, 0): the half-width holding all but epsilon / :data:`CONTRACT_MARGIN` of the
    spectrum of every Stokes I and V response (:func:`_stokes_response`) of ``jones``
    (nst, probe^2, 2, 2) times ``taper``, per station, output and input Stokes; (None, the
    largest part left at ``limit``) when one never gets there. A sky with Q or U has both
    (the transported basis mixes them)."""
    stokes = sorted(set(grid.stokes) | ({1, 2} if {1, 2} & set(grid.stokes) else set()))
    resp = _stokes_response(jones, tuple(stokes))
    nst, nin = len(jones), len(stokes)
    fields = np.moveaxis(resp.reshape(nst, _PROBE, _PROBE, 2 * nin, 2), 3, 1)
    tail = _spectral_tail(fields.reshape(-1, _PROBE, _PROBE, 2) * taper)
    # a response at the rounding level of the station's power (none: V from Q through a
    # real rotation) has nothing to hold
    power = np.mean(np.sum(np.abs(jones) ** 2, axis=(2, 3)), axis=1)            # (nst,)
    rms = np.sqrt(np.mean(np.abs(fields) ** 2, axis=(2, 3, 4))).reshape(-1)    # (nst 2nin,)
    tail[rms <= _ROUNDING * np.repeat(power, 2 * nin)] = 0.0
    ok = tail[:, :limit] <= grid.epsilon / CONTRACT_MARGIN
    if not ok.any(axis=1).all():
        return None, float(np.max(tail[:, limit - 1]))
    return int(np.max(np.argmax(ok, axis=1))), 0.0


def _spectral_tail(field: np.ndarray) -> np.ndarray:
    """t[i, r]: the part of the norm of the 2D spectrum of ``field[i]`` (n, n, entries)
    outside the square of half-width r cells, r = 0..n/2."""
    n = field.shape[1]
    power = np.sum(np.abs(np.fft.fft2(field, axes=(1, 2))) ** 2, axis=-1)
    k = np.abs(np.fft.fftfreq(n, 1.0 / n))
    radius = np.maximum(k[:, None], k[None, :]).astype(np.int64).ravel()
    rings = np.stack([np.bincount(radius, weights=pw.ravel(), minlength=n // 2 + 1)
                      for pw in power])
    outside = np.cumsum(rings[:, ::-1], axis=1)[:, ::-1]        # outside[r] = sum_{>= r}
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(np.append(outside[:, 1:], np.zeros((len(rings), 1)), axis=1)
                       / outside[:, :1])


#: geometries already logged in this process (one line per sky size and result)
_LOGGED: set = set()


def degrid_geometry(grid: PixelGrid, beam_model, times: np.ndarray, freq: np.ndarray,
                    stations: np.ndarray, centre_correction: bool) -> Geometry:
    """The :class:`Geometry` of a chunk: the beam's support measured (:func:`beam_support`)
    at the chunk's first, middle and last times and, when the zenith comes within the
    padded field, at the time it is nearest the phase centre (:func:`zenith_pass`), at
    the highest frequency (the largest support), and the subgrid size from it
    (:func:`subgrid_size`); logged once per sky size and result. A probe that refuses
    (:class:`DegridRefused`) names its time and the zenith's distance."""
    passing = zenith_pass(grid, times)
    probe = [] if passing is None else [passing]  # first: the likeliest to refuse
    probe += [float(t) for t in np.unique(times[[0, times.size // 2, -1]]) if t not in probe]
    results = []
    for t in probe:
        try:
            results.append(beam_support(grid, beam_model, t, float(np.max(freq)), stations,
                                        centre_correction))
        except DegridRefused as err:
            if grid.site is None:
                raise
            distance = np.degrees(_zenith_distance(grid, t)[0])
            raise DegridRefused(f"{err.reason} at {_iso(t)}, the zenith {distance:.1f} deg "
                                "from the phase centre") from None
    support, left = max(p[0] for p in results), max(p[1] for p in results)
    geometry = Geometry(nsub=subgrid_size(grid, support), support=support)
    key = (grid.npix, grid.dl, grid.epsilon, geometry)
    if key not in _LOGGED:
        _LOGGED.add(key)
        log.info("degrid %d x %d pixels: the beam takes %.1f uv cells per side at %.3f MHz, "
                 "subgrids of %d x %d (beam probed at %d times)", grid.npix, grid.npix,
                 support, np.max(freq) / 1e6, geometry.nsub, geometry.nsub, len(probe))
        if left > grid.epsilon:
            log.info("degrid %d x %d pixels: the beam's Jones spectrum keeps %.1e of its norm "
                     "beyond the subgrid's reach (a floor of the beam model, above epsilon "
                     "%g; its Stokes I and V response is held to epsilon; docs/predict.md)",
                     grid.npix, grid.npix, left, grid.epsilon)
    return geometry


#: zenith positions computed per chunk at most (evenly spaced times)
_ZENITH_SAMPLES = 64


def zenith_pass(grid: PixelGrid, times: np.ndarray) -> float | None:
    """The chunk time, among at most 64 evenly spaced, when the zenith of
    :attr:`PixelGrid.site` is nearest the phase centre, if it is then within the padded
    field's half-diagonal; else (or without a site) None."""
    if grid.site is None or times.size == 0:
        return None
    pick = np.unique(np.rint(np.linspace(0, times.size - 1,
                                         min(times.size, _ZENITH_SAMPLES))).astype(int))
    dist = _zenith_distance(grid, times[pick])
    i = int(np.argmin(dist))
    return float(times[pick[i]]) if dist[i] <= _zenith_reach(grid) else None


def zenith_near(grid: PixelGrid, times: np.ndarray) -> np.ndarray | None:
    """(ntime,) bool: the times at which the zenith of :attr:`PixelGrid.site` is within the
    padded field's half-diagonal of the phase centre (None without a site)."""
    if grid.site is None:
        return None
    return _zenith_distance(grid, times) <= _zenith_reach(grid)


def _zenith_reach(grid: PixelGrid) -> float:
    """Half-diagonal (rad) of the padded field the beam is probed over, plus the largest
    angle between the zenith of a used station and that of :attr:`PixelGrid.site`."""
    half = math.sqrt(2.0) * idg.PAD * grid.npix * grid.dl / 2
    return math.asin(min(1.0, half)) + grid.site_spread


def _zenith_distance(grid: PixelGrid, times) -> np.ndarray:
    """Angle (rad) between the zenith of :attr:`PixelGrid.site` and the phase centre."""
    zenith = radec_to_unit(*zenith_j2000(times, np.asarray(grid.site)))
    return np.arccos(np.clip(zenith @ radec_to_unit(grid.ra0, grid.dec0), -1.0, 1.0))


def _iso(time_mjd_s: float) -> str:
    """UTC of an MS time (MJD s), to the second."""
    from astropy.time import Time

    return Time(time_mjd_s / 86400.0, format="mjd", scale="utc").isot[:19]


def _subgrid_jones(grid: PixelGrid, beam_model, nsub: int, times, freq, stations,
                   centre_correction: bool) -> tuple:
    """J(s) R(psi) (nst, nt, nchan, nsub^2, 2, 2) at the subgrid directions in the
    transported basis, and the correction J(s0)^-1 (nst, nt, nchan, 2, 2) or None; (None,
    None) without a beam."""
    if beam_model is None:
        return None, None
    lmn1 = idg.subgrid_directions(nsub, grid.npix, grid.dl)
    ra, dec = lm_to_radec(lmn1[:, 0], lmn1[:, 1], grid.ra0, grid.dec0)
    rot = basis_rotation(transport_angle(grid.ra0, grid.dec0, ra, dec))
    jones = np.empty((stations.size, times.size, freq.size, ra.size, 2, 2), np.complex128)
    left = (np.empty((stations.size, times.size, freq.size, 2, 2), np.complex128)
            if centre_correction else None)
    turned = np.empty((stations.size * freq.size, ra.size, 2, 2), np.complex128)
    for it in range(times.size):  # one time at a time: no full-size temporaries
        full = beam_model.jones(times[it:it + 1], freq, np.append(ra, grid.ra0),
                                np.append(dec, grid.dec0), stations=stations,
                                dtype=np.complex128)
        idg.rotate_columns(full[:, 0, :, :-1].reshape(-1, ra.size, 2, 2), rot, turned)
        jones[:, it] = turned.reshape(stations.size, freq.size, ra.size, 2, 2)
        if left is not None:
            left[:, it] = correction_of(beam_model, full[:, :, :, -1], times[it:it + 1],
                                        freq, stations)[:, 0]
    return jones, left


def degrid_visibilities(grid: PixelGrid, geometry: Geometry, channels: slice, beam_model,
                        times: np.ndarray, freq: np.ndarray, stations: np.ndarray,
                        xyz: np.ndarray, tidx: np.ndarray, p: np.ndarray, q: np.ndarray,
                        centre_correction: bool) -> np.ndarray:
    """Visibilities (nrow, nchan, 4) XX, XY, YX, YY (linear feeds, complex128) of the rows
    (time index ``tidx``, stations ``p``, ``q`` into ``xyz`` (ntime, nstation, 3) m) on the
    channels ``freq`` (Hz), which are ``grid.iquv[channels]``, with ``geometry``
    (:func:`degrid_geometry`)."""
    nsub = geometry.nsub
    # a subgrid larger than the memory planner assumed: fewer times and subgrids at once
    shrink = min(1.0, (PLAN_NSUB / nsub) ** 2)
    block = max(1, int(times.size * shrink))
    out = np.empty((tidx.size, freq.size, 4), dtype=np.complex128)
    for t0 in range(0, times.size, block):
        t1 = min(times.size, t0 + block)
        rows = np.flatnonzero((tidx >= t0) & (tidx < t1))
        if rows.size == 0:
            continue
        jones, left = _subgrid_jones(grid, beam_model, nsub, times[t0:t1], freq, stations,
                                     centre_correction)
        for c in range(freq.size):  # one channel at a time: one transported copy
            channel = slice(channels.start + c, channels.start + c + 1)
            # without a beam the direct path's identity Jones is the local basis
            sky = grid.iquv[channel] if jones is None else grid.transported(channel)
            vis = idg.degrid(sky, grid.dl, freq[c:c + 1], xyz[t0:t1], tidx[rows] - t0,
                             p[rows], q[rows], None if jones is None else jones[:, :, c:c + 1],
                             nsub=nsub, epsilon=grid.epsilon, support=geometry.support,
                             jones_left=None if left is None else left[:, :, c:c + 1],
                             centre=grid.centre,
                             batch=max(1, int(DEGRID_BATCH * shrink)))
            out[rows, c] = vis.reshape(rows.size, 4)
    return out
