"""Ionospheric rotation measures for an MS (docs/predict.md, "Ionosphere").

:func:`rotation_measures` turns a predict ``ionosphere`` setting into a
:class:`~msleak.beam.ionosphere.RotationMeasures`: a CSV table (:func:`read_rm_table`),
``random:SEED`` (drawn over the MS's times, :func:`msleak.beam.ionosphere.random_rm`), or a
thin-shell model computed offline for the MS's stations, times and fields: ``spinifex``
(IRI) or ``ionex:PATH`` (local IONEX maps), :mod:`msleak.adapters.spinifex_rm`.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np

from msleak.adapters.spinifex_rm import is_model_spec, model_rotation_measures
from msleak.beam.ionosphere import RotationMeasures, random_rm
from msleak.errors import InputError
from msleak.io.ms import read_times

__all__ = ["rotation_measures", "read_rm_table", "RM_COLUMNS"]

#: the columns of an RM table: UTC (ISO, or MJD seconds as in the MS), a station name or
#: ``*`` (every station without a row of its own), RM in rad m^-2
RM_COLUMNS = ("time", "station", "rm")


def rotation_measures(spec: str | os.PathLike, ms: str | os.PathLike) -> RotationMeasures:
    """The RMs of ``spec``: ``random:SEED``, ``spinifex[:f107=SFU]``, ``ionex:PATH[,PATH]``
    or the path of a CSV table (:data:`RM_COLUMNS`).

    Raises
    ------
    InputError
        A spec that is none of these, or a table or map that cannot be read.
    """
    text = str(spec)
    if is_model_spec(text) and not Path(text).is_file():
        return model_rotation_measures(text, ms)
    if text.startswith("random:"):
        seed = text.partition(":")[2]
        if not seed.isdigit():
            raise InputError(f"ionosphere {text!r}: give random:SEED with a whole-number "
                             "seed, e.g. random:1", param="ionosphere")
        return random_rm(read_times(ms), int(seed), label=text)
    path = Path(text)
    if not path.is_file():
        raise InputError(f"ionosphere {text!r} is not a file; give a CSV table with the "
                         f"columns {', '.join(RM_COLUMNS)}, random:SEED, spinifex or "
                         "ionex:PATH", param="ionosphere")
    return read_rm_table(path)


def read_rm_table(path: str | os.PathLike) -> RotationMeasures:
    """A CSV table of RMs (:data:`RM_COLUMNS`, any order, more columns ignored) on one time
    axis: each station's RMs interpolated linearly onto the union of the table's times.

    Raises
    ------
    InputError
        Missing columns, unreadable values, a station with a time twice.
    """
    rows = _read_rows(Path(path))
    series: dict[str, dict[float, float]] = {}
    for line, (time, station, rm) in rows:
        if time in series.setdefault(station, {}):
            raise InputError(f"{path}:{line}: station {station!r} has time {time} twice")
        series[station][time] = rm
    times = np.unique([t for s in series.values() for t in s])
    table = []
    for values in series.values():
        t = np.array(sorted(values))
        table.append(np.interp(times, t, [values[x] for x in t]))
    return RotationMeasures(times=times, rm=np.array(table), stations=tuple(series),
                            label=str(path))


def _read_rows(path: Path) -> list:
    """(line, (time MJD s, station, rm)) of every data row of the CSV file ``path``."""
    try:
        with open(path, newline="") as fh:
            reader = csv.DictReader(fh)
            fields = [f.strip().lower() for f in reader.fieldnames or []]
            missing = [c for c in RM_COLUMNS if c not in fields]
            if missing:
                raise InputError(f"{path}: no column {', '.join(missing)}; an RM table has "
                                 f"the header {','.join(RM_COLUMNS)}")
            rows = []
            for record in reader:
                record = {k.strip().lower(): (v or "").strip() for k, v in record.items() if k}
                rows.append((reader.line_num, _row(path, reader.line_num, record)))
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        raise InputError(f"{path}: not a readable CSV table ({err})") from None
    if not rows:
        raise InputError(f"{path}: no rows below the header")
    return rows


def _row(path: Path, line: int, record: dict) -> tuple[float, str, float]:
    try:
        rm = float(record["rm"])
    except ValueError:
        raise InputError(f"{path}:{line}: rm {record['rm']!r} is not a number") from None
    return _mjd_seconds(path, line, record["time"]), record["station"] or "*", rm


def _mjd_seconds(path: Path, line: int, text: str) -> float:
    """MJD seconds of a time given as a number (MJD s, the MS's TIME) or UTC ISO text."""
    try:
        return float(text)
    except ValueError:
        pass
    from astropy.time import Time

    try:
        return float(Time(text, scale="utc").mjd) * 86400.0
    except ValueError:
        raise InputError(f"{path}:{line}: time {text!r} is neither MJD seconds nor an ISO "
                         "UTC time") from None
