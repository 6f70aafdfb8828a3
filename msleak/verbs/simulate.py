"""The verb :func:`simulate` (``msleak simulate``): a new Measurement Set for a LOFAR-like
(or any) array.

Rows are ordered by time, then baseline (ANTENNA1 < ANTENNA2, autocorrelations only with
``autocorrelations=True``). TIME is the centre of each integration. DATA is zero, FLAG
false, WEIGHT_SPECTRUM one. Rows are written in time chunks so memory stays bounded
whatever the length of the observation (docs/simulate.md).
"""

from __future__ import annotations

import logging
import os
import shutil
from pathlib import Path

import numpy as np

from msleak.errors import InputError
from msleak.io.columns import check_free_space
from msleak.io.ms import append_history
from msleak.io.ms_create import create_ms_tables, main_table, put_main_rows
from msleak.io.mwa import write_mwa_tile_pointing
from msleak.io.phased_array import write_phased_array
from msleak.io.products import call_record
from msleak.telescope.observation import (TELESCOPE_LABELS, Observation, plan_observation,
                                          zenith_j2000)
from msleak.telescope.ska_low import station_element_offsets
from msleak.telescope.uvw import antenna_uvw

__all__ = ["simulate"]

log = logging.getLogger(__name__)

#: Rows written per chunk (memory: about this x nchan x 4 x 13 bytes)
_CHUNK_ROWS = 200_000


def simulate(output: str | os.PathLike, *, field: str | None = None,
             phase_centre: tuple[float, float] | None = None, start: str | None = None,
             duration: float | None = None, interval: float = 120.0,
             freq_min: float | None = None, nchan: int = 50, chan_width: float = 195312.5,
             stations: str | None = None, layout: str | os.PathLike | None = None,
             autocorrelations: bool = False, telescope: str = "lofar",
             overwrite: bool = False, progress: bool = False) -> Path:
    """Create the Measurement Set ``output`` (``msleak simulate``, docs/simulate.md).

    Parameters
    ----------
    output : path
        The new MS; an existing one is refused unless ``overwrite``.
    field : {'ncp', '3c196', 'eor0'}, optional
        Observing preset (phase centre, duration, date); default the telescope's
        (``'3c196'`` for LOFAR, ``'eor0'`` for the others) unless ``phase_centre`` is given.
    phase_centre : (ra_deg, dec_deg), optional
        J2000 phase centre in degrees; overrides the preset's.
    start : str, optional
        ISO UTC start; default the preset's (centred on transit for 3C196 and any
        custom phase centre).
    duration, interval : float
        Synthesis time (hours) and integration time (seconds).
    freq_min, nchan, chan_width : float, int, float
        Channel i is centred at ``freq_min + i * chan_width`` (Hz); ``freq_min`` defaults
        to 150 MHz, for HERA to 135 MHz (its beam file ends at 145 MHz).
    stations : str, optional
        Station name patterns, comma-separated, e.g. ``"CS00[1-3]HBA*"``.
    layout : path, optional
        Layout text file of another array (no LOFAR beam tables then; with
        ``telescope='ska-low'``, real SKA-Low station positions).
    autocorrelations : bool
        Include autocorrelation rows.
    telescope : {'lofar', 'ska-low', 'hera', 'mwa'}
        LOFAR HBA core (default); an approximate SKA-Low core of 224 stations of 256
        elements with the PHASED_ARRAY table EveryBeam reads (docs/ska_low.md); HERA's 350
        dishes or the MWA's 128 tiles (zenith-fixed beams: 1 h around transit by default;
        docs/telescopes.md).
    progress : bool
        Show a progress bar on stderr.

    Returns
    -------
    pathlib.Path
        The MS, with a HISTORY row saying what was simulated.
    """
    call = dict(locals())
    path = Path(output)
    obs = plan_observation(telescope, field=field, phase_centre=phase_centre, start=start,
                           duration=duration, interval=interval, freq_min=freq_min,
                           nchan=nchan, chan_width=chan_width, stations=stations,
                           layout=layout)
    _prepare_output(path, overwrite)
    a1, a2 = np.triu_indices(len(obs.layout), k=0 if autocorrelations else 1)
    nrows = len(obs.times) * len(a1)
    log.info("creating %s: %d antennas, %d baselines, %d times x %.0f s, %d channels (%d rows)",
             path, len(obs.layout), len(a1), len(obs.times), interval, nchan, nrows)
    # DATA (complex64), WEIGHT_SPECTRUM (float32), FLAG (bits), ~200 B of other columns a
    # row, plus tiles and subtables: casacore aborts the process on a full disk.
    check_free_space(path.parent, nrows * (int(nchan) * 4 * 12.2 + 200) + 1.5 * 2**20,
                     f"the Measurement Set {path}")
    try:
        _write_ms(path, obs, telescope, a1, a2, progress)
        what = TELESCOPE_LABELS[telescope] + \
            (" (approximate core)" if telescope == "ska-low" and layout is None else "")
        append_history(path, f"simulated {len(obs.layout)} {what} stations, field {obs.name}, "
                             f"{len(obs.times)} x {interval:g} s, {int(nchan)} channels of "
                             f"{chan_width:.10g} Hz from {obs.freq[0]:.10g} Hz",
                       command=call_record(simulate, call, skip=("progress",)))
    except BaseException:
        log.error("simulate interrupted; %s is incomplete: rerun with --overwrite", path)
        raise
    return path


def _write_ms(path: Path, obs: Observation, telescope: str, a1, a2, progress: bool) -> None:
    """The tables of ``obs``, its main-table rows and the beam model's extra tables."""
    lay = obs.layout
    ra, dec = np.radians(obs.ra_deg), np.radians(obs.dec_deg)
    create_ms_tables(path, names=lay.names, positions=lay.positions, diameters=lay.diameters,
                     telescope=lay.telescope, freq=obs.freq, chan_width=obs.chan_width,
                     ra=ra, dec=dec, field_name=obs.name, time_range=obs.time_range,
                     nrows=len(obs.times) * len(a1),
                     lofar_fields=lay.fields if lay.is_lofar else None)
    _fill_main(path, obs, a1, a2, ra, dec, progress)
    _write_beam_tables(path, telescope, obs)


def _write_beam_tables(path: Path, telescope: str, obs: Observation) -> None:
    """What the beam model of ``telescope`` reads besides the standard subtables: SKA-Low's
    PHASED_ARRAY, the MWA's MWA_TILE_POINTING (zenith delays, pointing at the zenith
    mid-way through the observation). LOFAR's tables come with the MS."""
    positions = obs.layout.positions
    if telescope == "ska-low":
        axes, offsets = station_element_offsets(positions)
        write_phased_array(path, positions, axes, offsets)
    elif telescope == "mwa":
        time_range = obs.time_range
        mid = 0.5 * (time_range[0] + time_range[1])
        write_mwa_tile_pointing(path, time_range,
                                direction=zenith_j2000(positions.mean(axis=0), mid))


def _prepare_output(path: Path, overwrite: bool) -> None:
    """Refuse an existing ``path`` unless ``overwrite`` (then remove it, if an MS)."""
    if path.exists():
        if not overwrite:
            raise InputError(f"{path} exists; pass overwrite to replace it", param="overwrite")
        if path.is_dir() and not (path / "table.dat").exists():
            raise InputError(f"{path} exists and is not a Measurement Set; refusing to replace it")
        shutil.rmtree(path) if path.is_dir() else path.unlink()
    if not path.parent.exists():
        raise InputError(f"{path.parent}: no such directory")


def _fill_main(path: Path, obs: Observation, a1, a2, ra: float, dec: float,
               progress: bool) -> None:
    """The main-table rows, a chunk of times at a time, with their UVW."""
    nbl, nchan = len(a1), len(obs.freq)
    times_per_chunk = max(1, _CHUNK_ROWS // nbl)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(obs.times), unit="slot", desc="simulate", leave=False)
    with main_table(path) as ms:
        for t0 in range(0, len(obs.times), times_per_chunk):
            tchunk = obs.times[t0:t0 + times_per_chunk]
            auvw = antenna_uvw(obs.layout.positions, tchunk, ra, dec)   # (nt, nant, 3)
            uvw = (auvw[:, a2, :] - auvw[:, a1, :]).reshape(len(tchunk) * nbl, 3)
            put_main_rows(ms, t0 * nbl, tchunk, obs.interval, a1, a2, uvw, nchan)
            if bar is not None:
                bar.update(len(tchunk))
    if bar is not None:
        bar.close()
