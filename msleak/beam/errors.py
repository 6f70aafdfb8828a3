"""Errors of the beam model: the stations as built rather than as designed
(docs/beam.md, "Beam-model errors").

:class:`BeamErrors` draws, per station and reproducibly from a seed, failed elements (a
fraction of the elements switched off, as the ELEMENT_FLAG of LOFAR_ANTENNA_FIELD and
PHASED_ARRAY does), a rotation error of the station about its normal (axes and element
offsets turned together about the field's centre) and complex gain errors per feed (X, Y)
of every element (SKA-Low; LOFAR HBA: every dipole pair of every tile, or every tile).
:func:`perturb_lofar` applies them to a :class:`~msleak.beam.lofar_array.LofarArray`,
:func:`perturb_phased_array` to SKA-Low's PHASED_ARRAY; zero errors return the array
itself, so the beam is unchanged bit for bit.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace

import numpy as np

from msleak.beam.lofar_array import LofarArray, LofarField
from msleak.errors import InputError

__all__ = ["BeamErrors", "GAIN_LEVELS", "perturb_lofar", "perturb_phased_array",
           "rotation_about", "draw_gains"]

#: Where LOFAR HBA gain errors sit: every tile element (dipole pair), or every tile.
GAIN_LEVELS = ("element", "tile")


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
        rms of the fractional amplitude error of each gain, per feed: the gain is
        ``(1 + amplitude g1) exp(i phase g2)``, g1 and g2 standard normal, drawn for each
        feed (X, Y) separately, so the X and Y station beams differ.
    phase_deg : float
        rms (deg) of the phase error of each gain, per feed.
    seed : int
        The errors of station ``k`` depend on ``seed`` and ``k`` alone.
    level : {'element', 'tile'}
        Where the LOFAR HBA gains sit: ``element``, every dipole pair of every 16-element
        tile (the analogue tile beam former, which no station calibration corrects);
        ``tile``, one gain per tile and feed (the digital station beam former's inputs,
        what station calibration leaves). SKA-Low: ``element`` only (every antenna).
        The array factors keep the normalisation of the model without errors.
    """

    failed: float = 0.0
    rotation_deg: float = 0.0
    seed: int = 0
    amplitude: float = 0.0
    phase_deg: float = 0.0
    level: str = "element"

    def __post_init__(self) -> None:
        if self.level not in GAIN_LEVELS:
            raise InputError(f"beam_errors: level must be one of {', '.join(GAIN_LEVELS)}, "
                             f"got {self.level!r}", param="beam_errors")
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
        """From ``"failed=0.05,rotation=0.5,amplitude=0.02,phase=2,level=tile,seed=1"``
        (any subset, in any order)."""
        values = {}
        for part in filter(None, (p.strip() for p in str(text).split(","))):
            match = re.fullmatch(r"(failed|rotation|amplitude|phase|level|seed)=([^=]+)",
                                 part)
            if not match:
                raise InputError(f"beam_errors {text!r}: give failed=FRACTION, "
                                 "rotation=DEG, amplitude=FRACTION, phase=DEG, "
                                 "level=element|tile and seed=N, comma separated",
                                 param="beam_errors")
            key, value = match.groups()
            if key == "level":
                values[key] = value
                continue
            try:
                values[key] = int(value) if key == "seed" else float(value)
            except ValueError:
                raise InputError(f"beam_errors {text!r}: {key} {value!r} is not a number",
                                 param="beam_errors") from None
        return cls(failed=values.get("failed", 0.0), rotation_deg=values.get("rotation", 0.0),
                   seed=values.get("seed", 0), amplitude=values.get("amplitude", 0.0),
                   phase_deg=values.get("phase", 0.0), level=values.get("level", "element"))

    def describe(self) -> str:
        """The settings as :meth:`parse` reads them."""
        return (f"failed={self.failed:g},rotation={self.rotation_deg:g},"
                f"amplitude={self.amplitude:g},phase={self.phase_deg:g},"
                f"level={self.level},seed={self.seed}")


def rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """The 3 x 3 rotation by ``angle`` (rad, right-handed) about the unit vector ``axis``."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def perturb_lofar(array: LofarArray, errors: BeamErrors) -> LofarArray:
    """``array`` with ``errors`` drawn per station (its index ``k`` in ``array.stations``):
    one angle per station turns the tiles and elements of each of its fields about the
    field's own centre, about the normal of the station's first field,
    ``round(failed * ntile)`` tiles of each field are switched off (field centres and phase
    references stay) and, with gain errors, every field gets its ``element_gains``
    (:func:`draw_gains` per tile, element and feed, or per tile and feed for
    ``level='tile'``; drawn after the rotation and the failures from the same stream, for
    failed tiles too, so that adding gains leaves those draws as they were)."""
    if errors.none:
        return array
    stations = []
    for k, station in enumerate(array.stations):
        rng = np.random.default_rng([int(errors.seed), k])
        angle = math.radians(errors.rotation_deg) * rng.standard_normal()
        turn = rotation_about(station.fields[0].axes[2], angle)
        fields = tuple(_perturb_field(f, turn, errors.failed, rng) for f in station.fields)
        if errors.gains:
            fields = tuple(replace(f, element_gains=_tile_gains(f, errors, rng))
                           for f in fields)
        stations.append(replace(station, fields=fields))
    return replace(array, stations=tuple(stations))


def draw_gains(rng: np.random.Generator, shape: tuple, errors: BeamErrors) -> np.ndarray:
    """Complex gains ``(1 + amplitude g1) exp(i phase g2)`` of ``shape``, g1 and g2 standard
    normal (all g1 drawn first, then all g2)."""
    amp = 1.0 + errors.amplitude * rng.standard_normal(shape)
    phase = math.radians(errors.phase_deg) * rng.standard_normal(shape)
    return amp * np.exp(1j * phase)


def _tile_gains(field: LofarField, errors: BeamErrors, rng: np.random.Generator
                ) -> np.ndarray:
    """(ntile, nelem, 2) gains of a field's tile elements per feed (X, Y); None for a
    field without tiles (LBA)."""
    if field.element_offsets is None:
        return None
    ntile, nelem = len(field.tile_offsets), len(field.element_offsets)
    if errors.level == "tile":
        return np.repeat(draw_gains(rng, (ntile, 1, 2), errors), nelem, axis=1)
    return draw_gains(rng, (ntile, nelem, 2), errors)


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
        gains.append(draw_gains(rng, (len(off), 2), errors))
        axes.append(np.asarray(ax) @ turn.T)
        offsets.append(np.asarray(off) @ turn.T)
        flags.append(flag)
    return (replace(array, axes=np.array(axes), element_offsets=offsets, element_flags=flags),
            gains if errors.gains else None)
