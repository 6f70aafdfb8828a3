"""``msleak simulate``: create a Measurement Set (LOFAR HBA core by default)."""

from __future__ import annotations

import logging
import sys

import click

from msleak.cli._common import FloatList

log = logging.getLogger(__name__)


@click.command()
@click.argument("out", type=click.Path(dir_okay=True, file_okay=True))
@click.option("--field", type=click.Choice(["ncp", "3c196"], case_sensitive=False),
              default=None, help="Observing preset: ncp (RA 0, Dec 90, 13 h) or 3c196 "
              "(RA 123.4, Dec 48.2 deg, 8 h centred on transit). Default 3c196 unless "
              "--phase-centre is given.")
@click.option("--phase-centre", "phase_centre", type=FloatList(2), default=None,
              metavar="RA_DEG,DEC_DEG", help="Phase centre (J2000, degrees); overrides the preset.")
@click.option("--start", default=None, metavar="ISO",
              help="UTC start, e.g. 2012-12-16T20:00:00. Default: the preset's (3C196 and "
              "custom centres: centred on transit at the array).")
@click.option("--duration", "duration_h", type=float, default=None, metavar="HOURS",
              help="Synthesis time in hours [preset: 13 (ncp), 8 (3c196)].")
@click.option("--interval", "interval_s", type=float, default=120.0, show_default=True,
              metavar="SEC", help="Integration time in seconds.")
@click.option("--freq-min", "freq_min_hz", type=float, default=150e6, show_default=True,
              metavar="HZ", help="Centre frequency of the first channel (Hz).")
@click.option("--nchan", type=int, default=50, show_default=True, help="Number of channels.")
@click.option("--chan-width", "chan_width_hz", type=float, default=195312.5, show_default=True,
              metavar="HZ", help="Channel width (Hz).")
@click.option("--stations", default=None, metavar="PATTERN",
              help="Station (antenna field) names to use: shell patterns, comma-separated, "
              "e.g. 'CS00[1-7]HBA*'. Default: all 48 HBA core fields, or all of --layout.")
@click.option("--layout", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Layout text file for another array (format: docs/simulate.md); the MS "
              "then has no LOFAR beam tables.")
@click.option("--autocorrelations/--no-autocorrelations", default=False, show_default=True,
              help="Include autocorrelation rows.")
@click.option("--overwrite", is_flag=True, help="Replace OUT if it exists.")
def simulate(out, field, phase_centre, start, duration_h, interval_s, freq_min_hz, nchan,
             chan_width_hz, stations, layout, autocorrelations, overwrite):
    """Create the Measurement Set OUT: UVW, subtables and (for LOFAR) the beam tables
    EveryBeam needs, DATA zero, FLAG false, WEIGHT_SPECTRUM one.

    \b
    Examples:
      msleak simulate ncp.ms --field ncp
      msleak simulate 3c196.ms --field 3c196 --interval 10
      msleak simulate small.ms --stations 'CS00[1-3]HBA*' --duration 1 --nchan 10
      msleak simulate ska.ms --layout my_array.txt --phase-centre 60,-30
    """
    from msleak.io.ms import ms_summary
    from msleak.telescope.simulate import simulate_ms

    if field is None and phase_centre is None:
        field = "3c196"
    path = simulate_ms(out, field=field, phase_centre=tuple(phase_centre) if phase_centre else None,
                       start=start, duration_h=duration_h, interval_s=interval_s,
                       freq_min_hz=freq_min_hz, nchan=nchan, chan_width_hz=chan_width_hz,
                       stations=stations, layout=layout, autocorrelations=autocorrelations,
                       overwrite=overwrite, progress=sys.stderr.isatty())
    click.echo(ms_summary(path))
