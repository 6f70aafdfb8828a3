"""The ``beam_maps`` verb (``msleak beam``): beam maps of an MS at several hour angles.

:func:`beam_maps` (``msleak.beam_maps``) plans the maps of an MS (stations, times,
frequency, feeds), loads its beam (:func:`msleak.adapters.beams.load_beam`), computes
them with :func:`msleak.beam.maps.mueller_maps` and writes the ``beam`` product
(docs/beam.md).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import xarray as xr

from msleak.adapters.beams import beam_options, load_beam
from msleak.beam.maps import BASES, MAP_BEAMS, Basis, default_times, mueller_maps
from msleak.conventions import feed_type_from_corr_types
from msleak.errors import InputError
from msleak.io.measures import hour_angle_h
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
from msleak.io.products import call_record, save_product, stamp

__all__ = ["beam_maps", "times_for_hour_angles", "SIDEREAL_RATIO"]

log = logging.getLogger(__name__)

#: sidereal days per solar day
SIDEREAL_RATIO = 1.00273790935


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
        raise InputError(f"{output} exists; choose another name or pass overwrite",
                         param="overwrite")
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
        raise InputError(f"fov must be between 0 and 180 degrees, got {fov}", param="fov")
    if int(npix) != npix or not 2 <= npix <= 2049:
        raise InputError(f"npix must be an integer between 2 and 2049, got {npix}", param="npix")
    if freq is not None and not freq > 0:
        raise InputError(f"freq must be positive (Hz), got {freq}", param="freq")
    if beam not in MAP_BEAMS:
        raise InputError(f"unknown beam {beam!r}: use one of {', '.join(MAP_BEAMS)}",
                         param="beam")
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
                f"station {station!r} is not an antenna of the rows of field {field_id} "
                f"of {ms} (they are {', '.join(names[:6])}{', ...' if len(names) > 6 else ''})",
                param="station")
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
        raise InputError(f"{ms} has no rows, so no date for hour_angles", param="hour_angles")
    has = np.asarray(hour_angles, dtype=float)
    return times_for_hour_angles(has, ra0, position, float(np.median(times))), has


def _ms_history(ms: Path) -> list[str]:
    """The HISTORY rows of ``ms``, one line each, prefixed with the MS."""
    return [f"{Path(ms).resolve()} HISTORY {line}" for line in read_history(ms)]


def times_for_hour_angles(hour_angles_h, ra: float, position_itrf, reference_time: float
                          ) -> np.ndarray:
    """Times (MJD s) nearest ``reference_time`` at which ``ra`` has the given hour angles."""
    ha_ref = hour_angle_h([reference_time], ra, position_itrf)[0]
    out = []
    for h in np.atleast_1d(hour_angles_h):
        dh = (float(h) - ha_ref + 12) % 24 - 12
        out.append(reference_time + dh * 3600 / SIDEREAL_RATIO)
    return np.array(out)
