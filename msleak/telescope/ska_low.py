"""An approximate SKA-Low core: station centres and the element layout of each station.

No package on PyPI ships the SKA-Low station coordinates, so msleak generates an
*SKA-Low-like* core from the public design (docs/ska_low.md):

* stations of 38 m diameter, each with 256 dual-polarised log-periodic elements;
* a dense core about 1 km across near the array centre on the Murchison site
  (:data:`SKA_LOW_CENTRE`, longitude ~116.76 deg, latitude ~-26.82 deg);
* station centres on a perturbed sunflower (Vogel) spiral, at least
  :data:`MIN_STATION_SEPARATION_M` apart, on a flat ground (Up = 0);
* elements on a perturbed, randomly rotated sunflower spiral inside the station disc,
  at least :data:`MIN_ELEMENT_SPACING_M` apart, different for every station.

These are *not* the real SKA-Low positions (the real core also has a radial density
taper and terrain heights, and the outer stations lie in clusters along three spiral
arms out to ~65 km); a user's layout file with the real positions is read with
:func:`ska_low_from_layout_file`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msleak.beam.coords import enu_basis
from msleak.errors import InputError
from msleak.telescope.layouts import HBA_FIELD_DIAMETER, Layout, enu_to_itrf, read_layout_file

__all__ = ["SKA_LOW_CENTRE", "SKA_LOW_TELESCOPE_NAME", "STATION_DIAMETER_M",
           "ELEMENTS_PER_STATION", "MIN_ELEMENT_SPACING_M", "MIN_STATION_SEPARATION_M",
           "SkaLowLayout", "ska_low_centre_itrf", "station_elements", "ska_low_layout",
           "station_axes", "station_element_offsets", "ska_low_from_layout_file"]

log = logging.getLogger(__name__)

#: Approximate geodetic (WGS84) SKA-Low array centre: longitude, latitude (deg), height (m).
SKA_LOW_CENTRE = (116.7644482, -26.82472208, 377.8)
#: OBSERVATION::TELESCOPE_NAME for which EveryBeam 0.9.0 builds an SKA-Low (OSKAR) beam.
SKA_LOW_TELESCOPE_NAME = "SKA-LOW"
#: Station diameter (m) and elements per station of the SKA-Low design.
STATION_DIAMETER_M = 38.0
ELEMENTS_PER_STATION = 256
#: Minimum distance (m) between element centres in a generated station.
MIN_ELEMENT_SPACING_M = 1.5
#: Minimum distance (m) between generated station centres (38 m discs plus a 2 m gap).
MIN_STATION_SEPARATION_M = 40.0

_GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


@dataclass(frozen=True)
class SkaLowLayout:
    """Station names and positions of an SKA-Low(-like) array.

    Attributes
    ----------
    names : list of str
    enu : (nstation, 3) array
        East, North, Up offsets from ``reference``, m.
    positions : (nstation, 3) array
        ITRF station centres, m.
    reference : (3,) array
        ITRF position of the ENU origin, m.
    approximate : bool
        True for a generated layout (not the real SKA-Low positions).
    """

    names: list
    enu: np.ndarray
    positions: np.ndarray
    reference: np.ndarray
    approximate: bool = True

    def __len__(self) -> int:
        return len(self.names)

    def to_layout(self):
        """As a :class:`msleak.telescope.layouts.Layout` (TELESCOPE_NAME ``SKA-LOW``)."""
        return Layout(names=list(self.names), positions=self.positions.copy(),
                      diameters=np.full(len(self.names), STATION_DIAMETER_M),
                      telescope=SKA_LOW_TELESCOPE_NAME)


def ska_low_centre_itrf() -> np.ndarray:
    """ITRF position (3,) m of :data:`SKA_LOW_CENTRE`."""
    import astropy.units as u
    from astropy.coordinates import EarthLocation

    lon, lat, h = SKA_LOW_CENTRE
    loc = EarthLocation.from_geodetic(lon * u.deg, lat * u.deg, h * u.m)
    return np.array([loc.x.to_value(u.m), loc.y.to_value(u.m), loc.z.to_value(u.m)])


def _perturbed_sunflower(n: int, radius: float, min_dist: float, jitter: float,
                         rng: np.random.Generator) -> np.ndarray:
    """``n`` points (n, 2) on a sunflower spiral of ``radius``, each moved by up to
    ``jitter`` where that keeps every pair ``min_dist`` apart and the point inside ``radius``.

    Raises InputError if the unperturbed spiral is already too dense.
    """
    k = np.arange(n) + 0.5
    r = radius * np.sqrt(k / n)
    a = k * _GOLDEN_ANGLE + rng.uniform(0.0, 2 * np.pi)
    pts = np.stack([r * np.cos(a), r * np.sin(a)], axis=-1)
    if n > 1:
        gaps = np.linalg.norm(pts[:, None] - pts[None], axis=-1) + np.eye(n) * 1e300
        if gaps.min() < min_dist:
            raise InputError(f"{n} points do not fit {min_dist:g} m apart in a "
                             f"{2 * radius:g} m disc; use fewer or a larger diameter")
    for i in rng.permutation(n):
        for _ in range(20):
            step = jitter * np.sqrt(rng.uniform()) * np.exp(2j * np.pi * rng.uniform())
            trial = pts[i] + (step.real, step.imag)
            if np.hypot(*trial) > radius:
                continue
            dist = np.linalg.norm(pts - trial, axis=-1)
            dist[i] = np.inf
            if dist.min() >= min_dist:
                pts[i] = trial
                break
    return pts


def station_elements(n: int = ELEMENTS_PER_STATION, diameter: float = STATION_DIAMETER_M,
                     seed: int = 0, min_spacing: float = MIN_ELEMENT_SPACING_M,
                     jitter: float = 0.4) -> np.ndarray:
    """Element positions of one station: a perturbed, rotated sunflower pattern.

    Parameters
    ----------
    n : int
        Number of elements.
    diameter : float
        Station diameter, m; element centres lie within ``diameter / 2 - min_spacing / 2``
        of the centre, so the elements themselves fit the disc.
    seed : int
        Random seed (rotation of the spiral and perturbations).
    min_spacing : float
        Minimum distance between element centres, m.
    jitter : float
        Largest perturbation of an element from the spiral, m.

    Returns
    -------
    (n, 3) float array
        East, North, Up offsets from the station centre, m (Up = 0), centred on their mean.
    """
    if n < 1 or diameter <= 0 or min_spacing < 0 or jitter < 0:
        raise InputError("station elements: need n >= 1, diameter > 0, min_spacing >= 0 "
                         "and jitter >= 0")
    radius = diameter / 2 - min_spacing / 2
    pts = _perturbed_sunflower(int(n), radius, min_spacing, jitter,
                               np.random.default_rng(seed))
    return np.column_stack([pts, np.zeros(len(pts))])


def ska_low_layout(n_stations: int = 224, seed: int = 0, core_diameter: float = 1000.0,
                   min_separation: float = MIN_STATION_SEPARATION_M,
                   jitter: float = 8.0) -> SkaLowLayout:
    """An approximate SKA-Low core (see the module notes: not the real positions).

    Parameters
    ----------
    n_stations : int
        Number of core stations (the SKA-Low design has 224 in its ~1 km core).
    seed : int
        Random seed of the perturbations.
    core_diameter : float
        Diameter of the disc holding the station centres, m.
    min_separation : float
        Minimum distance between station centres, m.
    jitter : float
        Largest perturbation of a station from the spiral, m.

    Returns
    -------
    SkaLowLayout
        Stations ``S000``, ``S001``, ... around :data:`SKA_LOW_CENTRE`.
    """
    if n_stations < 2:
        raise InputError("an SKA-Low layout needs at least two stations")
    pts = _perturbed_sunflower(int(n_stations), core_diameter / 2, min_separation, jitter,
                               np.random.default_rng(seed))
    enu = np.column_stack([pts, np.zeros(len(pts))])
    ref = ska_low_centre_itrf()
    return SkaLowLayout(names=[f"S{i:03d}" for i in range(len(enu))], enu=enu,
                        positions=enu_to_itrf(enu, ref), reference=ref)


def station_axes(positions_itrf) -> np.ndarray:
    """Per station the East, North, Up unit vectors (rows) in ITRF (WGS84), (n, 3, 3)."""
    positions = np.atleast_2d(np.asarray(positions_itrf, dtype=float))
    return np.array([enu_basis(p) for p in positions])


def station_element_offsets(positions_itrf, *, seed: int = 0,
                            n_elements: int = ELEMENTS_PER_STATION,
                            diameter: float = STATION_DIAMETER_M,
                            min_spacing: float = MIN_ELEMENT_SPACING_M):
    """Axes and ITRF element offsets of every station, as PHASED_ARRAY holds them.

    Station ``i`` gets :func:`station_elements` with seed ``(seed, i)``, expressed in
    ITRF with its own local East, North, Up axes.

    Returns
    -------
    axes : (nstation, 3, 3) array
        :func:`station_axes`.
    offsets : list of (n_elements, 3) arrays
        Element offsets from the station centre, ITRF m.
    """
    axes = station_axes(positions_itrf)
    seeds = np.random.SeedSequence([int(seed), 0x5CA]).generate_state(len(axes))
    offsets = [station_elements(n_elements, diameter, int(s), min_spacing) @ a
               for s, a in zip(seeds, axes)]
    return axes, offsets


def ska_low_from_layout_file(path: str | Path, pattern: str | None = None):
    """A layout file (format of :mod:`msleak.telescope.layouts`) as an SKA-Low array.

    TELESCOPE_NAME becomes ``SKA-LOW`` and the diameter 38 m where the file leaves the
    layout-file default (30.75 m);
    an ENU file must state its ``reference =`` position (the default is LOFAR's).
    """
    lay = read_layout_file(path, pattern)
    far = np.linalg.norm(lay.positions - ska_low_centre_itrf(), axis=1).max()
    if far > 200e3:
        raise InputError(f"{path}: stations lie up to {far / 1e3:.0f} km from the SKA-Low "
                         "site; give ITRF positions or 'reference = X,Y,Z' of the site")
    # the layout-file default diameter is LOFAR's HBA field (30.75 m): use SKA-Low's
    diameters = np.where(lay.diameters == HBA_FIELD_DIAMETER, STATION_DIAMETER_M,
                         lay.diameters)
    return Layout(names=list(lay.names), positions=lay.positions, diameters=diameters,
                  telescope=SKA_LOW_TELESCOPE_NAME)
