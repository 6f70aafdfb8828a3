"""Sky directions for beam evaluation: J2000 -> ITRF, the sky (North, East) basis, the NCP.

:func:`itrf_map` converts many J2000 unit vectors of one time to ITRF through a map
fitted to a few exact casacore conversions
(:func:`msleak.io.measures.exact_j2000_to_itrf`);
:func:`sky_basis` gives EveryBeam's basis ``east = normalize(ncp x d)``,
``north = d x east``; :func:`clip_pole` moves directions within :data:`POLE_EPS_RAD` of
a celestial pole onto their own meridian so the basis stays finite;
:func:`transport_angle` and :func:`basis_rotation` refer Q and U to one frame per map.
Angles in radians, vectors as (..., 3) arrays. Details: docs/beam.md ("Conventions",
"Directions in ITRF").

The one module of :mod:`msleak.beam` that imports :mod:`msleak.io` (its casacore
conversions, :mod:`msleak.io.measures`): every beam model converts directions per time
slot inside its evaluation, and the map it fits needs exact conversions at that time.
"""

from __future__ import annotations

import functools
import logging

import numpy as np

from msleak.io.measures import exact_j2000_to_itrf, itrf_to_j2000

__all__ = [
    "POLE_EPS_RAD",
    "radec_to_unit",
    "unit_to_radec",
    "clip_pole",
    "ItrfMap",
    "itrf_map",
    "sky_basis",
    "enu_basis",
    "zenith_j2000",
    "transport_angle",
    "basis_rotation",
]

log = logging.getLogger(__name__)

#: Directions closer than this (rad, about 2 mas) to a celestial pole are moved onto their
#: meridian at this distance, so that the (North, East) basis is defined.
POLE_EPS_RAD = 1e-8


def radec_to_unit(ra, dec) -> np.ndarray:
    """Cartesian unit vectors (..., 3) of directions (ra, dec) in rad."""
    ra = np.asarray(ra, dtype=float)
    dec = np.asarray(dec, dtype=float)
    cd = np.cos(dec)
    return np.stack([cd * np.cos(ra), cd * np.sin(ra), np.sin(dec)], axis=-1)


def unit_to_radec(v) -> tuple[np.ndarray, np.ndarray]:
    """(ra, dec) in rad of Cartesian vectors (..., 3); ra in [0, 2 pi)."""
    v = np.asarray(v, dtype=float)
    ra = np.mod(np.arctan2(v[..., 1], v[..., 0]), 2 * np.pi)
    dec = np.arctan2(v[..., 2], np.hypot(v[..., 0], v[..., 1]))
    return ra, dec


def lm_to_radec(l, m, ra0: float, dec0: float) -> tuple[np.ndarray, np.ndarray]:
    """(ra, dec) in rad, ra in [0, 2 pi), of direction cosines (l, m) (East, North) about
    (ra0, dec0) in rad: the inverse of the SIN projection."""
    l, m = np.asarray(l, dtype=float), np.asarray(m, dtype=float)
    n = np.sqrt(np.clip(1 - l ** 2 - m ** 2, 0, None))
    dec = np.arcsin(np.clip(m * np.cos(dec0) + n * np.sin(dec0), -1, 1))
    ra = np.mod(ra0 + np.arctan2(l, n * np.cos(dec0) - m * np.sin(dec0)), 2 * np.pi)
    return ra, dec


def clip_pole(dec, eps: float = POLE_EPS_RAD) -> np.ndarray:
    """Declinations (rad) with the poles replaced by +-(pi/2 - eps) (see module notes)."""
    return np.clip(np.asarray(dec, dtype=float), -np.pi / 2 + eps, np.pi / 2 - eps)


#: a direction this close (rad) outside a map's region still counts as covered: a pole
#: within it is mapped like the directions about it (which :func:`clip_pole` puts 1e-8
#: rad from the pole), so that their (North, East) basis does not rest on the difference
#: between the map and an exact conversion (~1e-7 rad)
_COVER_MARGIN_RAD = 1e-6

#: The J2000 pole as a unit vector.
_J2000_POLE = np.array([0.0, 0.0, 1.0])


class ItrfMap:
    """The J2000 -> ITRF direction map ``normalize(M a + b)`` of one time (see module notes).

    Attributes
    ----------
    matrix : (3, 3) array
    offset : (3,) array
    centre : (3,) array
        J2000 unit vector at the centre of the region the map was fitted over.
    radius : float
        Angular radius (rad) of that region.
    fit_error : float
        Largest angle (rad) between the map and casacore at the anchor directions.
    time, position : float, (3,) array or None
        The time (UTC, MJD s) and frame position (m; None: EveryBeam's LOFAR position)
        the map was fitted for.
    """

    def __init__(self, matrix, offset, centre, radius, fit_error, time=0.0, position=None):
        self.matrix = matrix
        self.offset = offset
        self.centre = centre
        self.radius = radius
        self.fit_error = fit_error
        self.time = time
        self.position = position

    def __call__(self, unit_j2000: np.ndarray) -> np.ndarray:
        """ITRF unit vectors (..., 3) of J2000 unit vectors (..., 3)."""
        v = np.asarray(unit_j2000) @ self.matrix.T + self.offset
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

    def covers(self, unit_j2000: np.ndarray) -> bool:
        """Whether a direction lies inside the region the map was fitted over."""
        cosang = float(np.clip(np.dot(unit_j2000, self.centre), -1, 1))
        return np.arccos(cosang) <= self.radius + _COVER_MARGIN_RAD

    def pole(self) -> np.ndarray:
        """ITRF unit vector (3,) of the J2000 pole: through the map when the pole is inside
        its region (a sky basis consistent with the mapped directions), else converted
        exactly (casacore) at the map's time and position."""
        if self.covers(_J2000_POLE):
            return self(_J2000_POLE)
        return exact_j2000_to_itrf(self.time, 0.0, np.pi / 2, position_itrf=self.position)[0]


def _tangent_basis(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ref = np.array([0.0, 0.0, 1.0]) if abs(c[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e = np.cross(ref, c)
    e /= np.linalg.norm(e)
    return e, np.cross(c, e)


def _solve_map(anchors: np.ndarray, images: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares (M, b) with images ~ normalize(M anchors + b) (homogeneous SVD)."""
    n = len(anchors)
    rows = np.zeros((n, 3, 12))
    for i in range(3):
        rows[:, i, 3 * i:3 * i + 3] = anchors
        rows[:, i, 9 + i] = 1.0
    y = images
    cross = np.zeros((n, 3, 3))
    cross[:, 0, 1], cross[:, 0, 2] = -y[:, 2], y[:, 1]
    cross[:, 1, 0], cross[:, 1, 2] = y[:, 2], -y[:, 0]
    cross[:, 2, 0], cross[:, 2, 1] = -y[:, 1], y[:, 0]
    system = np.einsum("nij,njk->nik", cross, rows).reshape(3 * n, 12)
    # column scaling is unnecessary: all unknowns are of order one
    x = np.linalg.svd(system, full_matrices=False)[2][-1]  # the null vector: thin SVD suffices
    matrix, offset = x[:9].reshape(3, 3), x[9:]
    scale = np.cbrt(np.linalg.det(matrix))
    return matrix / scale, offset / scale


def itrf_map(time_mjd_s: float, unit_j2000: np.ndarray, *, min_radius_rad: float = 0.01,
             position_itrf=None) -> ItrfMap:
    """Fit the J2000 -> ITRF map of one time over the region spanned by ``unit_j2000``.

    Parameters
    ----------
    time_mjd_s : float
        UTC, MJD seconds.
    unit_j2000 : (n, 3) array
        Directions the map must cover.
    min_radius_rad : float
        Smallest radius of the fitted region.
    position_itrf : (3,) array, optional
        Frame position (m); EveryBeam's
        :data:`msleak.io.measures.LOFAR_FRAME_POSITION_ITRF` by default.
    """
    u = np.asarray(unit_j2000, dtype=float).reshape(-1, 3)
    mean = u.mean(axis=0)
    norm = np.linalg.norm(mean)
    centre = mean / norm if norm > 0 else np.array([0.0, 0.0, 1.0])
    spread = float(np.arccos(np.clip(u @ centre, -1, 1)).max())
    if norm < 0.5 or spread > _CAP_MAX_RAD:
        # very wide set of directions: one map over the whole sphere per time and position
        return _sphere_map(float(time_mjd_s), None if position_itrf is None else
                           tuple(float(x) for x in np.ravel(position_itrf)))
    return _fit_map(time_mjd_s, centre, max(spread, min_radius_rad), position_itrf)


#: widest cap (rad) :func:`itrf_map` fits on its own: its anchors reach 80 deg from the
#: centre along the axes, so directions beyond would be extrapolated (errors ~1e-6 rad at
#: 80 deg, growing beyond); wider sets take the whole-sphere map (5e-7 rad)
_CAP_MAX_RAD = np.radians(80.0)


@functools.lru_cache(maxsize=64)
def _sphere_map(time_mjd_s: float, position_itrf: tuple | None) -> ItrfMap:
    """:func:`itrf_map` fitted over the whole sphere (48 anchors on a Fibonacci lattice;
    about 5e-7 rad from casacore), kept for the blocks of directions of the same time."""
    k = np.arange(48) + 0.5
    anchors = radec_to_unit(np.pi * (1 + 5 ** 0.5) * k, np.arcsin(1 - 2 * k / 48))
    log.debug("J2000->ITRF map fitted over the whole sky (accuracy ~5e-7 rad)")
    return _solved(time_mjd_s, anchors, np.array([0.0, 0.0, 1.0]), np.pi,
                   None if position_itrf is None else np.asarray(position_itrf))


def _fit_map(time_mjd_s: float, centre: np.ndarray, radius: float,
             position_itrf) -> ItrfMap:
    """:func:`itrf_map` fitted over the cap of ``radius`` (rad) about ``centre``."""
    e, n = _tangent_basis(centre)
    side = 4 if radius < np.radians(20) else 6
    half = np.tan(min(radius, _CAP_MAX_RAD))
    g = np.linspace(-half, half, side)
    gl, gm = np.meshgrid(g, g)
    anchors = centre + gl.reshape(-1, 1) * e + gm.reshape(-1, 1) * n
    anchors = np.vstack([anchors, centre])
    anchors /= np.linalg.norm(anchors, axis=1, keepdims=True)
    radius = float(np.arccos(np.clip(anchors @ centre, -1, 1)).max())
    return _solved(time_mjd_s, anchors, centre, radius, position_itrf)


def _solved(time_mjd_s: float, anchors: np.ndarray, centre: np.ndarray, radius: float,
            position_itrf) -> ItrfMap:
    """The map fitted to casacore's conversions of ``anchors``."""
    ra, dec = unit_to_radec(anchors)
    images = exact_j2000_to_itrf(time_mjd_s, ra, dec, position_itrf)
    matrix, offset = _solve_map(anchors, images)
    fitted = anchors @ matrix.T + offset
    fitted /= np.linalg.norm(fitted, axis=1, keepdims=True)
    err = float(np.max(np.linalg.norm(fitted - images, axis=1)))
    if err > 1e-8:
        log.debug("J2000->ITRF map fit error %.2g rad at t=%.1f", err, time_mjd_s)
    return ItrfMap(matrix, offset, centre, radius, err, time_mjd_s, position_itrf)


def sky_basis(d_itrf: np.ndarray, ncp_itrf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """EveryBeam's sky polarization basis: (north, east) unit vectors (..., 3) in ITRF.

    ``east = normalize(ncp x d)``, ``north = d x east``; ``d`` must not be the pole (use
    :func:`clip_pole` on the declinations first).
    """
    east = np.cross(ncp_itrf, d_itrf)
    east /= np.linalg.norm(east, axis=-1, keepdims=True)
    north = np.cross(d_itrf, east)
    return north, east


def enu_basis(position_itrf) -> np.ndarray:
    """Rows (east, north, up) (3, 3) of the geodetic (WGS84) local frame at an ITRF position."""
    x, y, z = (float(c) for c in position_itrf)
    a, f = 6378137.0, 1 / 298.257223563
    e2 = f * (2 - f)
    lon = np.arctan2(y, x)
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1 - e2))
    for _ in range(6):
        n = a / np.sqrt(1 - e2 * np.sin(lat) ** 2)
        h = p / np.cos(lat) - n
        lat = np.arctan2(z, p * (1 - e2 * n / (n + h)))
    sl, cl, sp, cp = np.sin(lon), np.cos(lon), np.sin(lat), np.cos(lat)
    return np.array([[-sl, cl, 0.0],
                     [-sp * cl, -sp * sl, cp],
                     [cp * cl, cp * sl, sp]])


def zenith_j2000(time_mjd_s, position_itrf) -> tuple[np.ndarray, np.ndarray]:
    """J2000 (ra, dec) in rad of the geodetic zenith at ITRF ``position_itrf`` (m) at each
    UTC ``time_mjd_s`` (MJD s), one exact casacore conversion each (a few ms)."""
    up = enu_basis(position_itrf)[2]
    lon, lat = float(np.arctan2(up[1], up[0])), float(np.arcsin(up[2]))
    ra, dec = itrf_to_j2000(time_mjd_s, lon, lat, position_itrf)
    return np.mod(ra, 2 * np.pi), dec


def transport_angle(ra0: float, dec0: float, ra, dec) -> np.ndarray:
    """Angle (rad) from the local North of each direction to the phase centre's North
    parallel-transported to it along the great circle, positive towards East.

    The phase centre's (North, East) basis carried to every direction of a map gives one
    Q,U reference frame for the whole map (the tangent-plane basis); at a celestial pole
    the North of ``(ra0, +-90 deg)`` is the limit along the meridian ``ra0``, as in
    :func:`clip_pole`. Zero at the phase centre.
    """
    s0 = radec_to_unit(ra0, dec0)
    s = radec_to_unit(ra, clip_pole(dec))
    north0 = np.array([-np.sin(dec0) * np.cos(ra0), -np.sin(dec0) * np.sin(ra0), np.cos(dec0)])
    axis = np.cross(s0, s)                       # sin(angle) times the rotation axis
    cos_t = s @ s0
    carried = (north0 * cos_t[..., None] + np.cross(axis, north0)
               + axis * (axis @ north0)[..., None] / (1.0 + cos_t[..., None]))
    ra = np.asarray(ra, dtype=float)
    dec = clip_pole(dec)
    north = np.stack([-np.sin(dec) * np.cos(ra), -np.sin(dec) * np.sin(ra), np.cos(dec)], -1)
    east = np.stack([-np.sin(ra), np.cos(ra), np.zeros_like(ra)], -1)
    return np.arctan2(np.sum(carried * east, -1), np.sum(carried * north, -1))


def basis_rotation(psi) -> np.ndarray:
    """Matrices (..., 2, 2) taking (North, East) components in a basis turned by ``psi``
    (towards East) to components in the local (North, East) basis: ``J_local @ R`` is the
    Jones matrix in the turned basis."""
    c, s = np.cos(psi), np.sin(psi)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
