"""Celestial frames of all-sky maps: where a pixel of a Galactic or ecliptic map lies in
ICRS, and how its Q and U turn there (docs/sky.md, "HEALPix skies").

Galactic and ecliptic (mean ecliptic and equinox of J2000) coordinates are fixed rotations
of ICRS, taken from astropy. A frame change moves each pixel centre by that rotation and
turns its polarization basis: the polarization angle (from North through East) grows by
``psi``, the position angle in ICRS of the map frame's North pole seen from the pixel, so
Q + iU is multiplied by exp(2i psi). FK5 (J2000) and ICRS differ by 20 mas, which msleak
neglects everywhere (its J2000 is ICRS): an FK5 or "celestial" map is read as ICRS.
"""

from __future__ import annotations

import functools

import numpy as np

from msleak.errors import InputError

__all__ = ["SKY_FRAMES", "rotation_to_icrs", "north_angle", "rotate_qu"]

#: frames an all-sky map may be in: ICRS (J2000), Galactic, ecliptic (J2000)
SKY_FRAMES = ("icrs", "galactic", "ecliptic")


@functools.lru_cache(maxsize=None)
def rotation_to_icrs(frame: str) -> np.ndarray:
    """(3, 3) matrix R taking unit vectors of ``frame`` to ICRS (R @ v); identity for ICRS.

    Raises
    ------
    InputError
        A frame not in :data:`SKY_FRAMES`.
    """
    if frame not in SKY_FRAMES:
        raise InputError(f"sky frame {frame!r} is not one of {', '.join(SKY_FRAMES)}",
                         param="frame")
    if frame == "icrs":
        return np.eye(3)
    import astropy.units as u
    from astropy.coordinates import BarycentricMeanEcliptic, Galactic, SkyCoord

    native = Galactic() if frame == "galactic" else BarycentricMeanEcliptic(equinox="J2000")
    axes = SkyCoord([0.0, 90.0, 0.0] * u.deg, [0.0, 0.0, 90.0] * u.deg, frame=native).icrs
    ra, dec = axes.ra.rad, axes.dec.rad
    columns = np.stack([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)])
    return columns        # column k: the frame's axis k in ICRS


def north_angle(frame: str, ra: np.ndarray, dec: np.ndarray) -> np.ndarray:
    """Angle (rad) from the ICRS North to ``frame``'s North at ICRS directions (ra, dec)
    (rad), positive towards East: the position angle of the frame's pole there."""
    pole = rotation_to_icrs(frame)[:, 2]
    ra, dec = np.asarray(ra, float), np.asarray(dec, float)
    north = np.stack([-np.sin(dec) * np.cos(ra), -np.sin(dec) * np.sin(ra), np.cos(dec)], -1)
    east = np.stack([-np.sin(ra), np.cos(ra), np.zeros_like(ra)], -1)
    return np.arctan2(east @ pole, north @ pole)


def rotate_qu(q: np.ndarray, u: np.ndarray, psi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Q, U referred to a North turned by ``psi`` towards East: Q' + iU' = (Q + iU)
    exp(2i psi) (``psi`` broadcast against the last axis)."""
    c, s = np.cos(2 * psi), np.sin(2 * psi)
    return q * c - u * s, q * s + u * c
