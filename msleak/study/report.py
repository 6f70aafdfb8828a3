"""``report.md`` of the whole study: figures, statistics tables, per-field estimates and
the exact commands that made them."""

from __future__ import annotations

import csv
import logging
import os
import time
from pathlib import Path

import numpy as np

from msleak import __version__
from msleak.io.products import open_product
from msleak.plot.ps import plot_ps1d
from msleak.study.config import StudyConfig

__all__ = ["write_report"]

log = logging.getLogger(__name__)


def _rel(path: Path, base: Path) -> str:
    return os.path.relpath(path, base)


def _and(items: list[str]) -> str:
    return ", ".join(items[:-1]) + " and " + items[-1]


def _resolution_text(cfg: StudyConfig) -> str:
    """How the study's sky is sampled, predicted and gridded (``--resolution``)."""
    uv_min, uv_max = cfg.uv_range
    fovs = cfg.fields_of_view
    pixel = cfg.sky_fov / cfg.sky_npix
    sides = _and([f"{n * pixel:.3g}" for _, n in fovs])
    counts = _and([str(n) for _, n in fovs])
    labels = _and([label.removesuffix("deg") for label, _ in fovs])
    if cfg.resolution == "paper":
        sky = (f"for fields of view of {labels} deg (the paper's {counts} pixels of "
               f"{pixel:g} deg, i.e. {sides} deg a side)")
        one_d = ""
    else:
        k = cfg.kperp_1d
        sky = (f"at the resolution of observed LOFAR data, by image-domain gridding "
               f"(msleak predict --method auto), for fields of view of {labels} deg "
               f"({counts} pixels of {pixel * 60:.3g} arcmin, i.e. {sides} deg a side: "
               f"pixels of at most 1/(2 x {uv_max:g}) rad resolve every baseline up to "
               f"{uv_max:g} wavelengths)")
        one_d = f" (the 1D PS over k_perp {k[0]:g}-{k[1]:g} Mpc^-1, every gridded baseline)"
    return (f"{sky}, then gridded ({uv_min:g}-{uv_max:g} wavelengths, 16-wavelength "
            f"cells), delay-transformed (Blackman-Harris) and turned into Stokes power "
            f"spectra{one_d}.")


def stats_rows(path: Path) -> list[dict]:
    if not path.exists():
        return []
    with path.open() as fh:
        return list(csv.DictReader(fh))


def _extra_figures(cfg: StudyConfig, out: Path) -> dict:
    """1D PS of Q and U for the three fields of view, per field (docs/science.md section 8)."""
    made = {}
    for fld in cfg.fields:
        inputs = [(out / fld / f"ps_{label}.h5", label) for label, _ in cfg.fields_of_view]
        inputs = [(p, lab) for p, lab in inputs if p.exists()]
        if not inputs:
            continue
        path = out / "figures" / f"ps1d_{fld}.png"
        try:
            made[fld] = plot_ps1d(inputs, path, stokes=("Q", "U"), pdf=True,
                                  title=f"{fld.upper()}: Stokes Q and U")
        except Exception as err:  # a figure must not lose the report
            log.warning("1D PS figure for %s failed: %s", fld, err)
    return made


def _ps1d_caption(cfg: StudyConfig, fld: str) -> list[str]:
    """What sets the high-k_par floor of the 1D PS figure, when baselines cross the uv-range
    limits within the band (the grid records how many rows do)."""
    paths = [out for label, _ in cfg.fields_of_view
             if (out := Path(cfg.outdir) / fld / f"ps_{label}.h5").exists()]
    rows = max((int(open_product(p, "ps").attrs.get("n_rows_crossing_uv_range", 0) or 0)
                for p in paths), default=0)
    if not rows:
        return []
    lo, hi = cfg.uv_range
    return [f"The MS has {rows} rows (baseline x time) whose length crosses {lo:g} or "
            f"{hi:g} wavelengths within the band: each enters or leaves the uv range "
            "mid-band, a step in frequency in the cells it feeds, which puts a flat floor at "
            "high k_par there. Where such cells lie in the figure's k_perp range the curves "
            "flatten onto that floor; its height depends on the sky in those cells, so the Q "
            "and U floors can differ by orders of magnitude (docs/ps.md, \"A floor from the "
            "uv range\").", ""]


def _stats_table(rows: list[dict], with_seed: bool) -> list[str]:
    """The L_I statistics of every field of view (and sky seed) as a Markdown table."""
    seed_col = ("| sky seed ", "|---") if with_seed else ("", "")
    lines = ["Statistics of L_I over the 3D power-spectrum voxels (percent):", "",
             f"{seed_col[0]}| field of view | mean | median | std | peak | Pareto median "
             "| voxels |", f"{seed_col[1]}|---|---|---|---|---|---|---|"]
    for r in rows:
        seed = f"| {r['realisation']} " if with_seed else ""
        lines.append(f"{seed}| {r.get('label', '')} | {float(r['mean']):.3g} | "
                     f"{float(r['median']):.3g} | {float(r['std']):.3g} | "
                     f"{float(r['peak']):.3g} | {float(r['pareto_median']):.3g} | "
                     f"{r.get('n_voxels', '')} |")
    return lines + [""]


def _estimate_text(est: list[dict]) -> list[str]:
    """The per-field estimate from ``estimates.csv`` (written by ``msleak leakage``)."""
    total = est[-1]
    if len(est) == 2:
        return [f"Per-field estimate, the mean over the fields of view of the data medians: "
                f"**L_I = {float(total['estimate_data']):.3g} %**; of the fitted Pareto "
                f"medians: **{float(total['estimate']):.3g} %** (bootstrap error "
                f"{float(total['estimate_err']):.2g} %).", ""]
    lines = ["Per-field estimate of each sky realisation (mean over the fields of view; "
             "± bootstrap error):", "",
             "| sky seed | data medians (%) | Pareto medians (%) |", "|---|---|---|"]
    for r in est[:-1]:
        lines.append(f"| {r['realisation']} | {float(r['estimate_data']):.3g} ± "
                     f"{float(r['estimate_data_err']):.2g} | {float(r['estimate']):.3g} ± "
                     f"{float(r['estimate_err']):.2g} |")
    return lines + ["", f"Over {len(est) - 1} realisations (mean ± standard deviation): "
                    f"data medians **L_I = {float(total['estimate_data']):.3g} ± "
                    f"{float(total['realisation_std_data']):.2g} %**, Pareto medians "
                    f"**{float(total['estimate']):.3g} ± {float(total['realisation_std']):.2g} "
                    f"%**; the bootstrap error within one realisation is "
                    f"{float(total['estimate_err']):.2g} %.", ""]


def _summary(estimates: list, seeds: int) -> list[str]:
    """The per-field estimates of every field side by side."""
    if seeds == 1:
        lines = ["## Summary", "",
                 "| field | L_I, mean of data medians (%) | L_I, mean of Pareto medians (%) |",
                 "|---|---|---|"]
        return lines + [f"| {fld.upper()} | {float(t['estimate_data']):.3g} | "
                        f"{float(t['estimate']):.3g} |" for fld, t in estimates] + [""]
    lines = ["## Summary", "", f"Mean ± standard deviation over {seeds} sky realisations "
             "(bootstrap error within one realisation in brackets).", "",
             "| field | L_I, data medians (%) | L_I, Pareto medians (%) |", "|---|---|---|"]
    return lines + [f"| {fld.upper()} | {float(t['estimate_data']):.3g} ± "
                    f"{float(t['realisation_std_data']):.2g} ({float(t['estimate_data_err']):.2g})"
                    f" | {float(t['estimate']):.3g} ± {float(t['realisation_std']):.2g} "
                    f"({float(t['estimate_err']):.2g}) |" for fld, t in estimates] + [""]


#: the instrument's corruptions in the budget table: kind -> what the row says
BUDGET_KINDS = {"ionosphere": "ionospheric Faraday rotation", "beam_errors": "beam-model errors",
                 "noise": "thermal noise (even/odd cross power)"}


def spread_text(values: list[float]) -> str:
    """mean ± standard deviation (± 0 for one value)."""
    v = np.asarray(values, dtype=float)
    return f"{v.mean():.3g} ± {v.std():.2g}" if v.size > 1 else f"{v[0]:.3g}"


def _budget(cfg: StudyConfig, fdir: Path) -> list[str]:
    """The instrument's budget table of one field: L_I at the largest field of view for the
    ideal instrument (the first sky), over the sky realisations, and over the realisations
    of each corruption of the first sky (docs/paper.md, "The instrument's budget")."""
    label = cfg.fields_of_view[0][0]
    ideal = [r for r in stats_rows(fdir / "leakage" / "stats.csv") if r.get("label") == label]
    rows = []
    if ideal:
        first = [r for r in ideal if str(r.get("realisation", cfg.seed)) == str(cfg.seed)]
        rows.append(("ideal instrument, first sky", first or ideal[:1]))
        if len(ideal) > 1:
            rows.append(("sky realisations (ideal instrument)", ideal))
    corrupted = [(f"{text}, first sky", found) for kind, text in BUDGET_KINDS.items()
                 if (found := stats_rows(fdir / f"leakage_{kind}" / "stats.csv"))]
    if not corrupted:
        return []
    rows += corrupted
    lines = [f"The instrument's budget at {label} (docs/paper.md): L_I over the 3D voxels, "
             "mean ± standard deviation over the realisations of each source of variation "
             "alone (percent):", "",
             "| varied | realisations | data median | Pareto median |", "|---|---|---|---|"]
    for name, found in rows:
        lines.append(f"| {name} | {len(found)} | "
                     f"{spread_text([float(r['median']) for r in found])} | "
                     f"{spread_text([float(r['pareto_median']) for r in found])} |")
    return lines + [""] + _detectable(cfg, fdir, label)


def _detectable(cfg: StudyConfig, fdir: Path, label: str) -> list[str]:
    """The smallest detectable L_I of one field's budget, if it has noise runs."""
    if cfg.noise_sefd is None:
        return []
    return detectable_text(fdir / "ps_noise0.h5", [fdir / f"ps_noise{r}.h5" for r in
                                                   range(1, cfg.instrument_seeds + 1)],
                           cfg.noise_sefd, fdir / f"{fdir.name}.ms")


def detectable_text(ideal: Path, noisy: list[Path], sefd: float, ms: Path) -> list[str]:
    """The smallest L_I the thermal noise lets the observation ``ms`` detect (3 sigma per
    voxel; :func:`msleak.leakage.detectable.detectable_leakage`) from the even/odd PS of
    the noiseless column ``ideal`` and the noisy ones, as report lines (none while a file
    is missing)."""
    from msleak.io.ms import read_times
    from msleak.leakage.detectable import detectable_leakage

    if not ideal.exists() or not all(p.exists() for p in noisy):
        return []
    l_min = detectable_leakage(open_product(ideal, "ps"), [open_product(p, "ps")
                                                          for p in noisy], nsigma=3.0)
    times = read_times(ms)
    step = float(np.median(np.diff(times))) if times.size > 1 else 0.0
    hours = (times.max() - times.min() + step) / 3600.0    # first to last slot, both whole
    return [f"Smallest L_I detectable with this observation's thermal noise (SEFD "
            f"{sefd:g} Jy, {hours:.3g} h, the same grid and uv range): median "
            f"{np.median(l_min):.3g} % over the voxels (16th-84th percentile "
            f"{np.percentile(l_min, 16):.3g}-{np.percentile(l_min, 84):.3g} %), the L_I at "
            "which a voxel's leaked P_I stands 3 sigma above the noise's even/odd cross "
            "power in its uv cell (docs/paper.md); over the same uv coverage it scales as "
            "t^-1/2 with the observing time t.", ""]


def write_report(cfg: StudyConfig, steps, step_log, seconds: float) -> Path:
    """Write ``OUTDIR/report.md`` and return its path."""
    out = Path(cfg.outdir)
    ps1d = _extra_figures(cfg, out)
    lines = [
        "# Polarization leakage study",
        "",
        f"Made by msleak {__version__} on {time.strftime('%Y-%m-%d %H:%M')} "
        f"({'quick, reduced size' if cfg.quick else 'full scale'}"
        f"{'' if cfg.resolution == 'paper' else ', --resolution ' + cfg.resolution}); "
        "this run took "
        f"{seconds / 60:.1f} min (steps skipped as up to date are marked below).",
        "",
        "Method: Asad et al. (2018, MNRAS 476, 3051), as restated in msleak's docs. The "
        "same diffuse polarized sky (Q, U; differential Faraday rotation) is predicted "
        "through the per-station LOFAR HBA beam (EveryBeam model) with the beam at the "
        f"phase centre removed, {_resolution_text(cfg)} L_I = 100 sqrt(P_I / P_P). Sky "
        f"realisations: {cfg.seeds} (seeds {', '.join(map(str, cfg.realisations))}), each "
        "through the same MSs and beams; figures show the first.",
        "",
        "## Sky model",
        "",
        "![sky](figures/sky.png)",
        "",
    ]
    estimates = []
    for fld in cfg.fields:
        fdir = out / fld
        rows = stats_rows(fdir / "leakage" / "stats.csv")
        lines += [f"## Field {fld.upper()}", ""]
        if rows:
            lines += _stats_table(rows, cfg.seeds > 1)
            est = stats_rows(fdir / "leakage" / "estimates.csv")
            if est:
                lines += _estimate_text(est)
                estimates.append((fld, est[-1]))
        lines += _budget(cfg, fdir)
        for name, caption in (("leakage/leakage_maps.png", "P_P, P_I and L_I with wedges"),
                              ("leakage/leakage_hist.png", "L_I histograms and Pareto fits"),
                              ("leakage/expected_leakage.png", "expected leakage")):
            if (fdir / name).exists():
                lines += [f"![{caption}]({_rel(fdir / name, out)})", ""]
        beam_png = out / "figures" / f"beam_{fld}.png"
        if beam_png.exists():
            lines += [f"![beam {fld}]({_rel(beam_png, out)})", ""]
        if fld in ps1d:
            lines += [f"![1D PS {fld}]({_rel(ps1d[fld], out)})", "", *_ps1d_caption(cfg, fld)]
        for label, _ in cfg.fields_of_view:
            png = out / "figures" / f"ps_{fld}_{label}.png"
            if png.exists():
                lines += [f"![2D PS {fld} {label}]({_rel(png, out)})", ""]
    if estimates:
        lines += _summary(estimates, cfg.seeds)
    if cfg.extents:
        from msleak.study.extents import extent_lines
        from msleak.study.pipeline import extent_runs

        lines += extent_lines(extent_runs(cfg), out, cfg.nside)
    lines += ["## Commands", "",
              "Every step is one msleak command; run from the folder that holds this report's "
              "parent. Times are wall-clock seconds.", "",
              "| step | seconds | command |", "|---|---|---|"]
    for entry in step_log:
        mark = " (up to date, skipped)" if entry["skipped"] else ""
        lines.append(f"| {entry['name']}{mark} | {entry['seconds']:.1f} | "
                     f"`{entry['command']}` |")
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path
