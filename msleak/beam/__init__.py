"""Primary beams: Jones matrices per station, time, channel and direction, and Mueller maps.

The models (:mod:`msleak.beam.lofar_fast`, :mod:`~msleak.beam.ska_low`,
:mod:`~msleak.beam.uvbeam`, :mod:`~msleak.beam.mwa`, :mod:`~msleak.beam.dipole` and the
identity) are built from arrays; :func:`msleak.adapters.beams.load_beam` reads an MS and
builds one. All return ``J[station, time, channel, direction, 2, 2]`` (rows: feeds X, Y;
columns: sky North, East), zero below the horizon; ``centre_correction=True`` gives
``J(s0)^-1 J(s)``. Mueller matrices and maps come from :mod:`msleak.beam.mueller` and
:mod:`msleak.beam.maps`.

Models, conventions and accuracy: docs/beam.md.
"""

from __future__ import annotations

from msleak.beam.base import BEAM_NAMES, BeamModel, BeamName, IdentityBeam, invert_2x2
from msleak.beam.mueller import jones_to_mueller, leakage, polarized_beam, to_db
from msleak.errors import BeamUnavailable

__all__ = [
    "BeamName", "BeamModel", "BEAM_NAMES", "BeamUnavailable",
    "IdentityBeam",
    "invert_2x2",
    "jones_to_mueller", "polarized_beam", "leakage", "to_db",
]
