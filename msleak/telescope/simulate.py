"""``msleak simulate``: a new Measurement Set for a LOFAR-like (or any) array.

Rows are ordered by time, then baseline (ANTENNA1 < ANTENNA2, autocorrelations only with
``autocorrelations=True``). TIME is the centre of each integration. DATA is zero, FLAG
false, WEIGHT_SPECTRUM one. Rows are written in time chunks so memory stays bounded
whatever the length of the observation (docs/simulate.md).
"""

from __future__ import annotations

import logging
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msleak.errors import InputError
from msleak.io.columns import check_free_space
from msleak.io.ms import append_history
from msleak.io.mwa import write_mwa_tile_pointing
from msleak.io.phased_array import write_phased_array
from msleak.io.products import call_record
from msleak.telescope.hera_mwa import (
    HERA_DISH_DIAMETER_M,
    HERA_TELESCOPE_NAME,
    MWA_TELESCOPE_NAME,
    MWA_TILE_SIZE_M,
    hera_layout,
    mwa_layout,
)
from msleak.telescope.layouts import HBA_FIELD_DIAMETER, Layout, lofar_hba_core, read_layout_file
from msleak.telescope.ms_create import create_ms_tables
from msleak.telescope.ska_low import (
    ska_low_from_layout_file,
    ska_low_layout,
    station_element_offsets,
)
from msleak.telescope.uvw import antenna_uvw

__all__ = ["FIELD_PRESETS", "FieldPreset", "TELESCOPES", "simulate", "telescope_layout",
           "transit_start"]

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
    # the southern EoR0 field (RA 0 h, Dec -27 deg), 8 h centred on transit
    "eor0": FieldPreset("EoR0", 0.0, -27.0, 8.0, "2020-10-01", True),
}

#: telescopes msleak simulates, and the field each observes by default
TELESCOPES = {"lofar": "3c196", "ska-low": "eor0", "hera": "eor0", "mwa": "eor0"}
#: how each is named in HISTORY
_LABELS = {"lofar": "LOFAR", "ska-low": "SKA-Low", "hera": "HERA", "mwa": "MWA"}
#: telescopes whose beam is fixed on the ground (no tracking): a preset observes for this
#: long (hours) around transit instead of the preset's duration (docs/telescopes.md)
_FIXED_BEAM_DURATION_H = {"hera": 1.0, "mwa": 1.0}
#: first channel (Hz) where it is not 150 MHz: HERA's shipped beam file covers 100-145 MHz
_FREQ_MIN_HZ = {"hera": 135e6}

#: Rows written per chunk (memory: about this x nchan x 4 x 13 bytes)
_CHUNK_ROWS = 200_000

#: Most time slots one simulated MS may have (guards against typos such as 1e6 hours)
_MAX_TIME_SLOTS = 1e7

#: Default start for the NCP (any time sees it at the same elevation from LOFAR)
_NCP_START = "2013-02-06T12:00:00"
_DEFAULT_DATE = "2013-01-01"


def transit_start(ra_deg: float, date: str, duration_h: float, longitude_rad: float) -> float:
    """Start time (MJD s) of an observation of ``duration_h`` centred on the transit of
    right ascension ``ra_deg`` at ``longitude_rad`` on the UTC day ``date``."""
    import astropy.units as u
    from astropy.time import Time

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


def simulate(output: str | os.PathLike, *, field: str | None = None,
             phase_centre: tuple[float, float] | None = None, start: str | None = None,
             duration: float | None = None, interval: float = 120.0,
             freq_min: float | None = None, nchan: int = 50, chan_width: float = 195312.5,
             stations: str | None = None, layout: str | os.PathLike | None = None,
             autocorrelations: bool = False, telescope: str = "lofar",
             overwrite: bool = False, progress: bool = False) -> Path:
    """Create the Measurement Set ``output`` (``msleak simulate``, docs/simulate.md).

    Parameters
    ----------
    output : path
        The new MS; an existing one is refused unless ``overwrite``.
    field : {'ncp', '3c196', 'eor0'}, optional
        Observing preset (phase centre, duration, date); default the telescope's
        (``'3c196'`` for LOFAR, ``'eor0'`` for the others) unless ``phase_centre`` is given.
    phase_centre : (ra_deg, dec_deg), optional
        J2000 phase centre in degrees; overrides the preset's.
    start : str, optional
        ISO UTC start; default the preset's (centred on transit for 3C196 and any
        custom phase centre).
    duration, interval : float
        Synthesis time (hours) and integration time (seconds).
    freq_min, nchan, chan_width : float, int, float
        Channel i is centred at ``freq_min + i * chan_width`` (Hz); ``freq_min`` defaults
        to 150 MHz, for HERA to 135 MHz (its beam file ends at 145 MHz).
    stations : str, optional
        Station name patterns, comma-separated, e.g. ``"CS00[1-3]HBA*"``.
    layout : path, optional
        Layout text file of another array (no LOFAR beam tables then; with
        ``telescope='ska-low'``, real SKA-Low station positions).
    autocorrelations : bool
        Include autocorrelation rows.
    telescope : {'lofar', 'ska-low', 'hera', 'mwa'}
        LOFAR HBA core (default); an approximate SKA-Low core of 224 stations of 256
        elements with the PHASED_ARRAY table EveryBeam reads (docs/ska_low.md); HERA's 350
        dishes or the MWA's 128 tiles (zenith-fixed beams: 1 h around transit by default;
        docs/telescopes.md).
    progress : bool
        Show a progress bar on stderr.

    Returns
    -------
    pathlib.Path
        The MS, with a HISTORY row saying what was simulated.
    """
    call = dict(locals())
    path = Path(output)
    if telescope not in TELESCOPES:
        raise InputError(f"unknown telescope {telescope!r}: use one of {', '.join(TELESCOPES)}")
    preset, ra_deg, dec_deg, name = _pointing(
        TELESCOPES[telescope] if field is None and phase_centre is None else field,
        phase_centre)
    duration, freq_min = _telescope_defaults(telescope, preset, duration, freq_min)
    ntime = _time_slots(duration, interval, freq_min, chan_width, nchan)
    lay = telescope_layout(telescope, layout, stations)
    if len(lay) < 2:
        raise InputError("an interferometer needs at least two stations")
    _check_rises(lay, dec_deg, name)
    _prepare_output(path, overwrite)
    t_start = _start_time(start, preset, phase_centre, lay, ra_deg, duration)
    times = t_start + (np.arange(ntime) + 0.5) * interval
    freq = freq_min + np.arange(int(nchan)) * chan_width
    a1, a2 = np.triu_indices(len(lay), k=0 if autocorrelations else 1)
    nrows = ntime * len(a1)
    log.info("creating %s: %d antennas, %d baselines, %d times x %.0f s, %d channels (%d rows)",
             path, len(lay), len(a1), ntime, interval, nchan, nrows)

    # DATA (complex64), WEIGHT_SPECTRUM (float32), FLAG (bits), ~200 B of other columns a
    # row, plus tiles and subtables: casacore aborts the process on a full disk.
    check_free_space(path.parent, nrows * (int(nchan) * 4 * 12.2 + 200) + 1.5 * 2**20,
                     f"the Measurement Set {path}")
    ra, dec = np.radians(ra_deg), np.radians(dec_deg)
    try:
        create_ms_tables(path, layout=lay, freq=freq, chan_width=chan_width, ra=ra,
                         dec=dec, field_name=name,
                         time_range=(t_start, t_start + ntime * interval), nrows=nrows)
        _fill_main(path, times, interval, a1, a2, lay.positions, ra, dec, int(nchan),
                   _CHUNK_ROWS, progress)
        _write_beam_tables(path, telescope, lay, (t_start, t_start + ntime * interval))
        what = _LABELS[telescope] + \
            (" (approximate core)" if telescope == "ska-low" and layout is None else "")
        append_history(path, f"simulated {len(lay)} {what} stations, field {name}, {ntime} x "
                             f"{interval:g} s, {int(nchan)} channels of {chan_width:.10g} Hz "
                             f"from {freq_min:.10g} Hz",
                       command=call_record(simulate, call, skip=("progress",)))
    except BaseException:
        log.error("simulate interrupted; %s is incomplete: rerun with --overwrite", path)
        raise
    return path


def _telescope_defaults(telescope: str, preset, duration, freq_min) -> tuple[float, float]:
    """``duration`` (h) and ``freq_min`` (Hz), or the telescope's and the preset's."""
    if duration is None:
        duration = _FIXED_BEAM_DURATION_H.get(
            telescope, preset.duration_h if preset is not None else 8.0)
    return duration, _FREQ_MIN_HZ.get(telescope, 150e6) if freq_min is None else freq_min


def _write_beam_tables(path: Path, telescope: str, lay: Layout, time_range) -> None:
    """What the beam model of ``telescope`` reads besides the standard subtables: SKA-Low's
    PHASED_ARRAY, the MWA's MWA_TILE_POINTING (zenith delays, pointing at the zenith
    mid-way through the observation). LOFAR's tables come with the MS."""
    if telescope == "ska-low":
        axes, offsets = station_element_offsets(lay.positions)
        write_phased_array(path, lay.positions, axes, offsets)
    elif telescope == "mwa":
        mid = 0.5 * (time_range[0] + time_range[1])
        write_mwa_tile_pointing(path, time_range,
                                direction=_zenith_j2000(lay.positions.mean(axis=0), mid))


def _zenith_j2000(position_itrf, time_mjd_s: float) -> tuple[float, float]:
    """J2000 (ra, dec), rad, of the zenith at ``position_itrf`` (m) at UTC ``time_mjd_s``
    (astropy: metadata only, and casacore's measures keep caches that later conversions
    would depend on)."""
    import astropy.units as u
    from astropy.coordinates import FK5, AltAz, EarthLocation, SkyCoord
    from astropy.time import Time

    site = EarthLocation.from_geocentric(*position_itrf, unit=u.m)
    frame = AltAz(obstime=Time(time_mjd_s / 86400.0, format="mjd", scale="utc"), location=site)
    z = SkyCoord(alt=90 * u.deg, az=0 * u.deg, frame=frame).transform_to(FK5(equinox="J2000"))
    return float(z.ra.rad), float(z.dec.rad)


def telescope_layout(telescope: str, layout=None, stations: str | None = None) -> Layout:
    """The stations of ``telescope``, from ``layout`` if given, selected by ``stations``."""
    if telescope == "lofar":
        return (read_layout_file(layout, stations) if layout is not None
                else lofar_hba_core(stations or "CS*HBA*"))
    if telescope == "ska-low":
        if layout is not None:
            return ska_low_from_layout_file(layout, stations)
        return ska_low_layout().to_layout().select(stations, "the SKA-Low core")
    if layout is not None:   # a file's unstated diameter becomes the dish's or the tile's
        lay = read_layout_file(layout, stations)
        name, size = ((HERA_TELESCOPE_NAME, HERA_DISH_DIAMETER_M) if telescope == "hera"
                      else (MWA_TELESCOPE_NAME, MWA_TILE_SIZE_M))
        return Layout(names=lay.names, positions=lay.positions, telescope=name,
                      diameters=np.where(lay.diameters == HBA_FIELD_DIAMETER, size,
                                         lay.diameters))
    return hera_layout(stations) if telescope == "hera" else mwa_layout(stations)


def _check_rises(lay: Layout, dec_deg: float, name: str) -> None:
    """Refuse a field that never rises above the array's horizon."""
    import astropy.units as u
    from astropy.coordinates import EarthLocation

    lat = EarthLocation.from_geocentric(*lay.positions.mean(axis=0), unit=u.m).lat.deg
    if 90.0 - abs(lat - dec_deg) <= 0.0:
        raise InputError(f"field {name} (Dec {dec_deg:g} deg) never rises at the array's "
                         f"latitude {lat:.1f} deg: choose another --field or --phase-centre")


def _pointing(field, phase_centre):
    """(preset or None, ra_deg in [0, 360), dec_deg, FIELD name)."""
    preset = None
    if field is not None:
        if field.lower() not in FIELD_PRESETS:
            raise InputError(f"unknown field {field!r}: use one of "
                             f"{', '.join(FIELD_PRESETS)} or --phase-centre RA,DEC")
        preset = FIELD_PRESETS[field.lower()]
    if phase_centre is not None:
        if len(phase_centre) != 2:
            raise InputError(f"--phase-centre needs RA_DEG,DEC_DEG, got {phase_centre!r}")
        ra_deg, dec_deg = (float(v) for v in phase_centre)
    else:
        ra_deg, dec_deg = preset.ra_deg, preset.dec_deg
    if not (-90.0 <= dec_deg <= 90.0):
        raise InputError(f"declination {dec_deg} deg is outside -90..90")
    ra_deg = ra_deg % 360.0
    name = preset.name if (preset is not None and phase_centre is None) else \
        f"RA{ra_deg:.3f}_DEC{dec_deg:+.3f}"
    return preset, ra_deg, dec_deg, name


def _time_slots(duration, interval, freq_min, chan_width, nchan) -> int:
    """The number of integrations, after checking every number."""
    for name, value in (("--duration", duration), ("--interval", interval),
                        ("--chan-width", chan_width), ("--freq-min", freq_min)):
        if not np.isfinite(value) or value <= 0:
            raise InputError(f"{name} must be positive, got {value}")
    if int(nchan) != nchan or nchan <= 0:
        raise InputError(f"--nchan must be a positive integer, got {nchan}")
    slots = duration * 3600.0 / interval
    if not slots <= _MAX_TIME_SLOTS:
        raise InputError(f"--duration {duration} h at --interval {interval} s is "
                         f"{slots:.3g} time slots; at most {_MAX_TIME_SLOTS:.0e} are supported")
    ntime = int(round(slots))
    if ntime < 1:
        raise InputError(f"--duration {duration} h is shorter than one --interval of {interval} s")
    return ntime


def _prepare_output(path: Path, overwrite: bool) -> None:
    """Refuse an existing ``path`` unless ``overwrite`` (then remove it, if an MS)."""
    if path.exists():
        if not overwrite:
            raise InputError(f"{path} exists; pass --overwrite to replace it")
        if path.is_dir() and not (path / "table.dat").exists():
            raise InputError(f"{path} exists and is not a Measurement Set; refusing to replace it")
        shutil.rmtree(path) if path.is_dir() else path.unlink()
    if not path.parent.exists():
        raise InputError(f"{path.parent}: no such directory")


def _start_time(start, preset, phase_centre, lay: Layout, ra_deg: float,
                duration: float) -> float:
    """Start (MJD s): ``start``, the NCP preset's, or centred on transit at the array."""
    if start is not None:
        return _parse_start(start)
    if preset is not None and not preset.centre_on_transit and phase_centre is None:
        return _parse_start(_NCP_START)
    import astropy.units as u
    from astropy.coordinates import EarthLocation

    lon = EarthLocation.from_geocentric(*lay.positions.mean(axis=0), unit=u.m).lon
    date = preset.date if preset is not None else _DEFAULT_DATE
    return transit_start(ra_deg, date, duration, lon.to_value(u.rad))


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
