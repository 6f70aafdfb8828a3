"""The ``msleak`` command-line interface: one click group, one thin module per command.

Commands are imported only when used, so ``msleak --help`` stays fast and a heavy
dependency of one command never slows another.
"""

from __future__ import annotations

import errno
import importlib.util
import logging
import sys
import warnings
from pathlib import Path
from typing import Sequence

import click

from msleak import __version__
from msleak.cli._flags import as_flags
from msleak.errors import MsleakError

__all__ = ["main", "cli", "run_command"]

#: command name -> "module:function" (module relative to msleak.cli)
COMMANDS = {
    "simulate": "simulate:simulate",
    "sky": "sky:sky",
    "beam": "beam:beam",
    "predict": "predict:predict",
    "noise": "noise:noise",
    "grid": "grid:grid",
    "transform": "transform:transform",
    "ps": "ps:ps",
    "leakage": "leakage:leakage",
    "paper": "paper:paper",
    "forecast": "forecast:forecast",
}

log = logging.getLogger("msleak")

#: operating-system errors a user fixes (full disk, quota, read-only, forbidden or missing
#: paths): exit status 2 with one line, like any input error
_USER_OS_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM,
                   errno.ENOENT, errno.ENOTDIR, errno.EISDIR}


class LazyGroup(click.Group):
    """A click group that imports each command's module on first use."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return [name for name in COMMANDS if self._available(name)]

    @staticmethod
    def _available(name: str) -> bool:
        module = COMMANDS[name].split(":")[0]
        return importlib.util.find_spec(f"msleak.cli.{module}") is not None

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name not in COMMANDS or not self._available(name):
            return None
        module, func = COMMANDS[name].split(":")
        return getattr(importlib.import_module(f"msleak.cli.{module}"), func)

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except MsleakError as err:
            click.echo(f"msleak: error: {_one_line(as_flags(err, self._invoked(ctx)))}",
                       err=True)
            ctx.exit(2)
        except KeyboardInterrupt:
            click.echo("msleak: interrupted: rerun the same command (predict and paper "
                       "resume where they stopped; simulate needs --overwrite)", err=True)
            ctx.exit(130)
        except (click.exceptions.Exit, click.exceptions.Abort, click.ClickException):
            raise
        except Exception as err:  # noqa: BLE001 - last-resort one-line report
            if isinstance(err, OSError) and err.errno in _USER_OS_ERRORS:
                click.echo(f"msleak: error: {_one_line(err)} (check the path, free space or "
                           "permissions, then rerun)", err=True)
                ctx.exit(2)
            if ctx.obj and ctx.obj.get("debug"):
                raise
            click.echo(f"msleak: unexpected failure: {type(err).__name__}: {_one_line(err)} "
                       "(rerun with `msleak --debug ...` for the traceback)", err=True)
            ctx.exit(1)


    def _invoked(self, ctx: click.Context) -> click.Command | None:
        name = ctx.invoked_subcommand
        return self.get_command(ctx, name) if name else None


def _one_line(err: BaseException) -> str:
    text = " ".join(str(err).split())
    return text or type(err).__name__


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="msleak")
@click.option("-v", "--verbose", count=True,
              help="More output: -v progress and library warnings, -vv debugging detail.")
@click.option("-q", "--quiet", is_flag=True,
              help="Only errors and each command's result (no warnings, no progress).")
@click.option("--debug", is_flag=True, help="Show the full traceback of unexpected failures.")
@click.pass_context
def cli(ctx: click.Context, verbose: int, quiet: bool, debug: bool) -> None:
    """msleak: polarization leakage (Q/U -> I) through primary beams, and its effect on
    21-cm power spectra, from any Measurement Set.

    \b
    Typical flow:
      msleak simulate obs.ms --field 3c196
      msleak sky sky.fits
      msleak predict obs.ms --sky sky.fits --beam everybeam
      msleak noise obs.ms --sefd 2500 --from MODEL_DATA --column MODEL_NOISY   (optional)
      msleak grid obs.ms --column MODEL_DATA -o grid.h5
      msleak transform grid.h5 -o delay.h5
      msleak ps delay.h5 -o ps.h5
      msleak leakage ps.h5 -o leakage/
    or the whole study at once:  msleak paper OUTDIR [--quick]
    or other telescopes' leakage:  msleak forecast OUTDIR [--quick]
    """
    ctx.ensure_object(dict)
    ctx.obj["debug"] = debug
    # the global options, for commands that run other msleak commands (msleak paper)
    ctx.obj["global_args"] = (["-q"] if quiet else []) + ["-v"] * verbose + \
        (["--debug"] if debug else [])
    level = _log_level(verbose, quiet)
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(asctime)s %(name)s %(levelname)s: %(message)s",
                                           "%H:%M:%S"))
    root = logging.getLogger("msleak")
    root.handlers[:] = [h for h in root.handlers if isinstance(h, logging.NullHandler)]
    root.addHandler(handler)
    root.setLevel(level)
    # the step lines of multi-step commands (msleak paper) are progress the user needs
    logging.getLogger("msleak.study.steps").setLevel(level if quiet else min(level, logging.INFO))
    _route_warnings()
    log.debug("msleak %s from %s, Python %s", __version__,
              Path(__file__).resolve().parents[1], sys.version.split()[0])


def _log_level(verbose: int, quiet: bool) -> int:
    """Default WARNING; -v INFO, -vv DEBUG; -q ERROR (wins over -v)."""
    if quiet:
        return logging.ERROR
    return {0: logging.WARNING, 1: logging.INFO}.get(verbose, logging.DEBUG)


def _route_warnings() -> None:
    """Python warnings (astropy's included) become one INFO line each of ``msleak.warnings``:
    shown from -v on, never in the way of the one-line error."""
    import astropy  # noqa: F401  (astropy replaces warnings.showwarning when imported)

    warnings.showwarning = _log_warning


def _log_warning(message, category, filename, lineno, file=None, line=None) -> None:
    logging.getLogger("msleak.warnings").info("%s: %s", category.__name__, _one_line(message))


def run_command(args: Sequence[str]) -> int:
    """Run one msleak command line (with its global options) in this process; its exit
    status."""
    try:
        rc = cli.main(args=list(args), prog_name="msleak", standalone_mode=False)
    except click.ClickException as error:
        error.show()
        rc = error.exit_code
    except click.exceptions.Abort:
        rc = 1
    except SystemExit as exit_:
        rc = exit_.code
    return rc if isinstance(rc, int) else 0


def main() -> None:
    """Entry point of the ``msleak`` console script."""
    cli(prog_name="msleak")
