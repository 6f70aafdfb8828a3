"""The delay-transform stage, uvcube -> delay product (docs/transform.md).

:func:`transform` is the verb behind ``msleak transform``; it wraps the pure transform of
:mod:`msleak.ps.delay`. :func:`load_input` and :func:`refuse_existing` check the inputs
and outputs of this stage and of :mod:`msleak.ps.power`.
"""

from __future__ import annotations

import os
from typing import Iterable, Literal

import numpy as np
import xarray as xr

from msleak.errors import InputError
from msleak.io.products import (
    call_record,
    history_lines,
    open_product,
    refuse_existing,
    save_product,
    stamp,
)
from msleak.ps.delay import FFT_CONVENTION, delay_axis, delay_transform, spectral_window

__all__ = ["transform", "delay_dataset", "load_input", "refuse_existing"]

#: what transform and ps need of a uvcube: variables (coordinates included), attributes
#: cells empty in some unflagged channels: dropped, or those channels filled with zeros
Partial = Literal["drop", "zero"]

UVCUBE_VARIABLES = ("vis", "weight", "stokes", "freq", "v", "u")
UVCUBE_ATTRS = ("cell_lambda", "uv_min_lambda", "uv_max_lambda")


def load_input(item, kind: str, variables: Iterable[str], attrs: Iterable[str],
               maker: str) -> xr.Dataset:
    """A product of ``kind`` from a path, or an in-memory Dataset, with every variable
    and attribute the stage needs (one InputError naming all that are missing)."""
    if isinstance(item, (str, os.PathLike)):
        ds, label = open_product(item, kind, required=variables), str(item)
    elif isinstance(item, xr.Dataset):
        ds, label = item, f"the {kind} Dataset"
    else:
        raise InputError(f"a {kind} input must be a product path or an xarray.Dataset, "
                         f"got {type(item).__name__}")
    variables = list(variables)
    if "vis_a" in ds.variables:
        variables += ["vis_b"] + (["weight_a", "weight_b"] if kind == "uvcube" else [])
    lacks = [f"variable {v}" for v in variables if v not in ds.variables]
    lacks += [f"attribute {a}" for a in attrs if a not in ds.attrs]
    if lacks:
        raise InputError(f"{label} lacks {', '.join(lacks)}; make it with `{maker}` "
                         f"(docs/products.md '{kind}')")
    return ds


def transform(grid: str | os.PathLike | xr.Dataset, *, window: str = "blackman-harris",
              partial: Partial = "drop",
              output: str | os.PathLike | None = None, overwrite: bool = False) -> xr.Dataset:
    """Delay-transform every uv cell of a uv cube (``msleak transform``).

    Parameters
    ----------
    grid : path or xarray.Dataset
        A uvcube product (docs/products.md "uvcube"): ``vis`` (stokes, freq, v, u) complex
        Jy, ``weight`` (freq, v, u), coordinates ``stokes``, ``freq`` (Hz, evenly spaced),
        ``v``, ``u`` (wavelengths), attributes ``cell_lambda``, ``uv_min_lambda``,
        ``uv_max_lambda`` (wavelengths); optional halves ``vis_a``, ``vis_b`` with
        ``weight_a``, ``weight_b``.
    window : str
        Spectral window: ``none``, ``blackman-harris``, ``hann``, ... (docs/transform.md).
    partial : {"drop", "zero"}
        Cells empty in some unflagged channels: drop them, or fill those channels with 0.
    output : path, optional
        Also write the delay product there (refused if it exists, unless ``overwrite``).
    overwrite : bool
        Replace an existing ``output``.

    Returns
    -------
    xarray.Dataset
        The delay product: ``vis`` (stokes, delay, v, u) complex Jy (and ``vis_a``,
        ``vis_b``), ``weight`` (v, u), ``window_values`` (freq), coordinate ``delay`` (s).
    """
    command = call_record(transform, dict(locals()))
    refuse_existing(output, overwrite)
    uv = load_input(grid, "uvcube", UVCUBE_VARIABLES, UVCUBE_ATTRS, "msleak grid")
    ds = stamp(delay_dataset(uv, window, partial), command, history_lines(uv.attrs))
    if output is not None:
        save_product(ds, output, "delay", overwrite=overwrite)
    return ds


def delay_dataset(uv: xr.Dataset, window: str = "blackman-harris",
                  partial: Partial = "drop") -> xr.Dataset:
    """The delay Dataset of a checked uvcube Dataset (see :func:`transform`)."""
    freq = uv["freq"].values
    nchan = freq.size
    if nchan < 2:
        raise InputError(f"the uv cube has {nchan} channel(s); a delay transform needs >= 2")
    dnu = float(np.median(np.diff(freq)))
    if not np.allclose(np.diff(freq), dnu, rtol=1e-6, atol=0):
        raise InputError("the uv cube channels are not evenly spaced")
    win = spectral_window(window, nchan)
    weight = uv["weight"].values
    if "vis_a" in uv:  # halves: a cell must hold data in both halves to be used
        weight = np.where((uv["weight_a"].values > 0) & (uv["weight_b"].values > 0), weight, 0)
    out = {}
    cell_weight = window_norm = chan_ok = None
    for name in [n for n in ("vis", "vis_a", "vis_b") if n in uv]:
        vt, cell_weight, window_norm, chan_ok = delay_transform(
            uv[name].values, weight, win, partial=partial)
        out[name] = (("stokes", "delay", "v", "u"), vt, {"units": uv[name].attrs.get("units",
                                                                                    "Jy")})
    out["weight"] = (("v", "u"), cell_weight, {"units": "1",
                                               "long_name": "sum of weights over channels"})
    out["window_values"] = (("freq",), win * chan_ok, {"units": "1"})
    ds = xr.Dataset(out, coords={
        "stokes": uv["stokes"].values, "delay": ("delay", delay_axis(nchan, dnu), {"units": "s"}),
        "v": ("v", uv["v"].values, {"units": "wavelengths"}),
        "u": ("u", uv["u"].values, {"units": "wavelengths"}),
        "freq": ("freq", freq, {"units": "Hz"})})
    ds.attrs.update(uv.attrs)
    for key in ("msleak_product", "created", "command"):
        ds.attrs.pop(key, None)
    ds.attrs.update({
        "window": window.lower(), "window_norm": window_norm,
        "window_norm_definition": "sum(window^2 * channel_mask) / nchan",
        "freq_centre_hz": float(0.5 * (freq[0] + freq[-1])), "bandwidth_hz": nchan * dnu,
        "nchan": nchan, "channel_width_hz": dnu, "fft_convention": FFT_CONVENTION,
        "flagged_channels": int((~chan_ok).sum()), "empty_cell_policy": partial,
        "n_cells_used": int((cell_weight > 0).sum()),
    })
    if ds.attrs["n_cells_used"] == 0:
        raise InputError("no uv cell holds data in every channel; try --partial zero or a "
                         "wider uv range")
    return ds
