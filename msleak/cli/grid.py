"""``msleak grid``: grid Stokes visibilities of MS columns (or an image cube) into uv cubes."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import click

from msleak.cli._common import FloatList
from msleak.cli.predict import _Memory
from msleak.errors import InputError
from msleak.parallel.options import parallel_options

log = logging.getLogger(__name__)


@click.command()
@click.argument("ms", nargs=-1, type=click.Path())
@click.option("-o", "--output", "outputs", required=True, multiple=True,
              type=click.Path(dir_okay=False),
              help="Output uv cube (HDF5, docs/products.md 'uvcube'); with several --column, "
              "one -o per column, in the same order.")
@click.option("--column", "columns", default=["DATA"], multiple=True, show_default=True,
              help="Visibility column: DATA, MODEL_DATA, CORRECTED_DATA, ... Repeat to grid "
              "several columns in one pass (UVW, flags and weights are read once), each into "
              "its own -o.")
@click.option("--cell", "cell", type=float, default=16.0, show_default=True, metavar="LAMBDA",
              help="uv cell size in wavelengths (16 = a LOFAR core HBA station diameter).")
@click.option("--uv-range", "uv_range", type=FloatList(2), default="30,180", show_default=True,
              metavar="MIN,MAX", help="Baselines used, in wavelengths (per channel).")
@click.option("--gridder", type=click.Choice(["wgrid", "cell"]), default="wgrid",
              show_default=True, help="wgrid: w-corrected through ducc0's wgridder; cell: "
              "nearest cell, no w-correction (docs/grid.md).")
@click.option("--split", type=click.Choice(["even-odd", "first-second"]), default=None,
              help="Also grid two halves of the time steps (vis_a, vis_b) so `msleak ps` "
              "can form a noise-bias-free cross-power.")
@click.option("--field", "field_id", type=int, default=0, show_default=True,
              help="FIELD_ID of the rows used.")
@click.option("--ddid", type=int, default=0, show_default=True,
              help="DATA_DESC_ID (spectral window) of the rows used.")
@click.option("--beam-area", "beam_area_sr", type=float, default=None, metavar="SR",
              help="Primary-beam area Omega = int (A R)^2 dOmega (sr) for the mK^2 Mpc^3 "
              "normalisation. Default: the station power beam A of --beam-area-model times "
              "the gridder's response R (docs/grid.md).")
@click.option("--image", "images", multiple=True, type=click.Path(),
              help="FITS image cube(s) instead of an MS (repeat for several Stokes).")
@click.option("--stokes", "stokes", default=None, metavar="S[,S...]",
              help="With --image: the Stokes parameter of each file without a STOKES axis "
              "(e.g. Q,U). Default I.")
@click.option("--fov", "fov_deg", type=float, default=None, metavar="DEG",
              help="With --image: inner field of view used (deg); sets the cell to 1/FoV.")
@click.option("--beam-fwhm", "beam_fwhm_deg", type=float, default=None, metavar="DEG",
              help="With --image in Jy/beam without BMAJ/BMIN: the restoring beam FWHM (deg).")
@click.option("--taper", type=click.Choice(["cos2", "hann"]), default="cos2", show_default=True,
              help="wgrid uv kernel. cos2: positive, one cell wide; response wider than the "
              "station beam (half power at 2.6 deg from the centre for 16-wavelength cells). "
              "hann: legacy, ~4 cells wide, ~1.3 deg field (docs/grid.md).")
@click.option("--chunk-rows", type=click.IntRange(min=1), default=None,
              help="MS rows per chunk task (bounds memory, about chunk_rows x nchan x 270 "
              "bytes per task) [default: 2 million samples (rows x channels), within "
              "--memory-limit].")
@click.option("--memory-limit", type=_Memory(), default="2GB", show_default=True,
              help="Working-set budget shared by the chunks gridded at the same time (per "
              "worker process with a scheduler address); lowers --chunk-rows if needed.")
@click.option("--epsilon", type=float, default=1e-6, show_default=True,
              help="wgrid accuracy (relative, ducc0).")
@click.option("--threads", type=click.IntRange(min=1), default=1, show_default=True,
              help="Threads of the wgrid gridder per chunk (parallelism comes from the "
              "chunks, --workers). The cube depends on it at the --epsilon level: ducc0 "
              "chooses its kernel by thread count.")
@click.option("--beam-area-model", type=click.Choice(["auto", "everybeam", "dipole", "airy"]),
              default="auto", show_default=True,
              help="Station beam for Omega when --beam-area is not given: the MS's own beam "
              "model (auto: everybeam with LOFAR tables, else dipole), or an Airy disc of a "
              "cell-wide station.")
@parallel_options
def grid(ms, outputs, columns, cell, uv_range, gridder, split, field_id, ddid, beam_area_sr,
         images, stokes, fov_deg, beam_fwhm_deg, taper, chunk_rows, memory_limit, epsilon,
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
      msleak grid obs.ms --uv-range 30,800 --split even-odd -o grid.h5
      msleak grid SB000.ms SB001.ms SB002.ms --scheduler processes -o grid.h5
      msleak grid --image q.fits --image u.fits --stokes Q,U --fov 4 -o grid.h5
    """
    from msleak.io.products import save_product

    if bool(ms) == bool(images):
        raise click.UsageError("give either an MS or --image CUBE.fits (not both)")
    _check_outputs(outputs, columns, bool(images))
    if not cell > 0:
        raise click.BadParameter("must be positive (wavelengths)", param_hint="--cell")
    if not 0 <= uv_range[0] < uv_range[1]:
        raise click.BadParameter(f"empty range {uv_range[0]:g}..{uv_range[1]:g}",
                                 param_hint="--uv-range")
    if images:
        from msleak.ps.fitscube import grid_image

        slist = [s.strip().upper() for s in stokes.split(",")] if stokes else None
        if slist and any(s not in "IQUV" or len(s) != 1 for s in slist):
            raise click.BadParameter(f"{stokes!r}: use I, Q, U or V", param_hint="--stokes")
        cubes = [grid_image(images, stokes=slist, fov_deg=fov_deg, uv_range=tuple(uv_range),
                            beam_fwhm_deg=beam_fwhm_deg, beam_area_sr=beam_area_sr)]
    else:
        from msleak.ps.uvcube import grid_ms

        cubes = grid_ms(list(ms), column=list(columns), cell=cell, uv_range=tuple(uv_range),
                        gridder=gridder, split=split, field_id=field_id, ddid=ddid,
                        chunk_rows=chunk_rows, epsilon=epsilon, nthreads=threads,
                        beam_area_sr=beam_area_sr, taper=taper,
                        progress=sys.stderr.isatty(), scheduler=scheduler, workers=workers,
                        memory_limit=memory_limit, beam_area_model=beam_area_model)
        if cubes[0].attrs.get("n_gap_channels"):
            click.echo(f"warning: {cubes[0].attrs['n_gap_channels']} channel(s) missing between "
                       f"the Measurement Sets ({cubes[0].attrs['freq_gaps']}) are left empty",
                       err=True)
    for output, ds in zip(outputs, cubes):
        save_product(ds, output, "uvcube")
        n = int((ds["weight"].values > 0).any(axis=0).sum())
        what = f" ({ds.attrs['column']})" if len(cubes) > 1 else ""
        click.echo(f"uv cube {output}{what}: {ds.sizes['freq']} channels, "
                   f"{ds.sizes['u']}x{ds.sizes['v']} cells of {ds.attrs['cell_lambda']:.4g} "
                   f"wavelengths ({n} with data)")


def _check_outputs(outputs: tuple, columns: tuple, images: bool) -> None:
    """One output per column (one for --image), all different."""
    if images and len(outputs) != 1:
        raise InputError(f"--image makes one uv cube but {len(outputs)} -o/--output are "
                         "given; give one")
    if not images and len(outputs) != len(columns):
        raise InputError(f"{len(columns)} --column but {len(outputs)} -o/--output given: "
                         "give one -o per --column, in the same order")
    seen = set()
    for output in outputs:
        key = Path(output).resolve()
        if key in seen:
            raise InputError(f"-o {output} is given twice: give each --column its own output")
        seen.add(key)
