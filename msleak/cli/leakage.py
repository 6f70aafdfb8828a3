"""``msleak leakage``: fractional leakage maps, statistics, expected leakage, bias correction
(docs/leakage.md); a thin wrapper over :func:`msleak.verbs.leakage.leakage`."""

from __future__ import annotations

from typing import get_args

import click

from msleak.cli._common import FloatList
from msleak.leakage.fraction import NegativePolicy, StatsFrom
from msleak.leakage.observed import ModelMode
from msleak.verbs.leakage import leakage as leakage_verb
from msleak.verbs.leakage_files import estimate_summary

__all__ = ["leakage"]


def _labels(ctx, param, value):
    if value is None:
        return None
    parts = [p.strip() for p in value.split(",")]
    if any(p == "" for p in parts):
        raise click.BadParameter(f"empty label in {value!r}")
    return parts


def _ints(ctx, param, value):
    if value is None:
        return None
    try:
        return [int(p) for p in value.split(",")]
    except ValueError:
        raise click.BadParameter(f"expected comma-separated integers, got {value!r}") from None


@click.command(context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("ps", nargs=-1, required=True, type=click.Path())
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False),
              metavar="DIR", help="Output directory: stats.csv, estimates.csv, stats.md, "
              "leakage.h5, figures.")
@click.option("--overwrite", is_flag=True,
              help="Replace the leakage products of an existing output directory.")
@click.option("--labels", callback=_labels, metavar="L1,L2,...",
              help="One label per PS input, e.g. 15deg,9deg,4deg [default: file names].")
@click.option("--realisations", callback=_ints, metavar="N1,N2,...",
              help="The sky realisation (e.g. seed) of each PS input: the per-field "
              "estimate is then given per realisation and as mean +- std over them "
              "(estimates.csv). Labels need only be unique within a realisation.")
@click.option("--field-name", default="", metavar="NAME",
              help="Name of the field (e.g. NCP), used in tables and figure titles.")
@click.option("--stats-from", type=click.Choice(get_args(StatsFrom)), default="voxels",
              show_default=True,
              help="Statistics of the unaveraged 3D voxels (power3d) or of the 2D bins.")
@click.option("--negative", type=click.Choice(get_args(NegativePolicy)), default="mask",
              show_default=True,
              help="Negative P_I (cross-power): mask the voxel, or clip it to L_I = 0. "
                   "Non-positive P_P is always masked.")
@click.option("--bins", type=click.IntRange(min=2), default=100, show_default=True,
              metavar="N", help="Histogram bins of L_I (uniform from 0) for the peak and "
              "the figure.")
@click.option("--hist-quantile", type=click.FloatRange(0.5, 1.0), default=0.99,
              show_default=True, metavar="X",
              help="Upper end of the histogram: this quantile of L_I.")
@click.option("--k-par-range", type=FloatList(2), metavar="MIN,MAX",
              help="Statistics only for MIN <= |k_par| <= MAX, in Mpc^-1; maps unchanged.")
@click.option("--k-perp-range", type=FloatList(2), metavar="MIN,MAX",
              help="Statistics only for MIN <= k_perp <= MAX, in Mpc^-1; maps unchanged.")
@click.option("--expected", multiple=True, type=click.Path(),
              metavar="FILE", help="An observed PS product (repeatable): write the expected "
              "leakage PS (L_I_model/100)^2 x P_P,obs and its spherical average.")
@click.option("--observed", multiple=True, type=click.Path(), metavar="FILE",
              help="The PS product of the observation (its DATA, gridded as the inputs' "
              "columns; once for all inputs or once per input): the predicted leakage beside "
              "the observed Stokes I power, per bin and summed over the EoR window "
              "(observed.csv, observed.png).")
@click.option("--expected-labels", callback=_labels, metavar="L1,L2,...",
              help="Labels of the observed PS products [default: file names].")
@click.option("--expected-model", type=click.Choice(get_args(ModelMode)),
              default="auto", show_default=True,
              help="L_I model: the paired input's 2D map (same k grid), its fitted median, "
                   "or the per-field estimate; auto = map if the grids match, else median "
                   "(observed i pairs with input i, or with the only input), else field.")
@click.option("--leakage-rel-error", type=click.FloatRange(min=0), default=None,
              metavar="FRACTION",
              help="Relative uncertainty of the L_I model [default: fit error, plus the "
                   "spread over inputs for the field estimate].")
@click.option("--correct", multiple=True, type=click.Path(), metavar="FILE",
              help="An observed PS product (repeatable) whose Stokes I gets the expected "
                   "leakage subtracted (paired in order with --expected, else its own "
                   "Stokes P is used).")
@click.option("--figures/--no-figures", default=True, show_default=True,
              help="Write the PNG figures.")
@click.option("--pdf/--no-pdf", default=True, show_default=True,
              help="Also write each figure as PDF.")
@click.option("--n-boot", type=click.IntRange(min=10), default=200, show_default=True,
              metavar="N", help="Block-bootstrap resamples for the errors of the medians "
              "and mean.")
@click.option("--bootstrap-block", type=click.IntRange(min=1), default=2, show_default=True,
              metavar="N", help="Bootstrap block size, in uv cells a side (whole cells "
              "with all their delays are redrawn).")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              metavar="N", help="Seed of the bootstrap.")
def leakage(ps, output, overwrite, **options):
    """Fractional leakage L_I = 100 sqrt(P_I / P_P) (percent) of one or more PS products.

    \b
    Writes to the output directory:
      stats.csv, stats.md  per input: mean, median, std, peak, Pareto median of L_I (%)
      estimates.csv        the per-field estimate (per sky realisation)
      leakage.h5           L_I maps (input, k_par, k_perp) in %, masks, histograms, fits
      leakage_maps.png     P_P, P_I and L_I per input with the horizon/primary wedges
      leakage_hist.png     L_I histograms with the fitted Pareto model and medians
      expected_*.h5, expected_leakage.png   with --expected
      corrected_*.h5, corrected.png         with --correct
      observed.csv, observed.png            with --observed

    \b
    Example (three fields of view of one field):
      msleak leakage ps15.h5 ps9.h5 ps4.h5 --labels 15deg,9deg,4deg --field-name NCP -o out/
    """
    for name in ("k_par_range", "k_perp_range"):
        options[name] = tuple(options[name]) if options[name] is not None else None
    result = leakage_verb(list(ps), output=output, overwrite=overwrite, **options)
    click.echo(f"msleak leakage: wrote the leakage products of {result.sizes['input']} "
               f"input(s) to {output}")
    click.echo(estimate_summary(result))
