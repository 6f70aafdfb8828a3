"""``msleak noise``: thermal noise by the radiometer equation into a column of an MS."""

from __future__ import annotations

import click

from msleak.adapters.sefd import read_sefd
from msleak.verbs.noise import noise as verb

__all__ = ["noise"]


@click.command()
@click.argument("ms", type=click.Path())
@click.option("--sefd", required=True, metavar="JY|CSV",
              help="System equivalent flux density of every station (Jy), or a CSV table "
                   "with the columns station and sefd (Jy), one row per ANTENNA name.")
@click.option("--column", default="NOISE_DATA", show_default=True, metavar="NAME",
              help="Column to write (created like DATA if missing).")
@click.option("--seed", type=int, default=0, show_default=True, metavar="N",
              help="Random seed: the noise of a row depends on it and the row alone.")
@click.option("--from", "source", default=None, metavar="NAME",
              help="Write the values of this column plus the noise (e.g. the column "
                   "msleak predict wrote) [default: the noise alone].")
@click.option("--overwrite-data", is_flag=True,
              help="Allow --column DATA (overwrites the observed visibilities).")
def noise(ms, sefd, column, seed, source, overwrite_data):
    """Write thermal noise into a column of MS: complex Gaussian noise per correlation
    whose real and imaginary parts each have the rms SEFD / sqrt(2 dnu dt) (the radiometer
    equation; dnu the channel width, dt the row's EXPOSURE). Flagged samples are left as
    they are. A rerun gives the same column. See docs/noise.md.

    \b
    Examples:
      msleak noise obs.ms --sefd 2500 --seed 1
      msleak noise obs.ms --sefd 2500 --from MODEL_DATA --column MODEL_NOISY
      msleak noise obs.ms --sefd sefd.csv
    """
    result = verb(ms, sefd=read_sefd(sefd), column=column, seed=seed, source=source,
                  overwrite_data=overwrite_data)
    click.echo(f"{result.ms}: wrote noise of rms {result.sigma_jy:.4g} Jy per part into "
               f"{result.column} ({result.rows_written} rows, {result.samples} unflagged "
               "samples)", err=True)
