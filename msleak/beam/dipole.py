"""An analytic beam for any Measurement Set: crossed dipoles times a scalar station factor.

:class:`DipoleBeam` (``load_beam("dipole", ms, ...)`` in :mod:`msleak.adapters.beams`) gives, per station, the projection
of ideal X and Y dipoles (X along local North for feed angle 0) on the sky (North, East)
basis (:func:`dipole_jones`), optionally times a ground-plane factor, times a scalar
station factor (:func:`station_factor`: ``airy``, ``gaussian`` or ``none``, from the
station diameter). Directions below the station's horizon get a zero matrix.

Formulas: docs/beam.md ("The dipole model").
"""

from __future__ import annotations

import logging
from typing import Literal

import numpy as np

from msleak.beam.base import BeamModel
from msleak.beam.coords import (
    clip_pole,
    enu_basis,
    itrf_map,
    radec_to_unit,
    sky_basis,
)
from msleak.constants import SPEED_OF_LIGHT
from msleak.errors import BeamUnavailable, InputError

__all__ = ["DipoleBeam", "dipole_jones", "station_factor", "StationFactor"]

log = logging.getLogger(__name__)

StationFactor = Literal["airy", "gaussian", "none"]


def station_factor(kind: StationFactor, theta: np.ndarray, freq: np.ndarray,
                   diameter_m: float) -> np.ndarray:
    """Scalar station voltage pattern (nchan, ndir) for angles ``theta`` (ndir,) rad."""
    theta = np.asarray(theta, dtype=float)
    freq = np.asarray(freq, dtype=float)
    if kind == "none":
        return np.ones((freq.size, theta.size))
    if diameter_m <= 0:
        raise InputError(f"station diameter must be positive for a {kind} station factor, "
                         f"got {diameter_m} m")
    if kind == "airy":
        from scipy.special import j1

        u = np.pi * diameter_m * freq[:, None] * np.sin(theta)[None, :] / SPEED_OF_LIGHT
        small = np.abs(u) < 1e-8
        safe = np.where(small, 1.0, u)
        return np.where(small, 1.0 - u ** 2 / 8, 2 * j1(safe) / safe)
    if kind == "gaussian":
        fwhm = 1.02 * SPEED_OF_LIGHT / (freq[:, None] * diameter_m)
        return np.exp(-2 * np.log(2) * (theta[None, :] / fwhm) ** 2)
    raise InputError(f"unknown station factor {kind!r}: use airy, gaussian or none")


def dipole_jones(d: np.ndarray, north: np.ndarray, east: np.ndarray, enu: np.ndarray,
                 freq: np.ndarray, *, feed_angle_rad: float = 0.0,
                 ground_plane_height_m: float | None = None) -> np.ndarray:
    """Crossed-dipole Jones (nchan, ndir, 2, 2) of one station, without station factor.

    Parameters
    ----------
    d, north, east : (ndir, 3) arrays
        ITRF direction and its sky basis.
    enu : (3, 3) array
        Rows: the station's local east, north, up (ITRF unit vectors).
    freq : (nchan,) array, Hz
    feed_angle_rad : float
        Angle of the X dipole from local north through east.
    ground_plane_height_m : float, optional
        Height of the dipoles above a perfectly conducting ground plane.
    """
    e_loc, n_loc, up = enu
    ca, sa = np.cos(feed_angle_rad), np.sin(feed_angle_rad)
    x = ca * n_loc + sa * e_loc
    y = -sa * n_loc + ca * e_loc
    proj = np.empty((len(d), 2, 2))
    proj[:, 0, 0] = north @ x
    proj[:, 0, 1] = east @ x
    proj[:, 1, 0] = north @ y
    proj[:, 1, 1] = east @ y
    cosz = d @ up
    proj[cosz < 0] = 0
    out = np.broadcast_to(proj, (freq.size, len(d), 2, 2)).astype(complex)
    if ground_plane_height_m is not None:
        g = 2 * np.sin(2 * np.pi * freq[:, None] * ground_plane_height_m * cosz[None, :] / SPEED_OF_LIGHT)
        out = out * g[:, :, None, None]
    return out


class DipoleBeam(BeamModel):
    """The analytic ``dipole`` beam of the stations of an MS (see module notes).

    Parameters
    ----------
    positions : (nstation, 3) array
        ITRF station positions, m.
    diameters : (nstation,) array
        Station diameters, m (used by the station factor).
    pointing : (ra, dec)
        J2000 pointing of the station factor, rad.
    phase_centre : (ra, dec)
        J2000 phase centre, rad.
    station_names : list of str, optional
    used_stations : int array, optional
        The stations (rows of ``positions``) the beam is for: only their positions and
        diameters are checked and define the array centre; all by default.
    factor : {'airy', 'gaussian', 'none'}
    feed_angle_deg : float
        X dipole angle from local north through east, deg.
    ground_plane_height_m : float, optional
        Dipole height above a ground plane; free-space dipoles if None.
    diameter_m : float, optional
        Overrides ``diameters`` for every station.
    """

    name = "dipole"

    def __init__(self, positions, diameters, pointing, phase_centre, station_names=None, *,
                 used_stations=None, factor: StationFactor = "airy",
                 feed_angle_deg: float = 0.0, ground_plane_height_m: float | None = None,
                 diameter_m: float | None = None):
        positions = np.asarray(positions, dtype=float).reshape(-1, 3)
        super().__init__(len(positions), phase_centre, station_names, used_stations)
        used = self.used_stations
        if factor not in ("airy", "gaussian", "none"):
            raise InputError(f"unknown station factor {factor!r}: use airy, gaussian or none")
        diam = np.asarray(diameters, dtype=float).reshape(-1)
        if diameter_m is not None:
            if not diameter_m > 0:
                raise InputError(f"station diameter must be positive, got {diameter_m} m")
            diam = np.full(len(positions), float(diameter_m))
        if factor != "none" and not np.all(diam[used] > 0):
            bad = [self.station_names[i] for i in used if not diam[i] > 0]
            raise BeamUnavailable(
                f"ANTENNA::DISH_DIAMETER gives no diameter (<= 0) for station(s) "
                f"{', '.join(bad[:4])}{', ...' if len(bad) > 4 else ''}, so no Airy station "
                "factor", remedy="pass the station diameter with `diameter=M`")
        self._check_positions(positions)
        if ground_plane_height_m is not None and ground_plane_height_m <= 0:
            raise InputError("ground-plane height must be positive (m)")
        self.positions = positions
        self.diameters = diam
        self.pointing = (float(pointing[0]), float(pointing[1]))
        self.factor = factor
        self.feed_angle = np.radians(feed_angle_deg)
        self.ground_plane_height_m = ground_plane_height_m
        self._enu = np.zeros((len(positions), 3, 3))
        self._enu[used] = [enu_basis(positions[i]) for i in used]
        self._centre = positions[used].mean(axis=0)

    def _jones(self, time, freq, ra, dec, stations, dtype):
        out = np.zeros((stations.size, time.size, freq.size, ra.size, 2, 2), dtype)
        u = radec_to_unit(ra, clip_pole(dec))
        p = radec_to_unit(self.pointing[0], clip_pole(self.pointing[1]))
        diam_cache: dict[float, np.ndarray] = {}
        for it, t in enumerate(time):
            fitmap = itrf_map(float(t), np.vstack([u, p]), position_itrf=self._centre)
            d = fitmap(u)
            north, east = sky_basis(d, fitmap.pole())
            theta = np.arccos(np.clip(d @ fitmap(p), -1, 1))
            diam_cache.clear()
            for si, s in enumerate(stations):
                diam = float(self.diameters[s])
                if diam not in diam_cache:
                    diam_cache[diam] = station_factor(self.factor, theta, freq, diam)
                j = dipole_jones(d, north, east, self._enu[s], freq,
                                 feed_angle_rad=self.feed_angle,
                                 ground_plane_height_m=self.ground_plane_height_m)
                out[si, it] = j * diam_cache[diam][:, :, None, None]
        return out
