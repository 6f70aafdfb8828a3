"""``msleak transform``: delay transform (FFT along frequency) of every uv cell."""

from __future__ import annotations

from typing import get_args

import click

from msleak.ps.delay import WINDOWS, Partial
from msleak.verbs.transform import transform as verb


@click.command()
@click.argument("grid", type=click.Path())
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Output delay cube (HDF5, docs/products.md 'delay').")
@click.option("--overwrite", is_flag=True, help="Replace OUTPUT if it exists.")
@click.option("--window", type=click.Choice(sorted(WINDOWS), case_sensitive=False),
              default="blackman-harris", show_default=True,
              help="Spectral window applied before the FFT ('none' for no taper).")
@click.option("--partial", type=click.Choice(get_args(Partial)), default="drop",
              show_default=True, help="Cells empty in some (unflagged) channels: drop them, "
              "or fill the empty channels with zeros.")
def transform(grid, output, overwrite, window, partial):
    """Delay-transform the uv cube GRID:
    V~(b, tau) = (1/N) sum_nu w(nu) V(b, nu) exp(-2 pi i n k / N), delays in seconds.
    Channels empty in every cell (flagged) enter as zeros; see docs/transform.md.

    \b
    Example:
      msleak transform grid.h5 -o delay.h5 --window blackman-harris
    """
    ds = verb(grid, window=window, partial=partial, output=output, overwrite=overwrite)
    click.echo(f"delay cube {output}: {ds.sizes['delay']} delays, window {ds.attrs['window']} "
               f"(norm {ds.attrs['window_norm']:.4f}), {ds.attrs['n_cells_used']} cells used")
