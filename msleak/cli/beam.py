"""``msleak beam``: polarized-beam and leakage maps of an MS's primary beam at several hour angles."""

from __future__ import annotations

from pathlib import Path

import click

from msleak.beam.maps import BASES, MAP_BEAMS
from msleak.cli._common import FloatList, beam_model_options
from msleak.errors import InputError
from msleak.plot.beam import plot_beam_maps
from msleak.verbs.beam_maps import beam_maps


@click.command()
@click.argument("ms", type=click.Path(exists=False))
@click.option("-o", "--output", "output", required=True, type=click.Path(dir_okay=False),
              metavar="FIGURE.png", help="Figure file (PNG; the suffix chooses the format).")
@click.option("--product", "product", type=click.Path(dir_okay=False), default=None,
              metavar="FILE.h5", help="Write the maps to this HDF5 product file (kind "
              "'beam'). Default: the figure path with suffix .h5.")
@click.option("--fov", type=float, default=15.0, show_default=True, metavar="DEG",
              help="Width of the square maps (deg, SIN projection about the phase centre).")
@click.option("--npix", type=int, default=61, show_default=True, metavar="N",
              help="Pixels per map side.")
@click.option("--hour-angles", "hour_angles", type=FloatList(), default=None,
              metavar="H1,H2,...", help="Hour angles of the phase centre in hours, at the "
              "times nearest the middle of the observation. Default: 5 times spread over "
              "the observation.")
@click.option("--freq", type=float, default=None, metavar="HZ",
              help="Frequency (Hz). Default: the middle channel of the first spectral window.")
@click.option("--beam", type=click.Choice(MAP_BEAMS), default="everybeam", show_default=True,
              help="Beam model: everybeam (LOFAR, SKA-Low: fast evaluators), everybeam-direct "
              "(EveryBeam per direction, slow), uvbeam (a UVBeam file, HERA's by default), "
              "hyperbeam (the MWA tile) or dipole (analytic, any MS).")
@beam_model_options
@click.option("--station", default=None, metavar="NAME",
              help="Map one station (ANTENNA name). Default: Mueller matrices averaged over "
              "the stations that occur in the rows of the field.")
@click.option("--diameter", type=float, default=None, metavar="M",
              help="Dipole beam: station diameter (m) of its Airy station factor "
              "[default: ANTENNA::DISH_DIAMETER].")
@click.option("--field", default=None, metavar="ID|NAME",
              help="FIELD id or name whose phase centre, pointing and rows are mapped "
              "[default: 0].")
@click.option("--invariant", is_flag=True,
              help="Plot the polarized beam as sqrt(M11^2+M12^2+M21^2+M22^2), independent of "
              "the Q,U reference frame (useful near a celestial pole); both are in the product.")
@click.option("--basis", type=click.Choice(BASES), default="tangent", show_default=True,
              help="Q,U frame of the maps: tangent, the phase centre's (North, East) basis "
              "parallel-transported to every pixel (one frame for the map); local, each "
              "pixel's own North, which turns around a celestial pole.")
@click.option("--pdf/--no-pdf", default=True, show_default=True,
              help="Also write a PDF beside the figure.")
@click.option("--overwrite", is_flag=True,
              help="Replace existing outputs (figure, PDF, product); refused otherwise.")
def beam(ms, output, product, fov, npix, hour_angles, freq, beam, element_model, beam_file,
         station, diameter, field, invariant, basis, pdf, overwrite):
    """Maps of the polarized beam sqrt(M11^2+M22^2) and of the Q,U->I leakage
    sqrt(M01^2+M02^2)/M00 of MS's station beams, normalised to the phase centre, in dB,
    at several hour angles (docs/science.md section 8).

    \b
    Examples:
      msleak beam 3c196.ms -o beam.png
      msleak beam ncp.ms -o beam.png --fov 10 --hour-angles -6,-3,0,3,6
      msleak beam ska.ms -o beam.png --beam dipole --diameter 38
    """
    figure = Path(output)
    product = Path(product) if product else figure.with_suffix(".h5")
    vector = figure.with_suffix(".pdf") if pdf and figure.suffix.lower() != ".pdf" else None
    outputs = [p for p in (figure, vector, product) if p is not None]
    for path in outputs if not overwrite else ():
        if path.exists():
            raise InputError(f"{path} exists; choose another name or pass --overwrite")
    ds = beam_maps(ms, fov=fov, npix=npix, hour_angles=hour_angles, freq=freq, beam=beam,
                   station=station, diameter=diameter, element_model=element_model,
                   beam_file=beam_file, invariant=invariant, basis=basis,
                   field=field, output=product, overwrite=overwrite)
    stations = (f" (station {station})" if station else
                f" (mean of {len(ds.attrs['stations'].split(','))} stations)")
    plot_beam_maps(ds, figure, pdf=pdf, invariant=invariant,
                   title=f"{Path(ms).name}: {ds.attrs['beam']} beam at "
                         f"{ds.attrs['freq_hz'] / 1e6:.2f} MHz, normalised to the phase "
                         f"centre{stations}")
    click.echo(f"wrote {', '.join(map(str, outputs))}")
