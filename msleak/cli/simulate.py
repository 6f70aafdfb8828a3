"""``msleak simulate``: create a Measurement Set (LOFAR HBA core by default, or SKA-Low)."""

from __future__ import annotations

import logging
import sys

import click

from msleak.cli._common import FloatList
from msleak.io.ms import ms_summary
from msleak.telescope.observation import FIELD_PRESETS, TELESCOPES
from msleak.verbs import simulate as verb

log = logging.getLogger(__name__)


@click.command()
@click.argument("out", type=click.Path(dir_okay=True, file_okay=True))
@click.option("--telescope", type=click.Choice(list(TELESCOPES)), default="lofar",
              show_default=True, help="lofar: the HBA core (48 fields); ska-low: an "
              "approximate SKA-Low core (224 stations of 256 elements, docs/ska_low.md) with "
              "the PHASED_ARRAY table EveryBeam reads; hera: HERA's 350 dishes; mwa: the "
              "MWA's 128 tiles (hera and mwa need pip install 'msleak[hera]' or "
              "'msleak[mwa]'; docs/telescopes.md).")
@click.option("--field", type=click.Choice(list(FIELD_PRESETS), case_sensitive=False),
              default=None, help="Observing preset: ncp (RA 0, Dec 90, 13 h), 3c196 "
              "(RA 123.4, Dec 48.2 deg, 8 h centred on transit) or eor0 (RA 0, Dec -27 deg, "
              "8 h centred on transit). Default 3c196 for LOFAR, eor0 for the others, unless "
              "--phase-centre is given.")
@click.option("--phase-centre", "phase_centre", type=FloatList(2), default=None,
              metavar="RA_DEG,DEC_DEG", help="Phase centre (J2000, degrees); overrides the preset.")
@click.option("--start", default=None, metavar="ISO",
              help="UTC start, e.g. 2012-12-16T20:00:00. Default: the preset's (3C196 and "
              "custom centres: centred on transit at the array).")
@click.option("--duration", type=float, default=None, metavar="HOURS",
              help="Synthesis time in hours [preset: 13 (ncp), 8 (3c196, eor0); 1 for hera "
              "and mwa, whose beams do not track].")
@click.option("--interval", type=float, default=120.0, show_default=True,
              metavar="SEC", help="Integration time in seconds.")
@click.option("--freq-min", "freq_min", type=float, default=None, metavar="HZ",
              help="Centre frequency of the first channel (Hz) [default: 150e6; hera: "
              "135e6, inside its beam file's 100-145 MHz].")
@click.option("--nchan", type=int, default=50, show_default=True, metavar="N",
              help="Number of channels.")
@click.option("--chan-width", "chan_width", type=float, default=195312.5, show_default=True,
              metavar="HZ", help="Channel width (Hz).")
@click.option("--stations", default=None, metavar="PATTERN",
              help="Station (antenna field) names to use: shell patterns, comma-separated, "
              "e.g. 'CS00[1-7]HBA*' (LOFAR), 'S00*' (SKA-Low), 'HH1??' (HERA) or "
              "'Tile0*' (MWA). Default: all stations of "
              "the telescope, or all of --layout.")
@click.option("--layout", type=click.Path(exists=True, dir_okay=False), default=None,
              metavar="FILE", help="Layout text file for another array (format: "
              "docs/simulate.md; with --telescope ska-low, hera or mwa, that telescope's "
              "real positions); a LOFAR "
              "MS from a layout file has no LOFAR beam tables.")
@click.option("--autocorrelations/--no-autocorrelations", default=False, show_default=True,
              help="Include autocorrelation rows.")
@click.option("--overwrite", is_flag=True, help="Replace OUT if it exists.")
def simulate(out, telescope, field, phase_centre, start, duration, interval, freq_min, nchan,
             chan_width, stations, layout, autocorrelations, overwrite):
    """Create the Measurement Set OUT: UVW, subtables and (for LOFAR) the beam tables
    EveryBeam needs, DATA zero, FLAG false, WEIGHT_SPECTRUM one.

    \b
    Examples:
      msleak simulate ncp.ms --field ncp
      msleak simulate 3c196.ms --field 3c196 --interval 10
      msleak simulate small.ms --stations 'CS00[1-3]HBA*' --duration 1 --nchan 10
      msleak simulate ska.ms --telescope ska-low --stations 'S00*' --duration 2
      msleak simulate toy.ms --layout my_array.txt --phase-centre 60,-30
    """
    path = verb.simulate(out, field=field,
                         phase_centre=tuple(phase_centre) if phase_centre else None,
                         start=start, duration=duration, interval=interval,
                         freq_min=freq_min, nchan=nchan, chan_width=chan_width,
                         stations=stations, layout=layout, autocorrelations=autocorrelations,
                         telescope=telescope, overwrite=overwrite,
                         progress=sys.stderr.isatty())
    click.echo(ms_summary(path))
