"""Beam maps for ``msleak beam``: Mueller figures of merit over a field at several hour angles.

The map grid is a square in the SIN (orthographic) projection about the phase centre:
``l`` (towards East) and ``m`` (towards North) from ``-fov/2`` to ``+fov/2`` in direction
cosines expressed in degrees.  At each time the phase-centre-corrected Jones matrices of
the selected stations give auto-correlation Mueller matrices ``M_pp``
(:func:`msleak.beam.mueller.jones_to_mueller`), averaged over the stations, with Q and U
in one basis for the whole map by default (the phase centre's, parallel-transported); the
maps are the
polarized beam ``sqrt(M11^2 + M22^2)`` relative to its phase-centre value and the leakage
``sqrt(M01^2 + M02^2) / M00``, linear and in dB.
"""

from __future__ import annotations

import logging
from typing import Literal, get_args

import numpy as np

from msleak.beam.base import BeamModel
from msleak.beam.coords import basis_rotation, transport_angle
from msleak.beam.mueller import (jones_to_mueller, leakage, polarized_beam,
                                 polarized_beam_invariant, to_db)
from msleak.conventions import STOKES_CONVENTION, FeedType
from msleak.errors import InputError

__all__ = ["BASES", "Basis", "sin_grid", "hour_angle_h", "times_for_hour_angles", "default_times", "beam_maps",
           "SIDEREAL_RATIO"]

log = logging.getLogger(__name__)

Basis = Literal["tangent", "local"]
#: Q,U reference frames of beam maps (see :func:`beam_maps`)
BASES: tuple = get_args(Basis)
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
    ll, mm = np.meshgrid(lin, lin)
    nn = np.sqrt(np.clip(1 - ll ** 2 - mm ** 2, 0, None))
    dec = np.arcsin(np.clip(mm * np.cos(dec0) + nn * np.sin(dec0), -1, 1))
    ra = np.mod(ra0 + np.arctan2(ll, nn * np.cos(dec0) - mm * np.sin(dec0)), 2 * np.pi)
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


def beam_maps(beam: BeamModel, times_mjd_s, freq_hz: float, *, fov_deg: float = 15.0,
              npix: int = 61, feed: FeedType = "linear", stations=None, hour_angles_h=None,
              basis: Basis = "tangent"):
    """Polarized-beam and leakage maps at several times, as an :class:`xarray.Dataset`.

    Parameters
    ----------
    beam : BeamModel
    times_mjd_s : (ntime,) array
        UTC, MJD seconds.
    freq_hz : float
    fov_deg, npix : float, int
        Map size (deg, SIN projection) and pixels per side.
    feed : {'linear', 'circular'}
    stations : int array, optional
        Stations whose Mueller matrices are averaged (default ``beam.used_stations``, the
        antennas of the MS's rows).
    hour_angles_h : (ntime,) array, optional
        Hour angles to label the maps with (h).
    basis : {'tangent', 'local'}
        Q,U reference frame of the Mueller matrices: ``tangent``, the phase centre's
        (North, East) basis parallel-transported to every pixel (one frame for the whole
        map, so the pattern is the beam's even at a celestial pole); ``local``, each
        pixel's own (North, East) basis (docs/beam.md).

    Returns
    -------
    xarray.Dataset
        ``polarized_beam``, ``leakage``, ``polarized_beam_db``, ``leakage_db``
        (hour_angle, m, l) and ``mueller`` (hour_angle, m, l, mueller_row, mueller_col);
        coordinates ``hour_angle`` (h), ``time`` (MJD s), ``l``, ``m`` (deg), ``ra``,
        ``dec`` (deg, (m, l)).
    """
    import xarray as xr

    times = np.atleast_1d(np.asarray(times_mjd_s, dtype=float))
    ra0, dec0 = beam.phase_centre
    l_deg, m_deg, ra, dec = sin_grid(ra0, dec0, fov_deg, npix)
    centre = np.unravel_index(np.argmin(l_deg[None, :] ** 2 + m_deg[:, None] ** 2), ra.shape)
    if basis not in BASES:
        raise InputError(f"unknown Q,U basis {basis!r}: use {' or '.join(BASES)}")
    turn = (basis_rotation(transport_angle(ra0, dec0, ra.ravel(), dec.ravel()))
            if basis == "tangent" else None)
    mueller = np.empty((times.size, npix, npix, 4, 4))
    for it, t in enumerate(times):
        j = beam.jones([t], [freq_hz], ra.ravel(), dec.ravel(), stations=stations,
                       centre_correction=True)[:, 0, 0]           # (nstation, ndir, 2, 2)
        if turn is not None:
            j = j @ turn
        m = np.real(jones_to_mueller(j, feed=feed)).mean(axis=0)  # (ndir, 4, 4)
        mueller[it] = m.reshape(npix, npix, 4, 4)
    pb = polarized_beam(mueller)
    leak = leakage(mueller)
    # the phase centre itself (after correction M = I there, so pb0 = sqrt 2)
    pb0 = polarized_beam(np.real(jones_to_mueller(
        beam.jones(times, [freq_hz], [ra0], [dec0], stations=stations,
                   centre_correction=True)[:, :, 0, 0], feed=feed)).mean(axis=0))
    if not np.all(pb0 > 0):
        raise InputError("the beam is zero at the phase centre at some of the times "
                         "(source below the horizon?); choose other hour angles")
    pbi = polarized_beam_invariant(mueller)
    pb_db = to_db(pb, pb0[:, None, None])
    leak_db = to_db(leak)
    if hour_angles_h is None:
        hour_angles_h = np.full(times.size, np.nan)
    dims = ("hour_angle", "m", "l")
    ds = xr.Dataset(
        {
            "polarized_beam": (dims, pb / pb0[:, None, None], {
                "long_name": "polarized beam sqrt(M11^2+M22^2) relative to the phase centre",
                "units": "1"}),
            "polarized_beam_invariant": (dims, pbi / pb0[:, None, None], {
                "long_name": "sqrt(M11^2+M12^2+M21^2+M22^2) relative to the phase centre "
                             "(independent of the Q,U reference frame)", "units": "1"}),
            "polarized_beam_invariant_db": (dims, to_db(pbi, pb0[:, None, None]), {
                "units": "dB", "definition": "10 log10"}),
            "leakage": (dims, leak, {"long_name": "Q,U -> I leakage sqrt(M01^2+M02^2)/M00",
                                     "units": "1"}),
            "polarized_beam_db": (dims, pb_db, {"units": "dB", "definition": "10 log10"}),
            "leakage_db": (dims, leak_db, {"units": "dB", "definition": "10 log10"}),
            "mueller": (dims + ("mueller_row", "mueller_col"), mueller, {
                "long_name": "station-averaged auto-correlation Mueller matrix "
                             "(phase-centre corrected), Stokes I,Q,U,V order",
                "units": "1"}),
        },
        coords={
            "hour_angle": ("hour_angle", np.asarray(hour_angles_h, float), {"units": "h"}),
            "time": ("hour_angle", times, {"units": "s", "long_name": "UTC, MJD seconds"}),
            "l": ("l", l_deg, {"units": "deg", "long_name": "direction cosine towards East"}),
            "m": ("m", m_deg, {"units": "deg", "long_name": "direction cosine towards North"}),
            "ra": (("m", "l"), np.degrees(ra), {"units": "deg"}),
            "dec": (("m", "l"), np.degrees(dec), {"units": "deg"}),
        },
        attrs={
            "beam": beam.name,
            "freq_hz": float(freq_hz),
            "fov_deg": float(fov_deg),
            "npix": int(npix),
            "feed": feed,
            "projection": "SIN about the phase centre",
            "qu_basis": basis,
            "qu_basis_description": BASIS_DESCRIPTIONS[basis],
            "phase_centre_ra_deg": float(np.degrees(ra0)),
            "phase_centre_dec_deg": float(np.degrees(dec0)),
            "centre_pixel": f"{centre[0]},{centre[1]}",
            "stations": ",".join(beam.station_names[int(s)] for s in (
                beam.used_stations if stations is None else np.atleast_1d(stations))),
            "normalisation": "J(s0)^-1 J(s) per station; Mueller matrices averaged over "
                             "stations; dB = 10 log10",
            "db_floor": -100.0,
            "stokes_convention": STOKES_CONVENTION,
        },
    )
    return ds
