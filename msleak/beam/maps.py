"""Beam maps: Mueller figures of merit of a beam model over a field at several times.

:func:`mueller_maps` computes them on a SIN grid (:func:`sin_grid`) about the phase
centre: station-averaged, phase-centre-corrected auto-correlation Mueller matrices, the
polarized beam ``sqrt(M11^2 + M22^2)`` relative to the phase centre and the leakage
``sqrt(M01^2 + M02^2) / M00`` (docs/beam.md). The verb that reads an MS and writes them is
:func:`msleak.verbs.beam_maps.beam_maps` (``msleak beam``).
"""

from __future__ import annotations

from typing import Literal, get_args

import numpy as np
import xarray as xr

from msleak.beam.base import BeamModel
from msleak.beam.coords import basis_rotation, lm_to_radec, transport_angle
from msleak.beam.mueller import (
    jones_to_mueller,
    leakage,
    polarized_beam,
    polarized_beam_invariant,
    to_db,
)
from msleak.conventions import STOKES_CONVENTION, FeedType
from msleak.errors import InputError

__all__ = ["BASES", "Basis", "MAP_BEAMS", "BASIS_DESCRIPTIONS", "sin_grid", "default_times",
           "mueller_maps"]

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


def default_times(times_mjd_s: np.ndarray, n: int = 5) -> np.ndarray:
    """``n`` times evenly spread from the first to the last time of an observation."""
    times = np.asarray(times_mjd_s, dtype=float)
    if times.size == 0:
        raise InputError("the MS has no rows (no TIME values)")
    return np.linspace(times.min(), times.max(), n) if times.size > 1 else times[:1]


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


