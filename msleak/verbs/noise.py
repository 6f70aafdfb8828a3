"""The noise verb: thermal noise by the radiometer equation into a column of an MS
(docs/noise.md).

Rows are read and written :data:`~msleak.telescope.noise.NOISE_CHUNK_ROWS` at a time; the
noise of a row depends on the seed and the row alone. Flagged samples (FLAG, FLAG_ROW) are
left as they are (zero in a new column). DATA is written only when asked.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msleak.errors import InputError
from msleak.io import columns as colio
from msleak.io.ms import append_history, check_ms, iter_rows, read_antennas
from msleak.io.products import call_record
from msleak.telescope.noise import NOISE_CHUNK_ROWS, radiometer_sigma, thermal_noise

__all__ = ["noise", "NoiseResult"]

log = logging.getLogger(__name__)


@dataclass
class NoiseResult:
    """What a noise run wrote: rows, samples (unflagged), and the mean rms (Jy) of a part."""

    ms: Path
    column: str
    rows_written: int
    samples: int
    sigma_jy: float


def noise(ms: str | os.PathLike, *, sefd: float | dict[str, float], column: str = "NOISE_DATA",
          seed: int = 0, add: bool = False, overwrite_data: bool = False) -> NoiseResult:
    """Write thermal noise into ``column`` of ``ms``.

    Parameters
    ----------
    ms : path
        Measurement Set, written in place.
    sefd : float or dict
        System equivalent flux density (Jy) of every station, or per station name (every
        used station needs one).
    column : str
        Target column, created like DATA if missing; DATA needs ``overwrite_data``.
    seed : int
        The noise of a row depends on ``seed`` and the row alone.
    add : bool
        Add the noise to the column's values (it must exist) instead of replacing them.

    Returns
    -------
    NoiseResult
    """
    given = dict(locals())
    path = check_ms(ms)
    colio.check_column_name(column, overwrite_data=overwrite_data)
    names = read_antennas(path).names
    station_sefd = _station_sefd(sefd, names)
    colio.check_writable(path)
    with colio.open_for_writing(path) as table:
        if add and column not in table.colnames():
            raise InputError(f"{path}: no column {column} to add noise to; leave out `add`, "
                             "or give a `column` that exists", param=("add", "column"))
        created = colio.ensure_data_column(table, column)
        rows_written, samples, power = _write(path, table, column, station_sefd, seed,
                                              add and not created)
    sigma = float(np.sqrt(power / max(samples, 1)))
    append_history(path, f"noise: SEFD {_describe(sefd)} Jy, seed {seed} -> {column}"
                         f"{' (added)' if add else ''}; mean rms {sigma:.4g} Jy per part",
                   command=call_record(noise, given))
    return NoiseResult(ms=path, column=column, rows_written=rows_written, samples=samples,
                       sigma_jy=sigma)


def _write(path: Path, table, column: str, station_sefd: np.ndarray, seed: int,
           add: bool) -> tuple[int, int, float]:
    """Draw and write the noise chunk by chunk; (rows, unflagged samples, sum of sigma^2)."""
    widths = _channel_widths(path)
    rows_written = samples = 0
    power = 0.0
    columns = ["ANTENNA1", "ANTENNA2", "EXPOSURE", "DATA_DESC_ID", "FLAG", "FLAG_ROW"]
    for k, (rows, cols) in enumerate(iter_rows(path, columns, chunk_rows=NOISE_CHUNK_ROWS)):
        flags = cols["FLAG"] | cols["FLAG_ROW"][:, None, None]
        sigma = np.zeros(flags.shape[:2])
        for d in np.unique(cols["DATA_DESC_ID"]):
            at = cols["DATA_DESC_ID"] == d
            sigma[at] = radiometer_sigma(station_sefd[cols["ANTENNA1"][at]],
                                         station_sefd[cols["ANTENNA2"][at]], widths[d],
                                         cols["EXPOSURE"][at])
        values = thermal_noise(sigma, flags.shape[2], seed, k)
        old = colio.read_rows(table, column, rows)
        values = np.where(flags, old, (old if add else 0) + values).astype(old.dtype)
        colio.write_rows(table, column, rows, values)
        keep = ~flags
        rows_written += rows.size
        samples += int(keep.sum())
        power += float(np.sum(np.broadcast_to(sigma[..., None], flags.shape)[keep] ** 2))
    return rows_written, samples, power


def _channel_widths(path: Path) -> list[np.ndarray]:
    """Per DATA_DESC_ID: the channel widths (Hz) of its spectral window."""
    from msleak.io.ms import read_data_descriptions, read_spectral_windows

    spws = read_spectral_windows(path)
    return [np.abs(np.asarray(spws[s].width, float)) for s, _ in read_data_descriptions(path)]


def _station_sefd(sefd, names: list[str]) -> np.ndarray:
    """SEFD (Jy) per ANTENNA row."""
    if isinstance(sefd, dict):
        missing = [n for n in names if n not in sefd]
        if missing:
            raise InputError(f"sefd has no value for station(s) {', '.join(missing[:5])}",
                             param="sefd")
        values = np.array([float(sefd[n]) for n in names])
    else:
        values = np.full(len(names), float(sefd))
    if not np.all(np.isfinite(values)) or np.any(values <= 0):
        raise InputError(f"sefd must be positive (Jy), got {_describe(sefd)}", param="sefd")
    return values


def _describe(sefd) -> str:
    return f"{float(sefd):g}" if not isinstance(sefd, dict) else "per station"
