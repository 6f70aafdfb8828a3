"""The diffuse polarized foreground on the whole sphere, in HEALPix pixels (RING, ICRS).

:func:`generate_allsky` gives every pixel the line of sight of the flat generator
(:mod:`msleak.sky.foreground`): the same slab of ``ncells_los`` cells, regular plus random
magnetic field, log-normal thermal and cosmic-ray electrons, emission and differential
Faraday rotation integrated per channel. The random fields are spherical Gaussian random
fields layer by layer, correlated along the line of sight; one transverse cell of the flat
box subtends ``cell_deg`` on the sky. Q and U are in K, referred to each pixel's celestial
North (IAU). healpy (the ``healpix`` extra) does the spherical transforms.

Construction, angular scale, measured statistics: docs/sky.md, "All-sky skies".
"""

from __future__ import annotations

import importlib.util
import logging
import math
from dataclasses import dataclass, field, replace

import numpy as np

from msleak.constants import jy_per_kelvin
from msleak.errors import InputError
from msleak.sky.faraday import faraday_thickness, polarized_brightness
from msleak.sky.fields import lognormal_field
from msleak.sky.foreground import ForegroundParams, channel_frequencies
from msleak.sky.healpix import HEALPIX_UNITS, HealpixSky

__all__ = ["AllSky", "generate_allsky", "healpix_to_unit", "los_power", "regular_field_local",
           "check_geometry", "CELL_DEG", "BOX_DEG", "FIELD_REFERENCE"]

log = logging.getLogger(__name__)

#: angle (deg) one transverse cell of the flat box subtends: the flat cube's default pixel
CELL_DEG = 0.3
#: width (deg) of the flat box whose largest scales the sphere copies: the flat default
BOX_DEG = 15.0
#: (RA, Dec) deg where ``b_regular_ug`` holds as (east, north, towards the observer): the
#: flat cube's default centre, the NCP (its North at RA 180 deg, East at RA 90 deg)
FIELD_REFERENCE = (0.0, 90.0)


@dataclass(frozen=True, eq=False)
class AllSky:
    """A generated all-sky foreground: the sky, each pixel's Faraday depth, what made it.

    ``meta`` holds the seed entropy (``SEED``), ``BETA``, the emissivity scale ``EMSCALE``,
    rms |P| at the reference frequency (``PRMSREF``), the total Faraday depth over the
    sphere (``PHIMIN``, ``PHIMAX``, ``PHISTD``, rad m^-2), ``LMAX`` and ``D_PC`` (the
    distance that maps angle to transverse size).
    """

    sky: HealpixSky
    faraday_depth: np.ndarray   #: (npix,) total Faraday depth through the slab, rad m^-2
    meta: dict = field(default_factory=dict)


def _healpy():
    if importlib.util.find_spec("healpy") is None:
        raise InputError("all-sky skies need the Python package healpy: "
                         "pip install 'msleak[healpix]'")
    import healpy

    return healpy


def check_geometry(nside: int, cell_deg: float, box_deg: float) -> int:
    """Raise :class:`InputError` for an NSIDE that is not a power of 2 or an angular scale
    outside its range; returns NSIDE as an int."""
    if isinstance(nside, bool) or int(nside) != nside or nside < 1 or int(nside) & (int(nside) - 1):
        raise InputError(f"nside must be a power of 2 (1, 2, 4, ..., 1024), got {nside}",
                         param="nside")
    if not (math.isfinite(cell_deg) and 0 < cell_deg < 10):
        raise InputError(f"cell_deg must be in (0, 10) deg, got {cell_deg}", param="cell_deg")
    if not (math.isfinite(box_deg) and 2 * cell_deg <= box_deg <= 180):
        raise InputError(f"box_deg must be between 2 cell_deg and 180 deg, got {box_deg}",
                         param="box_deg")
    return int(nside)


def los_power(ell: np.ndarray, kz: np.ndarray, alpha: float, *, distance_pc: float,
              ell_box: float, outer_scale_pc: float | None = None,
              component: str = "scalar") -> np.ndarray:
    """Power of the harmonic coefficients a_lm(k_z) of a 3-D field P(k) ~ k^-alpha seen on
    spherical shells, up to one constant: (nell, nkz).

    ``k_perp = ell / distance_pc``. The multipoles below ``ell_box`` (the equal-area disc of
    the flat box's k_perp = 0 mode) carry P(|k_z|) with a weight that gives them the
    variance of that mode. ``component`` selects the diagonal of the solenoidal projector:
    ``"scalar"`` (none), ``"par"`` (line of sight, k_perp^2 / k^2), ``"grad"`` (the
    transverse part along k_perp, k_z^2 / k^2) or ``"curl"`` (1). The k = 0 mode is zero.
    """
    ell = np.asarray(ell, float)[:, None]
    kz = np.asarray(kz, float)[None, :]
    band = ell < ell_box
    kperp = np.where(band, 0.0, ell / distance_pc)
    k2 = kperp ** 2 + kz ** 2
    if outer_scale_pc is not None:
        k2 = k2 + (2 * np.pi / outer_scale_pc) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        power = np.where(kperp ** 2 + kz ** 2 > 0, k2 ** (-alpha / 2.0), 0.0)
        kk = kperp ** 2 + kz ** 2
        if component == "par":
            power = power * np.where(kk > 0, kperp ** 2 / kk, 0.0)
        elif component == "grad":
            power = power * np.where(kk > 0, kz ** 2 / kk, 0.0)
    lowest = 1.0 if component in ("grad", "curl") else 0.0
    inband = (ell[:, 0] < ell_box) & (ell[:, 0] >= lowest)
    modes = float(np.sum(2 * ell[inband, 0] + 1))
    if modes > 0:
        power[inband] *= ell_box ** 2 / modes
    power[ell[:, 0] < lowest] = 0.0
    return power


def _layer_alms(rng: np.random.Generator, power: np.ndarray, ell_of_alm: np.ndarray,
                m_is_zero: np.ndarray, nz: int) -> np.ndarray:
    """a_lm(z), (nz, nalm) complex: per (l, m) a Gaussian process along the periodic line of
    sight with spectrum ``power[l, k_z]`` (real for m = 0)."""
    amp = np.sqrt(power[ell_of_alm].T)                       # (nkz, nalm)
    if nz % 2 == 0:
        amp[-1] = 0.0                                        # the Nyquist plane, as fields.py
    noise = rng.standard_normal((2, nz, ell_of_alm.size))
    parts = np.fft.irfft(np.fft.rfft(noise, axis=1) * amp[None], n=nz, axis=1)
    alm = (parts[0] + 1j * parts[1]) / math.sqrt(2.0)
    alm[:, m_is_zero] = parts[0][:, m_is_zero]
    return alm


def _random_maps(hp, nside: int, lmax: int, params: ForegroundParams, nz: int, dz: float,
                 distance: float, ell_box: float, rngs) -> dict[str, np.ndarray]:
    """Unit random fields on (nz, npix): ``ne``, ``ncr`` (unit-variance Gaussian) and the
    random magnetic field's ``par``, ``north``, ``east`` (mean |B|^2 = 1)."""
    ell, m = hp.Alm.getlm(lmax)
    kz = 2 * np.pi * np.fft.rfftfreq(nz, d=dz)
    ells = np.arange(lmax + 1)

    def spectrum(alpha, component="scalar"):
        return los_power(ells, kz, alpha, distance_pc=distance, ell_box=ell_box,
                         outer_scale_pc=params.outer_scale_pc, component=component)

    rng_b, rng_ne, rng_cr = rngs
    sol = params.solenoidal
    alms = {
        "par": _layer_alms(rng_b, spectrum(params.b_index, "par" if sol else "scalar"),
                           ell, m == 0, nz),
        "grad": _layer_alms(rng_b, spectrum(params.b_index, "grad" if sol else "curl"),
                            ell, m == 0, nz),
        "curl": _layer_alms(rng_b, spectrum(params.b_index, "curl"), ell, m == 0, nz),
        "ne": _layer_alms(rng_ne, spectrum(params.ne_index), ell, m == 0, nz),
        "ncr": _layer_alms(rng_cr, spectrum(params.ncr_index), ell, m == 0, nz),
    }
    npix = 12 * nside ** 2
    maps = {name: np.empty((nz, npix)) for name in ("ne", "ncr", "par", "north", "east")}
    for z in range(nz):
        scal = hp.alm2map(np.stack([alms["ne"][z], alms["ncr"][z], alms["par"][z]]), nside,
                          lmax=lmax, pol=False)
        theta, phi = hp.alm2map_spin([alms["grad"][z], alms["curl"][z]], nside, 1, lmax)
        maps["ne"][z], maps["ncr"][z], maps["par"][z] = scal
        maps["north"][z], maps["east"][z] = -theta, phi      # e_theta points South
    del alms
    for name in ("ne", "ncr"):
        maps[name] -= maps[name].mean()
        maps[name] /= maps[name].std() or 1.0
    maps["par"] -= maps["par"].mean()
    norm = math.sqrt(sum(float(np.mean(maps[c] ** 2)) for c in ("par", "north", "east")))
    for c in ("par", "north", "east"):
        maps[c] /= norm or 1.0
    return maps


def regular_field_local(b_regular_ug, reference_deg: tuple[float, float], ra: np.ndarray,
                        dec: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(east, north, towards the observer) components, uG, at (ra, dec) (rad) of the uniform
    field whose components at ``reference_deg`` (RA, Dec, deg) are ``b_regular_ug``."""
    def basis(a, d):
        east = np.stack([-np.sin(a), np.cos(a), np.zeros_like(a)])
        north = np.stack([-np.sin(d) * np.cos(a), -np.sin(d) * np.sin(a), np.cos(d)])
        out = np.stack([np.cos(d) * np.cos(a), np.cos(d) * np.sin(a), np.sin(d)])
        return east, north, out

    a0, d0 = (np.atleast_1d(math.radians(v)) for v in reference_deg)
    e0, n0, r0 = (v[:, 0] for v in basis(a0, d0))
    b_e, b_n, b_par = (float(v) for v in b_regular_ug)
    bvec = b_e * e0 + b_n * n0 - b_par * r0
    east, north, out = basis(np.asarray(ra, float), np.asarray(dec, float))
    return (np.tensordot(bvec, east, 1), np.tensordot(bvec, north, 1),
            -np.tensordot(bvec, out, 1))


def _cells(hp, nside, params, distance, ell_box, lmax, seed, reference):
    """Per-cell emissivity, intrinsic angle and Faraday thickness on (nz, npix), and the seed
    entropy."""
    nz = int(params.ncells_los)
    dz = params.depth_pc / nz
    ss = np.random.SeedSequence(seed)
    rngs = [np.random.default_rng(s) for s in ss.spawn(3)]
    maps = _random_maps(hp, nside, lmax, params, nz, dz, distance, ell_box, rngs)
    theta, phi = hp.pix2ang(nside, np.arange(12 * nside ** 2))
    reg_e, reg_n, reg_par = regular_field_local(params.b_regular_ug, reference, phi,
                                                0.5 * np.pi - theta)
    rms = params.b_random_rms_ug
    bpar = reg_par + rms * maps.pop("par")
    dphi = faraday_thickness(lognormal_field(maps.pop("ne"), params.ne_mean_cm3,
                                             params.ne_sigma_ln), bpar, dz)
    del bpar
    bnorth = reg_n + rms * maps.pop("north")
    beast = reg_e + rms * maps.pop("east")
    chi0 = np.arctan2(beast, bnorth) + 0.5 * np.pi
    bperp = np.hypot(beast, bnorth)
    del beast, bnorth
    ncr = lognormal_field(maps.pop("ncr"), 1.0, params.ncr_sigma_ln)
    amp = params.intrinsic_fraction * ncr * bperp ** ((params.electron_index + 1.0) / 2.0) * dz
    return amp, chi0, dphi, int(ss.entropy)


def generate_allsky(*, nside: int, freq_min_hz: float = 150e6, nchan: int = 50,
                    chan_width_hz: float = 195312.5, seed: int | None = None,
                    params: ForegroundParams | None = None, cell_deg: float = CELL_DEG,
                    box_deg: float = BOX_DEG,
                    field_reference: tuple[float, float] = FIELD_REFERENCE) -> AllSky:
    """Q and U of the foreground on all ``12 nside^2`` HEALPix pixels (RING, ICRS), in K.

    Parameters
    ----------
    nside : HEALPix NSIDE, a power of 2
    freq_min_hz, nchan, chan_width_hz : channels, centre of channel i = freq_min + i width
    seed : integer seed; ``None`` draws fresh entropy (recorded in ``meta["SEED"]``)
    params : the physics (:class:`~msleak.sky.foreground.ForegroundParams`); ``p_rms_k``
        is the rms of |P| over the whole sphere at ``ref_freq_hz``
    cell_deg : angle one transverse cell (``cell_perp_pc``) subtends [0.3, the flat cube's
        default pixel]
    box_deg : the largest transverse scale of the random fields, as the flat cube of this
        width [15]; larger scales hold the power of the flat box's uniform mode
    field_reference : (RA, Dec) deg where ``b_regular_ug`` is (east, north, towards the
        observer); the regular field is uniform in space [the NCP]

    Returns
    -------
    :class:`AllSky`: ``sky`` with stokes (4, nchan, 12 nside^2) (I = V = 0), unit K.
    """
    params = params or ForegroundParams()
    params.validate()
    nside = check_geometry(nside, float(cell_deg), float(box_deg))
    hp = _healpy()
    freq = channel_frequencies(freq_min_hz, nchan, chan_width_hz)
    cell_perp = params.cell_perp_pc or params.depth_pc / params.ncells_los
    distance = cell_perp / math.radians(cell_deg)
    ell_box = 2 * math.sqrt(math.pi) / math.radians(box_deg)
    lmax = int(max(min(3 * nside - 1, math.pi / math.radians(cell_deg)), 1))
    amp, chi0, dphi, entropy = _cells(hp, nside, params, distance, ell_box, lmax, seed,
                                      field_reference)
    shape = (amp.shape[0], 12 * nside, nside)   # rows of pixels, for the chunked kernel
    amp, chi0, dphi = (a.reshape(shape) for a in (amp, chi0, dphi))
    ref = polarized_brightness(amp, chi0, dphi, np.array([params.ref_freq_hz]))[0]
    rms_ref = float(np.sqrt(np.mean(np.abs(ref) ** 2)))
    if not (rms_ref > 0 and math.isfinite(rms_ref)):
        raise InputError("the foreground parameters give no finite polarized emission; use "
                         "physically sensible values")
    scale = params.p_rms_k / rms_ref
    spectral = (freq / params.ref_freq_hz) ** (-params.beta)
    pol = polarized_brightness(amp * scale, chi0, dphi, freq, spectral_factor=spectral)
    pol = pol.reshape(nchan, -1)
    stokes = np.zeros((4, nchan, pol.shape[1]))
    stokes[1], stokes[2] = pol.real, pol.imag
    if not np.all(np.isfinite(stokes)):
        raise InputError("the foreground parameters overflow (non-finite brightness); use "
                         "physically sensible values", param="electron_index")
    phi_total = dphi.sum(axis=0).ravel()
    meta = {"SEED": entropy, "BETA": params.beta, "EMSCALE": scale, "PRMSREF": params.p_rms_k,
            "PHIMIN": float(phi_total.min()), "PHIMAX": float(phi_total.max()),
            "PHISTD": float(phi_total.std()), "LMAX": lmax, "D_PC": distance,
            "CELL_DEG": float(cell_deg), "BOX_DEG": float(box_deg),
            "FIELDREF": ",".join(str(float(v)) for v in field_reference)}
    sky = HealpixSky(nside=nside, order="ring", pixels=np.arange(pol.shape[1]), freq_hz=freq,
                     stokes=stokes, unit="K", label="msleak all-sky foreground")
    log.info("all-sky foreground: NSIDE %d, rms |P| %.3g K at %.4g MHz, total Faraday depth "
             "%.3g..%.3g rad/m^2", nside, params.p_rms_k, params.ref_freq_hz / 1e6,
             meta["PHIMIN"], meta["PHIMAX"])
    return AllSky(sky=sky, faraday_depth=phi_total, meta=meta)


def healpix_to_unit(sky: HealpixSky, unit: str) -> HealpixSky:
    """``sky`` in ``unit`` ("K" or "Jy/sr"; Rayleigh-Jeans, 2 k_B T nu^2 / c^2 per sr)."""
    if unit not in HEALPIX_UNITS:
        raise InputError(f"unit {unit!r} is not one of {', '.join(HEALPIX_UNITS)}",
                         param="units")
    if unit == sky.unit:
        return sky
    per_k = jy_per_kelvin(sky.freq_hz, 1.0)[None, :, None]
    stokes = sky.stokes * per_k if unit == "Jy/sr" else sky.stokes / per_k
    return replace(sky, stokes=stokes, unit=unit)
