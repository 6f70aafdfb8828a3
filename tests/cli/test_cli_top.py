"""The CLI's last-resort handling: OS errors a user fixes -> exit 2, one line; anything
else -> exit 1, one line (a traceback only with --debug); Ctrl-C -> 130 with advice."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

import msleak.verbs.simulate as simulate_module
from msleak.cli import cli


@pytest.mark.parametrize("target, message", [
    ("/proc/msleak-test/x.fits", "No such file or directory"),
    ("/sys/msleak-test.fits", "Permission denied"),
])
def test_unwritable_output_is_a_user_error(target, message):
    result = CliRunner().invoke(cli, ["-q", "sky", target, "--seed", "1", "--npix", "8",
                                      "--nchan", "2"])
    assert result.exit_code == 2, result.output
    lines = [ln for ln in result.output.splitlines() if ln.startswith("msleak")]
    assert len(lines) == 1 and message in lines[0]
    assert "Traceback" not in result.output


def test_unexpected_failure_is_one_line_exit_1(monkeypatch, tmp_path):
    def broken(*args, **kwargs):
        raise ZeroDivisionError("simulated bug")

    monkeypatch.setattr(simulate_module, "simulate", broken)
    result = CliRunner().invoke(cli, ["simulate", str(tmp_path / "x.ms")])
    assert result.exit_code == 1
    assert "unexpected failure: ZeroDivisionError: simulated bug" in result.output
    assert "--debug" in result.output and "Traceback" not in result.output
    result = CliRunner().invoke(cli, ["--debug", "simulate", str(tmp_path / "x.ms")])
    assert isinstance(result.exception, ZeroDivisionError)


def test_keyboard_interrupt_says_what_to_rerun(monkeypatch, tmp_path):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(simulate_module, "simulate", interrupted)
    result = CliRunner().invoke(cli, ["simulate", str(tmp_path / "x.ms")])
    assert result.exit_code == 130
    assert "rerun the same command" in result.output and "--overwrite" in result.output
