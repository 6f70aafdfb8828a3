"""Delay cubes and power spectra as product Datasets (docs/products.md "delay" and "ps").

:func:`transform_uvcube` turns a uvcube Dataset into a delay Dataset;
:func:`power_spectrum` turns a delay Dataset into a ps Dataset. Both wrap the pure
functions of :mod:`msleak.ps.delay`, :mod:`msleak.ps.binning` and
:mod:`msleak.ps.cosmology`.
"""

from __future__ import annotations

import logging
import math
from typing import Literal

import numpy as np
import xarray as xr

from msleak.errors import InputError
from msleak.ps import binning
from msleak.ps.cosmology import cosmo_at, jy2_to_mk2_mpc3
from msleak.ps.delay import FFT_CONVENTION, delay_axis, delay_transform, spectral_window

__all__ = ["transform_uvcube", "power_spectrum", "DEFAULT_KPERP_1D", "P_POWER_DEFINITION"]

log = logging.getLogger(__name__)

#: how the power of P = Q + iU is stored and averaged (attribute of the ps product)
P_POWER_DEFINITION = (
    "P is not Hermitian: every cell (u, tau) of the half plane holds two P voxels, "
    "|P~(u,tau)|^2 (power3d, stokes P) and |P~(-u,-tau)|^2 = |Q~(u,tau) - i U~(u,tau)|^2 "
    "(power3d_P_mirror), both paired with P_I(u,tau); the P bins average both voxels "
    "(= P_Q + P_U)")

#: default k_perp range (Mpc^-1) of the 1D PS (the paper's)
DEFAULT_KPERP_1D = (0.02, 0.1)


def transform_uvcube(uv: xr.Dataset, window: str = "blackman-harris",
                     partial: Literal["drop", "zero"] = "drop") -> xr.Dataset:
    """Delay-transform every uv cell of a uvcube Dataset (see :mod:`msleak.ps.delay`)."""
    freq = uv["freq"].values
    nchan = freq.size
    if nchan < 2:
        raise InputError(f"the uv cube has {nchan} channel(s); a delay transform needs >= 2")
    dnu = float(np.median(np.diff(freq)))
    if not np.allclose(np.diff(freq), dnu, rtol=1e-6, atol=0):
        raise InputError("the uv cube channels are not evenly spaced")
    win = spectral_window(window, nchan)
    names = [n for n in ("vis", "vis_a", "vis_b") if n in uv]
    weight = uv["weight"].values
    if "vis_a" in uv:  # halves: a cell must hold data in both halves to be used
        weight = np.where((uv["weight_a"].values > 0) & (uv["weight_b"].values > 0), weight, 0)
    out = {}
    cell_weight = window_norm = chan_ok = None
    for name in names:
        vt, cell_weight, window_norm, chan_ok = delay_transform(
            uv[name].values, weight, win, partial=partial)
        out[name] = (("stokes", "delay", "v", "u"), vt, {"units": "Jy"})
    out["weight"] = (("v", "u"), cell_weight, {"long_name": "sum of weights over channels"})
    out["window_values"] = (("freq",), win * chan_ok)
    ds = xr.Dataset(out, coords={
        "stokes": uv["stokes"].values, "delay": ("delay", delay_axis(nchan, dnu), {"units": "s"}),
        "v": uv["v"], "u": uv["u"], "freq": uv["freq"]})
    ds.attrs.update(uv.attrs)
    for key in ("msleak_product", "created", "command"):
        ds.attrs.pop(key, None)
    ds.attrs.update({
        "window": window.lower(), "window_norm": window_norm,
        "window_norm_definition": "sum(window^2 * channel_mask) / nchan",
        "freq_centre_hz": float(0.5 * (freq[0] + freq[-1])), "bandwidth_hz": nchan * dnu,
        "nchan": nchan, "channel_width_hz": dnu, "fft_convention": FFT_CONVENTION,
        "flagged_channels": int((~chan_ok).sum()), "empty_cell_policy": partial,
        "n_cells_used": int((cell_weight > 0).sum()),
    })
    if ds.attrs["n_cells_used"] == 0:
        raise InputError("no uv cell holds data in every channel; try --partial zero or a "
                         "wider uv range")
    return ds


def power_spectrum(dl: xr.Dataset, *, cosmology: str = "Planck18", n_perp: int | None = None,
                   log_perp: bool = False, n_sph: int = 12,
                   kperp_1d: tuple[float, float] = DEFAULT_KPERP_1D,
                   primary_theta_deg: float | None = None, beam_area_sr: float | None = None,
                   cross: bool | None = None, bin_width: float | None = None) -> xr.Dataset:
    """Cylindrical, spherical and 1D power spectra of a delay Dataset.

    Parameters
    ----------
    dl : delay Dataset
    cosmology : astropy cosmology name
    n_perp : number of |b| bins between the uv range limits (default: one per cell width)
    log_perp : logarithmic |b| bins
    n_sph : number of logarithmic spherical k bins
    kperp_1d : (min, max) k_perp (Mpc^-1) averaged in the 1D PS
    primary_theta_deg : angle of the primary wedge (default half the cube's
        ``primary_fwhm_deg``, the station beam's FWHM; else half its ``fov_deg``)
    beam_area_sr : Omega (default the delay cube's ``beam_area_sr``)
    cross : use the cross-power of ``vis_a``, ``vis_b`` (default: when they exist)
    bin_width : |b| bin width in wavelengths (linear bins from the uv minimum, as many
        whole bins as fit below the uv maximum); overrides ``n_perp``/``log_perp``
    """
    a = dl.attrs
    cell, uv_min, uv_max = a["cell_lambda"], a["uv_min_lambda"], a["uv_max_lambda"]
    if cross is None:
        cross = "vis_a" in dl
    if cross and "vis_a" not in dl:
        raise InputError("cross-power asked but the delay cube has no vis_a/vis_b halves "
                         "(grid with --split)")
    cosmo = cosmo_at(a["freq_centre_hz"], cosmology)
    uu, vv = np.meshgrid(dl["u"].values, dl["v"].values)
    b = np.hypot(uu, vv)
    sel = (binning.half_plane(uu, vv) & (dl["weight"].values > 0)
           & (b >= uv_min) & (b <= uv_max))
    if not sel.any():
        raise InputError(f"no used uv cell with |b| in {uv_min:g}..{uv_max:g} wavelengths")
    iv, iu = np.nonzero(sel)
    if cross:
        vt, vt_b = dl["vis_a"].values[:, :, iv, iu], dl["vis_b"].values[:, :, iv, iu]
    else:
        vt, vt_b = dl["vis"].values[:, :, iv, iu], None
    p3d = binning.power_3d(vt, vt_b, a["window_norm"])
    labels = [str(s) for s in dl["stokes"].values]
    p_mirror = binning.mirror_polarized_power(vt, vt_b, labels, a["window_norm"])
    del vt, vt_b
    p_bins = binning.pair_mean(p3d, p_mirror, labels)  # P bins: both voxels of each pair
    delay = dl["delay"].values
    b_cell = b[iv, iu]
    kperp_cell = cosmo.k_perp(b_cell)
    kpar_signed = cosmo.k_par(delay)
    if n_perp is None:
        n_perp = max(1, int(math.ceil((uv_max - uv_min) / cell)))
    lo = max(uv_min, cell / 2) if log_perp else uv_min
    if bin_width is not None:
        if not bin_width > 0 or bin_width > uv_max - uv_min:
            raise InputError(f"bin width {bin_width} must be within 0..{uv_max - uv_min:g} "
                             "wavelengths")
        nb = int(np.floor((uv_max - uv_min) / bin_width + 1e-9))
        edges_b = uv_min + bin_width * np.arange(nb + 1)
        log_perp = False
    else:
        edges_b = (binning.log_edges(lo, uv_max, n_perp) if log_perp
                   else binning.linear_edges(uv_min, uv_max, n_perp))
    cyl = binning.cylindrical_average(p_bins, delay, b_cell, edges_b)
    omega = float(beam_area_sr or a.get("beam_area_sr") or 0.0)
    factor = jy2_to_mk2_mpc3(cosmo, omega, a["bandwidth_hz"]) if omega > 0 else None
    units = "mK^2 Mpc^3" if factor else "Jy^2"
    scale = factor or 1.0
    k_perp_c = cosmo.k_perp(cyl.perp_centres)
    k_par = cosmo.k_par(cyl.folded_delay)
    power = cyl.power * scale
    delta2 = k_perp_c[None, None, :] ** 2 * k_par[None, :, None] * power / (2 * np.pi) ** 2

    kmax = float(np.sqrt(kperp_cell.max() ** 2 + np.abs(kpar_signed).max() ** 2))
    kmin = float(max(kperp_cell.min(), 1e-6))
    edges_k = binning.log_edges(kmin, kmax * (1 + 1e-9), n_sph)
    p_sph, c_sph = binning.spherical_average(p_bins * scale, kpar_signed, kperp_cell, edges_k)
    p_1d, c_1d = binning.average_1d(p_bins * scale, delay, kperp_cell, *kperp_1d)
    if c_1d.max() == 0:
        log.warning("no uv cell has k_perp in %g..%g Mpc^-1: the 1D PS is empty", *kperp_1d)
    if primary_theta_deg is not None:
        theta_p = primary_theta_deg
    elif a.get("primary_fwhm_deg"):  # half the station beam's FWHM (recorded by msleak grid)
        theta_p = float(a["primary_fwhm_deg"]) / 2
    else:
        theta_p = a.get("fov_deg", 0) / 2
    stokes = dl["stokes"].values
    d3 = ("stokes", "delay3d", "cell")
    ds = xr.Dataset(
        {
            "power": (("stokes", "k_par", "k_perp"), power, {"units": units}),
            "power_jy2": (("stokes", "k_par", "k_perp"), cyl.power, {"units": "Jy^2"}),
            "delta2": (("stokes", "k_par", "k_perp"), delta2,
                       {"units": "mK^2" if factor else "Jy^2 Mpc^-3",
                        "definition": "k_perp^2 k_par P / (2 pi)^2"}),
            "counts": (("k_par", "k_perp"), cyl.counts),
            "k_perp_lo": (("k_perp",), cosmo.k_perp(edges_b[:-1]), {"units": "Mpc^-1"}),
            "k_perp_hi": (("k_perp",), cosmo.k_perp(edges_b[1:]), {"units": "Mpc^-1"}),
            "b_lambda": (("k_perp",), cyl.perp_centres, {"units": "wavelengths"}),
            "delay_folded": (("k_par",), cyl.folded_delay, {"units": "s"}),
            "power_sph": (("stokes", "k"), p_sph, {"units": units}),
            "counts_sph": (("k",), c_sph),
            "k_lo": (("k",), edges_k[:-1], {"units": "Mpc^-1"}),
            "k_hi": (("k",), edges_k[1:], {"units": "Mpc^-1"}),
            "power_1d": (("stokes", "k_par"), p_1d, {"units": units}),
            "counts_1d": (("k_par",), c_1d),
            "power3d": (d3, p3d * scale, {"units": units}),
            "u_cell": (("cell",), dl["u"].values[iu], {"units": "wavelengths"}),
            "v_cell": (("cell",), dl["v"].values[iv], {"units": "wavelengths"}),
            "k_perp_cell": (("cell",), kperp_cell, {"units": "Mpc^-1"}),
            "k_par3d": (("delay3d",), kpar_signed, {"units": "Mpc^-1"}),
        },
        coords={"stokes": stokes,
                "k_par": ("k_par", k_par, {"units": "Mpc^-1"}),
                "k_perp": ("k_perp", k_perp_c, {"units": "Mpc^-1"}),
                "k": ("k", np.sqrt(edges_k[:-1] * edges_k[1:]), {"units": "Mpc^-1"}),
                "delay3d": ("delay3d", delay, {"units": "s"})},
    )
    if p_mirror is not None:
        ds["power3d_P_mirror"] = (d3[1:], p_mirror * scale, {
            "units": units, "long_name": "power of P = Q + iU in the mirrored voxel "
            "(-u, -tau) of every voxel (u, tau) of power3d"})
        ds.attrs["P_power_definition"] = P_POWER_DEFINITION
    keep = ("cell_lambda", "uv_min_lambda", "uv_max_lambda", "source", "source_kind",
            "column", "field_id", "gridder", "w_correction", "fov_deg", "taper",
            "primary_fwhm_deg", "window",
            "window_norm", "freq_centre_hz", "bandwidth_hz", "nchan", "channel_width_hz",
            "fft_convention", "stokes_convention", "split", "empty_cell_policy",
            "correlations", "stokes_missing")
    ds.attrs.update({k: a[k] for k in keep if k in a})
    ds.attrs.update({
        "cosmology": cosmology, "redshift": cosmo.z, "comoving_distance_mpc": cosmo.dc_mpc,
        "efunc": cosmo.efunc, "hubble_distance_mpc": cosmo.dh_mpc,
        "x_mpc_per_rad": cosmo.x_mpc_per_rad, "y_mpc_per_hz": cosmo.y_mpc_per_hz,
        "wedge_slope_horizon": cosmo.wedge_slope(90.0),
        "wedge_slope_primary": cosmo.wedge_slope(theta_p), "primary_theta_deg": theta_p,
        "wedge_definition": "k_par = sin(theta) D_c E(z) / (D_H (1 + z)) k_perp",
        "cross_power": int(bool(cross)), "units": units,
        "beam_area_sr": omega, "jy2_to_mk2_mpc3": factor or 0.0,
        "power_definition": ("P3D = |V~|^2 / window_norm" if not cross else
                             "P3D = Re(V~_a conj(V~_b)) / window_norm")
                            + (" times jy2_to_mk2_mpc3" if factor else ""),
        "k_perp_min_1d": kperp_1d[0], "k_perp_max_1d": kperp_1d[1],
        "k_perp_binning": "log" if log_perp else "linear",
    })
    return ds
