"""Beam models of a Measurement Set: read through :mod:`msleak.io`, built by :mod:`msleak.beam`.

:func:`load_beam` loads a model for an MS: ``everybeam`` (LOFAR HBA and SKA-Low through
msleak's fast evaluators, other telescopes through EveryBeam), ``everybeam-direct``
(EveryBeam's own calls, :mod:`msleak.adapters.everybeam`), ``uvbeam`` (a UVBeam/beamfits
file, HERA's by default), ``hyperbeam`` (the MWA tile through mwa_hyperbeam), ``dipole``
(analytic, any MS) or ``none`` (identity); :func:`beam_options` turns the beam settings of
a verb into its options. The per-model loaders (:func:`dipole_from_ms`,
:func:`uvbeam_from_ms`, :func:`mwa_from_ms`, :func:`ska_low_from_ms`,
:func:`read_lofar_array`) read what each model needs and call its array constructor.
Models, conventions and accuracy: docs/beam.md.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from msleak.beam.base import BEAM_NAMES, BeamModel, BeamName, IdentityBeam
from msleak.beam.errors import BeamErrors, perturb_lofar, perturb_phased_array
from msleak.beam.ionosphere import IonosphereBeam
from msleak.beam.lofar_array import LofarArray, lofar_array
from msleak.errors import BeamUnavailable, InputError
from msleak.io.lofar import read_lofar_antenna_fields, read_lofar_phase_references
from msleak.io.ms import (
    check_ms,
    has_lofar_tables,
    read_antennas,
    read_beam_directions,
    read_data_descriptions,
    read_fields,
    read_spectral_windows,
    read_telescope_name,
    read_used_antennas,
)

__all__ = ["load_beam", "beam_options", "dipole_from_ms", "uvbeam_from_ms", "mwa_from_ms",
           "ska_low_from_ms", "read_lofar_array"]

log = logging.getLogger(__name__)


def load_beam(model: BeamName, ms: str | os.PathLike, *, field_id: int | None = None,
              ddid: int | None = None, stations=None, ionosphere=None,
              beam_errors=None, **options) -> BeamModel:
    """The beam model ``model`` for the stations and field of ``ms``.

    Parameters
    ----------
    model : {'everybeam', 'everybeam-direct', 'uvbeam', 'hyperbeam', 'dipole', 'none'}
    ms : path
        Measurement Set.
    field_id, ddid : int, optional
        The main-table rows the beam is for (all when None): their antennas are the
        model's :attr:`~msleak.beam.base.BeamModel.used_stations`; FIELD ``field_id``
        (default 0) gives the phase centre.
    stations : int array, optional
        ANTENNA rows to use instead of those of the rows.
    ionosphere : str or path, optional
        Ionospheric Faraday rotation in front of the beam: a CSV table of RMs or
        ``random:SEED`` (:func:`msleak.adapters.ionosphere.rotation_measures`); the model
        is then a :class:`~msleak.beam.ionosphere.IonosphereBeam`.
    beam_errors : BeamErrors or str, optional
        Errors of the model (:class:`msleak.beam.errors.BeamErrors`, or its text
        ``"failed=F,rotation=DEG,amplitude=A,phase=DEG,level=element,seed=N"``): LOFAR HBA
        and SKA-Low through their fast paths only.
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
        An MS the model cannot describe (the message names the model to use instead, or
        the setting EveryBeam lacks).
    """
    errors = _beam_errors(model, beam_errors)
    if errors is not None:
        options = {**options, "beam_errors": errors}
    beam = _model(model, check_ms(ms), field_id, ddid, stations, options)
    if ionosphere is None:
        return beam
    from msleak.adapters.ionosphere import rotation_measures

    return IonosphereBeam(beam, rotation_measures(ionosphere, ms))


def _model(model: BeamName, ms: Path, field_id, ddid, stations, options: dict) -> BeamModel:
    """:func:`load_beam` without the ionosphere."""
    if model not in BEAM_NAMES:
        raise InputError(f"unknown beam {model!r}: use one of {', '.join(BEAM_NAMES)}")
    fields = read_fields(ms)
    field_row = 0 if field_id is None else int(field_id)
    if not 0 <= field_row < len(fields):
        raise InputError(f"{ms}: no FIELD_ID {field_row} (the MS has {len(fields)})")
    used = read_used_antennas(ms, field_id, ddid) if stations is None else stations
    if model == "none":
        _check_options(model, options, set())
        antennas = read_antennas(ms)
        field = fields[field_row]
        return IdentityBeam(len(antennas), (field.ra, field.dec), antennas.names, used)
    if model in _LOADERS:
        loader, allowed = _LOADERS[model]
        _check_options(model, options, allowed)
        return loader(ms, field_id=field_row, used_stations=used, **options)
    _check_options(model, options, {"element_model", "beam_errors"})
    element_model = options.get("element_model", "default")
    errors = options.get("beam_errors")
    if model == "everybeam":
        fast = _try_fast(ms, element_model, field_row, used, ddid, errors)
        if fast is not None:
            return fast
    if errors is not None:
        raise InputError(f"{ms}: beam errors are modelled for LOFAR HBA and SKA-Low "
                         "through msleak's fast paths only (`beam='everybeam'`, the default "
                         "element model)", param="beam_errors")
    from msleak.adapters.everybeam import EveryBeamDirect

    return EveryBeamDirect(ms, element_model=element_model, field_id=field_row,
                           used_stations=used)


def beam_options(model: str, *, diameter: float | None = None,
                 element_model: str | None = None,
                 beam_file: str | os.PathLike | None = None,
                 ionosphere: str | os.PathLike | None = None,
                 beam_errors: str | BeamErrors | None = None) -> dict:
    """The :func:`load_beam` options of a verb's beam settings ``diameter``,
    ``element_model``, ``beam_file``, ``ionosphere`` and ``beam_errors`` (None: not given;
    beam errors as their text, so that the options are a run's JSON settings).

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
            models = " or ".join(repr(m) for m in takes[name])
            raise InputError(f"{name} applies to beam {models} only, not beam {model!r}",
                             param=(name, "beam"))
    if diameter is not None and not diameter > 0:
        raise InputError(f"diameter takes a positive value (the station's, m), got {diameter}",
                         param=("diameter",))
    options = {"diameter_m": None if diameter is None else float(diameter),
               "element_model": element_model,
               "beam_file": None if beam_file is None else str(beam_file),
               "ionosphere": None if ionosphere is None else str(ionosphere),
               "beam_errors": _errors_text(model, beam_errors)}
    return {k: v for k, v in options.items() if v is not None}


def dipole_from_ms(ms, *, field_id: int = 0, used_stations=None, **options):
    """The dipole beam of the stations ``used_stations`` (ANTENNA rows, default all) of
    ``ms``; phase centre and pointing (:func:`msleak.io.ms.read_beam_directions`:
    DELAY_DIR, else PHASE_DIR) of FIELD ``field_id``; ``options`` as
    :class:`msleak.beam.dipole.DipoleBeam` takes them."""
    from msleak.beam.dipole import DipoleBeam

    antennas = read_antennas(ms)
    directions = read_beam_directions(ms, field_id)
    return DipoleBeam(antennas.positions, antennas.diameter, directions.delay,
                      directions.phase, antennas.names, used_stations=used_stations, **options)


def uvbeam_from_ms(ms, *, field_id: int = 0, used_stations=None,
                   beam_file: str | os.PathLike | None = None):
    """The beam of ``beam_file`` (default :func:`msleak.io.uvbeam.default_beam_file`) for
    the stations ``used_stations`` of ``ms``, phase centre of FIELD ``field_id``.

    Raises
    ------
    BeamUnavailable
        pyuvdata (or, for the default file, pyuvsim) is not installed.
    InputError
        A file :func:`msleak.io.uvbeam.read_beam_file` refuses, or channels outside its
        frequencies.
    """
    from msleak.beam.uvbeam import UVBeamModel, check_frequencies
    from msleak.io.uvbeam import default_beam_file, have_pyuvdata, read_beam_file

    if not have_pyuvdata():
        raise BeamUnavailable("beam 'uvbeam' needs the Python package pyuvdata",
                              remedy="pip install 'msleak[hera]'")
    ms = check_ms(ms)
    path = default_beam_file() if beam_file is None else Path(beam_file)
    beam = read_beam_file(path)
    for window in read_spectral_windows(ms):
        try:
            check_frequencies(window.freq, beam.freq_array, path.name)
        except InputError as err:
            raise InputError(f"{ms}: {err}") from None
    antennas = read_antennas(ms)
    directions = read_beam_directions(ms, field_id)
    log.info("uvbeam: %s, %d feeds (x at %.1f deg from North), %g-%g MHz", path.name,
             beam.Nfeeds, np.degrees(beam.feed_angle[list(beam.feed_array).index("x")]),
             beam.freq_array.min() / 1e6, beam.freq_array.max() / 1e6)
    return UVBeamModel(beam, antennas.positions, directions.phase, antennas.names,
                       used_stations=used_stations, name=path.name)


def mwa_from_ms(ms, *, field_id: int = 0, used_stations=None, element_model=None,
                beam_file=None):
    """The hyperbeam beam of ``ms``: delays from MWA_TILE_POINTING (zenith without it),
    phase centre of FIELD ``field_id``; every channel must lie in the model's band."""
    from msleak.beam.mwa import ELEMENT_MODELS, MwaBeam, require_hyperbeam
    from msleak.io.mwa import read_mwa_delays

    require_hyperbeam()
    ms = check_ms(ms)
    antennas = read_antennas(ms)
    model = MwaBeam(antennas.positions, read_beam_directions(ms, field_id).phase,
                    antennas.names, used_stations=used_stations,
                    element_model=ELEMENT_MODELS[0] if element_model is None else element_model,
                    beam_file=beam_file, delays=read_mwa_delays(ms))
    for w in read_spectral_windows(ms):
        try:
            model.check_band(w.freq)
        except InputError as err:
            raise InputError(f"{ms}: {err}") from None
    return model


def ska_low_from_ms(ms: str | os.PathLike, element_model: str = "default",
                    field_id: int = 0, used_stations=None, spw: int | None = None,
                    errors: BeamErrors | None = None):
    """The beam of an SKA-Low MS (TELESCOPE_NAME ``SKA-LOW`` with PHASED_ARRAY).

    The channels of SPECTRAL_WINDOW ``spw`` (all when None) must lie in the element
    model's band.

    Raises
    ------
    BeamUnavailable
        Not an SKA-Low MS, or no PHASED_ARRAY subtable.
    InputError
        A refused or unknown element model, or channels outside its band.
    """
    from msleak.beam.ska_low import SkaLowBeam, check_band, check_element_model
    from msleak.io.phased_array import has_phased_array, read_phased_array

    ms = check_ms(ms)
    telescope = read_telescope_name(ms)
    if telescope.upper() != "SKA-LOW":
        raise BeamUnavailable(f"{ms}: TELESCOPE_NAME is {telescope!r}, not 'SKA-LOW', "
                              "so no SKA-Low beam")
    if not has_phased_array(ms):
        raise BeamUnavailable(f"{ms}: no PHASED_ARRAY subtable (the SKA-Low station "
                              "layout), so no SKA-Low beam")
    model = check_element_model(element_model)
    windows = read_spectral_windows(ms)
    if spw is not None and not 0 <= spw < len(windows):
        raise InputError(f"{ms}: no SPECTRAL_WINDOW {spw} (the MS has {len(windows)})")
    for w in windows if spw is None else [windows[spw]]:
        try:
            check_band(model, w.freq)
        except InputError as err:
            raise InputError(f"{ms}: {err}") from None
    directions = read_beam_directions(ms, field_id)
    if errors is not None and errors.gains and errors.level != "element":
        raise InputError(f"{ms}: SKA-Low stations have no tiles, so beam_errors' gains "
                         "take level=element (every antenna), not level=tile",
                         param="beam_errors")
    array, gains = perturb_phased_array(read_phased_array(ms), errors or BeamErrors())
    return SkaLowBeam(array, directions.phase, directions.delay, read_antennas(ms).names,
                      model.name, used_stations, element_gains=gains)


def read_lofar_array(ms: str | os.PathLike, field_id: int = 0) -> LofarArray:
    """The LOFAR station layout of ``ms`` with the pointing of FIELD ``field_id``.

    Raises
    ------
    BeamUnavailable
        The MS lacks a LOFAR table or column the LOFAR beam needs.
    """
    ms = check_ms(ms)
    if not has_lofar_tables(ms):
        raise BeamUnavailable(f"{ms}: no LOFAR_ANTENNA_FIELD table (with "
                              "ANTENNA::LOFAR_PHASE_REFERENCE and FIELD::LOFAR_TILE_BEAM_DIR), "
                              "so no LOFAR beam")
    try:
        return lofar_array(read_antennas(ms).names, read_lofar_antenna_fields(ms),
                           read_lofar_phase_references(ms), read_beam_directions(ms, field_id))
    except BeamUnavailable as err:
        raise BeamUnavailable(f"{ms}: {err.reason}") from None


#: model -> (loader, the options it takes)
_LOADERS = {
    "dipole": (dipole_from_ms, {"factor", "diameter_m", "feed_angle_deg",
                                "ground_plane_height_m"}),
    "uvbeam": (uvbeam_from_ms, {"beam_file"}),
    "hyperbeam": (mwa_from_ms, {"element_model", "beam_file"}),
}


def _try_fast(ms: Path, element_model: str, field_id: int, used, ddid: int | None = None,
              errors=None):
    """The fast evaluator of a LOFAR HBA MS with its LOFAR tables or of an SKA-Low MS with
    its PHASED_ARRAY table, else None (EveryBeam directly, which says why it cannot read an
    MS)."""
    from msleak.io.phased_array import has_phased_array

    telescope = read_telescope_name(ms).upper()
    if telescope == "SKA-LOW" and has_phased_array(ms):
        spw = None if ddid is None else read_data_descriptions(ms)[ddid][0]
        return ska_low_from_ms(ms, element_model=element_model, field_id=field_id,
                               used_stations=used, spw=spw, errors=errors)
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

    return LofarFastBeam(array if errors is None else perturb_lofar(array, errors),
                         used_stations=used)


def _errors_text(model: str, beam_errors) -> str | None:
    errors = _beam_errors(model, beam_errors)
    return None if errors is None else errors.describe()


def _beam_errors(model: str, beam_errors):
    """The :class:`BeamErrors` of a ``beam_errors`` setting (None: none)."""
    if beam_errors is None:
        return None
    errors = beam_errors if isinstance(beam_errors, BeamErrors) else \
        BeamErrors.parse(beam_errors)
    if model != "everybeam":
        raise InputError(f"beam_errors applies to `beam='everybeam'` (LOFAR HBA, SKA-Low) "
                         f"only, not beam {model!r}", param="beam_errors")
    return None if errors.none else errors


def _check_options(model: str, options: dict, allowed: set) -> None:
    unknown = sorted(set(options) - allowed)
    if unknown:
        raise InputError(f"beam {model!r} takes no option {', '.join(unknown)}"
                         + (f" (allowed: {', '.join(sorted(allowed))})" if allowed else ""))
