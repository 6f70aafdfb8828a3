"""Import EveryBeam the way it works from a pip install.

Two facts about the PyPI wheels (documented in the README):

* the ``everybeam`` 0.9.0 wheel ships its coefficient files (Hamaker HBA/LBA, OSKAR, ...)
  under ``<prefix>/share/everybeam`` but only finds them when ``EVERYBEAM_DATADIR`` points
  there, so msleak sets it (if unset) before importing everybeam;
* everybeam bundles a casacore without measures data; importing python-casacore first makes
  its data tables (leap seconds, observatories) available, otherwise EveryBeam fails with
  "Cannot read leap second table".

Which telescopes the wheel's ``load_telescope`` accepts (:func:`everybeam_telescope`),
where its MWA beam finds the MWA FEE coefficients (:data:`MWA_BEAM_FILE_VARIABLE`) and
which MWA dipole delays it and mwa_hyperbeam take (:func:`check_delays`) are stated here
too, so msleak can refuse an MS before EveryBeam prints or raises anything.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from msleak.errors import ConfigurationError, InputError

__all__ = ["import_everybeam", "everybeam_datadir", "everybeam_telescope",
           "EVERYBEAM_TELESCOPES", "MWA_BEAM_FILE_VARIABLE", "MWA_BEAM_FILE_NAME",
           "check_delays"]

#: TELESCOPE_NAME (compared in upper case, as EveryBeam does) -> the EveryBeam telescope the
#: everybeam 0.9.0 Python bindings load for it; names starting with "OSKAR" load OSKAR too.
#: EveryBeam's C++ library knows more (VLA as EVLA*, ATCA*, GMRT, MEERKAT, ALMA, DSA_110,
#: OVRO_LWA, ...), but its ``load_telescope`` refuses them.
EVERYBEAM_TELESCOPES = {"LOFAR": "LOFAR", "AARTFAAC": "AARTFAAC", "MWA": "MWA",
                        "SKA-LOW": "OSKAR", "MID": "SKA-Mid"}

#: EveryBeam's MWA beam reads no environment variable for its coefficients file (it must be
#: passed as ``coeff_path``); msleak takes it from the variable mwa_hyperbeam also reads.
MWA_BEAM_FILE_VARIABLE = "MWA_BEAM_FILE"
MWA_BEAM_FILE_NAME = "mwa_full_embedded_element_pattern.h5"


def check_delays(delays) -> np.ndarray:
    """``delays`` as a (16,) int64 array, refused unless 16 integers in 0..32."""
    values = np.asarray(delays)
    if values.shape != (16,) or values.dtype.kind not in "iu" or np.any(
            (values < 0) | (values > 32)):
        raise InputError("MWA dipole delays must be 16 integers from 0 to 32 (32 = dead "
                         f"dipole), got {np.array2string(values.ravel()[:17], separator=',')}")
    return values.astype(np.int64)


def everybeam_telescope(telescope_name: str) -> str | None:
    """The EveryBeam telescope ``load_telescope`` makes for an MS's TELESCOPE_NAME, or None."""
    name = str(telescope_name).upper()
    if name.startswith("OSKAR"):
        return "OSKAR"
    return EVERYBEAM_TELESCOPES.get(name)


def everybeam_datadir() -> Path:
    """The folder holding EveryBeam's coefficient files for this Python environment."""
    if os.environ.get("EVERYBEAM_DATADIR"):
        return Path(os.environ["EVERYBEAM_DATADIR"])
    for prefix in (sys.prefix, sys.base_prefix):
        candidate = Path(prefix) / "share" / "everybeam"
        if (candidate / "HamakerHBACoeff.h5").exists():
            return candidate
    return Path(sys.prefix) / "share" / "everybeam"


def import_everybeam():
    """Return the ``everybeam`` module, with its data directory and casacore data set up."""
    import casacore.measures  # noqa: F401  (must precede everybeam, see module docstring)
    import casacore.tables  # noqa: F401

    datadir = everybeam_datadir()
    os.environ.setdefault("EVERYBEAM_DATADIR", str(datadir))
    try:
        import everybeam
    except ImportError as err:
        raise ConfigurationError(
            "the everybeam package is not importable; install it with "
            "`pip install everybeam==0.9.0` or use `beam='dipole'`") from err
    if not (Path(os.environ["EVERYBEAM_DATADIR"]) / "HamakerHBACoeff.h5").exists():
        raise ConfigurationError(
            f"EveryBeam coefficient files not found in {os.environ['EVERYBEAM_DATADIR']}; "
            "set EVERYBEAM_DATADIR to <prefix>/share/everybeam of an everybeam 0.9.0 install")
    return everybeam
