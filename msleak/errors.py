"""Exceptions msleak raises for problems a user can fix.

Every :class:`MsleakError` becomes a one-line message and exit status 2 on the command
line; anything else is an unexpected failure (exit status 1).
"""

__all__ = ["MsleakError", "InputError", "ConfigurationError"]


class MsleakError(Exception):
    """A problem with the user's input or environment, stated in one actionable line."""


class InputError(MsleakError, ValueError):
    """An input file, column, table or parameter is missing, malformed or inconsistent."""


class ConfigurationError(MsleakError, RuntimeError):
    """A dependency or the environment is not in the state msleak needs."""
