"""The leakage of PS products as xarray Datasets (docs/leakage.md): :func:`analyse` (L_I
maps, voxel statistics, Pareto fits, per-field estimate), the bootstrap groups of the
voxels (:func:`voxel_groups`) and the per-realisation estimates."""

from __future__ import annotations

import logging
from typing import Sequence

import numpy as np
import xarray as xr

from msleak.errors import InputError
from msleak.leakage.bootstrap import cell_groups, on_uv_grid, uv_cell_size
from msleak.leakage.fraction import (
    MASK_CODES,
    NegativePolicy,
    StatsFrom,
    leakage_fraction,
    leakage_map,
    leakage_voxels,
    voxel_power,
)
from msleak.leakage.stats import (LeakageStatistics, field_estimate, leakage_statistics,
                                  view_histogram)

__all__ = ["analyse", "realisation_estimates", "voxel_groups", "STAT_COLUMNS",
           "VOXEL_DEFINITION", "HIST_VIEW_QUANTILE"]

log = logging.getLogger(__name__)

#: per-input statistics, in the order of stats.csv (percent unless n_* or ks_*)
STAT_COLUMNS = ("mean", "median", "std", "peak", "pareto_median", "pareto_median_err",
                "pareto_median_hist", "peak_bin_width", "n_voxels", "n_masked",
                "median_err", "mean_err", "pareto_median_err_iid", "ks_d", "ks_p",
                "ks_p_eff", "n_eff", "n_groups")

#: what a voxel of the statistics is (attribute ``P_P_voxels`` of the result)
VOXEL_DEFINITION = ("full uv plane: each cell (u, tau) of power3d gives two voxels, "
                    "P_I(u,tau)/|P~(u,tau)|^2 and P_I(u,tau)/|P~(-u,-tau)|^2 "
                    "(power3d_P_mirror); bootstrap groups keep both")

#: the histogram figure shows L_I from 0 to this quantile (the Pareto tail of L_I is long:
#: its 0.99 quantile is many times the median, docs/leakage.md); the statistics use every voxel
HIST_VIEW_QUANTILE = 0.95

#: statistics in percent (units attribute)
_PERCENT = ("mean", "median", "std", "peak", "pareto_median", "pareto_median_err",
            "pareto_median_hist", "peak_bin_width", "median_err", "mean_err",
            "pareto_median_err_iid")

#: dimensionless statistics (units "1", the CF convention): counts, ratios, KS results
_DIMENSIONLESS = ("n_voxels", "n_masked", "ks_d", "ks_p", "ks_p_eff", "n_eff", "n_groups",
                  "pareto_loc", "pareto_scale", "wedge_slope_horizon", "wedge_slope_primary",
                  "hist_counts", "n_masked_by_reason", "hist_view_counts",
                  "n_beyond_hist_view")

_MASK_DOC = ", ".join(f"{c}={n}" for n, c in MASK_CODES.items())


def analyse(datasets: Sequence[xr.Dataset], labels: Sequence[str], paths: Sequence[str],
            *, stats_from: StatsFrom = "voxels",
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
    options = dict(stats_from=stats_from, negative=negative, bins=bins,
                   upper_quantile=upper_quantile, k_par_range=k_par_range,
                   k_perp_range=k_perp_range, n_boot=n_boot,
                   bootstrap_block=bootstrap_block, seed=seed)
    per_input = [_input_statistics(ds, label, str(path), **options)
                 for ds, label, path in zip(datasets, labels, paths)]
    out = _stack(datasets, [p[0] for p in per_input], labels, paths, realisations)
    for col in per_input[0][1]:
        out[col] = ("input", np.asarray([p[1][col] for p in per_input]))
    _statistics_attrs(out, n_boot)
    stats = [p[2] for p in per_input]
    nb = max(st.hist_counts.size for st in stats)
    out["hist_counts"] = (("input", "hist_bin"), np.array(
        [np.pad(st.hist_counts, (0, nb - st.hist_counts.size)) for st in stats]))
    out["hist_edges"] = (("input", "hist_edge"), np.array(
        [np.pad(st.hist_edges, (0, nb + 1 - st.hist_edges.size), mode="edge")
         for st in stats]), {"units": "percent"})
    views = [p[4] for p in per_input]
    out["hist_view_counts"] = (("input", "hist_view_bin"), np.array([v[0] for v in views]))
    out["hist_view_edges"] = (("input", "hist_view_edge"), np.array([v[1] for v in views]),
                              {"units": "percent"})
    out["n_beyond_hist_view"] = (("input",), np.array([v[2] for v in views], np.int64),
                                 {"long_name": "voxels above the last hist_view_edges"})
    out["n_masked_by_reason"] = (("input", "mask_reason"),
                                 np.array([p[3] for p in per_input], dtype=np.int64))
    out = out.assign_coords(mask_reason=[n for n in MASK_CODES if n != "valid"])
    for c in _DIMENSIONLESS:
        out[c].attrs["units"] = "1"
    out = out.merge(realisation_estimates(out))
    out.attrs.update(_result_attrs(out, datasets[0], field_name, options))
    return out


def _input_statistics(ds: xr.Dataset, label: str, name: str, *, stats_from, negative,
                      bins, upper_quantile, k_par_range, k_perp_range, n_boot,
                      bootstrap_block, seed
                      ) -> tuple[xr.Dataset, dict, LeakageStatistics, list[int], tuple]:
    """One input's L_I map, its row of statistics, the statistics, masked counts, and the
    histogram the figure shows (:func:`~msleak.leakage.stats.view_histogram`)."""
    m = leakage_map(ds, negative, name)
    n_bad = int((m["mask"] != 0).sum())
    if n_bad:
        log.info("%s: %d of %d (k_par, k_perp) bins masked", name, n_bad, m["mask"].size)
    vox = leakage_voxels(ds, stats_from, negative, k_par_range, k_perp_range, name)
    if vox.n_masked:
        log.warning("%s: masked %d of %d %s (%s)", name, vox.n_masked, vox.n_selected,
                    vox.source, ", ".join(f"{k}: {v}" for k, v in vox.masked.items()))
    if vox.L.size < 2:
        raise InputError(f"{name}: only {vox.L.size} valid {vox.source} (of "
                         f"{vox.n_selected}); P_P is zero or negative almost everywhere")
    groups = voxel_groups(ds, stats_from, negative, k_par_range, k_perp_range,
                          bootstrap_block, name)
    n_grp = np.unique(groups).size
    if n_boot > 0 and n_grp < 20:
        log.warning("%s: only %d independent groups of voxels for the bootstrap; its "
                    "errors are uncertain (use a smaller bootstrap block?)", name, n_grp)
    st = leakage_statistics(vox.L, bins, upper_quantile, groups=groups, n_boot=n_boot,
                            seed=seed)
    row = {
        "mean": st.mean, "median": st.median, "std": st.std, "peak": st.peak,
        "pareto_median": st.pareto_median, "pareto_median_err": st.pareto_median_err,
        "pareto_median_hist": st.fit_hist.median_percent if st.fit_hist else 0.0,
        "peak_bin_width": st.peak_bin_width, "n_voxels": st.n, "n_masked": vox.n_masked,
        "median_err": st.median_err, "mean_err": st.mean_err,
        "pareto_median_err_iid": st.fit.median_err_percent,
        "ks_d": st.ks_d, "ks_p": st.ks_p, "ks_p_eff": st.ks_p_eff,
        "n_eff": st.n_eff, "n_groups": st.boot.n_groups if st.boot else 0,
        "pareto_loc": st.fit.loc, "pareto_scale": st.fit.scale, "fit_method": st.fit.method,
        "wedge_slope_horizon": float(ds.attrs.get("wedge_slope_horizon", 0.0) or 0.0),
        "wedge_slope_primary": float(ds.attrs.get("wedge_slope_primary", 0.0) or 0.0),
    }
    log.info("%s (%s): median L_I %.4g +- %.2g %% (data), %.4g +- %.2g %% (Pareto fit; "
             "iid %.2g), %d %s worth %.0f independent, KS D %.3g", name, label,
             st.median, st.median_err, st.pareto_median, st.pareto_median_err,
             st.fit.median_err_percent, st.n, vox.source, st.n_eff, st.ks_d)
    return (m, row, st, [vox.masked.get(n, 0) for n in MASK_CODES if n != "valid"],
            view_histogram(vox.L, bins, HIST_VIEW_QUANTILE))


def _stack(datasets: Sequence[xr.Dataset], maps: list[xr.Dataset], labels, paths,
           realisations) -> xr.Dataset:
    """The inputs' maps on the union k grid, with the coordinates of the ``input`` dim:
    label, path, realisation, and the product's ``source``, ``column``, ``fov_deg`` and
    ``cell_lambda``."""
    fill = {"L_I": 0.0, "mask": MASK_CODES["not_in_grid"], "power_I": 0.0, "power_P": 0.0}
    grid = xr.concat(maps, dim="input", join="outer", fill_value=fill)
    grid["mask"] = grid["mask"].astype(np.int8)
    grid["mask"].attrs.update(long_name=f"mask reason code ({_MASK_DOC})",
                              flag_values=np.array(list(MASK_CODES.values()), np.int8),
                              flag_meanings=" ".join(MASK_CODES))
    if any(m["k_par"].size != grid["k_par"].size or m["k_perp"].size != grid["k_perp"].size
           for m in maps):
        log.warning("the inputs have different k grids; maps are on the union grid and "
                    "bins outside an input's grid are masked (code %d)",
                    MASK_CODES["not_in_grid"])
    out = grid.assign_coords(
        input=np.arange(len(maps)), label=("input", list(labels)),
        path=("input", [str(p) for p in paths]),
        realisation=("input", np.asarray(realisations, np.int64)),
        source=("input", [str(ds.attrs.get("source", "")) for ds in datasets]),
        column=("input", [str(ds.attrs.get("column", "")) for ds in datasets]),
        fov_deg=("input", [float(ds.attrs.get("fov_deg", 0.0) or 0.0) for ds in datasets],
                 {"units": "deg", "long_name": "full width at half power of the gridder's "
                  "sky response (0: unknown)"}),
        cell_lambda=("input", [float(ds.attrs.get("cell_lambda", 0.0) or 0.0)
                               for ds in datasets],
                     {"units": "wavelengths", "long_name": "uv cell size (0: unknown)"}))
    out["k_par"].attrs["units"] = "Mpc^-1"
    out["k_perp"].attrs["units"] = "Mpc^-1"
    return out


def _statistics_attrs(out: xr.Dataset, n_boot: int) -> None:
    """Units and long names of the per-input statistics."""
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


def _result_attrs(out: xr.Dataset, first: xr.Dataset, field_name: str, o: dict) -> dict:
    """The global attributes of the leakage result (docs/leakage.md "Outputs")."""
    est, spread = field_estimate(out["realisation_estimate"].values)
    est_data, spread_data = field_estimate(out["realisation_estimate_data"].values)
    block, n_boot = o["bootstrap_block"], o["n_boot"]
    return {
        "field_name": field_name,
        "field_estimate": est, "field_estimate_data": est_data,
        "n_realisations": int(out.sizes["realisation_id"]),
        "field_estimate_realisation_std": spread,
        "field_estimate_data_realisation_std": spread_data,
        "field_estimate_spread": _fov_spread(out, "pareto_median"),
        "field_estimate_data_spread": _fov_spread(out, "median"),
        "L_I_definition": "L_I = 100 sqrt(P_I / P_P) percent, P_P = power of Q + iU",
        "P_P_voxels": (VOXEL_DEFINITION if o["stats_from"] == "voxels" else
                       "2D bins: P_P = bin mean over both voxels (u,tau), (-u,-tau) of "
                       "every cell and delay (= P_Q + P_U)"),
        "stats_from": o["stats_from"], "negative_policy": o["negative"],
        "hist_bins": int(o["bins"]), "hist_upper_quantile": float(o["upper_quantile"]),
        "hist_binning": f"{o['bins']} uniform bins of L_I from 0 to its "
                        f"{o['upper_quantile']:g} quantile",
        "hist_view_quantile": HIST_VIEW_QUANTILE,
        "fit": "Pareto b=1 (scipy.stats.pareto) on W=(L_I/100)^2, loc and scale by maximum "
               "likelihood; pareto_median = 100 sqrt(loc + 2 scale)",
        "errors": (f"block bootstrap, {n_boot} resamples of "
                   + (f"{block}x{block} blocks of uv cells with all their delays"
                      if o["stats_from"] == "voxels" else "k_perp columns")
                   + f", seed {o['seed']}" if n_boot > 0 else
                   "asymptotic, independent voxels (no bootstrap)"),
        "n_boot": int(n_boot), "bootstrap_block": int(block), "bootstrap_seed": int(o["seed"]),
        "k_par_range": list(o["k_par_range"]) if o["k_par_range"] else [],
        "k_perp_range": list(o["k_perp_range"]) if o["k_perp_range"] else [],
        "mask_codes": _MASK_DOC,
        "units": str(first["power"].attrs.get("units", first.attrs.get("units", ""))),
    }


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
            cell = float(ds.attrs.get("cell_lambda", 0) or 0) or uv_cell_size(u, v)
            if on_uv_grid(u, v, cell):
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
