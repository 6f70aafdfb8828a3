"""Library parameter names to command-line flags: the one place the CLI translates them.

The library's errors name Python parameters (``epsilon must be in (0, 0.1)``) and list them
in :attr:`msleak.errors.MsleakError.params`; the command line shows each as the flag of the
running command that sets it (``--epsilon``), read from the command's own click options, or
from :data:`ALIASES` where the flag's name differs from the parameter's.
"""

from __future__ import annotations

import re

import click

from msleak.errors import MsleakError

__all__ = ["ALIASES", "flag_for", "as_flags", "rewrite"]

#: a word that is a path (absolute, home- or dot-relative, or with a folder and an
#: extension): parameter names inside it are left alone
_PATH = re.compile(r"^[(\[\"']?(?:[/~]|\.{1,2}/|[^\s/]+/\S*\.\w)")

#: parameter name -> flag, where the flag is not the parameter's name with dashes
ALIASES: dict[str, str] = {
    "fov_deg": "--fov", "freq_min_hz": "--freq-min", "chan_width_hz": "--chan-width",
    "output": "-o/--output",
}


def flag_for(param: str, command: click.Command | None = None) -> str:
    """The flag (or argument name) of ``command`` that sets the library parameter ``param``."""
    if param in ALIASES:
        return ALIASES[param]
    for option in getattr(command, "params", ()):
        if option.name == param:
            if isinstance(option, click.Argument):
                return option.human_readable_name
            longs = [o for o in option.opts if o.startswith("--")]
            return (longs or option.opts)[0]
    return "--" + param.replace("_", "-")


def as_flags(err: MsleakError, command: click.Command | None = None) -> str:
    """``err``'s message with each parameter it names written as the flag of ``command``
    (:func:`rewrite`)."""
    return rewrite(str(err), getattr(err, "params", ()), lambda p: flag_for(p, command))


def rewrite(text: str, params, flag_of) -> str:
    """``text`` with each of ``params`` written as ``flag_of(param)``. A quoted setting
    `` `beam='dipole'` `` becomes `` `--beam dipole` ``; a quoted name (`` `sky` ``) becomes
    the flag; a parameter quoted neither way is replaced wherever it stands as a word (not
    as part of a path or file name)."""
    for param in params:
        flag = flag_of(param)
        text, settings = re.subn(
            rf"`{re.escape(param)}=(?:'([^'`]*)'|\"([^\"`]*)\"|([^`]*))`",
            lambda m: f"`{flag} {next(g for g in m.groups() if g is not None)}`", text)
        quoted = f"`{param}`"
        if quoted in text:
            text = text.replace(quoted, flag)
        elif not settings:
            word = re.compile(rf"(?<![\w\-`'.]){re.escape(param)}(?![\w\-]|\.\w)")
            text = re.sub(r"\S+", lambda m: m.group(0) if _PATH.match(m.group(0))
                          else word.sub(flag, m.group(0)), text)
    return text
