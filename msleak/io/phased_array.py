"""The PHASED_ARRAY subtable: the station layout of an SKA-Low (OSKAR-type) Measurement Set.

EveryBeam describes an MS whose OBSERVATION::TELESCOPE_NAME is ``SKA-LOW`` as an OSKAR
telescope and reads each station's aperture-array layout from the subtable the MS keyword
``PHASED_ARRAY`` points to (docs/ska_low.md), one row per ANTENNA row:

``ANTENNA_ID`` (int)
    The ANTENNA row.
``POSITION`` (3,) double, m, ITRF
    Station centre: the origin of the element offsets and the beam-former phase reference.
``COORDINATE_AXES`` (3, 3) double
    Rows (as python-casacore reads them) are the station's East, North and Up unit vectors
    in ITRF; EveryBeam projects element offsets and directions on them.
``ELEMENT_OFFSET`` (nelem, 3) double, m, ITRF
    Element positions relative to POSITION.  On disk the casacore cell is a
    ``(nelem, 3)`` matrix, which python-casacore presents as a numpy ``(3, nelem)`` array;
    this module transposes, so callers always see ``(nelem, 3)``.
``ELEMENT_FLAG`` (nelem, 2) bool
    True = element (X, Y feed) switched off.  Stored like ELEMENT_OFFSET (numpy
    ``(2, nelem)`` cells).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msleak.errors import InputError
from msleak.io.ms import _subtable, check_ms, open_table

__all__ = ["PhasedArray", "write_phased_array", "read_phased_array", "has_phased_array",
           "PHASED_ARRAY_TABLE"]

#: Name of the subtable and of the MS keyword pointing to it.
PHASED_ARRAY_TABLE = "PHASED_ARRAY"


@dataclass(frozen=True)
class PhasedArray:
    """The contents of PHASED_ARRAY (nstation rows).

    Attributes
    ----------
    positions : (nstation, 3) float array
        Station centres, ITRF m.
    axes : (nstation, 3, 3) float array
        Per station the East, North, Up unit vectors (rows), ITRF.
    element_offsets : list of (nelem, 3) float arrays
        Element positions relative to the station centre, ITRF m.
    element_flags : list of (nelem, 2) bool arrays
        True where an element's X or Y feed is flagged.
    """

    positions: np.ndarray
    axes: np.ndarray
    element_offsets: list
    element_flags: list

    def __len__(self) -> int:
        return len(self.positions)


def _check_inputs(positions, axes, offsets, flags):
    positions = np.asarray(positions, dtype=float)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise InputError("PHASED_ARRAY: station positions must be an (nstation, 3) array (m)")
    n = len(positions)
    axes = np.asarray(axes, dtype=float)
    if axes.shape == (3, 3):
        axes = np.broadcast_to(axes, (n, 3, 3))
    if axes.shape != (n, 3, 3):
        raise InputError("PHASED_ARRAY: axes must be (3, 3) or (nstation, 3, 3)")
    if not np.allclose(axes @ axes.transpose(0, 2, 1), np.eye(3), atol=1e-9):
        raise InputError("PHASED_ARRAY: each station's axes must be orthonormal rows")
    if isinstance(offsets, np.ndarray) and offsets.ndim == 2:
        offsets = [offsets] * n
    offsets = [np.asarray(o, dtype=float) for o in offsets]
    if len(offsets) != n or any(o.ndim != 2 or o.shape[1] != 3 or len(o) == 0
                                for o in offsets):
        raise InputError("PHASED_ARRAY: element offsets must be one (nelem, 3) array per "
                         "station (or one for all)")
    if flags is None:
        flags = [np.zeros((len(o), 2), dtype=bool) for o in offsets]
    elif isinstance(flags, np.ndarray) and flags.ndim == 2:
        flags = [flags] * n
    flags = [np.asarray(f, dtype=bool) for f in flags]
    if len(flags) != n or any(f.shape != (len(o), 2) for f, o in zip(flags, offsets)):
        raise InputError("PHASED_ARRAY: element flags must be one (nelem, 2) bool array per "
                         "station, matching the element offsets")
    if not all(np.all(np.isfinite(a)) for a in [positions, axes, *offsets]):
        raise InputError("PHASED_ARRAY: positions, axes and offsets must be finite")
    return positions, np.array(axes), offsets, flags


def _table_description(pt):
    metre = {"QuantumUnits": np.array(["m"])}
    return pt.maketabdesc([
        pt.makescacoldesc("ANTENNA_ID", 0, valuetype="int"),
        pt.makearrcoldesc("POSITION", 0.0, shape=[3], valuetype="double",
                          keywords={"QuantumUnits": np.array(["m", "m", "m"]),
                                    "MEASINFO": {"type": "position", "Ref": "ITRF"}}),
        pt.makearrcoldesc("COORDINATE_AXES", 0.0, shape=[3, 3], valuetype="double",
                          keywords=metre),
        pt.makearrcoldesc("ELEMENT_OFFSET", 0.0, ndim=2, valuetype="double", keywords=metre),
        pt.makearrcoldesc("ELEMENT_FLAG", False, ndim=2, valuetype="boolean"),
    ])


def write_phased_array(ms: str | os.PathLike, positions_itrf, axes, element_offsets,
                       element_flags=None) -> Path:
    """Add (or replace) the PHASED_ARRAY subtable and its MS keyword.

    Parameters
    ----------
    ms : path
        Measurement Set; it must have one ANTENNA row per station given.
    positions_itrf : (nstation, 3) array
        Station centres, ITRF m (normally the ANTENNA positions).
    axes : (3, 3) or (nstation, 3, 3) array
        East, North, Up unit vectors (rows) in ITRF, per station or shared.
    element_offsets : (nelem, 3) array or list of them
        Element positions relative to the centre, ITRF m (shared or per station).
    element_flags : (nelem, 2) bool array or list of them, optional
        True = flagged (default none).

    Returns
    -------
    Path of the subtable.
    """
    import casacore.tables as pt

    ms = check_ms(ms)
    positions, axes, offsets, flags = _check_inputs(positions_itrf, axes, element_offsets,
                                                    element_flags)
    with open_table(ms / "ANTENNA") as t:
        nant = t.nrows()
    if nant != len(positions):
        raise InputError(f"{ms}: PHASED_ARRAY needs one row per ANTENNA row ({nant}), "
                         f"got {len(positions)} stations")
    path = ms / PHASED_ARRAY_TABLE
    with pt.table(str(path), _table_description(pt), nrow=len(positions), ack=False) as t:
        t.putcol("ANTENNA_ID", np.arange(len(positions), dtype=np.int32))
        t.putcol("POSITION", positions)
        t.putcol("COORDINATE_AXES", axes)
        for row, (o, f) in enumerate(zip(offsets, flags)):
            t.putcell("ELEMENT_OFFSET", row, np.ascontiguousarray(o.T))
            t.putcell("ELEMENT_FLAG", row, np.ascontiguousarray(f.T))
    with pt.table(str(ms), readonly=False, ack=False) as t:
        t.putkeyword(PHASED_ARRAY_TABLE, f"Table: {path.resolve()}")
    return path


def has_phased_array(ms: str | os.PathLike) -> bool:
    """True if the MS has a PHASED_ARRAY subtable and the main-table keyword to it."""
    ms = check_ms(ms)
    if not (ms / PHASED_ARRAY_TABLE / "table.dat").exists():
        return False
    with open_table(ms) as t:
        return PHASED_ARRAY_TABLE in t.getkeywords()


def read_phased_array(ms: str | os.PathLike) -> PhasedArray:
    """The PHASED_ARRAY subtable as arrays (see :class:`PhasedArray`).

    Raises
    ------
    InputError
        No PHASED_ARRAY subtable or keyword, a missing column, or a row count different
        from the ANTENNA table's.
    """
    ms = check_ms(ms)
    if not has_phased_array(ms):
        raise InputError(f"{ms}: no PHASED_ARRAY subtable (the SKA-Low station layout); "
                         "write one with msleak.io.phased_array.write_phased_array")
    with open_table(ms / "ANTENNA") as t:
        nant = t.nrows()
    with open_table(_subtable(ms, PHASED_ARRAY_TABLE)) as t:
        missing = {"POSITION", "COORDINATE_AXES", "ELEMENT_OFFSET", "ELEMENT_FLAG"} - set(
            t.colnames())
        if missing:
            raise InputError(f"{ms}: PHASED_ARRAY lacks column(s) {', '.join(sorted(missing))}")
        if t.nrows() != nant:
            raise InputError(f"{ms}: PHASED_ARRAY has {t.nrows()} rows, ANTENNA has {nant}")
        positions = np.asarray(t.getcol("POSITION"), dtype=float).reshape(-1, 3)
        axes = np.asarray(t.getcol("COORDINATE_AXES"), dtype=float).reshape(-1, 3, 3)
        offsets = [np.asarray(t.getcell("ELEMENT_OFFSET", r), dtype=float).T.copy()
                   for r in range(nant)]
        flags = [np.asarray(t.getcell("ELEMENT_FLAG", r), dtype=bool).T.copy()
                 for r in range(nant)]
    for r, (o, f) in enumerate(zip(offsets, flags)):
        if o.ndim != 2 or o.shape[1] != 3 or f.shape != (len(o), 2):
            raise InputError(f"{ms}: PHASED_ARRAY row {r}: ELEMENT_OFFSET/ELEMENT_FLAG cells "
                             "are not (nelem, 3) / (nelem, 2) casacore matrices")
    return PhasedArray(positions=positions, axes=axes, element_offsets=offsets,
                       element_flags=flags)
