"""Figures of ``msleak leakage``: L_I maps beside P_P and P_I, L_I histograms with the
Pareto model, spherical spectra of the expected leakage and of the bias correction, and the
predicted leakage beside the observed Stokes I.
Titles name the field, and each input by its label, MS column and uv cell size."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np
import xarray as xr

from msleak.leakage.stats import ParetoFit, pareto_density_percent
from msleak.plot import new_figure, save_figure, uv_cell_text

__all__ = ["plot_leakage_maps", "plot_leakage_histograms", "plot_expected_spherical",
           "plot_corrected_spherical", "plot_observed", "field_title", "input_title"]

_KPERP = r"$k_\perp$ [Mpc$^{-1}$]"
_KPAR = r"$k_\parallel$ [Mpc$^{-1}$]"


def field_title(result: xr.Dataset) -> str:
    """The field: ``field_name``, else the names of the inputs' sources (MS or images)."""
    name = str(result.attrs.get("field_name", ""))
    if name or "source" not in result.coords:
        return name
    sources = dict.fromkeys(Path(s.split(";")[0].strip()).name
                            for s in map(str, result["source"].values) if s)
    return ", ".join(sources)


def input_title(result: xr.Dataset, i: int, sep: str = ", ") -> str:
    """One input: its label, MS column and uv cell size (:func:`~msleak.plot.uv_cell_text`),
    e.g. ``15deg: MODEL_15DEG, uv cell 16 λ (field 1/cell = 3.58°)`` (``sep`` between
    column and cell size)."""
    r = result.isel(input=i)
    extra = []
    if "column" in r.coords and str(r["column"].values):
        extra.append(str(r["column"].values))
    if "cell_lambda" in r.coords and float(r["cell_lambda"]) > 0:
        extra.append(uv_cell_text(float(r["cell_lambda"])))
    label = str(r["label"].values)
    return f"{label}: {sep.join(extra)}" if extra else label


def _unit_tex(units: str) -> str:
    u = units.replace("^2", "$^2$").replace("^3", "$^3$")
    return f" [{u}]" if u else ""


def _edges(c: np.ndarray) -> np.ndarray:
    """Edges for log axes: midpoints, geometric at the ends; a k = 0 bin is drawn from a
    quarter of the first positive centre to the first midpoint."""
    c = np.asarray(c, dtype=float)
    if c.size == 1:
        return np.array([c[0] / 1.5, c[0] * 1.5]) if c[0] > 0 else np.array([0.5, 1.5])
    e = np.concatenate([[c[0] - 0.5 * (c[1] - c[0])], 0.5 * (c[1:] + c[:-1]),
                        [c[-1] + 0.5 * (c[-1] - c[-2])]])
    if e[0] <= 0:
        pos = c[c > 0]
        e[0] = min(pos[0] / 4.0 if pos.size else 1e-3, e[1] / 2.0)
    return e


def _number(v: float) -> str:
    """Plain numbers between 1e-3 and 1e4, otherwise m x 10^e in mathtext."""
    if v == 0 or 1e-3 <= abs(v) < 1e4:
        return f"{v:g}"
    e = int(np.floor(np.log10(abs(v))))
    m = v / 10.0**e
    mant = "" if np.isclose(m, 1.0) else f"{m:g}\\times"
    return f"${mant}10^{{{e}}}$"


def _tidy_log_axis(axis, lo: float, hi: float) -> None:
    """Log ticks at 1, 2, 5 x 10^n (more for short ranges, fewer for long ones), labelled
    as plain numbers where short, with no crowded minor labels."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    decades = np.log10(hi / lo) if lo > 0 and hi > lo else 1.0
    subs = ((1.0, 1.5, 2.0, 3.0, 5.0, 7.0) if decades < 1.2 else
            (1.0, 2.0, 5.0) if decades < 2.5 else (1.0,))
    axis.set_major_locator(LogLocator(subs=subs))
    if decades >= 2.5:
        from matplotlib.ticker import LogFormatterSciNotation

        axis.set_major_formatter(LogFormatterSciNotation())
    else:
        axis.set_major_formatter(FuncFormatter(lambda v, _: _number(v)))
    axis.set_minor_formatter(NullFormatter())


def _lognorm(values: np.ndarray, valid: np.ndarray, lo_q=1.0, hi_q=99.5):
    from matplotlib.colors import LogNorm

    v = values[valid & (values > 0) & np.isfinite(values)]
    if v.size == 0:
        return LogNorm(1e-3, 1.0)
    lo, hi = np.percentile(v, [lo_q, hi_q])
    if hi <= lo:
        lo, hi = v.min() * 0.9, v.max() * 1.1
    return LogNorm(lo, hi)


def _wedges(ax, result: xr.Dataset, i: int, kperp_max: float, legend: bool) -> None:
    for var, style, name in (("wedge_slope_horizon", "--", "horizon"),
                             ("wedge_slope_primary", ":", "primary beam")):
        slope = float(result[var].values[i]) if var in result else 0.0
        if slope > 0:
            x = np.geomspace(kperp_max / 1e3, kperp_max, 50)
            ax.plot(x, slope * x, color="k", ls=style, lw=1.6, label=f"{name} wedge")
            ax.plot(x, slope * x, color="w", ls=style, lw=0.7)
    if legend and ax.get_legend_handles_labels()[0]:
        ax.legend(loc="lower right", fontsize=7, framealpha=0.8)


def plot_leakage_maps(result: xr.Dataset, path: str | os.PathLike, pdf: bool = True) -> Path:
    """2D panels: columns P_P, P_I, L_I (log colour scales); rows the inputs; both wedges.

    Masked bins (``mask`` != 0) are left blank (grey).
    """
    n = result.sizes["input"]
    fig, axes = new_figure(n, 3, figsize=(12.5, 3.3 * n + 0.4), squeeze=False,
                           constrained_layout=True)
    kpar, kperp = result["k_par"].values, result["k_perp"].values
    xe, ye = _edges(kperp), _edges(kpar)
    units = _unit_tex(result.attrs.get("units", ""))
    for i in range(n):
        r = result.isel(input=i)
        valid = r["mask"].values == 0
        inside = r["mask"].values != 5
        panels = (("power_P", f"$P_P${units}", "viridis", inside),
                  ("power_I", f"$P_I${units}", "viridis", inside),
                  ("L_I", r"$L_I$ [%]", "magma", valid))
        for j, (var, clabel, cmap, ok) in enumerate(panels):
            ax = axes[i, j]
            ax.set_facecolor("0.8")
            vals = r[var].values
            norm = _lognorm(vals, ok)
            shown = np.ma.masked_where(~ok | (vals <= 0), vals)
            im = ax.pcolormesh(xe, ye, shown, norm=norm, cmap=cmap, shading="flat",
                               rasterized=True)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlim(xe[0], xe[-1])
            ax.set_ylim(ye[0], ye[-1])
            _wedges(ax, result, i, xe[-1], legend=(i == 0 and j == 0))
            _tidy_log_axis(ax.xaxis, xe[0], xe[-1])
            _tidy_log_axis(ax.yaxis, ye[0], ye[-1])
            cb = fig.colorbar(im, ax=ax, pad=0.02)
            cb.set_label(clabel)
            _tidy_log_axis(cb.ax.yaxis, norm.vmin, norm.vmax)
            if i == n - 1:
                ax.set_xlabel(_KPERP)
            ax.set_ylabel(f"{input_title(result, i, sep=chr(10))}\n{_KPAR}" if j == 0
                          else _KPAR)
            if i == 0:
                ax.set_title(("polarized power $P_P$", "Stokes I power $P_I$",
                              r"leakage $L_I = 100\sqrt{P_I/P_P}$")[j])
    name = field_title(result)
    if name:
        fig.suptitle(name)
    return save_figure(fig, path, pdf=pdf)


def plot_leakage_histograms(result: xr.Dataset, path: str | os.PathLike,
                            pdf: bool = True) -> Path:
    """Histogram (density) of L_I per input with the fitted Pareto model and both medians.

    The x axis ends at the ``hist_view_quantile`` of L_I (``hist_view_counts``,
    ``hist_view_edges``), and each panel says how many voxels lie beyond; the statistics
    in the panels are those of every voxel.
    """
    n = result.sizes["input"]
    ncol = min(n, 3)
    nrow = int(np.ceil(n / ncol))
    fig, axes = new_figure(nrow, ncol, figsize=(4.6 * ncol, 3.6 * nrow), squeeze=False,
                           constrained_layout=True)
    src = "voxels" if result.attrs.get("stats_from") == "voxels" else "bins"
    view = "hist_view_counts" in result
    for i in range(n):
        ax = axes.flat[i]
        r = result.isel(input=i)
        counts, edges, beyond = _view(r, result.attrs, view)
        total = float(r["n_voxels"].values)
        dens = counts / (total * np.diff(edges))
        ax.stairs(dens, edges, fill=True, color="C0", alpha=0.45, label=f"{src} (n={int(total)})")
        fit = ParetoFit(float(r["pareto_loc"]), float(r["pareto_scale"]), 0.0, 0.0, "", 0)
        x = np.linspace(edges[0], edges[-1], 400)
        ax.plot(x, pareto_density_percent(x, fit), color="C3", lw=1.8,
                label="Pareto fit ($b=1$)")
        med, pmed = float(r["median"]), float(r["pareto_median"])
        ax.axvline(med, color="k", ls="--", lw=1.2, label="median (data)")
        ax.axvline(pmed, color="C3", ls=":", lw=1.5, label="median (fit)")
        ax.set_xlim(edges[0], edges[-1])
        q = 100 * float(result.attrs.get("hist_view_quantile", 1.0))
        ax.set_xlabel(r"$L_I$ [%]" + (f"\n(x axis to the {q:.0f}th percentile; {beyond} of "
                                      f"{int(total)} {src} beyond)" if view else ""))
        if i % ncol == 0:
            ax.set_ylabel(r"probability density [%$^{-1}$]")
        ax.set_title(input_title(result, i), fontsize=9)
        ax.legend(loc="upper right", fontsize=8)
        ax.text(0.97, 0.5, _stats_text(r, src), transform=ax.transAxes, ha="right",
                va="top", fontsize=8, family="monospace",
                bbox=dict(boxstyle="round", facecolor="white", edgecolor="0.6", alpha=0.9))
    for ax in list(axes.flat)[n:]:
        ax.set_visible(False)
    name = field_title(result)
    binning = (f"{result.attrs.get('hist_bins', '')} bins of L_I up to its "
               f"{100 * float(result.attrs.get('hist_view_quantile', 1)):.0f}th percentile; "
               f"statistics of all {src}" if view else result.attrs.get("hist_binning", ""))
    fig.suptitle(f"{name + ': ' if name else ''}per-field estimate "
                 f"{result.attrs['field_estimate']:.3g} % (mean of fitted medians); "
                 f"histogram: {binning}".replace("L_I", "$L_I$"),
                 fontsize=9)
    return save_figure(fig, path, pdf=pdf)


def _view(r: xr.Dataset, attrs: dict, view: bool) -> tuple[np.ndarray, np.ndarray, int]:
    """(counts, edges, voxels beyond) of the histogram one panel shows: the view
    histogram, or (results without one) the statistics' histogram."""
    if view:
        return (r["hist_view_counts"].values, r["hist_view_edges"].values,
                int(r["n_beyond_hist_view"]))
    nb = int(attrs.get("hist_bins", r["hist_counts"].size))
    return r["hist_counts"].values[:nb], r["hist_edges"].values[: nb + 1], 0


def _stats_text(r: xr.Dataset, src: str) -> str:
    """The statistics box of one histogram panel; the KS p-value is the one for the
    effective number of independent voxels ``n_eff`` (docs/leakage.md, "Goodness of fit")."""
    med, pmed = float(r["median"]), float(r["pareto_median"])
    med_err = f" ± {float(r['median_err']):.1g}" if "median_err" in r else ""
    text = (f"median (data) = {med:.3g}{med_err} %\n"
            f"median (fit)  = {pmed:.3g} ± {float(r['pareto_median_err']):.1g} %\n"
            f"peak = {float(r['peak']):.3g} %, mean = {float(r['mean']):.3g} %")
    if "ks_d" in r:
        text += (f"\nKS D = {float(r['ks_d']):.3f}, p = {float(r['ks_p_eff']):.2g}"
                 f"\n(p for n_eff = {float(r['n_eff']):.0f} effective {src})")
    return text


def _sph_axes(title: str, units: str):
    fig, ax = new_figure(figsize=(6.4, 4.6), constrained_layout=True)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(r"$k$ [Mpc$^{-1}$]")
    ax.set_ylabel(f"$P(k)${_unit_tex(units)}")
    ax.set_title(title)
    ax.grid(True, which="major", alpha=0.3)
    return fig, ax


def plot_expected_spherical(expected: Sequence[xr.Dataset], path: str | os.PathLike,
                            pdf: bool = True, field_name: str = "") -> Path:
    """Spherical PS of the expected leakage (solid, with 1-sigma band) for several
    observed fields / fields of view, with the observed P_P (thin dashed) for scale."""
    units = expected[0].attrs.get("units", "")
    fig, ax = _sph_axes(f"Expected leakage{(' in ' + field_name) if field_name else ''}",
                        units)
    for i, e in enumerate(expected):
        k = e["k"].values
        ok = (e["counts_sph"].values > 0) & (e["power_leak_sph"].values > 0)
        c = f"C{i % 10}"
        lab = e.attrs.get("label", f"#{i}")
        ax.plot(k[ok], e["power_leak_sph"].values[ok], color=c, lw=1.8,
                label=f"{lab}: leakage ($L_I$={e.attrs['L_I_model_scalar']:.2g} %)")
        lo = np.maximum(e["power_leak_sph"].values - e["power_leak_sph_err"].values, 0)
        ax.fill_between(k[ok], np.where(lo[ok] > 0, lo[ok], np.nan),
                        (e["power_leak_sph"] + e["power_leak_sph_err"]).values[ok],
                        color=c, alpha=0.2, lw=0)
        pp = e["power_P_obs_sph"].values
        okp = (e["counts_sph"].values > 0) & (pp > 0)
        ax.plot(k[okp], pp[okp], color=c, lw=0.9, ls="--", alpha=0.8,
                label=f"{lab}: observed $P_P$")
    ax.legend(fontsize=7, ncol=1)
    return save_figure(fig, path, pdf=pdf)


def plot_corrected_spherical(corrected: Sequence[xr.Dataset], path: str | os.PathLike,
                             pdf: bool = True, field_name: str = "") -> Path:
    """Spherical Stokes I PS before and after subtracting the expected leakage (with
    1-sigma error bars), and the subtracted leakage, one panel per observed product."""
    n = len(corrected)
    units = corrected[0].attrs.get("units", "")
    fig, axes = new_figure(1, n, figsize=(5.2 * n, 4.4), squeeze=False,
                           constrained_layout=True)
    for i, c in enumerate(corrected):
        ax = axes[0, i]
        k = c["k"].values
        ok = c["counts_sph"].values > 0
        pi = c["power_I_obs_sph"].values
        corr, err = c["power_I_corrected_sph"].values, c["power_I_corrected_sph_err"].values
        leak = c["power_leak_sph"].values
        pos = ok & (pi > 0)
        ax.plot(k[pos], pi[pos], "k-", lw=1.2, label=r"observed $P_I$")
        pos = ok & (leak > 0)
        ax.plot(k[pos], leak[pos], "C3--", lw=1.2, label="expected leakage")
        pos = ok & (corr > 0)
        ax.errorbar(k[pos], corr[pos], yerr=np.minimum(err[pos], 0.999 * corr[pos]),
                    fmt="o", ms=3, color="C0", capsize=2, label=r"corrected $P_I$")
        neg = ok & (corr <= 0)
        if neg.any():
            ax.plot(k[neg], err[neg], "v", color="C0", mfc="none", ms=4,
                    label=r"corrected $\leq 0$ (1$\sigma$ shown)")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(r"$k$ [Mpc$^{-1}$]")
        if i == 0:
            ax.set_ylabel(f"$P(k)${_unit_tex(units)}")
        ax.set_title(f"{field_name + ' ' if field_name else ''}{c.attrs.get('label', '')}")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    return save_figure(fig, path, pdf=pdf)


def plot_observed(comparisons: Sequence[xr.Dataset], labels: Sequence[str],
                  path: str | os.PathLike, pdf: bool = True, title: str = "") -> Path:
    """2D panels per input: observed P_I, predicted leakage P_I (one colour scale for both)
    and their ratio, with the horizon wedge; the EoR-window ratio in the title."""
    n = len(comparisons)
    fig, axes = new_figure(n, 3, figsize=(12.5, 3.3 * n + 0.4), squeeze=False,
                           constrained_layout=True)
    for i, (c, label) in enumerate(zip(comparisons, labels)):
        xe, ye = _edges(c["k_perp"].values), _edges(c["k_par"].values)
        units = _unit_tex(c.attrs.get("units", ""))
        both = np.concatenate([c["power_observed"].values.ravel(),
                               c["power_leak"].values.ravel()])
        power_norm = _lognorm(both, np.isfinite(both))
        for j, (var, clabel) in enumerate((("power_observed", f"observed $P_I${units}"),
                                           ("power_leak", f"predicted leakage $P_I${units}"),
                                           ("ratio", "predicted / observed"))):
            ax = axes[i, j]
            ax.set_facecolor("0.8")
            vals = c[var].values
            ok = np.isfinite(vals) & (vals > 0)
            norm = power_norm if j < 2 else _lognorm(vals, ok, 0.5, 99.5)
            im = ax.pcolormesh(xe, ye, np.ma.masked_where(~ok, vals), norm=norm,
                               cmap="viridis" if j < 2 else "magma", shading="flat",
                               rasterized=True)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlim(xe[0], xe[-1])
            ax.set_ylim(ye[0], ye[-1])
            slope = float(c.attrs.get("wedge_slope_horizon", 0.0))
            if slope > 0:
                x = np.geomspace(xe[-1] / 1e3, xe[-1], 50)
                ax.plot(x, slope * x, color="k", ls="--", lw=1.6, label="horizon wedge")
                ax.plot(x, slope * x, color="w", ls="--", lw=0.7)
            _tidy_log_axis(ax.xaxis, xe[0], xe[-1])
            _tidy_log_axis(ax.yaxis, ye[0], ye[-1])
            fig.colorbar(im, ax=ax, pad=0.02).set_label(clabel)
            ax.set_xlabel(_KPERP)
            ax.set_ylabel(f"{label}\n{_KPAR}" if j == 0 else _KPAR)
            if j == 2:
                ratio = float(c.attrs["window_ratio"])
                ax.set_title(f"EoR window: {_number(ratio) if np.isfinite(ratio) else 'no'}"
                             " x the observed power")
    if title:
        fig.suptitle(title)
    return save_figure(fig, path, pdf=pdf)
