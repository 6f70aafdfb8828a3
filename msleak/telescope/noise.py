"""Thermal noise of a correlation by the radiometer equation (docs/noise.md).

Each correlation of a baseline (p, q) of bandwidth dnu (Hz) integrated for dt (s) gets
complex Gaussian noise whose real and imaginary parts each have the rms

    sigma_pq = sqrt(SEFD_p SEFD_q) / sqrt(2 dnu dt)          (Jy),

independent between correlations, channels, rows and the two parts (Thompson, Moran &
Swenson, eq. 6.50; SEFD in Jy). :func:`thermal_noise` draws it from a seeded generator so a
run is reproducible and its chunks independent of each other.
"""

from __future__ import annotations

import numpy as np

from msleak.errors import InputError

__all__ = ["radiometer_sigma", "thermal_noise", "NOISE_CHUNK_ROWS"]

#: rows drawn from one generator stream: chunk ``k`` of a run uses the stream (seed, k), so
#: the noise of a row depends on the seed and the row alone
NOISE_CHUNK_ROWS = 10_000


def radiometer_sigma(sefd_p: np.ndarray, sefd_q: np.ndarray, bandwidth_hz: np.ndarray,
                     exposure_s: np.ndarray) -> np.ndarray:
    """rms (Jy) of the real and of the imaginary part of a correlation (row, chan).

    Parameters
    ----------
    sefd_p, sefd_q : (row,) Jy
        System equivalent flux densities of the two stations.
    bandwidth_hz : (chan,) Hz
    exposure_s : (row,) s
    """
    sefd = np.sqrt(np.asarray(sefd_p, float) * np.asarray(sefd_q, float))
    bandwidth = np.asarray(bandwidth_hz, float)
    exposure = np.asarray(exposure_s, float)
    if np.any(bandwidth <= 0) or np.any(exposure <= 0) or np.any(~(sefd >= 0)):
        raise InputError("the radiometer equation needs positive channel widths and "
                         "exposures and non-negative SEFDs")
    return sefd[:, None] / np.sqrt(2.0 * bandwidth[None, :] * exposure[:, None])


def thermal_noise(sigma: np.ndarray, ncorr: int, seed: int, chunk: int) -> np.ndarray:
    """Complex noise (row, chan, ncorr) with rms ``sigma`` (row, chan) in each part, from
    the generator stream (``seed``, ``chunk``)."""
    rng = np.random.default_rng([int(seed), int(chunk)])
    shape = (*sigma.shape, ncorr)
    noise = rng.standard_normal(shape) + 1j * rng.standard_normal(shape)
    return noise * sigma[..., None]
