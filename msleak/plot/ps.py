"""Power-spectrum figures: 2D PS panels with wedge lines, 1D PS of several inputs
(docs/ps.md "Figures")."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

from msleak.io.products import open_product
from msleak.plot import new_figure, save_figure, uv_cell_text

__all__ = ["plot_ps2d", "plot_ps1d"]

_UNIT_TEX = {"mK^2 Mpc^3": r"mK$^2$ Mpc$^3$", "mK^2 h^-3 Mpc^3": r"mK$^2$ $h^{-3}$ Mpc$^3$",
             "Jy^2": r"Jy$^2$", "mK^2": r"mK$^2$", "Jy^2 Mpc^-3": r"Jy$^2$ Mpc$^{-3}$",
             "Jy^2 h^3 Mpc^-3": r"Jy$^2$ $h^3$ Mpc$^{-3}$", "Mpc^-1": r"Mpc$^{-1}$",
             "h Mpc^-1": r"$h$ Mpc$^{-1}$"}
#: percentiles of a panel's finite positive values that set its colour limits
_COLOUR_PERCENTILES = (1.0, 99.5)
#: how the inputs of a 1D PS figure are told apart: line style, open marker, and line
#: width and marker size shrinking from the first input on (overlapping curves stay visible)
_LINESTYLES = ("-", "--", ":", "-.")
_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")


def _open(ps):
    if isinstance(ps, (str, os.PathLike)):
        return open_product(ps, "ps")
    return ps


def _tex(unit: str) -> str:
    return _UNIT_TEX.get(unit, unit)


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


def describe_input(ds) -> str:
    """Field, uv cell size (:func:`~msleak.plot.uv_cell_text`) and column of a ps
    product, from its attributes."""
    attrs = ds.attrs
    name = attrs.get("field_name") or ", ".join(
        Path(part.strip()).name for part in str(attrs.get("source", "") or "?").split(";"))
    parts = [str(name)]
    if attrs.get("cell_lambda"):
        parts.append(uv_cell_text(float(attrs["cell_lambda"])))
    if attrs.get("column"):
        parts.append(f"column {attrs['column']}")
    return ", ".join(parts)


def colour_limits(values: np.ndarray) -> tuple[float, float, str]:
    """Log colour limits of one panel from its own finite positive values (percentiles
    ``_COLOUR_PERCENTILES``) and the colour bar's ``extend`` for values beyond them."""
    good = values[np.isfinite(values) & (values > 0)]
    if good.size == 0:
        return 1.0, 10.0, "neither"
    lo, hi = np.percentile(good, _COLOUR_PERCENTILES)
    if not hi > lo:
        lo, hi = lo / 2, hi * 2
    extend = {(False, False): "neither", (True, False): "min", (False, True): "max",
              (True, True): "both"}[(bool(good.min() < lo), bool(good.max() > hi))]
    return float(lo), float(hi), extend


def _wedges(ax, ds, xx: np.ndarray, y_lo: float) -> None:
    for name, style in (("horizon", "-"), ("primary", "--")):
        slope = ds.attrs.get(f"wedge_slope_{name}")
        if not slope:
            continue
        label = ("horizon (90$^\\circ$)" if name == "horizon" else
                 f"primary ({ds.attrs.get('primary_theta_deg', 0):.1f}$^\\circ$)")
        if slope * xx[-1] < y_lo:
            label += ", below axis"
        ax.plot(xx, slope * xx, style, color="white", lw=1.6, label=label)


def plot_ps2d(ps, path, stokes: Sequence[str] = ("I", "Q", "U", "P"),
              quantity: str = "power", pdf: bool = False, title: str | None = None) -> Path:
    """2D PS (k_par vs k_perp), one panel per Stokes with its own log colour scale
    (:func:`colour_limits`), both wedge lines; the title names field, uv cell size
    (:func:`~msleak.plot.uv_cell_text`) and column.

    ``quantity`` is ``power`` or ``delta2`` (k_perp^2 k_par P/(2 pi)^2). The k_par = 0 row
    is drawn at half the first non-zero k_par (log axes).
    """
    from matplotlib.colors import LogNorm

    ds = _open(ps)
    data = ds[quantity]
    units, k_units = _tex(data.attrs.get("units", "")), _tex(ds["k_par"].attrs.get("units", ""))
    bounds = ds["k_perp_bounds"].values
    x_edges = np.concatenate([bounds[:, 0], bounds[-1:, 1]])
    if x_edges[0] <= 0:
        x_edges[0] = x_edges[1] / 2
    kpar = ds["k_par"].values.copy()
    if kpar.size > 1 and kpar[0] == 0:
        kpar[0] = kpar[1] / 2
    y_edges = np.exp(_edges(np.log(kpar)))
    n = len(stokes)
    fig, axes = new_figure(1, n, figsize=(3.6 * n + 0.6, 3.8), sharey=True, squeeze=False,
                           constrained_layout=True)
    xx = np.geomspace(x_edges[0], x_edges[-1], 50)
    label = r"$P(k_\perp, k_\parallel)$" if quantity == "power" else r"$\Delta^2$"
    for ax, s in zip(axes[0], stokes):
        v = data.sel(stokes=s).values
        lo, hi, extend = colour_limits(v)
        good = np.isfinite(v) & (v > 0)
        mesh = ax.pcolormesh(x_edges, y_edges, np.where(good, v, np.nan),
                             norm=LogNorm(vmin=lo, vmax=hi), cmap="viridis", shading="flat")
        if good.any():
            fig.colorbar(mesh, ax=ax, extend=extend, pad=0.01, label=f"{label} [{units}]")
        else:
            ax.text(0.5, 0.5, "no positive power", transform=ax.transAxes, ha="center")
        _wedges(ax, ds, xx, y_edges[0])
        ax.set_xscale("log")
        ax.set_yscale("log")
        _nice_log_ticks(ax.xaxis, x_edges[0], x_edges[-1])
        ax.set_xlim(x_edges[0], x_edges[-1])
        ax.set_ylim(y_edges[0], y_edges[-1])
        ax.set_title(f"Stokes {s}" if s != "P" else "P = Q + iU", fontsize=11)
        ax.set_xlabel(rf"$k_\perp$ [{k_units}]")
    axes[0][0].set_ylabel(rf"$k_\parallel$ [{k_units}]")
    axes[0][0].legend(loc="lower right", fontsize=8, framealpha=0.5)
    extra = (f"{describe_input(ds)}; z = {ds.attrs.get('redshift', 0):.2f}, window "
             f"{ds.attrs.get('window', '?')}" + (", cross-power" if ds.attrs.get("cross_power")
                                                 else ""))
    fig.suptitle(f"{title}  ({extra})" if title else extra, fontsize=10)
    return save_figure(fig, path, pdf=pdf)


def plot_ps1d(inputs, path, stokes: Sequence[str] = ("Q", "U"), pdf: bool = False,
              title: str | None = None) -> Path:
    """1D PS versus k_par of several inputs on one axis: each input its own line style,
    open marker, line width and marker size, each Stokes its own colour, so curves of
    different inputs stay apart where they overlap. When the MS had rows whose baseline
    crosses the uv-range limits within the band (``n_rows_crossing_uv_range``), a note
    says that they set a floor at high k_par (docs/ps.md, "A floor from the uv range").

    ``inputs``: a sequence of ps products/paths or ``(ps, label)`` pairs.
    """
    fig, ax = new_figure(figsize=(6, 4.2), constrained_layout=True)
    units, ds, crossing = "", None, 0
    for i, item in enumerate(inputs):
        ps, label = item if isinstance(item, tuple) else (item, None)
        ds = _open(ps)
        crossing = max(crossing, int(ds.attrs.get("n_rows_crossing_uv_range", 0) or 0))
        label = label or describe_input(ds)
        units = ds["power_1d"].attrs.get("units", units)
        k = ds["k_par"].values
        for j, s in enumerate(stokes):
            y = ds["power_1d"].sel(stokes=s).values
            ok = np.isfinite(y) & (y > 0) & (k > 0)
            ax.plot(k[ok], y[ok], _LINESTYLES[i % len(_LINESTYLES)], color=f"C{j}",
                    lw=max(0.8, 2.4 - 0.6 * i), marker=_MARKERS[i % len(_MARKERS)],
                    ms=max(3.0, 8.0 - 2.0 * i), mfc="none", label=f"{label}: {s}")
    k_units = _tex(ds["k_par"].attrs.get("units", "")) if ds is not None else ""
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(rf"$k_\parallel$ [{k_units}]")
    ax.set_ylabel(f"$P(k_\\parallel)$ [{_tex(units)}]")
    ax.legend(fontsize=8)
    kp = (ds.attrs.get("k_perp_min_1d"), ds.attrs.get("k_perp_max_1d")) if ds is not None \
        else (None, None)
    sub = f"{kp[0]:g} < $k_\\perp$ < {kp[1]:g} {k_units}" if kp[0] is not None else ""
    ax.set_title(f"{title}  ({sub})" if title else sub, fontsize=10)
    ax.grid(alpha=0.3, which="both")
    if crossing:
        ax.text(0.98, 0.55, f"{crossing} rows (baseline x time) cross the\nuv-range limits "
                "within the band: in their\ncells a step in frequency sets a floor\nat high "
                "$k_\\parallel$ (docs/ps.md)", transform=ax.transAxes, fontsize=7,
                color="0.3", ha="right", va="top",
                bbox=dict(facecolor="white", edgecolor="none", alpha=0.8))
    return save_figure(fig, path, pdf=pdf)
