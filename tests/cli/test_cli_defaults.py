"""Each default is written once: every option of a command that sets a parameter of its verb
has the verb's default (docs/cli.md), and predict's degridder options are DegridOptions'."""

from __future__ import annotations

import inspect

import click
import pytest

import msleak
from msleak.cli import cli
from msleak.predict.options import DegridOptions

#: command -> the verb it calls
VERBS = {"simulate": "simulate", "sky": "make_sky", "beam": "beam_maps", "predict": "predict",
         "noise": "noise",
         "grid": "grid", "transform": "transform", "ps": "power_spectrum",
         "leakage": "leakage"}
#: (command, parameter) whose command-line default differs on purpose, and why
DIFFERENT = {("predict", "progress"): "the command shows a progress bar when stderr is a "
                                      "terminal; the verb shows none unless asked"}


def _normal(value):
    """Values compared across the two layers: sequences as tuples of text, numbers as floats."""
    if isinstance(value, (list, tuple)):
        return tuple(_normal(v) for v in value)
    if isinstance(value, bool) or value is None:
        return value
    if isinstance(value, (int, float)):
        return float(value)
    try:
        return float(value)
    except (TypeError, ValueError):
        return str(value)


def _cli_default(ctx: click.Context, param: click.Parameter):
    default = param.get_default(ctx, call=True)
    unset = default is None or type(default).__name__ == "Sentinel"
    if getattr(param, "is_flag", False) and not default:
        return None if unset and param.secondary_opts else False   # --x/--no-x: unset
    if unset:
        return None
    if isinstance(default, str) and param.type is not click.STRING:
        try:
            return param.type_cast_value(ctx, default)
        except click.BadParameter:
            return default
    return default


@pytest.mark.parametrize("command", sorted(VERBS))
def test_command_defaults_are_the_verbs(command):
    ctx = click.Context(cli)
    cmd = cli.get_command(ctx, command)
    signature = inspect.signature(getattr(msleak, VERBS[command]))
    compared = 0
    for param in cmd.params:
        verb_param = signature.parameters.get(param.name)
        if verb_param is None or verb_param.default is inspect.Parameter.empty \
                or param.multiple or (command, param.name) in DIFFERENT:
            continue
        compared += 1
        with click.Context(cmd) as sub:
            cli_value = _cli_default(sub, param)
            verb_value = verb_param.default
            if isinstance(verb_value, str) and param.type is not click.STRING:
                verb_value = param.type_cast_value(sub, verb_value)
        if isinstance(verb_value, tuple) and isinstance(cli_value, str):
            cli_value = tuple(cli_value.split(","))         # a comma-separated list option
        assert _normal(cli_value) == _normal(verb_value), (command, param.name)
    assert compared >= 2, command


def test_predict_degrid_defaults_come_from_degrid_options():
    signature = inspect.signature(msleak.predict)
    for name in ("method", "epsilon", "nsub"):
        assert signature.parameters[name].default == getattr(DegridOptions, name)


@pytest.mark.parametrize("kwargs,message", [
    (dict(method="fast"), "unknown method 'fast'"),
    (dict(epsilon=0.0), r"epsilon must be in \(0, 1\), got 0.0"),
    (dict(epsilon="x"), r"epsilon must be in \(0, 1\), got x"),
    (dict(nsub=7), "nsub must be an even integer >= 8, got 7"),
    (dict(nsub=True), "nsub must be an even integer >= 8, got True"),
])
def test_degrid_options_refuse_bad_values(kwargs, message):
    with pytest.raises(msleak.InputError, match=message) as err:
        DegridOptions(**kwargs)
    assert err.value.params == (next(iter(kwargs)),)
