"""Errors of the beam model: the stations as built rather than as designed
(docs/beam.md, "Beam-model errors").

:class:`BeamErrors` draws, per station and reproducibly from a seed, failed elements (a
fraction of the tiles of every antenna field switched off, as LOFAR_ANTENNA_FIELD's
ELEMENT_FLAG does) and a rotation error of the station about its field normal (its
COORDINATE_AXES, tile and element offsets turned together about each field's centre).
:func:`perturb_lofar` applies
them to a :class:`~msleak.beam.lofar_array.LofarArray`; zero errors return the array itself,
so the beam is unchanged bit for bit.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace

import numpy as np

from msleak.beam.lofar_array import LofarArray, LofarField
from msleak.errors import InputError

__all__ = ["BeamErrors", "perturb_lofar", "rotation_about"]


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
    seed : int
        The errors of station ``k`` depend on ``seed`` and ``k`` alone.
    """

    failed: float = 0.0
    rotation_deg: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 <= float(self.failed) < 1.0:
            raise InputError(f"beam_errors: failed must be a fraction in [0, 1), got "
                             f"{self.failed}", param="beam_errors")
        if not (math.isfinite(float(self.rotation_deg)) and self.rotation_deg >= 0):
            raise InputError(f"beam_errors: rotation must be a non-negative rms in degrees, "
                             f"got {self.rotation_deg}", param="beam_errors")

    @property
    def none(self) -> bool:
        """No error at all."""
        return self.failed == 0 and self.rotation_deg == 0

    @classmethod
    def parse(cls, text: str) -> "BeamErrors":
        """From ``"failed=0.05,rotation=0.5,seed=1"`` (any subset, in any order)."""
        values = {}
        for part in filter(None, (p.strip() for p in str(text).split(","))):
            match = re.fullmatch(r"(failed|rotation|seed)=([^=]+)", part)
            if not match:
                raise InputError(f"beam_errors {text!r}: give failed=FRACTION, "
                                 "rotation=DEG and seed=N, comma separated",
                                 param="beam_errors")
            key, value = match.groups()
            try:
                values[key] = int(value) if key == "seed" else float(value)
            except ValueError:
                raise InputError(f"beam_errors {text!r}: {key} {value!r} is not a number",
                                 param="beam_errors") from None
        return cls(failed=values.get("failed", 0.0),
                   rotation_deg=values.get("rotation", 0.0), seed=values.get("seed", 0))

    def describe(self) -> str:
        """The settings as :meth:`parse` reads them."""
        return f"failed={self.failed:g},rotation={self.rotation_deg:g},seed={self.seed}"


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
