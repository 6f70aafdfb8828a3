"""System equivalent flux densities for thermal noise (docs/noise.md): one value for every
station, or a CSV table of one value per station."""

from __future__ import annotations

import csv
import math
from pathlib import Path

from msleak.errors import InputError

__all__ = ["read_sefd", "SEFD_COLUMNS"]

#: the columns of a per-station SEFD table: the ANTENNA NAME and its SEFD (Jy)
SEFD_COLUMNS = ("station", "sefd")


def _names() -> str:
    return " and ".join(f"'{c}'" for c in SEFD_COLUMNS)


def read_sefd(text: str | float, param: str = "sefd") -> float | dict[str, float]:
    """``text`` as one SEFD (Jy), or the per-station SEFDs of the CSV table it names
    (columns :data:`SEFD_COLUMNS`).

    Raises
    ------
    InputError
        Neither a number nor a readable table; a table without the columns, with a value
        that is not a positive number, or with a station twice.
    """
    try:
        value = float(text)
    except (TypeError, ValueError):
        value = None
    if value is not None:
        return value
    path = Path(str(text))
    if not path.is_file():
        raise InputError(f"{param} {text!r} is neither a number (Jy) nor a CSV table with "
                         f"the columns {_names()}", param=param)
    with path.open(newline="") as handle:
        reader = csv.DictReader(handle)
        if not reader.fieldnames or not set(SEFD_COLUMNS) <= {f.strip() for f in
                                                               reader.fieldnames}:
            raise InputError(f"{path}: give the columns {_names()} "
                             f"(found {', '.join(reader.fieldnames or []) or 'none'})",
                             param=param)
        table: dict[str, float] = {}
        for line, row in enumerate(reader, start=2):
            row = {k.strip(): (v or "").strip() for k, v in row.items() if k}
            name = row["station"]
            try:
                sefd = float(row["sefd"])
            except ValueError:
                sefd = math.nan
            if not (math.isfinite(sefd) and sefd > 0):
                raise InputError(f"{path}, line {line}: SEFD {row['sefd']!r} of {name} is "
                                 "not a positive number (Jy)", param=param)
            if name in table:
                raise InputError(f"{path}, line {line}: station {name} appears twice",
                                 param=param)
            table[name] = sefd
    return table
