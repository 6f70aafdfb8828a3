"""The figure of ``msleak forecast``: median L_I and the EoR-window L_I of each telescope,
with the scatter over sky realisations."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

from msleak.plot import new_figure, save_figure

__all__ = ["plot_forecast", "plot_extents"]


def plot_forecast(rows: Sequence[dict], path: str | os.PathLike, pdf: bool = True) -> Path:
    """One point per telescope and statistic (keys of :func:`msleak.study.forecast`'s
    rows: ``median``, ``window`` and their ``*_scatter``), error bars the realisation
    scatter, log L_I axis."""
    fig, ax = new_figure(figsize=(6.4, 3.6))
    x = np.arange(len(rows))
    styles = (("median", "median over voxels", "o", "-0.08"),
              ("window", "EoR window (above the horizon wedge)", "s", "0.08"))
    for key, label, marker, shift in styles:
        y = np.array([r[key] for r in rows], dtype=float)
        err = np.array([r[f"{key}_scatter"] for r in rows], dtype=float)
        ok = np.isfinite(y) & (y > 0)
        ax.errorbar(x[ok] + float(shift), y[ok], yerr=err[ok], fmt=marker, capsize=3,
                    label=label)
    ax.set_xticks(x, [f"{r['label']}\n{r['band_mhz']} MHz" for r in rows], fontsize=8)
    ax.set_yscale("log")
    ax.set_ylabel(r"$L_I$ [%]")
    n = rows[0]["realisations"] if rows else 0
    ax.set_title(f"Leakage Q,U $\\to$ I, {n} sky realisation{'s' if n != 1 else ''}")
    ax.grid(True, which="both", axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    return save_figure(fig, path, pdf=pdf)


def plot_extents(rows: Sequence[dict], path: str | os.PathLike, pdf: bool = True) -> Path:
    """L_I against the sky's extent, one line per array and field (``name``): the median over the voxels
    (left) and the EoR-window L_I (right), error bars the realisation scatter."""
    fig, axes = new_figure(1, 2, figsize=(9.0, 3.6), sharex=True)
    names = list(dict.fromkeys(r["name"] for r in rows))
    for key, ax, title in (("median", axes[0], "median over voxels"),
                           ("window", axes[1], "EoR window (above the horizon wedge)")):
        for name in names:
            mine = [r for r in rows if r["name"] == name]
            x = np.array([r["extent_deg"] for r in mine], dtype=float)
            y = np.array([r[key] for r in mine], dtype=float)
            err = np.array([r[f"{key}_scatter"] for r in mine], dtype=float)
            ok = np.isfinite(y) & (y > 0)
            ax.errorbar(x[ok], y[ok], yerr=err[ok], fmt="o-", capsize=3,
                        label=mine[0]["label"])
        ax.set_yscale("log")
        ax.set_xlabel("extent of the sky [deg from the phase centre]")
        ax.set_title(title, fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel(r"$L_I$ [%]")
    axes[0].legend(fontsize=8)
    return save_figure(fig, path, pdf=pdf)
