"""Beam files for the ``uvbeam`` beam: read with pyuvdata's UVBeam and checked (docs/hera.md).

:func:`read_beam_file` refuses, in one line, what msleak cannot turn into Jones matrices:
unreadable files, power beams, feeds other than x and y, basis vectors not along azimuth
and zenith angle, steerable or phased-array antennas, and az/za grids that do not cover
the sky above the horizon.  :func:`default_beam_file` is pyuvsim's HERA beam.
"""

from __future__ import annotations

import importlib.resources
import os
import warnings
from pathlib import Path

import numpy as np

from msleak.errors import BeamUnavailable, InputError

try:
    from pyuvdata import UVBeam
except ImportError:  # the [hera] extra is optional; the beam model says how to install it
    UVBeam = None

__all__ = ["default_beam_file", "read_beam_file", "have_pyuvdata"]

_REMEDY = "give an E-field beam with `beam_file=PATH`"


def have_pyuvdata() -> bool:
    """Whether pyuvdata (the ``[hera]`` extra) is importable."""
    return UVBeam is not None


def default_beam_file() -> Path:
    """pyuvsim's HERA beam, ``HERA_NicCST.beamfits`` (BeamUnavailable without pyuvsim)."""
    try:
        path = importlib.resources.files("pyuvsim").joinpath("data", "HERA_NicCST.beamfits")
    except ModuleNotFoundError:
        raise BeamUnavailable("the default uvbeam beam file (HERA_NicCST.beamfits) comes "
                              "with pyuvsim, which is not installed",
                              remedy="pip install 'msleak[hera]', or give a beam with "
                                     "`beam_file=PATH`") from None
    return Path(str(path))


def read_beam_file(path: str | os.PathLike):
    """Read ``path`` with pyuvdata's UVBeam and check msleak can make Jones matrices of it.

    Raises
    ------
    InputError
        Unreadable, not an E-field beam, not x/y feeds, basis vectors not along az/za,
        a phased-array beam, or an az/za grid not covering the sky above the horizon.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such beam file; {_REMEDY}")
    try:
        with warnings.catch_warnings():  # files without mount_type: pyuvdata assumes "fixed"
            warnings.filterwarnings("ignore", message="The mount_type parameter must be set")
            beam = UVBeam.from_file(str(path))
    except Exception as err:  # noqa: BLE001 - pyuvdata raises many types for bad files
        reason = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise InputError(f"{path}: UVBeam cannot read it ({reason}); {_REMEDY}") from None
    if beam.beam_type != "efield":
        raise InputError(f"{path}: a {beam.beam_type} beam, not an E-field beam; Jones "
                         f"matrices need the E-field: {_REMEDY}")
    if getattr(beam, "mount_type", None) not in (None, "fixed"):
        raise InputError(f"{path}: a beam of an antenna with mount type {beam.mount_type!r}; "
                         f"msleak reads beams fixed on the ground (zenith-pointing): {_REMEDY}")
    if beam.antenna_type != "simple":
        raise InputError(f"{path}: a {beam.antenna_type} UVBeam (per-element beams); msleak "
                         f"reads simple antennas only: {_REMEDY}")
    feeds = [str(f).lower() for f in beam.feed_array]
    if sorted(feeds) != ["x", "y"]:
        raise InputError(f"{path}: feeds {', '.join(feeds)}; msleak needs the feeds x and y: "
                         f"{_REMEDY}")
    if getattr(beam, "feed_angle", None) is None:
        raise InputError(f"{path}: its feeds have no orientation (feed_angle); msleak needs "
                         f"it to tell the North-South feed from the East-West one: {_REMEDY}")
    basis = beam.basis_vector_array
    if (beam.Naxes_vec != 2 or basis is None or np.any(basis[0, 1] != 0)
            or np.any(basis[1, 0] != 0)):
        raise InputError(f"{path}: its E-field is not given along azimuth and zenith angle "
                         f"(Naxes_vec {beam.Naxes_vec}); {_REMEDY}")
    _check_sky_coverage(path, beam)
    return beam


def _check_sky_coverage(path: Path, beam) -> None:
    """Refuse a grid other than az/za covering every azimuth and zenith angles 0-90 deg."""
    if beam.pixel_coordinate_system != "az_za":
        raise InputError(f"{path}: pixel coordinate system {beam.pixel_coordinate_system!r}; "
                         f"msleak interpolates az_za beams: {_REMEDY}")
    az, za = np.asarray(beam.axis1_array), np.asarray(beam.axis2_array)
    step = float(np.diff(az)[0]) if az.size > 1 else 0.0
    full_circle = az.size > 1 and abs(az[-1] - az[0] + step - 2 * np.pi) <= step
    if not full_circle or za.min() > 1e-9 or za.max() < np.pi / 2 - 1e-9:
        raise InputError(f"{path}: the beam grid covers azimuth {np.degrees(az.min()):g}-"
                         f"{np.degrees(az.max()):g} deg, zenith angle {np.degrees(za.min()):g}-"
                         f"{np.degrees(za.max()):g} deg; msleak needs every azimuth and zenith "
                         f"angles 0-90 deg: {_REMEDY}")
