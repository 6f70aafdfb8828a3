"""Array layouts: LOFAR stations from ``lofarantpos``, or any array from a text file.

A :class:`Layout` holds station names and ITRF positions (m); for LOFAR HBA it also
carries the per-field data EveryBeam needs (:class:`FieldLayout`), which
:mod:`msleak.io.ms_create` writes into the LOFAR subtables.
:func:`lofar_hba_core` gives the LOFAR HBA core, :func:`read_layout_file` reads a
``--layout`` file (ITRF, or ENU about a reference position via :func:`enu_to_itrf`).

The layout file format: docs/simulate.md ("Other arrays: --layout FILE").
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from msleak.errors import InputError

__all__ = ["FieldLayout", "Layout", "lofar_hba_core", "read_layout_file", "enu_to_itrf",
           "LOFAR_CORE_STATIONS", "lofar_reference_position", "hba_tile_pqr"]

LOFAR_CORE_STATIONS = (
    "CS001", "CS002", "CS003", "CS004", "CS005", "CS006", "CS007", "CS011", "CS013",
    "CS017", "CS021", "CS024", "CS026", "CS028", "CS030", "CS031", "CS032", "CS101",
    "CS103", "CS201", "CS301", "CS302", "CS401", "CS501",
)

#: Diameter of a LOFAR core HBA field (24 tiles), m
HBA_FIELD_DIAMETER = 30.75


@dataclass(frozen=True)
class FieldLayout:
    """One LOFAR antenna field (e.g. CS002HBA0), all vectors ITRF in metres.

    ``axes`` rows are the field's P, Q, R unit vectors; ``element_offsets`` (ntile, 3) are
    tile centres relative to ``position``; ``tile_offsets`` (16, 3) the dipoles of a tile
    relative to its centre.
    """

    name: str
    position: np.ndarray
    axes: np.ndarray
    element_offsets: np.ndarray
    tile_offsets: np.ndarray
    tile_rotation: float


@dataclass(frozen=True)
class Layout:
    """Station names, ITRF positions (nstation, 3) m and diameters; LOFAR fields if any."""

    names: list
    positions: np.ndarray
    diameters: np.ndarray
    telescope: str
    fields: list = field(default_factory=list)

    @property
    def is_lofar(self) -> bool:
        return self.telescope == "LOFAR" and len(self.fields) == len(self.names)

    def __len__(self) -> int:
        return len(self.names)

    def select(self, pattern: str | None, what: str) -> "Layout":
        """The stations whose names match one of the comma-separated shell ``pattern``s
        (all if None); ``what`` names the array in the error for fewer than two."""
        if pattern is None:
            return self
        keep = [i for i, n in enumerate(self.names)
                if any(fnmatch.fnmatchcase(n, p.strip()) for p in pattern.split(","))]
        if len(keep) < 2:
            raise InputError(f"stations {pattern!r} selects {len(keep)} station(s) of "
                             f"{what} ({self.names[0]}..{self.names[-1]}); need at least two",
                             param="stations")
        return Layout(names=[self.names[i] for i in keep], positions=self.positions[keep],
                      diameters=self.diameters[keep], telescope=self.telescope,
                      fields=[self.fields[i] for i in keep] if self.fields else [])

    def innermost(self, n: int) -> "Layout":
        """The ``n`` stations nearest the mean position (all if ``n`` >= their number),
        in their original order."""
        if n >= len(self):
            return self
        dist = np.linalg.norm(self.positions - self.positions.mean(axis=0), axis=1)
        keep = np.sort(np.argsort(dist, kind="stable")[:n])
        return Layout(names=[self.names[i] for i in keep], positions=self.positions[keep],
                      diameters=self.diameters[keep], telescope=self.telescope,
                      fields=[self.fields[i] for i in keep] if self.fields else [])


def lofar_reference_position() -> np.ndarray:
    """ITRF position (m) of the LOFAR array reference (casacore's 'LOFAR' observatory)."""
    import casacore.measures as cm

    dm = cm.measures()
    pos = dm.measure(dm.observatory("LOFAR"), "itrf")
    lon, lat, h = pos["m0"]["value"], pos["m1"]["value"], pos["m2"]["value"]
    from astropy.coordinates import EarthLocation
    import astropy.units as u

    # casacore returns the observatory as WGS84 longitude, latitude and height
    loc = EarthLocation.from_geodetic(lon * u.rad, lat * u.rad, h * u.m)
    return np.array([loc.x.to_value(u.m), loc.y.to_value(u.m), loc.z.to_value(u.m)])


#: Distance between neighbouring dipoles of a LOFAR HBA tile, m
HBA_DIPOLE_SPACING = 1.25


def hba_tile_pqr(rotation: float) -> np.ndarray:
    """The 16 dipole offsets (16, 3) of a LOFAR HBA tile from its centre in the field's PQR
    frame (m): a 4 x 4 lattice :data:`HBA_DIPOLE_SPACING` apart, turned by ``rotation`` (rad,
    lofarantpos's ``hba_rotations``), in lofarantpos's order (rows from +Q to -Q, each from
    -P to +P).

    lofarantpos's own ``hba_dipole_pqr`` gives the same lattice rounded to float32 (about
    1e-7 m); this is it in float64, so that the offsets are a product lattice
    ``e[4 i + j] = a[i] + b[j]`` to rounding, as the fast beam evaluator sums them.
    """
    steps = HBA_DIPOLE_SPACING * np.array([-1.5, -0.5, 0.5, 1.5])
    p = np.tile(steps, 4)
    q = np.repeat(steps[::-1], 4)
    c, s = np.cos(rotation), np.sin(rotation)
    return np.stack([c * p + s * q, -s * p + c * q, np.zeros(16)], axis=-1)


def lofar_hba_core(pattern: str = "CS*HBA*") -> Layout:
    """The LOFAR HBA core: each core station as two fields HBA0, HBA1 (48 antennas).

    ``pattern`` is a shell-style pattern on the field names (e.g. ``"CS00[1-3]HBA*"``),
    or a comma-separated list of patterns.
    """
    import lofarantpos.db

    db = lofarantpos.db.LofarAntennaDatabase()
    all_names = [f"{st}HBA{i}" for st in LOFAR_CORE_STATIONS for i in (0, 1)]
    patterns = [p.strip() for p in pattern.split(",") if p.strip()]
    names = [n for n in all_names if any(fnmatch.fnmatchcase(n, p.upper()) for p in patterns)]
    if not names:
        raise InputError(f"no LOFAR HBA core field matches stations {pattern!r} "
                         f"(fields are CS001HBA0 ... CS501HBA1)", param="stations")
    fields = []
    for name in names:
        centre = np.asarray(db.phase_centres[name], dtype=float)
        pqr_to_etrs = np.asarray(db.pqr_to_etrs[name], dtype=float)
        tiles_etrs = np.asarray(db.antenna_etrs(name), dtype=float)
        tile_pqr = hba_tile_pqr(float(db.hba_rotations[name]))
        fields.append(FieldLayout(
            name=name, position=centre, axes=pqr_to_etrs.T.copy(),
            element_offsets=tiles_etrs - centre[None, :],
            tile_offsets=tile_pqr @ pqr_to_etrs.T,
            tile_rotation=float(db.hba_rotations[name])))
    return Layout(names=names, positions=np.array([f.position for f in fields]),
                  diameters=np.full(len(names), HBA_FIELD_DIAMETER), telescope="LOFAR",
                  fields=fields)


def enu_to_itrf(enu: np.ndarray, reference_itrf: np.ndarray) -> np.ndarray:
    """ITRF positions (n, 3) m of local East-North-Up offsets (n, 3) m about a reference."""
    from astropy.coordinates import EarthLocation
    import astropy.units as u

    loc = EarthLocation.from_geocentric(*reference_itrf, unit=u.m)
    lon, lat = loc.lon.to_value(u.rad), loc.lat.to_value(u.rad)
    east = np.array([-np.sin(lon), np.cos(lon), 0.0])
    north = np.array([-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)])
    up = np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    enu = np.atleast_2d(np.asarray(enu, dtype=float))
    return reference_itrf[None, :] + enu[:, :1] * east + enu[:, 1:2] * north + enu[:, 2:3] * up


def read_layout_file(path: str | Path, pattern: str | None = None) -> Layout:
    """Read a layout text file (format in the module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such layout file")
    settings = {"frame": "itrf", "reference": None, "diameter": "30.75", "telescope": "CUSTOM"}
    names, xyz, diam = [], [], []
    for lineno, raw in enumerate(path.read_text().splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        if "=" in line:
            key, value = (s.strip() for s in line.split("=", 1))
            if key.lower() not in settings:
                raise InputError(f"{path}:{lineno}: unknown setting {key!r} "
                                 f"(known: {', '.join(settings)})")
            settings[key.lower()] = value
            continue
        parts = line.split()
        if len(parts) not in (4, 5):
            raise InputError(f"{path}:{lineno}: expected 'NAME X Y Z [DIAMETER]', got {raw.strip()!r}")
        try:
            values = [float(p) for p in parts[1:]]
        except ValueError:
            raise InputError(f"{path}:{lineno}: coordinates must be numbers: {raw.strip()!r}") from None
        names.append(parts[0])
        xyz.append(values[:3])
        diam.append(values[3] if len(values) == 4 else None)
    if len(names) < 2:
        raise InputError(f"{path}: a layout needs at least two stations, found {len(names)}")
    if len(set(names)) != len(names):
        raise InputError(f"{path}: station names must be unique")
    try:
        default_diameter = float(settings["diameter"])
    except ValueError:
        raise InputError(f"{path}: diameter must be a number") from None
    xyz = np.array(xyz, dtype=float)
    frame = settings["frame"].lower()
    if frame == "enu":
        if settings["reference"]:
            try:
                ref = np.array([float(v) for v in settings["reference"].split(",")])
            except ValueError:
                raise InputError(f"{path}: reference must be X,Y,Z in metres") from None
            if ref.shape != (3,):
                raise InputError(f"{path}: reference must be X,Y,Z in metres")
        else:
            ref = lofar_reference_position()
        positions = enu_to_itrf(xyz, ref)
    elif frame == "itrf":
        if np.any(np.linalg.norm(xyz, axis=1) < 6.3e6):
            raise InputError(f"{path}: ITRF positions must be geocentric (|r| ~ 6.4e6 m); "
                             "use 'frame = enu' for local offsets")
        positions = xyz
    else:
        raise InputError(f"{path}: frame must be 'itrf' or 'enu', got {frame!r}")
    diameters = np.array([d if d is not None else default_diameter for d in diam])
    return Layout(names=names, positions=positions, diameters=diameters,
                  telescope=settings["telescope"]).select(pattern or None, str(path))
