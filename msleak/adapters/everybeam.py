"""EveryBeam itself, one call per direction: the reference path (``everybeam-direct``).

EveryBeam loads its telescope from the MS path, so this model reads the MS itself.

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

from msleak._everybeam import (
    EVERYBEAM_TELESCOPES,
    MWA_BEAM_FILE_NAME,
    MWA_BEAM_FILE_VARIABLE,
    everybeam_telescope,
    import_everybeam,
)
from msleak.adapters.beams import read_lofar_array
from msleak.beam.base import BeamModel
from msleak.beam.coords import clip_pole
from msleak.beam.lofar_fast import sky_rotation
from msleak.errors import BeamUnavailable, InputError
from msleak.io.measures import exact_j2000_to_itrf
from msleak.io.ms import (
    has_subtable,
    iter_rows,
    read_antennas,
    read_beam_directions,
    read_fields,
    read_spectral_windows,
    read_telescope_name,
)

__all__ = ["EveryBeamDirect", "load_everybeam_telescope", "pole_basis", "POLE_BASIS_RAD"]

#: Directions closer than this to a pole (rad) get the meridian-limit sky basis.
POLE_BASIS_RAD = 1e-6

log = logging.getLogger(__name__)


def load_everybeam_telescope(ms: str | os.PathLike, element_model: str = "default"):
    """``everybeam.load_telescope`` with no normalisation.

    Raises
    ------
    BeamUnavailable
        Before calling EveryBeam when the MS's TELESCOPE_NAME has no EveryBeam model, or an
        MS or environment lacks what that model reads (LOFAR tables, MWA dipole delays, the
        MWA coefficients file); any error of EveryBeam itself likewise.
    """
    name = read_telescope_name(ms)
    kind = everybeam_telescope(name)
    remedy = _remedy(ms)
    if kind is None:
        known = ", ".join(sorted(list(EVERYBEAM_TELESCOPES) + ["OSKAR*"]))
        raise BeamUnavailable(f"{ms}: EveryBeam has no beam model for TELESCOPE_NAME {name!r} "
                              f"(its Python bindings know {known})", remedy=remedy)
    coeff_path = ""
    if kind == "LOFAR" and not has_subtable(ms, "LOFAR_ANTENNA_FIELD"):
        raise BeamUnavailable(f"{ms}: no LOFAR_ANTENNA_FIELD table, so no LOFAR beam")
    if kind == "MWA":
        if not has_subtable(ms, "MWA_TILE_POINTING"):
            raise BeamUnavailable(f"{ms}: no MWA_TILE_POINTING table (the tiles' dipole "
                                  "delays), which EveryBeam's MWA beam needs", remedy=remedy)
        coeff_path = _mwa_coefficients(ms, remedy)
    eb = import_everybeam()
    return _everybeam_call(ms, eb.load_telescope, str(ms), use_differential_beam=False,
                           element_response_model=element_model, coeff_path=coeff_path)


#: the msleak beam models of telescopes EveryBeam lacks or needs a downloaded file for
_OTHER_MODELS = {
    "HERA": "use `beam='uvbeam'` (HERA's dish beam from a UVBeam file) or `beam='dipole'`",
    "MWA": "use `beam='hyperbeam'` (the MWA tile; analytic without any file) or "
           "`beam='dipole'`",
}

def _remedy(ms) -> str:
    """What to use instead of EveryBeam for the telescope of ``ms``."""
    return _OTHER_MODELS.get(read_telescope_name(ms).upper(),
                             "use `beam='dipole'` (analytic beam)")


#: The fix of the environment an MWA beam may need.
_MWA_SETTING = f"set {MWA_BEAM_FILE_VARIABLE} to the path of {MWA_BEAM_FILE_NAME}"


def _mwa_coefficients(ms, remedy: str) -> str:
    """The MWA FEE coefficients file named by MWA_BEAM_FILE, checked to be an HDF5 file."""
    path = os.environ.get(MWA_BEAM_FILE_VARIABLE, "")
    if not path:
        raise BeamUnavailable(f"{ms}: EveryBeam's MWA beam needs the MWA FEE coefficients "
                              f"file {MWA_BEAM_FILE_NAME} and {MWA_BEAM_FILE_VARIABLE} is not "
                              "set", setting=_MWA_SETTING, remedy=remedy)
    try:
        with open(path, "rb") as f:
            signature = f.read(8)
    except OSError as err:
        raise BeamUnavailable(f"{MWA_BEAM_FILE_VARIABLE}={path}: cannot read it "
                              f"({err.strerror})", setting=_MWA_SETTING, remedy=remedy) from err
    if signature != b"\x89HDF\r\n\x1a\n":
        raise BeamUnavailable(f"{MWA_BEAM_FILE_VARIABLE}={path}: not an HDF5 file",
                              setting=_MWA_SETTING, remedy=remedy)
    return path


def _everybeam_call(ms, function, *args, setting: str = "", **kwargs):
    """``function(*args, **kwargs)`` of EveryBeam with its errors as BeamUnavailable
    (naming ``setting``, the environment fix that may cure them, if any, and the msleak
    model that works for the telescope)."""
    try:
        return function(*args, **kwargs)
    except (RuntimeError, ValueError) as err:
        text = " ".join(str(err).split())[:160]
        raise BeamUnavailable(f"{ms}: EveryBeam cannot make a beam for this MS ({text})",
                              setting=setting, remedy=_remedy(ms)) from err


class EveryBeamDirect(BeamModel):
    """Station beams from EveryBeam's Python bindings, one direction per call (slow).

    Parameters
    ----------
    ms : path
        The Measurement Set EveryBeam loads.
    element_model : str
        EveryBeam element response model (``default`` = Hamaker for LOFAR).
    field_id : int
        FIELD row of the phase centre and pointing.
    used_stations : int array, optional
        The stations the beam is for (default all).

    The first used station's response towards the phase centre at the MS's first time and
    frequency is computed here, so an MS EveryBeam cannot evaluate is refused at once.
    """

    name = "everybeam-direct"

    def __init__(self, ms: str | os.PathLike, element_model: str = "default",
                 field_id: int = 0, used_stations=None):
        self.telescope = load_everybeam_telescope(ms, element_model)
        self._setting = _MWA_SETTING if type(self.telescope).__name__ == "MWA" else ""
        antennas = read_antennas(ms)
        field = read_fields(ms)[field_id]
        super().__init__(self.telescope.nr_stations, (field.ra, field.dec),
                         list(antennas.names), used_stations)
        self.ms = Path(ms)
        directions = read_beam_directions(ms, field_id)
        self._delay, self._tile = directions.delay, directions.tile
        self._axes = self._station_axes(ms, field_id)
        first = next(iter_rows(ms, ["TIME"], chunk_rows=1), (None, {"TIME": []}))[1]["TIME"]
        if len(first):
            self.jones(first[:1], read_spectral_windows(ms)[0].freq[:1], [field.ra],
                       [field.dec], stations=self.used_stations[:1])

    @staticmethod
    def _station_axes(ms, field_id: int):
        """Per station the common axes (3, 3) of its LOFAR fields, or None."""
        try:
            array = read_lofar_array(ms, field_id)
        except InputError:
            return None
        out = []
        for s in array.stations:
            axes = [f.axes for f in s.fields]
            same = all(np.allclose(a, axes[0], atol=1e-12) for a in axes)
            out.append(axes[0] if same else None)
        return out

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
                    r = _everybeam_call(self.ms, tel.station_response, np.array([t]),
                                        stations.astype(np.uint64), freq, d[k], s0, t0,
                                        setting=self._setting)
                    out[:, it, :, k] = np.asarray(r)[0]
                else:
                    for si, s in enumerate(stations):
                        for c, f in enumerate(freq):
                            out[si, it, c, k] = self._single(t, int(s), float(f), d[k],
                                                             ra[k], dec[k])
        # EveryBeam's element models are zero below the horizon; never hand out NaN
        out[~np.isfinite(out)] = 0
        return out.astype(dtype, copy=False)

    def _pole_response(self, t, stations, freq, ra, dec, d, s0, t0):
        raw = np.asarray(_everybeam_call(self.ms, self.telescope.station_response,
                                         np.array([t]), stations.astype(np.uint64), freq, d,
                                         s0, t0, False, setting=self._setting))[0]
        north, east = pole_basis(t, ra, dec, d)
        out = np.empty_like(raw)
        for si, s in enumerate(stations):
            rot = sky_rotation(self._axes[s], d[None], north[None], east[None])[0]
            out[si] = raw[si] @ rot
        return out

    def _single(self, t, s, f, d, ra, dec):
        """One (station, frequency) response from the bindings' direction-vector call (MWA),
        or their (ra, dec) call (dishes)."""
        call, setting = self.telescope.station_response, self._setting
        try:
            return np.asarray(_everybeam_call(self.ms, call, t, s, f, d, setting=setting))
        except TypeError:
            return np.asarray(_everybeam_call(self.ms, call, t, s, f, float(ra), float(dec),
                                              setting=setting))


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
