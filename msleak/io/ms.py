"""Measurement Set readers: one function per subtable, returning arrays, not open tables.

All readers check that the MS and the subtable exist and raise
:class:`~msleak.errors.InputError` with a one-line message otherwise. Tables are opened
with ``ack=False`` inside ``with`` blocks. Main-table data are read in row chunks by
:func:`iter_rows` so memory stays bounded whatever the size of the MS.
"""

from __future__ import annotations

import contextlib
import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from msleak import __version__
from msleak.conventions import CORR_NAMES
from msleak.errors import InputError

__all__ = [
    "SpectralWindow", "Field", "Antennas", "BeamDirections", "read_beam_directions",
    "check_ms", "open_table", "column_names", "data_column_names", "read_spectral_windows",
    "read_data_descriptions", "read_corr_types", "read_fields", "read_antennas",
    "read_used_antennas", "read_times", "read_telescope_name", "has_subtable", "has_lofar_tables",
    "resolve_field", "resolve_spw", "select_rows", "iter_rows",
    "append_history", "read_history", "ms_summary",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SpectralWindow:
    """One SPECTRAL_WINDOW row: channel centres ``freq`` and widths ``width`` (nchan,), Hz."""

    freq: np.ndarray
    width: np.ndarray
    name: str = ""

    @property
    def nchan(self) -> int:
        return int(self.freq.size)


@dataclass(frozen=True)
class Field:
    """One FIELD row: name and J2000 phase centre (rad)."""

    name: str
    ra: float
    dec: float


@dataclass(frozen=True)
class Antennas:
    """The ANTENNA table: ``names`` (nant,), ITRF ``positions`` (nant, 3) m, ``diameter`` (nant,) m."""

    names: list
    positions: np.ndarray
    diameter: np.ndarray
    stations: list

    def __len__(self) -> int:
        return len(self.names)


def _casacore_tables():
    import casacore.tables as pt

    return pt


def check_ms(path: str | os.PathLike) -> Path:
    """Return ``path`` as a Path if it is a readable Measurement Set, else raise InputError."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such Measurement Set")
    if not path.is_dir() or not (path / "table.dat").exists():
        from msleak.io.products import describe_path

        what = describe_path(path)[1]
        raise InputError(f"{path} {what}, not a Measurement Set (no casacore table there); "
                         "give an MS, e.g. one `msleak simulate OUT.ms` makes")
    for sub in ("ANTENNA", "SPECTRAL_WINDOW", "POLARIZATION", "FIELD", "DATA_DESCRIPTION"):
        if not (path / sub / "table.dat").exists():
            raise InputError(f"{path}: not a complete Measurement Set (no {sub} subtable)")
    return path


@contextlib.contextmanager
def open_table(path: str | os.PathLike, readonly: bool = True, lockoptions: str = "auto"):
    """Open a casacore table (``ack=False``) as a context manager."""
    pt = _casacore_tables()
    try:
        table = pt.table(str(path), readonly=readonly, ack=False, lockoptions=lockoptions)
    except RuntimeError as err:
        raise InputError(f"{path}: cannot open table ({' '.join(str(err).split())[:160]})") from err
    try:
        yield table
    finally:
        table.close()


def _subtable(ms: Path, name: str) -> Path:
    sub = Path(ms) / name
    if not (sub / "table.dat").exists():
        raise InputError(f"{ms}: Measurement Set has no {name} subtable")
    return sub


def column_names(ms: str | os.PathLike) -> list[str]:
    """Names of the main-table columns."""
    with open_table(check_ms(ms)) as t:
        return list(t.colnames())


def data_column_names(ms: str | os.PathLike) -> list[str]:
    """Names of the main-table columns holding complex visibilities (DATA, MODEL_DATA,
    CORRECTED_DATA, MODEL_4DEG, ...), in table order."""
    with open_table(check_ms(ms)) as t:
        return [c for c in t.colnames()
                if str(t.getcoldesc(c).get("valueType", "")).lower() in ("complex", "dcomplex")]


def read_spectral_windows(ms: str | os.PathLike) -> list[SpectralWindow]:
    """Every SPECTRAL_WINDOW row (channel centres and widths in Hz)."""
    with open_table(_subtable(check_ms(ms), "SPECTRAL_WINDOW")) as t:
        out = []
        for row in range(t.nrows()):
            freq = np.asarray(t.getcell("CHAN_FREQ", row), dtype=float)
            width = np.abs(np.asarray(t.getcell("CHAN_WIDTH", row), dtype=float))
            name = t.getcell("NAME", row) if "NAME" in t.colnames() else ""
            out.append(SpectralWindow(freq=freq, width=width, name=str(name)))
    return out


def read_data_descriptions(ms: str | os.PathLike) -> list[tuple[int, int]]:
    """(SPECTRAL_WINDOW_ID, POLARIZATION_ID) of every DATA_DESCRIPTION row."""
    with open_table(_subtable(check_ms(ms), "DATA_DESCRIPTION")) as t:
        spw = t.getcol("SPECTRAL_WINDOW_ID")
        pol = t.getcol("POLARIZATION_ID")
    return [(int(s), int(p)) for s, p in zip(spw, pol)]


def read_corr_types(ms: str | os.PathLike) -> list[np.ndarray]:
    """CORR_TYPE of every POLARIZATION row."""
    with open_table(_subtable(check_ms(ms), "POLARIZATION")) as t:
        return [np.asarray(t.getcell("CORR_TYPE", row), dtype=int) for row in range(t.nrows())]


def read_fields(ms: str | os.PathLike) -> list[Field]:
    """Name and phase centre (PHASE_DIR, rad) of every FIELD row."""
    with open_table(_subtable(check_ms(ms), "FIELD")) as t:
        names = t.getcol("NAME") if t.nrows() else []
        out = []
        for row in range(t.nrows()):
            direction = np.asarray(t.getcell("PHASE_DIR", row), dtype=float).reshape(-1, 2)[0]
            out.append(Field(name=str(names[row]), ra=float(direction[0]), dec=float(direction[1])))
    if not out:
        raise InputError(f"{ms}: FIELD table is empty")
    return out


@dataclass(frozen=True)
class BeamDirections:
    """The pointing of one FIELD row, J2000 (ra, dec) in rad: ``phase`` (PHASE_DIR),
    ``delay`` (DELAY_DIR, where the station beam is steered) and ``tile``
    (LOFAR_TILE_BEAM_DIR, where LOFAR HBA tiles are steered)."""

    phase: tuple[float, float]
    delay: tuple[float, float]
    tile: tuple[float, float]


def read_beam_directions(ms: str | os.PathLike, field_id: int = 0) -> BeamDirections:
    """Phase centre and beam-former directions of FIELD row ``field_id``.

    The one fallback: a beam without its own direction column points where the next one
    does (no DELAY_DIR: the phase centre; no LOFAR_TILE_BEAM_DIR: the DELAY_DIR).
    """
    ms = check_ms(ms)
    with open_table(_subtable(ms, "FIELD")) as t:
        if not 0 <= int(field_id) < t.nrows():
            raise InputError(f"{ms}: no FIELD_ID {field_id} (the MS has {t.nrows()})")
        cols = t.colnames()

        def direction(column: str, default: tuple) -> tuple[float, float]:
            if column not in cols:
                return default
            value = np.asarray(t.getcell(column, int(field_id)), dtype=float).reshape(-1, 2)[0]
            return float(value[0]), float(value[1])

        phase = direction("PHASE_DIR", None)
        delay = direction("DELAY_DIR", phase)
        return BeamDirections(phase=phase, delay=delay,
                              tile=direction("LOFAR_TILE_BEAM_DIR", delay))


def read_antennas(ms: str | os.PathLike) -> Antennas:
    """Names, ITRF positions (m) and dish diameters of every ANTENNA row."""
    with open_table(_subtable(check_ms(ms), "ANTENNA")) as t:
        names = [str(n) for n in t.getcol("NAME")]
        positions = np.asarray(t.getcol("POSITION"), dtype=float).reshape(-1, 3)
        diameter = np.asarray(t.getcol("DISH_DIAMETER"), dtype=float)
        stations = [str(s) for s in t.getcol("STATION")]
    return Antennas(names=names, positions=positions, diameter=diameter, stations=stations)


def read_used_antennas(ms: str | os.PathLike, field_id: int | None = None,
                       ddid: int | None = None) -> np.ndarray:
    """Sorted ANTENNA row numbers that occur as ANTENNA1 or ANTENNA2 in the main-table rows
    of ``field_id`` and ``ddid`` (all rows when None).

    Placeholder ANTENNA rows (never used, flagged, at the origin) that CASA or pyuvdata
    write are thereby left out of every per-station average or check.
    """
    used = np.zeros(0, dtype=np.int64)
    for _, cols in iter_rows(ms, ["ANTENNA1", "ANTENNA2"], field_id=field_id, ddid=ddid,
                             chunk_rows=1_000_000):
        used = np.union1d(used, np.concatenate([cols["ANTENNA1"], cols["ANTENNA2"]]))
    what = " and ".join(f"{name} {value}" for name, value in
                        (("FIELD_ID", field_id), ("DATA_DESC_ID", ddid)) if value is not None)
    if used.size == 0:
        raise InputError(f"{ms}: no rows{' for ' + what if what else ''}, so no antennas")
    with open_table(_subtable(check_ms(ms), "ANTENNA")) as t:
        nant = t.nrows()
    if used[0] < 0 or used[-1] >= nant:
        raise InputError(f"{ms}: ANTENNA1/ANTENNA2 refer to antenna "
                         f"{used[0] if used[0] < 0 else used[-1]}, the ANTENNA table has "
                         f"{nant} rows")
    return used.astype(np.int64)


def read_telescope_name(ms: str | os.PathLike) -> str:
    """OBSERVATION::TELESCOPE_NAME of the first row ('' if absent)."""
    sub = Path(check_ms(ms)) / "OBSERVATION"
    if not (sub / "table.dat").exists():
        return ""
    with open_table(sub) as t:
        return str(t.getcell("TELESCOPE_NAME", 0)) if t.nrows() else ""


def has_subtable(ms: str | os.PathLike, name: str) -> bool:
    """True if the MS has the subtable ``name`` (e.g. LOFAR_ANTENNA_FIELD, MWA_TILE_POINTING)."""
    return (check_ms(ms) / name / "table.dat").exists()


def has_lofar_tables(ms: str | os.PathLike) -> bool:
    """True if the MS has the LOFAR subtables EveryBeam needs for a LOFAR station beam."""
    ms = check_ms(ms)
    if not has_subtable(ms, "LOFAR_ANTENNA_FIELD"):
        return False
    with open_table(Path(ms) / "FIELD") as t:
        has_tile_dir = "LOFAR_TILE_BEAM_DIR" in t.colnames()
    with open_table(Path(ms) / "ANTENNA") as t:
        has_ref = "LOFAR_PHASE_REFERENCE" in t.colnames()
    return has_tile_dir and has_ref


def read_times(ms: str | os.PathLike, field_id: int | None = None,
               ddid: int | None = None) -> np.ndarray:
    """Sorted unique TIME values (MJD seconds, integration centres) of the main table."""
    times = []
    for _, cols in iter_rows(ms, ["TIME"], field_id=field_id, ddid=ddid, chunk_rows=1_000_000):
        times.append(np.unique(cols["TIME"]))
    if not times:
        return np.zeros(0)
    return np.unique(np.concatenate(times))


def resolve_field(ms: str | os.PathLike, field: int | str) -> int:
    """FIELD_ID of ``field``: an id (int or digits) or a FIELD::NAME."""
    names = [f.name for f in read_fields(ms)]
    text = str(field).strip()
    if text.lstrip("-").isdigit():
        index = int(text)
        if not 0 <= index < len(names):
            raise InputError(f"{ms}: no FIELD_ID {index} (the MS has {len(names)} fields); "
                             "give `field` ID or NAME", param="field")
        return index
    if text not in names:
        raise InputError(f"{ms}: no field named {text!r} (fields: "
                         f"{', '.join(f'{i}:{n}' for i, n in enumerate(names))}); "
                         "give `field` ID or NAME", param="field")
    return names.index(text)


def resolve_spw(ms: str | os.PathLike, spw: int) -> int:
    """DATA_DESC_ID of spectral window ``spw`` (the first DATA_DESCRIPTION row naming it)."""
    spws = [s for s, _ in read_data_descriptions(ms)]
    if int(spw) not in spws:
        raise InputError(f"{ms}: no spectral window {spw} in the DATA_DESCRIPTION table "
                         f"(spectral windows: {', '.join(map(str, sorted(set(spws))))}); "
                         "give one with `spw`", param="spw")
    return spws.index(int(spw))


def _selection(table, field_id, ddid):
    conditions = []
    if field_id is not None:
        conditions.append(f"FIELD_ID=={int(field_id)}")
    if ddid is not None:
        conditions.append(f"DATA_DESC_ID=={int(ddid)}")
    if not conditions:
        return table, None
    sel = table.query(" && ".join(conditions), sortlist="", columns="")
    return sel, sel.rownumbers(table)


def select_rows(ms: str | os.PathLike, *, field_id: int | None = None,
                ddid: int | None = None) -> np.ndarray:
    """Main-table row numbers (ascending) of ``field_id`` and ``ddid`` (None: any)."""
    with open_table(check_ms(ms)) as table:
        sel, rownumbers = _selection(table, field_id, ddid)
        if rownumbers is None:
            return np.arange(table.nrows(), dtype=np.int64)
        sel.close()
    return np.asarray(rownumbers, dtype=np.int64)


def iter_rows(ms: str | os.PathLike, columns: Sequence[str], *, chunk_rows: int = 100_000,
              field_id: int | None = None, ddid: int | None = None,
              rows: np.ndarray | None = None,
              readonly: bool = True) -> Iterator[tuple[np.ndarray, dict]]:
    """Yield ``(row_numbers, {column: array})`` chunks of the main table, in row order.

    Arrays come as casacore returns them: DATA ``(row, chan, corr)``, UVW ``(row, 3)``, ...
    ``row_numbers`` index the full main table (also when a selection is made). ``rows``
    (ascending main-table row numbers, e.g. a slice of :func:`select_rows`) reads those
    rows only, instead of a ``field_id``/``ddid`` selection.
    """
    ms = check_ms(ms)
    if chunk_rows <= 0:
        raise InputError("chunk size must be positive")
    with open_table(ms, readonly=readonly) as table:
        missing = [c for c in columns if c not in table.colnames()]
        if missing:
            raise InputError(f"{ms}: no column {', '.join(missing)} "
                             f"(columns: {', '.join(table.colnames())})")
        if rows is not None:
            yield from _iter_given_rows(table, columns, np.asarray(rows, np.int64), chunk_rows)
            return
        sel, rownumbers = _selection(table, field_id, ddid)
        try:
            nrow = sel.nrows()
            for start in range(0, nrow, chunk_rows):
                n = min(chunk_rows, nrow - start)
                got = (np.arange(start, start + n) if rownumbers is None
                       else np.asarray(rownumbers[start:start + n]))
                yield got, {c: sel.getcol(c, startrow=start, nrow=n) for c in columns}
        finally:
            if sel is not table:
                sel.close()


def _iter_given_rows(table, columns, rows: np.ndarray, chunk_rows: int):
    """Chunks of the given ascending rows: one read per column where they are contiguous."""
    for start in range(0, rows.size, chunk_rows):
        part = rows[start:start + chunk_rows]
        first, n = int(part[0]), int(part.size)
        if int(part[-1]) - first + 1 == n:
            yield part, {c: table.getcol(c, startrow=first, nrow=n) for c in columns}
            continue
        sel = table.selectrows(part.tolist())
        try:
            yield part, {c: sel.getcol(c) for c in columns}
        finally:
            sel.close()


def append_history(ms: str | os.PathLike, message: str, *, command: str = "") -> None:
    """Add one row to the MS HISTORY subtable (as DP3 and CASA tasks do): the time, the
    message, the application ``msleak <version>`` and the command line.

    Does nothing when the MS has no HISTORY subtable (it is optional in the MS definition).
    """
    ms = check_ms(ms)
    path = ms / "HISTORY"
    if not path.exists():
        log.debug("%s has no HISTORY subtable; no history row written", ms)
        return
    now = (np.datetime64("now", "s") - np.datetime64("1858-11-17T00:00:00", "s"))
    with open_table(path, readonly=False) as t:
        names = t.colnames()
        row = t.nrows()
        t.addrows(1)
        values = {"TIME": float(now / np.timedelta64(1, "s")), "OBSERVATION_ID": 0,
                  "MESSAGE": message, "PRIORITY": "NORMAL", "ORIGIN": "msleak",
                  "OBJECT_ID": 0, "APPLICATION": f"msleak {__version__}",
                  "CLI_COMMAND": [command or message], "APP_PARAMS": [""]}
        for name, value in values.items():
            if name in names:
                t.putcell(name, row, value)


def read_history(ms: str | os.PathLike) -> list[str]:
    """The HISTORY subtable's rows as ``"<application>: <message> (<command>)"`` lines
    (the command line when recorded and not the message), oldest first (empty when the MS
    has none)."""
    ms = check_ms(ms)
    path = ms / "HISTORY"
    if not path.exists():
        return []
    with open_table(path) as t:
        if t.nrows() == 0:
            return []
        order = np.argsort(t.getcol("TIME"), kind="stable")
        apps = t.getcol("APPLICATION") if "APPLICATION" in t.colnames() else [""] * t.nrows()
        msgs = t.getcol("MESSAGE")
        cmds = [" ".join(t.getcell("CLI_COMMAND", row)) if "CLI_COMMAND" in t.colnames()
                and t.iscelldefined("CLI_COMMAND", row) else "" for row in range(t.nrows())]
    return [f"{apps[i]}: {msgs[i]}".strip(": ")
            + (f" ({cmds[i].strip()})" if cmds[i].strip() not in ("", msgs[i]) else "")
            for i in order]


def ms_summary(ms: str | os.PathLike) -> str:
    """A short human-readable description of a Measurement Set."""
    ms = check_ms(ms)
    with open_table(ms) as t:
        nrow = t.nrows()
    times = read_times(ms)
    ants = read_antennas(ms)
    spws = read_spectral_windows(ms)
    fields = read_fields(ms)
    corr = read_corr_types(ms)
    beam_tables = ("LOFAR beam tables" if has_lofar_tables(ms) else
                   "PHASED_ARRAY table" if has_subtable(ms, "PHASED_ARRAY") else
                   "MWA_TILE_POINTING table" if has_subtable(ms, "MWA_TILE_POINTING") else
                   "no beam tables")
    lines = [f"Measurement Set {ms}",
             f"  telescope      {read_telescope_name(ms) or '?'} (with {beam_tables})",
             f"  rows           {nrow}",
             f"  antennas       {len(ants)} ({', '.join(ants.names[:4])}"
             f"{', ...' if len(ants) > 4 else ''})"]
    if times.size:
        step = np.median(np.diff(times)) if times.size > 1 else 0.0
        lines.append(f"  times          {times.size} x {step:.1f} s "
                     f"({(times[-1] - times[0] + step) / 3600:.2f} h)")
    for i, f in enumerate(fields):
        lines.append(f"  field {i}        {f.name}: RA {np.degrees(f.ra) % 360:.4f} deg, "
                     f"Dec {np.degrees(f.dec):.4f} deg")
    for i, s in enumerate(spws):
        lines.append(f"  spw {i}          {s.nchan} channels, {s.freq[0] / 1e6:.4f}-"
                     f"{s.freq[-1] / 1e6:.4f} MHz, width {s.width[0] / 1e3:.4f} kHz")
    lines.append("  correlations   " + "; ".join(
        ",".join(CORR_NAMES.get(int(x), str(int(x))) for x in c) for c in corr))
    lines.append(f"  data columns   {', '.join(data_column_names(ms))}")
    return "\n".join(lines)


if __name__ == "__main__":  # python -m msleak.io.ms summary PATH
    import sys

    if len(sys.argv) == 3 and sys.argv[1] == "summary":
        try:
            print(ms_summary(sys.argv[2]))
        except InputError as err:
            print(f"msleak: error: {err}", file=sys.stderr)
            sys.exit(2)
    else:
        print("usage: python -m msleak.io.ms summary MS", file=sys.stderr)
        sys.exit(2)
