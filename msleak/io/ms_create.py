"""Create a Measurement Set from scratch with python-casacore, and fill its main table.

The main table has fixed-shape DATA, FLAG and WEIGHT_SPECTRUM columns in tiled storage
managers (as DP3 writes them), UVW labelled J2000, and every subtable a reader expects.
For a LOFAR array (``lofar_fields`` given) the LOFAR subtables EveryBeam needs are written
too: LOFAR_ANTENNA_FIELD, LOFAR_ELEMENT_FAILURE, LOFAR_STATION,
ANTENNA::LOFAR_PHASE_REFERENCE, ANTENNA::LOFAR_STATION_ID and FIELD::LOFAR_TILE_BEAM_DIR.
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import Sequence

import numpy as np

from msleak import __version__

__all__ = ["create_ms_tables", "write_lofar_tables", "main_table", "put_main_rows"]

_TILE_ROWS = 256


def _pt():
    import casacore.tables as pt

    return pt


def _main_desc(nchan: int):
    pt = _pt()
    shape = [nchan, 4]
    cols = [
        pt.makearrcoldesc("DATA", 0j, shape=shape, valuetype="complex",
                          comment="The data column"),
        pt.makearrcoldesc("FLAG", False, shape=shape, valuetype="boolean",
                          comment="The data flags, array of bools with same shape as data"),
        pt.makearrcoldesc("WEIGHT_SPECTRUM", 1.0, shape=shape, valuetype="float",
                          comment="Weight for each data point"),
        pt.makearrcoldesc("WEIGHT", 1.0, shape=[4], valuetype="float",
                          comment="Weight for each polarization spectrum"),
        pt.makearrcoldesc("SIGMA", 1.0, shape=[4], valuetype="float",
                          comment="Estimated rms noise for channel with unity bandpass response"),
    ]
    dminfo = {
        "*1": {"TYPE": "TiledColumnStMan", "NAME": "TiledData",
               "SPEC": {"DEFAULTTILESHAPE": np.array([4, nchan, _TILE_ROWS], dtype=np.int32)},
               "COLUMNS": ["DATA"]},
        "*2": {"TYPE": "TiledColumnStMan", "NAME": "TiledFlag",
               "SPEC": {"DEFAULTTILESHAPE": np.array([4, nchan, 8 * _TILE_ROWS], dtype=np.int32)},
               "COLUMNS": ["FLAG"]},
        "*3": {"TYPE": "TiledColumnStMan", "NAME": "TiledWeightSpectrum",
               "SPEC": {"DEFAULTTILESHAPE": np.array([4, nchan, _TILE_ROWS], dtype=np.int32)},
               "COLUMNS": ["WEIGHT_SPECTRUM"]},
    }
    return pt.maketabdesc(cols), dminfo


def create_ms_tables(path: Path, *, names: Sequence[str], positions: np.ndarray,
                     diameters: np.ndarray, telescope: str, freq: np.ndarray,
                     chan_width: float, ra: float, dec: float, field_name: str,
                     time_range: tuple[float, float], nrows: int,
                     lofar_fields: Sequence | None = None) -> None:
    """Create the MS at ``path`` with ``nrows`` empty main-table rows and all subtables.

    Parameters
    ----------
    names, positions, diameters : the stations: names, ITRF positions (nstation, 3) m and
        dish diameters m
    telescope : TELESCOPE_NAME of the OBSERVATION table
    freq : (nchan,) channel centres, Hz
    chan_width : channel width, Hz
    ra, dec : J2000 phase centre, rad
    time_range : (start, end) of the observation, MJD seconds
    lofar_fields : the LOFAR antenna field of every station, records with ``name``,
        ``position``, ``axes``, ``element_offsets``, ``tile_offsets``, ``tile_rotation``
        (as :class:`msleak.telescope.layouts.FieldLayout`), or None for another array
    """
    pt = _pt()
    nchan = len(freq)
    desc, dminfo = _main_desc(nchan)
    ms = pt.default_ms(str(path), desc, dminfo)
    try:
        ms.putcolkeyword("UVW", "MEASINFO", {"type": "uvw", "Ref": "J2000"})
        ms.putcolkeyword("UVW", "QuantumUnits", np.array(["m", "m", "m"]))
        ms.addrows(nrows)
    finally:
        ms.close()
    lofar = lofar_fields is not None
    _write_antenna(path, names, positions, diameters, telescope, lofar)
    _write_feed(path, len(names), time_range)
    _write_spectral_window(path, freq, chan_width)
    _write_polarization(path)
    _write_data_description(path)
    _write_field(path, ra, dec, field_name, time_range[0], lofar=lofar)
    _write_observation(path, telescope, time_range)
    _write_processor_state(path)
    if lofar:
        write_lofar_tables(path, names, lofar_fields)


def _open(path: Path, name: str):
    return _pt().table(str(path / name), readonly=False, ack=False)


def _write_antenna(path: Path, names, positions, diameters, telescope: str,
                   lofar: bool) -> None:
    pt = _pt()
    n = len(names)
    with _open(path, "ANTENNA") as t:
        t.addrows(n)
        t.putcol("NAME", np.array(names))
        t.putcol("STATION", np.array(["LOFAR" if lofar else telescope] * n))
        t.putcol("TYPE", np.array(["GROUND-BASED"] * n))
        t.putcol("MOUNT", np.array(["X-Y"] * n))
        t.putcol("POSITION", positions)
        t.putcol("OFFSET", np.zeros((n, 3)))
        t.putcol("DISH_DIAMETER", np.asarray(diameters, dtype=float))
        t.putcol("FLAG_ROW", np.zeros(n, dtype=bool))
        if lofar:
            t.addcols(pt.maketabdesc([
                pt.makescacoldesc("LOFAR_STATION_ID", 0, valuetype="int"),
                pt.makearrcoldesc("LOFAR_PHASE_REFERENCE", 0.0, shape=[3], valuetype="double",
                                  keywords={"QuantumUnits": np.array(["m", "m", "m"]),
                                            "MEASINFO": {"type": "position", "Ref": "ITRF"}}),
            ]))
            stations = sorted({name[:5] for name in names})
            t.putcol("LOFAR_STATION_ID", np.array([stations.index(nm[:5]) for nm in names],
                                                  dtype=np.int32))
            t.putcol("LOFAR_PHASE_REFERENCE", positions)


def _write_feed(path: Path, nant: int, time_range) -> None:
    with _open(path, "FEED") as t:
        t.addrows(nant)
        t.putcol("ANTENNA_ID", np.arange(nant, dtype=np.int32))
        t.putcol("FEED_ID", np.zeros(nant, dtype=np.int32))
        t.putcol("SPECTRAL_WINDOW_ID", np.full(nant, -1, dtype=np.int32))
        t.putcol("TIME", np.full(nant, 0.5 * (time_range[0] + time_range[1])))
        t.putcol("INTERVAL", np.full(nant, time_range[1] - time_range[0]))
        t.putcol("NUM_RECEPTORS", np.full(nant, 2, dtype=np.int32))
        t.putcol("BEAM_ID", np.full(nant, -1, dtype=np.int32))
        t.putcol("BEAM_OFFSET", np.zeros((nant, 2, 2)))
        t.putcol("POLARIZATION_TYPE", np.array([["X", "Y"]] * nant))
        t.putcol("POL_RESPONSE", np.tile(np.eye(2, dtype=complex), (nant, 1, 1)))
        t.putcol("POSITION", np.zeros((nant, 3)))
        t.putcol("RECEPTOR_ANGLE", np.tile([0.0, np.pi / 2], (nant, 1)))


def _write_spectral_window(path: Path, freq: np.ndarray, chan_width: float) -> None:
    nchan = len(freq)
    width = np.full(nchan, float(chan_width))
    with _open(path, "SPECTRAL_WINDOW") as t:
        t.addrows(1)
        t.putcell("NUM_CHAN", 0, nchan)
        t.putcell("NAME", 0, "SB-0")
        t.putcell("REF_FREQUENCY", 0, float(np.mean(freq)))
        t.putcell("CHAN_FREQ", 0, np.asarray(freq, dtype=float))
        t.putcell("CHAN_WIDTH", 0, width)
        t.putcell("EFFECTIVE_BW", 0, width)
        t.putcell("RESOLUTION", 0, width)
        t.putcell("MEAS_FREQ_REF", 0, 5)  # TOPO
        t.putcell("TOTAL_BANDWIDTH", 0, float(nchan * chan_width))
        t.putcell("NET_SIDEBAND", 0, 1)
        t.putcell("IF_CONV_CHAIN", 0, 0)
        t.putcell("FREQ_GROUP", 0, 0)
        t.putcell("FREQ_GROUP_NAME", 0, "")
        t.putcell("FLAG_ROW", 0, False)


def _write_polarization(path: Path) -> None:
    with _open(path, "POLARIZATION") as t:
        t.addrows(1)
        t.putcell("NUM_CORR", 0, 4)
        t.putcell("CORR_TYPE", 0, np.array([9, 10, 11, 12], dtype=np.int32))
        t.putcell("CORR_PRODUCT", 0, np.array([[0, 0], [0, 1], [1, 0], [1, 1]], dtype=np.int32))
        t.putcell("FLAG_ROW", 0, False)


def _write_data_description(path: Path) -> None:
    with _open(path, "DATA_DESCRIPTION") as t:
        t.addrows(1)
        t.putcell("SPECTRAL_WINDOW_ID", 0, 0)
        t.putcell("POLARIZATION_ID", 0, 0)
        t.putcell("FLAG_ROW", 0, False)


def _write_field(path: Path, ra: float, dec: float, name: str, t0: float, lofar: bool) -> None:
    pt = _pt()
    direction = np.array([[ra, dec]])
    with _open(path, "FIELD") as t:
        t.addrows(1)
        t.putcell("NAME", 0, name)
        t.putcell("CODE", 0, "")
        t.putcell("TIME", 0, t0)
        t.putcell("NUM_POLY", 0, 0)
        for col in ("DELAY_DIR", "PHASE_DIR", "REFERENCE_DIR"):
            t.putcell(col, 0, direction)
        t.putcell("SOURCE_ID", 0, -1)
        t.putcell("FLAG_ROW", 0, False)
        if lofar:
            t.addcols(pt.maketabdesc([pt.makearrcoldesc(
                "LOFAR_TILE_BEAM_DIR", 0.0, ndim=2, valuetype="double",
                keywords={"QuantumUnits": np.array(["rad", "rad"]),
                          "MEASINFO": {"type": "direction", "Ref": "J2000"}})]))
            t.putcell("LOFAR_TILE_BEAM_DIR", 0, direction)


def _write_observation(path: Path, telescope: str, time_range) -> None:
    pt = _pt()

    with _open(path, "OBSERVATION") as t:
        t.addrows(1)
        t.putcell("TELESCOPE_NAME", 0, telescope)
        t.putcell("TIME_RANGE", 0, np.array(time_range, dtype=float))
        t.putcell("OBSERVER", 0, "msleak")
        t.putcell("PROJECT", 0, f"msleak {__version__} simulation")
        t.putcell("RELEASE_DATE", 0, float(time_range[1]))
        t.putcell("SCHEDULE_TYPE", 0, "")
        t.putcell("LOG", 0, np.array([f"created by msleak {__version__} simulate"]))
        t.putcell("SCHEDULE", 0, np.array([""]))
        t.putcell("FLAG_ROW", 0, False)
        if telescope == "LOFAR":
            t.addcols(pt.maketabdesc([pt.makescacoldesc("LOFAR_ANTENNA_SET", "")]))
            t.putcell("LOFAR_ANTENNA_SET", 0, "HBA_DUAL")


def _write_processor_state(path: Path) -> None:
    with _open(path, "PROCESSOR") as t:
        t.addrows(1)
        t.putcell("TYPE", 0, "CORRELATOR")
        t.putcell("SUB_TYPE", 0, "msleak")
        t.putcell("TYPE_ID", 0, -1)
        t.putcell("MODE_ID", 0, -1)
        t.putcell("FLAG_ROW", 0, False)


def write_lofar_tables(path: Path, names: Sequence[str], fields: Sequence) -> None:
    """Write LOFAR_ANTENNA_FIELD, LOFAR_ELEMENT_FAILURE and LOFAR_STATION for the LOFAR
    stations ``names`` and their antenna ``fields`` (as in :func:`create_ms_tables`)."""
    pt = _pt()
    metre3 = {"QuantumUnits": np.array(["m", "m", "m"])}
    field_desc = pt.maketabdesc([
        pt.makescacoldesc("ANTENNA_ID", 0, valuetype="int"),
        pt.makescacoldesc("NAME", ""),
        pt.makearrcoldesc("POSITION", 0.0, shape=[3], valuetype="double",
                          keywords={**metre3, "MEASINFO": {"type": "position", "Ref": "ITRF"}}),
        pt.makearrcoldesc("COORDINATE_AXES", 0.0, shape=[3, 3], valuetype="double",
                          keywords=metre3),
        pt.makescacoldesc("TILE_ROTATION", 0.0, valuetype="double",
                          keywords={"QuantumUnits": np.array(["rad"])}),
        pt.makearrcoldesc("TILE_ELEMENT_OFFSET", 0.0, shape=[16, 3], valuetype="double",
                          keywords=metre3),
        pt.makearrcoldesc("ELEMENT_OFFSET", 0.0, ndim=2, valuetype="double", keywords=metre3),
        pt.makearrcoldesc("ELEMENT_RCU", 0, ndim=2, valuetype="int"),
        pt.makearrcoldesc("ELEMENT_FLAG", False, ndim=2, valuetype="boolean"),
    ])
    with pt.table(str(path / "LOFAR_ANTENNA_FIELD"), field_desc, nrow=len(fields),
                  ack=False) as t:
        for row, f in enumerate(fields):
            ntile = len(f.element_offsets)
            t.putcell("ANTENNA_ID", row, row)
            t.putcell("NAME", row, f.name[5:])  # HBA0 / HBA1
            t.putcell("POSITION", row, f.position)
            t.putcell("COORDINATE_AXES", row, f.axes)
            t.putcell("TILE_ROTATION", row, f.tile_rotation)
            t.putcell("TILE_ELEMENT_OFFSET", row, f.tile_offsets)
            t.putcell("ELEMENT_OFFSET", row, f.element_offsets)
            rcu = np.arange(2 * ntile, dtype=np.int32).reshape(ntile, 2)
            t.putcell("ELEMENT_RCU", row, rcu)
            t.putcell("ELEMENT_FLAG", row, np.zeros((ntile, 2), dtype=bool))
    failure_desc = pt.maketabdesc([
        pt.makescacoldesc("ANTENNA_FIELD_ID", 0, valuetype="int"),
        pt.makescacoldesc("ELEMENT_INDEX", 0, valuetype="int"),
        pt.makescacoldesc("TIME", 0.0, valuetype="double",
                          keywords={"QuantumUnits": np.array(["s"]),
                                    "MEASINFO": {"type": "epoch", "Ref": "UTC"}}),
    ])
    pt.table(str(path / "LOFAR_ELEMENT_FAILURE"), failure_desc, nrow=0, ack=False).close()
    stations = sorted({name[:5] for name in names})
    station_desc = pt.maketabdesc([
        pt.makescacoldesc("NAME", ""),
        pt.makescacoldesc("CLOCK_ID", 0, valuetype="int"),
        pt.makescacoldesc("FLAG_ROW", False),
    ])
    with pt.table(str(path / "LOFAR_STATION"), station_desc, nrow=len(stations), ack=False) as t:
        t.putcol("NAME", np.array(stations))
        t.putcol("CLOCK_ID", np.zeros(len(stations), dtype=np.int32))
        t.putcol("FLAG_ROW", np.zeros(len(stations), dtype=bool))
    with pt.table(str(path), readonly=False, ack=False) as ms:
        for name in ("LOFAR_ANTENNA_FIELD", "LOFAR_ELEMENT_FAILURE", "LOFAR_STATION"):
            ms.putkeyword(name, f"Table: {Path(path).resolve() / name}")


@contextmanager
def main_table(path: Path):
    """The main table of the MS at ``path``, open for writing (:func:`put_main_rows`)."""
    with _pt().table(str(path), readonly=False, ack=False) as ms:
        yield ms


def put_main_rows(ms, row0: int, times: np.ndarray, interval: float, a1: np.ndarray,
                  a2: np.ndarray, uvw: np.ndarray, nchan: int) -> None:
    """Fill the rows from ``row0`` on of every time in ``times`` (MJD s) and baseline
    (``a1``, ``a2``): their ``uvw`` (ntime x nbaseline, 3) m, zero DATA, FLAG false,
    unit weights."""
    nbl = len(a1)
    n = len(times) * nbl
    ms.putcol("TIME", np.repeat(times, nbl), startrow=row0, nrow=n)
    ms.putcol("TIME_CENTROID", np.repeat(times, nbl), startrow=row0, nrow=n)
    ms.putcol("INTERVAL", np.full(n, interval), startrow=row0, nrow=n)
    ms.putcol("EXPOSURE", np.full(n, interval), startrow=row0, nrow=n)
    ms.putcol("ANTENNA1", np.tile(a1, len(times)).astype(np.int32), startrow=row0, nrow=n)
    ms.putcol("ANTENNA2", np.tile(a2, len(times)).astype(np.int32), startrow=row0, nrow=n)
    ms.putcol("UVW", uvw, startrow=row0, nrow=n)
    ms.putcol("SCAN_NUMBER", np.ones(n, dtype=np.int32), startrow=row0, nrow=n)
    ms.putcol("DATA", np.zeros((n, nchan, 4), dtype=np.complex64), startrow=row0, nrow=n)
    ms.putcol("FLAG", np.zeros((n, nchan, 4), dtype=bool), startrow=row0, nrow=n)
    ms.putcol("WEIGHT_SPECTRUM", np.ones((n, nchan, 4), dtype=np.float32), startrow=row0,
              nrow=n)
    ms.putcol("WEIGHT", np.ones((n, 4), dtype=np.float32), startrow=row0, nrow=n)
    ms.putcol("SIGMA", np.ones((n, 4), dtype=np.float32), startrow=row0, nrow=n)
