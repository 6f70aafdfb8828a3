"""The MWA_TILE_POINTING subtable: the dipole delays that steer every MWA tile.

cotter and Birli write it, and EveryBeam, WSClean and mwa_hyperdrive read it, through the
main-table keyword ``MWA_TILE_POINTING``; the readers use row 0 (docs/mwa.md):

``INTERVAL`` (2,) double, s (``MEASINFO`` epoch/UTC)
    Start and end (MJD seconds, UTC) of the pointing.
``DELAYS`` (16,) int
    Beam-former delays of the 16 dipoles in the M&C order, in steps of 435 ps; 32 marks a
    dead dipole.
``DIRECTION`` (2,) double, rad
    J2000 (ra, dec) the delays point at.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from msleak._everybeam import check_delays
from msleak.errors import InputError
from msleak.io.ms import _subtable, check_ms, open_table, read_beam_directions

__all__ = ["MWA_TILE_POINTING_TABLE", "write_mwa_tile_pointing", "read_mwa_delays"]

log = logging.getLogger(__name__)

#: Name of the subtable and of the MS keyword pointing to it.
MWA_TILE_POINTING_TABLE = "MWA_TILE_POINTING"
_REWRITE = ("write it again with msleak.io.mwa.write_mwa_tile_pointing, or use "
            "beam='dipole'")


def _table_description(pt):
    return pt.maketabdesc([
        pt.makearrcoldesc("INTERVAL", 0.0, ndim=1, valuetype="double",
                          keywords={"QuantumUnits": np.array(["s"]),
                                    "MEASINFO": {"type": "epoch", "Ref": "UTC"}}),
        pt.makearrcoldesc("DELAYS", 0, ndim=1, valuetype="int"),
        pt.makearrcoldesc("DIRECTION", 0.0, ndim=1, valuetype="double"),
    ])


def write_mwa_tile_pointing(ms: str | os.PathLike, time_range, delays=(0,) * 16,
                            direction=None) -> Path:
    """Add (or replace) the MWA_TILE_POINTING subtable (one row) and its MS keyword.

    Parameters
    ----------
    ms : path
        Measurement Set.
    time_range : (start, end)
        MJD seconds (UTC) the pointing covers.
    delays : 16 ints
        Dipole delays in the M&C order, 0..32 (default: zenith).
    direction : (ra, dec), optional
        J2000 pointing, rad; FIELD 0's DELAY_DIR (else PHASE_DIR) by default.

    Returns
    -------
    Path of the subtable.
    """
    import casacore.tables as pt

    ms = check_ms(ms)
    delays = check_delays(delays)
    start, end = (float(v) for v in np.asarray(time_range, dtype=float).reshape(2))
    if not (np.isfinite(start) and np.isfinite(end) and start <= end):
        raise InputError(f"MWA_TILE_POINTING: time range must be finite with start <= end, "
                         f"got {start}, {end}")
    if direction is None:
        direction = read_beam_directions(ms, 0).delay
    direction = np.asarray(direction, dtype=float).reshape(2)
    path = ms / MWA_TILE_POINTING_TABLE
    with pt.table(str(path), _table_description(pt), nrow=1, ack=False) as t:
        t.putcell("INTERVAL", 0, np.array([start, end]))
        t.putcell("DELAYS", 0, delays.astype(np.int32))
        t.putcell("DIRECTION", 0, direction)
    with pt.table(str(ms), readonly=False, ack=False) as t:
        t.putkeyword(MWA_TILE_POINTING_TABLE, f"Table: {path.resolve()}")
    return path


def read_mwa_delays(ms: str | os.PathLike) -> np.ndarray:
    """The (16,) dipole delays of MWA_TILE_POINTING row 0; zeros (zenith) without the table.

    Raises
    ------
    InputError
        A table without rows or a DELAYS cell that is not 16 integers in 0..32.
    """
    ms = check_ms(ms)
    if not (ms / MWA_TILE_POINTING_TABLE / "table.dat").exists():
        log.info("%s: no %s table; the MWA tiles are taken to point at the zenith (all "
                 "dipole delays 0)", ms, MWA_TILE_POINTING_TABLE)
        return np.zeros(16, dtype=np.int64)
    with open_table(_subtable(ms, MWA_TILE_POINTING_TABLE)) as t:
        if "DELAYS" not in t.colnames() or t.nrows() == 0:
            raise InputError(f"{ms}: {MWA_TILE_POINTING_TABLE} has no DELAYS row; {_REWRITE}")
        if t.nrows() > 1:
            log.info("%s: %s has %d rows; using row 0, as EveryBeam does", ms,
                     MWA_TILE_POINTING_TABLE, t.nrows())
        delays = np.asarray(t.getcell("DELAYS", 0)).ravel()
    try:
        return check_delays(delays)
    except InputError as err:
        raise InputError(f"{ms}: {MWA_TILE_POINTING_TABLE}: {err}; {_REWRITE}") from None
