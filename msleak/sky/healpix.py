"""All-sky skies on HEALPix pixels (docs/sky.md, "All-sky skies").

:class:`HealpixSky` holds the brightness of a sky on a set of HEALPix pixels of one NSIDE:
Stokes (I, Q, U, V) per channel, in K or Jy/sr, in ICRS, with Q and U referred to each
pixel's celestial North (the IAU convention, as pyradiosky's SkyModel and msleak's
point sources). Readers of SkyH5 and HEALPix FITS maps (:mod:`msleak.adapters.healpix`)
and the all-sky foreground generator make it; :func:`healpix_sources` turns it into point
sources at the pixel centres carrying the pixel's flux, which is how predict sees it.

The pixel geometry comes from astropy-healpix (the ``healpix`` extra).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from msleak.constants import jy_per_kelvin
from msleak.errors import InputError
from msleak.sky.sources import PointSources

__all__ = ["HealpixSky", "healpix_sources", "pixel_area_sr", "HEALPIX_UNITS",
           "HEALPIX_ORDERS"]

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
        Channel frequencies, increasing.
    stokes : (4, nchan, npix) float
        I, Q, U, V brightness in ``unit``; Q, U referred to each pixel's ICRS North.
    unit : {"K", "Jy/sr"}
    label : str
        Where the sky comes from (a file name), for messages.
    """

    nside: int
    order: str
    pixels: np.ndarray
    freq_hz: np.ndarray
    stokes: np.ndarray
    unit: str = "K"
    label: str = ""

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

    @property
    def npix(self) -> int:
        return int(self.pixels.size)

    @property
    def pixel_area_sr(self) -> float:
        return pixel_area_sr(self.nside)

    def directions(self) -> tuple[np.ndarray, np.ndarray]:
        """ICRS (ra, dec) of the pixel centres, rad."""
        from astropy_healpix import healpix_to_lonlat

        lon, lat = healpix_to_lonlat(self.pixels, self.nside, order=self.order)
        return (np.asarray(lon.to_value("rad"), float) % (2 * math.pi),
                np.asarray(lat.to_value("rad"), float))

    def flux_jy(self) -> np.ndarray:
        """(4, nchan, npix) flux of each pixel, Jy: the brightness times the pixel's solid
        angle (``2 k_B T nu^2 / c^2`` per sr for K)."""
        if self.unit == "Jy/sr":
            return self.stokes * self.pixel_area_sr
        return self.stokes * jy_per_kelvin(self.freq_hz, self.pixel_area_sr)[:, None]


def healpix_sources(sky: HealpixSky) -> PointSources:
    """Point sources at the pixel centres of ``sky``, each carrying its pixel's flux (Jy) per
    channel (tabulated spectra)."""
    ra, dec = sky.directions()
    flux = sky.flux_jy()
    return PointSources(ra=ra, dec=dec, freq=sky.freq_hz.copy(),
                        stokes=np.ascontiguousarray(np.moveaxis(flux, 0, -1).transpose(1, 0, 2)))
