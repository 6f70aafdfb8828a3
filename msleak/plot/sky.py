"""Figures of sky cubes: Q and U slices, one pixel's spectrum, angular PS of P."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import xarray as xr
from astropy.io import fits

from msleak.errors import InputError
from msleak.plot import new_figure, save_figure
from msleak.sky.spectrum import angular_power_spectrum

__all__ = ["plot_sky"]

#: multipoles labelled on the angular power spectrum's axis
_ELL_TICKS = (10, 20, 30, 50, 100, 200, 300, 500, 1000, 2000, 3000, 5000, 10000)


def plot_sky(ds: xr.Dataset, path, *, channel: int = 0,
             pixel: tuple[int, int] | None = None) -> Path:
    """Four panels: Q and U at one channel, the Q/U/|P| spectrum of one pixel, and the
    angular power spectrum of P = Q + iU at that channel (docs/sky.md, "Figures").

    Parameters
    ----------
    ds : sky Dataset (:func:`msleak.make_sky`; any units, axes labelled with them)
    path : output figure, format from the suffix (.png, .pdf)
    channel : 0-based channel of the slices and the power spectrum
    pixel : (x, y) 0-based pixel of the spectrum panel (default the grid centre)
    """
    nchan, ny, nx = ds.sizes["freq"], ds.sizes["y"], ds.sizes["x"]
    if not 0 <= channel < nchan:
        raise InputError(f"channel {channel} is outside 0..{nchan - 1}", param="channel")
    px, py = (nx // 2, ny // 2) if pixel is None else pixel
    if not (0 <= px < nx and 0 <= py < ny):
        raise InputError(f"pixel {px},{py} is outside the {nx}x{ny} grid", param="pixel")
    zero = np.zeros((nchan, ny, nx))
    q, u = (ds[s].transpose("freq", "y", "x").values if s in ds else zero for s in "QU")
    unit = ds.attrs["units"]
    header = fits.Header.fromstring(ds.attrs["fits_header"], sep="\n")
    dx, dy = abs(header["CDELT1"]), abs(header["CDELT2"])
    x, y = ds["x"].values, ds["y"].values
    sx, sy = np.sign(header["CDELT1"]), np.sign(header["CDELT2"])
    extent = [x[0] - sx * dx / 2, x[-1] + sx * dx / 2, y[0] - sy * dy / 2, y[-1] + sy * dy / 2]
    fmhz = ds["freq"].values / 1e6

    fig, axes = new_figure(2, 2, figsize=(11, 9.2))
    lim = float(np.max(np.abs(np.concatenate([q[channel].ravel(), u[channel].ravel()])))) or 1
    for ax, data, label in ((axes[0, 0], q, "Q"), (axes[0, 1], u, "U")):
        im = ax.imshow(data[channel], origin="lower", extent=extent, cmap="RdBu_r",
                       vmin=-lim, vmax=lim, interpolation="nearest")
        ax.set_xlim(extent[0], extent[1])
        ax.set_xlabel("l offset (deg, east to the left)")
        ax.set_ylabel("m offset (deg)")
        ax.set_title(f"Stokes {label} at {fmhz[channel]:.3f} MHz")
        fig.colorbar(im, ax=ax, label=f"{label} ({unit})", shrink=0.85)
        ax.plot([x[px]], [y[py]], marker="s", mfc="none", mec="k", ms=8)

    ax = axes[1, 0]
    ax.plot(fmhz, q[:, py, px], "-o", ms=3, label="Q")
    ax.plot(fmhz, u[:, py, px], "-o", ms=3, label="U")
    ax.plot(fmhz, np.hypot(q[:, py, px], u[:, py, px]), "k--", label="|P|")
    ax.axhline(0, color="0.6", lw=0.8)
    ax.set_xlabel("frequency (MHz)")
    ax.set_ylabel(f"brightness ({unit})")
    ax.set_title(f"spectrum of pixel x={px}, y={py} (square in the maps)")
    ax.legend(loc="best")

    _angular_panel(axes[1, 1], q[channel] + 1j * u[channel], math.radians(0.5 * (dx + dy)),
                   unit, fmhz[channel])
    fig.suptitle(f"sky cube: {nx}x{ny} pixels of {dx * 60:.3g}' about RA "
                 f"{header['CRVAL1']:.3f}, Dec {header['CRVAL2']:.3f} deg; {nchan} channels "
                 f"{fmhz[0]:.3f}-{fmhz[-1]:.3f} MHz")
    fig.tight_layout()
    return save_figure(fig, path)


def _angular_panel(ax, p_map: np.ndarray, pixel_rad: float, unit: str, fmhz: float) -> None:
    """l(l+1)C_l/2pi of P on log axes, the multipole axis labelled with plain numbers."""
    from matplotlib.ticker import FixedLocator, NullFormatter, StrMethodFormatter

    ny, nx = p_map.shape
    ell, _, d_ell = angular_power_spectrum(p_map, pixel_rad,
                                           nbins=max(4, min(12, min(nx, ny) // 3)))
    good = np.isfinite(d_ell) & (d_ell > 0)
    ax.loglog(ell[good], d_ell[good], "o-", color="C3")
    ax.xaxis.set_major_locator(FixedLocator(_ELL_TICKS))
    ax.xaxis.set_major_formatter(StrMethodFormatter("{x:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel(r"multipole $\ell$")
    ax.set_ylabel(rf"$\ell(\ell+1)C_\ell/2\pi$ of P ({unit}$^2$)")
    ax.set_title(f"angular power spectrum of P = Q + iU at {fmhz:.3f} MHz")
    ax.grid(True, which="both", alpha=0.3)
