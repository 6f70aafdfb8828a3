"""Primary beams: Jones matrices per station, time, channel and direction, and Mueller maps.

:func:`load_beam` loads a model for a Measurement Set: ``everybeam`` (LOFAR HBA and
SKA-Low through msleak's fast evaluators, other telescopes through EveryBeam),
``everybeam-direct`` (EveryBeam's own calls), ``uvbeam`` (a UVBeam/beamfits file, HERA's by
default), ``hyperbeam`` (the MWA tile through mwa_hyperbeam), ``dipole`` (analytic, any
MS) or ``none`` (identity). All
return ``J[station, time, channel, direction, 2, 2]`` (rows: feeds X, Y; columns: sky
North, East), zero below the horizon; ``centre_correction=True`` gives ``J(s0)^-1 J(s)``.
Mueller matrices and maps come from :mod:`msleak.beam.mueller` and the map functions.

Models, conventions and accuracy: docs/beam.md.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

from msleak.beam.base import (BEAM_NAMES, BeamModel, BeamName, BeamUnavailable, IdentityBeam,
                              invert_2x2)
from msleak.beam.mueller import jones_to_mueller, leakage, polarized_beam, to_db
from msleak.errors import InputError

__all__ = [
    "BeamName", "BeamModel", "BEAM_NAMES", "BeamUnavailable", "load_beam", "beam_options",
    "IdentityBeam",
    "invert_2x2",
    "jones_to_mueller", "polarized_beam", "leakage", "to_db",
]

log = logging.getLogger(__name__)


def load_beam(model: BeamName, ms: str | os.PathLike, *, field_id: int | None = None,
              ddid: int | None = None, stations=None, **options) -> BeamModel:
    """The beam model ``model`` for the stations and field of ``ms``.

    Parameters
    ----------
    model : {'everybeam', 'everybeam-direct', 'uvbeam', 'hyperbeam', 'dipole', 'none'}
    ms : path
        Measurement Set.
    field_id, ddid : int, optional
        The main-table rows the beam is for (all when None): their antennas are the
        model's :attr:`~BeamModel.used_stations`; FIELD ``field_id`` (default 0) gives the
        phase centre.
    stations : int array, optional
        ANTENNA rows to use instead of those of the rows.
    **options
        ``everybeam``/``everybeam-direct``: ``element_model`` (EveryBeam element response
        model name, default Hamaker for LOFAR).  ``uvbeam``: ``beam_file`` (default
        pyuvsim's HERA beam).  ``hyperbeam``: ``element_model`` ('analytic' or 'fee'),
        ``beam_file`` (the FEE model's HDF5 file).  ``dipole``: ``factor``
        ('airy' | 'gaussian' | 'none'), ``diameter_m``, ``feed_angle_deg``,
        ``ground_plane_height_m`` (see :class:`msleak.beam.dipole.DipoleBeam`).

    Raises
    ------
    InputError
        Unknown model or options.
    BeamUnavailable
        An MS the model cannot describe (the message names ``--beam dipole``, or the
        setting EveryBeam lacks).
    """
    from msleak.io.ms import check_ms, read_antennas, read_fields, read_used_antennas

    ms = check_ms(ms)
    if model not in BEAM_NAMES:
        raise InputError(f"unknown beam {model!r}: use one of {', '.join(BEAM_NAMES)}")
    fields = read_fields(ms)
    field_row = 0 if field_id is None else int(field_id)
    if not 0 <= field_row < len(fields):
        raise InputError(f"{ms}: no FIELD_ID {field_row} (the MS has {len(fields)})")
    used = read_used_antennas(ms, field_id, ddid) if stations is None else stations
    if model == "none":
        _no_options(model, options)
        antennas = read_antennas(ms)
        field = fields[field_row]
        return IdentityBeam(len(antennas), (field.ra, field.dec), antennas.names, used)
    if model == "dipole":
        from msleak.beam.dipole import DipoleBeam

        allowed = {"factor", "diameter_m", "feed_angle_deg", "ground_plane_height_m"}
        _check_options(model, options, allowed)
        return DipoleBeam.from_ms(ms, field_id=field_row, used_stations=used, **options)
    if model == "uvbeam":
        from msleak.beam.uvbeam import UVBeamModel

        _check_options(model, options, {"beam_file"})
        return UVBeamModel.from_ms(ms, field_id=field_row, used_stations=used, **options)
    if model == "hyperbeam":
        from msleak.beam.mwa import MwaBeam

        _check_options(model, options, {"element_model", "beam_file"})
        return MwaBeam.from_ms(ms, field_id=field_row, used_stations=used, **options)
    _check_options(model, options, {"element_model"})
    element_model = options.get("element_model", "default")
    if model == "everybeam":
        fast = _try_fast(ms, element_model, field_row, used, ddid)
        if fast is not None:
            return fast
    from msleak.beam.everybeam_direct import EveryBeamDirect

    return EveryBeamDirect(ms, element_model=element_model, field_id=field_row,
                           used_stations=used)


def beam_options(model: str, *, diameter: float | None = None,
                 element_model: str | None = None,
                 beam_file: str | os.PathLike | None = None) -> dict:
    """The :func:`load_beam` options of the command-line settings ``--diameter``,
    ``--element-model`` and ``--beam-file`` (None: not given).

    Raises
    ------
    InputError
        A setting the model does not take, or a diameter that is not positive.
    """
    takes = {"diameter": ("dipole",), "element_model": ("everybeam", "everybeam-direct",
                                                        "hyperbeam"),
             "beam_file": ("uvbeam", "hyperbeam")}
    given = {"diameter": diameter, "element_model": element_model, "beam_file": beam_file}
    for name, value in given.items():
        if value is not None and model not in takes[name]:
            raise InputError(f"--{name.replace('_', '-')} applies to --beam "
                             f"{' or '.join(takes[name])} only, not --beam {model}")
    if diameter is not None and not diameter > 0:
        raise InputError(f"--diameter takes a positive station diameter (m), got {diameter}")
    options = {"diameter_m": None if diameter is None else float(diameter),
               "element_model": element_model,
               "beam_file": None if beam_file is None else str(beam_file)}
    return {k: v for k, v in options.items() if v is not None}


def _try_fast(ms: Path, element_model: str, field_id: int, used, ddid: int | None = None):
    """The fast evaluator of a LOFAR HBA MS with its LOFAR tables or of an SKA-Low MS with
    its PHASED_ARRAY table, else None (EveryBeam directly, which says why it cannot read an
    MS)."""
    from msleak.beam.lofar_array import read_lofar_array
    from msleak.io.ms import has_lofar_tables, read_data_descriptions, read_telescope_name
    from msleak.io.phased_array import has_phased_array

    telescope = read_telescope_name(ms).upper()
    if telescope == "SKA-LOW" and has_phased_array(ms):
        from msleak.beam.ska_low import SkaLowBeam

        spw = None if ddid is None else read_data_descriptions(ms)[ddid][0]
        return SkaLowBeam.from_ms(ms, element_model=element_model, field_id=field_id,
                                  used_stations=used, spw=spw)
    if telescope != "LOFAR" or not has_lofar_tables(ms):
        log.info("%s: telescope %r without LOFAR tables: using EveryBeam directly (slow)", ms,
                 telescope)
        return None
    if element_model not in ("default", "hamaker"):
        log.info("element model %r: using EveryBeam directly (slow)", element_model)
        return None
    array = read_lofar_array(ms, field_id)
    if any(f.name == "LBA" for s in array.stations for f in s.fields):
        log.info("%s has LBA fields: using EveryBeam directly (slow)", ms)
        return None
    from msleak.beam.lofar_fast import LofarFastBeam

    return LofarFastBeam(array, used_stations=used)


def _no_options(model: str, options: dict) -> None:
    _check_options(model, options, set())


def _check_options(model: str, options: dict, allowed: set) -> None:
    unknown = sorted(set(options) - allowed)
    if unknown:
        raise InputError(f"beam {model!r} takes no option {', '.join(unknown)}"
                         + (f" (allowed: {', '.join(sorted(allowed))})" if allowed else ""))
