"""Import EveryBeam the way it works from a pip install.

Two facts about the PyPI wheels (documented in the README):

* the ``everybeam`` 0.9.0 wheel ships its coefficient files (Hamaker HBA/LBA, OSKAR, ...)
  under ``<prefix>/share/everybeam`` but only finds them when ``EVERYBEAM_DATADIR`` points
  there, so msleak sets it (if unset) before importing everybeam;
* everybeam bundles a casacore without measures data; importing python-casacore first makes
  its data tables (leap seconds, observatories) available, otherwise EveryBeam fails with
  "Cannot read leap second table".
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from msleak.errors import ConfigurationError

__all__ = ["import_everybeam", "everybeam_datadir"]


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
            "`pip install everybeam==0.9.0` or use `--beam dipole`") from err
    if not (Path(os.environ["EVERYBEAM_DATADIR"]) / "HamakerHBACoeff.h5").exists():
        raise ConfigurationError(
            f"EveryBeam coefficient files not found in {os.environ['EVERYBEAM_DATADIR']}; "
            "set EVERYBEAM_DATADIR to <prefix>/share/everybeam of an everybeam 0.9.0 install")
    return everybeam
