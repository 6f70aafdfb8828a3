"""The noise verb: thermal noise by the radiometer equation into a column of an MS
(docs/noise.md).

Rows are read and written :data:`~msleak.telescope.noise.NOISE_CHUNK_ROWS` at a time; the
noise of a row depends on the seed and the row alone. Flagged samples (FLAG, FLAG_ROW) are
left as they are: zero, or the source column's values. The target is never its own source, so
a rerun gives the same column; its ``MSLEAK_NOISE`` record keeps the run's progress (a rerun
of an interrupted run continues it; ``msleak grid`` refuses a column left half written).
DATA is written only when asked.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msleak.errors import InputError
from msleak.io import columns as colio
from msleak.io.ms import append_history, check_ms, iter_rows, read_antennas
from msleak.io.products import call_record
from msleak.telescope.noise import NOISE_CHUNK_ROWS, radiometer_sigma, thermal_noise

__all__ = ["noise", "add_noise", "station_sefd", "NoiseResult"]


@dataclass
class NoiseResult:
    """What a noise run wrote: rows, samples (unflagged), and the mean rms (Jy) of a part."""

    ms: Path
    column: str
    rows_written: int
    samples: int
    sigma_jy: float


def noise(ms: str | os.PathLike, *, sefd: float | dict[str, float], column: str = "NOISE_DATA",
          seed: int = 0, source: str | None = None,
          overwrite_data: bool = False) -> NoiseResult:
    """Write thermal noise into ``column`` of ``ms``, alone or on top of ``source``'s values.

    Parameters
    ----------
    ms : path
        Measurement Set, written in place.
    sefd : float or dict
        System equivalent flux density (Jy) of every station, or per station name (every
        ANTENNA row needs one).
    column : str
        Target column, created like ``source`` (or DATA) if missing; DATA needs
        ``overwrite_data``.
    seed : int
        The noise of a row depends on ``seed`` and the row alone.
    source : str, optional
        A column whose values the noise is added to (e.g. MODEL_DATA after predict); not
        ``column`` itself, so that a rerun gives the same result.

    Returns
    -------
    NoiseResult
    """
    given = dict(locals())
    path = check_ms(ms)
    colio.check_column_name(column, overwrite_data=overwrite_data)
    if source is not None and source == column:
        raise InputError(f"noise is written next to its `source`, not into it: give another "
                         f"`column` than {column}", param=("source", "column"))
    result = add_noise(path, column, sefd, seed, source)
    append_history(path, f"noise: SEFD {_describe(sefd)} Jy, seed {seed} -> {column}"
                         f"{f' (added to {source})' if source else ''}; mean rms "
                         f"{result.sigma_jy:.4g} Jy per part", command=call_record(noise, given))
    return result


def add_noise(path: Path, column: str, sefd: float | dict[str, float], seed: int,
              source: str | None, *, start_over: bool = False) -> NoiseResult:
    """Write noise into ``column`` of the MS at ``path`` (checked by the caller), alone or
    added to ``source`` (which may be ``column`` itself: predict's noise, added in place
    right after the column was predicted). An interrupted run of the same settings is
    continued unless ``start_over`` (the column was rewritten since)."""
    sefds = station_sefd(sefd, read_antennas(path).names)
    colio.check_writable(path)
    settings = f"sefd={_describe(sefd)},seed={seed},source={source or ''}"
    with colio.open_for_writing(path) as table:
        double = source is not None and _is_double(path, table, source)
        colio.ensure_data_column(table, column, double=double)
        state = None if start_over else colio.read_noise_state(table, column)
        start = int(state.get("rows_done", 0)) if state and not state.get("complete", True) \
            and state.get("settings") == settings else 0
        rows_written, samples, power = _write(path, table, column, source, sefds,
                                              seed, settings, start)
    return NoiseResult(ms=path, column=column, rows_written=rows_written, samples=samples,
                       sigma_jy=float(np.sqrt(power / max(samples, 1))))


def _is_double(path: Path, table, source: str) -> bool:
    """Whether ``source`` exists as complex128 (the target is then made so too)."""
    if source not in table.colnames():
        raise InputError(f"{path}: no column {source} to add noise to; give an existing "
                         "`source` (e.g. the column msleak predict wrote)", param="source")
    return table.getcoldesc(source).get("valueType") == "dcomplex"


def _write(path: Path, table, column: str, source: str | None, station_sefd: np.ndarray,
           seed: int, settings: str, start: int) -> tuple[int, int, float]:
    """Draw and write the noise chunk by chunk from row ``start`` on (an interrupted run of
    the same ``settings`` wrote those before), keeping the progress in the column's
    ``MSLEAK_NOISE`` record; (rows, unflagged samples, sum of sigma^2) written now."""
    widths = _channel_widths(path)
    rows_written = samples = 0
    power = 0.0
    columns = ["ANTENNA1", "ANTENNA2", "EXPOSURE", "DATA_DESC_ID", "FLAG", "FLAG_ROW"]
    state = {"settings": settings, "rows_done": start, "complete": False}
    colio.write_noise_state(table, column, state)
    for k, (rows, cols) in enumerate(iter_rows(path, columns, chunk_rows=NOISE_CHUNK_ROWS)):
        if rows[-1] < start:
            continue
        flags = cols["FLAG"] | cols["FLAG_ROW"][:, None, None]
        sigma = np.zeros(flags.shape[:2])
        for d in np.unique(cols["DATA_DESC_ID"]):
            at = cols["DATA_DESC_ID"] == d
            sigma[at] = radiometer_sigma(station_sefd[cols["ANTENNA1"][at]],
                                         station_sefd[cols["ANTENNA2"][at]], widths[d],
                                         cols["EXPOSURE"][at])
        base = colio.read_rows(table, source or column, rows)
        if source is None:
            base = np.zeros_like(base)
        values = np.where(flags, base, base + thermal_noise(sigma, flags.shape[2], seed, k))
        colio.write_rows(table, column, rows, values.astype(base.dtype))
        keep = ~flags
        rows_written += rows.size
        samples += int(keep.sum())
        power += float(np.sum(np.broadcast_to(sigma[..., None], flags.shape)[keep] ** 2))
        colio.write_noise_state(table, column, {**state, "rows_done": int(rows[-1]) + 1})
    colio.write_noise_state(table, column, {**state, "rows_done": table.nrows(),
                                            "complete": True})
    return rows_written, samples, power


def _channel_widths(path: Path) -> list[np.ndarray]:
    """Per DATA_DESC_ID: the channel widths (Hz) of its spectral window."""
    from msleak.io.ms import read_data_descriptions, read_spectral_windows

    spws = read_spectral_windows(path)
    return [np.abs(np.asarray(spws[s].width, float)) for s, _ in read_data_descriptions(path)]


def station_sefd(sefd, names: list[str]) -> np.ndarray:
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
