"""``msleak predict``: beam-corrupted visibilities of a Q/U sky into a column of an MS."""

from __future__ import annotations

import sys

import click

from msleak.adapters.sefd import read_sefd
from msleak.beam.base import BEAM_NAMES
from msleak.cli._common import MemorySize, beam_model_options
from msleak.parallel.options import parallel_options
from msleak.predict.gridsky import AUTO_MIN_PIXELS
from msleak.predict.options import METHODS, MIN_ELEVATION_DEG, DegridOptions
from msleak.verbs.predict import predict as run

__all__ = ["predict"]


def _split(_ctx, _param, value):
    if value is None:
        return None
    return [v.strip() for v in value.split(",") if v.strip()]


@click.command("predict")
@click.argument("ms", nargs=-1, required=True, type=click.Path())
@click.option("--sky", "sky", required=True, multiple=True, type=click.Path(dir_okay=False),
              help="Sky model: a FITS cube (Q/U[/I/V] x frequency, each voxel a point source "
                   "at its channel; Jy/pixel or K), a makesourcedb text file (Jy), or an "
                   "all-sky HEALPix sky (SkyH5, or a HEALPix FITS map; K or Jy/sr; every "
                   "pixel above the horizon). Repeat it to predict several skies in one "
                   "pass, each into the --column given in the same position.")
@click.option("--fov", "fov", type=float, multiple=True, metavar="DEG",
              help="Keep the central DEG x DEG degrees of the sky (default: all of it); "
                   "once for every sky, or once per --sky in the same order.")
@click.option("--extent", "extent", type=float, multiple=True, metavar="DEG",
              help="Keep the pixels of a HEALPix sky (or the sources of a makesourcedb "
                   "sky) within DEG degrees of the phase centre (default: the whole sky); "
                   "once for every sky, or once per --sky in the same order.")
@click.option("--min-elevation", "min_elevation", type=float, default=MIN_ELEVATION_DEG,
              show_default=True, metavar="DEG",
              help="At each time, leave out the pixels of a HEALPix sky below DEG degrees "
                   "of elevation, seen from the array centre.")
@click.option("--flat-spectrum", is_flag=True,
              help="Use a HEALPix map of one frequency (or none) at every channel.")
@click.option("--beam", type=click.Choice(BEAM_NAMES),
              default="everybeam", show_default=True,
              help="Station beam: EveryBeam (LOFAR and SKA-Low through msleak's fast paths), "
                   "EveryBeam called directly, a UVBeam file (HERA), the MWA tile "
                   "(mwa_hyperbeam), an analytic dipole, or no beam.")
@click.option("--diameter", "diameter", type=float, default=None, metavar="M",
              help="With --beam dipole: station diameter (m) of its Airy station factor "
                   "[default: ANTENNA::DISH_DIAMETER].")
@beam_model_options
@click.option("--ionosphere", metavar="CSV|random:SEED|spinifex|ionex:PATH", default=None,
              help="Ionospheric Faraday rotation in front of each station's beam: a CSV "
                   "table with the columns time (UTC ISO or MJD seconds), station (a name, "
                   "or * for all) and rm (rad/m^2), interpolated in time; random:SEED "
                   "(a drifting screen of mean 1 and rms 0.3 rad/m^2); or a thin shell at "
                   "450 km computed offline per station towards the phase centre, every "
                   "5 min: spinifex (IRI climatology, F10.7 100 sfu; spinifex:f107=SFU) or "
                   "ionex:PATH[,PATH] (local IONEX maps); needs pip install "
                   "'msleak[ionosphere]' (docs/predict.md, \"Ionosphere\").")
@click.option("--beam-errors",
              metavar="failed=F,rotation=DEG,amplitude=A,phase=DEG,level=element|tile,seed=N",
              default=None,
              help="Errors of the LOFAR HBA or SKA-Low beam model, per station and "
                   "reproducible: a fraction of failed tiles (elements), the rms rotation "
                   "error of each station (degrees) and the rms fractional amplitude and "
                   "phase (degrees) errors of the complex gains, drawn per feed (X, Y) for "
                   "every element (LOFAR: every dipole pair of every tile, or with "
                   "level=tile every tile) (docs/beam.md, \"Beam-model errors\").")
@click.option("--noise", "noise", default=None, metavar="JY|CSV",
              help="Add thermal noise to each column once it is predicted: the SEFD (Jy) of "
                   "every station, or a CSV table with the columns station and sefd "
                   "(msleak noise; docs/noise.md).")
@click.option("--noise-seed", type=int, default=0, show_default=True, metavar="N",
              help="Seed of the thermal noise: the noise of a row depends on it and the "
                   "row alone.")
@click.option("--column", "column", multiple=True, metavar="NAME",
              help="Column to write (created like DATA, tiled storage, if missing) "
                   "[default: MODEL_DATA]; with several --sky, one per --sky, all different.")
@click.option("--centre-correction/--no-centre-correction", "centre_correction", default=True,
              show_default=True,
              help="Remove the beam at the phase centre, V' = J_p(s0)^-1 V J_q(s0)^-H, "
                   "leaving the differential beam; --no-centre-correction keeps the full beam.")
@click.option("--interpolate-frequency", is_flag=True,
              help="Interpolate the sky cube linearly to the MS channels instead of "
                   "requiring matching channels (relative tolerance 1e-6).")
@click.option("--double", is_flag=True,
              help="complex128 arithmetic (default complex64; phases always in float64).")
@click.option("--double-column", is_flag=True,
              help="Create the columns as complex128 (casacore DComplex) to keep --double's "
                   "values (implies --double). For columns msleak grid reads: DP3 and "
                   "WSClean cannot open a complex128 column.")
@click.option("--method", type=click.Choice(METHODS), default=DegridOptions.method,
              show_default=True,
              help="direct: every pixel summed as a point source; degrid: image-domain "
                   "gridding, at a cost independent of the pixel count (pixel skies only); "
                   f"auto: degrid for pixel skies of at least {AUTO_MIN_PIXELS} pixels "
                   "where cheaper, direct otherwise (logged with -v).")
@click.option("--epsilon", type=float, default=DegridOptions.epsilon, show_default=True,
              metavar="FRACTION",
              help="Requested relative accuracy of --method degrid.")
@click.option("--nsub", type=int, default=DegridOptions.nsub, metavar="N",
              help="Subgrid size of --method degrid (even, >= 8) [default: from the beam's "
                   "measured spectrum, at least 32; w-layers serve any |w|].")
@click.option("--memory-limit", type=MemorySize(), default="2GB", show_default=True,
              help="Working-set budget, e.g. 2GB, 512MB (binary units), shared by the chunks "
                   "computed at the same time (per worker process with a scheduler address).")
@click.option("--overwrite-data", is_flag=True,
              help="Allow --column DATA (overwrites the observed visibilities).")
@click.option("--field", "field", callback=_split, default=None, metavar="ID|NAME",
              help="FIELD id or name; several comma separated (default: all).")
@click.option("--spw", "spw", callback=_split, default=None, metavar="ID",
              help="SPECTRAL_WINDOW id; several comma separated (default: all).")
@click.option("--restart", is_flag=True,
              help="Start over instead of resuming an interrupted run with the same settings.")
@click.option("--progress/--no-progress", default=None,
              help="Progress bar (default: when stderr is a terminal).")
@parallel_options
def predict(ms, sky, fov, extent, min_elevation, flat_spectrum, beam, diameter,
            element_model, beam_file, ionosphere, beam_errors, noise, noise_seed, column,
            centre_correction, interpolate_frequency,
            double, double_column, method, epsilon, nsub, memory_limit, overwrite_data, field, spw,
            restart, progress, scheduler, workers):
    """Predict the visibilities of SKY through the station beams into MS (one or more
    Measurement Sets, e.g. one per subband; each gets the same skies).

    Computes V_pq = sum_s J_p(s) B_s J_q(s)^H exp(+2 pi i (u l + v m + w (n - 1))) for
    every row, (u, v, w) = UVW / lambda from the MS (antenna 2 - antenna 1, the
    convention DP3 uses; docs/science.md's -2 pi i form for u_pq = u_p - u_q),
    per-station beams and w-terms, with
    B = [[I+Q, U+iV], [U-iV, I-Q]] (I = (XX+YY)/2; circular feeds analogously), then by
    default removes the beam at the phase centre. DATA and FLAG are never touched
    (unless --column DATA --overwrite-data). An interrupted run leaves the column marked
    incomplete (keyword MSLEAK_PREDICT); rerunning the same command resumes it.
    Time chunks of all the MSs are computed in parallel (--scheduler, --workers) and
    written by this process in time order (docs/parallel.md).

    Several --sky/--column pairs (matched in order) are predicted in one pass: per chunk
    the beam is evaluated once towards the union of the skies' directions (directions
    with exactly the same RA and Dec, as in crops of one cube or cubes on the same pixel
    grid, count once); each column equals a run with its sky alone (docs/predict.md).

    HEALPix skies (SkyH5, HEALPix FITS maps) are predicted pixel by pixel to the horizon:
    every pixel above --min-elevation at a time (seen from the array centre) is a source
    at its direction (l, m, n), n > -1 (docs/predict.md, "All-sky HEALPix skies").

    Pixel skies (FITS cubes) are predicted pixel by pixel (--method direct) or by
    image-domain gridding at a cost independent of the pixel count (--method degrid, to
    a relative accuracy --epsilon, the subgrid sized from the beam's measured spectrum);
    --method auto (the default) degrids the larger ones (docs/predict.md, "Image-domain
    gridding").

    \b
    Examples:
      msleak predict obs.ms --sky sky.fits --fov 9
      msleak predict obs.ms --sky sources.skymodel --beam none --column MODEL_NOBEAM
      msleak predict obs.ms --sky sky.fits --column MODEL_15DEG \\
          --sky sky9.fits --column MODEL_9DEG --sky sky4.fits --column MODEL_4DEG
      msleak predict obs.ms --sky s1.fits --column M1 --sky s2.fits --column M2 --fov 4
      msleak predict SB*.ms --sky sky.fits --scheduler tcp://head:8786
      msleak predict obs.ms --sky allsky.skyh5 --extent 60 --min-elevation 10
    """
    results = run(list(ms), list(sky), column=list(column) or ["MODEL_DATA"] * (len(sky) == 1),
                  fov=list(fov) or None, beam=beam, diameter=diameter,
                  element_model=element_model, beam_file=beam_file, ionosphere=ionosphere,
                  beam_errors=beam_errors,
                  centre_correction=centre_correction, interpolate_frequency=interpolate_frequency,
                  double=double, double_column=double_column, field=field, spw=spw, memory_limit=memory_limit,
                  overwrite_data=overwrite_data, restart=restart, scheduler=scheduler,
                  workers=workers, progress=sys.stderr.isatty() if progress is None else progress,
                  method=method, epsilon=epsilon, nsub=nsub, extent=list(extent) or None,
                  min_elevation=min_elevation, flat_spectrum=flat_spectrum,
                  noise=None if noise is None else read_sefd(noise, "noise"),
                  noise_seed=noise_seed)
    for result in results:
        if result.skipped:
            click.echo(f"{result.ms}: {result.column} is complete from an identical run; "
                       "left as it is (--restart recomputes it)", err=True)
            continue
        click.echo(f"{result.ms}: wrote {result.rows_written} rows into {result.column}"
                   f"{' (resumed run)' if result.resumed else ''} in {result.seconds:.1f} s"
                   + (f", thermal noise of rms {result.noise_sigma_jy:.4g} Jy per part added"
                      if result.noise_sigma_jy else ""), err=True)
