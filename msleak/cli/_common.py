"""Small helpers shared by the command modules (option parsing, messages)."""

from __future__ import annotations

from typing import Sequence

import click

__all__ = ["parse_float_list", "FloatList"]


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
