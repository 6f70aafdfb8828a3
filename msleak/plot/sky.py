"""Figures of sky cubes: Q and U slices, one pixel's spectrum, angular PS of P."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from msleak.errors import InputError
from msleak.plot import new_figure, save_figure
from msleak.sky.analysis import angular_power_spectrum
from msleak.sky.cube import SkyCube, pixel_size_deg

__all__ = ["plot_sky_cube"]


def plot_sky_cube(cube: SkyCube, path, *, channel: int = 0,
                  pixel: tuple[int, int] | None = None, pdf: bool = False) -> Path:
    """Four panels: Q and U at one channel, the Q/U/|P| spectrum of one pixel, and the
    angular power spectrum of P = Q + iU at that channel (docs/science.md section 8).

    Parameters
    ----------
    cube : the cube (any units; axes labelled with them)
    path : output figure (PNG or PDF)
    channel : 0-based channel of the slices and the power spectrum
    pixel : (x, y) 0-based pixel of the spectrum panel (default the grid centre)
    """
    nchan = cube.data.shape[1]
    ny, nx = cube.npix
    if not 0 <= channel < nchan:
        raise InputError(f"--plot-channel {channel} is outside 0..{nchan - 1}")
    if pixel is None:
        pixel = (nx // 2, ny // 2)
    px, py = pixel
    if not (0 <= px < nx and 0 <= py < ny):
        raise InputError(f"--plot-pixel {px},{py} is outside the {nx}x{ny} grid")
    q, u = cube.plane("Q"), cube.plane("U")
    unit = cube.units
    dx, dy = pixel_size_deg(cube)
    crpix = cube.wcs.wcs.crpix
    # projection-plane offsets from the reference, deg (l to the east = left)
    extent = [(-0.5 - (crpix[0] - 1)) * -dx, (nx - 0.5 - (crpix[0] - 1)) * -dx,
              (-0.5 - (crpix[1] - 1)) * dy, (ny - 0.5 - (crpix[1] - 1)) * dy]
    ra0, dec0 = cube.wcs.wcs.crval[:2]
    fmhz = cube.freq / 1e6

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
        lx = (px - (crpix[0] - 1)) * -dx
        ly = (py - (crpix[1] - 1)) * dy
        ax.plot([lx], [ly], marker="s", mfc="none", mec="k", ms=8)

    ax = axes[1, 0]
    ax.plot(fmhz, q[:, py, px], "-o", ms=3, label="Q")
    ax.plot(fmhz, u[:, py, px], "-o", ms=3, label="U")
    ax.plot(fmhz, np.hypot(q[:, py, px], u[:, py, px]), "k--", label="|P|")
    ax.axhline(0, color="0.6", lw=0.8)
    ax.set_xlabel("frequency (MHz)")
    ax.set_ylabel(f"brightness ({unit})")
    ax.set_title(f"spectrum of pixel x={px}, y={py} (square in the maps)")
    ax.legend(loc="best")

    ax = axes[1, 1]
    pixel_rad = math.radians(0.5 * (dx + dy))
    ell, cl, d_ell = angular_power_spectrum(q[channel] + 1j * u[channel], pixel_rad,
                                            nbins=max(4, min(12, min(nx, ny) // 3)))
    good = np.isfinite(d_ell) & (d_ell > 0)
    ax.loglog(ell[good], d_ell[good], "o-", color="C3")
    ax.set_xlabel(r"multipole $\ell$")
    ax.set_ylabel(rf"$\ell(\ell+1)C_\ell/2\pi$ of P ({unit}$^2$)")
    ax.set_title(f"angular power spectrum of P = Q + iU at {fmhz[channel]:.3f} MHz")
    ax.grid(True, which="both", alpha=0.3)

    fig.suptitle(f"sky cube: {nx}x{ny} pixels of {dx * 60:.3g}' about RA {ra0:.3f}, "
                 f"Dec {dec0:.3f} deg; {nchan} channels {fmhz[0]:.3f}-{fmhz[-1]:.3f} MHz")
    fig.tight_layout()
    return save_figure(fig, path, pdf=pdf)
