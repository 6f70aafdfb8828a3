"""The MWA tile beam through mwa_hyperbeam (beam ``hyperbeam``).

Every MWA tile is 4 x 4 bowtie dipoles fixed on the ground, steered by 16 delays
(MWA_TILE_POINTING, :mod:`msleak.io.mwa`). hyperbeam evaluates the tile response at an
azimuth and zenith angle, in its own basis: rows the East-West then the North-South
dipole, columns the sky field along increasing zenith angle (theta) and increasing
azimuth (phi, North through East). :func:`hyperbeam_to_sky` turns that into msleak's
convention: rows X = North-South, Y = East-West (IAU), columns sky (North, East)
(:func:`msleak.beam.coords.sky_basis`). All tiles share one delay set, so the beam is
evaluated once per time slot in the array centre's local frame for every station. The
analytic model gets the delays with their rows reversed (:func:`analytic_order`).

Element models: ``analytic`` (hyperbeam's AnalyticBeam, mwa_pb's formula; no file) and
``fee`` (the FEE model, from ``mwa_full_embedded_element_pattern.h5``). Details, bands and
accuracy: docs/mwa.md.
"""

from __future__ import annotations

import os

import numpy as np

from msleak._everybeam import MWA_BEAM_FILE_NAME, MWA_BEAM_FILE_VARIABLE, check_delays
from msleak.beam.base import BeamModel
from msleak.beam.coords import (clip_pole, enu_basis, itrf_map,
                                radec_to_unit, sky_basis)
from msleak.errors import BeamUnavailable, InputError

try:
    import mwa_hyperbeam
except ImportError:
    mwa_hyperbeam = None

__all__ = ["MwaBeam", "ELEMENT_MODELS", "ANALYTIC_BAND_HZ", "hyperbeam_to_sky",
           "theta_phi_to_sky", "local_az_za", "analytic_order", "require_hyperbeam"]

#: The element models (``element_model``; the first is the default).
ELEMENT_MODELS = ("analytic", "fee")
#: Band (Hz) msleak accepts for the analytic model: the MWA receiver's 70-300 MHz.
ANALYTIC_BAND_HZ = (70e6, 300e6)
_FEE_REMEDY = (f"download {MWA_BEAM_FILE_NAME} (about 200 MB, from the MWA beam pages) and "
               f"pass it with `beam_file=PATH` or set {MWA_BEAM_FILE_VARIABLE} to it")


def require_hyperbeam():
    """The mwa_hyperbeam module (BeamUnavailable, naming the extra, without it)."""
    if mwa_hyperbeam is None:
        raise BeamUnavailable("the hyperbeam beam needs the mwa_hyperbeam package, which is "
                              "not installed", remedy="pip install 'msleak[mwa]'")
    return mwa_hyperbeam


def _make_beam(element_model: str, beam_file):
    """(hyperbeam beam object, band (lo, hi) Hz, FEE file frequencies or None)."""
    hb = require_hyperbeam()
    if str(element_model).lower() not in ELEMENT_MODELS:
        raise InputError(f"unknown MWA element model {element_model!r}; use one of "
                         f"{', '.join(ELEMENT_MODELS)}")
    if str(element_model).lower() == "analytic":
        if beam_file is not None:
            raise InputError("the analytic MWA beam reads no file; drop beam_file, or use "
                             "element_model 'fee'", param=("beam_file", "element_model"))
        return hb.AnalyticBeam(), ANALYTIC_BAND_HZ, None
    path = beam_file if beam_file is not None else os.environ.get(MWA_BEAM_FILE_VARIABLE)
    if not path:
        raise InputError("the MWA FEE beam needs its coefficients file and neither "
                         f"`beam_file` nor {MWA_BEAM_FILE_VARIABLE} gives one; "
                         + _FEE_REMEDY, param="beam_file")
    try:
        beam = hb.FEEBeam(str(path))
    except hb.HyperbeamError as err:
        raise InputError(f"{path}: not a readable MWA FEE beam file "
                         f"({' '.join(str(err).split())[:120]}); " + _FEE_REMEDY) from err
    freqs = np.asarray(beam.get_fee_beam_freqs(), dtype=float)
    return beam, (float(freqs.min()), float(freqs.max())), freqs


def analytic_order(values) -> np.ndarray:
    """Per-dipole values in the M&C order (row 0 = the northern row, West to East) put in
    the order hyperbeam's AnalyticBeam places them (row 0 = the southern row).

    mwa_hyperbeam 0.10 puts AnalyticBeam's dipole row 0 in the South, so M&C delays that
    point North would point its beam South (docs/mwa.md); the FEE model takes the M&C
    order as it is.
    """
    return np.asarray(values).reshape(4, 4)[::-1].ravel()


def local_az_za(d_local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth (North through East) and zenith angle (rad) of local (E, N, U) unit vectors."""
    return (np.arctan2(d_local[:, 0], d_local[:, 1]),
            np.arccos(np.clip(d_local[:, 2], -1.0, 1.0)))


def theta_phi_to_sky(az: np.ndarray, za: np.ndarray, enu: np.ndarray, north: np.ndarray,
                     east: np.ndarray) -> np.ndarray:
    """Matrices ``R`` (n, 2, 2) taking hyperbeam's (theta, phi) columns to sky (North, East).

    ``R[k, c] = b_k . s_c`` with ``b`` the unit vectors of increasing zenith angle and
    azimuth at (az, za), ``s`` the ITRF sky basis ``north``, ``east`` (n, 3), ``enu`` rows
    the local East, North, Up in ITRF.
    """
    sa, ca, sz, cz = np.sin(az), np.cos(az), np.sin(za), np.cos(za)
    e_theta = np.stack([cz * sa, cz * ca, -sz], -1) @ enu
    e_phi = np.stack([ca, -sa, np.zeros_like(az)], -1) @ enu
    rot = np.empty((len(az), 2, 2))
    rot[:, 0, 0] = np.sum(e_theta * north, -1)
    rot[:, 0, 1] = np.sum(e_theta * east, -1)
    rot[:, 1, 0] = np.sum(e_phi * north, -1)
    rot[:, 1, 1] = np.sum(e_phi * east, -1)
    return rot


def hyperbeam_to_sky(h: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """hyperbeam Jones (n, 4) (rows EW, NS dipole; columns theta, phi) -> msleak Jones
    (n, 2, 2) (rows NS = X, EW = Y; columns North, East): ``P H R`` with ``P`` the row
    swap and ``R`` from :func:`theta_phi_to_sky`."""
    return np.asarray(h).reshape(-1, 2, 2)[:, ::-1, :] @ rot


class MwaBeam(BeamModel):
    """MWA tile beams from mwa_hyperbeam (see module notes).

    Parameters
    ----------
    positions : (nstation, 3) array
        ITRF tile positions, m.
    phase_centre : (ra, dec)
        J2000 phase centre, rad.
    station_names : list of str, optional
    used_stations : int array, optional
        The stations the beam is for; their mean position is the frame of the beam.
    element_model : {'analytic', 'fee'}
    beam_file : path, optional
        The FEE coefficients file (``fee``; default ``$MWA_BEAM_FILE``).
    delays : 16 ints
        Dipole delays of every tile (M&C order; 32 = dead dipole).
    """

    name = "hyperbeam"

    def __init__(self, positions, phase_centre, station_names=None, *, used_stations=None,
                 element_model: str = "analytic", beam_file=None, delays=(0,) * 16):
        positions = np.asarray(positions, dtype=float).reshape(-1, 3)
        super().__init__(len(positions), phase_centre, station_names, used_stations)
        self._beam, self.band, self._fee_freqs = _make_beam(element_model, beam_file)
        self.element_model = str(element_model).lower()
        self.delays = check_delays(delays)
        self.amps = np.where(self.delays == 32, 0.0, 1.0)
        self._analytic_delays = analytic_order(self.delays).tolist()
        self._analytic_amps = analytic_order(self.amps).tolist()
        self._check_positions(positions)
        self._centre = positions[self.used_stations].mean(axis=0)
        self._enu = enu_basis(self._centre)
        self._latitude = float(np.arcsin(self._enu[2, 2]))

    def check_band(self, freq_hz) -> None:
        """Raise InputError if a frequency (Hz) lies outside :attr:`band`."""
        freq = np.atleast_1d(np.asarray(freq_hz, dtype=float))
        lo, hi = self.band
        bad = freq[(freq < lo) | (freq > hi)]
        if bad.size:
            what = ("the file's" if self._fee_freqs is not None else "the MWA receiver's")
            raise InputError(f"the {self.element_model} MWA beam covers {lo / 1e6:g}-"
                             f"{hi / 1e6:g} MHz ({what} band); {bad[0] / 1e6:g} MHz requested "
                             f"({bad.size} channel(s) outside); use `beam='dipole'` there")

    def _evaluation_freqs(self, freq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distinct frequencies hyperbeam is called at and, per channel, its index."""
        whole = np.round(freq)
        if self._fee_freqs is not None:  # hyperbeam uses the nearest file frequency
            whole = self._fee_freqs[np.argmin(np.abs(whole[:, None] - self._fee_freqs), 1)]
        used, index = np.unique(whole, return_inverse=True)
        return used, index

    def _tile_jones(self, time: float, ra, dec, set_freq) -> np.ndarray:
        """One tile's Jones (nset, ndir, 2, 2) at one time, zero below the horizon."""
        u = radec_to_unit(ra, clip_pole(dec))
        fitmap = itrf_map(time, u, position_itrf=self._centre)
        d = fitmap(u)
        north, east = sky_basis(d, fitmap.pole())
        up = (d @ self._enu.T)[:, 2] > 0
        az, za = local_az_za(d[up] @ self._enu.T)
        rot = theta_phi_to_sky(az, za, self._enu, north[up], east[up])
        out = np.zeros((len(set_freq), len(d), 2, 2), complex)
        for i, f in enumerate(set_freq):
            if self._fee_freqs is None:
                h = self._beam.calc_jones_array(az, za, float(f), self._analytic_delays,
                                                self._analytic_amps, self._latitude, True)
            else:
                h = self._beam.calc_jones_array(az, za, float(f), self.delays.tolist(),
                                                self.amps.tolist(), True)
            out[i, up] = hyperbeam_to_sky(h, rot)
        return out

    def _jones(self, time, freq, ra, dec, stations, dtype):
        self.check_band(freq)
        out = np.empty((stations.size, time.size, freq.size, ra.size, 2, 2), dtype)
        if out.size == 0:
            return out
        set_freq, index = self._evaluation_freqs(freq)
        for it, t in enumerate(time):
            out[:, it] = self._tile_jones(float(t), ra, dec, set_freq)[index]
        return out
