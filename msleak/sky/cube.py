"""Sky cubes: Stokes x frequency x image-plane arrays with a celestial WCS.

:class:`SkyCube` holds ``data`` of shape ``(stokes, freq, y, x)`` (``x`` the first, RA
FITS axis; pixel (0, 0) is FITS pixel (1, 1)) in ``"K"`` or ``"Jy/pixel"``, with Q and U
referred to each pixel's local celestial North (``meta["POLFRAME"] = "LOCAL-NORTH"``).
Helpers make the SIN WCS msleak uses (:func:`make_celestial_wcs`), give pixel directions
and true solid angles, convert units, crop, re-centre, and give the position angle of
the image +y axis per pixel (:func:`y_axis_position_angle`).

Geometry, units and the polarization frame: docs/sky.md ("Conventions").
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
from astropy.wcs import WCS

from msleak.constants import jy_per_kelvin
from msleak.errors import InputError

__all__ = [
    "SkyCube",
    "Units",
    "STOKES_CODES",
    "make_celestial_wcs",
    "pixel_directions",
    "pixel_solid_angle",
    "kelvin_to_jansky",
    "jansky_to_kelvin",
    "convert_units",
    "crop_npix_for_fov",
    "crop",
    "recentre",
    "pixel_size_deg",
    "y_axis_position_angle",
    "rotate_polarization",
    "POLFRAME",
]

Units = Literal["K", "Jy/pixel"]

#: FITS STOKES axis codes (Greisen & Calabretta 2002).
STOKES_CODES = {"I": 1, "Q": 2, "U": 3, "V": 4}


#: ``meta["POLFRAME"]`` of cubes whose Q, U are referred to the local North of each pixel
POLFRAME = "LOCAL-NORTH"

#: pixels closer than this to a celestial pole (rad) take the North of their own meridian,
#: as the beam does (msleak.beam.coords.POLE_EPS_RAD)
_POLE_EPS = 1e-8


@dataclass(frozen=True, eq=False)
class SkyCube:
    """A Stokes cube on a celestial grid.

    Attributes
    ----------
    data : (nstokes, nfreq, ny, nx) float array, in ``units``
    freq : (nfreq,) channel centre frequencies, Hz
    stokes : labels of the first axis, e.g. ``("Q", "U")``
    wcs : 2-D celestial :class:`astropy.wcs.WCS` of the (x, y) axes
    units : ``"K"`` or ``"Jy/pixel"``
    meta : extra header cards (name -> value), e.g. the generator's parameters
    """

    data: np.ndarray
    freq: np.ndarray
    stokes: tuple[str, ...]
    wcs: object
    units: Units = "K"
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        data = np.asarray(self.data)
        if data.ndim != 4:
            raise InputError(f"a sky cube needs 4 axes (stokes, freq, y, x), got {data.shape}")
        if data.shape[0] != len(self.stokes):
            raise InputError(f"{len(self.stokes)} Stokes labels for {data.shape[0]} planes")
        if data.shape[1] != len(np.atleast_1d(self.freq)):
            raise InputError(f"{len(self.freq)} frequencies for {data.shape[1]} channels")
        bad = [s for s in self.stokes if s not in STOKES_CODES]
        if bad:
            raise InputError(f"unknown Stokes labels {bad}; use I, Q, U, V")
        if self.units not in ("K", "Jy/pixel"):
            raise InputError(f"unknown brightness unit {self.units!r}; use K or Jy/pixel")

    @property
    def npix(self) -> tuple[int, int]:
        """(ny, nx)."""
        return self.data.shape[2], self.data.shape[3]

    def plane(self, stokes: str) -> np.ndarray:
        """The (nfreq, ny, nx) cube of one Stokes parameter (zeros if absent)."""
        if stokes in self.stokes:
            return self.data[self.stokes.index(stokes)]
        if stokes not in STOKES_CODES:
            raise InputError(f"unknown Stokes parameter {stokes!r}")
        return np.zeros(self.data.shape[1:], dtype=self.data.dtype)


def make_celestial_wcs(nx: int, ny: int, pixel_deg: float, ra_deg: float, dec_deg: float):
    """SIN-projected celestial WCS centred on (ra, dec), the grid centre as reference.

    The reference pixel is the grid centre, CRPIX = (n + 1) / 2 (between two pixels for
    even n). RA increases to the left. LONPOLE = 180 deg keeps the orientation of the
    limit Dec -> 90 deg at the pole itself.
    """
    if not (-90.0 <= dec_deg <= 90.0):
        raise InputError(f"declination {dec_deg} deg is outside -90..90")
    if pixel_deg <= 0 or nx < 1 or ny < 1:
        raise InputError("pixel size and pixel counts must be positive")
    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---SIN", "DEC--SIN"]
    w.wcs.cunit = ["deg", "deg"]
    w.wcs.crval = [ra_deg % 360.0, dec_deg]
    w.wcs.crpix = [(nx + 1) / 2.0, (ny + 1) / 2.0]
    w.wcs.cdelt = [-pixel_deg, pixel_deg]
    w.wcs.lonpole = 180.0
    w.wcs.radesys = "FK5"
    w.wcs.equinox = 2000.0
    w.wcs.set()
    return w


def pixel_size_deg(cube: SkyCube) -> tuple[float, float]:
    """|CDELT| of the (x, y) axes in degrees (projection-plane pixel size)."""
    scale = np.abs(cube.wcs.pixel_scale_matrix)
    return float(np.hypot(scale[0, 0], scale[1, 0])), float(np.hypot(scale[0, 1], scale[1, 1]))


def pixel_directions(wcs, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(RA, Dec) of every pixel centre, rad, each of shape (ny, nx).

    Raises
    ------
    InputError
        If some pixels lie outside the projection (e.g. beyond the SIN horizon).
    """
    ny, nx = shape
    y, x = np.mgrid[0:ny, 0:nx]
    ra, dec = wcs.all_pix2world(x.astype(float), y.astype(float), 0)
    ra, dec = np.radians(ra), np.radians(dec)
    if not (np.all(np.isfinite(ra)) and np.all(np.isfinite(dec))):
        raise InputError("some cube pixels fall outside the projection (beyond the "
                         "horizon of the SIN grid?); crop the cube with a smaller fov",
                         param="fov")
    return np.mod(ra, 2 * np.pi), dec


def _unit_vectors(wcs, x, y):
    ra, dec = wcs.all_pix2world(x, y, 0)
    ra, dec = np.radians(ra), np.radians(dec)
    return np.stack([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)])


def pixel_solid_angle(wcs, shape: tuple[int, int]) -> np.ndarray:
    """True solid angle of every pixel, sr, shape (ny, nx), for any projection.

    Computed as |ds/dx x ds/dy| with s the unit vector of the pixel centre and central
    differences of +-1/2 pixel; for SIN this is Delta l Delta m / n to O(pixel^2).
    """
    ny, nx = shape
    y, x = np.mgrid[0:ny, 0:nx].astype(float)
    h = 0.5
    dsx = _unit_vectors(wcs, x + h, y) - _unit_vectors(wcs, x - h, y)
    dsy = _unit_vectors(wcs, x, y + h) - _unit_vectors(wcs, x, y - h)
    omega = np.linalg.norm(np.cross(dsx, dsy, axis=0), axis=0) / (2 * h) ** 2
    if not np.all(np.isfinite(omega)):
        raise InputError("pixel solid angles are undefined at the edge of the projection; "
                         "crop the cube with a smaller fov", param="fov")
    return omega


def kelvin_to_jansky(temp_k: np.ndarray, freq_hz: np.ndarray, omega_sr: np.ndarray
                     ) -> np.ndarray:
    """Rayleigh-Jeans: S [Jy] = 2 k_B T Omega nu^2 / c^2 / 1e-26.

    Parameters
    ----------
    temp_k : (..., nfreq, ny, nx) brightness temperature, K
    freq_hz : (nfreq,) Hz
    omega_sr : (ny, nx) or scalar pixel solid angle, sr
    """
    factor = jy_per_kelvin(freq_hz, 1.0)
    return np.asarray(temp_k) * factor[:, None, None] * np.asarray(omega_sr)


def jansky_to_kelvin(flux_jy: np.ndarray, freq_hz: np.ndarray, omega_sr: np.ndarray
                     ) -> np.ndarray:
    """Inverse of :func:`kelvin_to_jansky`."""
    factor = jy_per_kelvin(freq_hz, 1.0)
    return np.asarray(flux_jy) / (factor[:, None, None] * np.asarray(omega_sr))


def convert_units(cube: SkyCube, units: Units) -> SkyCube:
    """The same cube in ``units`` (``"K"`` or ``"Jy/pixel"``)."""
    if units not in ("K", "Jy/pixel"):
        raise InputError(f"unknown brightness unit {units!r}; use K or Jy/pixel")
    if units == cube.units:
        return cube
    omega = pixel_solid_angle(cube.wcs, cube.npix)
    if units == "Jy/pixel":
        data = kelvin_to_jansky(cube.data, cube.freq, omega)
    else:
        data = jansky_to_kelvin(cube.data, cube.freq, omega)
    return replace(cube, data=data.astype(cube.data.dtype, copy=False), units=units)


def crop_npix_for_fov(fov_deg: float, pixel_deg: float, npix: int) -> int:
    """Pixels a side of a centred crop covering ``fov_deg``.

    Rule: n = fov / pixel rounded to the nearest integer of the same parity as ``npix``
    (so the crop stays centred on the same point), halves rounded down. A FoV within 1e-6
    of the full cube keeps every pixel.

    Raises
    ------
    InputError
        If the FoV is larger than the cube or smaller than one pixel.
    """
    if not (fov_deg > 0 and math.isfinite(fov_deg)):
        raise InputError(f"fov_deg must be a positive number of degrees, got {fov_deg}",
                         param="fov_deg")
    full = npix * pixel_deg
    if fov_deg > full * (1 + 1e-6):
        raise InputError(f"field of view {fov_deg:g} deg is larger than the cube "
                         f"({npix} pixels of {pixel_deg:.4g} deg = {full:.4g} deg)")
    exact = fov_deg / pixel_deg
    if abs(exact - npix) <= 1e-6 * npix:
        return npix
    # nearest integer with the parity of npix: npix - 2 k, k = round((npix - exact) / 2)
    k = math.ceil((npix - exact) / 2 - 0.5)
    n = npix - 2 * k
    if n < 1:
        raise InputError(f"field of view {fov_deg:g} deg is smaller than one pixel "
                         f"({pixel_deg:.4g} deg)")
    return n


def crop(cube: SkyCube, *, fov_deg: float | None = None, npix: int | None = None) -> SkyCube:
    """The centred square crop of a cube, by field of view or by pixel count.

    The crop removes the same number of pixels on each side (the cube's parity is kept);
    the WCS reference pixel moves with it. ``fov_deg`` uses
    :func:`crop_npix_for_fov` with the larger of the two pixel sizes.
    """
    ny, nx = cube.npix
    if (fov_deg is None) == (npix is None):
        raise InputError("give exactly one of fov_deg and npix to crop a cube")
    if fov_deg is not None:
        px, py = pixel_size_deg(cube)
        if not math.isclose(px, py, rel_tol=1e-6):
            raise InputError(f"cropping by field of view needs square pixels, got "
                             f"{px:.6g} x {py:.6g} deg")
        nxc = crop_npix_for_fov(fov_deg, px, nx)
        nyc = crop_npix_for_fov(fov_deg, py, ny)
    else:
        if npix < 1 or npix > min(nx, ny) or (nx - npix) % 2 or (ny - npix) % 2:
            raise InputError(f"cannot crop a {ny}x{nx} cube to {npix} pixels a side "
                             "(needs 1 <= npix <= the cube size and the same parity)")
        nxc = nyc = npix
    x0, y0 = (nx - nxc) // 2, (ny - nyc) // 2
    w = cube.wcs.deepcopy()
    w.wcs.crpix = [w.wcs.crpix[0] - x0, w.wcs.crpix[1] - y0]
    w.wcs.set()
    data = cube.data[:, :, y0:y0 + nyc, x0:x0 + nxc].copy()
    meta = dict(cube.meta)
    meta["CROPFOV"] = float(fov_deg) if fov_deg is not None else nxc * pixel_size_deg(cube)[0]
    return replace(cube, data=data, wcs=w, meta=meta)


def y_axis_position_angle(wcs, shape: tuple[int, int], h: float = 1e-3) -> np.ndarray:
    """Position angle psi of the image +y direction at every pixel centre, rad (ny, nx).

    psi is counted from the local celestial North through East at the pixel's direction:
    the tangent t = ds/dy of the pixel-centre unit vector s (central differences of
    +-``h`` pixel through the WCS) gives psi = atan2(t . East, t . North), with
    East = (-sin a, cos a, 0) and North = (-sin d cos a, -sin d sin a, cos d). A pixel
    within 1e-8 rad of a pole takes the North of its own right ascension's meridian (as
    the beam does). A polarization vector at angle chi_y from +y (towards the image
    direction 90 deg east of it) has the position angle chi_y + psi, i.e.
    Q + iU (local North) = (Q + iU)(+y) exp(2i psi).
    """
    ny, nx = shape
    y, x = np.mgrid[0:ny, 0:nx].astype(float)
    t = _unit_vectors(wcs, x, y + h) - _unit_vectors(wcs, x, y - h)
    ra, dec = wcs.all_pix2world(x, y, 0)
    ra = np.radians(ra)
    dec = np.clip(np.radians(dec), -np.pi / 2 + _POLE_EPS, np.pi / 2 - _POLE_EPS)
    east = np.stack([-np.sin(ra), np.cos(ra), np.zeros_like(ra)])
    north = np.stack([-np.sin(dec) * np.cos(ra), -np.sin(dec) * np.sin(ra), np.cos(dec)])
    psi = np.arctan2(np.sum(t * east, axis=0), np.sum(t * north, axis=0))
    if not np.all(np.isfinite(psi)):
        raise InputError("the polarization frame is undefined at some pixels (beyond the "
                         "projection's horizon?); crop the cube with a smaller fov",
                         param="fov")
    return psi


def rotate_polarization(cube: SkyCube, angle: np.ndarray) -> SkyCube:
    """Rotate every pixel's polarization: Q + iU -> (Q + iU) exp(2i angle).

    Parameters
    ----------
    cube : SkyCube
    angle : (ny, nx) or scalar, rad; positive from North towards East

    A cube with only one of Q and U gets the other (zeros before the rotation); I and V
    are unchanged.
    """
    angle = np.asarray(angle, dtype=float)
    if not np.any(angle) or not ({"Q", "U"} & set(cube.stokes)):
        return cube
    if not {"Q", "U"} <= set(cube.stokes):
        labels = tuple(sorted(set(cube.stokes) | {"Q", "U"}, key=STOKES_CODES.get))
        data = np.stack([cube.plane(st) for st in labels])
        cube = replace(cube, data=data, stokes=labels)
    iq, iu = cube.stokes.index("Q"), cube.stokes.index("U")
    p = (cube.data[iq] + 1j * cube.data[iu]) * np.exp(2j * angle)
    data = np.array(cube.data, copy=True)
    data[iq], data[iu] = p.real, p.imag
    return replace(cube, data=data.astype(cube.data.dtype, copy=False))


def recentre(cube: SkyCube, ra: float, dec: float) -> SkyCube:
    """Move the cube to a new phase centre (RA, Dec in rad).

    The projection-plane grid is kept (same projection, CRPIX, CDELT), only the reference
    direction CRVAL changes: every pixel keeps its (l, m) relative to the reference, so a
    cube made for one field can be placed on any other. LONPOLE is set to 180 deg. For a
    zenithal projection this moves the whole pattern by one rotation of the sphere, which
    carries each pixel's polarization vector along with the grid: its angle from the
    image +y axis is kept, so Q + iU (local North) is rotated by
    exp(2i (psi_new - psi_old)), psi the position angle of +y (:func:`y_axis_position_angle`)
    at the pixel's old and new directions. Re-centring back returns the original Q, U.
    """
    dec_deg = math.degrees(dec)
    if not (-90.0 - 1e-9 <= dec_deg <= 90.0 + 1e-9):
        raise InputError(f"declination {dec_deg} deg is outside -90..90")
    w = copy.deepcopy(cube.wcs)
    w.wcs.crval = [math.degrees(ra) % 360.0, min(max(dec_deg, -90.0), 90.0)]
    w.wcs.lonpole = 180.0
    w.wcs.set()
    moved = replace(cube, wcs=w)
    if {"Q", "U"} & set(cube.stokes):
        turn = y_axis_position_angle(w, cube.npix) - y_axis_position_angle(cube.wcs,
                                                                            cube.npix)
        moved = rotate_polarization(moved, turn)
    return moved
