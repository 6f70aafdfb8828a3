"""Summary statistics of sky maps (pure numpy): the flat-sky angular power spectrum."""

from __future__ import annotations

import numpy as np

from msleak.errors import InputError

__all__ = ["angular_power_spectrum"]


def angular_power_spectrum(image: np.ndarray, pixel_rad: float, nbins: int = 12
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Azimuthally averaged flat-sky angular power spectrum of a (complex) map.

    With the map T(x) on N = ny * nx pixels of solid angle Omega_p = pixel^2 (total
    area A = N Omega_p), C(ell) = < |Omega_p FFT(T)|^2 > / A in (map unit)^2 sr, at
    multipole ell = 2 pi |u| (u in cycles per radian). For a complex map (P = Q + iU)
    this is the power of Q plus that of U. The mean (ell = 0) is excluded.

    Parameters
    ----------
    image : (ny, nx) real or complex map
    pixel_rad : pixel size, rad (square pixels)
    nbins : logarithmic ell bins between the fundamental mode and the Nyquist ell

    Returns
    -------
    ell : (nbins,) mean ell of the modes in each bin
    cl : (nbins,) C(ell), (map unit)^2 sr; NaN for empty bins
    d_ell : (nbins,) ell (ell + 1) C(ell) / (2 pi), (map unit)^2
    """
    img = np.asarray(image)
    if img.ndim != 2 or min(img.shape) < 2:
        raise InputError(f"an angular power spectrum needs a 2-D map, got {img.shape}")
    ny, nx = img.shape
    omega = pixel_rad**2
    ft = np.fft.fft2(img) * omega
    power = np.abs(ft) ** 2 / (ny * nx * omega)
    uy = np.fft.fftfreq(ny, d=pixel_rad)[:, None]
    ux = np.fft.fftfreq(nx, d=pixel_rad)[None, :]
    ell = 2 * np.pi * np.hypot(uy, ux)
    lmin = 2 * np.pi / (max(ny, nx) * pixel_rad)
    lmax = np.pi / pixel_rad
    edges = np.geomspace(lmin * 0.999, lmax * 1.001, nbins + 1)
    idx = np.digitize(ell.ravel(), edges) - 1
    use = (ell.ravel() > 0) & (idx >= 0) & (idx < nbins)
    counts = np.bincount(idx[use], minlength=nbins)
    csum = np.bincount(idx[use], weights=power.ravel()[use], minlength=nbins)
    lsum = np.bincount(idx[use], weights=ell.ravel()[use], minlength=nbins)
    with np.errstate(invalid="ignore", divide="ignore"):
        cl = csum / counts
        ellc = lsum / counts
    return ellc, cl, ellc * (ellc + 1) * cl / (2 * np.pi)
