"""The files of the verb :func:`msleak.leakage` (docs/leakage.md "Outputs"): tables,
products and figures of a leakage result."""

from __future__ import annotations

import csv
import os
import re
from pathlib import Path
from typing import Sequence

import numpy as np
import xarray as xr

from msleak.errors import InputError
from msleak.io.products import history_lines, save_product
from msleak.leakage.analysis import STAT_COLUMNS
from msleak.leakage.compare import COMPARE_COLUMNS
from msleak.plot import leakage as plots

__all__ = ["OUTPUT_FILES", "write_leakage", "refuse_existing",
           "write_stats_csv", "write_estimates_csv", "write_stats_md", "estimate_summary",
           "default_labels"]

#: the files that make a directory hold leakage products
OUTPUT_FILES = ("leakage.h5", "stats.csv", "estimates.csv", "stats.md")


def default_labels(paths: Sequence[str | os.PathLike]) -> list[str]:
    """File stems, made unique by their position when two are equal."""
    stems = [Path(p).stem for p in paths]
    if len(set(stems)) == len(stems):
        return stems
    return [f"{s}_{i + 1}" for i, s in enumerate(stems)]


def _safe(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9._+-]+", "_", label).strip("_") or "input"


def write_stats_csv(result: xr.Dataset, path: str | os.PathLike) -> Path:
    """``stats.csv``: one row per input; L_I statistics in percent, counts as integers."""
    path = Path(path)
    cols = ("input", "label", *STAT_COLUMNS, "realisation")
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(cols)
        for i in range(result.sizes["input"]):
            row = [str(result["path"].values[i]), str(result["label"].values[i])]
            for c in STAT_COLUMNS:
                v = result[c].values[i]
                row.append(int(round(float(v))) if c.startswith("n_") else f"{float(v):.6g}")
            w.writerow(row + [int(result["realisation"].values[i])])
    return path


def write_estimates_csv(result: xr.Dataset, path: str | os.PathLike) -> Path:
    """``estimates.csv``: the per-field estimate of each sky realisation (mean over its
    inputs of the Pareto and data medians, with errors), then a row ``all``: the mean over
    realisations, the mean error within one, and the standard deviation over them."""
    path = Path(path)
    a = result.attrs
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["realisation", "estimate", "estimate_err", "estimate_data",
                    "estimate_data_err", "realisation_std", "realisation_std_data"])
        for k, r in enumerate(result["realisation_id"].values):
            w.writerow([int(r)] + [f"{float(result[c].values[k]):.6g}" for c in (
                "realisation_estimate", "realisation_estimate_err",
                "realisation_estimate_data", "realisation_estimate_data_err")] + ["", ""])
        w.writerow(["all", f"{a['field_estimate']:.6g}",
                    f"{float(result['realisation_estimate_err'].mean()):.6g}",
                    f"{a['field_estimate_data']:.6g}",
                    f"{float(result['realisation_estimate_data_err'].mean()):.6g}",
                    f"{a['field_estimate_realisation_std']:.6g}",
                    f"{a['field_estimate_data_realisation_std']:.6g}"])
    return path


def estimate_summary(result: xr.Dataset, bold: str = "") -> str:
    """The per-field estimate in one sentence (what ``msleak leakage`` prints); ``bold``
    marks the estimate (``**`` in stats.md)."""
    a = result.attrs
    if a["n_realisations"] == 1:
        return (f"Per-field estimate (mean of the Pareto medians over "
                f"{result.sizes['input']} input(s)): {bold}{a['field_estimate']:.4g} %{bold} "
                f"(spread {a['field_estimate_spread']:.2g} %); mean of the data medians: "
                f"{a['field_estimate_data']:.4g} % (spread "
                f"{a['field_estimate_data_spread']:.2g} %).")
    err = float(result["realisation_estimate_err"].mean())
    err_data = float(result["realisation_estimate_data_err"].mean())
    return (f"Per-field estimate over {a['n_realisations']} sky realisations (mean ± "
            f"standard deviation over realisations; bootstrap error within one realisation "
            f"in brackets), Pareto medians: {bold}{a['field_estimate']:.4g} ± "
            f"{a['field_estimate_realisation_std']:.2g} %{bold} ({err:.2g} %); data medians: "
            f"{a['field_estimate_data']:.4g} ± {a['field_estimate_data_realisation_std']:.2g} "
            f"% ({err_data:.2g} %).")


def _estimate_lines(result: xr.Dataset) -> list[str]:
    """The per-field estimate in Markdown: one realisation, or a table of realisations
    and their mean +- std."""
    if result.attrs["n_realisations"] == 1:
        return [estimate_summary(result, "**")]
    lines = ["| realisation | estimate, Pareto medians (%) | estimate, data medians (%) |",
             "|---|---:|---:|"]
    for k, r in enumerate(result["realisation_id"].values):
        lines.append(f"| {int(r)} | {float(result['realisation_estimate'].values[k]):.4g} ± "
                     f"{float(result['realisation_estimate_err'].values[k]):.2g} | "
                     f"{float(result['realisation_estimate_data'].values[k]):.4g} ± "
                     f"{float(result['realisation_estimate_data_err'].values[k]):.2g} |")
    return lines + ["", estimate_summary(result, "**")]


def write_stats_md(result: xr.Dataset, path: str | os.PathLike) -> Path:
    """``stats.md``: the statistics as a Markdown table, plus the per-field estimate."""
    a = result.attrs
    title = f"L_I statistics{(' of ' + a['field_name']) if a.get('field_name') else ''}"
    lines = [f"# {title}", "",
             "| input | mean (%) | median (%) | std (%) | peak (%) | Pareto median (%) "
             "| KS D (p for n_eff) | voxels (n_eff) | masked |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for i in range(result.sizes["input"]):
        def g(c, fmt=".4g"):
            return format(float(result[c].values[i]), fmt) if c in result else "-"
        lines.append(
            f"| {result['label'].values[i]} | {g('mean')} ± {g('mean_err', '.2g')} "
            f"| {g('median')} ± {g('median_err', '.2g')} | {g('std')} "
            f"| {g('peak')} | {g('pareto_median')} ± {g('pareto_median_err', '.2g')} "
            f"| {g('ks_d', '.3f')} ({g('ks_p_eff', '.2g')}) "
            f"| {int(result['n_voxels'].values[i])} ({g('n_eff', '.0f')}) "
            f"| {int(result['n_masked'].values[i])} |")
    unit = ("voxel of the unaveraged 3D power on the full uv plane (P = Q + iU is not "
            "Hermitian: each uv cell and delay (u, tau) gives two voxels, (u, tau) and "
            "(-u, -tau), each with its own P_P = |P~|^2 and the same P_I; the bootstrap "
            "draws both together)" if a["stats_from"] == "voxels"
            else "2D (k_par, k_perp) bin")
    lines += ["", *_estimate_lines(result), "",
        f"L_I = 100 sqrt(P_I / P_P) per {unit}{_range_text(a)}. "
        f"Peak = centre of the fullest bin of {a['hist_binning']} "
        "(bin widths in stats.csv, `peak_bin_width`). Pareto median = 100 sqrt(loc + 2 scale) "
        "of the maximum-likelihood fit of scipy.stats.pareto (b = 1) to W = (L_I/100)^2. "
        f"Errors (±): {a.get('errors', 'asymptotic')}; voxels are correlated, so these "
        "exceed the independent-voxel error (A/2) sqrt(3/n) (`pareto_median_err_iid` in "
        "stats.csv); n_eff = n (iid error / bootstrap error)^2 is the effective number of "
        "independent voxels. KS D = largest difference between the L_I distribution and "
        "the fitted model's CDF; its p-value is the one for n_eff voxels, not for all n "
        "(`ks_p_eff`; `ks_p` in stats.csv is for n, too small for correlated voxels), and "
        "approximate (the model was fitted to the same voxels); a small p means the single "
        "Pareto does not describe the voxels (e.g. L_I varies with k): prefer the data "
        "median then. The histogram figure shows L_I up to its "
        f"{a.get('hist_view_quantile', 1):g} quantile; every statistic uses all voxels. "
        "The standard "
        "deviation of L_I does not converge under the model (infinite variance). "
        "Masked: voxels with P_P <= 0, a "
        "non-finite power" + (", or P_I < 0" if a["negative_policy"] == "mask" else "")
        + "; see `n_masked_by_reason` in leakage.h5.",
        "",
    ]
    Path(path).write_text("\n".join(lines))
    return Path(path)


def _range_text(a) -> str:
    parts = []
    if len(a.get("k_par_range", [])) == 2:
        lo, hi = a["k_par_range"]
        parts.append(f"{lo:g} <= |k_par| <= {hi:g} Mpc^-1")
    if len(a.get("k_perp_range", [])) == 2:
        lo, hi = a["k_perp_range"]
        parts.append(f"{lo:g} <= k_perp <= {hi:g} Mpc^-1")
    return (" with " + " and ".join(parts)) if parts else ""


def refuse_existing(output: str | os.PathLike, overwrite: bool) -> None:
    """Refuse an output that is a file, or a directory holding leakage products (unless
    ``overwrite``)."""
    output = Path(output)
    if output.exists() and not output.is_dir():
        raise InputError(f"{output} exists and is not a directory; choose another output",
                         param="output")
    found = [name for name in OUTPUT_FILES if (output / name).exists()]
    if found and not overwrite:
        raise InputError(f"{output} holds leakage products ({', '.join(found)}); choose "
                         "another output or pass overwrite", param=("output", "overwrite"))


def first_realisation(result: xr.Dataset) -> xr.Dataset:
    """The inputs of the first sky realisation (all inputs when there is one): the maps
    figure shows one realisation, whose maps the others resemble."""
    realisation = result["realisation"].values
    return result.isel(input=np.flatnonzero(realisation == realisation[0]))


def write_leakage(result: xr.Dataset, expected: Sequence[xr.Dataset],
                  corrected: Sequence[xr.Dataset], outdir: str | os.PathLike, *,
                  figures: bool = True, pdf: bool = True,
                  observed: Sequence[xr.Dataset] = ()) -> dict[str, Path]:
    """Write the tables, products (their ``history`` that of the Datasets plus this
    command) and figures of a leakage result into ``outdir``, with the comparisons
    ``observed`` (:func:`msleak.leakage.compare.compare_observed`, one per input); returns
    them by role."""
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    files = {"stats_csv": write_stats_csv(result, outdir / "stats.csv"),
             "stats_md": write_stats_md(result, outdir / "stats.md"),
             "estimates_csv": write_estimates_csv(result, outdir / "estimates.csv"),
             "leakage": save_product(result, outdir / "leakage.h5", "leakage", overwrite=True,
                                     history=history_lines(result.attrs))}
    for kind, items in (("expected", expected), ("corrected", corrected)):
        for ds in items:
            lab = ds.attrs["label"]
            files[f"{kind}_{lab}"] = save_product(
                ds, outdir / f"{kind}_{_safe(lab)}.h5", f"leakage_{kind}", overwrite=True,
                history=history_lines(ds.attrs))
    labels = [str(x) for x in np.asarray(result["label"].values).ravel()]
    if observed:
        files["observed_csv"] = _write_observed_csv(observed, labels, outdir / "observed.csv")
    if figures and observed:
        files["observed_png"] = plots.plot_observed(observed, labels, outdir / "observed.png",
                                                    pdf, plots.field_title(result))
    if figures:
        files["maps_png"] = plots.plot_leakage_maps(first_realisation(result),
                                                    outdir / "leakage_maps.png", pdf)
        files["hist_png"] = plots.plot_leakage_histograms(result, outdir / "leakage_hist.png",
                                                          pdf)
        name = plots.field_title(result)
        if expected:
            files["expected_png"] = plots.plot_expected_spherical(
                expected, outdir / "expected_leakage.png", pdf, name)
        if corrected:
            files["corrected_png"] = plots.plot_corrected_spherical(
                corrected, outdir / "corrected.png", pdf, name)
    return files


def _write_observed_csv(observed: Sequence[xr.Dataset], labels: Sequence[str],
                        path: Path) -> Path:
    """One row per input: the predicted leakage and the observed Stokes I power summed over
    the EoR window and over all bins, and their ratios (:data:`COMPARE_COLUMNS`)."""
    with open(path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["label", *COMPARE_COLUMNS])
        for c, label in zip(observed, labels):
            writer.writerow([label, *(c.attrs[k] if k == "units" else f"{c.attrs[k]:.6g}"
                                      for k in COMPARE_COLUMNS)])
    return path
