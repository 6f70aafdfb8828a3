"""``msleak grid``: grid Stokes visibilities of MS columns (or an image cube) into uv cubes."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import get_args

import click

from msleak.cli._common import FloatList, MemorySize
from msleak.errors import InputError
from msleak.parallel.options import parallel_options
from msleak.ps.beam_area import BEAM_AREA_MODELS
from msleak.ps.gridding import GRID_EPSILON, Gridder
from msleak.verbs.grid import Split
from msleak.verbs.grid import grid as grid_verb


@click.command()
@click.argument("ms", nargs=-1, type=click.Path())
@click.option("-o", "--output", "outputs", required=True, multiple=True,
              type=click.Path(dir_okay=False),
              help="Output uv cube (HDF5, docs/products.md 'uvcube'); with several --column, "
              "one -o per column, in the same order.")
@click.option("--overwrite", is_flag=True,
              help="Replace existing outputs (otherwise refused before any work).")
@click.option("--column", "columns", default=["DATA"], multiple=True, show_default=True,
              metavar="NAME",
              help="Visibility column: DATA, MODEL_DATA, CORRECTED_DATA, ... Repeat to grid "
              "several columns in one pass (UVW, flags and weights are read once), each into "
              "its own -o.")
@click.option("--cell", "cell", type=float, default=16.0, show_default=True, metavar="LAMBDA",
              help="uv cell size in wavelengths (16 = a LOFAR core HBA station diameter).")
@click.option("--uv-range", "uv_range", type=FloatList(2), default="30,180", show_default=True,
              metavar="MIN,MAX", help="Baselines used, in wavelengths (per channel).")
@click.option("--gridder", type=click.Choice(get_args(Gridder)), default="wgrid",
              show_default=True, help="wgrid: w-corrected through ducc0's wgridder with a "
              "one-cell cos^2 kernel; cell: nearest cell, no w-correction (docs/grid.md).")
@click.option("--split", type=click.Choice(get_args(Split)), default=None,
              help="Also grid two halves of the time steps (vis_a, vis_b) so `msleak ps` "
              "can form a noise-bias-free cross-power.")
@click.option("--field", default="0", show_default=True, metavar="ID|NAME",
              help="Field of the rows used: a FIELD_ID or a FIELD::NAME.")
@click.option("--spw", default="0", show_default=True, metavar="ID",
              help="Spectral window of the rows used (its DATA_DESC_ID is looked up).")
@click.option("--beam-area", "beam_area", type=float, default=None, metavar="SR",
              help="Primary-beam area Omega = int (A R)^2 dOmega (sr) for the mK^2 Mpc^3 "
              "normalisation. Default: the station power beam A of --beam-area-model times "
              "the gridder's response R (docs/grid.md).")
@click.option("--image", "images", multiple=True, metavar="FITS|GLOB",
              help="FITS image cube(s) instead of an MS: repeat for several Stokes, or give "
              "per-channel images (WSClean NAME-0000-Q-image.fits ...) or a quoted glob of "
              "them; channels are stacked in frequency order.")
@click.option("--stokes", "stokes", default=None, metavar="S[,S...]",
              help="With --image: the Stokes label of each file without a STOKES axis "
              "(e.g. Q,U). Default I.")
@click.option("--fov", "fov", type=float, default=None, metavar="DEG",
              help="With --image: inner field of view used (deg); sets the cell to 1/FoV.")
@click.option("--beam-fwhm", "beam_fwhm", type=float, default=None, metavar="DEG",
              help="With --image in Jy/beam without BMAJ/BMIN: the restoring beam FWHM (deg).")
@click.option("--chunk-rows", type=click.IntRange(min=1), default=None, metavar="N",
              help="MS rows per chunk task (bounds memory: per task about chunk_rows x nchan "
              "x (110 + 33 x columns) bytes, docs/grid.md) [default: 2 million samples "
              "(rows x channels), within --memory-limit].")
@click.option("--memory-limit", type=MemorySize(), default="2GB", show_default=True,
              help="Working-set budget of the chunks gridded at the same time and of the "
              "grids and samples this process sums (per worker process with a scheduler "
              "address); lowers --chunk-rows, then the chunks at a time, if needed.")
@click.option("--epsilon", type=float, default=GRID_EPSILON, show_default=True, metavar="X",
              help="wgrid accuracy (relative, ducc0).")
@click.option("--threads", type=click.IntRange(min=1), default=1, show_default=True,
              metavar="N", help="Threads of the wgrid gridder per chunk (parallelism comes "
              "from the chunks, --workers). The cube depends on it at the --epsilon level: "
              "ducc0 chooses its kernel by thread count.")
@click.option("--beam-area-model", type=click.Choice(BEAM_AREA_MODELS),
              default="auto", show_default=True,
              help="Station beam for Omega when --beam-area is not given: the MS's own beam "
              "model (auto: everybeam with LOFAR tables, else dipole), or an Airy disc of a "
              "cell-wide station.")
@parallel_options
def grid(ms, outputs, overwrite, columns, cell, uv_range, gridder, split, field, spw,
         beam_area, images, stokes, fov, beam_fwhm, chunk_rows, memory_limit, epsilon,
         threads, beam_area_model, scheduler, workers):
    """Grid Stokes I, Q, U, V (and P = Q + iU) visibilities of MS, channel by channel, on
    square uv cells with natural weighting, both Hermitian halves. Flags (FLAG, FLAG_ROW)
    and weights (WEIGHT_SPECTRUM or WEIGHT) are honoured; autocorrelations are skipped.
    Several MSs (e.g. one per subband) are put on one frequency axis in frequency order:
    overlapping channels are an error, missing channels are left empty and reported.
    Several columns are gridded in one pass, one uv cube each, every column identical to
    its own single-column run.

    \b
    Examples:
      msleak grid obs.ms --column MODEL_DATA -o grid.h5
      msleak grid obs.ms --column MODEL_4DEG --column MODEL_8DEG -o g4.h5 -o g8.h5
      msleak grid obs.ms --uv-range 30,800 --split even-odd --field 3C196 -o grid.h5
      msleak grid SB000.ms SB001.ms SB002.ms --scheduler processes -o grid.h5
      msleak grid --image q.fits --image u.fits --stokes Q,U --fov 4 -o grid.h5
      msleak grid --image 'obs-*-[QU]-image.fits' --fov 4 -o grid.h5
    """
    if bool(ms) == bool(images):
        raise click.UsageError("give either an MS or --image CUBE.fits (not both)")
    _check_outputs(outputs, columns, bool(images))
    if images:
        cubes = [grid_verb(image=list(images), output=outputs[0] if len(outputs) == 1
                           else list(outputs), overwrite=overwrite, uv_range=tuple(uv_range),
                           stokes=stokes, fov=fov, beam_fwhm=beam_fwhm, beam_area=beam_area)]
    else:
        cubes = grid_verb(list(ms), column=list(columns), output=list(outputs),
                          overwrite=overwrite, cell=cell, uv_range=tuple(uv_range),
                          gridder=gridder, split=split, field=field, spw=spw,
                          beam_area=beam_area, beam_area_model=beam_area_model,
                          chunk_rows=chunk_rows, memory_limit=memory_limit,
                          epsilon=epsilon, threads=threads, scheduler=scheduler,
                          workers=workers, progress=sys.stderr.isatty())
    for output, ds in zip(outputs, cubes):
        n = int((ds["weight"].values > 0).any(axis=0).sum())
        what = f" ({ds.attrs['column']})" if len(cubes) > 1 else ""
        click.echo(f"uv cube {output}{what}: {ds.sizes['freq']} channels, "
                   f"{ds.sizes['u']}x{ds.sizes['v']} cells of {ds.attrs['cell_lambda']:.4g} "
                   f"wavelengths ({n} with data)")


def _check_outputs(outputs, columns, image: bool) -> None:
    """One -o per --column (one for --image), each a different file (the verb checks the
    same in the words of its parameters, after a column given twice)."""
    if len(set(columns)) < len(columns):
        return
    if len(outputs) != (1 if image else len(columns)):
        raise InputError(f"--image makes one uv cube but {len(outputs)} -o/--output are "
                         "given; give one" if image else f"{len(columns)} --column but "
                         f"{len(outputs)} -o/--output given: give one -o per --column, in "
                         "the same order")
    seen = set()
    for text in outputs:
        if Path(text).resolve() in seen:
            raise InputError(f"-o {text} is given twice: give each --column its own output")
        seen.add(Path(text).resolve())
