"""``msleak forecast``: the same skies through LOFAR, SKA-Low, HERA and the MWA."""

from __future__ import annotations

from pathlib import Path

import click

from msleak.cli._common import (study_double_option, study_extent_options,
                                study_instrument_seeds_option, study_invoker,
                                study_workers_option)
from msleak.study.config import Instrument
from msleak.study.forecast import SETUPS, ForecastConfig, run_forecast


def _telescopes(ctx, param, value):
    if value is None:
        return tuple(SETUPS)
    names = tuple(v.strip().lower() for v in value.split(",") if v.strip())
    unknown = [n for n in names if n not in SETUPS]
    if unknown or not names:
        raise click.BadParameter(f"{unknown[0] if unknown else value!r} is not a telescope: "
                                 f"use some of {','.join(SETUPS)}")
    return names


def _noise(ctx, param, value):
    """``JY`` for every telescope, or ``tel=JY,tel=JY``."""
    if value is None:
        return None
    try:
        return float(value)
    except ValueError:
        pass
    sefd = {}
    for part in filter(None, (p.strip() for p in value.split(","))):
        tel, _, jy = part.partition("=")
        try:
            sefd[tel.strip().lower()] = float(jy)
        except ValueError:
            raise click.BadParameter(f"{value!r}: give an SEFD in Jy for every telescope, "
                                     "or TELESCOPE=JY pairs (e.g. lofar=4000,hera=...)") \
                from None
    return sefd


@click.command()
@click.argument("outdir", type=click.Path(file_okay=False))
@click.option("--telescopes", callback=_telescopes, default=None, metavar="T1,T2,...",
              help=f"Telescope names to compare, comma-separated [default: {','.join(SETUPS)}].")
@click.option("--seed", type=click.IntRange(0, None), default=2018, show_default=True,
              metavar="N", help="Seed of the first sky realisation.")
@click.option("--seeds", type=click.IntRange(1, None), default=None, metavar="N",
              help="Sky realisations (seeds SEED, SEED+1, ...), the same through every "
              "telescope; the table gives their mean +- standard deviation [3; --quick: 2].")
@click.option("--stations", type=click.IntRange(2, None), default=None, metavar="N",
              help="Use each array's N stations nearest its centre (the LOFAR HBA core has "
              "48 fields) [48; --quick: 8].")
@click.option("--duration", "duration_h", type=float, default=None, metavar="HOURS",
              help="Synthesis time, centred on transit (HERA's and the MWA's beams do not "
              "track: keep it short) [1; --quick: 0.2].")
@click.option("--interval", "interval_s", type=float, default=None, metavar="SEC",
              help="Integration time [120; --quick: 360].")
@click.option("--nchan", type=click.IntRange(8, None), default=None, metavar="N",
              help="Channels of 195.3125 kHz of the MSs and skies [50; --quick: 10].")
@click.option("--quick", is_flag=True, help="Test size for every setting not given: 8 "
              "stations, 0.2 h at 360 s, 10 channels, a 6 deg sky, 2 realisations (30 s on "
              "2 cores).")
@click.option("--ionosphere", default=None, metavar="random|spinifex|ionex:PATH|CSV",
              help="Add the instrument's budget runs with ionospheric Faraday rotation on the "
              "first sky: random (a drifting screen per --instrument-seeds realisation), "
              "spinifex or ionex:PATH (computed offline for each telescope's MS, once) or a "
              "CSV table of RMs (msleak predict --ionosphere).")
@click.option("--beam-errors", default=None,
              metavar="failed=F,rotation=DEG[,amplitude=A,phase=DEG,level=element|tile]",
              help="Add budget runs with beam-model errors (without seed: one per "
              "realisation), for the telescopes whose beam model has them (LOFAR, SKA-Low).")
@click.option("--noise", callback=_noise, default=None, metavar="JY|TEL=JY,...",
              help="Add budget runs with thermal noise: one SEFD (Jy) for every telescope, or "
              "one per telescope (e.g. lofar=4000); gridded in even/odd halves.")
@study_extent_options
@study_instrument_seeds_option
@study_double_option
@study_workers_option("the telescopes' predicts overlap, as do the grids and power spectra "
                      "of a telescope")
@click.option("--overwrite", is_flag=True,
              help="Rerun every step, replacing its outputs (without it an existing OUTDIR "
              "resumes).")
@click.pass_context
def forecast(ctx, outdir, telescopes, seed, seeds, stations, duration_h, interval_s, nchan,
             quick, ionosphere, beam_errors, noise, extents, nside, instrument_seeds, double,
             workers, overwrite):
    """Leakage forecast: the same sky realisations through LOFAR (3C196), SKA-Low, HERA and
    the MWA (EoR0) with matched settings, each with its own beam model and the beam at the
    phase centre removed; OUTDIR/forecast.md, forecast.csv and figures/forecast.png compare
    the median L_I and the L_I in the EoR window (docs/telescopes.md).

    HERA and the MWA need pip install 'msleak[hera]' and 'msleak[mwa]'.
    Resumable like msleak paper.

    \b
    Examples:
      msleak forecast forecast/ --quick
      msleak forecast forecast/ --telescopes lofar,ska-low --seeds 5
      msleak forecast forecast/ --ionosphere random --noise lofar=4000
      msleak forecast forecast/ --extents 4,9,15,30,60,90
    """
    cfg = ForecastConfig(outdir=Path(outdir), telescopes=telescopes, seed=seed, seeds=seeds,
                         stations=stations, duration_h=duration_h, interval_s=interval_s,
                         nchan=nchan, quick=quick, double=double, noise=noise,
                         extents=tuple(extents or ()), nside=nside,
                         instrument=Instrument(ionosphere, beam_errors, None,
                                               instrument_seeds))
    with study_invoker(ctx, "forecast", workers) as (invoke, workers):
        report = run_forecast(cfg, invoke, overwrite=overwrite, workers=workers)
    click.echo(f"forecast: {report}")
