"""msleak: polarization leakage (Stokes Q/U -> I) of radio primary beams and its effect
on 21-cm power spectra, measured from any Measurement Set.

The package never configures logging itself; the command-line interface does.
"""

import logging

from msleak.errors import MsleakError

__version__ = "0.1.0"
__all__ = ["__version__", "MsleakError"]

logging.getLogger(__name__).addHandler(logging.NullHandler())
