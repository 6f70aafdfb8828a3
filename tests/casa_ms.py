"""Small Measurement Sets built the way CASA, cotter and pyuvdata write them, independently
of ``msleak simulate``.

The tables come from casacore's own MS definition (``default_ms`` and
``default_ms_subtable``, what CASA's simulator and pyuvdata's MS writer start from), filled
row by row here. UVW are antenna-based, computed here from the ITRF positions with the
textbook Greenwich-hour-angle rotation (no precession or aberration: a test MS needs a
self-consistent UVW, not an astrometric one), in the MS sign convention
UVW(row) = uvw(ANTENNA2) - uvw(ANTENNA1).

Options reproduce what real writers do and ``msleak simulate`` never does:
placeholder ANTENNA rows (never used, FLAG_ROW set, at the origin with DISH_DIAMETER 0),
float32-rounded UVW (an MS converted from uvfits), any CORR_TYPE order, circular feeds,
two correlations, and any TELESCOPE_NAME.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

C = 299_792_458.0
LINEAR = ("XX", "XY", "YX", "YY")
CIRCULAR = ("RR", "RL", "LR", "LL")
#: casacore Stokes enumeration of the correlation products
CORR_CODE = {"RR": 5, "RL": 6, "LR": 7, "LL": 8, "XX": 9, "XY": 10, "YX": 11, "YY": 12}
#: the MWA site (m, ITRF), a non-LOFAR array position for the default layout
MWA_ITRF = np.array([-2559454.08, 5095372.14, -2849057.18])


@dataclass
class MSSpec:
    """What to build. Angles in degrees, times in seconds, frequencies in Hz."""

    #: near the zenith of the MWA site at the default time (LST 253.5 deg, latitude -26.7)
    ra_deg: float = 253.5
    dec_deg: float = -27.0
    telescope: str = "MWA"
    site_itrf: np.ndarray = field(default_factory=lambda: MWA_ITRF.copy())
    #: ENU offsets (m) of the antennas used in the main table
    enu: np.ndarray = field(default_factory=lambda: np.array(
        [[0.0, 0.0, 0.0], [30.0, 5.0, 0.2], [-12.0, 41.0, -0.1], [55.0, -38.0, 0.3],
         [-47.0, -20.0, 0.0]]))
    dish_diameter: float = 4.4
    #: placeholder ANTENNA rows: "unused" (valid position, never in the main table),
    #: "flagged" (FLAG_ROW set), "origin" (POSITION (0,0,0), DISH_DIAMETER 0)
    placeholders: tuple[str, ...] = ()
    corr: tuple[str, ...] = LINEAR
    freq0_hz: float = 150e6
    nchan: int = 4
    chan_width_hz: float = 195312.5
    ntime: int = 3
    interval_s: float = 120.0
    #: MJD seconds of the first integration centre (2013-02-06 00:00 UTC by default)
    time0_s: float = 56329.0 * 86400.0
    uvw_float32: bool = False
    autocorrelations: bool = False
    extra_columns: tuple[str, ...] = ("DATA",)
    #: write the MWA_TILE_POINTING subtable (16 dipole delays, zenith), as cotter and Birli do
    mwa_tile_pointing: bool = False


def _gmst_rad(mjd_seconds: np.ndarray) -> np.ndarray:
    """Greenwich mean sidereal time (IAU 1982 polynomial, UT1 = UTC): radians."""
    d = mjd_seconds / 86400.0 - 51544.5
    gmst_h = 18.697374558 + 24.06570982441908 * d
    return np.mod(gmst_h, 24.0) * np.pi / 12.0


def enu_to_itrf(site: np.ndarray, enu: np.ndarray) -> np.ndarray:
    """ITRF positions (n, 3) of local East/North/Up offsets (n, 3) around ``site``."""
    x, y, z = site
    lon = np.arctan2(y, x)
    lat = np.arctan2(z, np.hypot(x, y))  # geocentric latitude, enough for a test layout
    east = np.array([-np.sin(lon), np.cos(lon), 0.0])
    north = np.array([-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)])
    up = np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    return site + enu @ np.vstack([east, north, up])


def antenna_uvw(itrf: np.ndarray, ra: float, dec: float, mjd_seconds: float) -> np.ndarray:
    """uvw (nant, 3) m of each antenna position towards (ra, dec) rad at one time."""
    h = _gmst_rad(np.asarray(mjd_seconds)) - ra  # Greenwich hour angle
    rot = np.array([[np.sin(h), np.cos(h), 0.0],
                    [-np.sin(dec) * np.cos(h), np.sin(dec) * np.sin(h), np.cos(dec)],
                    [np.cos(dec) * np.cos(h), -np.cos(dec) * np.sin(h), np.sin(dec)]])
    return itrf @ rot.T


def _array_col(pt, name, value, ndim, shape=None, comment=""):
    kw = dict(valuetype=type(value).__name__ if not isinstance(value, complex) else "complex",
              ndim=ndim, comment=comment)
    if shape is not None:
        kw["shape"] = list(shape)
        kw["options"] = 4  # FixedShape
    return pt.makearrcoldesc(name, value, **kw)


def build_ms(path: str | Path, spec: MSSpec | None = None, **overrides) -> Path:
    """Write the MS ``path`` from ``spec``, with :class:`MSSpec` fields overridden by keywords."""
    import casacore.tables as pt

    spec = replace(spec or MSSpec(), **overrides)
    path = Path(path)
    ncorr = len(spec.corr)
    ra, dec = np.radians(spec.ra_deg), np.radians(spec.dec_deg)
    used_itrf = enu_to_itrf(np.asarray(spec.site_itrf, float), np.asarray(spec.enu, float))
    nused = used_itrf.shape[0]

    desc = {}
    for name in spec.extra_columns:
        desc[name] = _array_col(pt, name, 0j, 2, (spec.nchan, ncorr))
    desc["WEIGHT_SPECTRUM"] = _array_col(pt, "WEIGHT_SPECTRUM", 0.0, 2, (spec.nchan, ncorr))
    tabdesc = pt.maketabdesc(list(desc.values()))
    ms = pt.default_ms(str(path), tabdesc)

    # antennas: the used ones first, then placeholders (as pyuvdata and CASA append them)
    names, positions, diameters, flags = [], [], [], []
    for k in range(nused):
        names.append(f"Tile{k:03d}")
        positions.append(used_itrf[k])
        diameters.append(spec.dish_diameter)
        flags.append(False)
    for k, kind in enumerate(spec.placeholders):
        names.append(f"Placeholder{k}")
        if kind == "origin":
            positions.append(np.zeros(3))
            diameters.append(0.0)
        else:
            positions.append(used_itrf[0] + np.array([100.0 + 10 * k, 50.0, 0.0]))
            diameters.append(spec.dish_diameter)
        flags.append(kind == "flagged")
        if kind not in ("unused", "flagged", "origin"):
            raise ValueError(f"unknown placeholder kind {kind!r}")
    with pt.table(f"{path}/ANTENNA", readonly=False, ack=False) as t:
        t.addrows(len(names))
        t.putcol("NAME", names)
        t.putcol("STATION", names)
        t.putcol("TYPE", ["GROUND-BASED"] * len(names))
        t.putcol("MOUNT", ["X-Y"] * len(names))
        t.putcol("POSITION", np.array(positions))
        t.putcol("OFFSET", np.zeros((len(names), 3)))
        t.putcol("DISH_DIAMETER", np.array(diameters))
        t.putcol("FLAG_ROW", np.array(flags))

    feed_pol = ["X", "Y"] if spec.corr[0][0] in "XY" else ["R", "L"]
    with pt.table(f"{path}/FEED", readonly=False, ack=False) as t:
        t.addrows(len(names))
        t.putcol("ANTENNA_ID", np.arange(len(names), dtype=np.int32))
        t.putcol("FEED_ID", np.zeros(len(names), np.int32))
        t.putcol("SPECTRAL_WINDOW_ID", -np.ones(len(names), np.int32))
        t.putcol("NUM_RECEPTORS", np.full(len(names), 2, np.int32))
        t.putcol("POLARIZATION_TYPE", np.array([feed_pol] * len(names)))
        t.putcol("RECEPTOR_ANGLE", np.zeros((len(names), 2)))
        t.putcol("POL_RESPONSE", np.tile(np.eye(2, dtype=complex), (len(names), 1, 1)))
        t.putcol("BEAM_OFFSET", np.zeros((len(names), 2, 2)))
        t.putcol("POSITION", np.zeros((len(names), 3)))
        t.putcol("TIME", np.full(len(names), spec.time0_s))
        t.putcol("INTERVAL", np.full(len(names), 1e30))

    freqs = spec.freq0_hz + spec.chan_width_hz * np.arange(spec.nchan)
    with pt.table(f"{path}/SPECTRAL_WINDOW", readonly=False, ack=False) as t:
        t.addrows(1)
        t.putcell("CHAN_FREQ", 0, freqs)
        t.putcell("CHAN_WIDTH", 0, np.full(spec.nchan, spec.chan_width_hz))
        t.putcell("EFFECTIVE_BW", 0, np.full(spec.nchan, spec.chan_width_hz))
        t.putcell("RESOLUTION", 0, np.full(spec.nchan, spec.chan_width_hz))
        t.putcell("NUM_CHAN", 0, spec.nchan)
        t.putcell("REF_FREQUENCY", 0, float(freqs[0]))
        t.putcell("TOTAL_BANDWIDTH", 0, spec.nchan * spec.chan_width_hz)
        t.putcell("NAME", 0, "SPW0")
        t.putcell("MEAS_FREQ_REF", 0, 5)  # TOPO

    products = {"X": 0, "Y": 1, "R": 0, "L": 1}
    with pt.table(f"{path}/POLARIZATION", readonly=False, ack=False) as t:
        t.addrows(1)
        t.putcell("NUM_CORR", 0, ncorr)
        t.putcell("CORR_TYPE", 0, np.array([CORR_CODE[c] for c in spec.corr], np.int32))
        t.putcell("CORR_PRODUCT", 0, np.array([[products[c[0]], products[c[1]]]
                                               for c in spec.corr], np.int32))
    with pt.table(f"{path}/DATA_DESCRIPTION", readonly=False, ack=False) as t:
        t.addrows(1)
        t.putcell("SPECTRAL_WINDOW_ID", 0, 0)
        t.putcell("POLARIZATION_ID", 0, 0)

    direction = np.array([[ra, dec]])
    with pt.table(f"{path}/FIELD", readonly=False, ack=False) as t:
        t.addrows(1)
        for col in ("PHASE_DIR", "DELAY_DIR", "REFERENCE_DIR"):
            t.putcell(col, 0, direction)
        t.putcell("NAME", 0, "TARGET")
        t.putcell("TIME", 0, spec.time0_s)

    times = spec.time0_s + spec.interval_s * np.arange(spec.ntime)
    with pt.table(f"{path}/OBSERVATION", readonly=False, ack=False) as t:
        t.addrows(1)
        t.putcell("TELESCOPE_NAME", 0, spec.telescope)
        t.putcell("OBSERVER", 0, "test")
        t.putcell("PROJECT", 0, "msleak-tests")
        t.putcell("TIME_RANGE", 0, np.array([times[0] - spec.interval_s / 2,
                                             times[-1] + spec.interval_s / 2]))

    # main table: time-major, baselines p <= q (p < q without autocorrelations)
    p, q = np.triu_indices(nused, 0 if spec.autocorrelations else 1)
    nbl = p.size
    rows_t = np.repeat(times, nbl)
    a1, a2 = np.tile(p, spec.ntime), np.tile(q, spec.ntime)
    uvw = np.concatenate([(lambda u: u[q] - u[p])(antenna_uvw(used_itrf, ra, dec, t))
                          for t in times])
    if spec.uvw_float32:
        uvw = uvw.astype(np.float32).astype(np.float64)
    nrow = rows_t.size
    ms.addrows(nrow)
    ms.putcol("TIME", rows_t)
    ms.putcol("TIME_CENTROID", rows_t)
    ms.putcol("INTERVAL", np.full(nrow, spec.interval_s))
    ms.putcol("EXPOSURE", np.full(nrow, spec.interval_s))
    ms.putcol("ANTENNA1", a1.astype(np.int32))
    ms.putcol("ANTENNA2", a2.astype(np.int32))
    ms.putcol("UVW", uvw)
    zeros_i = np.zeros(nrow, np.int32)
    for col in ("DATA_DESC_ID", "FIELD_ID", "ARRAY_ID", "OBSERVATION_ID", "PROCESSOR_ID",
                "SCAN_NUMBER", "STATE_ID", "FEED1", "FEED2"):
        ms.putcol(col, zeros_i)
    ms.putcol("FLAG_ROW", np.zeros(nrow, bool))
    ms.putcol("FLAG", np.zeros((nrow, spec.nchan, ncorr), bool))
    ms.putcol("WEIGHT", np.ones((nrow, ncorr), np.float32))
    ms.putcol("SIGMA", np.ones((nrow, ncorr), np.float32))
    ms.putcol("WEIGHT_SPECTRUM", np.ones((nrow, spec.nchan, ncorr), np.float32))
    for name in spec.extra_columns:
        ms.putcol(name, np.zeros((nrow, spec.nchan, ncorr), np.complex64))
    if spec.mwa_tile_pointing:
        _write_mwa_tile_pointing(pt, ms, path, times, spec.interval_s, ra, dec)
    ms.close()
    return path


def _write_mwa_tile_pointing(pt, ms, path, times, interval_s, ra, dec):
    """The MWA_TILE_POINTING subtable (INTERVAL, DELAYS, DIRECTION) and its main-table keyword."""
    desc = pt.maketabdesc([_array_col(pt, "INTERVAL", 0.0, 1, (2,)),
                           _array_col(pt, "DELAYS", 0, 1, (16,)),
                           _array_col(pt, "DIRECTION", 0.0, 1, (2,))])
    with pt.table(f"{path}/MWA_TILE_POINTING", desc, nrow=1, ack=False) as t:
        t.putcell("INTERVAL", 0, np.array([times[0] - interval_s / 2, times[-1] + interval_s / 2]))
        t.putcell("DELAYS", 0, np.zeros(16, np.int32))
        t.putcell("DIRECTION", 0, np.array([ra, dec]))
    ms.putkeyword("MWA_TILE_POINTING", f"Table: {Path(path).resolve()}/MWA_TILE_POINTING")
