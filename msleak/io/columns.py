"""Writing visibility columns into a Measurement Set: creation, chunked writes, provenance.

:func:`check_writable` refuses a read-only MS; :func:`ensure_data_column` creates a
column shaped like DATA in a tiled storage manager (never a compressing one);
:func:`write_rows` writes a block of rows; the run state (provenance, ``complete``,
per-group progress) lives in the column keyword ``MSLEAK_PREDICT``
(:func:`read_run_state`), updated after every chunk so an interrupted run can resume;
a :class:`Rollback` puts the MS files back as they were when a run is refused part-way.

Column options, run state and safety: docs/predict.md ("Output").
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import stat
from pathlib import Path

import numpy as np

from msleak.errors import InputError

__all__ = [
    "RUN_KEYWORD",
    "check_writable",
    "check_column_name",
    "open_for_writing",
    "check_free_space",
    "check_data_column",
    "ensure_data_column",
    "Rollback",
    "write_rows",
    "read_rows",
    "read_run_state",
    "write_run_state",
    "BACKUP_DIR",
    "backup_headers",
    "discard_header_backup",
    "repair_interrupted",
]

log = logging.getLogger(__name__)

#: Column keyword holding msleak's provenance and progress record.
RUN_KEYWORD = "MSLEAK_PREDICT"

_TILED = ("TiledColumnStMan", "TiledShapeStMan", "TiledCellStMan")
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
#: Main-table columns that are never a target for visibilities.
_RESERVED = {"UVW", "FLAG", "FLAG_ROW", "FLAG_CATEGORY", "WEIGHT", "SIGMA", "WEIGHT_SPECTRUM",
             "SIGMA_SPECTRUM", "TIME", "TIME_CENTROID", "ANTENNA1", "ANTENNA2", "FEED1",
             "FEED2", "DATA_DESC_ID", "FIELD_ID", "SCAN_NUMBER", "INTERVAL", "EXPOSURE",
             "ARRAY_ID", "OBSERVATION_ID", "PROCESSOR_ID", "STATE_ID"}


def check_writable(ms: str | os.PathLike) -> None:
    """Raise InputError if the Measurement Set cannot or must not be written."""
    ms = Path(ms)
    for path in (ms, ms / "table.dat"):
        mode = path.stat().st_mode
        if not os.access(path, os.W_OK) or not mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH):
            raise InputError(f"{ms}: Measurement Set is read-only; copy it or make it "
                             "writable (chmod -R u+w) first")


@contextlib.contextmanager
def open_for_writing(ms: str | os.PathLike, wait_message: str = "waiting for it to finish"):
    """Open the main table for writing and hold its write lock until the block ends.

    Another process writing (or reading) the same MS at the same time would otherwise
    interleave with this one chunk by chunk under casacore's automatic locking. Here the
    lock is taken once (a warning is logged while another process holds it, and we wait)
    and kept, so a second msleak process waits for the first to finish. A killed process
    loses its lock with it (fcntl locks), so a stale lock never blocks a rerun.
    """
    import casacore.tables as pt

    def _open(lockoptions):
        return pt.table(str(ms), readonly=False, ack=False, lockoptions=lockoptions)

    try:
        try:
            table = _open("permanent")
        except RuntimeError as err:
            if "lock" not in str(err).lower():
                raise
            log.warning("%s is in use by another process; %s", ms, wait_message)
            table = _open("permanentwait")
    except RuntimeError as err:
        raise InputError(f"{ms}: cannot open for writing ({' '.join(str(err).split())[:160]})"
                         ) from err
    try:
        yield table
    finally:
        table.close()


def check_free_space(path: str | os.PathLike, nbytes: float, what: str) -> None:
    """Raise InputError if the file system holding ``path`` has less than ``nbytes`` free.

    casacore aborts the whole process (an exception thrown while closing a table) when a
    write hits a full disk, so writers check the space they will need before starting.
    """
    import shutil

    path = Path(path)
    probe = path if path.exists() else path.parent
    try:
        free = shutil.disk_usage(probe).free
    except OSError:  # pragma: no cover - unusual file systems: let the write decide
        return
    if free < nbytes:
        raise InputError(f"not enough disk space for {what}: needs about {nbytes / 2**20:.1f} "
                         f"MB, {free / 2**20:.1f} MB free on {probe}; free some space or "
                         "write elsewhere")


def check_column_name(name: str, *, overwrite_data: bool = False) -> None:
    """Validate a target column name (DATA only with ``overwrite_data``)."""
    if not _NAME.match(name or ""):
        raise InputError(f"invalid column name {name!r}: use letters, digits and underscores "
                         "(e.g. MODEL_DATA)")
    if name.upper() in _RESERVED:
        raise InputError(f"column {name} holds MS metadata, not visibilities; choose another "
                         "`column` (e.g. MODEL_DATA)", param="column")
    if name == "DATA" and not overwrite_data:
        raise InputError("refusing to overwrite the DATA column; pass overwrite_data with "
                         "`column` DATA, or write into another column (default MODEL_DATA)",
                         param=("overwrite_data", "column"))


def _tile_shape(cell_shape: tuple[int, ...], target_bytes: int = 1 << 20) -> list[int]:
    """Tile shape (corr, chan, row) holding about ``target_bytes`` of complex64 values."""
    ncorr, nchan = (list(cell_shape) + [1, 1])[:2] if len(cell_shape) >= 2 else (cell_shape[0], 1)
    per_row = 8 * ncorr * nchan
    return [int(ncorr), int(nchan), int(max(1, target_bytes // max(per_row, 1)))]


def check_data_column(table, name: str, like: str = "DATA", double: bool = False) -> bool:
    """Refuse ``name`` as a target shaped like ``like`` (with ``double``, as a complex128
    target); True if it exists already.

    Parameters
    ----------
    table : casacore.tables.table
        The main table (read-only is enough).
    name : str
        Target column.
    like : str
        Template column (DATA).
    double : bool
        The target must hold complex128 values (casacore DComplex).

    Raises
    ------
    InputError
        If ``like`` is missing, ``name`` exists but is not a complex array column of the
        same cell shape (or, with ``double``, is a complex64 column), or a new column would
        not fit on the disk.
    """
    cols = table.colnames()
    if like not in cols:
        raise InputError(f"the Measurement Set has no {like} column to take the shape from")
    if name in cols:
        have = table.getcoldesc(name)
        if have.get("valueType") not in ("complex", "dcomplex") or have.get("ndim", 0) == 0:
            raise InputError(f"column {name} exists but is not a complex visibility column "
                             f"({have.get('valueType')}); choose another `column`",
                             param="column")
        if (table.nrows() and table.iscelldefined(like, 0) and table.iscelldefined(name, 0)
                and table.getcolshapestring(name, 0, 1) != table.getcolshapestring(like, 0, 1)):
            raise InputError(f"column {name} exists with another shape than {like}; "
                             "choose another `column`", param="column")
        if double and have.get("valueType") != "dcomplex":
            raise InputError(f"column {name} exists as complex64, which would round "
                             "the values of double_column; choose another `column`, or remove "
                             f"it first (TaQL: ALTER TABLE <ms> DROP COLUMN {name}); in a "
                             "msleak paper or forecast OUTDIR of an earlier msleak, rerun "
                             "with overwrite", param=("double_column", "column", "overwrite"))
        return True
    itemsize = 16 if double else 8
    cell_bytes = itemsize * int(np.prod(table.getcell(like, 0).shape)) if table.nrows() else 0
    check_free_space(table.name(), table.nrows() * cell_bytes + 1.1 * 2**20, f"column {name}")
    return False


def ensure_data_column(table, name: str, like: str = "DATA", double: bool = False) -> bool:
    """Create column ``name`` shaped like ``like`` (tiled) if missing; True if created.

    Parameters
    ----------
    table : casacore.tables.table
        The main table, opened for writing.
    name : str
        Column to create (or check).
    like : str
        Template column (DATA).
    double : bool
        Create it as complex128 (casacore DComplex) instead of with ``like``'s type.

    Raises
    ------
    InputError
        As :func:`check_data_column`.
    """
    from casacore.tables import makecoldesc

    if check_data_column(table, name, like, double):
        return False
    desc = table.getcoldesc(like)
    dm = table.getdminfo(like)
    fixed = "shape" in desc and len(desc.get("shape", [])) > 0 and bool(desc.get("option", 0) & 4)
    if dm.get("TYPE") in _TILED:
        dm_type = dm["TYPE"]
        spec = {k: v for k, v in dm.get("SPEC", {}).items()
                if k in ("DEFAULTTILESHAPE", "MAXIMUMCACHESIZE")}
    else:
        dm_type = "TiledColumnStMan" if fixed else "TiledShapeStMan"
        spec = {}
    if "DEFAULTTILESHAPE" not in spec:
        cell = tuple(int(x) for x in desc.get("shape", [])) if fixed else tuple(
            int(x) for x in table.getcell(like, 0).shape) if table.nrows() else (4, 1)
        spec["DEFAULTTILESHAPE"] = np.asarray(_tile_shape(cell[::-1] if cell else (4, 1)),
                                              dtype=np.int32)
    group = f"Tiled{name}"
    newdesc = dict(desc)
    newdesc.pop("keywords", None)
    newdesc["dataManagerType"] = dm_type
    newdesc["dataManagerGroup"] = group
    if double:
        newdesc["valueType"] = "dcomplex"
    newdesc["comment"] = "visibilities predicted by msleak (see keyword MSLEAK_PREDICT)"
    table.addcols(makecoldesc(name, newdesc), {"TYPE": dm_type, "NAME": group, "SPEC": spec})
    log.info("created column %s (%s, %slike %s)", name, dm_type,
             "complex128, shaped " if double else "", like)
    return True


def _runs(rows: np.ndarray) -> list[tuple[int, int, int]]:
    """Contiguous runs (start_index, start_row, length) of ascending row numbers."""
    if rows.size == 0:
        return []
    breaks = np.nonzero(np.diff(rows) != 1)[0] + 1
    starts = np.concatenate([[0], breaks])
    ends = np.concatenate([breaks, [rows.size]])
    return [(int(s), int(rows[s]), int(e - s)) for s, e in zip(starts, ends)]


def write_rows(table, column: str, rows: np.ndarray, values: np.ndarray) -> None:
    """Write ``values`` (nrow, chan, corr) into ``column`` at main-table ``rows`` (any order)."""
    rows = np.asarray(rows, dtype=np.int64)
    order = np.argsort(rows, kind="stable")
    rows = rows[order]
    values = values[order]
    runs = _runs(rows)
    if len(runs) <= 64:
        for start, row0, n in runs:
            table.putcol(column, values[start:start + n], startrow=row0, nrow=n)
    else:
        sel = table.selectrows(rows.tolist())
        try:
            sel.putcol(column, values)
        finally:
            sel.close()


def read_rows(table, column: str, rows: np.ndarray) -> np.ndarray:
    """Read ``column`` at ascending main-table ``rows`` (contiguous runs or a selection)."""
    rows = np.asarray(rows, dtype=np.int64)
    runs = _runs(rows)
    if len(runs) == 1:
        return table.getcol(column, startrow=runs[0][1], nrow=runs[0][2])
    if len(runs) <= 64:
        return np.concatenate([table.getcol(column, startrow=r0, nrow=n) for _, r0, n in runs])
    sel = table.selectrows(rows.tolist())
    try:
        return sel.getcol(column)
    finally:
        sel.close()


def read_run_state(table, column: str) -> dict | None:
    """The ``MSLEAK_PREDICT`` record of ``column`` (None if absent).

    Keys: ``msleak_version``, ``settings`` (a record of the options that define the
    result), ``complete`` (bool), ``rows_done`` (int), ``progress`` (record: group key
    ``f<FIELD_ID>_d<DATA_DESC_ID>`` -> last TIME written, MJD s), ``started``, ``updated``
    (ISO UTC).
    """
    if column not in table.colnames():
        return None
    keywords = table.getcolkeywords(column)
    state = keywords.get(RUN_KEYWORD)
    return dict(state) if isinstance(state, dict) else None


#: column keyword of a ``msleak noise`` run: ``settings`` (text), ``rows_done``, ``complete``
NOISE_KEYWORD = "MSLEAK_NOISE"


def read_noise_state(table, column: str) -> dict | None:
    """The ``MSLEAK_NOISE`` record of ``column`` (None if absent)."""
    if column not in table.colnames():
        return None
    state = table.getcolkeywords(column).get(NOISE_KEYWORD)
    return dict(state) if isinstance(state, dict) else None


def write_noise_state(table, column: str, state: dict) -> None:
    """Store the ``MSLEAK_NOISE`` record of ``column`` and flush the table."""
    table.putcolkeyword(column, NOISE_KEYWORD, state)
    table.flush()


def drop_noise_state(table, column: str) -> None:
    """Remove the ``MSLEAK_NOISE`` record of ``column`` (if any): its values are being
    rewritten without noise."""
    if column in table.colnames() and NOISE_KEYWORD in table.getcolkeywords(column):
        table.removecolkeyword(column, NOISE_KEYWORD)


def write_run_state(table, states: dict[str, dict]) -> None:
    """Store the run records of one run's columns (``{column: record}``) and flush the
    table to disk once.

    While the run is incomplete, copies of its columns' storage-manager header files are
    kept in the MS (see :func:`repair_interrupted`); they are removed when every record
    says the run is complete.
    """
    for column, state in states.items():
        table.putcolkeyword(column, RUN_KEYWORD, state)
    table.flush()
    if all(state.get("complete") for state in states.values()):
        discard_header_backup(table.name())
    else:
        backup_headers(table, list(states))


#: Directory inside the MS holding header copies while a write is in progress.
BACKUP_DIR = ".msleak_backup"


def backup_headers(table, columns: list[str]) -> None:
    """Copy the (flushed) header files that casacore rewrites in place on every flush.

    casacore rewrites the header file ``table.f<SEQNR>`` of a storage manager whose data
    changed (and ``table.info``) in place at every flush, so a process killed during a
    flush can leave it truncated, and then the whole MS no longer opens. Their content
    does not change while rows are only overwritten, so a copy taken once is valid for
    the whole run: files copied already are kept, those of ``columns`` not yet copied are
    added (each file appears whole or not at all).
    """
    import shutil

    ms = Path(table.name())
    backup = ms / BACKUP_DIR
    names = ["table.info"] + sorted({f"table.f{int(table.getdminfo(c)['SEQNR'])}"
                                     for c in columns})
    missing = [n for n in names if (ms / n).is_file() and not (backup / n).is_file()]
    if not missing:
        return
    tmp = ms / f"{BACKUP_DIR}.partial"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    for name in missing:
        shutil.copy2(ms / name, tmp / name)
    if not backup.is_dir():
        os.replace(tmp, backup)
        return
    for name in missing:
        os.replace(tmp / name, backup / name)
    tmp.rmdir()


def discard_header_backup(ms: str | os.PathLike) -> None:
    """Remove the header copies of :func:`backup_headers` (the run completed)."""
    import shutil

    shutil.rmtree(Path(ms) / BACKUP_DIR, ignore_errors=True)


class Rollback:
    """Puts a Measurement Set back exactly as it was before a write run that is refused.

    Made while the main table is open for writing and before the run changes anything: it
    keeps the bytes of ``table.dat`` (column list, keywords, storage managers) and notes
    whether a header backup (:func:`backup_headers`) exists. :meth:`save_rows` keeps the
    old values of rows about to be overwritten in a column that existed before, in an
    unnamed temporary file inside the MS (it vanishes with the process, so a killed run
    leaves nothing of it). :meth:`restore` removes the column if the run created it (set
    :attr:`created`), or writes the old values back; then it puts ``table.dat`` back and
    removes a header backup the run made.

    Parameters
    ----------
    table : casacore.tables.table
        The main table, open for writing.
    column : str
        The column the run writes.
    nrows : int
        Rows the run may overwrite. When the disk has no room for their old values,
        they are not kept (a warning says so) and a refused run leaves the rows it wrote
        with their new values.
    """

    def __init__(self, table, column: str, nrows: int):
        self.ms = Path(table.name())
        self.column = column
        self.created = False
        self._table_dat = (self.ms / "table.dat").read_bytes()
        self._had_backup = (self.ms / BACKUP_DIR).exists()
        self._saved: list[tuple[np.ndarray, int, np.dtype, tuple]] = []
        self._file = None
        self._keep = column in table.colnames() and nrows > 0
        if self._keep:
            itemsize = 16 if table.getcoldesc(column).get("valueType") == "dcomplex" else 8
            cell = int(np.prod(table.getcell("DATA", 0).shape)) if "DATA" in table.colnames() else 0
            try:
                check_free_space(self.ms, nrows * cell * itemsize + 1.1 * 2**20,
                                 f"a copy of column {column} to undo a refused run")
            except InputError as err:
                log.warning("%s; a run refused part-way leaves the rows it wrote with their "
                            "new values", err)
                self._keep = False

    def save_rows(self, table, rows: np.ndarray) -> None:
        """Keep the current values of ``rows`` of the column (before they are overwritten)."""
        if not self._keep:
            return
        rows = np.sort(np.asarray(rows, dtype=np.int64))
        try:
            old = np.ascontiguousarray(read_rows(table, self.column, rows))
        except RuntimeError as err:  # cells without an array: no value to put back
            log.warning("%s: column %s has rows without values (%s); a run refused part-way "
                        "leaves the rows it wrote with their new values", self.ms, self.column,
                        " ".join(str(err).split())[:80])
            self._keep = False
            self._saved.clear()
            return
        if self._file is None:
            import tempfile

            self._file = tempfile.TemporaryFile(dir=self.ms)
        self._file.seek(0, os.SEEK_END)
        self._saved.append((rows, self._file.tell(), old.dtype, old.shape))
        self._file.write(memoryview(old).cast("B"))

    def restore(self) -> None:
        """Undo the run (its tables must be closed): the MS files are as before it."""
        import shutil

        with open_for_writing(self.ms) as table:
            if self.created and self.column in table.colnames():
                table.removecols([self.column])
            for rows, offset, dtype, shape in reversed(self._saved):
                self._file.seek(offset)
                values = np.frombuffer(self._file.read(int(np.prod(shape)) * dtype.itemsize),
                                       dtype=dtype).reshape(shape)
                write_rows(table, self.column, rows, values)
            table.flush()
        # casacore rewrites table.dat on close, with a data-manager counter that an added
        # and removed column leaves changed: the saved bytes are the table as it was
        path = self.ms / "table.dat"
        tmp = self.ms / "table.dat.msleak-restore"
        tmp.write_bytes(self._table_dat)
        shutil.copymode(path, tmp)
        os.replace(tmp, path)
        if not self._had_backup:
            discard_header_backup(self.ms)
        log.info("%s: put back as it was before the refused run", self.ms)

    def close(self) -> None:
        """Drop the kept values."""
        if self._file is not None:
            self._file.close()
            self._file = None
        self._saved.clear()


def repair_interrupted(ms: str | os.PathLike) -> bool:
    """Restore header files truncated by a killed msleak write; True if it did.

    Only acts when a header backup exists (an msleak write was interrupted) *and* the
    main table no longer opens; then the copies are put back and the table must open.
    """
    import shutil

    import casacore.tables as pt

    ms = Path(ms)
    backup = ms / BACKUP_DIR
    if not backup.is_dir():
        return False
    try:
        pt.table(str(ms), ack=False).close()
        return False
    except RuntimeError as err:
        reason = " ".join(str(err).split())[:160]
    for path in sorted(backup.iterdir()):
        shutil.copy2(path, ms / path.name)
    try:
        pt.table(str(ms), ack=False).close()
    except RuntimeError as err:
        raise InputError(f"{ms}: the main table does not open ({reason}) and restoring the "
                         f"header copies in {BACKUP_DIR} did not help "
                         f"({' '.join(str(err).split())[:120]})") from err
    log.warning("%s: restored header files truncated by an interrupted run (%s)", ms, reason)
    return True
