"""``msleak simulate``: a new Measurement Set for a LOFAR-like (or any) array.

Rows are ordered by time, then baseline (ANTENNA1 < ANTENNA2, autocorrelations only with
``autocorrelations=True``). TIME is the centre of each integration. DATA is zero, FLAG
false, WEIGHT_SPECTRUM one. Rows are written in time chunks so memory stays bounded
(about ``chunk_rows`` x nchan x 4 x 13 bytes) whatever the length of the observation.
"""

from __future__ import annotations

import logging
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msleak.errors import InputError
from msleak.telescope.layouts import Layout, lofar_hba_core, read_layout_file
from msleak.telescope.ms_create import create_ms_tables
from msleak.telescope.uvw import antenna_uvw

__all__ = ["FIELD_PRESETS", "FieldPreset", "simulate_ms", "transit_start"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FieldPreset:
    """A named observing set-up of docs/science.md section 2."""

    name: str
    ra_deg: float
    dec_deg: float
    duration_h: float
    date: str            # default observing date (UTC)
    centre_on_transit: bool


FIELD_PRESETS = {
    "ncp": FieldPreset("NCP", 0.0, 90.0, 13.0, "2013-02-06", False),
    "3c196": FieldPreset("3C196", 123.4, 48.2, 8.0, "2012-12-16", True),
}

#: Most time slots one simulated MS may have (guards against typos such as 1e6 hours)
_MAX_TIME_SLOTS = 1e7

#: Default start for the NCP (any time sees it at the same elevation from LOFAR)
_NCP_START = "2013-02-06T12:00:00"
_DEFAULT_DATE = "2013-01-01"


def transit_start(ra_deg: float, date: str, duration_h: float, longitude_rad: float) -> float:
    """Start time (MJD s) of an observation of ``duration_h`` centred on the transit of
    right ascension ``ra_deg`` at ``longitude_rad`` on the UTC day ``date``."""
    from astropy.time import Time
    import astropy.units as u

    t0 = Time(f"{date}T00:00:00", scale="utc")
    lst0 = t0.sidereal_time("apparent", longitude=longitude_rad * u.rad).to_value(u.hourangle)
    dt_sidereal = (ra_deg / 15.0 - lst0) % 24.0
    transit = t0 + (dt_sidereal / 1.00273790935) * u.hour
    return float(transit.mjd * 86400.0 - duration_h * 1800.0)


def _parse_start(start: str) -> float:
    from astropy.time import Time

    try:
        return float(Time(start, scale="utc").mjd * 86400.0)
    except ValueError:
        raise InputError(f"--start {start!r} is not an ISO date/time such as "
                         "2012-12-16T20:00:00") from None


def simulate_ms(path: str | Path, *, field: str | None = "3c196",
                phase_centre: tuple[float, float] | None = None, start: str | None = None,
                duration_h: float | None = None, interval_s: float = 120.0,
                freq_min_hz: float = 150e6, nchan: int = 50, chan_width_hz: float = 195312.5,
                stations: str | None = None, layout: str | Path | None = None,
                autocorrelations: bool = False, overwrite: bool = False,
                chunk_rows: int = 200_000, progress: bool = False) -> Path:
    """Create a Measurement Set at ``path`` (see ``msleak simulate --help``).

    Parameters
    ----------
    field : 'ncp' or '3c196' preset (phase centre, duration, date), or None with
        ``phase_centre``
    phase_centre : (RA, Dec) in degrees, overrides the preset's
    start : ISO UTC start time; default: the preset's (centred on transit for 3C196 and
        any custom phase centre)
    duration_h, interval_s : synthesis time (h) and integration (s)
    freq_min_hz, nchan, chan_width_hz : channel i is centred at freq_min + i * width
    stations : station/field name pattern(s), e.g. ``"CS00[1-3]HBA*"``
    layout : layout text file for a non-LOFAR array (see msleak.telescope.layouts)
    """
    path = Path(path)
    preset = None
    if field is not None:
        key = field.lower()
        if key not in FIELD_PRESETS:
            raise InputError(f"unknown field {field!r}: use one of "
                             f"{', '.join(FIELD_PRESETS)} or --phase-centre RA,DEC")
        preset = FIELD_PRESETS[key]
    if phase_centre is None and preset is None:
        raise InputError("give --field ncp|3c196 or --phase-centre RA_DEG,DEC_DEG")
    ra_deg, dec_deg = phase_centre if phase_centre is not None else (preset.ra_deg, preset.dec_deg)
    if not (-90.0 <= dec_deg <= 90.0):
        raise InputError(f"declination {dec_deg} deg is outside -90..90")
    ra_deg = ra_deg % 360.0
    if duration_h is None:
        duration_h = preset.duration_h if preset is not None else 8.0
    for name, value in (("--duration", duration_h), ("--interval", interval_s),
                        ("--chan-width", chan_width_hz), ("--freq-min", freq_min_hz)):
        if not np.isfinite(value) or value <= 0:
            raise InputError(f"{name} must be positive, got {value}")
    if int(nchan) != nchan or nchan <= 0:
        raise InputError(f"--nchan must be a positive integer, got {nchan}")
    slots = duration_h * 3600.0 / interval_s
    if not slots <= _MAX_TIME_SLOTS:
        raise InputError(f"--duration {duration_h} h at --interval {interval_s} s is "
                         f"{slots:.3g} time slots; at most {_MAX_TIME_SLOTS:.0e} are supported")
    ntime = int(round(slots))
    if ntime < 1:
        raise InputError(f"--duration {duration_h} h is shorter than one --interval of {interval_s} s")
    if path.exists():
        if not overwrite:
            raise InputError(f"{path} exists; pass --overwrite to replace it")
        if path.is_dir() and not (path / "table.dat").exists():
            raise InputError(f"{path} exists and is not a Measurement Set; refusing to replace it")
        shutil.rmtree(path) if path.is_dir() else path.unlink()
    if not path.parent.exists():
        raise InputError(f"{path.parent}: no such directory")

    lay: Layout = (read_layout_file(layout, stations) if layout is not None
                   else lofar_hba_core(stations or "CS*HBA*"))
    if len(lay) < 2:
        raise InputError("an interferometer needs at least two stations")

    ra, dec = np.radians(ra_deg), np.radians(dec_deg)
    if start is not None:
        t_start = _parse_start(start)
    elif preset is not None and not preset.centre_on_transit and phase_centre is None:
        t_start = _parse_start(_NCP_START)
    else:
        from astropy.coordinates import EarthLocation
        import astropy.units as u

        lon = EarthLocation.from_geocentric(*lay.positions.mean(axis=0), unit=u.m).lon
        date = preset.date if preset is not None else _DEFAULT_DATE
        t_start = transit_start(ra_deg, date, duration_h, lon.to_value(u.rad))
    times = t_start + (np.arange(ntime) + 0.5) * interval_s
    freq = freq_min_hz + np.arange(int(nchan)) * chan_width_hz

    nant = len(lay)
    a1, a2 = np.triu_indices(nant, k=0 if autocorrelations else 1)
    nbl = len(a1)
    nrows = ntime * nbl
    name = preset.name if (preset is not None and phase_centre is None) else \
        f"RA{ra_deg:.3f}_DEC{dec_deg:+.3f}"
    log.info("creating %s: %d antennas, %d baselines, %d times x %.0f s, %d channels (%d rows)",
             path, nant, nbl, ntime, interval_s, nchan, nrows)
    from msleak.io.columns import check_free_space

    # DATA (complex64), WEIGHT_SPECTRUM (float32), FLAG (bits), ~200 B of other columns a
    # row, plus tiles and subtables: casacore aborts the process on a full disk.
    check_free_space(path.parent, nrows * (int(nchan) * 4 * 12.2 + 200) + 1.5 * 2**20,
                     f"the Measurement Set {path}")
    try:
        create_ms_tables(path, layout=lay, freq=freq, chan_width=chan_width_hz, ra=ra,
                         dec=dec, field_name=name,
                         time_range=(t_start, t_start + ntime * interval_s), nrows=nrows)
        _fill_main(path, times, interval_s, a1, a2, lay.positions, ra, dec, int(nchan),
                   chunk_rows, progress)
    except BaseException:
        log.error("simulate interrupted; %s is incomplete: rerun with --overwrite", path)
        raise
    return path


def _fill_main(path: Path, times, interval, a1, a2, positions, ra, dec, nchan, chunk_rows,
               progress) -> None:
    import casacore.tables as pt

    nbl = len(a1)
    times_per_chunk = max(1, chunk_rows // nbl)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(times), unit="slot", desc="simulate", leave=False)
    with pt.table(str(path), readonly=False, ack=False) as ms:
        for t0 in range(0, len(times), times_per_chunk):
            tchunk = times[t0:t0 + times_per_chunk]
            n = len(tchunk) * nbl
            row0 = t0 * nbl
            auvw = antenna_uvw(positions, tchunk, ra, dec)          # (nt, nant, 3)
            uvw = (auvw[:, a2, :] - auvw[:, a1, :]).reshape(n, 3)
            ms.putcol("TIME", np.repeat(tchunk, nbl), startrow=row0, nrow=n)
            ms.putcol("TIME_CENTROID", np.repeat(tchunk, nbl), startrow=row0, nrow=n)
            ms.putcol("INTERVAL", np.full(n, interval), startrow=row0, nrow=n)
            ms.putcol("EXPOSURE", np.full(n, interval), startrow=row0, nrow=n)
            ms.putcol("ANTENNA1", np.tile(a1, len(tchunk)).astype(np.int32), startrow=row0, nrow=n)
            ms.putcol("ANTENNA2", np.tile(a2, len(tchunk)).astype(np.int32), startrow=row0, nrow=n)
            ms.putcol("UVW", uvw, startrow=row0, nrow=n)
            ms.putcol("SCAN_NUMBER", np.ones(n, dtype=np.int32), startrow=row0, nrow=n)
            ms.putcol("DATA", np.zeros((n, nchan, 4), dtype=np.complex64), startrow=row0, nrow=n)
            ms.putcol("FLAG", np.zeros((n, nchan, 4), dtype=bool), startrow=row0, nrow=n)
            ms.putcol("WEIGHT_SPECTRUM", np.ones((n, nchan, 4), dtype=np.float32),
                      startrow=row0, nrow=n)
            ms.putcol("WEIGHT", np.ones((n, 4), dtype=np.float32), startrow=row0, nrow=n)
            ms.putcol("SIGMA", np.ones((n, 4), dtype=np.float32), startrow=row0, nrow=n)
            if bar is not None:
                bar.update(len(tchunk))
    if bar is not None:
        bar.close()
