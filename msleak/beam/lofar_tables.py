"""Read the LOFAR station description EveryBeam uses from a Measurement Set.

One reader for the LOFAR subtables (LOFAR_ANTENNA_FIELD, ANTENNA::LOFAR_PHASE_REFERENCE,
FIELD::DELAY_DIR and FIELD::LOFAR_TILE_BEAM_DIR), returning plain arrays in frozen
dataclasses.  Array layouts follow python-casacore (a casacore ``(3, n)`` matrix is a numpy
``(n, 3)`` array), so ``COORDINATE_AXES`` rows are the field's p, q and r axes in ITRF.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msleak.beam.base import BeamUnavailable
from msleak.errors import InputError

__all__ = ["LofarField", "LofarStation", "LofarArray", "read_lofar_array"]


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
    """

    name: str
    origin: np.ndarray
    axes: np.ndarray
    tile_offsets: np.ndarray
    tile_enabled: np.ndarray
    element_offsets: np.ndarray | None


@dataclass(frozen=True)
class LofarStation:
    """One ANTENNA row of a LOFAR MS with its antenna fields."""

    name: str
    phase_reference: np.ndarray
    fields: tuple


@dataclass(frozen=True)
class LofarArray:
    """Everything the LOFAR beam needs from one MS.

    ``delay_dir`` and ``tile_beam_dir`` are J2000 (ra, dec) in rad (FIELD row 0);
    ``phase_centre`` is FIELD::PHASE_DIR of the same row.
    """

    stations: tuple
    delay_dir: tuple
    tile_beam_dir: tuple
    phase_centre: tuple


def _cell(table, column: str, row: int) -> np.ndarray:
    return np.asarray(table.getcell(column, row), dtype=float)


def read_lofar_array(ms: str | os.PathLike) -> LofarArray:
    """Read the LOFAR station layout of ``ms``.

    Raises
    ------
    BeamUnavailable
        If the MS lacks a LOFAR table or column EveryBeam needs, or has several fields.
    InputError
        If LOFAR_ANTENNA_FIELD refers to a missing antenna.
    """
    from msleak.io.ms import check_ms, open_table

    ms = check_ms(ms)
    field_table = Path(ms) / "LOFAR_ANTENNA_FIELD"
    if not (field_table / "table.dat").exists():
        raise BeamUnavailable(f"{ms}: no LOFAR_ANTENNA_FIELD table, so no LOFAR beam")
    with open_table(Path(ms) / "FIELD") as t:
        if "LOFAR_TILE_BEAM_DIR" not in t.colnames():
            raise BeamUnavailable(f"{ms}: FIELD has no LOFAR_TILE_BEAM_DIR column, so no "
                                  "LOFAR beam")
        if t.nrows() != 1:
            raise BeamUnavailable(f"{ms}: the LOFAR beam needs an MS with one field, this one "
                                  f"has {t.nrows()}", remedy="split it per field (DP3) or use "
                                  "`--beam dipole` (analytic beam)")
        delay = _cell(t, "DELAY_DIR", 0).reshape(-1, 2)[0]
        tile = _cell(t, "LOFAR_TILE_BEAM_DIR", 0).reshape(-1, 2)[0]
        phase = _cell(t, "PHASE_DIR", 0).reshape(-1, 2)[0]
    with open_table(Path(ms) / "ANTENNA") as t:
        names = [str(n) for n in t.getcol("NAME")]
        if "LOFAR_PHASE_REFERENCE" in t.colnames():
            refs = np.asarray(t.getcol("LOFAR_PHASE_REFERENCE"), dtype=float).reshape(-1, 3)
        else:  # what EveryBeam does without the column
            refs = np.zeros((len(names), 3))
    fields: list[list[LofarField]] = [[] for _ in names]
    with open_table(field_table) as t:
        cols = set(t.colnames())
        for row in range(t.nrows()):
            station = int(t.getcell("ANTENNA_ID", row))
            if not 0 <= station < len(names):
                raise InputError(f"{ms}: LOFAR_ANTENNA_FIELD row {row} refers to antenna "
                                 f"{station}, the ANTENNA table has {len(names)} rows")
            name = str(t.getcell("NAME", row))
            offsets = _cell(t, "ELEMENT_OFFSET", row).reshape(-1, 3)
            flags = np.asarray(t.getcell("ELEMENT_FLAG", row), dtype=bool).reshape(len(offsets), -1)
            element_offsets = None
            if name != "LBA":
                if "TILE_ELEMENT_OFFSET" not in cols:
                    raise BeamUnavailable(f"{ms}: LOFAR_ANTENNA_FIELD has no "
                                          "TILE_ELEMENT_OFFSET column for HBA fields")
                element_offsets = _cell(t, "TILE_ELEMENT_OFFSET", row).reshape(-1, 3)
            fields[station].append(LofarField(
                name=name,
                origin=_cell(t, "POSITION", row).reshape(3),
                axes=_cell(t, "COORDINATE_AXES", row).reshape(3, 3),
                tile_offsets=offsets,
                tile_enabled=~flags[:, 0],
                element_offsets=element_offsets,
            ))
    missing = [names[i] for i, f in enumerate(fields) if not f]
    if missing:
        raise BeamUnavailable(f"{ms}: stations {', '.join(missing[:5])} have no "
                              "LOFAR_ANTENNA_FIELD rows")
    stations = tuple(LofarStation(name=n, phase_reference=refs[i], fields=tuple(fields[i]))
                     for i, n in enumerate(names))
    return LofarArray(stations=stations, delay_dir=(float(delay[0]), float(delay[1])),
                      tile_beam_dir=(float(tile[0]), float(tile[1])),
                      phase_centre=(float(phase[0]), float(phase[1])))
