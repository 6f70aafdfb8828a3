"""Physical constants and unit conversions, in SI floats, taken from astropy.constants.

Numerical kernels (numba included) use these plain floats; the public edges may accept
astropy Quantities and convert with the functions here.
"""

from __future__ import annotations

import numpy as np
from astropy import constants as _const
from astropy import units as _u

__all__ = ["SPEED_OF_LIGHT", "BOLTZMANN", "JANSKY", "FREQ_21CM", "FARADAY_RM",
           "jy_per_kelvin"]

#: speed of light in vacuum [m s^-1] (exact)
SPEED_OF_LIGHT: float = float(_const.c.to_value(_u.m / _u.s))
#: Boltzmann constant [J K^-1] (exact)
BOLTZMANN: float = float(_const.k_B.to_value(_u.J / _u.K))
#: one jansky [W m^-2 Hz^-1]
JANSKY: float = float((1 * _u.Jy).to_value(_u.W / _u.m**2 / _u.Hz))
#: rest frequency of the 21-cm hyperfine line of neutral hydrogen [Hz]
FREQ_21CM: float = 1420405751.768
#: Faraday rotation per electron column and parallel field, e^3 / (8 pi^2 eps0 m_e^2 c^3)
#: [rad m^-2 per (m^-2 T)]: RM = FARADAY_RM * integral n_e B_par dl (B_par towards the observer)
FARADAY_RM: float = float((_const.e.si ** 3 / (8.0 * np.pi ** 2 * _const.eps0 * _const.m_e ** 2
                                               * _const.c ** 3)).decompose().value)


def jy_per_kelvin(freq_hz, solid_angle_sr: float) -> np.ndarray:
    """Rayleigh-Jeans flux density [Jy] of a 1 K brightness temperature over
    ``solid_angle_sr`` at ``freq_hz``: astropy's ``u.brightness_temperature``,
    S = 2 k_B T nu^2 / c^2 Omega."""
    freq = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    kelvin = np.ones_like(freq) * _u.K
    jy = kelvin.to_value(_u.Jy, equivalencies=_u.brightness_temperature(
        freq * _u.Hz, beam_area=solid_angle_sr * _u.sr))
    return jy if np.ndim(freq_hz) else jy[0]
