"""Readers of the LOFAR subtables of a Measurement Set (the station layout EveryBeam uses).

One reader per table, returning arrays, not open tables (docs/beam.md, "The LOFAR fast
evaluator"). Array layouts follow python-casacore: a casacore ``(3, n)`` matrix is a numpy
``(n, 3)`` array, so ``COORDINATE_AXES`` rows are a field's p, q and r axes in ITRF.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from msleak.errors import InputError
from msleak.io.ms import _subtable, check_ms, open_table

__all__ = ["AntennaFieldRow", "read_lofar_antenna_fields", "read_lofar_phase_references"]


@dataclass(frozen=True)
class AntennaFieldRow:
    """One row of LOFAR_ANTENNA_FIELD.

    Attributes
    ----------
    antenna_id : int
        ANTENNA row of the station.
    name : str
        ``HBA``, ``HBA0``, ``HBA1`` or ``LBA``.
    position : (3,) array
        Field centre, ITRF m.
    axes : (3, 3) array
        Rows p, q, r (unit vectors in ITRF).
    element_offsets : (ntile, 3) array
        Tile (HBA) or dipole (LBA) positions relative to ``position``, ITRF m.
    element_flags : (ntile, 2) bool array
        ELEMENT_FLAG per element and polarization.
    tile_element_offsets : (16, 3) array or None
        HBA tile element positions relative to the tile centre, ITRF m; None when the
        table has no TILE_ELEMENT_OFFSET column.
    """

    antenna_id: int
    name: str
    position: np.ndarray
    axes: np.ndarray
    element_offsets: np.ndarray
    element_flags: np.ndarray
    tile_element_offsets: np.ndarray | None


def _cell(table, column: str, row: int) -> np.ndarray:
    return np.asarray(table.getcell(column, row), dtype=float)


def read_lofar_antenna_fields(ms: str | os.PathLike) -> list[AntennaFieldRow]:
    """Every row of LOFAR_ANTENNA_FIELD.

    Raises
    ------
    InputError
        No such subtable, or a row refers to an antenna the ANTENNA table lacks.
    """
    ms = check_ms(ms)
    with open_table(_subtable(ms, "ANTENNA")) as t:
        nant = t.nrows()
    rows = []
    with open_table(_subtable(ms, "LOFAR_ANTENNA_FIELD")) as t:
        has_tile = "TILE_ELEMENT_OFFSET" in t.colnames()
        for row in range(t.nrows()):
            station = int(t.getcell("ANTENNA_ID", row))
            if not 0 <= station < nant:
                raise InputError(f"{ms}: LOFAR_ANTENNA_FIELD row {row} refers to antenna "
                                 f"{station}, the ANTENNA table has {nant} rows")
            offsets = _cell(t, "ELEMENT_OFFSET", row).reshape(-1, 3)
            rows.append(AntennaFieldRow(
                antenna_id=station,
                name=str(t.getcell("NAME", row)),
                position=_cell(t, "POSITION", row).reshape(3),
                axes=_cell(t, "COORDINATE_AXES", row).reshape(3, 3),
                element_offsets=offsets,
                element_flags=np.asarray(t.getcell("ELEMENT_FLAG", row),
                                         dtype=bool).reshape(len(offsets), -1),
                tile_element_offsets=(_cell(t, "TILE_ELEMENT_OFFSET", row).reshape(-1, 3)
                                      if has_tile else None),
            ))
    return rows


def read_lofar_phase_references(ms: str | os.PathLike) -> np.ndarray:
    """ANTENNA::LOFAR_PHASE_REFERENCE (nant, 3), ITRF m; zeros when the column is absent
    (what EveryBeam uses then)."""
    with open_table(_subtable(check_ms(ms), "ANTENNA")) as t:
        if "LOFAR_PHASE_REFERENCE" not in t.colnames():
            return np.zeros((t.nrows(), 3))
        return np.asarray(t.getcol("LOFAR_PHASE_REFERENCE"), dtype=float).reshape(-1, 3)
