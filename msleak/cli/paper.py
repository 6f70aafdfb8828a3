"""``msleak paper``: the whole leakage study in one command."""

from __future__ import annotations

from pathlib import Path

import click

from msleak.cli._common import (study_double_option, study_extent_options,
                                study_instrument_seeds_option, study_invoker,
                                study_workers_option)
from msleak.study.config import (OBSERVED_UV_RANGE, RESOLUTIONS, SKY_FOV_DEG, StudyConfig,
                                  nyquist_npix)
from msleak.study.pipeline import run_study


def _observed(ctx, param, values):
    out = {}
    for item in values:
        try:
            fld, cubes = item.split("=", 1)
            q_cube, u_cube = cubes.split(",")
        except ValueError:
            raise click.BadParameter(f"{item!r}: expected FIELD=Q.fits,U.fits "
                                     "(e.g. ncp=ncp_Q.fits,ncp_U.fits)") from None
        if fld.lower() not in ("ncp", "3c196"):
            raise click.BadParameter(f"unknown field {fld!r}: ncp or 3c196")
        for cube in (q_cube, u_cube):
            if not click.Path(exists=True, dir_okay=False).convert(cube, param, ctx):
                raise click.BadParameter(f"{cube}: no such file")
        out[fld.lower()] = (q_cube, u_cube)
    return out


@click.command()
@click.argument("outdir", type=click.Path(file_okay=False))
@click.option("--quick", is_flag=True, help="Reduced size (18 HBA fields, 2 h at 600 s, "
              "both fields, all three fields of view): about 3 minutes on 2 cores. With "
              "--resolution observed: 20 HBA fields whose baselines reach 800 wavelengths.")
@click.option("--resolution", type=click.Choice(RESOLUTIONS), default="paper",
              show_default=True, help="paper: a 50-pixel 15-deg sky, baselines 30-180 "
              "wavelengths; observed: that of observed LOFAR data, baselines 30-800 "
              "wavelengths and a sky whose pixels resolve them "
              f"({nyquist_npix(SKY_FOV_DEG, OBSERVED_UV_RANGE[1])} pixels over "
              f"{SKY_FOV_DEG:g} deg), "
              "predicted by image-domain gridding (docs/paper.md 'Observation "
              "resolution'). An OUTDIR holds one resolution.")
@click.option("--seed", type=click.IntRange(0, None), default=2018, show_default=True,
              metavar="N", help="Seed of the sky model (the first realisation).")
@click.option("--seeds", type=click.IntRange(1, None), default=1, show_default=True,
              metavar="N", help="Sky realisations (seeds SEED, SEED+1, ...) through the same "
              "MSs and beams, predicted and gridded in one pass per field; the per-field "
              "estimate is then their mean +- standard deviation.")
@click.option("--field", "fields", type=click.Choice(["ncp", "3c196"]), multiple=True,
              help="Only these fields (repeatable) [default: both].")
@click.option("--beam", type=click.Choice(["everybeam", "everybeam-direct", "dipole"]),
              default="everybeam", show_default=True, help="Beam model for predict and maps.")
@click.option("--observed", multiple=True, callback=_observed, metavar="FIELD=Q.fits,U.fits",
              help="Observed Q and U image cubes of a field, by file name: adds its polarized "
              "PS and the expected leakage (docs/science.md section 6-7). Repeatable.")
@click.option("--stations", default=None, metavar="PATTERN",
              help="Override the stations (e.g. 'CS00[1-7]HBA*') [48 HBA core fields; "
              "--quick: 18, or 20 with --resolution observed].")
@click.option("--duration", "duration_h", type=float, default=None, metavar="HOURS",
              help="Override the synthesis time of both fields [13 h NCP, 8 h 3C196; "
              "--quick: 2 h].")
@click.option("--interval", "interval_s", type=float, default=None, metavar="SEC",
              help="Override the integration time [120 s; --quick: 600 s].")
@click.option("--nchan", type=click.IntRange(8, None), default=None, metavar="N",
              help="Override the number of channels of the MSs and the sky [50].")
@click.option("--ionosphere", default=None, metavar="random|spinifex|ionex:PATH|CSV",
              help="Add the instrument's budget runs with ionospheric Faraday rotation: "
              "random (a drifting screen, one per --instrument-seeds realisation), spinifex "
              "or ionex:PATH (RMs computed offline for each MS, once) or a CSV table of RMs "
              "(msleak predict --ionosphere).")
@click.option("--beam-errors", default=None,
              metavar="failed=F,rotation=DEG[,amplitude=A,phase=DEG,level=element|tile]",
              help="Add budget runs with beam-model errors (msleak predict --beam-errors, "
              "without seed: one per realisation; failed and amplitude are fractions, "
              "rotation and phase in degrees).")
@click.option("--noise", "noise_sefd", type=float, default=None, metavar="JY",
              help="Add budget runs with thermal noise of this SEFD (Jy), gridded in "
              "even/odd halves (msleak noise).")
@study_extent_options
@study_instrument_seeds_option
@study_double_option
@study_workers_option("the two fields' predicts overlap, as do the grid and beam maps of "
                      "a field")
@click.option("--overwrite", is_flag=True,
              help="Rerun every step, replacing its outputs, even those up to date "
              "(without it an existing OUTDIR resumes).")
@click.pass_context
def paper(ctx, outdir, quick, resolution, seed, seeds, fields, beam, observed, stations,
          duration_h, interval_s, nchan, ionosphere, beam_errors, noise_sefd, extents,
          nside, instrument_seeds, double, workers, overwrite):
    """Run the whole study into OUTDIR: simulate both fields, generate the sky, predict it
    through the LOFAR beam for 15, 9 and 4 deg fields of view, power spectra, leakage
    statistics, every figure, and OUTDIR/report.md with the commands used.

    Resumable: a rerun skips finished steps whose inputs are unchanged; --overwrite
    reruns them all (and may replace a study of the other --resolution).

    \b
    Examples:
      msleak paper study/ --quick
      msleak paper study_observed/ --resolution observed
      msleak paper study/ --observed ncp=ncp_Q.fits,ncp_U.fits
      msleak paper study/ --ionosphere random --beam-errors failed=0.05,rotation=1 \\
          --noise 2500
      msleak paper study/ --extents 4,9,15,30,60,90
    """
    cfg = StudyConfig(outdir=Path(outdir), quick=quick, seed=seed, seeds=seeds,
                      fields=tuple(fields) or ("ncp", "3c196"), beam=beam,
                      observed=observed, stations=stations, duration_h=duration_h,
                      interval_s=interval_s, nchan=nchan, double=double,
                      resolution=resolution, ionosphere=ionosphere, beam_errors=beam_errors,
                      noise_sefd=noise_sefd, instrument_seeds=instrument_seeds,
                      extents=tuple(extents or ()), nside=nside)
    with study_invoker(ctx, "paper", workers) as (invoke, workers):
        report = run_study(cfg, invoke, overwrite=overwrite, workers=workers)
    click.echo(f"report: {report}")
