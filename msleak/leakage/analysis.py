"""Assemble leakage results as xarray Datasets (no file access here).

:func:`analyse` turns several PS products (e.g. three fields of view of one field) into
one leakage result (layout in docs/leakage.md); :func:`predict` and :func:`correct` make
the expected-leakage and bias-corrected spectra of observed PS products.
"""

from __future__ import annotations

import logging
from typing import Literal, Sequence

import numpy as np
import xarray as xr

from msleak.errors import InputError
from msleak.leakage import expected as ex
from msleak.leakage.bootstrap import cell_groups
from msleak.leakage.fraction import (MASK_CODES, NegativePolicy, leakage_fraction,
                                     leakage_map, leakage_voxels, stokes_power, voxel_power)
from msleak.leakage.stats import field_estimate, leakage_statistics

__all__ = ["analyse", "realisation_estimates", "predict", "correct", "voxel_groups",
           "correlation", "STAT_COLUMNS", "VOXEL_DEFINITION"]

log = logging.getLogger(__name__)

ModelMode = Literal["auto", "map", "median", "field"]

#: per-input statistics, in the order of stats.csv (percent unless n_* or ks_*)
STAT_COLUMNS = ("mean", "median", "std", "peak", "pareto_median", "pareto_median_err",
                "pareto_median_hist", "peak_bin_width", "n_voxels", "n_masked",
                "median_err", "mean_err", "pareto_median_err_iid", "ks_d", "ks_p",
                "ks_p_eff", "n_eff", "n_groups")

#: what a voxel of the statistics is (attribute ``P_P_voxels`` of the result)
VOXEL_DEFINITION = ("full uv plane: each cell (u, tau) of power3d gives two voxels, "
                    "P_I(u,tau)/|P~(u,tau)|^2 and P_I(u,tau)/|P~(-u,-tau)|^2 "
                    "(power3d_P_mirror); bootstrap groups keep both")

#: statistics in percent (units attribute)
_PERCENT = ("mean", "median", "std", "peak", "pareto_median", "pareto_median_err",
            "pareto_median_hist", "peak_bin_width", "median_err", "mean_err",
            "pareto_median_err_iid")

_MASK_DOC = ", ".join(f"{c}={n}" for n, c in MASK_CODES.items())


def analyse(datasets: Sequence[xr.Dataset], labels: Sequence[str], paths: Sequence[str],
            *, stats_from: Literal["voxels", "bins"] = "voxels",
            negative: NegativePolicy = "mask", bins: int = 100, upper_quantile: float = 0.99,
            k_par_range: tuple[float, float] | None = None,
            k_perp_range: tuple[float, float] | None = None,
            field_name: str = "", n_boot: int = 200, bootstrap_block: int = 2,
            seed: int = 0, realisations: Sequence[int] | None = None) -> xr.Dataset:
    """L_I maps, voxel statistics and Pareto fits of several PS products.

    Parameters
    ----------
    datasets : sequence of xarray.Dataset
        PS products (docs/products.md "ps"), one per input (e.g. field of view).
    labels, paths : sequence of str
        A short label (e.g. ``15deg``) and the file name of each input.
    stats_from : {"voxels", "bins"}
        Statistics from the unaveraged 3D voxels (``power3d``, default) or the 2D bins.
    negative : {"mask", "clip"}
        Treatment of negative P_I (cross-power), see :mod:`msleak.leakage.fraction`.
    bins, upper_quantile :
        Histogram binning of L_I for the peak: ``bins`` uniform bins on [0, quantile].
    k_par_range, k_perp_range : (float, float), optional
        Restrict the statistics (not the maps) to |k_par| and k_perp in these ranges, Mpc^-1.
    n_boot, bootstrap_block, seed : int
        Block bootstrap of the errors: ``n_boot`` resamples (0: none) of uv cells with all
        their delays, in blocks of ``bootstrap_block`` x ``bootstrap_block`` neighbouring
        cells (with ``stats_from="bins"``: of k_perp columns), seeded by ``seed``.
    realisations : sequence of int, optional
        The sky realisation (e.g. its seed) of each input; the per-field estimate is the
        mean over realisations of each realisation's mean over its inputs, with the
        scatter over realisations (:func:`realisation_estimates`). Default: all one.

    Returns
    -------
    xarray.Dataset
        Dims (input, k_par, k_perp) for the maps, (input,) for statistics,
        (input, hist_bin) and (input, hist_edge) for the histograms.
    """
    if not datasets:
        raise InputError("no PS product given")
    realisations = [0] * len(datasets) if realisations is None else list(realisations)
    if len(realisations) != len(datasets):
        raise InputError(f"{len(realisations)} realisations for {len(datasets)} inputs")
    maps, rows, hists, edges, masked = [], [], [], [], []
    for ds, label, path in zip(datasets, labels, paths):
        name = str(path)
        m = leakage_map(ds, negative, name)
        n_bad = int((m["mask"] != 0).sum())
        if n_bad:
            log.info("%s: %d of %d (k_par, k_perp) bins masked", name, n_bad, m["mask"].size)
        maps.append(m)
        vox = leakage_voxels(ds, stats_from, negative, k_par_range, k_perp_range, name)
        if vox.n_masked:
            log.warning("%s: masked %d of %d %s (%s)", name, vox.n_masked, vox.n_selected,
                        vox.source, ", ".join(f"{k}: {v}" for k, v in vox.masked.items()))
        if vox.L.size < 2:
            raise InputError(f"{name}: only {vox.L.size} valid {vox.source} (of "
                             f"{vox.n_selected}); P_P is zero or negative almost everywhere")
        groups = voxel_groups(ds, stats_from, negative, k_par_range, k_perp_range,
                              bootstrap_block, name)
        if groups.size != vox.L.size:  # pragma: no cover - guards the selection logic
            raise RuntimeError(f"{name}: {groups.size} group labels for {vox.L.size} voxels")
        n_grp = np.unique(groups).size
        if n_boot > 0 and n_grp < 20:
            log.warning("%s: only %d independent groups of voxels for the bootstrap; its "
                        "errors are uncertain (use a smaller bootstrap block?)", name, n_grp)
        st = leakage_statistics(vox.L, bins, upper_quantile, groups=groups, n_boot=n_boot,
                                seed=seed)
        boot = st.boot
        rows.append({
            "mean": st.mean, "median": st.median, "std": st.std, "peak": st.peak,
            "pareto_median": st.pareto_median, "pareto_median_err": st.pareto_median_err,
            "pareto_median_hist": st.fit_hist.median_percent if st.fit_hist else 0.0,
            "peak_bin_width": st.peak_bin_width, "n_voxels": st.n, "n_masked": vox.n_masked,
            "median_err": st.median_err, "mean_err": st.mean_err,
            "pareto_median_err_iid": st.fit.median_err_percent,
            "ks_d": st.ks_d, "ks_p": st.ks_p, "ks_p_eff": st.ks_p_eff,
            "n_eff": st.n_eff, "n_groups": boot.n_groups if boot else 0,
            "pareto_loc": st.fit.loc, "pareto_scale": st.fit.scale,
            "fit_method": st.fit.method,
            "wedge_slope_horizon": float(ds.attrs.get("wedge_slope_horizon", 0.0) or 0.0),
            "wedge_slope_primary": float(ds.attrs.get("wedge_slope_primary", 0.0) or 0.0),
        })
        hists.append(st.hist_counts)
        edges.append(st.hist_edges)
        masked.append([vox.masked.get(n, 0) for n in MASK_CODES if n != "valid"])
        log.info("%s (%s): median L_I %.4g +- %.2g %% (data), %.4g +- %.2g %% (Pareto fit; "
                 "iid %.2g), %d %s worth %.0f independent, KS D %.3g", name, label,
                 st.median, st.median_err, st.pareto_median, st.pareto_median_err,
                 st.fit.median_err_percent, st.n, vox.source, st.n_eff, st.ks_d)

    fill = {"L_I": 0.0, "mask": MASK_CODES["not_in_grid"], "power_I": 0.0, "power_P": 0.0}
    grid = xr.concat(maps, dim="input", join="outer", fill_value=fill)
    grid["mask"] = grid["mask"].astype(np.int8)
    grid["mask"].attrs["long_name"] = f"mask reason code ({_MASK_DOC})"
    if any(m["k_par"].size != grid["k_par"].size or m["k_perp"].size != grid["k_perp"].size
           for m in maps):
        log.warning("the inputs have different k grids; maps are on the union grid and "
                    "bins outside an input's grid are masked (code %d)",
                    MASK_CODES["not_in_grid"])
    n_in = len(datasets)
    out = grid.assign_coords(input=np.arange(n_in), label=("input", list(labels)),
                             path=("input", [str(p) for p in paths]),
                             realisation=("input", np.asarray(realisations, np.int64)))
    for col in rows[0]:
        values = [r[col] for r in rows]
        out[col] = ("input", np.asarray(values))
    for c in _PERCENT:
        out[c].attrs["units"] = "percent"
    out["pareto_median_err"].attrs["long_name"] = (
        "block-bootstrap standard error of pareto_median" if n_boot > 0 else
        "asymptotic standard error of pareto_median (independent voxels)")
    out["pareto_median_err_iid"].attrs["long_name"] = (
        "asymptotic standard error of pareto_median for independent voxels, "
        "(A/2) sqrt(3/n)")
    out["n_eff"].attrs["long_name"] = ("effective number of independent voxels, "
                                       "n (pareto_median_err_iid / pareto_median_err)^2")
    out["ks_p"].attrs["long_name"] = "KS p-value of ks_d for n_voxels independent voxels"
    out["ks_p_eff"].attrs["long_name"] = "KS p-value of ks_d for n_eff voxels"
    out["k_par"].attrs["units"] = "Mpc^-1"
    out["k_perp"].attrs["units"] = "Mpc^-1"
    nb = max(len(h) for h in hists)
    out["hist_counts"] = (("input", "hist_bin"), np.array([np.pad(h, (0, nb - len(h)))
                                                            for h in hists]))
    out["hist_edges"] = (("input", "hist_edge"), np.array(
        [np.pad(e, (0, nb + 1 - len(e)), mode="edge") for e in edges]),
        {"units": "percent"})
    reasons = [n for n in MASK_CODES if n != "valid"]
    out["n_masked_by_reason"] = (("input", "mask_reason"), np.array(masked, dtype=np.int64))
    out = out.assign_coords(mask_reason=reasons)
    out = out.merge(realisation_estimates(out))
    est, spread = field_estimate(out["realisation_estimate"].values)
    est_data, spread_data = field_estimate(out["realisation_estimate_data"].values)
    out.attrs.update({
        "field_name": field_name,
        "field_estimate": est, "field_estimate_data": est_data,
        "n_realisations": int(out.sizes["realisation_id"]),
        "field_estimate_realisation_std": spread,
        "field_estimate_data_realisation_std": spread_data,
        "field_estimate_spread": _fov_spread(out, "pareto_median"),
        "field_estimate_data_spread": _fov_spread(out, "median"),
        "L_I_definition": "L_I = 100 sqrt(P_I / P_P) percent, P_P = power of Q + iU",
        "P_P_voxels": (VOXEL_DEFINITION if stats_from == "voxels" else
                       "2D bins: P_P = bin mean over both voxels (u,tau), (-u,-tau) of "
                       "every cell and delay (= P_Q + P_U)"),
        "stats_from": stats_from, "negative_policy": negative,
        "hist_bins": int(bins), "hist_upper_quantile": float(upper_quantile),
        "hist_binning": f"{bins} uniform bins of L_I from 0 to its {upper_quantile:g} quantile",
        "fit": "Pareto b=1 (scipy.stats.pareto) on W=(L_I/100)^2, loc and scale by maximum "
               "likelihood; pareto_median = 100 sqrt(loc + 2 scale)",
        "errors": (f"block bootstrap, {n_boot} resamples of "
                   + (f"{bootstrap_block}x{bootstrap_block} blocks of uv cells with all "
                      "their delays" if stats_from == "voxels" else "k_perp columns")
                   + f", seed {seed}" if n_boot > 0 else
                   "asymptotic, independent voxels (no bootstrap)"),
        "n_boot": int(n_boot), "bootstrap_block": int(bootstrap_block),
        "bootstrap_seed": int(seed),
        "k_par_range": list(k_par_range) if k_par_range else [],
        "k_perp_range": list(k_perp_range) if k_perp_range else [],
        "mask_codes": _MASK_DOC,
        "units": str(datasets[0]["power"].attrs.get("units",
                                                    datasets[0].attrs.get("units", ""))),
    })
    return out


def realisation_estimates(result: xr.Dataset) -> xr.Dataset:
    """Per-field estimate of each sky realisation: the mean over its inputs (fields of
    view) of the Pareto and of the data medians, with the mean of their bootstrap errors
    as the error (the fields of view of one sky are nested, so their errors are taken as
    fully correlated). Dim ``realisation_id``, coordinate values the realisations."""
    ids = np.unique(result["realisation"].values)
    cols = {"realisation_estimate": "pareto_median",
            "realisation_estimate_err": "pareto_median_err",
            "realisation_estimate_data": "median", "realisation_estimate_data_err": "median_err"}
    data = {}
    for name, col in cols.items():
        values = result[col].values
        data[name] = ("realisation_id", np.array(
            [values[result["realisation"].values == r].mean() for r in ids]),
            {"units": "percent", "long_name": f"mean of {col} over the realisation's inputs"})
    return xr.Dataset(data, coords={"realisation_id": ids})


def _fov_spread(result: xr.Dataset, col: str) -> float:
    """Standard deviation of ``col`` over each realisation's inputs, averaged."""
    return float(np.mean([field_estimate(result[col].values[result["realisation"].values == r])[1]
                          for r in result["realisation_id"].values]))


def voxel_groups(ds: xr.Dataset, source: str = "voxels", negative: NegativePolicy = "mask",
                 k_par_range: tuple[float, float] | None = None,
                 k_perp_range: tuple[float, float] | None = None, block: int = 1,
                 name: str = "PS product") -> np.ndarray:
    """Bootstrap group of every voxel that :func:`leakage_voxels` returns, same order.

    ``voxels``: the uv cell of the voxel (all its delays, and the mirrored voxels
    (-u, -tau) of them, together) or, with ``block`` > 1, its block of ``block`` x
    ``block`` neighbouring cells (from ``u_cell``, ``v_cell`` and the ``cell_lambda``
    attribute, or the smallest spacing of the cell coordinates). A voxel and its mirror
    always share a group: they share P_I, and their P~ are made of the same Q~ and U~.
    ``bins``: the k_perp column of the 2D bin.
    """
    if source == "voxels":
        p_i, p_p = voxel_power(ds, name)
        _, mask = leakage_fraction(p_i, p_p, None, negative)
        kpar = np.abs(np.asarray(ds["k_par3d"].values, float))[None, :, None]
        kperp = np.asarray(ds["k_perp_cell"].values, float)[None, None, :]
        ncell = p_i.shape[-1]
        label = np.arange(ncell)
        if block > 1:
            if "u_cell" not in ds.variables or "v_cell" not in ds.variables:
                raise InputError(f"{name}: bootstrap blocks of uv cells need u_cell, v_cell")
            u, v = ds["u_cell"].values, ds["v_cell"].values
            cell = float(ds.attrs.get("cell_lambda", 0) or 0) or _spacing(u, v)
            if _on_grid(u, v, cell):
                label = cell_groups(u, v, cell, block)
            else:
                log.warning("%s: the uv cells are not on a grid of %g wavelengths; the "
                            "bootstrap resamples single cells", name, cell)
        label = np.broadcast_to(label[None, None, :], mask.shape)
    else:
        m = leakage_map(ds, negative, name)
        mask = m["mask"].values
        kpar = m["k_par"].values[:, None]
        kperp = m["k_perp"].values[None, :]
        label = np.broadcast_to(np.arange(mask.shape[1])[None, :], mask.shape)
    sel = np.ones(mask.shape, dtype=bool)
    for x, rng in ((kpar, k_par_range), (kperp, k_perp_range)):
        if rng is not None:
            sel = sel & ((x >= rng[0]) & (x <= rng[1]))
    return label[sel & (mask == 0)]


def _on_grid(u: np.ndarray, v: np.ndarray, cell: float) -> bool:
    """True if the cell coordinates are whole multiples of ``cell`` (to 1e-3 cell)."""
    return bool(all(np.allclose(c / cell, np.rint(c / cell), rtol=0, atol=1e-3)
                    for c in (np.asarray(u, float), np.asarray(v, float))))


def _spacing(u: np.ndarray, v: np.ndarray) -> float:
    """Smallest positive spacing of the distinct cell coordinates (the cell size)."""
    steps = [np.diff(np.unique(np.round(np.asarray(c, float), 9))) for c in (u, v)]
    steps = np.concatenate(steps)
    steps = steps[steps > 0]
    return float(steps.min()) if steps.size else 1.0


def _pair(i_obs: int, n_obs: int, n_in: int) -> int | None:
    if n_in == 1:
        return 0
    return i_obs if n_obs == n_in else None


def predict(result: xr.Dataset, obs: xr.Dataset, i_obs: int, n_obs: int,
            mode: ModelMode = "auto", rel_error: float | None = None,
            name: str = "observed PS") -> xr.Dataset:
    """Expected leakage PS of one observed PS product: (L_I_model / 100)^2 P_P,obs.

    Parameters
    ----------
    result : xarray.Dataset
        Output of :func:`analyse` (the model).
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
    """
    n_in = result.sizes["input"]
    j = _pair(i_obs, n_obs, n_in)
    p_p = stokes_power(obs, "power", "P", name).transpose("k_par", "k_perp")
    k_par, k_perp = obs["k_par"].values, obs["k_perp"].values
    if "counts" in obs.variables:
        counts = obs["counts"].transpose("k_par", "k_perp").values.astype(float)
    else:
        log.warning("%s: no 'counts'; sample-variance errors assume 1 cell per bin", name)
        counts = np.ones(p_p.shape)
    counts = np.where(np.isfinite(p_p.values), counts, 0.0)
    p_p_val = np.where(counts > 0, np.real(p_p.values), 0.0)
    grid_ok = False
    if j is not None:
        model = _own_grid(result.isel(input=j))
        grid_ok = ex.same_grid(model["k_par"].values, model["k_perp"].values, k_par, k_perp)
    if mode == "auto":
        mode = "map" if grid_ok else ("median" if j is not None else "field")
    if mode in ("map", "median") and j is None:
        raise InputError(f"--expected-model {mode} pairs observed PS i with model input i: "
                         f"give {n_in} observed PS (got {n_obs}) or use --expected-model field")
    if mode == "map" and not grid_ok:
        raise InputError(f"{name}: its (k_par, k_perp) grid differs from the model input "
                         f"{result['label'].values[j]!r}; use --expected-model median or field")
    filled = np.zeros(p_p.shape, dtype=np.int8)
    if mode == "field":
        L_scalar = float(result.attrs["field_estimate"])
        stat = float(np.sqrt(np.mean(result["pareto_median_err"].values ** 2)))
        default_rel = _ratio(ex.leakage_model_error(stat, result["pareto_median"].values),
                             L_scalar)
        L_model = np.full(p_p.shape, L_scalar)
        model_label = f"field estimate of {','.join(map(str, result['label'].values))}"
    else:
        L_scalar = float(result["pareto_median"].values[j])
        default_rel = _ratio(float(result["pareto_median_err"].values[j]), L_scalar)
        model_label = str(result["label"].values[j])
        if mode == "median":
            L_model = np.full(p_p.shape, L_scalar)
        else:
            mask = model["mask"].values
            L_model = np.where(mask == 0, model["L_I"].values, L_scalar)
            filled = (mask != 0).astype(np.int8)
            if filled.any():
                log.info("%s: %d masked model bins use the median L_I %.4g %%", name,
                         int(filled.sum()), L_scalar)
    rel = default_rel if rel_error is None else float(rel_error)
    L_err = rel * L_model
    corr = correlation(obs, "P", name)
    counts_eff = counts / np.where(k_par[:, None] > 0, corr["c_2d"], corr["c_2d_zero"])
    leak = ex.expected_leakage_power(p_p_val, L_model)
    leak_err = ex.expected_leakage_error(p_p_val, counts_eff, L_model, L_err)
    units = str(obs["power"].attrs.get("units", obs.attrs.get("units", "")))
    dims = ("k_par", "k_perp")
    out = xr.Dataset(
        {
            "power_P_obs": (dims, p_p_val, {"units": units}),
            "counts": (dims, counts),
            "counts_eff": (dims, counts_eff, {"long_name": "effective number of independent "
                                              "cells, counts / corr_factor_2d"}),
            "L_I_model": (dims, L_model, {"units": "percent"}),
            "L_I_model_err": (dims, L_err, {"units": "percent"}),
            "L_I_model_filled": (dims, filled),
            "power_leak": (dims, leak, {"units": units,
                                        "long_name": "(L_I_model/100)^2 P_P,obs"}),
            "power_leak_err": (dims, leak_err, {"units": units}),
        },
        coords={"k_par": ("k_par", k_par, {"units": "Mpc^-1"}),
                "k_perp": ("k_perp", k_perp, {"units": "Mpc^-1"})},
    )
    k, k_edges = _k_bins(obs, k_par, k_perp)
    if mode != "map" and "power_sph" in obs.variables:
        # a scalar model scales the observed spherical average exactly
        pp_sph = np.real(stokes_power(obs, "power_sph", "P", name).values)
        c_sph = (obs["counts_sph"].values.astype(float) if "counts_sph" in obs.variables
                 else np.ones(k.size))
        c_sph = np.where(np.isfinite(pp_sph), c_sph, 0.0)
        pp_sph = np.where(c_sph > 0, pp_sph, 0.0)
        sph_source = "power_sph"
    else:
        pp_sph, c_sph = ex.spherical_from_bins(p_p_val, counts, k_par, k_perp, k_edges)
        sph_source = "2D bins"
    if mode == "map":
        leak_sph, _ = ex.spherical_from_bins(leak, counts, k_par, k_perp, k_edges)
        Lsph = np.where(pp_sph > 0, 100 * np.sqrt(np.divide(
            leak_sph, pp_sph, out=np.zeros_like(pp_sph), where=pp_sph > 0)), L_scalar)
    else:
        leak_sph = ex.expected_leakage_power(pp_sph, L_scalar)
        Lsph = np.full(k.size, L_scalar)
    out = out.assign_coords(k=("k", k, {"units": "Mpc^-1"}))
    out["power_P_obs_sph"] = ("k", pp_sph, {"units": units})
    out["counts_sph"] = ("k", c_sph)
    out["counts_sph_eff"] = ("k", c_sph / corr["c_sph"])
    out["power_leak_sph"] = ("k", leak_sph, {"units": units})
    out["power_leak_sph_err"] = ("k", ex.expected_leakage_error(
        pp_sph, c_sph / corr["c_sph"], Lsph, rel * Lsph), {"units": units})
    out.attrs.update({
        "source": name, "model_mode": mode, "model_input": model_label,
        "L_I_model_scalar": L_scalar, "L_I_model_rel_error": rel,
        "spherical_from": sph_source, "units": units,
        "formula": "P_leak = (L_I_model/100)^2 P_P,obs; sigma_leak^2 = (l^2 |P_P|/sqrt(N))^2 "
                   "+ (2 l sigma_l P_P)^2, l = L_I_model/100, N = counts / corr_factor",
        "corr_factor_2d": corr["c_2d"], "corr_factor_2d_kpar0": corr["c_2d_zero"],
        "corr_factor_sph": corr["c_sph"], "corr_method": corr["method"],
    })
    for key in ("wedge_slope_horizon", "wedge_slope_primary", "cosmology", "redshift"):
        if key in obs.attrs:
            out.attrs[key] = obs.attrs[key]
    return out


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
    need = ("power3d", "k_par3d", "k_perp_cell", "u_cell", "v_cell", "k_perp_lo", "k_perp_hi")
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
            edges = np.concatenate([ds["k_perp_lo"].values[:1], ds["k_perp_hi"].values])
            iperp = np.clip(np.digitize(ds["k_perp_cell"].values, edges) - 1, 0,
                            edges.size - 2)
            bins = ipar[:, None] * (edges.size + 1) + iperp[None, :]
            order = np.argsort(np.asarray(ds["delay3d"].values, float))
            dk = np.empty(order.size, dtype=np.int64)
            dk[order] = np.arange(order.size) - int(np.argmin(np.abs(
                np.asarray(ds["delay3d"].values, float)[order])))
            u, v = ds["u_cell"].values, ds["v_cell"].values
            cell = float(ds.attrs.get("cell_lambda", 0) or 0) or _spacing(u, v)
            iu, iv = np.rint(u / cell), np.rint(v / cell)
            if not _on_grid(u, v, cell):
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
            from msleak.ps.delay import spectral_window

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
    """Spherical k bin centres and edges: the product's ``k`` (edges from ``k_lo``/``k_hi``
    or midpoints), or, without ``k``, 20 log bins over the 2D grid."""
    if "k" in obs.coords or "k" in obs.variables:
        k = np.asarray(obs["k"].values, dtype=float)
        if "k_lo" in obs.variables and "k_hi" in obs.variables:
            edges = np.concatenate([obs["k_lo"].values[:1], obs["k_hi"].values]).astype(float)
        else:
            edges = ex.edges_from_centres(k)
        return k, edges
    kk = np.hypot(np.asarray(k_par)[:, None], np.asarray(k_perp)[None, :])
    lo = max(kk[kk > 0].min(), 1e-6) if np.any(kk > 0) else 1e-3
    edges = np.geomspace(lo, kk.max() * 1.0001, 21)
    return np.sqrt(edges[1:] * edges[:-1]), edges


def correct(obs_i: xr.Dataset, expected: xr.Dataset, name: str = "observed PS"
            ) -> xr.Dataset:
    """Subtract the expected leakage from the observed Stokes I PS (bias correction).

    Parameters
    ----------
    obs_i : xarray.Dataset
        Observed PS product with Stokes I in ``power`` on the grid of ``expected``.
    expected : xarray.Dataset
        Output of :func:`predict`.

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
    corr, err = ex.bias_correct(p_i_val, counts_eff, expected["power_leak"].values,
                                expected["power_leak_err"].values)
    out = expected.copy()
    units = expected.attrs.get("units", "")
    dims = ("k_par", "k_perp")
    out["power_I_obs"] = (dims, p_i_val, {"units": units})
    out["power_I_corrected"] = (dims, corr, {"units": units,
                                             "long_name": "P_I,obs - P_leak"})
    out["power_I_corrected_err"] = (dims, err, {"units": units})
    k_edges = ex.edges_from_centres(expected["k"].values)
    if "k_lo" in obs_i.variables and "k_hi" in obs_i.variables:
        k_edges = np.concatenate([obs_i["k_lo"].values[:1], obs_i["k_hi"].values])
    if expected.attrs.get("spherical_from") == "power_sph" and "power_sph" in obs_i.variables:
        pi_sph = np.real(stokes_power(obs_i, "power_sph", "I", name).values)
        pi_sph = np.where(np.isfinite(pi_sph), pi_sph, 0.0)
        c_sph = expected["counts_sph"].values
    else:
        pi_sph, c_sph = ex.spherical_from_bins(p_i_val, counts, expected["k_par"].values,
                                               expected["k_perp"].values, k_edges)
    corr_sph, err_sph = ex.bias_correct(pi_sph, c_sph / cf["c_sph"],
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
