"""Gaussian random fields with power-law spectra on periodic 3-D boxes (numpy FFT).

Conventions
-----------
A field ``f`` on a box of shape ``(nz, ny, nx)`` with cell sizes ``(dz, dy, dx)`` (any
length unit, pc in msleak) has the 3-D power spectrum

    P(k) = |f_k|^2 proportional to (k^2 + k0^2)^(-alpha / 2),     k0 = 2 pi / outer_scale

with ``k`` the angular wavenumber (rad per length unit) and ``k0 = 0`` (a pure power law)
unless an outer scale is given. The k = 0 mode and the Nyquist planes of even-length axes
are removed, so fields have zero mean (and vector fields stay divergence-free), and
every field is normalised to unit variance over the box. For Kolmogorov turbulence the 3-D
index is alpha = 11/3.
"""

from __future__ import annotations

import numpy as np

from msleak.errors import InputError

__all__ = [
    "wavenumbers",
    "gaussian_random_field",
    "solenoidal_vector_field",
    "lognormal_field",
]


def wavenumbers(shape: tuple[int, int, int], cell: tuple[float, float, float]
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Angular wavenumbers of an ``rfftn`` of a box.

    Parameters
    ----------
    shape : (nz, ny, nx)
    cell : (dz, dy, dx) cell sizes (length unit L)

    Returns
    -------
    kz, ky, kx : arrays broadcastable to (nz, ny, nx // 2 + 1), rad / L
    """
    nz, ny, nx = shape
    dz, dy, dx = cell
    kz = 2 * np.pi * np.fft.fftfreq(nz, d=dz)[:, None, None]
    ky = 2 * np.pi * np.fft.fftfreq(ny, d=dy)[None, :, None]
    kx = 2 * np.pi * np.fft.rfftfreq(nx, d=dx)[None, None, :]
    return kz, ky, kx


def _amplitude(shape, cell, alpha: float, outer_scale: float | None) -> np.ndarray:
    kz, ky, kx = wavenumbers(shape, cell)
    k2 = kz**2 + ky**2 + kx**2
    if outer_scale is not None:
        k2 = k2 + (2 * np.pi / outer_scale) ** 2
    with np.errstate(divide="ignore"):
        amp = k2 ** (-alpha / 4.0)  # sqrt of P(k) = k^-alpha
    amp[0, 0, 0] = 0.0
    # drop the Nyquist planes of even axes: their sign is ambiguous, so a projection
    # (div B = 0) cannot survive the real transform there
    nz, ny, nx = shape
    if nz % 2 == 0:
        amp[nz // 2, :, :] = 0.0
    if ny % 2 == 0:
        amp[:, ny // 2, :] = 0.0
    if nx % 2 == 0:
        amp[:, :, -1] = 0.0
    return amp


def _check(shape, cell, alpha):
    if len(shape) != 3 or min(shape) < 2:
        raise InputError(f"a random-field box needs 3 axes of at least 2 cells, got {shape}")
    if min(cell) <= 0:
        raise InputError(f"cell sizes must be positive, got {cell}")
    if not np.isfinite(alpha):
        raise InputError(f"spectral index must be finite, got {alpha}")


def gaussian_random_field(shape: tuple[int, int, int], cell: tuple[float, float, float],
                          alpha: float, rng: np.random.Generator, *,
                          outer_scale: float | None = None) -> np.ndarray:
    """A zero-mean, unit-variance Gaussian random field with P(k) ~ k^-alpha.

    White noise drawn from ``rng`` (standard normal, float64, C order) is filtered in
    Fourier space, so the same generator state gives the same field bit for bit.

    Parameters
    ----------
    shape : (nz, ny, nx)
    cell : (dz, dy, dx), length unit L
    alpha : 3-D power-spectrum index (P proportional to k^-alpha)
    rng : numpy Generator
    outer_scale : optional outer scale (L); flattens the spectrum below 2 pi / outer_scale

    Returns
    -------
    (nz, ny, nx) float64 array
    """
    _check(shape, cell, alpha)
    noise = rng.standard_normal(shape)
    return _filter_unit(noise, cell, alpha, outer_scale)


def _filter_unit(noise: np.ndarray, cell, alpha, outer_scale) -> np.ndarray:
    fk = np.fft.rfftn(noise)
    fk *= _amplitude(noise.shape, cell, alpha, outer_scale)
    field = np.fft.irfftn(fk, s=noise.shape, axes=(0, 1, 2))
    field -= field.mean()
    std = field.std()
    if std > 0:
        field /= std
    return field


def solenoidal_vector_field(shape: tuple[int, int, int], cell: tuple[float, float, float],
                            alpha: float, rng: np.random.Generator, *,
                            outer_scale: float | None = None,
                            solenoidal: bool = True) -> np.ndarray:
    """A random vector field (e.g. a turbulent magnetic field) with P(k) ~ k^-alpha.

    Three independent Gaussian fields are drawn; with ``solenoidal`` their Fourier
    components are projected perpendicular to k (div B = 0), which keeps the isotropic
    spectral shape. The result is scaled so that the mean of |B|^2 over the box is 1
    (each component has variance ~1/3).

    Returns
    -------
    (3, nz, ny, nx) float64 array, components along (z, y, x)
    """
    _check(shape, cell, alpha)
    noise = rng.standard_normal((3, *shape))
    amp = _amplitude(shape, cell, alpha, outer_scale)
    fk = np.stack([np.fft.rfftn(noise[i]) * amp for i in range(3)])
    del noise
    if solenoidal:
        kz, ky, kx = wavenumbers(shape, cell)
        k2 = kz**2 + ky**2 + kx**2
        k2[0, 0, 0] = 1.0
        kdotb = (kz * fk[0] + ky * fk[1] + kx * fk[2]) / k2
        fk[0] -= kz * kdotb
        fk[1] -= ky * kdotb
        fk[2] -= kx * kdotb
        del kdotb
    vec = np.stack([np.fft.irfftn(fk[i], s=shape, axes=(0, 1, 2)) for i in range(3)])
    del fk
    vec -= vec.mean(axis=(1, 2, 3), keepdims=True)
    norm = np.sqrt(np.mean(np.sum(vec**2, axis=0)))
    if norm > 0:
        vec /= norm
    return vec


def lognormal_field(gauss: np.ndarray, mean: float, sigma_ln: float) -> np.ndarray:
    """A positive field ``mean * exp(sigma g - sigma^2 / 2)`` from a unit Gaussian ``g``.

    Its expectation is ``mean`` and its logarithm has standard deviation ``sigma_ln``;
    ``sigma_ln = 0`` gives the uniform field ``mean``.
    """
    if sigma_ln < 0:
        raise InputError(f"log-normal width must be >= 0, got {sigma_ln}")
    return mean * np.exp(sigma_ln * gauss - 0.5 * sigma_ln**2)

