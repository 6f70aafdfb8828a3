"""The delay-transform verb, uvcube -> delay product (docs/transform.md).

:func:`transform` is the verb behind ``msleak transform``; it wraps the pure transform of
:mod:`msleak.ps.delay`. :func:`load_input` checks the input products of this verb and of
:mod:`msleak.verbs.power`.
"""

from __future__ import annotations

import os
from typing import Iterable

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
from msleak.ps.delay import Partial, delay_dataset

__all__ = ["transform", "load_input"]

#: what transform needs of a uvcube: variables (coordinates included), attributes
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

