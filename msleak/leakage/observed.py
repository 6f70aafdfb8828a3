"""Expected leakage and bias correction of observed PS products, as xarray Datasets
(docs/leakage.md "Expected leakage", "Bias correction"); the formulas are in
:mod:`msleak.leakage.expected`."""

from __future__ import annotations

import logging
from typing import Literal

import numpy as np
import xarray as xr

from msleak.errors import InputError
from msleak.leakage import expected as ex
from msleak.leakage.bootstrap import on_uv_grid, uv_cell_size
from msleak.leakage.fraction import MASK_CODES, stokes_power
from msleak.ps.delay import spectral_window

__all__ = ["expected_leakage", "bias_correct", "correlation", "ModelMode"]

log = logging.getLogger(__name__)

ModelMode = Literal["auto", "map", "median", "field"]


def _pair(i_obs: int, n_obs: int, n_in: int) -> int | None:
    if n_in == 1:
        return 0
    return i_obs if n_obs == n_in else None


def _observed_p(obs: xr.Dataset, name: str) -> tuple[np.ndarray, np.ndarray]:
    """The observed Stokes P power (0 in empty bins) and the counts of its 2D bins."""
    p_p = stokes_power(obs, "power", "P", name).transpose("k_par", "k_perp")
    if "counts" in obs.variables:
        counts = obs["counts"].transpose("k_par", "k_perp").values.astype(float)
    else:
        log.warning("%s: no 'counts'; sample-variance errors assume 1 cell per bin", name)
        counts = np.ones(p_p.shape)
    counts = np.where(np.isfinite(p_p.values), counts, 0.0)
    return np.where(counts > 0, np.real(p_p.values), 0.0), counts


def _leakage_model(result: xr.Dataset, obs: xr.Dataset, i_obs: int, n_obs: int,
                   mode: ModelMode, name: str) -> dict:
    """The L_I model of one observed product (docs/leakage.md "Expected leakage"): its
    mode, 2D values (percent), scalar, default relative error, label and filled bins."""
    n_in = result.sizes["input"]
    j = _pair(i_obs, n_obs, n_in)
    shape = (obs.sizes["k_par"], obs.sizes["k_perp"])
    grid_ok = False
    if j is not None:
        model = _own_grid(result.isel(input=j))
        grid_ok = ex.same_grid(model["k_par"].values, model["k_perp"].values,
                               obs["k_par"].values, obs["k_perp"].values)
    if mode == "auto":
        mode = "map" if grid_ok else ("median" if j is not None else "field")
    if mode in ("map", "median") and j is None:
        raise InputError(f"expected_model {mode} pairs observed PS i with model input i: "
                         f"give {n_in} observed PS (got {n_obs}) or use expected_model field",
                         param="expected_model")
    if mode == "map" and not grid_ok:
        raise InputError(f"{name}: its (k_par, k_perp) grid differs from the model input "
                         f"{result['label'].values[j]!r}; use expected_model median or field",
                         param="expected_model")
    filled = np.zeros(shape, dtype=np.int8)
    if mode == "field":
        scalar = float(result.attrs["field_estimate"])
        stat = float(np.sqrt(np.mean(result["pareto_median_err"].values ** 2)))
        rel = _ratio(ex.leakage_model_error(stat, result["pareto_median"].values), scalar)
        return {"mode": mode, "L": np.full(shape, scalar), "scalar": scalar, "rel": rel,
                "label": f"field estimate of {','.join(map(str, result['label'].values))}",
                "filled": filled}
    scalar = float(result["pareto_median"].values[j])
    rel = _ratio(float(result["pareto_median_err"].values[j]), scalar)
    L_model = np.full(shape, scalar)
    if mode == "map":
        mask = model["mask"].values
        L_model = np.where(mask == 0, model["L_I"].values, scalar)
        filled = (mask != 0).astype(np.int8)
        if filled.any():
            log.info("%s: %d masked model bins use the median L_I %.4g %%", name,
                     int(filled.sum()), scalar)
    return {"mode": mode, "L": L_model, "scalar": scalar, "rel": rel,
            "label": str(result["label"].values[j]), "filled": filled}


def _spherical_p(obs: xr.Dataset, p_p: np.ndarray, counts: np.ndarray, k_edges: np.ndarray,
                 scalar_model: bool, name: str) -> tuple[np.ndarray, np.ndarray, str]:
    """Spherical P_P,obs and counts: the product's ``power_sph`` for a scalar model (it
    scales exactly), else the counts-weighted average of the 2D bins."""
    if scalar_model and "power_sph" in obs.variables:
        pp_sph = np.real(stokes_power(obs, "power_sph", "P", name).values)
        c_sph = (obs["counts_sph"].values.astype(float) if "counts_sph" in obs.variables
                 else np.ones(pp_sph.size))
        c_sph = np.where(np.isfinite(pp_sph), c_sph, 0.0)
        return np.where(c_sph > 0, pp_sph, 0.0), c_sph, "power_sph"
    pp_sph, c_sph = ex.spherical_from_bins(p_p, counts, obs["k_par"].values,
                                           obs["k_perp"].values, k_edges)
    return pp_sph, c_sph, "2D bins"


def expected_leakage(result: xr.Dataset, obs: xr.Dataset, i_obs: int = 0, n_obs: int = 1,
                     mode: ModelMode = "auto", rel_error: float | None = None,
                     name: str = "observed PS") -> xr.Dataset:
    """Expected leakage PS of one observed PS product: (L_I_model / 100)^2 P_P,obs.

    Parameters
    ----------
    result : xarray.Dataset
        The leakage result (:func:`msleak.leakage.analysis.analyse`), the model.
    obs : xarray.Dataset
        Observed PS product with Stokes P in ``power`` (and ``counts``; ``power_sph``
        optional).
    i_obs, n_obs : int
        Index of this observed product and how many there are: observed product i pairs
        with model input i when their numbers agree, or with the only model input.
    mode : {"auto", "map", "median", "field"}
        ``map``: the paired input's L_I map (grids must match; masked model bins take the
        paired median); ``median``: the paired input's fitted median; ``field``: the
        per-field estimate (mean of fitted medians); ``auto``: map if paired with the
        same grid, else median if paired, else field.
    rel_error : float, optional
        Relative uncertainty of the model L_I; default: the fit's statistical error (map,
        median), combined with the spread over fields of view (field).

    Returns
    -------
    xarray.Dataset
        The layout of ``expected_<label>.h5`` (docs/leakage.md).
    """
    p_p, counts = _observed_p(obs, name)
    m = _leakage_model(result, obs, i_obs, n_obs, mode, name)
    k_par, k_perp = obs["k_par"].values, obs["k_perp"].values
    rel = m["rel"] if rel_error is None else float(rel_error)
    corr = correlation(obs, "P", name)
    counts_eff = counts / np.where(k_par[:, None] > 0, corr["c_2d"], corr["c_2d_zero"])
    leak = ex.expected_leakage_power(p_p, m["L"])
    units = str(obs["power"].attrs.get("units", obs.attrs.get("units", "")))
    dims = ("k_par", "k_perp")
    k, k_edges = _k_bins(obs, k_par, k_perp)
    out = xr.Dataset(
        {"power_P_obs": (dims, p_p, {"units": units}),
         "counts": (dims, counts),
         "counts_eff": (dims, counts_eff, {"long_name": "effective number of independent "
                                           "cells, counts / corr_factor_2d"}),
         "L_I_model": (dims, m["L"], {"units": "percent"}),
         "L_I_model_err": (dims, rel * m["L"], {"units": "percent"}),
         "L_I_model_filled": (dims, m["filled"]),
         "power_leak": (dims, leak, {"units": units,
                                     "long_name": "(L_I_model/100)^2 P_P,obs"}),
         "power_leak_err": (dims, ex.expected_leakage_error(p_p, counts_eff, m["L"],
                                                            rel * m["L"]), {"units": units})},
        coords={"k_par": ("k_par", k_par, {"units": "Mpc^-1"}),
                "k_perp": ("k_perp", k_perp, {"units": "Mpc^-1"}),
                "k": ("k", k, {"units": "Mpc^-1"})})
    pp_sph, c_sph, sph_source = _spherical_p(obs, p_p, counts, k_edges, m["mode"] != "map",
                                             name)
    if m["mode"] == "map":
        leak_sph, _ = ex.spherical_from_bins(leak, counts, k_par, k_perp, k_edges)
        L_sph = np.where(pp_sph > 0, 100 * np.sqrt(np.divide(
            leak_sph, pp_sph, out=np.zeros_like(pp_sph), where=pp_sph > 0)), m["scalar"])
    else:
        leak_sph = ex.expected_leakage_power(pp_sph, m["scalar"])
        L_sph = np.full(k.size, m["scalar"])
    out["power_P_obs_sph"] = ("k", pp_sph, {"units": units})
    out["counts_sph"] = ("k", c_sph)
    out["counts_sph_eff"] = ("k", c_sph / corr["c_sph"])
    out["power_leak_sph"] = ("k", leak_sph, {"units": units})
    out["power_leak_sph_err"] = ("k", ex.expected_leakage_error(
        pp_sph, c_sph / corr["c_sph"], L_sph, rel * L_sph), {"units": units})
    out.attrs.update(_expected_attrs(obs, m, rel, sph_source, units, corr, name))
    return out


def _expected_attrs(obs: xr.Dataset, m: dict, rel: float, sph_source: str, units: str,
                    corr: dict, name: str) -> dict:
    attrs = {
        "source": name, "model_mode": m["mode"], "model_input": m["label"],
        "L_I_model_scalar": m["scalar"], "L_I_model_rel_error": rel,
        "spherical_from": sph_source, "units": units,
        "formula": "P_leak = (L_I_model/100)^2 P_P,obs; sigma_leak^2 = (l^2 |P_P|/sqrt(N))^2 "
                   "+ (2 l sigma_l P_P)^2, l = L_I_model/100, N = counts / corr_factor",
        "corr_factor_2d": corr["c_2d"], "corr_factor_2d_kpar0": corr["c_2d_zero"],
        "corr_factor_sph": corr["c_sph"], "corr_method": corr["method"],
    }
    for key in ("wedge_slope_horizon", "wedge_slope_primary", "cosmology", "redshift"):
        if key in obs.attrs:
            attrs[key] = obs.attrs[key]
    return attrs


def correlation(ds: xr.Dataset, stokes: str, name: str = "PS product") -> dict:
    """Voxels per independent sample of a PS product's Stokes ``stokes`` power.

    From the unaveraged power (``power3d`` with ``k_par3d``, ``k_perp_cell``, ``u_cell``,
    ``v_cell``; for P the mean of each voxel and its mirror ``power3d_P_mirror``, what the
    P bins average) by :func:`msleak.leakage.expected.correlation_factors` (``method`` =
    ``measured``); without it, by counting uv cells rather than voxels: the +tau and
    -tau voxels of a cell count once in a 2D bin (c = 2 for k_par > 0), and in a spherical
    shell also the window's delay correlation length (``method`` = ``uv-cells``).

    Returns
    -------
    dict
        ``c_2d`` (k_par > 0 bins), ``c_2d_zero`` (the k_par = 0 row), ``c_sph``,
        ``method``.
    """
    need = ("power3d", "k_par3d", "k_perp_cell", "u_cell", "v_cell", "k_perp_bounds")
    if all(v in ds.variables for v in need) and "delay3d" in ds.dims:
        try:
            p3 = stokes_power(ds, "power3d", stokes, name).transpose("delay3d", "cell").values
        except InputError:
            p3 = None
        if p3 is not None and stokes == "P":  # the P bins average each voxel and its mirror
            p3 = (0.5 * (p3 + ds["power3d_P_mirror"].transpose("delay3d", "cell").values)
                  if "power3d_P_mirror" in ds.variables else None)
        if p3 is not None:
            k3 = np.abs(np.asarray(ds["k_par3d"].values, float))
            k_par = np.asarray(ds["k_par"].values, float)
            ipar = np.argmin(np.abs(k3[:, None] - k_par[None, :]), axis=1)
            bounds = ds["k_perp_bounds"].values
            edges = np.concatenate([bounds[:, 0], bounds[-1:, 1]])
            iperp = np.clip(np.digitize(ds["k_perp_cell"].values, edges) - 1, 0,
                            edges.size - 2)
            bins = ipar[:, None] * (edges.size + 1) + iperp[None, :]
            order = np.argsort(np.asarray(ds["delay3d"].values, float))
            dk = np.empty(order.size, dtype=np.int64)
            dk[order] = np.arange(order.size) - int(np.argmin(np.abs(
                np.asarray(ds["delay3d"].values, float)[order])))
            u, v = ds["u_cell"].values, ds["v_cell"].values
            cell = float(ds.attrs.get("cell_lambda", 0) or 0) or uv_cell_size(u, v)
            iu, iv = np.rint(u / cell), np.rint(v / cell)
            if not on_uv_grid(u, v, cell):
                log.warning("%s: the uv cells are not on a grid of %g wavelengths; their "
                            "uv correlation is not measured", name, cell)
                iu = iv = None
            r = ex.correlation_factors(p3, bins, dk, iu, iv)
            c0 = max(1.0, r["c_2d"] - r["rho_mirror"])
            log.info("%s: Stokes %s voxels per independent sample %.2g (2D bins), %.2g "
                     "(spherical)", name, stokes, r["c_2d"], r["c_sph"])
            return {"c_2d": r["c_2d"], "c_2d_zero": c0, "c_sph": r["c_sph"],
                    "method": "measured"}
    window = 1.0
    if "window" in ds.attrs and "nchan" in ds.attrs:
        try:
            window = ex.window_correlation_length(
                spectral_window(str(ds.attrs["window"]), int(ds.attrs["nchan"])))
        except (InputError, ValueError):
            window = 1.0
    log.warning("%s: no unaveraged power (power3d with cell coordinates): sample-variance "
                "errors count uv cells, not voxels", name)
    return {"c_2d": 2.0, "c_2d_zero": 1.0, "c_sph": 2.0 * window, "method": "uv-cells"}


def _ratio(a: float, b: float) -> float:
    return a / b if b > 0 else 0.0


def _own_grid(model: xr.Dataset) -> xr.Dataset:
    """One input's map on its own k grid (drop union-grid rows/columns it lacks)."""
    inside = model["mask"] != MASK_CODES["not_in_grid"]
    return model.isel(k_par=inside.any("k_perp").values, k_perp=inside.any("k_par").values)


def _k_bins(obs: xr.Dataset, k_par, k_perp) -> tuple[np.ndarray, np.ndarray]:
    """Spherical k bin centres and edges: the product's ``k`` (edges from ``k_bounds``
    or midpoints), or, without ``k``, 20 log bins over the 2D grid."""
    if "k" in obs.coords or "k" in obs.variables:
        k = np.asarray(obs["k"].values, dtype=float)
        if "k_bounds" in obs.variables:
            bounds = obs["k_bounds"].values
            edges = np.concatenate([bounds[:, 0], bounds[-1:, 1]]).astype(float)
        else:
            edges = ex.edges_from_centres(k)
        return k, edges
    kk = np.hypot(np.asarray(k_par)[:, None], np.asarray(k_perp)[None, :])
    lo = max(kk[kk > 0].min(), 1e-6) if np.any(kk > 0) else 1e-3
    edges = np.geomspace(lo, kk.max() * 1.0001, 21)
    return np.sqrt(edges[1:] * edges[:-1]), edges


def bias_correct(obs_i: xr.Dataset, expected: xr.Dataset, name: str = "observed PS"
                 ) -> xr.Dataset:
    """Subtract the expected leakage from the observed Stokes I PS (bias correction).

    Parameters
    ----------
    obs_i : xarray.Dataset
        Observed PS product with Stokes I in ``power`` on the grid of ``expected``.
    expected : xarray.Dataset
        Output of :func:`expected_leakage`.

    Returns
    -------
    xarray.Dataset
        ``expected`` plus ``power_I_obs``, ``power_I_corrected``,
        ``power_I_corrected_err`` (k_par, k_perp) and their spherical versions (k).
    """
    p_i = stokes_power(obs_i, "power", "I", name).transpose("k_par", "k_perp")
    if not ex.same_grid(obs_i["k_par"].values, obs_i["k_perp"].values,
                        expected["k_par"].values, expected["k_perp"].values):
        raise InputError(f"{name}: its (k_par, k_perp) grid differs from that of the "
                         f"polarized PS {expected.attrs.get('source', '')}")
    counts = expected["counts"].values
    if "counts" in obs_i.variables:
        counts = np.minimum(counts, obs_i["counts"].transpose("k_par", "k_perp").values)
    counts = np.where(np.isfinite(p_i.values), counts, 0.0)
    p_i_val = np.where(counts > 0, np.real(p_i.values), 0.0)
    cf = correlation(obs_i, "I", name)
    k_par = expected["k_par"].values
    counts_eff = counts / np.where(k_par[:, None] > 0, cf["c_2d"], cf["c_2d_zero"])
    corr, err = ex.corrected_power(p_i_val, counts_eff, expected["power_leak"].values,
                                   expected["power_leak_err"].values)
    out = expected.copy()
    units = expected.attrs.get("units", "")
    dims = ("k_par", "k_perp")
    out["power_I_obs"] = (dims, p_i_val, {"units": units})
    out["power_I_corrected"] = (dims, corr, {"units": units,
                                             "long_name": "P_I,obs - P_leak"})
    out["power_I_corrected_err"] = (dims, err, {"units": units})
    k_edges = ex.edges_from_centres(expected["k"].values)
    if "k_bounds" in obs_i.variables:
        bounds = obs_i["k_bounds"].values
        k_edges = np.concatenate([bounds[:, 0], bounds[-1:, 1]])
    if expected.attrs.get("spherical_from") == "power_sph" and "power_sph" in obs_i.variables:
        pi_sph = np.real(stokes_power(obs_i, "power_sph", "I", name).values)
        pi_sph = np.where(np.isfinite(pi_sph), pi_sph, 0.0)
        c_sph = expected["counts_sph"].values
    else:
        pi_sph, c_sph = ex.spherical_from_bins(p_i_val, counts, expected["k_par"].values,
                                               expected["k_perp"].values, k_edges)
    corr_sph, err_sph = ex.corrected_power(pi_sph, c_sph / cf["c_sph"],
                                           expected["power_leak_sph"].values,
                                           expected["power_leak_sph_err"].values)
    out["power_I_obs_sph"] = ("k", pi_sph, {"units": units})
    out["power_I_corrected_sph"] = ("k", corr_sph, {"units": units})
    out["power_I_corrected_sph_err"] = ("k", err_sph, {"units": units})
    out.attrs["source_I"] = name
    out.attrs["correction_formula"] = (
        "P_I,corr = P_I,obs - P_leak; sigma^2 = (|P_I,obs|/sqrt(N))^2 + sigma_leak^2, "
        "N = counts / corr_factor (of Stokes I)")
    out.attrs.update({"corr_factor_I_2d": cf["c_2d"], "corr_factor_I_sph": cf["c_sph"],
                      "corr_method_I": cf["method"]})
    return out
