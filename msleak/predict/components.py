"""Sky components for the predict kernel: unique directions, spectra on the MS channels,
brightness factors (docs/predict.md).

A FITS cube gives one source per pixel with the cube's spectrum (each voxel a point
source at its own channel, docs/science.md section 3); a makesourcedb file gives parametric
spectra; a HEALPix sky gives one source per pixel at its centre. Sources sharing a direction are
merged (their Stokes add), sources without flux on the channels are dropped, and so are
directions 90 deg or more from the phase centre (they would need n <= 0: not in the
visible hemisphere of the phase centre), except for HEALPix skies, which keep every
direction with n > -1 and drop, per time, those below the horizon
(:mod:`msleak.predict.horizon`).

Several skies predicted in one run form a :class:`SkySet`: the union of their directions
(a direction shared by several skies, matched by exact (ra, dec) equality, appears once:
fields of view cropped from one cube, other realisations on the same pixel grid), on
which the beam is evaluated once, and each sky's rows in it.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from msleak.errors import InputError
from msleak.predict.gridsky import PixelGrid, choose_method, pixel_grid
from msleak.predict.horizon import Horizon
from msleak.predict.kernels import brightness_factors, lmn_minus_one
from msleak.predict.options import DegridOptions
from msleak.sky.cube import SkyCube, crop, recentre
from msleak.sky.healpix import HealpixSky, healpix_sources
from msleak.sky.sources import DEFAULT_RTOL, PointSources, sources_from_cube

__all__ = ["SkyComponents", "SkySet", "sky_components", "sky_set", "prepare_sources"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SkyComponents:
    """Directions and brightness factors of one (field, spectral window).

    Attributes
    ----------
    ra, dec : (ndir,) rad
    lmn1 : (ndir, 3) (l, m, n - 1) about the phase centre
    iquv : (ndir, nchan, 4) Jy
    w : (ndir, nchan, 2, 2) complex128, sign : (ndir, nchan, 2) int8
        B = w diag(sign) w^H (linear-feed brightness matrix, see kernels)
    grid : PixelGrid or None
        Set when the sky is predicted by degridding (:mod:`msleak.predict.gridsky`);
        its directions then stay out of a :class:`SkySet`'s union.
    horizon : Horizon or None
        Set for an all-sky sky whose directions count only while above the horizon
        (:mod:`msleak.predict.horizon`); its directions then stay out of the union too.
    """

    ra: np.ndarray
    dec: np.ndarray
    lmn1: np.ndarray
    iquv: np.ndarray
    w: np.ndarray
    sign: np.ndarray
    grid: PixelGrid | None = None
    horizon: Horizon | None = None

    @property
    def ndir(self) -> int:
        return int(self.ra.size)

    @property
    def own(self) -> bool:
        """Predicted on its own (degridded or culled at the horizon), not in the union."""
        return self.grid is not None or self.horizon is not None

    @property
    def nbytes(self) -> int:
        return int(self.lmn1.nbytes + self.iquv.nbytes + self.w.nbytes + self.sign.nbytes
                   + (0 if self.grid is None else self.grid.nbytes))


@dataclass(frozen=True)
class SkySet:
    """Several skies of one (field, spectral window) and the union of their directions.

    Attributes
    ----------
    ra, dec : (ndir,) rad
        Every direction of any sky once, in order of first appearance (the first sky's
        directions first, in its order).
    lmn1 : (ndir, 3)
        (l, m, n - 1) about the phase centre; the rows of sky k are ``skies[k].lmn1``.
    skies : tuple of SkyComponents
    index : tuple of (ndir_k,) int64
        Rows of ``ra``, ``dec``, ``lmn1`` holding the directions of ``skies[k]``, in order.
    """

    ra: np.ndarray
    dec: np.ndarray
    lmn1: np.ndarray
    skies: tuple
    index: tuple

    @property
    def ndir(self) -> int:
        return int(self.ra.size)

    @property
    def nbytes(self) -> int:
        return int(self.lmn1.nbytes + sum(s.nbytes for s in self.skies)
                   + sum(i.nbytes for i in self.index))


def sky_set(skies: Sequence[SkyComponents]) -> SkySet:
    """The union of the skies' directions, exact (ra, dec) matches merged (pure function).

    One sky gives its own directions in its own order (``index`` = 0..ndir-1). A degridded
    sky (``grid`` set) or one culled at the horizon (``horizon`` set) adds no direction and
    gets an empty index.
    """
    skies = tuple(skies)
    keys = np.concatenate([np.stack([s.ra, s.dec], axis=1)[:0 if s.own else None]
                           for s in skies]) if skies else np.zeros((0, 2))
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")  # unique directions by first appearance
    rank = np.empty(order.size, dtype=np.int64)
    rank[order] = np.arange(order.size)
    rows_all = rank[np.asarray(inverse, dtype=np.int64).ravel()]
    bounds = np.cumsum([0] + [0 if s.own else s.ndir for s in skies])
    index = tuple(rows_all[bounds[k]:bounds[k + 1]] for k in range(len(skies)))
    union = keys[first[order]]
    lmn1 = np.zeros((union.shape[0], 3))
    for sky, rows in zip(skies, index):
        if not sky.own:
            lmn1[rows] = sky.lmn1
    return SkySet(ra=union[:, 0].copy(), dec=union[:, 1].copy(), lmn1=lmn1, skies=skies,
                  index=index)


def prepare_sources(ra: np.ndarray, dec: np.ndarray, iquv: np.ndarray, ra0: float,
                    dec0: float, all_sky: bool = False) -> SkyComponents:
    """Merge, filter and factorise point sources (pure function).

    Parameters
    ----------
    ra, dec : (nsrc,) rad
    iquv : (nsrc, nchan, 4) Jy, Stokes (I, Q, U, V) on the MS channels
    ra0, dec0 : phase centre, rad
    all_sky : bool
        Keep every direction with n > -1 (an all-sky sky, culled per time at the horizon),
        not only those with n > 0.
    """
    ra = np.asarray(ra, dtype=np.float64)
    dec = np.asarray(dec, dtype=np.float64)
    iquv = np.asarray(iquv, dtype=np.float64)
    if ra.size:
        keys, inverse = np.unique(np.stack([ra, dec], axis=1), axis=0, return_inverse=True)
        inverse = inverse.ravel()
        if keys.shape[0] < ra.size:
            merged = np.zeros((keys.shape[0],) + iquv.shape[1:])
            np.add.at(merged, inverse, iquv)
            ra, dec, iquv = keys[:, 0], keys[:, 1], merged
    has_flux = np.any(iquv != 0, axis=(1, 2)) if iquv.size else np.zeros(ra.size, bool)
    lmn1 = lmn_minus_one(ra, dec, ra0, dec0)
    front = lmn1[:, 2] > (-2.0 if all_sky else -1.0)
    if np.any(has_flux & ~front):
        log.warning("%d sources are %s the phase centre; they are ignored",
                    int(np.count_nonzero(has_flux & ~front)),
                    "opposite" if all_sky else "90 deg or more from")
    keep = has_flux & front
    ra, dec, iquv, lmn1 = ra[keep], dec[keep], iquv[keep], lmn1[keep]
    w, sign = brightness_factors(iquv)
    return SkyComponents(ra=ra, dec=dec, lmn1=lmn1, iquv=iquv, w=w, sign=sign)


def sky_components(sky: SkyCube | PointSources | HealpixSky, freq: np.ndarray, ra0: float,
                   dec0: float, *, label: str = "", fov_deg: float | None = None,
                   interpolate: bool = False, degrid: DegridOptions = DegridOptions(),
                   site=None, site_spread: float = 0.0, phase_centre_of: str = "",
                   extent_deg: float | None = None,
                   horizon: Horizon | None = None) -> SkyComponents:
    """The sources of one sky for one field and spectral window.

    ``sky`` a pixel sky (:class:`~msleak.sky.cube.SkyCube`, re-centred on the phase centre
    and cropped to the central ``fov_deg`` degrees),
    :class:`~msleak.sky.sources.PointSources` (those within ``fov_deg`` kept) or an all-sky
    :class:`~msleak.sky.healpix.HealpixSky` (its pixel centres; those within ``fov_deg``
    kept; every direction with n > -1, culled per time by ``horizon``, which it needs),
    named ``label`` in messages; ``extent_deg`` keeps the sources (not of a cube) within
    that angle of the phase centre; ``freq`` the channels (Hz), ``ra0, dec0`` the phase
    centre (rad); ``degrid`` how pixel skies are predicted; ``site`` the ITRF position (m)
    of the array's centre and ``site_spread`` the largest angle (rad) from its zenith to a
    used station's (:class:`PixelGrid`; without a site the degridder's probe does not look
    for the zenith); ``phase_centre_of`` names where the phase centre comes from (e.g. the
    MS) in the warning a pixel sky centred elsewhere gets when it is re-centred.

    Raises
    ------
    InputError
        Frequency mismatch, FoV larger than the cube, degrid asked for a sky that is not a
        pixel grid, an extent for a cube, ...
    """
    label = label or f"<in-memory {type(sky).__name__}>"
    cube, sources = _sources(sky, freq, ra0, dec0, label, fov_deg, extent_deg, degrid,
                             horizon, phase_centre_of)
    iquv = sources.at_frequencies(np.asarray(freq, dtype=np.float64), interpolate=interpolate)
    grid = None
    if cube is not None and degrid.method != "direct":
        grid = pixel_grid(sources.ra, sources.dec, iquv, cube.npix, ra0, dec0,
                          epsilon=degrid.epsilon, nsub=degrid.nsub, site=site,
                          site_spread=site_spread)
    chosen = choose_method(degrid.method, grid, len(sources), label, cube is not None)
    all_sky = isinstance(sky, HealpixSky)
    comp = prepare_sources(sources.ra, sources.dec, iquv, ra0, dec0, all_sky=all_sky)
    if chosen == "degrid":
        comp = replace(comp, grid=replace(grid, auto=degrid.method == "auto"))
    if all_sky:
        comp = replace(comp, horizon=horizon)
    log.info("sky %s: %d sources, %d directions with flux, predicted by %s%s", label,
             len(sources), comp.ndir, chosen,
             f" ({grid.npix} x {grid.npix} pixels, epsilon {degrid.epsilon:g})"
             if comp.grid else
             (f" above {np.degrees(horizon.min_elevation):g} deg elevation" if all_sky
              else ""))
    return comp


def _sources(sky, freq, ra0: float, dec0: float, label: str, fov_deg, extent_deg, degrid,
             horizon, phase_centre_of: str) -> tuple:
    """(the cropped cube or None, its or the sky's point sources) of :func:`sky_components`."""
    if isinstance(sky, SkyCube):
        if extent_deg is not None:
            raise InputError(f"extent keeps the pixels of HEALPix skies and the sources of "
                             f"point-source skies within an angle; {label} is a cube: crop "
                             "it with fov", param=("extent", "fov"))
        _warn_recentre(sky, ra0, dec0, label, phase_centre_of)
        cube = recentre(sky, ra0, dec0)
        cube = cube if fov_deg is None else crop(cube, fov_deg=fov_deg)
        return cube, sources_from_cube(cube)
    if isinstance(sky, HealpixSky):
        if degrid.method == "degrid":
            raise InputError(f"method degrid needs a pixel sky on a SIN grid; {label} is a "
                             "HEALPix sky (summed pixel by pixel): use method direct or auto",
                             param="method")
        if horizon is None:
            raise InputError(f"{label}: a HEALPix sky is predicted to the horizon, which "
                             "needs `horizon` (the array's position)", param="horizon")
        sky = healpix_sources(_healpix_on_channels(sky, np.asarray(freq, float), label))
    elif not isinstance(sky, PointSources):
        raise InputError(f"sky must be a SkyCube, PointSources or HealpixSky, not "
                         f"{type(sky).__name__}", param="sky")
    return None, _near(_within(sky, ra0, dec0, fov_deg), ra0, dec0, extent_deg)


def _healpix_on_channels(sky: HealpixSky, freq: np.ndarray, label: str) -> HealpixSky:
    """``sky`` on the channels ``freq``; a map of one frequency that is not the channels'
    is refused, naming ``flat_spectrum``."""
    if sky.flat or sky.rotation_measure is not None:
        return sky.on_channels(freq)
    if sky.freq_hz.size == 1 and np.any(np.abs(freq - sky.freq_hz[0])
                                        > DEFAULT_RTOL * np.abs(freq)):
        raise InputError(f"{label}: one map at {sky.freq_hz[0] / 1e6:.6f} MHz for channels "
                         f"{freq.min() / 1e6:.6f}-{freq.max() / 1e6:.6f} MHz; pass "
                         "flat_spectrum to use it at every channel",
                         param="flat_spectrum")
    return sky


def _near(sky: PointSources, ra0: float, dec0: float, extent_deg: float | None
          ) -> PointSources:
    """The sources of ``sky`` within ``extent_deg`` degrees of ``ra0, dec0`` (rad)."""
    if extent_deg is None:
        return sky
    return sky.select(sky.lmn(ra0, dec0)[2] >= np.cos(np.radians(extent_deg)))


#: a pixel sky whose centre differs from the phase centre by more than this in RA or Dec
#: (arcsec; at a pole RA sets the orientation) is re-centred with a warning
RECENTRE_WARN_ARCSEC = 1.0


def _warn_recentre(cube: SkyCube, ra0: float, dec0: float, label: str,
                   phase_centre_of: str) -> None:
    """Warn, in one line, that ``cube`` (centred at its reference direction CRVAL) is
    moved onto the phase centre ``ra0, dec0`` (rad) of ``phase_centre_of``
    (docs/sky.md, "Re-centring")."""
    ra_c, dec_c = (float(x) for x in cube.wcs.wcs.crval[:2])
    ra_p, dec_p = np.degrees(ra0) % 360.0, float(np.degrees(dec0))
    d_ra = (ra_c - ra_p + 180.0) % 360.0 - 180.0
    if max(abs(d_ra), abs(dec_c - dec_p)) * 3600.0 <= RECENTRE_WARN_ARCSEC:
        return
    log.warning("sky %s is centred at RA %.4f deg, Dec %.4f deg; re-centred on the phase "
                "centre RA %.4f deg, Dec %.4f deg%s (every pixel keeps its offset from the "
                "centre, docs/sky.md)", label, ra_c % 360.0, dec_c, ra_p, dec_p,
                f" of {phase_centre_of}" if phase_centre_of else "")


def _within(sky: PointSources, ra0: float, dec0: float, fov_deg: float | None
            ) -> PointSources:
    """The sources of ``sky`` with |l|, |m| <= fov / 2 about ``ra0, dec0`` (rad), in front."""
    if fov_deg is None:
        return sky
    half = np.radians(fov_deg) / 2
    l_, m_, n_ = sky.lmn(ra0, dec0)
    return sky.select((np.abs(l_) <= half) & (np.abs(m_) <= half) & (n_ > 0))
