"""Small helpers shared by the command modules (option parsing, messages)."""

from __future__ import annotations

import contextlib
import os
from typing import Sequence

import click

from msleak.errors import InputError
from msleak.parallel.runner import parse_memory

__all__ = ["parse_float_list", "FloatList", "MemorySize", "cosmology_options", "beam_model_options",
           "step_invoker", "study_workers_option", "study_invoker", "study_extent_options",
           "study_instrument_seeds_option"]


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


def beam_model_options(func):
    """``--element-model`` and ``--beam-file``: the settings of the beam models that take
    them (:func:`msleak.adapters.beams.beam_options` refuses them for the others)."""
    func = click.option(
        "--beam-file", "beam_file", type=click.Path(exists=True, dir_okay=False),
        default=None, metavar="FILE",
        help="With --beam uvbeam: a UVBeam-readable E-field beam (beamfits, ...) [default: "
             "pyuvsim's HERA beam, 100-145 MHz]; with --beam hyperbeam --element-model fee: "
             "the MWA FEE HDF5 file [default: $MWA_BEAM_FILE].")(func)
    return click.option(
        "--element-model", "element_model", default=None, metavar="NAME",
        help="With --beam everybeam[-direct]: EveryBeam's element response model (LOFAR: "
             "hamaker; SKA-Low: oskar_dipole_cos, skala40_wave); with --beam hyperbeam: "
             "analytic (default) or fee.")(func)


def step_invoker(ctx: click.Context, command: str):
    """``invoke(args)``: run one msleak command line in this process with the global
    options of ``ctx`` (for multi-step commands such as ``msleak paper``); a failure says
    to rerun ``msleak COMMAND`` to resume."""
    from msleak.study.steps import step_failed

    root = ctx.find_root().command

    def invoke(args):
        rc = root.main(args=[*ctx.obj.get("global_args", []), *args], prog_name="msleak",
                       standalone_mode=False, obj=ctx.obj)
        if rc not in (None, 0):
            raise step_failed(args, rc, command)
    return invoke


def study_workers_option(overlap: str):
    """``--workers N`` of the multi-step commands (paper, forecast): steps run at once;
    ``overlap`` says what then overlaps."""
    return click.option(
        "--workers", type=click.IntRange(1, None), default=None, metavar="N",
        help=f"Steps run at once, in as many msleak worker processes ({overlap}); 1 runs "
             "them one after another in this process [default: 2, or 1 on a one-core "
             "machine].")


#: ``--double/--no-double`` of the multi-step commands (paper, forecast)
study_double_option = click.option(
    "--double/--no-double", default=True, show_default=True,
    help="Predict in complex128 arithmetic into complex128 columns (msleak predict "
         "--double --double-column). complex64 rounding sets the Stokes I power of the "
         "faintest voxels: --no-double predicts faster (into new complex64 columns, half "
         "the disk), but raised the "
         "15 deg 3C196 median of L_I by 1.5 % and the forecast's LOFAR median by 74 % "
         "(docs/leakage.md).")


def study_extent_options(func):
    """``--extents`` and ``--nside`` of the multi-step commands (paper, forecast)."""
    func = click.option("--nside", type=click.IntRange(1, None), default=None, metavar="N",
                        help="NSIDE of the all-sky skies of --extents, a power of 2 [64; "
                             "--quick: 16].")(func)
    return click.option(
        "--extents", type=FloatList(), default=None, metavar="DEG,DEG,...",
        help="Also predict all-sky HEALPix skies of the same realisations within each extent "
             "(deg from the phase centre, up to 180: every pixel above the horizon) and "
             "tabulate and plot L_I against the extent; with 15 and a larger extent, also "
             "the PS of the sky beyond 15 deg (docs/paper.md, docs/telescopes.md).")(func)


#: ``--instrument-seeds`` of the multi-step commands (paper, forecast)
study_instrument_seeds_option = click.option(
    "--instrument-seeds", type=click.IntRange(1, None), default=3, show_default=True,
    metavar="N", help="Realisations of each corruption in the budget (docs/paper.md).")


@contextlib.contextmanager
def study_invoker(ctx: click.Context, command: str, workers: int | None):
    """``with study_invoker(ctx, command, workers) as (invoke, workers):`` for a multi-step
    command: with more than one worker, steps run in msleak worker processes
    (:class:`msleak.study.steps.ProcessInvoker`, ended on exit), else in this one
    (:func:`step_invoker`)."""
    from msleak.study.steps import ProcessInvoker

    if workers is None:
        workers = min(2, os.cpu_count() or 1)
    if workers == 1:
        yield step_invoker(ctx, command), 1
        return
    with ProcessInvoker(ctx.obj.get("global_args", []), command, workers) as invoke:
        yield invoke, workers
