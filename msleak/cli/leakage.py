"""``msleak leakage``: fractional leakage maps, statistics, expected leakage, bias correction."""

from __future__ import annotations

import click

from msleak.cli._common import parse_float_list

__all__ = ["leakage"]


def _paths(ctx, param, value):
    if not value:
        return []
    parts = [p.strip() for p in value.split(",") if p.strip()]
    if not parts:
        raise click.BadParameter("expected a comma-separated list of files")
    return parts


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


def _range(ctx, param, value):
    if value is None:
        return None
    lo, hi = parse_float_list(value, 2, param.name)
    if not (0 <= lo < hi):
        raise click.BadParameter(f"need 0 <= MIN < MAX, got {value!r}")
    return (lo, hi)


@click.command(context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("ps", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("-o", "--outdir", required=True, type=click.Path(file_okay=False),
              help="Output directory: stats.csv, stats.md, leakage.h5, figures.")
@click.option("--labels", callback=_labels, metavar="L1,L2,...",
              help="One label per PS input, e.g. 15deg,9deg,4deg (default: file names).")
@click.option("--realisations", callback=_ints, metavar="R1,R2,...",
              help="The sky realisation (e.g. seed) of each PS input: the per-field "
              "estimate is then given per realisation and as mean +- std over them "
              "(estimates.csv). Labels need only be unique within a realisation.")
@click.option("--field-name", default="", metavar="NAME",
              help="Name of the field (e.g. NCP), used in tables and figure titles.")
@click.option("--stats-from", type=click.Choice(["voxels", "bins"]), default="voxels",
              show_default=True,
              help="Statistics of the unaveraged 3D voxels (power3d) or of the 2D bins.")
@click.option("--negative", type=click.Choice(["mask", "clip"]), default="mask",
              show_default=True,
              help="Negative P_I (cross-power): mask the voxel, or clip it to L_I = 0. "
                   "Non-positive P_P is always masked.")
@click.option("--bins", type=click.IntRange(min=2), default=100, show_default=True,
              help="Histogram bins of L_I (uniform from 0) for the peak and the figure.")
@click.option("--hist-quantile", type=click.FloatRange(0.5, 1.0), default=0.99,
              show_default=True, help="Upper end of the histogram: this quantile of L_I.")
@click.option("--k-par-range", callback=_range, metavar="MIN,MAX",
              help="Statistics only for MIN <= |k_par| <= MAX (Mpc^-1); maps unchanged.")
@click.option("--k-perp-range", callback=_range, metavar="MIN,MAX",
              help="Statistics only for MIN <= k_perp <= MAX (Mpc^-1); maps unchanged.")
@click.option("--expected", "expected", callback=_paths, metavar="OBS_PS.h5[,...]",
              help="Observed PS products: write the expected leakage PS "
                   "(L_I_model/100)^2 x P_P,obs and its spherical average.")
@click.option("--expected-labels", callback=_labels, metavar="L1,L2,...",
              help="Labels of the observed PS products (default: file names).")
@click.option("--expected-model", type=click.Choice(["auto", "map", "median", "field"]),
              default="auto", show_default=True,
              help="L_I model: the paired input's 2D map (same k grid), its fitted median, "
                   "or the per-field estimate; auto = map if the grids match, else median "
                   "(observed i pairs with input i, or with the only input), else field.")
@click.option("--leakage-rel-error", type=click.FloatRange(min=0), default=None,
              metavar="FRACTION",
              help="Relative uncertainty of the L_I model (default: fit error, plus the "
                   "spread over inputs for the field estimate).")
@click.option("--correct", "correct", callback=_paths, metavar="OBS_I_PS.h5[,...]",
              help="Observed PS products whose Stokes I gets the expected leakage "
                   "subtracted (paired with --expected, else their own Stokes P is used).")
@click.option("--figures/--no-figures", default=True, show_default=True,
              help="Write the PNG figures.")
@click.option("--pdf/--no-pdf", default=True, show_default=True,
              help="Also write each figure as PDF.")
@click.option("--n-boot", type=click.IntRange(min=10), default=200, show_default=True,
              help="Block-bootstrap resamples for the errors of the medians and mean.")
@click.option("--bootstrap-block", type=click.IntRange(min=1), default=2, show_default=True,
              help="Bootstrap block size, in uv cells a side (whole cells with all their "
              "delays are redrawn).")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Seed of the bootstrap.")
def leakage(ps, outdir, labels, realisations, field_name, stats_from, negative, bins, hist_quantile,
            k_par_range, k_perp_range, expected, expected_labels, expected_model,
            leakage_rel_error, correct, figures, pdf, n_boot, bootstrap_block, seed):
    """Fractional leakage L_I = 100 sqrt(P_I / P_P) (percent) of one or more PS products.

    \b
    Writes to OUTDIR:
      stats.csv, stats.md  per input: mean, median, std, peak, Pareto median of L_I (%)
      leakage.h5           L_I maps (input, k_par, k_perp) in %, masks, histograms, fits
      leakage_maps.png     P_P, P_I and L_I per input with the horizon/primary wedges
      leakage_hist.png     L_I histograms with the fitted Pareto model and medians
      expected_*.h5, expected_leakage.png   with --expected
      corrected_*.h5, corrected.png         with --correct

    \b
    Example (three fields of view of one field):
      msleak leakage ps15.h5 ps9.h5 ps4.h5 --labels 15deg,9deg,4deg --field-name NCP -o out/
    """
    from msleak.leakage.report import LeakageOptions, estimate_summary, run_leakage

    if labels is not None and len(labels) != len(ps):
        raise click.BadParameter(f"{len(labels)} labels for {len(ps)} PS inputs",
                                 param_hint="--labels")
    if realisations is not None and len(realisations) != len(ps):
        raise click.BadParameter(f"{len(realisations)} realisations for {len(ps)} PS inputs",
                                 param_hint="--realisations")
    obs = expected or correct
    if expected_labels is not None and len(expected_labels) != len(obs):
        raise click.BadParameter(f"{len(expected_labels)} labels for {len(obs)} observed PS",
                                 param_hint="--expected-labels")
    opts = LeakageOptions(field_name=field_name, stats_from=stats_from, negative=negative,
                          bins=bins, upper_quantile=hist_quantile, k_par_range=k_par_range,
                          k_perp_range=k_perp_range, expected_model=expected_model,
                          rel_error=leakage_rel_error, figures=figures, pdf=pdf,
                          n_boot=n_boot, bootstrap_block=bootstrap_block, seed=seed)
    files, result = run_leakage(ps, outdir, labels, expected, expected_labels, correct, opts,
                                realisations)
    click.echo(f"msleak leakage: wrote {len(files)} files to {outdir}")
    click.echo(estimate_summary(result))
