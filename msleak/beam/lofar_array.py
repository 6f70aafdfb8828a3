"""The LOFAR station description the fast beam uses, assembled from the MS's LOFAR tables.

The tables are read by :mod:`msleak.io.lofar` and :func:`msleak.io.ms.read_beam_directions`
(:func:`msleak.adapters.beams.read_lofar_array`); :func:`lofar_array` checks and groups
those arrays per station (docs/beam.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msleak.errors import BeamUnavailable

__all__ = ["LofarField", "LofarStation", "LofarArray", "lofar_array"]


@dataclass(frozen=True)
class LofarField:
    """One antenna field (row of LOFAR_ANTENNA_FIELD).

    Attributes
    ----------
    name : str
        ``HBA``, ``HBA0``, ``HBA1`` or ``LBA``.
    origin : (3,) array
        Field centre, ITRF m.
    axes : (3, 3) array
        Rows p, q, r (unit vectors in ITRF).
    tile_offsets : (ntile, 3) array
        Tile (HBA) or dipole (LBA) positions relative to ``origin``, ITRF m.
    tile_enabled : (ntile,) bool array
        Not flagged (EveryBeam uses the X flag for both polarizations).
    element_offsets : (16, 3) array or None
        HBA tile element positions relative to the tile centre, ITRF m.
    element_gains : (ntile, 16, 2) complex array or None
        Complex gain of every element of every tile per feed (X, Y) on its beam-former
        weight (errors of the model, :func:`msleak.beam.errors.perturb_lofar`); None: 1.
    """

    name: str
    origin: np.ndarray
    axes: np.ndarray
    tile_offsets: np.ndarray
    tile_enabled: np.ndarray
    element_offsets: np.ndarray | None
    element_gains: np.ndarray | None = None


@dataclass(frozen=True)
class LofarStation:
    """One ANTENNA row of a LOFAR MS with its antenna fields."""

    name: str
    phase_reference: np.ndarray
    fields: tuple


@dataclass(frozen=True)
class LofarArray:
    """Everything the LOFAR beam needs from one MS and field.

    ``delay_dir`` and ``tile_beam_dir`` are J2000 (ra, dec) in rad; ``phase_centre`` is
    FIELD::PHASE_DIR of the same row.
    """

    stations: tuple
    delay_dir: tuple
    tile_beam_dir: tuple
    phase_centre: tuple


def lofar_array(names, field_rows, phase_references, directions) -> LofarArray:
    """Group LOFAR_ANTENNA_FIELD rows per station.

    Parameters
    ----------
    names : list of str
        ANTENNA names (nant).
    field_rows : list of msleak.io.lofar.AntennaFieldRow
    phase_references : (nant, 3) array
        ANTENNA::LOFAR_PHASE_REFERENCE, ITRF m.
    directions : msleak.io.ms.BeamDirections

    Raises
    ------
    BeamUnavailable
        An HBA field without tile element offsets, or a station without fields.
    """
    fields: list[list[LofarField]] = [[] for _ in names]
    for row in field_rows:
        if row.name != "LBA" and row.tile_element_offsets is None:
            raise BeamUnavailable("LOFAR_ANTENNA_FIELD has no TILE_ELEMENT_OFFSET column "
                                  "for HBA fields")
        fields[row.antenna_id].append(LofarField(
            name=row.name, origin=row.position, axes=row.axes,
            tile_offsets=row.element_offsets, tile_enabled=~row.element_flags[:, 0],
            element_offsets=None if row.name == "LBA" else row.tile_element_offsets))
    missing = [names[i] for i, f in enumerate(fields) if not f]
    if missing:
        raise BeamUnavailable(f"stations {', '.join(missing[:5])} have no "
                              "LOFAR_ANTENNA_FIELD rows")
    stations = tuple(LofarStation(name=n, phase_reference=np.asarray(phase_references[i]),
                                  fields=tuple(fields[i])) for i, n in enumerate(names))
    return LofarArray(stations=stations, delay_dir=directions.delay,
                      tile_beam_dir=directions.tile, phase_centre=directions.phase)
