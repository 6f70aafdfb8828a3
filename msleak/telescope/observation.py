"""The observation a simulated Measurement Set holds: field presets, the telescope's
stations, times and channels (:func:`plan_observation`, docs/simulate.md); the verb
:func:`msleak.simulate` writes it.

Times are the centres of the integrations; channel i is centred at freq_min + i chan_width.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msleak.errors import InputError
from msleak.telescope.hera_mwa import (
    HERA_DISH_DIAMETER_M,
    HERA_TELESCOPE_NAME,
    MWA_TELESCOPE_NAME,
    MWA_TILE_SIZE_M,
    hera_layout,
    mwa_layout,
)
from msleak.telescope.layouts import HBA_FIELD_DIAMETER, Layout, lofar_hba_core, read_layout_file
from msleak.telescope.ska_low import ska_low_from_layout_file, ska_low_layout

__all__ = ["FIELD_PRESETS", "FieldPreset", "TELESCOPES", "TELESCOPE_LABELS", "Observation",
           "plan_observation", "telescope_layout", "transit_start", "zenith_j2000"]


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
TELESCOPE_LABELS = {"lofar": "LOFAR", "ska-low": "SKA-Low", "hera": "HERA", "mwa": "MWA"}
#: telescopes whose beam is fixed on the ground (no tracking): a preset observes for this
#: long (hours) around transit instead of the preset's duration (docs/telescopes.md)
_FIXED_BEAM_DURATION_H = {"hera": 1.0, "mwa": 1.0}
#: first channel (Hz) where it is not 150 MHz: HERA's shipped beam file covers 100-145 MHz
_FREQ_MIN_HZ = {"hera": 135e6}

#: Most time slots one simulated MS may have (guards against typos such as 1e6 hours)
_MAX_TIME_SLOTS = 1e7

#: Default start for the NCP (any time sees it at the same elevation from LOFAR)
_NCP_START = "2013-02-06T12:00:00"
_DEFAULT_DATE = "2013-01-01"


@dataclass(frozen=True)
class Observation:
    """What a simulated MS holds: the field, the stations, the integrations (``start``,
    MJD s, and the centres ``times``) and the channels (centres, Hz)."""

    name: str
    ra_deg: float
    dec_deg: float
    layout: Layout
    start: float
    times: np.ndarray
    interval: float
    freq: np.ndarray
    chan_width: float

    @property
    def time_range(self) -> tuple[float, float]:
        """(start, end) of the observation, MJD s."""
        return self.start, self.start + len(self.times) * self.interval


def plan_observation(telescope: str = "lofar", *, field: str | None = None,
                     phase_centre: tuple[float, float] | None = None,
                     start: str | None = None, duration: float | None = None,
                     interval: float = 120.0, freq_min: float | None = None, nchan: int = 50,
                     chan_width: float = 195312.5, stations: str | None = None,
                     layout=None) -> Observation:
    """The observation of :func:`msleak.simulate` (its parameters, docs/simulate.md), after
    checking every parameter: refuses an unknown telescope or field, fewer than two
    stations and a field that never rises."""
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
    t_start = _start_time(start, preset, phase_centre, lay, ra_deg, duration)
    return Observation(name=name, ra_deg=ra_deg, dec_deg=dec_deg, layout=lay, start=t_start,
                       times=t_start + (np.arange(ntime) + 0.5) * interval, interval=interval,
                       freq=freq_min + np.arange(int(nchan)) * chan_width,
                       chan_width=chan_width)


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
        raise InputError(f"start {start!r} is not an ISO date/time such as "
                         "2012-12-16T20:00:00", param="start") from None


def _telescope_defaults(telescope: str, preset, duration, freq_min) -> tuple[float, float]:
    """``duration`` (h) and ``freq_min`` (Hz), or the telescope's and the preset's."""
    if duration is None:
        duration = _FIXED_BEAM_DURATION_H.get(
            telescope, preset.duration_h if preset is not None else 8.0)
    return duration, _FREQ_MIN_HZ.get(telescope, 150e6) if freq_min is None else freq_min


def zenith_j2000(position_itrf, time_mjd_s: float) -> tuple[float, float]:
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
                         f"latitude {lat:.1f} deg: choose another field or phase_centre",
                         param=("field", "phase_centre"))


def _pointing(field, phase_centre):
    """(preset or None, ra_deg in [0, 360), dec_deg, FIELD name)."""
    preset = None
    if field is not None:
        if field.lower() not in FIELD_PRESETS:
            raise InputError(f"unknown field {field!r}: use one of "
                             f"{', '.join(FIELD_PRESETS)} or phase_centre RA,DEC",
                             param="phase_centre")
        preset = FIELD_PRESETS[field.lower()]
    if phase_centre is not None:
        if len(phase_centre) != 2:
            raise InputError(f"phase_centre needs RA_DEG,DEC_DEG, got {phase_centre!r}",
                             param="phase_centre")
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
    for name, value in (("duration", duration), ("interval", interval),
                        ("chan_width", chan_width), ("freq_min", freq_min)):
        if not np.isfinite(value) or value <= 0:
            raise InputError(f"{name} must be positive, got {value}", param=name)
    if int(nchan) != nchan or nchan <= 0:
        raise InputError(f"nchan must be a positive integer, got {nchan}", param="nchan")
    slots = duration * 3600.0 / interval
    if not slots <= _MAX_TIME_SLOTS:
        raise InputError(f"duration {duration} h at interval {interval} s is "
                         f"{slots:.3g} time slots; at most {_MAX_TIME_SLOTS:.0e} are supported",
                         param=("duration", "interval"))
    ntime = int(round(slots))
    if ntime < 1:
        raise InputError(f"duration {duration} h is shorter than one interval of {interval} s",
                         param=("duration", "interval"))
    return ntime


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
