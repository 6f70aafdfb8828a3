"""The command line writes the library's parameter names as its flags (msleak/cli/_flags.py)."""

from __future__ import annotations

import click
import pytest

from msleak.cli import cli
from msleak.cli._flags import as_flags, flag_for
from msleak.errors import InputError


def _command(name: str) -> click.Command:
    return cli.get_command(click.Context(cli), name)


@pytest.mark.parametrize("message,params,expected", [
    ("epsilon must be in (0, 1), got 2", "epsilon", "--epsilon must be in (0, 1), got 2"),
    ("uv_range and uv_range_x", "uv_range", "--uv-range and uv_range_x"),
    ("`fov` is given 2 times for 3 `sky`; once (for every sky) or once per `sky`",
     ("fov", "sky"), "--fov is given 2 times for 3 --sky; once (for every sky) or once per --sky"),
    ("no LOFAR tables: use `beam='dipole'` or `beam_file=PATH`; the beam is EveryBeam's",
     ("beam", "beam_file"),
     "no LOFAR tables: use `--beam dipole` or `--beam-file PATH`; the beam is EveryBeam's"),
    ("the sky is fine", (), "the sky is fine"),
    ("/data/fov/fov.fits: fov is too wide.", "fov", "/data/fov/fov.fits: --fov is too wide."),
    ("out/fov/a.fits and ./fov: om0/fov", ("fov", "om0"),
     "out/fov/a.fits and ./fov: --om0/--fov"),
])
def test_parameters_become_flags(message, params, expected):
    assert as_flags(InputError(message, param=params), _command("predict")) == expected


def test_flags_come_from_the_running_commands_options():
    assert flag_for("duration_h", _command("forecast")) == "--duration"
    assert flag_for("ms", _command("predict")) == "MS"
    assert flag_for("memory_limit", None) == "--memory-limit"


def test_a_library_error_reaches_the_command_line_as_flags(tmp_path):
    from click.testing import CliRunner

    result = CliRunner().invoke(cli, ["forecast", str(tmp_path / "out"), "--duration", "-1"])
    assert result.exit_code == 2
    assert "msleak: error: --duration (-1.0 h) and --interval" in result.output, result.output
