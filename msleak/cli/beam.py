"""``msleak beam``: polarized-beam and leakage maps of an MS's primary beam at several hour angles."""

from __future__ import annotations

import logging
from pathlib import Path

import click
import numpy as np

from msleak.beam.maps import BASES
from msleak.cli._common import FloatList

log = logging.getLogger(__name__)


@click.command()
@click.argument("ms", type=click.Path(exists=False))
@click.option("-o", "--output", "output", required=True, type=click.Path(dir_okay=False),
              help="Figure file (PNG; the suffix chooses the format).")
@click.option("--fov", "fov_deg", type=float, default=15.0, show_default=True, metavar="DEG",
              help="Width of the square maps (deg, SIN projection about the phase centre).")
@click.option("--npix", type=int, default=61, show_default=True,
              help="Pixels per map side.")
@click.option("--hour-angles", "hour_angles", type=FloatList(), default=None,
              metavar="H1,H2,...", help="Hour angles of the phase centre (hours) nearest the "
              "middle of the observation. Default: 5 times spread over the observation.")
@click.option("--freq", "freq_hz", type=float, default=None, metavar="HZ",
              help="Frequency (Hz). Default: the middle channel of the first spectral window.")
@click.option("--beam", "beam_name",
              type=click.Choice(["everybeam", "everybeam-direct", "dipole"]),
              default="everybeam", show_default=True,
              help="Beam model: everybeam (LOFAR, fast evaluator), everybeam-direct "
              "(EveryBeam per direction, slow) or dipole (analytic, any MS).")
@click.option("--station", "station", default=None, metavar="NAME",
              help="Map one station (ANTENNA name). Default: Mueller matrices averaged over "
              "the stations that occur in the rows of field 0.")
@click.option("--diameter", "diameter_m", type=float, default=None, metavar="M",
              help="Dipole beam: station diameter (m) of its Airy station factor "
              "[default: ANTENNA::DISH_DIAMETER].")
@click.option("--product", "product", type=click.Path(dir_okay=False), default=None,
              help="Write the maps to this HDF5 product file (kind 'beam'). Default: the "
              "figure path with suffix .h5.")
@click.option("--invariant", is_flag=True,
              help="Plot the polarized beam as sqrt(M11^2+M12^2+M21^2+M22^2), independent of "
              "the Q,U reference frame (useful near a celestial pole); both are in the product.")
@click.option("--basis", type=click.Choice(BASES), default="tangent", show_default=True,
              help="Q,U frame of the maps: tangent, the phase centre's (North, East) basis "
              "parallel-transported to every pixel (one frame for the map); local, each "
              "pixel's own North, which turns around a celestial pole.")
@click.option("--pdf", is_flag=True, help="Also write a PDF beside the figure.")
def beam(ms, output, fov_deg, npix, hour_angles, freq_hz, beam_name, station, diameter_m,
         product, invariant, basis, pdf):
    """Maps of the polarized beam sqrt(M11^2+M22^2) and of the Q,U->I leakage
    sqrt(M01^2+M02^2)/M00 of MS's station beams, normalised to the phase centre, in dB,
    at several hour angles (docs/science.md section 8).

    \b
    Examples:
      msleak beam 3c196.ms -o beam.png
      msleak beam ncp.ms -o beam.png --fov 10 --hour-angles -6,-3,0,3,6
      msleak beam ska.ms -o beam.png --beam dipole --diameter 38
    """
    from msleak.beam import load_beam
    from msleak.beam.maps import (beam_maps, default_times, hour_angle_h,
                                  times_for_hour_angles)
    from msleak.conventions import feed_type_from_corr_types
    from msleak.io.ms import (check_ms, read_antennas, read_corr_types,
                              read_data_descriptions, read_spectral_windows, read_times,
                              read_used_antennas)
    from msleak.io.products import save_product
    from msleak.plot.beam import plot_beam_maps

    if not 0 < fov_deg < 180:
        raise click.BadParameter("must be between 0 and 180 degrees", param_hint="--fov")
    if npix < 2 or npix > 2049:
        raise click.BadParameter("must be between 2 and 2049", param_hint="--npix")
    if freq_hz is not None and freq_hz <= 0:
        raise click.BadParameter("must be positive (Hz)", param_hint="--freq")
    if diameter_m is not None and beam_name != "dipole":
        raise click.BadParameter("only applies to --beam dipole", param_hint="--diameter")
    ms = check_ms(ms)
    options = {"diameter_m": diameter_m} if diameter_m is not None else {}
    antennas = read_antennas(ms)
    in_rows = read_used_antennas(ms, field_id=0)
    used = in_rows
    if station is not None:
        names = [antennas.names[i] for i in in_rows]
        if station not in names:
            raise click.BadParameter(
                f"{station!r} is not an antenna of the rows of field 0 of {ms} (they are "
                f"{', '.join(names[:6])}{', ...' if len(names) > 6 else ''})",
                param_hint="--station")
        used = in_rows[[names.index(station)]]
    model = load_beam(beam_name, ms, field_id=0, stations=used, **options)
    ddid = read_data_descriptions(ms)
    pol_id = ddid[0][1] if ddid else 0
    feed = feed_type_from_corr_types(read_corr_types(ms)[pol_id])
    if freq_hz is None:
        freq = read_spectral_windows(ms)[ddid[0][0] if ddid else 0].freq
        freq_hz = float(freq[freq.size // 2])
    position = antennas.positions[in_rows].mean(axis=0)
    ra0 = model.phase_centre[0]
    times = read_times(ms, field_id=0)
    if hour_angles:
        mid = float(np.median(times)) if times.size else None
        if mid is None:
            raise click.UsageError(f"{ms} has no rows, so no date for --hour-angles")
        times = times_for_hour_angles(hour_angles, ra0, position, mid)
        has = np.asarray(hour_angles, float)
    else:
        times = default_times(times)
        has = hour_angle_h(times, ra0, position)
    log.info("beam maps of %s (%s) at %.3f MHz, hour angles %s h", ms, model.name,
             freq_hz / 1e6, ", ".join(f"{h:+.2f}" for h in has))
    ds = beam_maps(model, times, freq_hz, fov_deg=fov_deg, npix=npix, feed=feed,
                   hour_angles_h=has, basis=basis)
    ds.attrs["source"] = str(ms)
    product = Path(product) if product else Path(output).with_suffix(".h5")
    save_product(ds, product, "beam")
    figure = plot_beam_maps(ds, output, pdf=pdf, invariant=invariant,
                            title=f"{Path(ms).name}: {model.name} beam at "
                                  f"{freq_hz / 1e6:.2f} MHz, normalised to the phase centre"
                                  + (f" (station {station})" if station else
                                     f" (mean of {len(ds.attrs['stations'].split(','))} "
                                     "stations)"))
    click.echo(f"wrote {figure} and {product}")
