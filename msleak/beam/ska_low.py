"""The fast SKA-Low station beam: EveryBeam's OSKAR-type station response, vectorised.

For an MS with TELESCOPE_NAME ``SKA-LOW`` and a PHASED_ARRAY subtable EveryBeam 0.9.0
builds an OSKAR telescope: per station one beam former over identical elements, steered
to FIELD::DELAY_DIR (formula in :mod:`msleak.beam.ska_low_kernels`).  This module does
the same for all directions, channels and stations of a time slot at once:

1. directions -> ITRF once per time slot and the sky (North, East) basis
   (:mod:`msleak.beam.coords`, as for LOFAR);
2. the element response from ``everybeam.ElementResponse`` on arrays, once per group of
   stations with identical axes, in the station frame (theta from Up, phi from East
   towards North; element 0's coefficients for every element, as EveryBeam does),
   rotated to (North, East);
3. the 256-element array factor and the product in numba.

Element models (:data:`ELEMENT_MODELS`; EveryBeam's ``default`` for SKA-Low is
``oskar_dipole_cos``) and the bands msleak accepts for them are in docs/ska_low.md;
``skalow_feko`` is refused (:data:`REFUSED_MODELS`).  Below a station's horizon the
result is zero (EveryBeam's element patterns are not).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from msleak._everybeam import import_everybeam
from msleak.beam.base import BeamModel
from msleak.beam.coords import clip_pole, itrf_map, radec_to_unit, sky_basis
from msleak.beam.ska_low_kernels import ska_low_station_kernel
from msleak.errors import InputError

__all__ = ["ElementModel", "ELEMENT_MODELS", "REFUSED_MODELS", "SKALA40_FREQUENCIES_HZ",
           "SkaLowBeam", "check_element_model", "check_band", "element_frequency_sets",
           "station_angles", "sky_rotation", "element_jones"]

log = logging.getLogger(__name__)


#: Frequencies (Hz) of the SKALA4.0 spherical-wave coefficient sets in EveryBeam 0.9.0's
#: ``oskar.h5`` (one element's coefficients each).
SKALA40_FREQUENCIES_HZ = np.array([50e6, 70e6, 110e6, 137e6, 160e6, 230e6, 320e6])


@dataclass(frozen=True)
class ElementModel:
    """An EveryBeam element model msleak evaluates for SKA-Low.

    ``band`` (Hz) is where msleak accepts it; ``frequency_independent`` says that
    EveryBeam's pattern does not depend on frequency; ``per_element_call`` that EveryBeam
    wants the element id argument (spherical-wave models).
    """

    name: str
    band: tuple
    frequency_independent: bool
    per_element_call: bool
    description: str


#: The element models of the fast path.
ELEMENT_MODELS = {
    "oskar_dipole_cos": ElementModel(
        "oskar_dipole_cos", (50e6, 350e6), True, False,
        "OSKAR's analytic dipole with a cosine taper (EveryBeam's default for SKA-Low); "
        "frequency independent, accepted over the SKA-Low band"),
    "oskar_dipole": ElementModel(
        "oskar_dipole", (50e6, 350e6), True, False,
        "OSKAR's analytic dipole; frequency independent, accepted over the SKA-Low band"),
    "skala40_wave": ElementModel(
        "skala40_wave", (50e6, 320e6), False, True,
        "SKALA4.0 spherical-wave fit at 50, 70, 110, 137, 160, 230, 320 MHz; EveryBeam "
        "uses the set nearest the whole MHz below each frequency"),
}

#: Element models refused, with the reason.
REFUSED_MODELS = {
    "skalow_feko": "EveryBeam 0.9.0's 'skalow_feko' element model is broken (its Y feed "
                   "is turned by 90 deg, element ids >= 1 read past its data, which cover "
                   "only 100-106 MHz)",
}
REFUSED_MODELS["ska_low_feko"] = REFUSED_MODELS["skalow_feko"]

_ALIASES = {"default": "oskar_dipole_cos", "skala40_spherical": "skala40_wave"}


def check_element_model(name: str) -> ElementModel:
    """The :class:`ElementModel` called ``name`` (``default`` = ``oskar_dipole_cos``).

    Raises
    ------
    InputError
        A refused or unknown model (one line, naming the usable ones).
    """
    usable = ", ".join(ELEMENT_MODELS)
    key = _ALIASES.get(str(name).lower(), str(name).lower())
    if key in REFUSED_MODELS:
        raise InputError(f"{REFUSED_MODELS[key]}; use element model {usable}")
    if key not in ELEMENT_MODELS:
        raise InputError(f"unknown SKA-Low element model {name!r}; use one of {usable}")
    return ELEMENT_MODELS[key]


def check_band(model: ElementModel, freq_hz) -> None:
    """Raise InputError if any frequency (Hz) lies outside ``model.band``."""
    freq = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    lo, hi = model.band
    bad = freq[(freq < lo) | (freq > hi)]
    if bad.size:
        raise InputError(f"SKA-Low element model {model.name!r} covers {lo / 1e6:g}-"
                         f"{hi / 1e6:g} MHz; {bad[0] / 1e6:g} MHz requested "
                         f"({bad.size} channel(s) outside)")


def element_frequency_sets(model: ElementModel, freq_hz) -> tuple[np.ndarray, np.ndarray]:
    """The distinct frequencies at which the element response must be evaluated.

    Returns
    -------
    set_freq : (nset,) array, Hz
        Frequencies to evaluate at.
    chan_set : (nchan,) int64 array
        For each channel the index into ``set_freq`` giving its response.

    Dipole models are frequency independent (one set).  For ``skala40_wave`` EveryBeam
    truncates the frequency to whole MHz and takes the coefficient set nearest to that,
    the lower one on a tie; the sets are evaluated at their own frequencies.
    """
    freq = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    if model.frequency_independent:
        return freq[:1].copy(), np.zeros(freq.size, dtype=np.int64)
    whole_mhz = np.floor(freq / 1e6)
    sets = np.argmin(np.abs(whole_mhz[:, None] - SKALA40_FREQUENCIES_HZ[None] / 1e6), axis=1)
    used, chan_set = np.unique(sets, return_inverse=True)
    return SKALA40_FREQUENCIES_HZ[used], chan_set.astype(np.int64)


def station_angles(axes: np.ndarray, d: np.ndarray):
    """(theta, phi, local d) of ITRF directions ``d`` (ndir, 3) in a station frame.

    ``axes`` rows are East, North, Up; theta is measured from Up, phi from East towards
    North (EveryBeam's OSKAR element orientation).
    """
    dl = d @ axes.T
    theta = np.pi / 2 - np.arctan2(dl[:, 2], np.hypot(dl[:, 0], dl[:, 1]))
    phi = np.arctan2(dl[:, 1], dl[:, 0])
    return theta, phi, dl


def sky_rotation(axes: np.ndarray, d: np.ndarray, north: np.ndarray, east: np.ndarray
                 ) -> np.ndarray:
    """Rotation (ndir, 2, 2) from the station's (theta, phi) basis to sky (North, East).

    With ``e_phi = normalize(up x d)`` and ``e_theta = e_phi x d`` (station frame),
    ``R = [[e_theta.n, e_theta.e], [e_phi.n, e_phi.e]]``; a Jones matrix ``H`` in the
    (theta, phi) basis becomes ``H @ R``.  At the zenith the ``phi = 0`` limit is used.
    """
    dl, nl, el = d @ axes.T, north @ axes.T, east @ axes.T
    e_phi = np.stack([-dl[:, 1], dl[:, 0], np.zeros(len(dl))], axis=-1)
    e_phi[np.hypot(dl[:, 0], dl[:, 1]) < 1e-12] = (0.0, 1.0, 0.0)
    e_phi /= np.linalg.norm(e_phi, axis=-1, keepdims=True)
    e_theta = np.cross(e_phi, dl)
    return np.stack([np.stack([np.sum(e_theta * nl, -1), np.sum(e_theta * el, -1)], -1),
                     np.stack([np.sum(e_phi * nl, -1), np.sum(e_phi * el, -1)], -1)], -2)


def element_jones(response, model: ElementModel, axes: np.ndarray, set_freq: np.ndarray,
                  d: np.ndarray, north: np.ndarray, east: np.ndarray) -> np.ndarray:
    """Element Jones (nset, ndir, 2, 2) of a station frame in the sky (North, East) basis.

    ``response`` is ``everybeam.ElementResponse.create(model.name)``; ``set_freq`` (Hz)
    from :func:`element_frequency_sets`; ``d``, ``north``, ``east`` (ndir, 3) ITRF.
    Zero below the station horizon.
    """
    theta, phi, dl = station_angles(axes, d)
    rot = sky_rotation(axes, d, north, east)
    ndir = len(d)
    out = np.empty((set_freq.size, ndir, 2, 2), complex)
    for i, f in enumerate(set_freq):
        fr = np.full(ndir, float(f))
        if model.per_element_call:
            h = response.response(np.zeros(ndir, np.int32), fr, theta, phi)
        else:
            h = response.response(fr, theta, phi)
        out[i] = np.einsum("dij,djk->dik", np.asarray(h).reshape(ndir, 2, 2), rot)
    out[:, dl[:, 2] < 0] = 0
    return out


def _uniform_step(freq: np.ndarray) -> tuple[bool, float]:
    """(True, step) if ``freq`` is evenly spaced to 1 mHz, else (False, 0)."""
    if freq.size < 2:
        return True, 0.0
    step = (freq[-1] - freq[0]) / (freq.size - 1)
    even = np.max(np.abs(freq - (freq[0] + step * np.arange(freq.size)))) < 1e-3
    return bool(even), float(step) if even else 0.0


class SkaLowBeam(BeamModel):
    """SKA-Low station beams evaluated like EveryBeam's ``station_response``, vectorised.

    Parameters
    ----------
    array : msleak.io.phased_array.PhasedArray
        The PHASED_ARRAY contents (one row per ANTENNA row).
    phase_centre, delay_dir : (float, float)
        J2000 (ra, dec), rad: FIELD::PHASE_DIR and FIELD::DELAY_DIR (beam-former
        direction).
    station_names : list of str, optional
    element_model : str
        A key of :data:`ELEMENT_MODELS` or ``default`` (``oskar_dipole_cos``).
    used_stations : int array, optional
        The ANTENNA rows the beam is for (default all).
    element_gains : list of (nelem, 2) complex arrays, optional
        Per station, element and feed a complex gain on the beam-former weight (errors of
        the model, :func:`msleak.beam.errors.perturb_phased_array`); default 1.
    """

    name = "everybeam"

    def __init__(self, array, phase_centre, delay_dir, station_names=None,
                 element_model: str = "default", used_stations=None, element_gains=None):
        self.model = check_element_model(element_model)
        super().__init__(len(array), phase_centre, station_names, used_stations)
        self.array = array
        self.delay_dir = (float(delay_dir[0]), float(delay_dir[1]))
        self._response = import_everybeam().ElementResponse.create(self.model.name)
        n = len(array)
        nmax = max(len(o) for o in array.element_offsets)
        self._pos = np.zeros((n, nmax, 3))
        self._w = np.zeros((n, 2, nmax))
        self._wi = np.zeros((n, 2, nmax))
        self._nelem = np.array([len(o) for o in array.element_offsets], dtype=np.int64)
        self._up = np.ascontiguousarray(array.axes[:, 2])
        groups: dict[bytes, int] = {}
        self._group_axes: list[np.ndarray] = []
        self._station_group = np.zeros(n, dtype=np.int64)
        for i, (axes, off, flag) in enumerate(zip(array.axes, array.element_offsets,
                                                  array.element_flags)):
            # EveryBeam projects offsets and directions on the axes: x . d -> (A x) . (A d)
            self._pos[i, :len(off)] = off @ (axes.T @ axes)
            on = ~np.asarray(flag, dtype=bool)
            count = on.sum(axis=0)
            if np.any(count == 0):
                log.warning("station %s has every element of a feed flagged: its beam is "
                            "zero for that feed", self.station_names[i])
            weight = (on / np.maximum(count, 1)).T
            if element_gains is not None:            # (nelem, 2) complex per station
                weight = weight * np.asarray(element_gains[i]).T
            self._w[i, :, :len(off)] = np.real(weight)
            self._wi[i, :, :len(off)] = np.imag(weight)
            key = np.round(axes, 12).tobytes()
            if key not in groups:
                groups[key] = len(self._group_axes)
                self._group_axes.append(np.array(axes))
            self._station_group[i] = groups[key]
        log.info("SKA-Low beam (%s): %d stations, %d element-response groups",
                 self.model.name, n, len(self._group_axes))

    def _directions(self, time: float, ra: np.ndarray, dec: np.ndarray):
        """ITRF directions (ndir, 3), delay direction (3,) and the J2000 pole (3,)."""
        u = radec_to_unit(ra, clip_pole(dec))
        s0u = radec_to_unit(self.delay_dir[0], clip_pole(self.delay_dir[1]))
        fitmap = itrf_map(time, np.vstack([u, s0u]))
        return fitmap(u), fitmap(s0u), fitmap.pole()

    def _jones(self, time, freq, ra, dec, stations, dtype):
        check_band(self.model, freq)
        out = np.empty((stations.size, time.size, freq.size, ra.size, 2, 2), dtype)
        if out.size == 0:
            return out
        set_freq, chan_set = element_frequency_sets(self.model, freq)
        uniform, df = _uniform_step(freq)
        used, local_group = np.unique(self._station_group[stations], return_inverse=True)
        pos, w, wi = self._pos[stations], self._w[stations], self._wi[stations]
        nelem, up = self._nelem[stations], self._up[stations]
        for it, t in enumerate(time):
            d, s0, ncp = self._directions(float(t), ra, dec)
            north, east = sky_basis(d, ncp)
            ej = np.empty((used.size, set_freq.size, ra.size, 2, 2), complex)
            for i, g in enumerate(used):
                ej[i] = element_jones(self._response, self.model, self._group_axes[g],
                                      set_freq, d, north, east)
            ska_low_station_kernel(d, s0, freq, uniform, df, pos, w, wi, nelem, up,
                                   local_group.astype(np.int64), chan_set, ej, out[:, it])
        return out
