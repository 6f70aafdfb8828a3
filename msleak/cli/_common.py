"""Small helpers shared by the command modules (option parsing, messages)."""

from __future__ import annotations

from typing import Sequence

import click

from msleak.errors import InputError
from msleak.parallel.runner import parse_memory

__all__ = ["parse_float_list", "FloatList", "MemorySize", "cosmology_options"]


def parse_float_list(text: str, n: int | None = None, name: str = "value") -> list[float]:
    """Parse ``"a,b,c"`` into floats, optionally requiring exactly ``n`` of them."""
    try:
        values = [float(part) for part in text.split(",") if part.strip() != ""]
    except ValueError:
        raise click.BadParameter(f"{text!r} is not a comma-separated list of numbers") from None
    if n is not None and len(values) != n:
        raise click.BadParameter(f"expected {n} comma-separated numbers for {name}, got {text!r}")
    return values


class FloatList(click.ParamType):
    """A click type for ``a,b,...`` lists of floats (optionally of fixed length)."""

    name = "LIST"

    def __init__(self, n: int | None = None):
        self.n = n

    def convert(self, value, param, ctx) -> Sequence[float]:
        if isinstance(value, (list, tuple)):
            return list(value)
        try:
            return parse_float_list(value, self.n, param.name if param else "value")
        except click.BadParameter as err:
            self.fail(err.message, param, ctx)


class MemorySize(click.ParamType):
    """A click type for memory sizes (``2GB``, ``512MB``, ``4e9``), converted to bytes."""

    name = "SIZE"

    def convert(self, value, param, ctx) -> int:
        try:
            return parse_memory(value)
        except InputError as err:
            self.fail(str(err), param, ctx)


def cosmology_options(func):
    """``--cosmology NAME`` or ``--h0 --om0 [--ob0] [--tcmb0]`` (docs/cli.md "cosmology"),
    passed as ``cosmology``, ``h0``, ``om0``, ``ob0``, ``tcmb0``."""
    options = [
        click.option("--cosmology", default=None, metavar="NAME",
                     help="astropy cosmology realisation: Planck18, Planck15, Planck13, "
                     "WMAP9, ... [default: Planck18]. Excludes --h0/--om0."),
        click.option("--h0", type=float, default=None, metavar="KM/S/MPC",
                     help="Hubble constant of a flat LambdaCDM, with --om0, instead of "
                     "--cosmology."),
        click.option("--om0", type=float, default=None, metavar="X",
                     help="Matter density parameter today (with --h0)."),
        click.option("--ob0", type=float, default=None, metavar="X",
                     help="Baryon density parameter today (with --h0, --om0) [default: 0]."),
        click.option("--tcmb0", type=float, default=None, metavar="K",
                     help="CMB temperature today (with --h0, --om0) [default: 0, no "
                     "radiation]."),
    ]
    for option in reversed(options):
        func = option(func)
    return func
