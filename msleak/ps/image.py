"""uv cubes from image cubes (docs/science.md section 6): unit conversion and spatial FFT.

An image cube ``S`` (chan, y, x) in Jy per pixel, with pixel offsets
``l = (x - x0) dl_x``, ``m = (y - y0) dl_y`` (rad, signed as CDELT1/2: RA pixels usually
have ``dl_x < 0``), ``(x0, y0) = (n/2, n/2)``, gives the visibilities at cell centres::

    V(u_c, v_c) = sum_{x, y} S(x, y) exp(-2 pi i (u_c l + v_c m))      (Jy)

on cells of ``1 / (n |dl|)`` wavelengths, the same convention and orientation as the
visibility gridders (u towards increasing l = East for a standard RA axis).
"""

from __future__ import annotations

import math

import numpy as np

from msleak.constants import jy_per_kelvin
from msleak.errors import InputError

__all__ = ["beam_solid_angle", "to_jy_per_pixel", "crop_centre", "image_to_uv",
           "IMAGE_UNITS"]

#: BUNIT values understood (upper case, spaces removed) -> canonical
IMAGE_UNITS = {"JY/BEAM": "Jy/beam", "JY/PIXEL": "Jy/pixel", "JY/PIX": "Jy/pixel",
               "K": "K", "MK": "mK"}


def beam_solid_angle(bmaj_deg: float, bmin_deg: float) -> float:
    """Solid angle (sr) of a Gaussian beam of FWHM ``bmaj`` x ``bmin`` (deg)."""
    return math.pi * math.radians(bmaj_deg) * math.radians(bmin_deg) / (4 * math.log(2))


def to_jy_per_pixel(cube: np.ndarray, unit: str, freq_hz: np.ndarray, pixel_sr: float,
                    beam_sr: float | None = None) -> np.ndarray:
    """Convert a cube (..., chan, y, x) to Jy per pixel.

    ``Jy/beam``: times ``pixel_sr / beam_sr``. ``K`` / ``mK`` (Rayleigh-Jeans brightness
    temperature): ``S = 2 k_B T nu^2 / c^2 * pixel_sr / 1e-26``.
    """
    key = unit.upper().replace(" ", "")
    if key not in IMAGE_UNITS:
        raise InputError(f"image unit {unit!r} not understood: use Jy/beam, Jy/pixel, K or mK")
    canon = IMAGE_UNITS[key]
    cube = np.asarray(cube, dtype=np.float64)
    if canon == "Jy/pixel":
        return cube
    if canon == "Jy/beam":
        if not beam_sr or beam_sr <= 0:
            raise InputError("image in Jy/beam without a beam size (BMAJ/BMIN): give "
                             "beam_fwhm or use an image with a restoring beam",
                             param="beam_fwhm")
        return cube * (pixel_sr / beam_sr)
    scale = 1e-3 if canon == "mK" else 1.0
    k_to_jy = jy_per_kelvin(freq_hz, pixel_sr)
    return cube * scale * k_to_jy[:, None, None]


def crop_centre(cube: np.ndarray, n: int) -> np.ndarray:
    """The central ``n x n`` pixels (n even) of a cube (..., y, x), around pixel (N/2, N/2)."""
    ny, nx = cube.shape[-2:]
    if n > min(ny, nx):
        raise InputError(f"field of view of {n} pixels is larger than the image "
                         f"({nx} x {ny} pixels)")
    y0, x0 = ny // 2 - n // 2, nx // 2 - n // 2
    return cube[..., y0:y0 + n, x0:x0 + n]


def image_to_uv(cube: np.ndarray, dl_x: float, dl_y: float, uv_max: float | None = None
                ) -> tuple[np.ndarray, float, int]:
    """Spatial FFT of a Jy/pixel cube to visibilities on cell centres.

    Parameters
    ----------
    cube : (..., chan, y, x) float or complex
        Square (n x n, n even), Jy per pixel.
    dl_x, dl_y : float
        Signed pixel increments, rad (|dl_x| must equal |dl_y|).
    uv_max : float, optional
        Keep cells up to ``uv_max`` wavelengths (plus one); default: all up to Nyquist.

    Returns
    -------
    vis : (..., chan, v, u) complex
        Cells from ``-M`` to ``+M`` on both axes, Jy.
    cell : float
        Cell size, wavelengths.
    M : int
    """
    n = cube.shape[-1]
    if cube.shape[-2] != n or n % 2:
        raise InputError(f"image_to_uv needs an even square image, got {cube.shape[-2:]}")
    if not math.isclose(abs(dl_x), abs(dl_y), rel_tol=1e-6):
        raise InputError(f"pixels are not square ({abs(dl_x)} vs {abs(dl_y)} rad)")
    cell = 1.0 / (n * abs(dl_x))
    M = n // 2 - 1
    if uv_max is not None:
        M = min(M, int(math.ceil(uv_max / cell)) + 1)
    f = np.fft.fftshift(np.fft.fft2(np.fft.ifftshift(cube, axes=(-2, -1))), axes=(-2, -1))
    # f[..., p_y, p_x] with p = index - n/2 is at u = p / (n dl_x), v = p / (n dl_y)
    if dl_x < 0:
        f = np.roll(f[..., ::-1], 1, axis=-1)
    if dl_y < 0:
        f = np.roll(f[..., ::-1, :], 1, axis=-2)
    lo = n // 2 - M
    return f[..., lo:lo + 2 * M + 1, lo:lo + 2 * M + 1], cell, M
