"""L_I against the sky's extent, for ``msleak forecast --extents`` and ``msleak paper
--extents`` (docs/telescopes.md, "L_I against the sky's extent").

One all-sky HEALPix sky per realisation (``msleak sky --healpix``) is predicted within each
extent (deg from the phase centre) into one column per extent and realisation, gridded,
delay-transformed and averaged, with one leakage result per MS (``leakage_extent``). The
summary tabulates the median and the EoR-window L_I per extent and computes where the leakage
from beyond 15 deg lands in k-space: the uv cube of the largest extent minus that of 15 deg
is the cube of the pixels between them (gridding is linear, both cubes have the same
weights).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msleak.errors import InputError
from msleak.io.products import open_product
from msleak.leakage.fraction import window_leakage
from msleak.plot.forecast import plot_extents
from msleak.plot.ps import plot_ps2d
from msleak.study.report import stats_rows
from msleak.study.steps import Step

__all__ = ["ExtentRun", "extent_label", "allsky_step", "extent_steps", "extent_rows",
           "beyond_ps", "extent_lines", "BEYOND_DEG"]

#: the extent (deg from the phase centre) beyond which the leakage is located: twice the
#: half-width of the paper's widest (15 x 15 deg) field, so the sky the flat study leaves out
BEYOND_DEG = 15.0


def extent_label(extent: float) -> str:
    """File and column label of an extent (deg): ``e15``, ``e7p5``."""
    return "e" + f"{extent:g}".replace(".", "p")


def allsky_step(path: Path, nside: int, seed: int, sky_args: list) -> Step:
    """``msleak sky PATH --healpix NSIDE --seed SEED`` with the band options ``sky_args``."""
    return Step(f"allsky-{path.stem}", ["sky", path, "--healpix", nside, "--seed", seed,
                                        *sky_args, "--overwrite"], outputs=[path])


@dataclass(frozen=True)
class ExtentRun:
    """The extent runs of one MS: its name in step names and tables, the MS and the
    directory of its products, the predict options (beam, precision), grid and ps options,
    the all-sky sky of each realisation ``{seed: path}``, the extents (deg), the step that
    must run first and the field name of the leakage tables."""

    name: str
    label: str
    ms: Path
    outdir: Path
    predict: list
    grid: list
    ps: list
    skies: dict
    extents: tuple
    after: str
    field_name: str

    @property
    def names(self) -> list[tuple[int, str, float]]:
        return [(seed, extent_label(e), e) for seed in self.skies for e in self.extents]


def extent_steps(run: ExtentRun) -> list[Step]:
    """One predict and one grid of every (realisation, extent), a PS per column and one
    leakage result (``OUTDIR/leakage_extent``)."""
    predict = ["predict", run.ms, *run.predict]
    grid = ["grid", run.ms, *run.grid, "--overwrite"]
    for seed, label, extent in run.names:
        column = f"MODEL_{label.upper()}_S{seed}"
        predict += ["--sky", run.skies[seed], "--column", column, "--extent", f"{extent:g}"]
        grid += ["--column", column, "-o", run.outdir / f"grid_{label}_s{seed}.h5"]
    steps = [Step(f"predict-{run.name}-extents", predict, after=[run.after], outputs=[run.ms],
                  inputs=sorted(set(run.skies.values()))),
             Step(f"grid-{run.name}-extents", grid, after=[f"predict-{run.name}-extents"],
                  reads=[run.ms], outputs=[run.outdir / f"grid_{label}_s{seed}.h5"
                                           for seed, label, _ in run.names])]
    ps_files = []
    for seed, label, _ in run.names:
        grid_h5, delay, ps = (run.outdir / f"{x}_{label}_s{seed}.h5"
                              for x in ("grid", "delay", "ps"))
        steps += [Step(f"transform-{run.name}-{label}-s{seed}", ["transform", grid_h5, "-o",
                                                                 delay, "--overwrite"],
                       inputs=[grid_h5], outputs=[delay]),
                  Step(f"ps-{run.name}-{label}-s{seed}", ["ps", delay, "-o", ps,
                                                          "--overwrite", *run.ps],
                       inputs=[delay], outputs=[ps])]
        ps_files.append(ps)
    steps.append(Step(f"leakage-{run.name}-extents", [
        "leakage", *ps_files, "--labels", ",".join(label for _, label, _ in run.names),
        "--realisations", ",".join(str(seed) for seed, _, _ in run.names), "--field-name",
        run.field_name, "-o", run.outdir / "leakage_extent", "--no-pdf", "--overwrite"],
        inputs=ps_files, outputs=[run.outdir / "leakage_extent" / "stats.csv"]))
    return steps


def extent_rows(run: ExtentRun) -> list[dict]:
    """Median L_I and EoR-window L_I per extent, mean and standard deviation over the
    realisations (from ``leakage_extent/stats.csv`` and the PS files)."""
    stats = stats_rows(run.outdir / "leakage_extent" / "stats.csv")
    rows = []
    for extent in run.extents:
        label = extent_label(extent)
        medians = np.array([float(r["median"]) for r in stats if r["label"] == label])
        window = np.array([window_leakage(open_product(run.outdir / f"ps_{label}_s{s}.h5",
                                                       "ps")) for s in run.skies])
        rows.append({"name": run.name, "label": run.label, "extent_deg": extent,
                     "realisations": len(medians),
                     "median": float(np.mean(medians)) if medians.size else float("nan"),
                     "median_scatter": _scatter(medians),
                     "window": float(np.nanmean(window)) if np.isfinite(window).any()
                     else float("nan"), "window_scatter": _scatter(window)})
    return rows


def _scatter(x: np.ndarray) -> float:
    return float(np.nanstd(x, ddof=1)) if np.sum(np.isfinite(x)) > 1 else 0.0


def beyond_ps(run: ExtentRun, inner: float = BEYOND_DEG):
    """The power spectra of the sky beyond ``inner`` deg (first realisation): the uv cube
    of the largest extent minus that of ``inner``, delay-transformed; None without both
    extents."""
    from msleak.verbs.power import power_spectrum
    from msleak.verbs.transform import transform

    if inner not in run.extents or max(run.extents) <= inner:
        return None
    seed = next(iter(run.skies))
    outer = open_product(run.outdir / f"grid_{extent_label(max(run.extents))}_s{seed}.h5",
                         "uvcube")
    near = open_product(run.outdir / f"grid_{extent_label(inner)}_s{seed}.h5", "uvcube")
    same = all(np.array_equal(outer[k].values, near[k].values)
               for k in ("weight", "u", "v", "freq"))
    if not same:
        raise InputError(f"{run.outdir}: the uv cubes of {extent_label(max(run.extents))} "
                         f"and {extent_label(inner)} differ in weights or axes; grid both "
                         "columns in one pass to subtract them")
    diff = outer.copy()
    diff["vis"] = outer["vis"] - near["vis"]
    diff.attrs["column"] = f"{outer.attrs.get('column')} - {near.attrs.get('column')}"
    return power_spectrum(transform(diff), **({} if not run.ps else _ps_options(run.ps)))


def _ps_options(args: list) -> dict:
    """The 1D k_perp range of ``msleak ps`` options (the only one the study passes)."""
    if "--kperp-1d" not in args:
        return {}
    lo, hi = (float(x) for x in str(args[args.index("--kperp-1d") + 1]).split(","))
    return {"kperp_1d": (lo, hi)}


def extent_lines(runs: list[ExtentRun], out: Path, nside: int) -> list[str]:
    """The table of L_I against the extent (``extents.csv``, ``figures/extents.png``) and
    where the leakage from beyond 15 deg lands in k-space, as markdown lines."""
    if not runs:
        return []
    rows = [r for run in runs for r in extent_rows(run)]
    with (out / "extents.csv").open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    fig = plot_extents(rows, out / "figures" / "extents.png")
    lines = ["", "## L_I against the sky's extent", "",
             f"All-sky HEALPix skies (NSIDE {nside}, the same realisations), every pixel "
             "above the horizon within the extent of the phase centre "
             "(docs/telescopes.md); mean ± standard deviation over the realisations.", "",
             "| array | extent (deg) | median L_I (%) | EoR window L_I (%) |",
             "|---|---|---|---|"]
    lines += [f"| {r['label']} | {r['extent_deg']:g} | {r['median']:.3g} ± "
              f"{r['median_scatter']:.2g} | {r['window']:.3g} ± {r['window_scatter']:.2g} |"
              for r in rows]
    lines += ["", f"![L_I against extent]({fig.relative_to(out)})", ""]
    for run in runs:
        ps = beyond_ps(run)
        if ps is None:
            continue
        path = plot_ps2d(ps, out / "figures" / f"beyond15_{run.name}.png", stokes=("I", "P"))
        lines += [f"{run.label}, the sky beyond {BEYOND_DEG:g} deg: "
                  f"{above_horizon(ps):.3g} % of its leaked P_I lies above the horizon "
                  f"wedge. ![beyond {BEYOND_DEG:g} deg]({path.relative_to(out)})", ""]
    return lines


def above_horizon(ps) -> float:
    """Percentage of the cylindrical P_I (Jy^2, weighted by the cells per bin) above the
    horizon wedge."""
    slope = float(ps.attrs["wedge_slope_horizon"])
    k_par = ps["k_par"].values[:, None]
    k_perp = ps["k_perp"].values[None, :]
    n = ps["counts"].transpose("k_par", "k_perp").values
    p_i = ps["power_jy2"].sel(stokes="I").transpose("k_par", "k_perp").values
    ok = (n > 0) & np.isfinite(p_i)
    total = np.sum((n * p_i)[ok])
    return float(100.0 * np.sum((n * p_i)[ok & (k_par > slope * k_perp)]) / total) \
        if total > 0 else float("nan")
