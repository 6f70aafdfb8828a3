"""All-sky skies on HEALPix pixels (docs/sky.md, "All-sky skies").

:class:`HealpixSky` holds the brightness of a sky on a set of HEALPix pixels of one NSIDE:
Stokes (I, Q, U, V) per channel, in K or Jy/sr, on a pixel grid in ICRS (or, as a map
read from a file may be, Galactic or ecliptic coordinates), with Q and U referred to each
pixel's North in that frame (the IAU convention, as pyradiosky's SkyModel and msleak's
point sources). Readers of SkyH5 and HEALPix FITS maps (:mod:`msleak.adapters.healpix`)
and the all-sky foreground generator make it; :func:`healpix_sources` turns it into point
sources at the pixel centres (in ICRS, Q and U referred to the ICRS North) carrying the
pixel's flux, which is how predict sees it. A sky of one map may hold at every frequency,
unchanged (``flat``) or Faraday-rotated by a rotation measure per pixel
(:meth:`HealpixSky.on_channels`).

The pixel geometry comes from astropy-healpix (the ``healpix`` extra).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from msleak.constants import SPEED_OF_LIGHT, jy_per_kelvin
from msleak.errors import InputError
from msleak.sky.frames import SKY_FRAMES, north_angle, rotate_qu, rotation_to_icrs
from msleak.sky.sources import PointSources

__all__ = ["HealpixSky", "healpix_sources", "pixel_area_sr", "HEALPIX_UNITS",
           "HEALPIX_ORDERS", "SKY_FRAMES"]

#: the brightness units a :class:`HealpixSky` may carry
HEALPIX_UNITS = ("K", "Jy/sr")
#: the pixel orderings
HEALPIX_ORDERS = ("ring", "nested")


def pixel_area_sr(nside: int) -> float:
    """The solid angle (sr) of one HEALPix pixel, 4 pi / (12 NSIDE^2)."""
    return 4.0 * math.pi / (12.0 * int(nside) ** 2)


@dataclass(frozen=True, eq=False)
class HealpixSky:
    """Brightness on HEALPix pixels.

    Attributes
    ----------
    nside : int
        HEALPix NSIDE (a power of 2).
    order : {"ring", "nested"}
        Pixel ordering of ``pixels``.
    pixels : (npix,) int64
        The pixels that carry the sky (all ``12 NSIDE^2`` for a whole sphere), unique.
    freq_hz : (nchan,) float
        Channel frequencies, increasing; with ``flat`` or ``rotation_measure`` the one
        map's frequency (NaN when a ``flat`` map has none).
    stokes : (4, nchan, npix) float
        I, Q, U, V brightness in ``unit``; Q, U referred to each pixel's North in ``frame``.
    unit : {"K", "Jy/sr"}
    label : str
        Where the sky comes from (a file name), for messages.
    frame : {"icrs", "galactic", "ecliptic"}
        Frame of the pixel grid (:mod:`msleak.sky.frames`).
    flat : bool
        The one map (nchan = 1) holds at every frequency, in ``unit``.
    rotation_measure : (npix,) float or None
        rad m^-2: the one map is the sky at ``freq_hz[0]`` and at wavelength lambda
        Q + iU = (Q0 + iU0) exp(2i RM (lambda^2 - lambda0^2)); I, V and |Q + iU| in
        ``unit`` are the same at every frequency.
    """

    nside: int
    order: str
    pixels: np.ndarray
    freq_hz: np.ndarray
    stokes: np.ndarray
    unit: str = "K"
    label: str = ""
    frame: str = "icrs"
    flat: bool = False
    rotation_measure: np.ndarray | None = None

    def __post_init__(self) -> None:
        nside = int(self.nside)
        if nside < 1 or nside & (nside - 1):
            raise InputError(f"{self.label or 'HEALPix sky'}: NSIDE {self.nside} is not a "
                             "power of 2", param="nside")
        if self.order not in HEALPIX_ORDERS:
            raise InputError(f"{self.label or 'HEALPix sky'}: ordering {self.order!r} is "
                             "not ring or nested", param="order")
        if self.unit not in HEALPIX_UNITS:
            raise InputError(f"{self.label or 'HEALPix sky'}: unit {self.unit!r} is not one "
                             f"of {', '.join(HEALPIX_UNITS)}", param="unit")
        pixels = np.asarray(self.pixels, dtype=np.int64)
        freq = np.asarray(self.freq_hz, dtype=float)
        stokes = np.asarray(self.stokes, dtype=float)
        if stokes.shape != (4, freq.size, pixels.size):
            raise InputError(f"{self.label or 'HEALPix sky'}: Stokes of shape {stokes.shape},"
                             f" expected (4, {freq.size}, {pixels.size})", param="stokes")
        if pixels.size and (pixels.min() < 0 or pixels.max() >= 12 * nside ** 2):
            raise InputError(f"{self.label or 'HEALPix sky'}: pixel indices outside "
                             f"0..{12 * nside ** 2 - 1} for NSIDE {nside}", param="pixels")
        object.__setattr__(self, "nside", nside)
        object.__setattr__(self, "pixels", pixels)
        object.__setattr__(self, "freq_hz", freq)
        object.__setattr__(self, "stokes", stokes)
        self._check_spectrum()

    def _check_spectrum(self) -> None:
        """Refuse a frame, a one-map spectrum or a rotation measure that do not fit."""
        name = self.label or "HEALPix sky"
        if self.frame not in SKY_FRAMES:
            raise InputError(f"{name}: frame {self.frame!r} is not one of "
                             f"{', '.join(SKY_FRAMES)}", param="frame")
        one_map = self.flat or self.rotation_measure is not None
        if one_map and self.freq_hz.size != 1:
            raise InputError(f"{name}: a flat or Faraday-rotated sky has one map, not "
                             f"{self.freq_hz.size}", param="stokes")
        if self.rotation_measure is not None:
            rm = np.asarray(self.rotation_measure, dtype=float)
            if self.flat:
                raise InputError(f"{name}: a sky is flat or Faraday-rotated, not both",
                                 param="flat")
            if rm.shape != self.pixels.shape or not np.all(np.isfinite(rm)):
                raise InputError(f"{name}: the rotation measure needs one finite value per "
                                 f"pixel ({self.npix})", param="rotation_measure")
            object.__setattr__(self, "rotation_measure", rm)
        freq_ok = np.isfinite(self.freq_hz) & (self.freq_hz > 0)
        if not np.all(freq_ok) and not (self.flat and np.all(np.isnan(self.freq_hz))):
            raise InputError(f"{name}: channel frequencies must be positive (Hz)",
                             param="freq_hz")
        if np.any(np.diff(self.freq_hz) <= 0):
            raise InputError(f"{name}: channel frequencies must increase", param="freq_hz")

    @property
    def npix(self) -> int:
        return int(self.pixels.size)

    @property
    def pixel_area_sr(self) -> float:
        return pixel_area_sr(self.nside)

    def directions(self) -> tuple[np.ndarray, np.ndarray]:
        """ICRS (ra, dec) of the pixel centres, rad (converted from ``frame``)."""
        from astropy_healpix import healpix_to_lonlat

        lon, lat = healpix_to_lonlat(self.pixels, self.nside, order=self.order)
        lon = np.asarray(lon.to_value("rad"), float)
        lat = np.asarray(lat.to_value("rad"), float)
        if self.frame != "icrs":
            unit = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon),
                             np.sin(lat)], -1) @ rotation_to_icrs(self.frame).T
            lon = np.arctan2(unit[:, 1], unit[:, 0])
            lat = np.arctan2(unit[:, 2], np.hypot(unit[:, 0], unit[:, 1]))
        return lon % (2 * math.pi), lat

    def on_channels(self, freq_hz) -> "HealpixSky":
        """The sky on the channels ``freq_hz`` (Hz): a flat or Faraday-rotated sky evaluated
        there; a sky with its own channels as it is."""
        if not self.flat and self.rotation_measure is None:
            return self
        freq = np.atleast_1d(np.asarray(freq_hz, dtype=float))
        stokes = np.repeat(self.stokes, freq.size, axis=1)
        if self.rotation_measure is not None:
            lam2 = (SPEED_OF_LIGHT / freq) ** 2 - (SPEED_OF_LIGHT / self.freq_hz[0]) ** 2
            turn = self.rotation_measure[None, :] * lam2[:, None]   # (nchan, npix) rad
            stokes[1], stokes[2] = rotate_qu(stokes[1], stokes[2], turn)
        return HealpixSky(nside=self.nside, order=self.order, pixels=self.pixels,
                          freq_hz=freq, stokes=stokes, unit=self.unit, label=self.label,
                          frame=self.frame)

    def flux_jy(self) -> np.ndarray:
        """(4, nchan, npix) flux of each pixel, Jy: the brightness times the pixel's solid
        angle (``2 k_B T nu^2 / c^2`` per sr for K)."""
        if self.unit == "Jy/sr":
            return self.stokes * self.pixel_area_sr
        return self.stokes * jy_per_kelvin(self.freq_hz, self.pixel_area_sr)[:, None]


def healpix_sources(sky: HealpixSky) -> PointSources:
    """Point sources at the pixel centres of ``sky`` (ICRS), each carrying its pixel's flux
    (Jy) per channel (tabulated spectra), Q and U referred to the ICRS North (turned from
    the sky's frame, :mod:`msleak.sky.frames`). A flat or Faraday-rotated sky is first put
    on channels with :meth:`HealpixSky.on_channels`."""
    if sky.flat or sky.rotation_measure is not None:
        raise InputError(f"{sky.label or 'HEALPix sky'}: a flat or Faraday-rotated sky has "
                         "no channels of its own; put it on channels first (on_channels)")
    ra, dec = sky.directions()
    flux = sky.flux_jy()
    if sky.frame != "icrs":
        flux[1], flux[2] = rotate_qu(flux[1], flux[2], north_angle(sky.frame, ra, dec))
    return PointSources(ra=ra, dec=dec, freq=sky.freq_hz.copy(),
                        stokes=np.ascontiguousarray(np.moveaxis(flux, 0, -1).transpose(1, 0, 2)))
