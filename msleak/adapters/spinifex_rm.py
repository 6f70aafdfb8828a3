"""Rotation measures of a thin-shell ionosphere above an MS's stations, computed offline with
spinifex (docs/predict.md, "Ionosphere").

Each station's line of sight to its field's phase centre pierces a shell
:data:`SHELL_HEIGHT_KM` above a spherical Earth (spinifex's geometry). There, the vertical
electron column comes from the International Reference Ionosphere (PyIRI, which spinifex
ships; spec ``spinifex``) or from local IONEX maps (``ionex:PATH``, read and interpolated by
spinifex), the geomagnetic field from IGRF (ppigrf, through spinifex), and
``RM = FARADAY_RM * TEC * airmass * B_par`` (:func:`msleak.beam.ionosphere.thin_shell_rm`).
RMs are computed every :data:`SAMPLE_STEP_S` over each field's times and interpolated
linearly in time by :class:`~msleak.beam.ionosphere.RotationMeasures`.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import NamedTuple

import numpy as np

from msleak.beam.ionosphere import RotationMeasures, thin_shell_rm
from msleak.errors import ConfigurationError, InputError
from msleak.io.ms import read_antennas, read_fields, read_times, read_used_antennas

__all__ = ["model_rotation_measures", "is_model_spec", "parse_model_spec", "PiercePoints",
           "pierce_points", "mean_pierce_point", "vertical_tec", "b_along_los", "station_rms",
           "SAMPLE_STEP_S", "SHELL_HEIGHT_KM", "IRI_F107", "IRI_HEIGHTS_KM"]

#: RMs are computed every SAMPLE_STEP_S seconds of each field's time span (both ends
#: included) and interpolated linearly in between
SAMPLE_STEP_S = 300.0
#: height (km) of the thin shell above a spherical Earth (spinifex's default)
SHELL_HEIGHT_KM = 450.0
#: solar 10.7 cm flux (sfu) given to IRI unless the spec sets ``f107=`` (spinifex's value)
IRI_F107 = 100.0
#: heights (km) of IRI's electron density profile summed into the vertical TEC
IRI_HEIGHTS_KM = np.concatenate([np.arange(60.0, 1000.0, 5.0), np.arange(1000.0, 20001.0, 50.0)])
#: spinifex's ionosphere models that download their maps (msleak runs offline)
_DOWNLOADING = ("ionex", "ionex_iri", "tomion", "tomion_dual", "cod", "uqr", "igs", "esa",
                "jpl", "upc", "irt")


class PiercePoints(NamedTuple):
    """Where each station's line of sight crosses the shell, (nstation, ntime) arrays:
    geocentric ``lon_deg``, ``lat_deg`` (spherical Earth), ``airmass`` (slant / vertical
    path), and spinifex's ``ipp`` of all of them, station after station (for its field
    model)."""

    lon_deg: np.ndarray
    lat_deg: np.ndarray
    airmass: np.ndarray
    ipp: object


def is_model_spec(text: str) -> bool:
    """True if the ionosphere setting ``text`` names a model of this module."""
    return text == "spinifex" or text.startswith(("spinifex:", "ionex:"))


def parse_model_spec(text: str) -> dict:
    """``{"tec": "iri", "f107": sfu}`` for ``spinifex[:f107=SFU]``, ``{"tec": "ionex",
    "files": [Path, ...]}`` for ``ionex:PATH[,PATH...]``.

    Raises
    ------
    InputError
        A model that downloads its data, a bad ``f107`` or a missing IONEX file.
    """
    head, _, rest = text.partition(":")
    if head == "ionex":
        files = [Path(p) for p in rest.split(",") if p]
        missing = [str(p) for p in files if not p.is_file()]
        if not files or missing:
            raise InputError(f"ionosphere {text!r}: no IONEX file {', '.join(missing)}; give "
                             "ionex:PATH with local IONEX maps (e.g. CODG or UQRG files from "
                             "CDDIS) covering the observation", param="ionosphere")
        return {"tec": "ionex", "files": files}
    if rest in ("", "iri"):
        return {"tec": "iri", "f107": IRI_F107}
    if rest.startswith("f107="):
        try:
            f107 = float(rest[5:])
        except ValueError:
            f107 = float("nan")
        if not 0 < f107 < 1000:
            raise InputError(f"ionosphere {text!r}: f107 must be a solar flux in sfu, e.g. "
                             "spinifex:f107=120", param="ionosphere")
        return {"tec": "iri", "f107": f107}
    if rest in _DOWNLOADING:
        raise InputError(f"ionosphere {text!r}: spinifex downloads these maps and msleak runs "
                         "offline; download an IONEX file yourself and give ionex:PATH, or "
                         "use spinifex (IRI, offline)", param="ionosphere")
    raise InputError(f"ionosphere {text!r}: give spinifex, spinifex:f107=SFU or ionex:PATH",
                     param="ionosphere")


def model_rotation_measures(spec: str, ms: str | os.PathLike, *,
                            step_s: float = SAMPLE_STEP_S) -> RotationMeasures:
    """RMs per used station of ``ms`` towards each field's phase centre, sampled every
    ``step_s`` seconds over that field's times, from the model ``spec``
    (:func:`parse_model_spec`). Labelled ``spinifex:iri,f107=...`` or ``ionex:FILES``.

    Raises
    ------
    InputError
        A bad spec, fields observed at overlapping times, times outside the IONEX maps.
    ConfigurationError
        spinifex is not installed.
    """
    model = parse_model_spec(spec)
    _import_spinifex()
    antennas = read_antennas(ms)
    used = read_used_antennas(ms)
    names = [antennas.names[k] for k in used]
    samples, rms, last_end = [], [], -np.inf
    fields = [(read_times(ms, field_id=k), fld) for k, fld in enumerate(read_fields(ms))]
    for times, fld in sorted((f for f in fields if f[0].size), key=lambda f: f[0][0]):
        if times[0] <= last_end:
            raise InputError(f"{ms}: fields observed at overlapping times; the RM model "
                             "follows one direction at a time: split the MS by field")
        last_end = times[-1]
        grid = _sample_times(times, step_s)
        samples.append(grid)
        rms.append(station_rms(antennas.positions[used], grid, fld.ra, fld.dec, model))
    label = (f"spinifex:iri,f107={model['f107']:g}" if model["tec"] == "iri"
             else "ionex:" + ",".join(p.name for p in model["files"]))
    return RotationMeasures(times=np.concatenate(samples), rm=np.concatenate(rms, axis=1),
                            stations=tuple(names), label=label)


def _sample_times(times: np.ndarray, step_s: float) -> np.ndarray:
    """Times every at most ``step_s`` from the first to the last of ``times`` (MJD s)."""
    n = max(int(np.ceil((times[-1] - times[0]) / step_s)), 1) + 1
    return np.unique(np.linspace(times[0], times[-1], n))


def station_rms(positions_itrf, times_mjd_s, ra: float, dec: float, model: dict,
                height_km: float = SHELL_HEIGHT_KM) -> np.ndarray:
    """RM (rad m^-2) (nstation, ntime) at ``times_mjd_s`` of the stations at
    ``positions_itrf`` (nstation, 3) m towards J2000 (``ra``, ``dec``) rad, through the
    shell at ``height_km``, with the model ``model`` (:func:`parse_model_spec`)."""
    pierce = pierce_points(positions_itrf, times_mjd_s, ra, dec, height_km)
    if model["tec"] == "iri":
        # one IRI column per time, at the stations' mean pierce point: IRI's F1 layer is
        # switched on by a threshold, which makes TEC jump by up to ~10 % between stations
        # a few km apart (an artefact, not structure)
        lon, lat = mean_pierce_point(pierce)
        tec = vertical_tec(lon, lat, times_mjd_s, model)[None, :]
    else:
        tec = vertical_tec(pierce.lon_deg, pierce.lat_deg, times_mjd_s, model)
    return thin_shell_rm(tec, pierce.airmass, b_along_los(pierce))


def mean_pierce_point(pierce: PiercePoints) -> tuple[np.ndarray, np.ndarray]:
    """(lon, lat) deg (ntime,) of the mean of the stations' pierce points (on the sphere)."""
    lon, lat = np.radians(pierce.lon_deg), np.radians(pierce.lat_deg)
    xyz = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)]).mean(1)
    return (np.degrees(np.arctan2(xyz[1], xyz[0])),
            np.degrees(np.arctan2(xyz[2], np.hypot(xyz[0], xyz[1]))))


def pierce_points(positions_itrf, times_mjd_s, ra: float, dec: float,
                  height_km: float = SHELL_HEIGHT_KM) -> PiercePoints:
    """spinifex's pierce points of the lines of sight from ``positions_itrf`` (nstation, 3)
    m, ITRF, to J2000 (``ra``, ``dec``) rad at ``times_mjd_s`` (UTC) through the shell at
    ``height_km``. The direction is converted once, at the stations' centre (a few km
    change it by far less than 1e-6 rad)."""
    import astropy.units as u
    from astropy.coordinates import ITRS, AltAz, EarthLocation, SkyCoord
    from astropy.utils import iers
    from spinifex.geometry.get_ipp import get_ipp_from_itrs

    positions = np.atleast_2d(np.asarray(positions_itrf, dtype=float))
    times = _utc(np.atleast_1d(times_mjd_s))
    centre = EarthLocation.from_geocentric(*positions.mean(axis=0), unit=u.m)
    with iers.conf.set_temp("auto_download", False):     # nothing downloaded at run time
        los = SkyCoord(ra * u.rad, dec * u.rad, frame="icrs").transform_to(
            ITRS(obstime=times, location=centre))
        altaz = los.transform_to(AltAz(obstime=times, location=centre))
    if np.any(altaz.alt.deg <= 0):
        raise InputError(f"the phase centre is below the horizon at some time (lowest "
                         f"elevation {np.min(altaz.alt.deg):.1f} deg): no ionospheric "
                         "pierce point", param="ionosphere")
    parts = [get_ipp_from_itrs(EarthLocation.from_geocentric(*p, unit=u.m), times, los,
                               np.array([height_km]) * u.km, altaz=altaz) for p in positions]
    ipp = parts[0]._replace(
        lon=np.concatenate([q.lon for q in parts]), lat=np.concatenate([q.lat for q in parts]),
        height=np.concatenate([q.height for q in parts]),
        times=_utc(np.tile(np.atleast_1d(times_mjd_s), len(parts))),
        los=np.concatenate([q.los for q in parts]),
        airmass=np.concatenate([q.airmass for q in parts]))
    shape = (len(parts), times.size)
    return PiercePoints(lon_deg=ipp.lon.to_value(u.deg).reshape(shape),
                        lat_deg=ipp.lat.to_value(u.deg).reshape(shape),
                        airmass=np.asarray(ipp.airmass, dtype=float).reshape(shape), ipp=ipp)


def b_along_los(pierce: PiercePoints) -> np.ndarray:
    """IGRF field (T) at the pierce points along the line of sight towards the source
    (spinifex's ppigrf model), (nstation, ntime)."""
    from spinifex.magnetic.models import magnetic_models

    field = magnetic_models.ppigrf(ipp=pierce.ipp).magnetic_field
    return np.asarray(field.to_value("T"), dtype=float).reshape(pierce.lon_deg.shape)


def vertical_tec(lon_deg, lat_deg, times_mjd_s, model: dict) -> np.ndarray:
    """Vertical electron column (m^-2) at the points (``lon_deg``, ``lat_deg``) at
    ``times_mjd_s``, all of one shape, from IRI or the IONEX maps of ``model``."""
    lon, lat = np.asarray(lon_deg, dtype=float), np.asarray(lat_deg, dtype=float)
    times = np.broadcast_to(np.asarray(times_mjd_s, dtype=float), lon.shape)
    if model["tec"] == "iri":
        tecu = _iri_tec(lon.ravel(), lat.ravel(), times.ravel(), model["f107"])
    else:
        tecu = _ionex_tec(lon.ravel(), lat.ravel(), times.ravel(), model["files"])
    return tecu.reshape(lon.shape) * 1e16


def _iri_tec(lon, lat, times, f107: float) -> np.ndarray:
    """IRI vertical TEC (TECU) per point, one PyIRI evaluation per distinct time."""
    from PyIRI import coeff_dir
    from PyIRI.main_library import IRI_density_1day, edp_to_vtec

    out = np.empty(lon.size)
    for t in np.unique(times):
        sel = times == t
        year, month, day, hour, minute, second = _utc(t).ymdhms
        ut = np.array([hour + minute / 60.0 + second / 3600.0])
        edp = IRI_density_1day(int(year), int(month), int(day), ut, lon[sel], lat[sel],
                               IRI_HEIGHTS_KM, f107, coeff_dir, 0)[-1]
        out[sel] = edp_to_vtec(edp, IRI_HEIGHTS_KM)[0]
    return out


def _ionex_tec(lon, lat, times, files: list[Path]) -> np.ndarray:
    """Vertical TEC (TECU) interpolated from the IONEX maps of ``files`` (spinifex's reader
    and interpolation, Earth rotation included), each point from a file that covers it."""
    from spinifex.exceptions import IonexError
    from spinifex.ionospheric.ionex_manipulation import interpolate_ionex
    from spinifex.ionospheric.ionex_parser import read_ionex
    from spinifex.ionospheric.tec_data import IonexOptions

    out = np.full(lon.size, np.nan)
    mjd = times / 86400.0
    for path in files:
        try:
            maps = read_ionex(path, options=IonexOptions(prefix="", correct_uqrg_rms=False))
        except (IonexError, OSError, ValueError, UnicodeDecodeError, IndexError) as err:
            raise InputError(f"{path}: not a readable IONEX file ({err})",
                             param="ionosphere") from None
        sel = np.isnan(out) & (mjd >= maps.times.mjd[0]) & (mjd <= maps.times.mjd[-1])
        if np.any(sel):
            out[sel] = interpolate_ionex(maps, lon[sel], lat[sel], _utc(times[sel]))
    if np.any(np.isnan(out)):
        span = ", ".join(str(p.name) for p in files)
        raise InputError(f"the IONEX maps {span} do not cover the observation at "
                         f"{_utc(times[np.isnan(out)][0]).isot} UTC: give the maps of every "
                         "day it spans, ionex:PATH1,PATH2", param="ionosphere")
    return out


def _utc(times_mjd_s):
    from astropy.time import Time

    return Time(np.asarray(times_mjd_s, dtype=float) / 86400.0, format="mjd", scale="utc")


def _import_spinifex() -> None:
    """Check that spinifex is installed, and keep its INFO log lines off the terminal."""
    try:
        import spinifex  # noqa: F401
    except ImportError as err:
        raise ConfigurationError(f"the spinifex ionosphere needs spinifex ({err}): pip "
                                 "install 'msleak[ionosphere]'") from None
    logging.getLogger("spinifex").setLevel(logging.WARNING)
