"""Files of ``msleak leakage``: read PS products, write tables, products and figures.

This is the I/O edge of :mod:`msleak.leakage`; the numbers come from
:mod:`msleak.leakage.analysis`.
"""

from __future__ import annotations

import csv
import logging
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import xarray as xr

from msleak.errors import InputError
from msleak.io.products import open_product, save_product
from msleak.leakage.analysis import STAT_COLUMNS, ModelMode, analyse, correct, predict

__all__ = ["LeakageOptions", "run_leakage", "write_stats_csv", "write_estimates_csv",
           "write_stats_md", "estimate_summary", "default_labels"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LeakageOptions:
    """Options of :func:`run_leakage` (see ``msleak leakage --help``)."""

    field_name: str = ""
    stats_from: str = "voxels"
    negative: str = "mask"
    bins: int = 100
    upper_quantile: float = 0.99
    k_par_range: tuple[float, float] | None = None
    k_perp_range: tuple[float, float] | None = None
    expected_model: ModelMode = "auto"
    rel_error: float | None = None
    figures: bool = True
    pdf: bool = True
    n_boot: int = 200
    bootstrap_block: int = 2
    seed: int = 0
    extra: dict = field(default_factory=dict)


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


def estimate_summary(result: xr.Dataset) -> str:
    """The per-field estimate in one plain line (what ``msleak leakage`` prints)."""
    return _estimate_lines(result)[-1].replace("**", "")


def _estimate_lines(result: xr.Dataset) -> list[str]:
    """The per-field estimate in words: one realisation, or mean +- std over several."""
    a = result.attrs
    n = result.sizes["input"]
    if a["n_realisations"] == 1:
        return [f"Per-field estimate (mean of the Pareto medians over {n} input(s)): "
                f"**{a['field_estimate']:.4g} %** (spread {a['field_estimate_spread']:.2g} %); "
                f"mean of the data medians: {a['field_estimate_data']:.4g} % "
                f"(spread {a['field_estimate_data_spread']:.2g} %)."]
    lines = ["| realisation | estimate, Pareto medians (%) | estimate, data medians (%) |",
             "|---|---:|---:|"]
    for k, r in enumerate(result["realisation_id"].values):
        lines.append(f"| {int(r)} | {float(result['realisation_estimate'].values[k]):.4g} ± "
                     f"{float(result['realisation_estimate_err'].values[k]):.2g} | "
                     f"{float(result['realisation_estimate_data'].values[k]):.4g} ± "
                     f"{float(result['realisation_estimate_data_err'].values[k]):.2g} |")
    err = float(result["realisation_estimate_err"].mean())
    err_data = float(result["realisation_estimate_data_err"].mean())
    return lines + ["", f"Per-field estimate over {a['n_realisations']} sky realisations "
                    f"(mean ± standard deviation over realisations; bootstrap error within "
                    f"one realisation in brackets), Pareto medians: "
                    f"**{a['field_estimate']:.4g} ± {a['field_estimate_realisation_std']:.2g} %** "
                    f"({err:.2g} %); data medians: {a['field_estimate_data']:.4g} ± "
                    f"{a['field_estimate_data_realisation_std']:.2g} % ({err_data:.2g} %)."]


def write_stats_md(result: xr.Dataset, path: str | os.PathLike) -> Path:
    """``stats.md``: the statistics as a Markdown table, plus the per-field estimate."""
    a = result.attrs
    title = f"L_I statistics{(' of ' + a['field_name']) if a.get('field_name') else ''}"
    lines = [f"# {title}", "",
             "| input | mean (%) | median (%) | std (%) | peak (%) | Pareto median (%) "
             "| KS D (p) | voxels (independent) | masked |",
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
        "stats.csv); 'independent' = n (iid error / bootstrap error)^2. KS D = largest "
        "difference between the L_I distribution and the fitted model's CDF, with its "
        "p-value for that number of independent voxels (approximate: the model was fitted "
        "to the same voxels); a small p means the single Pareto does not describe the "
        "voxels (e.g. L_I varies with k): prefer the data median then. The standard "
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


def _open_ps(path) -> xr.Dataset:
    return open_product(path, "ps", required=["power"])


def run_leakage(inputs: Sequence[str | os.PathLike], outdir: str | os.PathLike,
                labels: Sequence[str] | None = None,
                expected: Sequence[str | os.PathLike] = (),
                expected_labels: Sequence[str] | None = None,
                correct_inputs: Sequence[str | os.PathLike] = (),
                options: LeakageOptions = LeakageOptions(),
                realisations: Sequence[int] | None = None
                ) -> tuple[dict[str, Path], xr.Dataset]:
    """Run the whole ``msleak leakage`` command; returns the written files by role and the
    leakage result (:func:`msleak.leakage.analysis.analyse`).

    Parameters
    ----------
    inputs : sequence of path
        Model PS products (kind ``ps``), e.g. one per field of view.
    outdir : path
        Output directory (created; files in it are replaced).
    labels : sequence of str, optional
        One label per input (default: file stems).
    expected : sequence of path
        Observed PS products whose Stokes P gives the expected leakage.
    expected_labels : sequence of str, optional
        One label per observed product (default: file stems).
    correct_inputs : sequence of path
        Observed PS products whose Stokes I is bias-corrected; paired one to one with
        ``expected`` (or, without ``expected``, their own Stokes P is used).
    realisations : sequence of int, optional
        The sky realisation (seed) of each input; the per-field estimate is then given
        per realisation and as mean +- std over them (``estimates.csv``).
    """
    inputs = [str(p) for p in inputs]
    labels = list(labels) if labels else default_labels(inputs)
    if len(labels) != len(inputs):
        raise InputError(f"{len(labels)} labels for {len(inputs)} inputs")
    if realisations is not None and len(realisations) != len(inputs):
        raise InputError(f"{len(realisations)} realisations for {len(inputs)} inputs")
    keys = list(zip(labels, realisations or [0] * len(labels)))
    if len(set(keys)) != len(keys):
        raise InputError(f"labels must be unique within a realisation, got {','.join(labels)}")
    expected = [str(p) for p in expected]
    correct_inputs = [str(p) for p in correct_inputs]
    if correct_inputs and expected and len(correct_inputs) != len(expected):
        raise InputError(f"--correct pairs one to one with --expected: got "
                         f"{len(correct_inputs)} and {len(expected)} files")
    obs_paths = expected or correct_inputs
    obs_labels = list(expected_labels) if expected_labels else default_labels(obs_paths)
    if len(set(obs_labels)) != len(obs_labels):
        raise InputError(f"--expected-labels must be unique, got {','.join(obs_labels)}")
    if obs_paths and len(obs_labels) != len(obs_paths):
        raise InputError(f"{len(obs_labels)} --expected-labels for {len(obs_paths)} "
                         "observed PS products")
    # open everything first: a bad file fails before any output is written
    datasets = [_open_ps(p) for p in inputs]
    observed = [_open_ps(p) for p in obs_paths]
    observed_i = [_open_ps(p) for p in correct_inputs] if expected else observed
    o = options
    result = analyse(datasets, labels, inputs, stats_from=o.stats_from, negative=o.negative,
                     bins=o.bins, upper_quantile=o.upper_quantile,
                     k_par_range=o.k_par_range, k_perp_range=o.k_perp_range,
                     field_name=o.field_name, n_boot=o.n_boot,
                     bootstrap_block=o.bootstrap_block, seed=o.seed,
                     realisations=realisations)
    outdir = Path(outdir)
    if outdir.exists() and not outdir.is_dir():
        raise InputError(f"{outdir} exists and is not a directory")
    outdir.mkdir(parents=True, exist_ok=True)
    files: dict[str, Path] = {}
    files["stats_csv"] = write_stats_csv(result, outdir / "stats.csv")
    files["stats_md"] = write_stats_md(result, outdir / "stats.md")
    files["estimates_csv"] = write_estimates_csv(result, outdir / "estimates.csv")
    files["leakage"] = save_product(result, outdir / "leakage.h5", "leakage")

    exp_results, corr_results = [], []
    for i, (obs, lab, path) in enumerate(zip(observed, obs_labels, obs_paths)):
        exp = predict(result, obs, i, len(observed), o.expected_model, o.rel_error, path)
        exp.attrs["label"] = lab
        if expected:
            exp_results.append(exp)
            files[f"expected_{lab}"] = save_product(
                exp, outdir / f"expected_{_safe(lab)}.h5", "leakage_expected")
        if correct_inputs:
            cor = correct(observed_i[i], exp, correct_inputs[i])
            cor.attrs["label"] = lab
            corr_results.append(cor)
            files[f"corrected_{lab}"] = save_product(
                cor, outdir / f"corrected_{_safe(lab)}.h5", "leakage_corrected")
        log.info("%s (%s): expected leakage from L_I model %s (%s, %.4g %%)", path, lab,
                 exp.attrs["model_input"], exp.attrs["model_mode"],
                 exp.attrs["L_I_model_scalar"])

    if o.figures:
        from msleak.plot import leakage as pl

        files["maps_png"] = pl.plot_leakage_maps(result, outdir / "leakage_maps.png", o.pdf)
        files["hist_png"] = pl.plot_leakage_histograms(result, outdir / "leakage_hist.png",
                                                       o.pdf)
        if exp_results:
            files["expected_png"] = pl.plot_expected_spherical(
                exp_results, outdir / "expected_leakage.png", o.pdf, o.field_name)
        if corr_results:
            files["corrected_png"] = pl.plot_corrected_spherical(
                corr_results, outdir / "corrected.png", o.pdf, o.field_name)
    return files, result
