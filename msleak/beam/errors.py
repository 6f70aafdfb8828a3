"""Errors of the beam model: the stations as built rather than as designed
(docs/beam.md, "Beam-model errors").

:class:`BeamErrors` draws, per station and reproducibly from a seed, failed elements (a
fraction of the elements switched off, as the ELEMENT_FLAG of LOFAR_ANTENNA_FIELD and
PHASED_ARRAY does), a rotation error of the station about its normal (axes and element
offsets turned together about the field's centre) and, for SKA-Low, complex gain errors of
every element and feed. :func:`perturb_lofar` applies them to a
:class:`~msleak.beam.lofar_array.LofarArray`, :func:`perturb_phased_array` to SKA-Low's
PHASED_ARRAY; zero errors return the array itself, so the beam is unchanged bit for bit.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace

import numpy as np

from msleak.beam.lofar_array import LofarArray, LofarField
from msleak.errors import InputError

__all__ = ["BeamErrors", "perturb_lofar", "perturb_phased_array", "rotation_about"]


@dataclass(frozen=True)
class BeamErrors:
    """Beam-model errors.

    Parameters
    ----------
    failed : float
        Fraction of the tiles of each antenna field that have failed, 0 <= failed < 1
        (rounded to whole tiles per field; the tiles are drawn at random).
    rotation_deg : float
        rms (deg) of each station's rotation error about its field normal (Gaussian).
    amplitude : float
        rms of the fractional amplitude error of each element's gain, per feed (SKA-Low).
    phase_deg : float
        rms (deg) of the phase error of each element's gain, per feed (SKA-Low).
    seed : int
        The errors of station ``k`` depend on ``seed`` and ``k`` alone.
    """

    failed: float = 0.0
    rotation_deg: float = 0.0
    seed: int = 0
    amplitude: float = 0.0
    phase_deg: float = 0.0

    def __post_init__(self) -> None:
        if not 0.0 <= float(self.failed) < 1.0:
            raise InputError(f"beam_errors: failed must be a fraction in [0, 1), got "
                             f"{self.failed}", param="beam_errors")
        for key, value in (("rotation", self.rotation_deg), ("amplitude", self.amplitude),
                           ("phase", self.phase_deg)):
            if not (math.isfinite(float(value)) and value >= 0):
                raise InputError(f"beam_errors: {key} must be a non-negative rms, got {value}",
                                 param="beam_errors")

    @property
    def none(self) -> bool:
        """No error at all."""
        return self.failed == 0 and self.rotation_deg == 0 and not self.gains

    @property
    def gains(self) -> bool:
        """Gain errors (amplitude or phase) are asked for."""
        return self.amplitude != 0 or self.phase_deg != 0

    @classmethod
    def parse(cls, text: str) -> "BeamErrors":
        """From ``"failed=0.05,rotation=0.5,amplitude=0.02,phase=2,seed=1"`` (any subset,
        in any order)."""
        values = {}
        for part in filter(None, (p.strip() for p in str(text).split(","))):
            match = re.fullmatch(r"(failed|rotation|amplitude|phase|seed)=([^=]+)", part)
            if not match:
                raise InputError(f"beam_errors {text!r}: give failed=FRACTION, "
                                 "rotation=DEG, amplitude=FRACTION, phase=DEG and seed=N, "
                                 "comma separated", param="beam_errors")
            key, value = match.groups()
            try:
                values[key] = int(value) if key == "seed" else float(value)
            except ValueError:
                raise InputError(f"beam_errors {text!r}: {key} {value!r} is not a number",
                                 param="beam_errors") from None
        return cls(failed=values.get("failed", 0.0), rotation_deg=values.get("rotation", 0.0),
                   seed=values.get("seed", 0), amplitude=values.get("amplitude", 0.0),
                   phase_deg=values.get("phase", 0.0))

    def describe(self) -> str:
        """The settings as :meth:`parse` reads them."""
        return (f"failed={self.failed:g},rotation={self.rotation_deg:g},"
                f"amplitude={self.amplitude:g},phase={self.phase_deg:g},seed={self.seed}")


def rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """The 3 x 3 rotation by ``angle`` (rad, right-handed) about the unit vector ``axis``."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def perturb_lofar(array: LofarArray, errors: BeamErrors) -> LofarArray:
    """``array`` with ``errors`` drawn per station (its index ``k`` in ``array.stations``):
    one angle per station turns the tiles and elements of each of its fields about the
    field's own centre, about the normal of the station's first field, and
    ``round(failed * ntile)`` tiles of each field are switched off (field centres and phase
    references stay)."""
    if errors.none:
        return array
    stations = []
    for k, station in enumerate(array.stations):
        rng = np.random.default_rng([int(errors.seed), k])
        angle = math.radians(errors.rotation_deg) * rng.standard_normal()
        turn = rotation_about(station.fields[0].axes[2], angle)
        fields = tuple(_perturb_field(f, turn, errors.failed, rng) for f in station.fields)
        stations.append(replace(station, fields=fields))
    return replace(array, stations=tuple(stations))


def _perturb_field(field: LofarField, turn: np.ndarray, failed: float,
                   rng: np.random.Generator) -> LofarField:
    """A field turned by ``turn`` (3 x 3, ITRF) with a fraction ``failed`` of its tiles off."""
    enabled = np.array(field.tile_enabled, dtype=bool)
    n_off = int(round(failed * enabled.size))
    if n_off:
        enabled[rng.choice(enabled.size, size=n_off, replace=False)] = False
    return replace(field, axes=field.axes @ turn.T, tile_offsets=field.tile_offsets @ turn.T,
                   tile_enabled=enabled,
                   element_offsets=None if field.element_offsets is None
                   else field.element_offsets @ turn.T)


def perturb_phased_array(array, errors: BeamErrors) -> tuple:
    """SKA-Low's PHASED_ARRAY contents (:class:`msleak.io.phased_array.PhasedArray`) with
    ``errors`` drawn per station ``k``: the station's axes and element offsets turned about
    its Up axis, ``round(failed * nelem)`` elements flagged (both feeds), and the complex
    gains (nstation list of (nelem, 2)) ``(1 + amplitude g1) exp(i phase g2)``, g1, g2
    standard normal, per element and feed (None without gain errors). Zero errors: the
    array itself and None."""
    if errors.none:
        return array, None
    axes, offsets, flags, gains = [], [], [], []
    for k, (ax, off, flag) in enumerate(zip(array.axes, array.element_offsets,
                                            array.element_flags)):
        rng = np.random.default_rng([int(errors.seed), k])
        turn = rotation_about(ax[2], math.radians(errors.rotation_deg) * rng.standard_normal())
        flag = np.array(flag, dtype=bool)
        n_off = int(round(errors.failed * len(off)))
        if n_off:
            flag[rng.choice(len(off), size=n_off, replace=False)] = True
        shape = (len(off), 2)
        amp = 1.0 + errors.amplitude * rng.standard_normal(shape)
        phase = math.radians(errors.phase_deg) * rng.standard_normal(shape)
        gains.append(amp * np.exp(1j * phase))
        axes.append(np.asarray(ax) @ turn.T)
        offsets.append(np.asarray(off) @ turn.T)
        flags.append(flag)
    return (replace(array, axes=np.array(axes), element_offsets=offsets, element_flags=flags),
            gains if errors.gains else None)
