"""Beam-map figure of ``msleak beam``: polarized beam and leakage in dB at several hour angles."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from msleak.plot import new_figure, save_figure

__all__ = ["plot_beam_maps"]


def _limits(values: np.ndarray, low_pct: float, floor: float, top: float | None = None):
    finite = values[np.isfinite(values) & (values > floor)]
    if finite.size == 0:
        return floor, 0.0
    lo = float(np.floor(np.percentile(finite, low_pct)))
    hi = float(np.ceil(finite.max())) if top is None else top
    return lo, max(hi, lo + 1)


def plot_beam_maps(ds, path: str | Path, *, title: str | None = None, pdf: bool = False,
                   invariant: bool = False) -> Path:
    """Two rows (polarized beam, leakage; dB) by one column per hour angle.

    Parameters
    ----------
    ds : xarray.Dataset
        From :func:`msleak.verbs.beam_maps.beam_maps`.
    path : path
        Output image (PNG; a PDF beside it if ``pdf``).
    title : str, optional
        Figure title; a default names the beam and frequency.
    invariant : bool
        Plot the Q,U-frame-invariant polarized beam instead of sqrt(M11^2 + M22^2).
    """
    nha = ds.sizes["hour_angle"]
    l_deg = ds["l"].values
    m_deg = ds["m"].values
    extent = (l_deg[0], l_deg[-1], m_deg[0], m_deg[-1])
    pb = ds["polarized_beam_invariant_db" if invariant else "polarized_beam_db"].values
    pb_label = ("polarized beam\n$\\sqrt{M_{11}^2+M_{12}^2+M_{21}^2+M_{22}^2}$ [dB]"
                if invariant else "polarized beam\n$\\sqrt{M_{11}^2+M_{22}^2}$ [dB]")
    lk = ds["leakage_db"].values
    pb_lim = _limits(pb, 1.0, -100.0, top=0.0)
    lk_lim = _limits(lk, 2.0, -100.0)
    has = ds["hour_angle"].values.astype(float)
    steps = np.abs(np.diff(has[np.isfinite(has)]))
    decimals = 1 if steps.size == 0 or steps.min() >= 0.2 else (2 if steps.min() >= 0.02 else 3)
    width = 2.55 * nha + 1.4
    fig, axes = new_figure(2, nha, figsize=(width, 5.9), squeeze=False, sharex=True,
                           sharey=True, constrained_layout=True)
    rows = [
        (pb, pb_lim, "viridis", pb_label, (-3, -10)),
        (lk, lk_lim, "magma", "leakage Q,U$\\rightarrow$I\n"
         "$\\sqrt{M_{01}^2+M_{02}^2}/M_{00}$ [dB]", (-30, -20)),
    ]
    for r, (data, (vmin, vmax), cmap, label, levels) in enumerate(rows):
        image = None
        for c in range(nha):
            ax = axes[r, c]
            image = ax.imshow(data[c], origin="lower", extent=extent, cmap=cmap, vmin=vmin,
                              vmax=vmax, interpolation="nearest", aspect="equal")
            lev = [v for v in levels if vmin < v < vmax]
            if lev:
                cs = ax.contour(l_deg, m_deg, data[c], levels=sorted(lev), colors="white",
                                linewidths=0.7, alpha=0.8)
                ax.clabel(cs, fmt="%d dB", fontsize=7)
            ax.plot(0, 0, marker="+", color="white", ms=7, mew=1.0)
            ax.tick_params(labelsize=8, direction="out")
            if r == 0:
                ha = round(float(has[c]), decimals) + 0.0   # no "-0.0"
                ax.set_title(f"HA = {ha:+.{decimals}f} h" if np.isfinite(ha) else f"time {c}",
                             fontsize=10)
            if r == 1:
                ax.set_xlabel("$l$ [deg] (East left)", fontsize=9)
            if c == 0:
                ax.set_ylabel("$m$ [deg] (North up)", fontsize=9)
        # astronomers' convention: East to the left
        axes[r, 0].set_xlim(extent[1], extent[0])
        bar = fig.colorbar(image, ax=list(axes[r, :]), shrink=0.95, pad=0.01, aspect=18)
        bar.set_label(label, fontsize=9)
        bar.ax.tick_params(labelsize=8)
    if title is None:
        title = (f"{ds.attrs.get('beam', '')} beam at {ds.attrs.get('freq_hz', 0) / 1e6:.2f} "
                 f"MHz, normalised to the phase centre "
                 f"(RA {ds.attrs.get('phase_centre_ra_deg', 0):.1f} deg, "
                 f"Dec {ds.attrs.get('phase_centre_dec_deg', 0):.1f} deg)")
    if not invariant and ds.attrs.get("qu_basis_description"):
        title += f"\n{ds.attrs['qu_basis_description']}"
    fig.suptitle(title, fontsize=11)
    return save_figure(fig, path, pdf=pdf, dpi=150)
