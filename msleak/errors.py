"""Exceptions msleak raises for problems a user can fix.

Every :class:`MsleakError` becomes a one-line message and exit status 2 on the command
line; anything else is an unexpected failure (exit status 1). A message names the Python
parameters it is about (``epsilon must be in (0, 0.1)``) and lists them in ``param``; the
command line shows each as the flag that sets it (``--epsilon``), so the library never
spells a flag. Where a name is also an ordinary word of the message, the message quotes the
parameter in backticks (`` `sky` ``) and only those occurrences become flags; a remedy
quoted as a Python setting (`` `beam='dipole'` ``) becomes the option (`` `--beam dipole` ``).
"""

from __future__ import annotations

import re

__all__ = ["MsleakError", "InputError", "ConfigurationError", "BeamUnavailable"]

#: a setting quoted in a message, `` `name=value` ``: ``name`` is a parameter
_SETTING = re.compile(r"`([a-z_][a-z0-9_]*)=")


class MsleakError(Exception):
    """A problem with the user's input or environment, stated in one actionable line.

    Parameters
    ----------
    message : str
        The line, naming parameters by their Python names.
    param : str or sequence of str, optional
        The parameters the message names (as whole words, or in backticks where the name is
        also an ordinary word of the message); the CLI writes each as its flag. Settings
        quoted in the message (`` `beam='dipole'` ``) are added.
    """

    def __init__(self, message: str = "", *, param: str | tuple[str, ...] | list[str] = ()):
        super().__init__(message)
        given = (param,) if isinstance(param, str) else tuple(param)
        settings = tuple(_SETTING.findall(str(message)))
        self.params: tuple[str, ...] = tuple(dict.fromkeys(given + settings))


class InputError(MsleakError, ValueError):
    """An input file, column, table or parameter is missing, malformed or inconsistent."""


class ConfigurationError(MsleakError, RuntimeError):
    """A dependency or the environment is not in the state msleak needs."""


class BeamUnavailable(InputError):
    """A beam model cannot describe an MS: ``reason`` says why, ``setting`` is an optional
    fix of the environment (e.g. an environment variable), ``remedy`` the command-line way
    on; the message is ``reason; [setting, or ]remedy``.  Commands whose options differ
    (``msleak grid``) re-raise it with their own remedy."""

    def __init__(self, reason: str, remedy: str = "use `beam='dipole'` (analytic beam)",
                 setting: str = "", *, param: str | tuple[str, ...] = ()):
        self.reason, self.remedy, self.setting = reason, remedy, setting
        super().__init__(f"{reason}; {setting + ', or ' if setting else ''}{remedy}",
                         param=param)
