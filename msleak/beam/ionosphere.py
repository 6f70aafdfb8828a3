"""Ionospheric Faraday rotation as a per-station Jones matrix (docs/predict.md, "Ionosphere").

The ionosphere above station ``p`` turns the polarization angle of the incoming field by
``phi = RM_p(t) lambda^2``, so that ``Q + iU -> (Q + iU) exp(2i phi)``. On the field in the
sky's (North, East) basis that is the rotation

    R(phi) = [[cos phi, -sin phi], [sin phi, cos phi]],   J_p(s) -> J_p(s) R(phi_p),

applied before the beam. The phase-centre correction keeps using the beam alone: a rotation
common to all stations leaves unpolarized calibrators unchanged, so calibration cannot
remove it (docs/predict.md).

Models of RM_p(t) (:class:`RotationMeasures`): a table (station, time) interpolated linearly
in time, read from a CSV file (:func:`msleak.adapters.ionosphere.read_rm_table`), drawn at
random (:func:`random_rm`) or computed for a thin shell (:func:`thin_shell_rm`, by
:mod:`msleak.adapters.spinifex_rm`). :class:`IonosphereBeam` puts them in front of any beam
model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msleak.beam.base import BeamModel
from msleak.constants import FARADAY_RM, SPEED_OF_LIGHT
from msleak.errors import InputError

__all__ = ["RotationMeasures", "IonosphereBeam", "faraday_rotation", "random_rm", "thin_shell_rm",
           "RANDOM_RM_MEAN", "RANDOM_RM_RMS", "RANDOM_RM_INDEX"]

#: ``random:SEED``: the mean (rad m^-2) of the RM drawn at random: a mid-latitude night
#: (LOFAR observations show 0.5-2 rad m^-2; Sotomayor-Beltran et al. 2013)
RANDOM_RM_MEAN = 1.0
#: ``random:SEED``: the rms (rad m^-2) of its variation over the observation
RANDOM_RM_RMS = 0.3
#: ``random:SEED``: the temporal power spectrum of the variation goes as f^-RANDOM_RM_INDEX
#: (8/3: a Kolmogorov screen drifting over the array, the form of ionospheric phase spectra)
RANDOM_RM_INDEX = 8.0 / 3.0


@dataclass(frozen=True)
class RotationMeasures:
    """RM (rad m^-2) per station and tabulated time, interpolated linearly in time.

    Attributes
    ----------
    times : (ntime,) float
        MJD seconds, increasing.
    rm : (nstation_table, ntime) float
        Row ``k`` belongs to the stations ``station_rows == k``.
    stations : tuple of str
        The station name of each row; ``"*"`` is every station without a row of its own.
    label : str
        Where the table comes from (recorded in the run's settings).
    """

    times: np.ndarray
    rm: np.ndarray
    stations: tuple[str, ...]
    label: str = ""

    def __post_init__(self) -> None:
        times = np.asarray(self.times, dtype=np.float64)
        rm = np.atleast_2d(np.asarray(self.rm, dtype=np.float64))
        if times.ndim != 1 or rm.shape != (len(self.stations), times.size) or not times.size:
            raise InputError(f"an RM table needs one row of {times.size} values per station, "
                             f"got {rm.shape} for {len(self.stations)} stations")
        if np.any(np.diff(times) <= 0) or not np.all(np.isfinite(rm)):
            raise InputError("an RM table needs increasing times and finite RMs")
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "rm", rm)

    def at(self, names: list[str], times: np.ndarray) -> np.ndarray:
        """RM (nstation, ntime) of the stations ``names`` at ``times`` (MJD s).

        Raises
        ------
        InputError
            A station without a row (and no ``*`` row), or a time outside the table by
            more than half its spacing.
        """
        times = np.asarray(times, dtype=np.float64)
        slack = 0.5 * (float(np.min(np.diff(self.times))) if self.times.size > 1 else 1.0)
        if times.size and (times.min() < self.times[0] - slack
                           or times.max() > self.times[-1] + slack):
            raise InputError(f"the RM table {self.label} spans MJD {self.times[0]:.1f}-"
                             f"{self.times[-1]:.1f} s; the observation runs from "
                             f"{times.min():.1f} to {times.max():.1f} s: give RMs for all "
                             "of it")
        rows = []
        for name in names:
            if name in self.stations:
                rows.append(self.stations.index(name))
            elif "*" in self.stations:
                rows.append(self.stations.index("*"))
            else:
                raise InputError(f"the RM table {self.label} has no station {name!r} and no "
                                 "'*' row for the others")
        if self.times.size == 1:
            return np.repeat(self.rm[rows, :1], times.size, axis=1)
        return np.stack([np.interp(times, self.times, self.rm[r]) for r in rows])


def faraday_rotation(rm: np.ndarray, freq_hz: np.ndarray) -> np.ndarray:
    """The rotation matrices R(RM lambda^2) (nstation, ntime, nchan, 2, 2), float64, of the
    RMs ``rm`` (nstation, ntime; rad m^-2) at the frequencies ``freq_hz``: right-multiplied
    onto a station's Jones matrices, they turn Q + iU by exp(2i RM lambda^2)."""
    lam2 = (SPEED_OF_LIGHT / np.asarray(freq_hz, dtype=np.float64)) ** 2
    phi = np.asarray(rm, dtype=np.float64)[:, :, None] * lam2[None, None, :]
    c, s = np.cos(phi), np.sin(phi)
    return np.stack([np.stack([c, -s], axis=-1), np.stack([s, c], axis=-1)], axis=-2)


def thin_shell_rm(vtec_m2, airmass, b_los_t) -> np.ndarray:
    """RM (rad m^-2) of a thin ionospheric shell: ``FARADAY_RM * vtec * airmass * B_par``.

    ``vtec_m2`` is the vertical electron column at the pierce point (m^-2), ``airmass`` the
    slant factor there, ``b_los_t`` the geomagnetic field (T) along the line of sight from
    the observer towards the source; the field towards the observer is its negative, so a
    northern-hemisphere field (pointing down) gives a positive RM. Arrays broadcast.
    """
    return -FARADAY_RM * (np.asarray(vtec_m2, dtype=np.float64) * np.asarray(airmass)
                          * np.asarray(b_los_t, dtype=np.float64))


def random_rm(times: np.ndarray, seed: int, *, mean: float = RANDOM_RM_MEAN,
              rms: float = RANDOM_RM_RMS, index: float = RANDOM_RM_INDEX,
              label: str = "") -> RotationMeasures:
    """An RM time series drawn at random, the same for every station (one screen over an
    array a few km across): mean ``mean``, a Gaussian variation of rms ``rms`` with power
    spectrum f^-``index`` over the span of ``times`` (MJD s), reproducible from ``seed``."""
    times = np.unique(np.asarray(times, dtype=np.float64))
    n = max(times.size, 2)
    grid = np.linspace(times[0], times[-1] if times.size > 1 else times[0] + 1.0, n)
    rng = np.random.default_rng(seed)
    freqs = np.fft.rfftfreq(2 * n)[1:]
    amplitude = freqs ** (-index / 2.0)
    spectrum = amplitude * (rng.standard_normal(freqs.size) + 1j * rng.standard_normal(freqs.size))
    series = np.fft.irfft(np.concatenate([[0.0], spectrum]), 2 * n)[:n]
    series -= series.mean()
    std = series.std()
    series = series / std * rms if std > 0 else series
    return RotationMeasures(times=grid, rm=(mean + series)[None, :], stations=("*",),
                            label=label or f"random:{seed}")


class IonosphereBeam(BeamModel):
    """``model`` behind the ionosphere ``rms``: J_p(s) R(RM_p(t) lambda^2) for every
    direction; with the centre correction J_p(s0)^-1 J_p(s) R (the beam alone is removed).

    :meth:`sky_rotation` gives R, so that a caller who inverts the Jones matrix it got
    towards the phase centre (J(s0) R) recovers J(s0)^-1 (:func:`msleak.beam.base.
    centre_correction`).
    """

    def __init__(self, model: BeamModel, rms: RotationMeasures):
        super().__init__(model.n_stations, model.phase_centre, model.station_names,
                         model.used_stations)
        self.model, self.rms, self.name = model, rms, model.name

    def sky_rotation(self, time, freq, stations=None) -> np.ndarray:
        """R (nstation, ntime, nchan, 2, 2) float64 of ``stations`` (default the used ones)."""
        stations = self.used_stations if stations is None else np.asarray(stations)
        names = [self.station_names[int(k)] for k in stations]
        return faraday_rotation(self.rms.at(names, np.atleast_1d(time)), np.atleast_1d(freq))

    def _jones(self, time, freq, ra, dec, stations, dtype):
        jones = self.model._jones(time, freq, ra, dec, stations, np.complex128)
        jones = jones @ self.sky_rotation(time, freq, stations)[:, :, :, None]
        return jones.astype(dtype, copy=False)

    def _jones_factors(self, time, freq, ra, dec, stations, dtype):
        """The model's factors with R on the element matrices, where every station has the
        same RM (one screen over the array); else None (full Jones matrices)."""
        factors = self.model._jones_factors(time, freq, ra, dec, stations, dtype)
        if factors is None:
            return None
        rotation = self.sky_rotation(time, freq, stations)
        if not np.all(rotation == rotation[:1]):
            return None
        element = factors.element @ rotation[0][None, :, :, None]
        return factors._replace(element=element.astype(factors.element.dtype, copy=False))

    def jones(self, time_mjd_s, freq_hz, ra, dec, *, stations=None,
              centre_correction: bool = False, dtype=np.complex128) -> np.ndarray:
        if not centre_correction:
            return super().jones(time_mjd_s, freq_hz, ra, dec, stations=stations, dtype=dtype)
        time, freq, ra, dec, stations = self._check(time_mjd_s, freq_hz, ra, dec, stations)
        jones = self.model.jones(time, freq, ra, dec, stations=stations,
                                 centre_correction=True, dtype=np.complex128)
        jones = jones @ self.sky_rotation(time, freq, stations)[:, :, :, None]
        return jones.astype(dtype, copy=False)
