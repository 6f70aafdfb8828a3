"""msleak: polarization leakage (Stokes Q/U -> I) of radio primary beams and its effect
on 21-cm power spectra, measured from any Measurement Set.

The verbs below are the Python API; each ``msleak`` command is a thin wrapper over one of
them (docs/api.md). They are imported on first use, so ``import msleak`` stays light.
The package never configures logging itself; the command-line interface does. Importing it
has no side effect: casacore is configured where msleak first uses it (:mod:`msleak.io`).
"""

import importlib
import logging

from msleak.errors import ConfigurationError, InputError, MsleakError

__version__ = "0.1.0"

#: public verb -> "module:function", or the stage package that is callable as the verb
#: (msleak.predict and msleak.leakage: importing a subpackage makes it msleak's attribute)
_VERBS = {
    "simulate": "msleak.verbs.simulate:simulate",
    "make_sky": "msleak.verbs.sky:make_sky",
    "make_allsky": "msleak.verbs.allsky:make_allsky",
    "beam_maps": "msleak.verbs.beam_maps:beam_maps",
    "predict": "msleak.predict",
    "noise": "msleak.verbs.noise:noise",
    "grid": "msleak.verbs.grid:grid",
    "transform": "msleak.verbs.transform:transform",
    "power_spectrum": "msleak.verbs.power:power_spectrum",
    "leakage": "msleak.leakage",
}

__all__ = ["__version__", "MsleakError", "InputError", "ConfigurationError", *_VERBS]


def __getattr__(name: str):
    if name in _VERBS:
        module, _, func = _VERBS[name].partition(":")
        found = importlib.import_module(module)
        return getattr(found, func) if func else found
    raise AttributeError(f"module 'msleak' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_VERBS))


logging.getLogger(__name__).addHandler(logging.NullHandler())
