"""Power spectra of delay cubes on arrays: the 3D power of the used voxels, the
cylindrical, spherical and 1D averages (:mod:`msleak.ps.binning`) in k (:mod:`msleak.ps.cosmology`),
and the ps product's attributes (docs/ps.md, docs/products.md "ps").
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import xarray as xr

from msleak.errors import InputError
from msleak.ps import binning
from msleak.ps.cosmology import Cosmo, jy2_to_mk2_mpc3

__all__ = ["perp_edges", "Voxels", "voxels", "spectra", "ps_attrs", "to_little_h",
           "DEFAULT_KPERP_1D", "P_POWER_DEFINITION"]

log = logging.getLogger(__name__)

#: how the power of P = Q + iU is stored and averaged (attribute of the ps product)
P_POWER_DEFINITION = (
    "P is not Hermitian: every cell (u, tau) of the half plane holds two P voxels, "
    "|P~(u,tau)|^2 (power3d, stokes P) and |P~(-u,-tau)|^2 = |Q~(u,tau) - i U~(u,tau)|^2 "
    "(power3d_P_mirror), both paired with P_I(u,tau); the P bins average both voxels "
    "(= P_Q + P_U)")

#: default k_perp range (Mpc^-1) of the 1D PS (the paper's)
DEFAULT_KPERP_1D = (0.02, 0.1)

#: unit -> (unit with little h, power of h the values are multiplied by)
_LITTLE_H = {"Mpc^-1": ("h Mpc^-1", -1), "mK^2 Mpc^3": ("mK^2 h^-3 Mpc^3", 3),
             "Jy^2 Mpc^-3": ("Jy^2 h^3 Mpc^-3", -3)}


def perp_edges(a: dict, bins: int | None, log_bins: bool,
                bin_width: float | None) -> tuple[np.ndarray, bool]:
    """|b| bin edges (wavelengths) and whether they are logarithmic."""
    cell, uv_min, uv_max = a["cell_lambda"], a["uv_min_lambda"], a["uv_max_lambda"]
    if bin_width is not None:
        if not bin_width > 0 or bin_width > uv_max - uv_min:
            raise InputError(f"bin width {bin_width} must be within 0..{uv_max - uv_min:g} "
                             "wavelengths")
        nb = int(np.floor((uv_max - uv_min) / bin_width + 1e-9))
        return uv_min + bin_width * np.arange(nb + 1), False
    n = bins if bins is not None else max(1, int(math.ceil((uv_max - uv_min) / cell)))
    if log_bins:
        return binning.log_edges(max(uv_min, cell / 2), uv_max, n), True
    return binning.linear_edges(uv_min, uv_max, n), False


@dataclass(frozen=True)
class Voxels:
    """The used cells (one Hermitian half) and their 3D power (stokes, delay, cell), Jy^2."""

    iv: np.ndarray
    iu: np.ndarray
    b: np.ndarray                  #: |b| of each cell, wavelengths
    p3d: np.ndarray                #: |P~(u, tau)|^2 for Stokes P
    p_mirror: np.ndarray | None    #: (delay, cell) P power of the mirrored voxels
    p_bins: np.ndarray             #: p3d with P the mean of each voxel pair
    cross: bool


def voxels(dl: xr.Dataset, cross: bool | None) -> Voxels:
    a = dl.attrs
    uv_min, uv_max = a["uv_min_lambda"], a["uv_max_lambda"]
    cross = "vis_a" in dl if cross is None else bool(cross)
    if cross and "vis_a" not in dl:
        raise InputError("cross-power asked but the delay cube has no vis_a/vis_b halves "
                         "(grid with split)", param="split")
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
    labels = [str(s) for s in dl["stokes"].values]
    p3d = binning.power_3d(vt, vt_b, a["window_norm"])
    p_mirror = binning.mirror_polarized_power(vt, vt_b, labels, a["window_norm"])
    return Voxels(iv, iu, b[iv, iu], p3d, p_mirror, binning.pair_mean(p3d, p_mirror, labels),
                   cross)


def spectra(dl: xr.Dataset, vox: Voxels, cosmo: Cosmo, edges_b: np.ndarray, omega: float,
             sph_bins: int, k_range: tuple[float, float]) -> tuple[xr.Dataset, float | None]:
    """The ps variables and coordinates (k in Mpc^-1) and the Jy^2 -> mK^2 Mpc^3 factor."""
    factor = jy2_to_mk2_mpc3(cosmo, omega, dl.attrs["bandwidth_hz"]) if omega > 0 else None
    units, scale = ("mK^2 Mpc^3", factor) if factor else ("Jy^2", 1.0)
    delay = dl["delay"].values
    kperp_cell, kpar3d = cosmo.k_perp(vox.b), cosmo.k_par(delay)
    cyl = binning.cylindrical_average(vox.p_bins, delay, vox.b, edges_b)
    k_perp, k_par = cosmo.k_perp(cyl.perp_centres), cosmo.k_par(cyl.folded_delay)
    power = cyl.power * scale
    delta2 = k_perp[None, None, :] ** 2 * k_par[None, :, None] * power / (2 * np.pi) ** 2
    kmax = float(np.sqrt(kperp_cell.max() ** 2 + np.abs(kpar3d).max() ** 2))
    edges_k = binning.log_edges(float(max(kperp_cell.min(), 1e-6)), kmax * (1 + 1e-9),
                                sph_bins)
    p_sph, c_sph = binning.spherical_average(vox.p_bins * scale, kpar3d, kperp_cell, edges_k)
    p_1d, c_1d = binning.average_1d(vox.p_bins * scale, delay, kperp_cell, *k_range)
    if c_1d.max() == 0:
        log.warning("no uv cell has k_perp in %g..%g Mpc^-1: the 1D PS is empty", *k_range)
    cyl3, d3, kunit, one = ("stokes", "k_par", "k_perp"), ("stokes", "delay3d", "cell"), \
        {"units": "Mpc^-1"}, {"units": "1"}
    ds = xr.Dataset({
        "power": (cyl3, power, {"units": units}),
        "power_jy2": (cyl3, cyl.power, {"units": "Jy^2"}),
        "delta2": (cyl3, delta2, {"units": "mK^2" if factor else "Jy^2 Mpc^-3",
                                  "definition": "k_perp^2 k_par P / (2 pi)^2"}),
        "counts": (("k_par", "k_perp"), cyl.counts, one),
        "k_perp_bounds": (("k_perp", "nv"), cosmo.k_perp(np.column_stack(
            [edges_b[:-1], edges_b[1:]])), kunit),
        "power_sph": (("stokes", "k"), p_sph, {"units": units}),
        "counts_sph": (("k",), c_sph, one),
        "k_bounds": (("k", "nv"), np.column_stack([edges_k[:-1], edges_k[1:]]), kunit),
        "power_1d": (("stokes", "k_par"), p_1d, {"units": units}),
        "counts_1d": (("k_par",), c_1d, one),
        "power3d": (d3, vox.p3d * scale, {"units": units}),
    }, coords={
        "stokes": dl["stokes"].values,
        "k_par": ("k_par", k_par, {**kunit, "long_name": "k_par of the folded delays"}),
        "k_perp": ("k_perp", k_perp, {**kunit, "bounds": "k_perp_bounds"}),
        "k": ("k", np.sqrt(edges_k[:-1] * edges_k[1:]), {**kunit, "bounds": "k_bounds"}),
        "delay3d": ("delay3d", delay, {"units": "s"}),
        "b_lambda": ("k_perp", cyl.perp_centres, {"units": "wavelengths"}),
        "delay_folded": ("k_par", cyl.folded_delay, {"units": "s"}),
        "k_par3d": ("delay3d", kpar3d, kunit),
        "u_cell": ("cell", dl["u"].values[vox.iu], {"units": "wavelengths"}),
        "v_cell": ("cell", dl["v"].values[vox.iv], {"units": "wavelengths"}),
        "k_perp_cell": ("cell", kperp_cell, kunit),
    })
    if vox.p_mirror is not None:
        ds["power3d_P_mirror"] = (d3[1:], vox.p_mirror * scale, {
            "units": units, "long_name": "power of P = Q + iU in the mirrored voxel "
            "(-u, -tau) of every voxel (u, tau) of power3d"})
        ds.attrs["P_power_definition"] = P_POWER_DEFINITION
    return ds, factor


def ps_attrs(a: dict, cosmo: Cosmo, factor: float | None, omega: float,
              primary_theta: float | None, cross: bool) -> dict:
    """Cosmology, wedge and normalisation attributes of the ps product."""
    if primary_theta is not None:
        theta_p = float(primary_theta)
    elif a.get("primary_fwhm_deg"):  # half the station beam's FWHM (recorded by msleak grid)
        theta_p = float(a["primary_fwhm_deg"]) / 2
    else:
        theta_p = float(a.get("fov_deg", 0)) / 2
    return {
        "redshift": cosmo.z, "comoving_distance_mpc": cosmo.dc_mpc,
        "efunc": cosmo.efunc, "hubble_distance_mpc": cosmo.dh_mpc,
        "x_mpc_per_rad": cosmo.x_mpc_per_rad, "y_mpc_per_hz": cosmo.y_mpc_per_hz,
        "wedge_slope_horizon": cosmo.wedge_slope(90.0),
        "wedge_slope_primary": cosmo.wedge_slope(theta_p), "primary_theta_deg": theta_p,
        "wedge_definition": "k_par = sin(theta) D_c E(z) / (D_H (1 + z)) k_perp",
        "cross_power": int(cross), "units": "mK^2 Mpc^3" if factor else "Jy^2",
        "beam_area_sr": omega, "jy2_to_mk2_mpc3": factor or 0.0,
        "power_definition": ("P3D = |V~|^2 / window_norm" if not cross else
                             "P3D = Re(V~_a conj(V~_b)) / window_norm")
                            + (" times jy2_to_mk2_mpc3" if factor else ""),
    }


def to_little_h(ds: xr.Dataset, h: float) -> xr.Dataset:
    """A ps Dataset with k in h Mpc^-1 and P in mK^2 h^-3 Mpc^3 (Jy^2 Mpc^-3 in
    Jy^2 h^3 Mpc^-3): every variable and coordinate converted by its ``units``."""
    new = {}
    for name, var in ds.variables.items():
        unit = _LITTLE_H.get(var.attrs.get("units"))
        if unit:
            new[name] = xr.Variable(var.dims, var.values * h ** unit[1],
                                    {**var.attrs, "units": unit[0]})
    out = ds.assign_coords({n: v for n, v in new.items() if n in ds.coords})
    out = out.assign({n: v for n, v in new.items() if n not in ds.coords})
    out.attrs["units"] = _LITTLE_H.get(ds.attrs["units"], (ds.attrs["units"],))[0]
    out.attrs["k_perp_min_1d"] = ds.attrs["k_perp_min_1d"] / h
    out.attrs["k_perp_max_1d"] = ds.attrs["k_perp_max_1d"] / h
    out.attrs["little_h"] = 1
    return out
