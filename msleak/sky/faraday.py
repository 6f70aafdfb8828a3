"""Differential Faraday rotation through a box of emitting, rotating cells (pure numpy).

Geometry: a box of shape (nz, ny, nx); z is the line of sight, cell 0 nearest the
observer, each cell ``dl_pc`` deep. Every cell has a polarized emissivity ``amp``
(brightness per cell at the reference frequency), an intrinsic polarization angle
``chi0`` (rad, IAU: from north through east) and a Faraday thickness

    dphi = 0.812 n_e[cm^-3] B_par[uG] dl[pc]   rad m^-2   (B_par > 0 towards the observer)

The Faraday depth at the near face of cell z is phi_z = sum_{z' < z} dphi_z'. Inside a
cell the medium is uniform, so its emission is integrated exactly along the cell:

    P(lambda^2) = sum_z amp_z exp(2i (chi0_z + (phi_z + dphi_z / 2) lambda^2))
                          * sin(dphi_z lambda^2) / (dphi_z lambda^2)

which makes a uniform slab reproduce Burn's (1966) formula for any number of cells.
"""

from __future__ import annotations

import numpy as np

__all__ = ["RM_CONSTANT", "faraday_thickness", "faraday_depth_near_face",
           "polarized_brightness", "burn_slab", "wavelength_squared"]

#: e^3 / (2 pi m_e^2 c^4) in rad m^-2 per (cm^-3 uG pc).
RM_CONSTANT = 0.812

from msleak.constants import SPEED_OF_LIGHT


def wavelength_squared(freq_hz) -> np.ndarray:
    """lambda^2 = (c / nu)^2 in m^2."""
    return (SPEED_OF_LIGHT / np.asarray(freq_hz, dtype=float)) ** 2


def faraday_thickness(ne_cm3: np.ndarray, bpar_ug: np.ndarray, dl_pc: float) -> np.ndarray:
    """Faraday thickness of every cell, rad m^-2 (same shape as the inputs)."""
    return RM_CONSTANT * ne_cm3 * bpar_ug * dl_pc


def faraday_depth_near_face(dphi: np.ndarray) -> np.ndarray:
    """Faraday depth from the observer to the near face of each cell (axis 0 = z)."""
    phi = np.cumsum(dphi, axis=0)
    phi -= dphi
    return phi


def polarized_brightness(amp: np.ndarray, chi0: np.ndarray, dphi: np.ndarray,
                         freq_hz: np.ndarray, *, spectral_factor: np.ndarray | None = None,
                         chunk_cells: int = 2_000_000) -> np.ndarray:
    """Complex polarized brightness P = Q + iU of a box at each frequency.

    Parameters
    ----------
    amp : (nz, ny, nx) polarized emissivity of each cell at the reference frequency
        (brightness units, e.g. K per cell)
    chi0 : (nz, ny, nx) intrinsic polarization angle, rad
    dphi : (nz, ny, nx) Faraday thickness of each cell, rad m^-2
    freq_hz : (nchan,) Hz
    spectral_factor : (nchan,) optional brightness scaling of the emission with frequency
        (e.g. (nu / nu_ref)^-beta); 1 if omitted
    chunk_cells : bound on the number of cells processed at once (memory)

    Returns
    -------
    (nchan, ny, nx) complex128
    """
    nz, ny, nx = amp.shape
    lam2 = wavelength_squared(np.atleast_1d(freq_hz))
    fac = np.ones(lam2.size) if spectral_factor is None else np.asarray(spectral_factor, float)
    phi_mid = faraday_depth_near_face(dphi) + 0.5 * dphi
    out = np.empty((lam2.size, ny, nx), dtype=np.complex128)
    rows = max(1, int(chunk_cells // max(1, nz * nx)))
    for y0 in range(0, ny, rows):
        sl = np.s_[:, y0:y0 + rows, :]
        a, c, pm, dp = amp[sl], chi0[sl], phi_mid[sl], dphi[sl]
        for ic, l2 in enumerate(lam2):
            phase = 2.0 * (c + pm * l2)
            depol = np.sinc(dp * l2 / np.pi)          # sin(x)/x, x = dphi lambda^2
            term = a * depol
            out[ic, y0:y0 + rows, :] = fac[ic] * (
                np.sum(term * np.cos(phase), axis=0) + 1j * np.sum(term * np.sin(phase), axis=0))
    return out


def burn_slab(p0: float, chi0: float, total_depth: float, freq_hz) -> np.ndarray:
    """Burn (1966): uniform emitting and rotating slab of total Faraday depth F.

    P = P0 exp(2i (chi0 + F lambda^2 / 2)) sin(F lambda^2) / (F lambda^2).
    """
    l2 = wavelength_squared(freq_hz)
    x = total_depth * l2
    return p0 * np.exp(2j * (chi0 + 0.5 * x)) * np.sinc(x / np.pi)
