"""The beam interface every model implements, the phase-centre correction, the identity.

Conventions
-----------
A beam Jones matrix ``J[p, i]`` maps the sky electric field in the (North, East) basis of
the direction (columns ``i``: 0 = North, 1 = East, as EveryBeam returns them with its
parallactic rotation on) to the voltages of station ``p``'s two feeds (rows: X, Y or R, L).
Directions below a station's horizon get a zero matrix (never NaN).

Phase-centre correction (docs/science.md section 4): with ``centre_correction=True``
:meth:`BeamModel.jones` returns ``J_p(s0)^-1 J_p(s)`` per station, time and channel, where
``s0`` is the MS phase centre, so that ``J_p(s0)^-1 V_pq J_q(s0)^-H`` equals the sum over
sources of ``(J0p^-1 Jp) B (J0q^-1 Jq)^H``.  A singular ``J_p(s0)`` (phase centre below the
horizon) gives a zero inverse and a warning.
"""

from __future__ import annotations

import abc
import logging
from typing import Literal, NamedTuple

import numpy as np

from msleak.beam.lofar_kernels import apply_left_inverse
from msleak.errors import InputError

__all__ = ["BeamName", "BeamModel", "IdentityBeam", "JonesFactors", "invert_2x2",
           "BEAM_NAMES", "centre_inverse", "centre_correction"]

log = logging.getLogger(__name__)

BeamName = Literal["everybeam", "everybeam-direct", "uvbeam", "hyperbeam", "dipole", "none"]
BEAM_NAMES = ("everybeam", "everybeam-direct", "uvbeam", "hyperbeam", "dipole", "none")


def invert_2x2(j: np.ndarray, *, rcond: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of a stack of 2x2 matrices (..., 2, 2); singular ones give zeros.

    Returns
    -------
    inverse : (..., 2, 2) array
    singular : (...) bool array
        Where ``|det| <= rcond * max|J|^2`` (including all-zero matrices).
    """
    j = np.asarray(j)
    det = j[..., 0, 0] * j[..., 1, 1] - j[..., 0, 1] * j[..., 1, 0]
    scale = np.max(np.abs(j), axis=(-2, -1)) ** 2
    singular = ~(np.abs(det) > rcond * scale)
    safe = np.where(singular, 1.0, det)
    inv = np.empty_like(j)
    inv[..., 0, 0] = j[..., 1, 1] / safe
    inv[..., 0, 1] = -j[..., 0, 1] / safe
    inv[..., 1, 0] = -j[..., 1, 0] / safe
    inv[..., 1, 1] = j[..., 0, 0] / safe
    inv[singular] = 0
    return inv, singular


def centre_inverse(centre: np.ndarray) -> np.ndarray:
    """J(s0)^-1 (..., 2, 2) complex128 of the beams at the phase centre for the centre
    correction; singular samples give zeros (their corrected visibilities are zero) and
    one warning counting them."""
    left, singular = invert_2x2(np.asarray(centre).astype(np.complex128))
    if singular.any():
        log.warning("beam at the phase centre is singular for %d station/time/channel "
                    "samples; their corrected visibilities are zero", int(singular.sum()))
    return left


def centre_correction(beam_model, centre: np.ndarray, time, freq, stations) -> np.ndarray:
    """J(s0)^-1 (nstation, ntime, nchan, 2, 2) complex128 from the Jones matrices ``centre``
    that ``beam_model`` gave towards the phase centre at ``time``, ``freq`` for ``stations``:
    :func:`centre_inverse`, except that a model with a rotation on the sky's side
    (``sky_rotation``, e.g. the ionosphere's) keeps it: only the beam is removed."""
    left = centre_inverse(centre)
    rotation = getattr(beam_model, "sky_rotation", None)
    return left if rotation is None else rotation(time, freq, stations) @ left


class JonesFactors(NamedTuple):
    """Beam Jones matrices as a scalar per station times a matrix per element group:
    ``J[p, t, c, k] = scalar[p, t, c, k] * element[group[p], t, c, k]``.

    The form of array beams whose stations' fields share one element response per
    station (LOFAR HBA: one group for all core stations, one per remote station): the
    scalar is the station's array factor. Axes 0-2 of ``scalar`` and 1-2 of
    ``element`` may have length 1 (broadcast).

    Attributes
    ----------
    scalar : (nstation, ntime, nchan, ndir) complex
    element : (ngroup, ntime, nchan, ndir, 2, 2) complex
        Rows: feeds; columns: sky (North, East), as :meth:`BeamModel.jones`.
    group : (nstation,) int
        Element group of each station.
    """

    scalar: np.ndarray
    element: np.ndarray
    group: np.ndarray

    def full(self, index=slice(None)) -> np.ndarray:
        """The Jones matrices (nstation, ntime, nchan, ndir, 2, 2) of directions ``index``."""
        element = self.element[..., index, :, :]
        return self.scalar[..., index, None, None] * element[self.group]


class BeamModel(abc.ABC):
    """A primary-beam model of the stations of one Measurement Set.

    Attributes
    ----------
    name : str
        The model name (one of :data:`BEAM_NAMES`).
    n_stations : int
        Number of stations (ANTENNA rows).
    station_names : list of str
    used_stations : (nused,) int array
        The ANTENNA rows the model is for (those in the selected main-table rows); the
        default of ``stations`` and the only ones it evaluates.
    phase_centre : (float, float)
        J2000 (ra, dec) in rad of the direction ``jones_centre`` and the correction use.
    """

    name: str = ""

    def __init__(self, n_stations: int, phase_centre: tuple[float, float],
                 station_names: list[str] | None = None, used_stations=None):
        self.n_stations = int(n_stations)
        self.phase_centre = (float(phase_centre[0]), float(phase_centre[1]))
        self.station_names = list(station_names) if station_names is not None else [
            str(i) for i in range(self.n_stations)]
        used = np.arange(self.n_stations) if used_stations is None else np.unique(
            np.asarray(used_stations, dtype=np.int64))
        if used.size == 0 or used[0] < 0 or used[-1] >= self.n_stations:
            raise InputError(f"beam: used stations must be ANTENNA rows 0..{self.n_stations - 1}")
        self.used_stations = used

    # -- to implement ------------------------------------------------------------------
    @abc.abstractmethod
    def _jones(self, time: np.ndarray, freq: np.ndarray, ra: np.ndarray, dec: np.ndarray,
               stations: np.ndarray, dtype) -> np.ndarray:
        """Uncorrected Jones (nstation, ntime, nchan, ndir, 2, 2) of ``dtype``, checked inputs."""

    # -- public ---------------------------------------------------------------------------
    def jones(self, time_mjd_s, freq_hz, ra, dec, *, stations=None,
              centre_correction: bool = False, dtype=np.complex128) -> np.ndarray:
        """Beam Jones matrices.

        Parameters
        ----------
        time_mjd_s : (ntime,) array
            UTC as MJD seconds (the MS TIME column).
        freq_hz : (nchan,) array
            Frequencies, Hz.
        ra, dec : (ndir,) arrays
            J2000 directions, rad.
        stations : (nstation,) int array, optional
            ANTENNA rows among :attr:`used_stations` (the default).
        centre_correction : bool
            Return ``J(s0)^-1 J(s)`` (s0 the phase centre) instead of ``J(s)``.
        dtype : numpy complex dtype
            Of the result.

        Returns
        -------
        (nstation, ntime, nchan, ndir, 2, 2) complex array
            Rows: feeds (X, Y); columns: sky (North, East).  Zero below the horizon.
            A new array the caller may change (predict zeroes it in place below its
            horizon); a model must not return an array it keeps.
        """
        time, freq, ra, dec, stations = self._check(time_mjd_s, freq_hz, ra, dec, stations)
        dtype = np.dtype(dtype)
        if dtype.kind != "c":
            raise InputError(f"beam: dtype must be complex, not {dtype}")
        if not centre_correction:
            return self._jones(time, freq, ra, dec, stations, dtype)

        ra0, dec0 = self.phase_centre
        # the centre is evaluated in the same call, so both share one coordinate conversion
        both = self._jones(time, freq, np.append(ra, ra0), np.append(dec, dec0), stations,
                           np.complex128)
        inv, singular = invert_2x2(both[..., -1, :, :])
        if singular.any():
            log.warning("beam at the phase centre is singular (below the horizon?) for %d "
                        "station/time/channel samples; their corrected beam is zero",
                        int(singular.sum()))
        apply_left_inverse(inv, both)  # in place; the centre column becomes the identity
        return both[..., :-1, :, :].astype(dtype, copy=False)

    def jones_factors(self, time_mjd_s, freq_hz, ra, dec, *, stations=None,
                      dtype=np.complex128) -> JonesFactors | None:
        """The uncorrected :meth:`jones` as :class:`JonesFactors`, or None if the model's
        stations do not factor so (the default); same parameters as :meth:`jones`, and,
        like it, new arrays the caller may change."""
        time, freq, ra, dec, stations = self._check(time_mjd_s, freq_hz, ra, dec, stations)
        dtype = np.dtype(dtype)
        if dtype.kind != "c":
            raise InputError(f"beam: dtype must be complex, not {dtype}")
        return self._jones_factors(time, freq, ra, dec, stations, dtype)

    def _jones_factors(self, time: np.ndarray, freq: np.ndarray, ra: np.ndarray,
                       dec: np.ndarray, stations: np.ndarray, dtype) -> JonesFactors | None:
        """:meth:`jones_factors` on checked inputs; models that factor override it."""
        return None

    def jones_centre(self, time_mjd_s, freq_hz, *, stations=None) -> np.ndarray:
        """Jones (nstation, ntime, nchan, 2, 2) towards the phase centre (uncorrected)."""
        ra0, dec0 = self.phase_centre
        return self.jones(time_mjd_s, freq_hz, [ra0], [dec0], stations=stations)[..., 0, :, :]

    # -- helpers -------------------------------------------------------------------------
    def _check_positions(self, positions: np.ndarray) -> None:
        """Refuse a used station whose ITRF ``positions`` row (m) is not on the Earth."""
        used = self.used_stations
        radius = np.linalg.norm(positions[used], axis=1)
        off = ~((radius > 6.2e6) & (radius < 6.5e6))
        if np.any(off):
            k = int(used[np.argmax(off)])
            raise InputError(f"ANTENNA row {k} ({self.station_names[k]}) is used but its "
                             f"POSITION is {np.linalg.norm(positions[k]) / 1e3:.0f} km from "
                             "the geocentre, not an ITRF position on the Earth")

    def _check(self, time, freq, ra, dec, stations):
        time = np.atleast_1d(np.asarray(time, dtype=float))
        freq = np.atleast_1d(np.asarray(freq, dtype=float))
        ra = np.atleast_1d(np.asarray(ra, dtype=float))
        dec = np.atleast_1d(np.asarray(dec, dtype=float))
        if time.ndim != 1 or freq.ndim != 1 or ra.ndim != 1 or ra.shape != dec.shape:
            raise InputError("beam: time and freq must be 1-D, ra and dec 1-D of equal length")
        if not (np.all(np.isfinite(time)) and np.all(np.isfinite(freq))
                and np.all(np.isfinite(ra)) and np.all(np.isfinite(dec))):
            raise InputError("beam: time, frequency and direction values must be finite")
        if np.any(freq <= 0):
            raise InputError("beam: frequencies must be positive (Hz)")
        if np.any(np.abs(dec) > np.pi / 2 + 1e-12):
            raise InputError("beam: declinations must lie in [-pi/2, pi/2] rad")
        dec = np.clip(dec, -np.pi / 2, np.pi / 2)
        if stations is None:
            stations = self.used_stations
        stations = np.atleast_1d(np.asarray(stations))
        if stations.dtype.kind not in "iu" or stations.ndim != 1:
            raise InputError("beam: stations must be a 1-D array of ANTENNA row numbers")
        if stations.size and (stations.min() < 0 or stations.max() >= self.n_stations):
            raise InputError(f"beam: station index out of range 0..{self.n_stations - 1}")
        unused = np.setdiff1d(stations, self.used_stations)
        if unused.size:
            raise InputError(f"beam: ANTENNA row(s) {', '.join(map(str, unused[:5]))} do not "
                             "occur in the selected rows of the MS")
        return time, freq, ra, dec, stations.astype(np.int64)

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name!r}: {self.n_stations} stations>"


class IdentityBeam(BeamModel):
    """The ``none`` beam: the identity everywhere (no horizon)."""

    name = "none"

    def _jones(self, time, freq, ra, dec, stations, dtype):
        out = np.zeros((stations.size, time.size, freq.size, ra.size, 2, 2), dtype)
        out[..., 0, 0] = 1
        out[..., 1, 1] = 1
        return out
