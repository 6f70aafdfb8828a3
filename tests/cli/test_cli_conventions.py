"""The command-line convention table of docs/cli.md, enforced over every command's parameters.

Each rule below is one row of that table; a new option that breaks a rule fails here.
"""

from __future__ import annotations

import click
import pytest

from msleak.cli import COMMANDS, cli

#: commands whose output is their positional argument (they only create)
CREATE = {"simulate": "out", "sky": "out", "paper": "outdir", "forecast": "outdir"}
#: commands that turn an input into a product named by -o/--output
TRANSFORM = {"beam", "grid", "transform", "ps", "leakage"}
#: one-way switches that change what is computed (not --x/--no-x pairs)
ONE_WAY = {"quick", "double", "double_column", "restart", "overwrite", "overwrite_data",
           "invariant", "interpolate_frequency", "flat_spectrum", "log_bins", "little_h", "add"}
#: metavars of single numbers: a unit, or N (count) / X (dimensionless) / FRACTION
UNIT_METAVARS = {"HZ", "DEG", "SEC", "HOURS", "M", "LAMBDA", "SR", "PC", "UG", "CM-3", "K",
                 "KM/S/MPC", "MPC-1", "N", "X", "FRACTION", "SIZE", "JY"}
#: words by which the help of a list option states its unit
UNIT_WORDS = ("Hz", "deg", "wavelength", "Mpc", "hour", "metre", "pc", "microgauss", "percent",
              "dimensionless", "pixel", "index", "indices", "label", "name", "seed", "column",
              "Jy")


def _command(name: str) -> click.Command:
    return cli.get_command(click.Context(cli), name)


def _options(name: str) -> list[click.Option]:
    return [p for p in _command(name).params if isinstance(p, click.Option)
            and p.name != "help"]


ALL = list(COMMANDS)
NUMERIC = (click.types.FloatParamType, click.types.IntParamType)


@pytest.mark.parametrize("name", ALL)
def test_output_rule(name):
    params = _command(name).params
    opts = {o for p in params if isinstance(p, click.Option) for o in p.opts}
    assert "--outdir" not in opts
    if name in CREATE:
        first = params[0]
        assert isinstance(first, click.Argument) and first.name == CREATE[name]
        assert "-o" not in opts
    elif name in TRANSFORM:
        out = [p for p in params if isinstance(p, click.Option) and "-o" in p.opts]
        assert out and "--output" in out[0].opts


@pytest.mark.parametrize("name", ALL)
def test_overwrite_rule(name):
    names = {p.name for p in _options(name)}
    if name in {"predict", "noise"}:                  # they write a column of an MS
        assert "overwrite_data" in names and "overwrite" not in names
    else:
        assert "overwrite" in names


@pytest.mark.parametrize("name", ALL)
def test_numbers_state_their_unit(name):
    for opt in _options(name):
        if isinstance(opt.type, NUMERIC) and not opt.is_flag:
            assert opt.metavar in UNIT_METAVARS, f"{name} {opt.opts[0]}: metavar {opt.metavar}"
        elif opt.metavar and "," in opt.metavar:
            assert any(w.lower() in (opt.help or "").lower() for w in UNIT_WORDS), \
                f"{name} {opt.opts[0]}: the help of a list option says its unit"


@pytest.mark.parametrize("name", ALL)
def test_switches(name):
    for opt in _options(name):
        if opt.is_flag and not opt.count:
            if opt.secondary_opts:
                assert opt.secondary_opts[0] == "--no-" + opt.opts[-1][2:]
            else:
                assert opt.name in ONE_WAY, f"{name} {opt.opts[0]}: a --x/--no-x pair"
        if opt.name == "pdf":
            assert opt.default is True


@pytest.mark.parametrize("name", ALL)
def test_selection_rule(name):
    opts = {p.name: p for p in _options(name)}
    assert "ddid" not in opts
    if name in {"predict", "grid"}:
        assert "spw" in opts and "field" in opts
    if "field" in opts and name not in {"simulate", "paper"}:
        # an id or a FIELD::NAME: not an integer type
        assert not isinstance(opts["field"].type, click.types.IntParamType)


def test_cosmology_rule():
    opts = {p.name for p in _options("ps")}
    assert {"cosmology", "h0", "om0", "ob0", "tcmb0", "little_h"} <= opts


def test_the_table_lists_every_rule():
    """docs/cli.md is the table this file enforces."""
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "docs" / "cli.md").read_text()
    for concept in ("outputs", "existing outputs", "MS selection", "units", "on/off",
                    "cosmology", "little h"):
        assert f"| {concept} |" in text
