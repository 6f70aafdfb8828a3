"""21-cm cosmology: redshift, comoving distances, k_perp / k_par and the wedge.

All quantities are in Mpc (not h^-1 Mpc), s and Hz; the cosmology is an astropy
realisation chosen by name (default ``Planck18``) or a flat LambdaCDM from H0 and Om0
(docs/ps.md "Cosmology").

Formulas (docs/science.md section 5)::

    z       = f21 / nu - 1,                   f21 = 1420.405751768 MHz
    X       = D_c(z)                          (Mpc per radian)
    Y       = c (1 + z)^2 / (H0 f21 E(z))     (Mpc per Hz)
    k_perp  = 2 pi |b| / D_c(z)               (|b| in wavelengths)
    k_par   = 2 pi tau / Y = 2 pi tau H0 f21 E(z) / (c (1 + z)^2)
    wedge   k_par = sin(theta) D_c(z) E(z) / (D_H (1 + z)) k_perp,  D_H = c / H0
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from msleak.constants import BOLTZMANN, FREQ_21CM, SPEED_OF_LIGHT
from msleak.errors import InputError

if TYPE_CHECKING:
    from astropy.cosmology import Cosmology

__all__ = ["Cosmo", "get_cosmology", "make_cosmology", "describe", "cosmo_at",
           "jy2_to_mk2_mpc3"]

DEFAULT_COSMOLOGY = "Planck18"


def get_cosmology(name: str = DEFAULT_COSMOLOGY) -> Cosmology:
    """An astropy cosmology realisation by name (any of ``astropy.cosmology.realizations``)."""
    from astropy.cosmology import realizations

    available = list(realizations.available)
    if name not in available:
        raise InputError(f"unknown cosmology {name!r}: use one of {', '.join(available)}, "
                         "or h0 and om0 for a flat LambdaCDM", param=("h0", "om0"))
    return getattr(realizations, name)


def make_cosmology(cosmology: str | Cosmology | None = None, *, h0: float | None = None,
                   om0: float | None = None, ob0: float | None = None,
                   tcmb0: float | None = None) -> Cosmology:
    """The astropy cosmology of the ``msleak ps`` options.

    ``cosmology`` is a realisation name or an astropy cosmology (default Planck18); or
    ``h0`` (km/s/Mpc) and ``om0`` (with optional ``ob0`` and ``tcmb0`` in K) give a
    ``FlatLambdaCDM``. A name and H0/Om0 exclude each other.
    """
    params = {"h0": h0, "om0": om0, "ob0": ob0, "tcmb0": tcmb0}
    given = [k for k, v in params.items() if v is not None]
    if not given:
        if cosmology is None or isinstance(cosmology, str):
            return get_cosmology(cosmology or DEFAULT_COSMOLOGY)
        return cosmology
    if cosmology is not None:
        raise InputError(f"cosmology and {'/'.join(given)} exclude each other: give a "
                         "realisation name or h0 and om0 (flat LambdaCDM)",
                         param=("cosmology", *given, "h0", "om0"))
    if h0 is None or om0 is None:
        raise InputError(f"{'/'.join(given)} without {'h0' if h0 is None else 'om0'}: a "
                         "flat LambdaCDM needs both h0 and om0 (or use cosmology NAME)",
                         param=(*given, "h0", "om0", "cosmology"))
    for opt, v in params.items():
        positive = opt in ("h0", "om0")
        if v is not None and not (math.isfinite(v) and (v > 0 if positive else v >= 0)):
            raise InputError(f"{opt} {v:g}: must be a {'positive' if positive else 'non-negative'}"
                             " finite number", param=opt)
    from astropy.cosmology import FlatLambdaCDM

    try:
        return FlatLambdaCDM(H0=h0, Om0=om0, Tcmb0=tcmb0 or 0.0,
                             **({} if ob0 is None else {"Ob0": ob0}))
    except ValueError as err:
        raise InputError(f"flat LambdaCDM (h0 {h0:g} om0 {om0:g}): {err}",
                         param=("h0", "om0")) from err


def describe(cosmo: Cosmology) -> dict:
    """Product attributes recording an astropy cosmology: its name or parameters, and h."""
    import astropy.units as u

    h0 = float(cosmo.H0.to_value(u.km / u.s / u.Mpc))
    params = (f"H0={h0:.10g} km/s/Mpc, Om0={cosmo.Om0:.10g}, Ob0={cosmo.Ob0:.10g}, "
              f"Tcmb0={cosmo.Tcmb0.to_value(u.K):.10g} K")
    return {"cosmology": cosmo.name or type(cosmo).__name__,
            "cosmology_parameters": f"{type(cosmo).__name__}: {params}",
            "h": h0 / 100.0}


@dataclass(frozen=True)
class Cosmo:
    """The cosmological conversion factors at one redshift (SI-free: Mpc, s, Hz)."""

    name: str
    z: float
    freq_hz: float
    dc_mpc: float        #: comoving distance D_c(z), Mpc
    efunc: float         #: E(z) = H(z) / H0
    h0_km_s_mpc: float   #: H0, km/s/Mpc
    dh_mpc: float        #: Hubble distance c / H0, Mpc

    @property
    def h(self) -> float:
        """Little h = H0 / (100 km/s/Mpc)."""
        return self.h0_km_s_mpc / 100.0

    @property
    def x_mpc_per_rad(self) -> float:
        return self.dc_mpc

    @property
    def y_mpc_per_hz(self) -> float:
        return self.dh_mpc * (1 + self.z) ** 2 / (FREQ_21CM * self.efunc)

    def k_perp(self, b_lambda):
        """k_perp (Mpc^-1) of baselines ``b_lambda`` (wavelengths)."""
        return 2 * np.pi * np.asarray(b_lambda, dtype=float) / self.dc_mpc

    def k_par(self, delay_s):
        """k_par (Mpc^-1) of delays ``delay_s`` (s); the sign of the delay is kept."""
        return 2 * np.pi * np.asarray(delay_s, dtype=float) / self.y_mpc_per_hz

    def wedge_slope(self, theta_deg: float) -> float:
        """k_par / k_perp of the wedge line for a source at ``theta_deg`` from the centre."""
        return (np.sin(np.radians(theta_deg)) * self.dc_mpc * self.efunc
                / (self.dh_mpc * (1 + self.z)))


def cosmo_at(freq_hz: float, cosmology: str | Cosmology = DEFAULT_COSMOLOGY) -> Cosmo:
    """Conversion factors for the 21-cm line observed at ``freq_hz``; ``cosmology`` is a
    realisation name or an astropy cosmology (:func:`make_cosmology`)."""
    if not (freq_hz > 0 and freq_hz < FREQ_21CM):
        raise InputError(f"frequency {freq_hz / 1e6:.3f} MHz is not below the 21-cm rest "
                         f"frequency {FREQ_21CM / 1e6:.3f} MHz: no 21-cm redshift")
    import astropy.units as u

    c = get_cosmology(cosmology) if isinstance(cosmology, str) else cosmology
    z = FREQ_21CM / freq_hz - 1
    h0 = c.H0.to_value(u.km / u.s / u.Mpc)
    return Cosmo(name=describe(c)["cosmology"], z=z, freq_hz=float(freq_hz),
                 dc_mpc=float(c.comoving_distance(z).to_value("Mpc")),
                 efunc=float(c.efunc(z)), h0_km_s_mpc=float(h0), dh_mpc=SPEED_OF_LIGHT / 1e3 / h0)


def jy2_to_mk2_mpc3(cosmo: Cosmo, beam_area_sr: float, bandwidth_hz: float) -> float:
    """Factor turning a delay power ``|V~|^2 / window_norm`` (Jy^2) into mK^2 Mpc^3.

    With ``V~ = (1/N) sum_nu w V exp(...)`` and the continuous transform
    ``Vt = N dnu V~`` (Jy Hz), the standard normalisation is::

        P = |Vt|^2 (lambda^2 / (2 k_B))^2 X^2 Y / (Omega B_eff),  B_eff = B window_norm

    so ``P = (|V~|^2 / window_norm) * B * (1e-26 lambda^2 / (2 k_B))^2 X^2 Y / Omega * 1e6``
    with B = N dnu the bandwidth, lambda = c / nu_centre, Omega the beam area (sr), 1e-26
    converting Jy to W m^-2 Hz^-1 and 1e6 K^2 to mK^2.
    """
    if not beam_area_sr > 0:
        raise InputError(f"beam area must be positive (sr), got {beam_area_sr}")
    lam = SPEED_OF_LIGHT / cosmo.freq_hz
    jy_to_k_sr = 1e-26 * lam ** 2 / (2 * BOLTZMANN)
    return (bandwidth_hz * jy_to_k_sr ** 2 * cosmo.x_mpc_per_rad ** 2 * cosmo.y_mpc_per_hz
            / beam_area_sr * 1e6)
