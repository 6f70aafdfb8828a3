"""Power-spectrum figures: 2D PS panels with wedge lines, 1D and spherical PS."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

from msleak.plot import new_figure, save_figure

__all__ = ["plot_ps2d", "plot_ps1d", "plot_ps_sph"]

_UNIT_TEX = {"mK^2 Mpc^3": r"mK$^2$ Mpc$^3$", "Jy^2": r"Jy$^2$", "mK^2": r"mK$^2$",
             "Jy^2 Mpc^-3": r"Jy$^2$ Mpc$^{-3}$"}


def _open(ps):
    if isinstance(ps, (str, os.PathLike)):
        from msleak.io.products import open_product

        return open_product(ps, "ps")
    return ps


def _edges(centres: np.ndarray) -> np.ndarray:
    c = np.asarray(centres, float)
    if c.size == 1:
        return np.array([c[0] * 0.9, c[0] * 1.1]) if c[0] > 0 else np.array([-0.5, 0.5])
    mid = 0.5 * (c[1:] + c[:-1])
    return np.concatenate([[c[0] - (mid[0] - c[0])], mid, [c[-1] + (c[-1] - mid[-1])]])


def _nice_log_ticks(axis, lo: float, hi: float) -> None:
    """Plain-number major ticks (1, 2, 5 x 10^n) within lo..hi, no minor labels."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullFormatter

    ticks = [m * 10.0 ** e for e in range(-4, 3) for m in (1, 2, 5) if lo <= m * 10.0 ** e <= hi]
    if len(ticks) >= 2:
        axis.set_major_locator(FixedLocator(ticks))
        axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        axis.set_minor_formatter(NullFormatter())


def plot_ps2d(ps, path, stokes: Sequence[str] = ("I", "Q", "U", "P"),
              quantity: str = "power", vmin: float | None = None, vmax: float | None = None,
              pdf: bool = False, title: str | None = None) -> Path:
    """2D PS (k_par vs k_perp), one panel per Stokes, log colour, both wedge lines.

    ``quantity`` is ``power`` (mK^2 Mpc^3 or Jy^2) or ``delta2`` (k_perp^2 k_par P/(2 pi)^2).
    The k_par = 0 row is drawn at half the first non-zero k_par (log axes).
    """
    from matplotlib.colors import LogNorm

    ds = _open(ps)
    data = ds[quantity]
    units = _UNIT_TEX.get(data.attrs.get("units", ""), data.attrs.get("units", ""))
    kperp_lo, kperp_hi = ds["k_perp_lo"].values, ds["k_perp_hi"].values
    kpar = ds["k_par"].values.copy()
    if kpar.size > 1 and kpar[0] == 0:
        kpar[0] = kpar[1] / 2
    x_edges = np.concatenate([kperp_lo, kperp_hi[-1:]])
    if x_edges[0] <= 0:
        x_edges[0] = x_edges[1] / 2
    y_edges = np.exp(_edges(np.log(kpar)))
    values = [data.sel(stokes=s).values for s in stokes]
    finite = np.concatenate([v[np.isfinite(v) & (v > 0)].ravel() for v in values] + [[1.0]])
    vmax = vmax or float(np.nanmax(finite))
    vmin = vmin or max(float(np.nanpercentile(finite, 2)), vmax * 1e-8)
    n = len(stokes)
    fig, axes = new_figure(1, n, figsize=(3.3 * n + 1.2, 3.6), sharey=True, squeeze=False,
                           constrained_layout=True)
    slopes = {"horizon": ds.attrs.get("wedge_slope_horizon"),
              "primary": ds.attrs.get("wedge_slope_primary")}
    xx = np.geomspace(x_edges[0], x_edges[-1], 50)
    mesh = None
    for ax, s, v in zip(axes[0], stokes, values):
        vv = np.where(np.isfinite(v) & (v > 0), v, np.nan)
        mesh = ax.pcolormesh(x_edges, y_edges, vv, norm=LogNorm(vmin=vmin, vmax=vmax),
                             cmap="viridis", shading="flat")
        for name, style in (("horizon", "-"), ("primary", "--")):
            if slopes[name]:
                label = ("horizon (90$^\\circ$)" if name == "horizon" else
                         f"primary ({ds.attrs.get('primary_theta_deg', 0):.1f}$^\\circ$)")
                if slopes[name] * x_edges[-1] < y_edges[0]:
                    label += ", below axis"
                ax.plot(xx, slopes[name] * xx, style, color="white", lw=1.6, label=label)
        ax.set_xscale("log")
        ax.set_yscale("log")
        _nice_log_ticks(ax.xaxis, x_edges[0], x_edges[-1])
        ax.set_xlim(x_edges[0], x_edges[-1])
        ax.set_ylim(y_edges[0], y_edges[-1])
        ax.set_title(f"Stokes {s}" if s != "P" else "P = Q + iU", fontsize=11)
        ax.set_xlabel(r"$k_\perp$ [Mpc$^{-1}$]")
    axes[0][0].set_ylabel(r"$k_\parallel$ [Mpc$^{-1}$]")
    axes[0][0].legend(loc="lower right", fontsize=8, framealpha=0.5)
    label = (r"$P(k_\perp, k_\parallel)$" if quantity == "power" else r"$\Delta^2$")
    fig.colorbar(mesh, ax=list(axes[0]), label=f"{label} [{units}]", pad=0.01)
    extra = (f"z = {ds.attrs.get('redshift', 0):.2f}, window {ds.attrs.get('window', '?')}"
             + (", cross-power" if ds.attrs.get("cross_power") else ""))
    fig.suptitle(f"{title}  ({extra})" if title else extra, fontsize=10)
    return save_figure(fig, path, pdf=pdf)


def _plot_spectra(ax, inputs, variable: str, coord: str, stokes, styles, positive_k: bool):
    """One line per (input, Stokes) of ``variable`` against ``coord``; colour per input,
    line style per Stokes. Returns the units and the last dataset plotted."""
    units, ds = "", None
    for i, item in enumerate(inputs):
        ps, label = item if isinstance(item, tuple) else (item, None)
        ds = _open(ps)
        label = label or Path(str(ds.attrs.get("source", f"input {i}"))).name
        units = ds[variable].attrs.get("units", units)
        k = ds[coord].values
        for j, s in enumerate(stokes):
            y = ds[variable].sel(stokes=s).values
            ok = np.isfinite(y) & (y > 0) & ((k > 0) if positive_k else True)
            ax.plot(k[ok], y[ok], styles[j % len(styles)], color=f"C{i}", marker="o", ms=3,
                    label=f"{label}: {s}")
    return units, ds


def plot_ps1d(inputs, path, stokes: Sequence[str] = ("Q", "U"), pdf: bool = False,
              title: str | None = None) -> Path:
    """1D PS versus k_par of several inputs on one axis.

    ``inputs``: a sequence of ps products/paths or ``(ps, label)`` pairs.
    """
    fig, ax = new_figure(figsize=(6, 4.2), constrained_layout=True)
    units, ds = _plot_spectra(ax, inputs, "power_1d", "k_par", stokes,
                              ["-", "--", ":", "-."], positive_k=True)
    kp = (ds.attrs.get("k_perp_min_1d"), ds.attrs.get("k_perp_max_1d"))
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(r"$k_\parallel$ [Mpc$^{-1}$]")
    ax.set_ylabel(f"$P(k_\\parallel)$ [{_UNIT_TEX.get(units, units)}]")
    ax.legend(fontsize=8)
    sub = f"{kp[0]:g} < $k_\\perp$ < {kp[1]:g} Mpc$^{{-1}}$" if kp[0] is not None else ""
    ax.set_title(f"{title}  ({sub})" if title else sub, fontsize=10)
    ax.grid(alpha=0.3, which="both")
    return save_figure(fig, path, pdf=pdf)


def plot_ps_sph(inputs, path, stokes: Sequence[str] = ("I",), pdf: bool = False,
                title: str | None = None) -> Path:
    """Spherically averaged PS of several inputs on one axis."""
    fig, ax = new_figure(figsize=(6, 4.2), constrained_layout=True)
    units, _ = _plot_spectra(ax, inputs, "power_sph", "k", stokes, ["-", "--", ":"],
                             positive_k=False)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(r"$k$ [Mpc$^{-1}$]")
    ax.set_ylabel(f"$P(k)$ [{_UNIT_TEX.get(units, units)}]")
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3, which="both")
    return save_figure(fig, path, pdf=pdf)
