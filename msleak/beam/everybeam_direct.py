"""EveryBeam itself, one call per direction: the reference path (``everybeam-direct``).

Directions are converted to ITRF one by one with casacore (the frame EveryBeam uses), and
``PhasedArray.station_response(times, stations, freqs, direction, station0, tile0)`` gives
all stations and channels of one direction per call.  Telescopes whose bindings lack that
call (MWA, SKA-Mid, dishes) are evaluated with their per-(station, channel) call.
Near a celestial pole EveryBeam's sky basis ``normalize(ncp x d)`` is ill-conditioned
(any difference between two casacore conversions is divided by the distance to the pole).
For directions within :data:`POLE_BASIS_RAD` of a pole of a LOFAR MS this path therefore
asks EveryBeam for the unrotated response and applies the rotation to the limit of the
(North, East) basis along the direction's meridian, found from two exactly converted
points on that meridian either side of the pole (:func:`pole_basis`).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from msleak._everybeam import import_everybeam
from msleak.beam.base import BeamModel
from msleak.beam.coords import clip_pole, exact_j2000_to_itrf
from msleak.beam.lofar_tables import NO_LOFAR_HINT
from msleak.errors import InputError

__all__ = ["EveryBeamDirect", "load_everybeam_telescope", "pole_basis", "POLE_BASIS_RAD"]

#: Directions closer than this to a pole (rad) get the meridian-limit sky basis.
POLE_BASIS_RAD = 1e-6

log = logging.getLogger(__name__)


def load_everybeam_telescope(ms: str | os.PathLike, element_model: str = "default"):
    """``everybeam.load_telescope`` with no normalisation; InputError naming --beam dipole."""
    eb = import_everybeam()
    try:
        return eb.load_telescope(str(ms), use_differential_beam=False,
                                 element_response_model=element_model)
    except RuntimeError as err:
        text = " ".join(str(err).split())[:160]
        raise InputError(f"{ms}: EveryBeam cannot make a beam for this MS ({text}); "
                         f"{NO_LOFAR_HINT}") from err


class EveryBeamDirect(BeamModel):
    """Station beams from EveryBeam's Python bindings, one direction per call (slow).

    Parameters
    ----------
    ms : path
        The Measurement Set EveryBeam loads.
    element_model : str
        EveryBeam element response model (``default`` = Hamaker for LOFAR).
    """

    name = "everybeam-direct"

    def __init__(self, ms: str | os.PathLike, element_model: str = "default"):
        from msleak.io.ms import read_antennas, read_fields

        self.telescope = load_everybeam_telescope(ms, element_model)
        antennas = read_antennas(ms)
        field = read_fields(ms)[0]
        super().__init__(self.telescope.nr_stations, (field.ra, field.dec),
                         list(antennas.names))
        self.ms = Path(ms)
        self._delay, self._tile = self._read_beam_dirs(ms, (field.ra, field.dec))
        self._axes = self._station_axes(ms)

    @staticmethod
    def _station_axes(ms):
        """Per station the common axes (3, 3) of its LOFAR fields, or None."""
        from msleak.beam.lofar_tables import read_lofar_array

        try:
            array = read_lofar_array(ms)
        except InputError:
            return None
        out = []
        for s in array.stations:
            axes = [f.axes for f in s.fields]
            same = all(np.allclose(a, axes[0], atol=1e-12) for a in axes)
            out.append(axes[0] if same else None)
        return out

    @staticmethod
    def _read_beam_dirs(ms, default):
        from msleak.io.ms import open_table

        with open_table(Path(ms) / "FIELD") as t:
            cols = t.colnames()
            delay = np.asarray(t.getcell("DELAY_DIR", 0), float).reshape(-1, 2)[0] \
                if "DELAY_DIR" in cols else np.asarray(default)
            tile = np.asarray(t.getcell("LOFAR_TILE_BEAM_DIR", 0), float).reshape(-1, 2)[0] \
                if "LOFAR_TILE_BEAM_DIR" in cols else delay
        return (float(delay[0]), float(delay[1])), (float(tile[0]), float(tile[1]))

    def _jones(self, time, freq, ra, dec, stations, dtype):
        tel = self.telescope
        out = np.zeros((stations.size, time.size, freq.size, ra.size, 2, 2), complex)
        near_pole = np.pi / 2 - np.abs(dec) < POLE_BASIS_RAD
        dec = clip_pole(dec)
        vector_call = hasattr(tel, "array_factor")  # PhasedArray (LOFAR, OSKAR)
        pole_fix = vector_call and self._axes is not None and all(
            self._axes[s] is not None for s in stations)
        for it, t in enumerate(time):
            t = float(t)
            d = exact_j2000_to_itrf(t, ra, dec)
            s0 = exact_j2000_to_itrf(t, self._delay[0], clip_pole(self._delay[1]))[0]
            t0 = exact_j2000_to_itrf(t, self._tile[0], clip_pole(self._tile[1]))[0]
            for k in range(ra.size):
                if vector_call and pole_fix and near_pole[k]:
                    out[:, it, :, k] = self._pole_response(t, stations, freq, ra[k], dec[k],
                                                           d[k], s0, t0)
                elif vector_call:
                    r = tel.station_response(np.array([t]), stations.astype(np.uint64),
                                             freq, d[k], s0, t0)
                    out[:, it, :, k] = np.asarray(r)[0]
                else:
                    for si, s in enumerate(stations):
                        for c, f in enumerate(freq):
                            out[si, it, c, k] = self._single(tel, t, int(s), float(f),
                                                             d[k], ra[k], dec[k])
        # EveryBeam's element models are zero below the horizon; never hand out NaN
        out[~np.isfinite(out)] = 0
        return out.astype(dtype, copy=False)

    def _pole_response(self, t, stations, freq, ra, dec, d, s0, t0):
        from msleak.beam.lofar_fast import sky_rotation

        raw = np.asarray(self.telescope.station_response(
            np.array([t]), stations.astype(np.uint64), freq, d, s0, t0, False))[0]
        north, east = pole_basis(t, ra, dec, d)
        out = np.empty_like(raw)
        for si, s in enumerate(stations):
            rot = sky_rotation(self._axes[s], d[None], north[None], east[None])[0]
            out[si] = raw[si] @ rot
        return out

    @staticmethod
    def _single(tel, t, s, f, d, ra, dec):
        try:
            return np.asarray(tel.station_response(t, s, f, d))
        except TypeError:
            return np.asarray(tel.station_response(t, s, f, float(ra), float(dec)))


def pole_basis(time_mjd_s: float, ra: float, dec: float, d: np.ndarray,
               delta: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """Sky (north, east) ITRF unit vectors at a direction ``d`` next to a celestial pole.

    The limit of the basis along the meridian ``ra``: ``north`` is the chord between the
    exactly converted points ``(ra, +-(pi/2 - delta))`` and ``(ra + pi, ...)`` on either
    side of the pole (parallel to the meridian's tangent at the pole to second order),
    ``east = normalize(north x d)``, then ``north = d x east``.
    """
    sign = 1.0 if dec > 0 else -1.0
    lat = sign * (np.pi / 2 - delta)
    a, b = exact_j2000_to_itrf(time_mjd_s, [ra, ra + np.pi], [lat, lat])
    north = sign * (b - a)
    east = np.cross(north, d)
    east /= np.linalg.norm(east)
    return np.cross(d, east), east
