"""A fixed, zenith-pointing dish (HERA) through a UVBeam E-field beam file: beam ``uvbeam``.

:class:`UVBeamModel` takes one E-field beam read by :mod:`msleak.io.uvbeam` (default:
pyuvsim's ``HERA_NicCST.beamfits``) and, per time slot, interpolates it with pyuvdata's
own ``UVBeam.interp`` in one call, at the file's frequencies, at the azimuth and zenith
angle of every direction in the array centre's local frame.  Each feed's response becomes
a vector ``g = D_az az_hat + D_za za_hat`` in the local (East, North, Up) frame.  Each
station's own frame (a rotation of the centre's by < 1e-4 rad) is reached to first order
from three more points of the same call (the directions turned by a small angle about the
local East, North and Up axes); near the zenith, where the (az, za) interpolant curves
fast, the station's own az/za are interpolated instead.  ``J[p, i] = g_p . b_i`` with
``b`` the sky (North, East) basis; channels between the file's frequencies take
pyuvdata's own interpolation weights (cubic).  Zero below each station's horizon.
Conventions, accuracy and speed: docs/hera.md.
"""

from __future__ import annotations

import logging

import numpy as np

from msleak.beam.base import BeamModel
from msleak.beam.coords import (
    clip_pole,
    enu_basis,
    itrf_map,
    radec_to_unit,
    sky_basis,
)
from msleak.errors import InputError

__all__ = ["UVBeamModel", "frequency_weights", "check_frequencies", "response_vectors"]

log = logging.getLogger(__name__)

#: rotation angle (rad) of the finite differences that move the beam to each station's frame
_STEP_RAD = 1e-6
#: a station evaluates directions within this many times its frame tilt (rad) of the zenith
#: in its own frame: the (az, za) interpolant curves too fast there for the first-order move
_EXACT_ZA_PER_TILT = 700.0
#: channels this close (Hz) to the file's frequency range count as inside (pyuvdata's tolerance)
_FREQ_TOL_HZ = 1.0


def check_frequencies(freq_hz, file_freq_hz, name: str) -> None:
    """Raise a one-line InputError if a frequency (Hz) lies outside the file's range."""
    freq = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    lo, hi = float(np.min(file_freq_hz)), float(np.max(file_freq_hz))
    bad = freq[(freq < lo - _FREQ_TOL_HZ) | (freq > hi + _FREQ_TOL_HZ)]
    if bad.size:
        raise InputError(
            f"the beam file {name} covers {lo / 1e6:g}-{hi / 1e6:g} MHz and pyuvdata does "
            f"not extrapolate; {bad[0] / 1e6:g} MHz requested ({bad.size} channel(s) "
            f"outside): simulate inside it (`msleak simulate --freq-min HZ`) or give "
            f"another `beam_file=PATH`")


def frequency_weights(file_freq_hz, freq_hz) -> np.ndarray:
    """Weights (nchan, nfile) with ``beam(freq) = sum_k w[:, k] beam(file_freq[k])``.

    pyuvdata's frequency interpolation (``scipy.interpolate.interp1d``, cubic by default)
    is linear in the data, so its weights are its interpolation of the identity; fewer
    than four file frequencies interpolate linearly, one frequency is used as it is.
    """
    from scipy.interpolate import interp1d

    file_freq = np.asarray(file_freq_hz, dtype=float)
    freq = np.clip(np.asarray(freq_hz, dtype=float), file_freq.min(), file_freq.max())
    if file_freq.size == 1:
        return np.ones((freq.size, 1))
    kind = "cubic" if file_freq.size >= 4 else "linear"
    return interp1d(file_freq, np.eye(file_freq.size), kind=kind, axis=0)(freq)


def response_vectors(beam, local: np.ndarray, feed_order) -> np.ndarray:
    """Feed response vectors (nfile, 2, n, 3) in the local (East, North, Up) frame.

    ``local`` (n, 3): unit directions in that frame.  One ``beam.interp`` call at the
    file's frequencies; pyuvdata's azimuth runs from East through North, its first basis
    vector is az_hat (increasing azimuth), the second za_hat (increasing zenith angle).
    Not zeroed below the horizon (the caller does, per station).
    """
    east, north, up = local[:, 0], local[:, 1], local[:, 2]
    az = np.mod(np.arctan2(north, east), 2 * np.pi)
    za = np.arccos(np.clip(up, -1.0, 1.0))
    data, _ = beam.interp(az_array=az, za_array=za, reuse_spline=True,
                          check_azza_domain=False, return_basis_vector=False)
    data = data[:, feed_order]                          # (2 basis, 2 feeds, nfile, n)
    ca, sa, cz, sz = np.cos(az), np.sin(az), np.cos(za), np.sin(za)
    az_hat = np.stack([-sa, ca, np.zeros_like(az)], axis=-1)
    za_hat = np.stack([cz * ca, cz * sa, -sz], axis=-1)
    g = data[0][..., None] * az_hat + data[1][..., None] * za_hat
    return g.transpose(1, 0, 2, 3)


def feed_rows(beam) -> list[int]:
    """The file's feed indices in msleak's row order: X, the feed closer to North-South
    (``feed_angle`` 0 modulo pi), then Y (the IAU order msleak's Stokes use)."""
    angle = np.mod(np.asarray(beam.feed_angle, dtype=float), np.pi)
    ns = int(np.argmin(np.minimum(angle, np.pi - angle)))
    return [ns, 1 - ns]


def zenith_normalised(beam):
    """A copy of ``beam`` divided, at each file frequency, by one complex number: the
    amplitude of the zenith component (basis vector, feed, azimuth) largest at the first
    frequency, times its phase relative to the first frequency.

    A beam file keeps physical units and the feed's electrical phase (HERA's file peaks at
    90.8 and its zenith phase moves by about 180 deg, modulo 360, from one file frequency
    to the next). Both are the same for every direction and every station, so they cancel
    in every visibility J_p B J_q^H, but interpolating the raw complex values between frequencies 15 MHz apart
    would shrink the amplitude (to 0.37 of the zenith gain at 121 MHz for HERA's file).
    Removed, the zenith gain is 1 at every frequency, the phase at the first frequency is
    kept, and the interpolation follows the beam's shape only (docs/hera.md).
    """
    out = beam.copy()
    zenith = int(np.argmin(np.abs(np.asarray(beam.axis2_array, dtype=float))))
    at_zenith = beam.data_array[:, :, :, zenith, :]               # (basis, feed, freq, az)
    ref = np.unravel_index(np.argmax(np.abs(at_zenith[:, :, 0, :])), at_zenith[:, :, 0].shape)
    ref_value = at_zenith[ref[0], ref[1], :, ref[2]]              # (freq,) complex
    norm = np.abs(ref_value) * np.exp(1j * np.angle(ref_value / ref_value[0]))
    out.data_array = beam.data_array / norm[None, None, :, None, None]
    return out


def _rotations(step: float) -> np.ndarray:
    """(3, 3, 3): rotations by ``step`` about the local East, North and Up axes."""
    c, s = np.cos(step), np.sin(step)
    return np.array([[[1, 0, 0], [0, c, -s], [0, s, c]],
                     [[c, 0, s], [0, 1, 0], [-s, 0, c]],
                     [[c, -s, 0], [s, c, 0], [0, 0, 1]]])


class UVBeamModel(BeamModel):
    """The ``uvbeam`` model: one UVBeam E-field file for every station (see module notes).

    Parameters
    ----------
    beam : pyuvdata.UVBeam
        From :func:`msleak.io.uvbeam.read_beam_file`.
    positions : (nstation, 3) array
        ITRF station positions, m.
    phase_centre : (float, float)
        J2000 (ra, dec), rad.
    station_names : list of str, optional
    used_stations : int array, optional
        ANTENNA rows the beam is for (default all); their mean position is the centre.
    name : str
        The file name, for messages.
    """

    name = "uvbeam"

    def __init__(self, beam, positions, phase_centre, station_names=None, *,
                 used_stations=None, name: str = "beam"):
        positions = np.asarray(positions, dtype=float).reshape(-1, 3)
        super().__init__(len(positions), phase_centre, station_names, used_stations)
        used = self.used_stations
        self._check_positions(positions)
        self.beam = zenith_normalised(beam)
        self.positions = positions
        self.file_name = name
        self.file_freq = np.asarray(beam.freq_array, dtype=float).reshape(-1)
        self._feed_order = feed_rows(beam)
        self._centre = positions[used].mean(axis=0)
        centre_axes = enu_basis(self._centre)
        self._axes = np.zeros((len(positions), 3, 3))
        self._omega = np.zeros((len(positions), 3))
        for s in used:
            self._axes[s] = enu_basis(positions[s])
            rel = self._axes[s] @ centre_axes.T        # centre-frame vectors -> station frame
            self._omega[s] = 0.5 * np.array([rel[2, 1] - rel[1, 2], rel[0, 2] - rel[2, 0],
                                             rel[1, 0] - rel[0, 1]])
        self._centre_axes = centre_axes
        self._turns = _rotations(_STEP_RAD)

    def _directions(self, time: float, ra, dec):
        """ITRF directions (ndir, 3) and their sky (North, East) basis of one time."""
        u = radec_to_unit(ra, clip_pole(dec))
        fitmap = itrf_map(time, u, position_itrf=self._centre)
        d = fitmap(u)
        return d, *sky_basis(d, fitmap.pole())

    def _jones(self, time, freq, ra, dec, stations, dtype):
        check_frequencies(freq, self.file_freq, self.file_name)
        out = np.empty((stations.size, time.size, freq.size, ra.size, 2, 2), dtype)
        if out.size == 0:
            return out
        weights = frequency_weights(self.file_freq, freq).astype(complex)  # (nchan, nfile)
        axes, omega = self._axes[stations], self._omega[stations]
        exact_za = np.minimum(_EXACT_ZA_PER_TILT * np.linalg.norm(omega, axis=1), np.pi / 2)
        ndir = ra.size
        for it, t in enumerate(time):
            d, north, east = self._directions(float(t), ra, dec)
            local = d @ self._centre_axes.T
            st, near = np.nonzero(local[:, 2] > np.cos(exact_za)[:, None])
            exact = np.einsum("nc,nec->ne", d[near], axes[st])
            points = np.vstack([local] + [local @ r.T for r in self._turns] + [exact])
            g = response_vectors(self.beam, points, self._feed_order)
            g0 = g[:, :, :ndir]
            dg = (g[:, :, ndir:4 * ndir].reshape(g.shape[:2] + (3, ndir, 3))
                  - g0[:, :, None]) / _STEP_RAD                     # (nfile, 2, 3, ndir, 3)
            g_st = g0[None] + np.tensordot(omega, dg, axes=([1], [2]))  # (nst, nfile, 2, ndir, 3)
            g_st[st, :, :, near] = g[:, :, 4 * ndir:].transpose(2, 0, 1, 3)
            basis = np.stack([north, east], axis=1)                  # (ndir, 2, 3) ITRF
            b_st = basis @ axes.transpose(0, 2, 1)[:, None]          # (nst, ndir, 2, 3) local
            b_st *= (d @ axes[:, 2].T >= 0).T[:, :, None, None]      # station horizons
            jk = np.ascontiguousarray(np.einsum("sfpdc,sdic->fsdpi", g_st, b_st, optimize=True))
            chans = weights @ jk.reshape(weights.shape[1], -1)        # one product for all
            out[:, it] = chans.reshape((freq.size, stations.size) + jk.shape[2:]).swapaxes(0, 1)
        return out
