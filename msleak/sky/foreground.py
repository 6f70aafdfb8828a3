"""Diffuse polarized Galactic foreground cubes after Jelic et al. (2008, 2010), "model B".

:func:`generate_foreground_cube` fills a slab of ``npix x npix`` lines of sight and
``ncells_los`` cells (observer in front of cell 0) with a random magnetic field and
log-normal thermal and cosmic-ray electrons (:func:`build_box`, :class:`ForegroundParams`),
integrates the Faraday-rotated synchrotron emission per channel and returns a
:class:`~msleak.sky.cube.SkyCube` of Q and U in K (rms |P| at ``ref_freq_hz`` equal to
``p_rms_k``, Q and U referred to each pixel's local North); one seed, one cube bit for bit.

Model, box axes, calibration, polarization frame: docs/sky.md and docs/science.md section 3.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass

import numpy as np

from msleak.errors import InputError
from msleak.sky.cube import (POLFRAME, SkyCube, make_celestial_wcs,
                             y_axis_position_angle)
from msleak.sky.faraday import (faraday_depth_near_face, faraday_thickness,
                                polarized_brightness)
from msleak.sky.fields import gaussian_random_field, lognormal_field, solenoidal_vector_field

__all__ = ["ForegroundParams", "ForegroundBox", "build_box", "generate_foreground_cube",
           "channel_frequencies"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ForegroundParams:
    """Physical parameters of the foreground model (units in the names).

    Defaults are calibrated to a few K rms polarized brightness at 150 MHz and Faraday
    depths within about +-10 rad m^-2 (see docs/sky.md for measured values).
    """

    depth_pc: float = 1000.0             #: slab depth along the line of sight, pc
    ncells_los: int = 100                #: cells along the line of sight
    cell_perp_pc: float | None = None    #: transverse cell size, pc (default: depth/ncells)
    b_regular_ug: tuple[float, float, float] = (1.0, 1.0, 0.2)  #: (B_east, B_north, B_par), uG
    b_random_rms_ug: float = 2.5         #: rms |B_random|, uG
    b_index: float = 11.0 / 3.0          #: 3-D power-spectrum index of B_random
    solenoidal: bool = True              #: project B_random to div B = 0
    ne_mean_cm3: float = 0.01            #: mean thermal electron density, cm^-3
    ne_sigma_ln: float = 0.5             #: log-normal width of n_e
    ne_index: float = 11.0 / 3.0         #: 3-D spectral index of log n_e
    ncr_sigma_ln: float = 0.5            #: log-normal width of n_CR
    ncr_index: float = 11.0 / 3.0        #: 3-D spectral index of log n_CR
    electron_index: float = 2.1          #: p, cosmic-ray energy spectrum N(E) ~ E^-p
    outer_scale_pc: float | None = None  #: outer scale of all random fields, pc (None: none)
    p_rms_k: float = 3.0                 #: rms |P| at ref_freq_hz, K
    ref_freq_hz: float = 150e6           #: normalisation frequency, Hz

    def __post_init__(self):
        object.__setattr__(self, "b_regular_ug", tuple(self.b_regular_ug))

    def validate(self) -> None:
        """Raise :class:`InputError` for unphysical values."""
        checks = [
            (self.depth_pc > 0, "depth_pc must be > 0", "depth_pc"),
            (self.ncells_los >= 2, "ncells_los must be >= 2", "ncells_los"),
            (self.cell_perp_pc is None or self.cell_perp_pc > 0, "cell_perp_pc must be > 0",
             "cell_perp_pc"),
            (len(self.b_regular_ug) == 3, "b_regular_ug needs 3 components", "b_regular_ug"),
            (self.b_random_rms_ug >= 0, "b_random_rms_ug must be >= 0", "b_random_rms_ug"),
            (self.ne_mean_cm3 >= 0, "ne_mean_cm3 must be >= 0", "ne_mean_cm3"),
            (self.ne_sigma_ln >= 0 and self.ncr_sigma_ln >= 0, "log-normal widths must be >= 0",
             ()),
            (self.electron_index > 1, "electron_index must be > 1", "electron_index"),
            (self.outer_scale_pc is None or self.outer_scale_pc > 0,
             "outer_scale_pc must be > 0", "outer_scale_pc"),
            (self.p_rms_k > 0, "p_rms_k must be > 0", "p_rms_k"),
            (self.ref_freq_hz > 0, "ref_freq_hz must be > 0", "ref_freq_hz"),
        ]
        for ok, msg, param in checks:
            if not ok:
                raise InputError(msg, param=param)
        values = [self.depth_pc, self.b_random_rms_ug, self.ne_mean_cm3, self.p_rms_k,
                  self.b_index, self.ne_index, self.ncr_index, *self.b_regular_ug]
        if not all(math.isfinite(float(v)) for v in values):
            raise InputError("foreground parameters must be finite numbers")

    @property
    def beta(self) -> float:
        """Brightness-temperature spectral index, T ~ nu^-beta, beta = (p + 3) / 2."""
        return (self.electron_index + 3.0) / 2.0

    @property
    def intrinsic_fraction(self) -> float:
        """Intrinsic polarized fraction of synchrotron emission, (p + 1) / (p + 7/3)."""
        p = self.electron_index
        return (p + 1.0) / (p + 7.0 / 3.0)


@dataclass(frozen=True, eq=False)
class ForegroundBox:
    """Per-cell quantities of a generated box, each (nz, ny, nx) (z = line of sight).

    amp is the polarized emissivity per cell in relative units (before normalisation).
    """

    amp: np.ndarray
    chi0: np.ndarray
    dphi: np.ndarray
    cell_pc: tuple[float, float, float]

    def faraday_depth(self) -> np.ndarray:
        """Faraday depth at the far side of every cell, rad m^-2, (nz, ny, nx)."""
        return np.cumsum(self.dphi, axis=0)


def build_box(params: ForegroundParams, npix: int, seed: int | None = None
              ) -> tuple[ForegroundBox, int]:
    """Draw the random fields and return the per-cell emission and Faraday quantities.

    The transverse cell size is ``params.cell_perp_pc`` or, by default, the line-of-sight
    cell size (cubic cells, as in Jelic et al.'s boxes).

    Returns the box and the integer entropy of the seed sequence actually used (equal to
    ``seed`` when given), so that an unseeded run can be reproduced.
    """
    params.validate()
    if npix < 2:
        raise InputError(f"npix must be >= 2, got {npix}", param="npix")
    nz = int(params.ncells_los)
    dz = params.depth_pc / nz
    dperp = params.cell_perp_pc if params.cell_perp_pc is not None else dz
    shape, cell = (nz, npix, npix), (dz, dperp, dperp)
    ss = np.random.SeedSequence(seed)
    rng_b, rng_ne, rng_cr = (np.random.default_rng(s) for s in ss.spawn(3))

    b_e, b_n, b_par = (float(v) for v in params.b_regular_ug)
    bvec = solenoidal_vector_field(shape, cell, params.b_index, rng_b,
                                   outer_scale=params.outer_scale_pc,
                                   solenoidal=params.solenoidal)
    bvec *= params.b_random_rms_ug
    bz_par = b_par - bvec[0]
    bnorth = b_n + bvec[1]
    beast = b_e - bvec[2]
    del bvec
    gne = gaussian_random_field(shape, cell, params.ne_index, rng_ne,
                                outer_scale=params.outer_scale_pc)
    ne = lognormal_field(gne, params.ne_mean_cm3, params.ne_sigma_ln)
    del gne
    gcr = gaussian_random_field(shape, cell, params.ncr_index, rng_cr,
                                outer_scale=params.outer_scale_pc)
    ncr = lognormal_field(gcr, 1.0, params.ncr_sigma_ln)
    del gcr

    bperp = np.hypot(bnorth, beast)
    amp = params.intrinsic_fraction * ncr * bperp ** ((params.electron_index + 1.0) / 2.0) * dz
    del ncr, bperp
    chi0 = np.arctan2(beast, bnorth) + 0.5 * np.pi
    del beast, bnorth
    dphi = faraday_thickness(ne, bz_par, dz)
    return ForegroundBox(amp=amp, chi0=chi0, dphi=dphi, cell_pc=cell), int(ss.entropy)


def channel_frequencies(freq_min_hz: float, nchan: int, chan_width_hz: float) -> np.ndarray:
    """Channel centres: channel i at freq_min + i * width (Hz), as ``msleak simulate``."""
    if not (freq_min_hz > 0 and chan_width_hz > 0 and nchan >= 1):
        raise InputError("freq_min_hz and chan_width_hz must be > 0 and nchan >= 1",
                         param=("freq_min_hz", "chan_width_hz", "nchan"))
    return freq_min_hz + np.arange(int(nchan)) * chan_width_hz


def generate_foreground_cube(*, npix: int = 50, fov_deg: float = 15.0,
                             freq_min_hz: float = 150e6, nchan: int = 50,
                             chan_width_hz: float = 195312.5,
                             phase_centre: tuple[float, float] = (0.0, math.pi / 2),
                             seed: int | None = None,
                             params: ForegroundParams | None = None) -> SkyCube:
    """Generate Q and U foreground cubes in K (docs/science.md section 3).

    Parameters
    ----------
    npix : pixels a side
    fov_deg : field of view a side, deg (pixel = fov / npix)
    freq_min_hz, nchan, chan_width_hz : channels, centre of channel i = freq_min + i width
    phase_centre : (RA, Dec) of the cube centre, rad (default the NCP)
    seed : integer seed; ``None`` draws fresh entropy (recorded in ``meta["SEED"]``)
    params : physical parameters (:class:`ForegroundParams`)

    Returns
    -------
    SkyCube with data (2, nchan, npix, npix) float64 (Q, U) in K and the parameters,
    seed and measured statistics (PRMS150, PHIMIN, PHIMAX, PHISTD) in ``meta``.
    """
    params = params or ForegroundParams()
    if not (fov_deg > 0 and math.isfinite(fov_deg)) or fov_deg >= 180:
        raise InputError(f"fov_deg must be between 0 and 180 deg, got {fov_deg}",
                         param="fov_deg")
    freq = channel_frequencies(freq_min_hz, nchan, chan_width_hz)
    box, entropy = build_box(params, int(npix), seed)
    beta = params.beta
    ref = polarized_brightness(box.amp, box.chi0, box.dphi, np.array([params.ref_freq_hz]))[0]
    rms_ref = float(np.sqrt(np.mean(np.abs(ref) ** 2)))
    if rms_ref == 0:
        raise InputError("the model has no polarized emission (B_perp or n_CR is zero)")
    if not math.isfinite(rms_ref):
        raise InputError("the foreground parameters overflow (non-finite brightness); use "
                         "physically sensible values")
    scale = params.p_rms_k / rms_ref
    spectral = (freq / params.ref_freq_hz) ** (-beta)
    pcube = polarized_brightness(box.amp * scale, box.chi0, box.dphi, freq,
                                 spectral_factor=spectral)
    data = np.stack([pcube.real, pcube.imag])
    if not np.all(np.isfinite(data)):
        raise InputError("the foreground parameters overflow (non-finite brightness, e.g. an "
                         "extreme electron_index over the band); use physically sensible "
                         "values", param="electron_index")
    phi_total = box.faraday_depth()[-1]
    phi_all = faraday_depth_near_face(box.dphi) + 0.5 * box.dphi
    ra0, dec0 = phase_centre
    wcs = make_celestial_wcs(npix, npix, fov_deg / npix, math.degrees(ra0), math.degrees(dec0))
    # the box's angles are referred to the image +y axis; FITS Q, U to the local North
    turn = np.exp(2j * y_axis_position_angle(wcs, (npix, npix)))[None]
    pcube = pcube * turn
    data = np.stack([pcube.real, pcube.imag])
    meta = {f"P_{k.upper()}": (v if not isinstance(v, tuple) else ",".join(map(str, v)))
            for k, v in asdict(params).items() if v is not None}
    meta.update({
        "GENERATR": "msleak.sky.foreground (Jelic et al. 2008/2010 model B)",
        "POLFRAME": POLFRAME,
        "SEED": entropy,
        "BETA": beta,
        "EMSCALE": scale,
        "PRMSREF": float(np.sqrt(np.mean(np.abs(pcube[0]) ** 2))) if nchan else 0.0,
        "PRMS150": params.p_rms_k,
        "PHIMIN": float(phi_total.min()),
        "PHIMAX": float(phi_total.max()),
        "PHISTD": float(phi_total.std()),
        "PHICELL1": float(np.percentile(phi_all, 1)),
        "PHICEL99": float(np.percentile(phi_all, 99)),
    })
    log.info("foreground cube: rms |P| = %.3g K at %.4g MHz, total Faraday depth %.3g..%.3g "
             "rad/m^2", params.p_rms_k, params.ref_freq_hz / 1e6, meta["PHIMIN"], meta["PHIMAX"])
    return SkyCube(data=data, freq=freq, stokes=("Q", "U"), wcs=wcs, units="K", meta=meta)
