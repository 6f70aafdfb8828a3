"""The power-spectrum verb, delay product -> ps product (docs/ps.md, docs/products.md "ps").

:func:`power_spectrum` is the verb behind ``msleak ps``; it wraps the spectra of
:mod:`msleak.ps.spectra` and the conversions of :mod:`msleak.ps.cosmology`, and draws the
2D PS (:mod:`msleak.plot.ps`).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np
import xarray as xr

from msleak.errors import InputError
from msleak.io.products import call_record, history_lines, refuse_existing, save_product, stamp
from msleak.plot import figure_formats
from msleak.plot.ps import plot_ps2d
from msleak.ps.cosmology import cosmo_at, describe, make_cosmology
from msleak.ps.spectra import (DEFAULT_KPERP_1D, perp_edges, ps_attrs, spectra, to_little_h,
                                voxels)
from msleak.verbs.transform import load_input

if TYPE_CHECKING:
    from astropy.cosmology import Cosmology

__all__ = ["power_spectrum"]

#: what ps needs of a delay product: variables (coordinates included), attributes
DELAY_VARIABLES = ("vis", "weight", "stokes", "delay", "v", "u")
DELAY_ATTRS = ("cell_lambda", "uv_min_lambda", "uv_max_lambda", "freq_centre_hz",
               "bandwidth_hz", "window_norm")

#: attributes of the delay product the ps product keeps
KEEP_ATTRS = ("cell_lambda", "uv_min_lambda", "uv_max_lambda", "source", "source_kind",
              "column", "field_id", "field_name", "gridder", "w_correction", "fov_deg", "taper",
              "primary_fwhm_deg", "beam_area_model", "window", "window_norm", "freq_centre_hz",
              "bandwidth_hz", "nchan", "channel_width_hz", "fft_convention",
              "stokes_convention", "split", "empty_cell_policy", "correlations",
              "stokes_missing", "n_rows_crossing_uv_range", "history")


def power_spectrum(delay: str | os.PathLike | xr.Dataset, *,
                   cosmology: str | Cosmology | None = None,
                   h0: float | None = None, om0: float | None = None,
                   ob0: float | None = None, tcmb0: float | None = None,
                   little_h: bool = False, bins: int | None = None,
                   bin_width: float | None = None, log_bins: bool = False, sph_bins: int = 12,
                   kperp_1d: tuple[float, float] | None = None,
                   primary_theta: float | None = None, beam_area: float | None = None,
                   cross: bool | None = None, plot: str | os.PathLike | None = None,
                   stokes: str | Sequence[str] = ("I", "Q", "U", "P"),
                   output: str | os.PathLike | None = None, overwrite: bool = False
                   ) -> xr.Dataset:
    """Cylindrical, spherical and 1D power spectra of a delay cube (``msleak ps``).

    Parameters
    ----------
    delay : path or xarray.Dataset
        A delay product (``msleak transform``, docs/products.md "delay").
    cosmology : str or astropy cosmology, optional
        Realisation name (default Planck18); or ``h0`` (km/s/Mpc) and ``om0``, with
        optional ``ob0`` and ``tcmb0`` (K), for a flat LambdaCDM.
    little_h : bool
        k in h Mpc^-1 and P in mK^2 h^-3 Mpc^3 (``kperp_1d`` then in h Mpc^-1 too).
    bins, bin_width, log_bins : int, float (wavelengths), bool
        |b| (k_perp) bins over the uv range: ``bins`` of them (default one per cell),
        logarithmic with ``log_bins``; or linear bins ``bin_width`` wide.
    sph_bins : int
        Logarithmic bins of the spherical average.
    kperp_1d : (min, max), optional
        k_perp range of the 1D PS (default 0.02-0.1 Mpc^-1).
    primary_theta : float, optional
        Angle (deg) of the primary wedge (default half the cube's ``primary_fwhm_deg``,
        else half its ``fov_deg``).
    beam_area : float, optional
        Omega (sr) for mK^2 Mpc^3 (default the cube's ``beam_area_sr``).
    cross : bool, optional
        Cross-power of the halves ``vis_a``, ``vis_b`` (default: when the cube has them).
    plot, stokes : path, Stokes labels
        Also draw the 2D PS of these Stokes panels (format from the suffix).
    output, overwrite : path, bool
        Also write the ps product; existing ``output`` and ``plot`` files are refused
        unless ``overwrite``.

    Returns
    -------
    xarray.Dataset
        The ps product (docs/products.md "ps"): ``power`` (stokes, k_par, k_perp),
        ``power_sph`` (stokes, k), ``power_1d`` (stokes, k_par), ``power3d``
        (stokes, delay3d, cell), ... in mK^2 Mpc^3 (Jy^2 without a beam area).
    """
    command = call_record(power_spectrum, dict(locals()))
    refuse_existing(output, overwrite)
    _check_figure(plot, overwrite)
    _check_options(bins, sph_bins, kperp_1d, primary_theta, beam_area)
    astro = make_cosmology(cosmology, h0=h0, om0=om0, ob0=ob0, tcmb0=tcmb0)
    dl = load_input(delay, "delay", DELAY_VARIABLES, DELAY_ATTRS, "msleak transform")
    panels = _plot_stokes(stokes, dl) if plot is not None else []
    cosmo = cosmo_at(dl.attrs["freq_centre_hz"], astro)
    h = cosmo.h if little_h else 1.0
    k_range = DEFAULT_KPERP_1D if kperp_1d is None else (kperp_1d[0] * h, kperp_1d[1] * h)
    edges_b, log_bins = perp_edges(dl.attrs, bins, log_bins, bin_width)
    vox = voxels(dl, cross)
    omega = float(beam_area or dl.attrs.get("beam_area_sr") or 0.0)
    ds, factor = spectra(dl, vox, cosmo, edges_b, omega, sph_bins, k_range)
    ds.attrs.update({k: dl.attrs[k] for k in KEEP_ATTRS if k in dl.attrs})
    ds.attrs.update(describe(astro))
    ds.attrs.update(ps_attrs(dl.attrs, cosmo, factor, omega, primary_theta, vox.cross))
    ds.attrs.update({"k_perp_min_1d": k_range[0], "k_perp_max_1d": k_range[1],
                     "k_perp_binning": "log" if log_bins else "linear", "little_h": 0})
    if little_h:
        ds = to_little_h(ds, cosmo.h)
    ds = stamp(ds, command, history_lines(dl.attrs))
    if output is not None:
        save_product(ds, output, "ps", overwrite=overwrite)
    if plot is not None:
        plot_ps2d(ds, plot, stokes=panels)
    return ds


def _check_figure(plot, overwrite: bool) -> None:
    if plot is None:
        return
    refuse_existing(plot, overwrite)

    suffix = Path(plot).suffix.lower().lstrip(".")
    if suffix not in figure_formats():
        raise InputError(f"plot {plot}: unknown figure format {suffix!r}; end the name in "
                         ".png, .pdf or .svg", param="plot")


def _check_options(bins, sph_bins, kperp_1d, primary_theta, beam_area) -> None:
    for name, n in (("bins", bins), ("sph_bins", sph_bins)):
        if n is not None and not (isinstance(n, (int, np.integer)) and n >= 1):
            raise InputError(f"{name} {n}: must be a whole number >= 1", param=name)
    if kperp_1d is not None and not (len(kperp_1d) == 2 and 0 <= kperp_1d[0] < kperp_1d[1]):
        raise InputError(f"kperp_1d {','.join(f'{k:g}' for k in kperp_1d)}: need "
                         "0 <= MIN < MAX", param="kperp_1d")
    if primary_theta is not None and not 0 <= primary_theta <= 90:
        raise InputError(f"primary_theta {primary_theta:g}: must be within 0..90 degrees",
                         param="primary_theta")
    if beam_area is not None and not (math.isfinite(beam_area) and beam_area > 0):
        raise InputError(f"beam_area {beam_area:g}: must be a positive solid angle in sr",
                         param="beam_area")


def _plot_stokes(stokes: str | Sequence[str], dl: xr.Dataset) -> list[str]:
    """The ``stokes`` panels, checked against the cube's Stokes labels."""
    items = stokes.split(",") if isinstance(stokes, str) else stokes
    labels = [str(s).strip().upper() for s in items if str(s).strip()]
    have = [str(s) for s in dl["stokes"].values]
    bad = [s for s in labels if s not in have]
    if bad or not labels:
        raise InputError(f"stokes {','.join(bad) or '(empty)'}: not in the delay cube "
                         f"(it has {','.join(have)})", param="stokes")
    return labels
