"""Beam maps (``msleak beam``): Mueller figures of merit over a field at several hour angles.

:func:`beam_maps` (``msleak.beam_maps``) plans the maps of an MS (stations, times,
frequency, feeds) and :func:`mueller_maps` computes them from a beam model on a SIN grid
about the phase centre: station-averaged, phase-centre-corrected auto-correlation Mueller
matrices, the polarized beam ``sqrt(M11^2 + M22^2)`` relative to the phase centre and the
leakage ``sqrt(M01^2 + M02^2) / M00`` (docs/beam.md).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Sequence, get_args

import numpy as np
import xarray as xr

from msleak.beam import beam_options, load_beam
from msleak.beam.base import BeamModel
from msleak.beam.coords import basis_rotation, lm_to_radec, transport_angle
from msleak.beam.mueller import (
    jones_to_mueller,
    leakage,
    polarized_beam,
    polarized_beam_invariant,
    to_db,
)
from msleak.conventions import STOKES_CONVENTION, FeedType, feed_type_from_corr_types
from msleak.errors import InputError
from msleak.io.ms import (
    check_ms,
    read_antennas,
    read_corr_types,
    read_data_descriptions,
    read_fields,
    read_history,
    read_spectral_windows,
    read_times,
    read_used_antennas,
    resolve_field,
)
from msleak.io.measures import set_epoch
from msleak.io.products import call_record, save_product, stamp

__all__ = ["BASES", "Basis", "MAP_BEAMS", "sin_grid", "hour_angle_h", "times_for_hour_angles",
           "default_times", "mueller_maps", "beam_maps", "SIDEREAL_RATIO"]

log = logging.getLogger(__name__)

Basis = Literal["tangent", "local"]
#: Q,U reference frames of beam maps (see :func:`mueller_maps`)
BASES: tuple = get_args(Basis)
#: beam models ``msleak beam`` maps
MAP_BEAMS = ("everybeam", "everybeam-direct", "uvbeam", "hyperbeam", "dipole")
BASIS_DESCRIPTIONS = {
    "tangent": "Q,U in the phase centre's (North, East) basis parallel-transported along "
               "great circles to each pixel",
    "local": "Q,U in each pixel's own (North, East) basis",
}

#: sidereal days per solar day
SIDEREAL_RATIO = 1.00273790935


def sin_grid(ra0: float, dec0: float, fov_deg: float, npix: int):
    """J2000 directions of an ``npix`` x ``npix`` SIN-projection grid about (ra0, dec0).

    Returns
    -------
    l_deg, m_deg : (npix,) arrays
        Direction cosines (East, North) in degrees (``degrees(l)``).
    ra, dec : (npix, npix) arrays
        rad, indexed ``[m, l]``.
    """
    if not 0 < fov_deg < 180:
        raise InputError(f"field of view must be between 0 and 180 deg, got {fov_deg}")
    if npix < 2:
        raise InputError(f"need at least 2 pixels per side, got {npix}")
    half = np.sin(np.radians(fov_deg / 2))
    lin = np.linspace(-half, half, npix)
    ra, dec = lm_to_radec(*np.meshgrid(lin, lin), ra0, dec0)
    return np.degrees(lin), np.degrees(lin), ra, dec


def hour_angle_h(times_mjd_s, ra: float, position_itrf) -> np.ndarray:
    """Hour angle (h, in [-12, 12)) of right ascension ``ra`` at ``position_itrf`` (casacore LAST)."""
    from casacore.measures import measures
    from casacore.quanta import quantity

    dm = measures()
    x, y, z = (float(c) for c in position_itrf)
    dm.do_frame(dm.position("ITRF", f"{x!r}m", f"{y!r}m", f"{z!r}m"))
    out = []
    for t in np.atleast_1d(times_mjd_s):
        set_epoch(dm, t)
        last = dm.measure(dm.epoch("UTC", quantity(float(t), "s")), "LAST")["m0"]["value"]
        lst_h = (last % 1.0) * 24
        out.append((lst_h - np.degrees(ra) / 15 + 12) % 24 - 12)
    return np.array(out)


def default_times(times_mjd_s: np.ndarray, n: int = 5) -> np.ndarray:
    """``n`` times evenly spread from the first to the last time of an observation."""
    times = np.asarray(times_mjd_s, dtype=float)
    if times.size == 0:
        raise InputError("the MS has no rows (no TIME values)")
    return np.linspace(times.min(), times.max(), n) if times.size > 1 else times[:1]


def times_for_hour_angles(hour_angles_h, ra: float, position_itrf, reference_time: float
                          ) -> np.ndarray:
    """Times (MJD s) nearest ``reference_time`` at which ``ra`` has the given hour angles."""
    ha_ref = hour_angle_h([reference_time], ra, position_itrf)[0]
    out = []
    for h in np.atleast_1d(hour_angles_h):
        dh = (float(h) - ha_ref + 12) % 24 - 12
        out.append(reference_time + dh * 3600 / SIDEREAL_RATIO)
    return np.array(out)


def mueller_maps(model: BeamModel, times_mjd_s, freq_hz: float, *, fov: float = 15.0,
                 npix: int = 61, feed: FeedType = "linear", stations=None, hour_angles=None,
                 basis: Basis = "tangent") -> xr.Dataset:
    """Polarized-beam and leakage maps of ``model`` at several times.

    Parameters
    ----------
    model : BeamModel
    times_mjd_s : (ntime,) array
        UTC, MJD seconds.
    freq_hz : float
    fov, npix : float, int
        Map width (deg, SIN projection) and pixels per side.
    feed : {'linear', 'circular'}
    stations : int array, optional
        Stations whose Mueller matrices are averaged (default ``model.used_stations``).
    hour_angles : (ntime,) array, optional
        Hour angles to label the maps with (h).
    basis : {'tangent', 'local'}
        Q,U frame: the phase centre's (North, East) basis parallel-transported to every
        pixel (one frame for the map), or each pixel's own (docs/beam.md).

    Returns
    -------
    xarray.Dataset
        The ``beam`` product (docs/beam.md): maps (hour_angle, m, l), ``mueller``
        (hour_angle, m, l, 4, 4), coordinates ``hour_angle`` (h), ``time`` (MJD s),
        ``l``, ``m``, ``ra``, ``dec`` (deg).
    """
    times = np.atleast_1d(np.asarray(times_mjd_s, dtype=float))
    if basis not in BASES:
        raise InputError(f"unknown Q,U basis {basis!r}: use {' or '.join(BASES)}")
    ra0, dec0 = model.phase_centre
    l_deg, m_deg, ra, dec = sin_grid(ra0, dec0, fov, npix)
    turn = (basis_rotation(transport_angle(ra0, dec0, ra.ravel(), dec.ravel()))
            if basis == "tangent" else None)
    mueller = np.empty((times.size, npix, npix, 4, 4))
    for it, t in enumerate(times):
        j = model.jones([t], [freq_hz], ra.ravel(), dec.ravel(), stations=stations,
                        centre_correction=True)[:, 0, 0]           # (nstation, ndir, 2, 2)
        if turn is not None:
            j = j @ turn
        m = np.real(jones_to_mueller(j, feed=feed)).mean(axis=0)  # (ndir, 4, 4)
        mueller[it] = m.reshape(npix, npix, 4, 4)
    # the phase centre itself (after correction M = I there, so pb0 = sqrt 2)
    pb0 = polarized_beam(np.real(jones_to_mueller(
        model.jones(times, [freq_hz], [ra0], [dec0], stations=stations,
                    centre_correction=True)[:, :, 0, 0], feed=feed)).mean(axis=0))
    if not np.all(pb0 > 0):
        raise InputError("the beam is zero at the phase centre at some of the times "
                         "(source below the horizon?); choose other hour angles")
    if hour_angles is None:
        hour_angles = np.full(times.size, np.nan)
    ds = _maps_dataset(mueller, pb0, times, np.asarray(hour_angles, float), l_deg, m_deg,
                       ra, dec)
    centre = np.unravel_index(np.argmin(l_deg[None, :] ** 2 + m_deg[:, None] ** 2), ra.shape)
    ds.attrs.update({
        "beam": model.name, "freq_hz": float(freq_hz), "fov_deg": float(fov),
        "npix": int(npix), "feed": feed, "projection": "SIN about the phase centre",
        "qu_basis": basis, "qu_basis_description": BASIS_DESCRIPTIONS[basis],
        "phase_centre_ra_deg": float(np.degrees(ra0)),
        "phase_centre_dec_deg": float(np.degrees(dec0)),
        "centre_pixel": f"{centre[0]},{centre[1]}",
        "stations": ",".join(model.station_names[int(s)] for s in (
            model.used_stations if stations is None else np.atleast_1d(stations))),
        "normalisation": "J(s0)^-1 J(s) per station; Mueller matrices averaged over "
                         "stations; dB = 10 log10",
        "db_floor": -100.0,
        "stokes_convention": STOKES_CONVENTION,
    })
    return ds


def _maps_dataset(mueller, pb0, times, hour_angles, l_deg, m_deg, ra, dec) -> xr.Dataset:
    """The map variables and coordinates of a beam product (attributes added by the caller)."""
    pb = polarized_beam(mueller)
    pbi = polarized_beam_invariant(mueller)
    leak = leakage(mueller)
    norm = pb0[:, None, None]
    dims = ("hour_angle", "m", "l")
    db = {"units": "dB", "definition": "10 log10"}
    return xr.Dataset(
        {
            "polarized_beam": (dims, pb / norm, {
                "long_name": "polarized beam sqrt(M11^2+M22^2) relative to the phase centre",
                "units": "1"}),
            "polarized_beam_invariant": (dims, pbi / norm, {
                "long_name": "sqrt(M11^2+M12^2+M21^2+M22^2) relative to the phase centre "
                             "(independent of the Q,U reference frame)", "units": "1"}),
            "polarized_beam_invariant_db": (dims, to_db(pbi, norm), db),
            "leakage": (dims, leak, {"long_name": "Q,U -> I leakage sqrt(M01^2+M02^2)/M00",
                                     "units": "1"}),
            "polarized_beam_db": (dims, to_db(pb, norm), db),
            "leakage_db": (dims, to_db(leak), db),
            "mueller": (dims + ("mueller_row", "mueller_col"), mueller, {
                "long_name": "station-averaged auto-correlation Mueller matrix "
                             "(phase-centre corrected), Stokes I,Q,U,V order",
                "units": "1"}),
        },
        coords={
            "hour_angle": ("hour_angle", hour_angles, {"units": "h"}),
            "time": ("hour_angle", times, {"units": "s", "long_name": "UTC, MJD seconds"}),
            "l": ("l", l_deg, {"units": "deg", "long_name": "direction cosine towards East"}),
            "m": ("m", m_deg, {"units": "deg", "long_name": "direction cosine towards North"}),
            "ra": (("m", "l"), np.degrees(ra), {"units": "deg"}),
            "dec": (("m", "l"), np.degrees(dec), {"units": "deg"}),
        },
    )


def beam_maps(ms: str | os.PathLike, *, fov: float = 15.0, npix: int = 61,
              hour_angles: Sequence[float] | None = None, freq: float | None = None,
              beam: str = "everybeam", station: str | None = None,
              diameter: float | None = None, element_model: str | None = None,
              beam_file: str | os.PathLike | None = None, invariant: bool = False,
              basis: Basis = "tangent", field: int | str | None = None,
              output: str | os.PathLike | None = None, overwrite: bool = False) -> xr.Dataset:
    """Polarized-beam and leakage maps of the station beams of ``ms`` (``msleak beam``).

    Parameters
    ----------
    ms : path
        Measurement Set.
    fov, npix : float, int
        Map width (deg, SIN projection about the phase centre) and pixels per side.
    hour_angles : sequence of float, optional
        Hour angles (h) of the phase centre, at the times nearest the middle of the
        observation; default 5 times spread over the rows of the field.
    freq : float, optional
        Hz; default the middle channel of the first spectral window.
    beam : {'everybeam', 'everybeam-direct', 'uvbeam', 'hyperbeam', 'dipole'}
    station : str, optional
        One ANTENNA name; default the Mueller matrices of the field's stations averaged.
    diameter, element_model, beam_file : optional
        Settings of the beam model, as in :func:`msleak.predict`.
    invariant : bool
        Recorded for the figure (attribute ``invariant``): plot the Q,U-frame-invariant
        polarized beam; the product holds both.
    basis : {'tangent', 'local'}
        Q,U frame of the maps (docs/beam.md).
    field : int or str, optional
        FIELD id or name giving the phase centre, pointing and rows; default 0.
    output : path, optional
        Also write the ``beam`` product there (refused if it exists, unless ``overwrite``).

    Returns
    -------
    xarray.Dataset
        The ``beam`` product: maps (hour_angle, m, l), ``mueller`` (hour_angle, m, l, 4, 4)
        (docs/beam.md).
    """
    command = call_record(beam_maps, dict(locals()))
    _check_options(fov, npix, freq, beam, basis)
    options = beam_options(beam, diameter=diameter, element_model=element_model,
                           beam_file=beam_file)
    if output is not None and Path(output).exists() and not overwrite:
        raise InputError(f"{output} exists; choose another name or pass --overwrite")
    ms = check_ms(ms)
    field_id = 0 if field is None else resolve_field(ms, field)
    plan = _plan(ms, field_id, station, freq)
    model = load_beam(beam, ms, field_id=field_id, stations=plan.stations, **options)
    times, has = _map_times(ms, field_id, hour_angles, model.phase_centre[0], plan.position)
    log.info("beam maps of %s (%s) at %.3f MHz, hour angles %s h", ms, model.name,
             plan.freq / 1e6, ", ".join(f"{h:+.2f}" for h in has))
    ds = mueller_maps(model, times, plan.freq, fov=fov, npix=npix, feed=plan.feed,
                      hour_angles=has, basis=basis)
    ds.attrs.update(source=str(ms), field_id=field_id, field_name=plan.field_name,
                    invariant=int(bool(invariant)),
                    )
    ds = stamp(ds, command, _ms_history(ms))
    if output is not None:
        save_product(ds, output, "beam", overwrite=overwrite)
    return ds


def _check_options(fov, npix, freq, beam, basis) -> None:
    """The option errors of ``msleak beam``, before any work."""
    if not 0 < fov < 180:
        raise InputError(f"--fov must be between 0 and 180 degrees, got {fov}")
    if int(npix) != npix or not 2 <= npix <= 2049:
        raise InputError(f"--npix must be an integer between 2 and 2049, got {npix}")
    if freq is not None and not freq > 0:
        raise InputError(f"--freq must be positive (Hz), got {freq}")
    if beam not in MAP_BEAMS:
        raise InputError(f"unknown --beam {beam!r}: use one of {', '.join(MAP_BEAMS)}")
    if basis not in BASES:
        raise InputError(f"unknown Q,U basis {basis!r}: use {' or '.join(BASES)}")


@dataclass(frozen=True)
class _Plan:
    stations: np.ndarray      # ANTENNA rows averaged
    position: np.ndarray      # ITRF array centre (m) of the field's stations
    freq: float               # Hz
    feed: str
    field_name: str


def _plan(ms: Path, field_id: int, station: str | None, freq: float | None) -> _Plan:
    """Stations, array centre, frequency and feed type of the maps of FIELD ``field_id``."""
    antennas = read_antennas(ms)
    in_rows = read_used_antennas(ms, field_id=field_id)
    used = in_rows
    if station is not None:
        names = [antennas.names[i] for i in in_rows]
        if station not in names:
            raise InputError(
                f"--station {station!r} is not an antenna of the rows of field {field_id} "
                f"of {ms} (they are {', '.join(names[:6])}{', ...' if len(names) > 6 else ''})")
        used = in_rows[[names.index(station)]]
    ddid = read_data_descriptions(ms)
    spw, pol = ddid[0] if ddid else (0, 0)
    if freq is None:
        channels = read_spectral_windows(ms)[spw].freq
        freq = float(channels[channels.size // 2])
    return _Plan(stations=used, position=antennas.positions[in_rows].mean(axis=0),
                 freq=float(freq), feed=feed_type_from_corr_types(read_corr_types(ms)[pol]),
                 field_name=read_fields(ms)[field_id].name)


def _map_times(ms: Path, field_id: int, hour_angles, ra0: float, position):
    """(times in MJD s, hour angles in h) of the maps."""
    times = read_times(ms, field_id=field_id)
    if hour_angles is None or len(hour_angles) == 0:
        times = default_times(times)
        return times, hour_angle_h(times, ra0, position)
    if times.size == 0:
        raise InputError(f"{ms} has no rows, so no date for --hour-angles")
    has = np.asarray(hour_angles, dtype=float)
    return times_for_hour_angles(has, ra0, position, float(np.median(times))), has


def _ms_history(ms: Path) -> list[str]:
    """The HISTORY rows of ``ms``, one line each, prefixed with the MS."""
    return [f"{Path(ms).resolve()} HISTORY {line}" for line in read_history(ms)]
