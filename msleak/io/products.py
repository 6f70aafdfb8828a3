"""msleak's data products on disk: self-describing HDF5 files readable with xarray.

Every product is an :class:`xarray.Dataset` written with the h5netcdf engine (complex
values allowed), so ``xarray.open_dataset(path)`` opens it. Global attributes always
present:

``msleak_product``   the kind: ``uvcube``, ``delay``, ``ps``, ``beam``, ``leakage``, ...
``msleak_version``   the version that wrote it
``msleak_format``    the product format version (an integer, bumped on layout changes)
``command``          the command line that made it
``created``          UTC time stamp (ISO 8601)
``history``          the whole chain that made it, oldest first, one line per step
                     (the CF ``history`` attribute): the source MS's HISTORY rows and
                     column provenance, then every msleak command up to this one
``Conventions``      ``CF-1.10``

The layouts of each kind are documented in docs/products.md.
"""

from __future__ import annotations

import datetime as _dt
import errno
import inspect
import os
import sys
from pathlib import Path
from typing import Iterable

import numpy as np
import xarray as xr

from msleak import __version__
from msleak.errors import InputError

__all__ = ["FORMAT_VERSION", "CF_CONVENTIONS", "save_product", "open_product", "command_line",
           "call_record", "refuse_existing", "stamp", "history_lines"]

#: Layout version of every product kind written by this msleak.
FORMAT_VERSION = 2
#: the CF conventions version the products' attributes follow where they can
CF_CONVENTIONS = "CF-1.10"

#: errno values of a write the user can fix: no space, quota, file too large, read-only
#: file system, permission denied.
_WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EACCES,
                 errno.EPERM}


def command_line() -> str:
    """The command line of this process, for provenance."""
    return " ".join([Path(sys.argv[0]).name, *sys.argv[1:]])


def call_record(func, given: dict, *, skip: Iterable[str] = ()) -> str:
    """What made a product: the command line under the ``msleak`` CLI, else the Python
    call ``msleak.<verb>(...)`` with the arguments that differ from their defaults
    (``given`` is the verb's ``locals()``; in-memory objects appear as ``<Type>``)."""
    import click

    if click.get_current_context(silent=True) is not None:
        return command_line()
    params = [p for p in inspect.signature(func).parameters.values() if p.name not in skip]
    shown = [p for p in params if p.default is p.empty or not _same(given[p.name], p.default)]
    args = [_text(given[p.name]) if p.kind is p.POSITIONAL_OR_KEYWORD
            else f"{p.name}={_text(given[p.name])}" for p in shown]
    return f"msleak.{func.__name__}({', '.join(args)})"


def _text(value) -> str:
    if isinstance(value, (str, os.PathLike)):
        return repr(os.fspath(value))
    if isinstance(value, (list, tuple)):
        inner = ", ".join(_text(v) for v in value)
        return f"[{inner}]" if isinstance(value, list) else f"({inner})"
    if isinstance(value, (bool, int, float, type(None))) or (
            isinstance(value, np.ndarray) and value.size <= 16):
        return repr(value)
    return f"<{type(value).__name__}>"


def _same(value, default) -> bool:
    try:
        return bool(value == default)
    except (TypeError, ValueError):  # arrays, Datasets
        return False


def refuse_existing(path: str | os.PathLike | None, overwrite: bool) -> None:
    """One-line InputError if ``path`` exists and ``overwrite`` is false (checked before
    any work, so a refused run costs nothing)."""
    if path is not None and Path(path).exists() and not overwrite:
        raise InputError(f"{path} exists; choose another name or pass --overwrite")


def stamp(ds: xr.Dataset, command: str, history: Iterable[str] | None = None) -> xr.Dataset:
    """``ds`` with the provenance attributes of a product made by ``command``: ``command``,
    ``Conventions`` and the ``history`` chain (``history``, default the chain ``ds``
    already holds, plus this step's line), whether or not it is then written."""
    chain = list(history_lines(ds.attrs) if history is None else history)
    now = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    chain.append(f"{now} msleak {__version__}: {command}")
    return ds.assign_attrs(command=command, history="\n".join(chain),
                           Conventions=CF_CONVENTIONS)


def history_lines(attrs: dict) -> list[str]:
    """The ``history`` chain stored in a product's (or dataset's) attributes."""
    text = attrs.get("history", "")
    return [line for line in str(text).splitlines() if line.strip()]


def save_product(ds: xr.Dataset, path: str | os.PathLike, kind: str, *,
                 overwrite: bool, history: Iterable[str] = ()) -> Path:
    """Write ``ds`` as an msleak product of the given kind; returns the path.

    A dataset made by :func:`stamp` keeps its provenance. Otherwise its ``command``
    (default: this process's command line) is stamped now, after ``history`` (the chain
    of the inputs, e.g. :func:`history_lines` of the input product) or, when that is
    empty, after the chain ``ds`` already holds.

    The file is written to a temporary name and renamed, so an interrupted or failed
    write (full disk: a one-line :class:`InputError`) never leaves a truncated product
    under the final name.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise InputError(f"{path} exists; choose another name or pass --overwrite")
    if path.parent and not path.parent.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
    ds = ds.copy()
    ds.attrs.update({
        "msleak_product": kind,
        "msleak_version": __version__,
        "msleak_format": FORMAT_VERSION,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    })
    command = ds.attrs.setdefault("command", command_line())
    chain = history_lines(ds.attrs)
    if not (chain and chain[-1].endswith(f": {command}")):
        ds = stamp(ds, command, list(history) or chain)
    for name, value in list(ds.attrs.items()):
        if isinstance(value, bool):
            ds.attrs[name] = int(value)
        elif value is None:
            ds.attrs[name] = ""
    tmp = path.with_name(f".{path.name}.partial")
    # Serialised in memory, then written with plain file I/O: HDF5 crashes the process
    # when it closes a file whose write failed (full disk, quota), Python does not.
    data = ds.to_netcdf(engine="h5netcdf", invalid_netcdf=True)
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except OSError as err:
        if err.errno not in _WRITE_ERRNOS:
            raise
        raise InputError(f"{path}: cannot write the {kind} product "
                         f"({os.strerror(err.errno)}); nothing was written") from err
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def open_product(path: str | os.PathLike, kind: str | Iterable[str] | None = None,
                 required: Iterable[str] = ()) -> xr.Dataset:
    """Open an msleak product, loaded into memory, checking its kind and variables.

    Raises
    ------
    InputError
        If the file is missing, not an msleak product, of another kind, written by an
        incompatible format version, or lacks a required variable.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    try:
        with xr.open_dataset(path, engine="h5netcdf") as ds:
            ds = ds.load()
    except Exception as err:  # h5py/h5netcdf raise many types for a bad file
        raise InputError(f"{path}: not a readable msleak product file ({_short(err)})") from err
    found = ds.attrs.get("msleak_product")
    if found is None:
        raise InputError(f"{path}: not an msleak product (no msleak_product attribute)")
    kinds = {kind} if isinstance(kind, str) else (set(kind) if kind else None)
    if kinds and found not in kinds:
        raise InputError(f"{path}: is a {found!r} product, expected {' or '.join(sorted(kinds))}")
    fmt = int(ds.attrs.get("msleak_format", 0))
    if fmt != FORMAT_VERSION:
        raise InputError(
            f"{path}: product format {fmt} written by msleak "
            f"{ds.attrs.get('msleak_version', '?')}, this msleak {__version__} reads format "
            f"{FORMAT_VERSION}; regenerate it with this version")
    missing = [name for name in required if name not in ds.variables]
    if missing:
        raise InputError(f"{path}: {found} product lacks {', '.join(missing)}")
    return ds


def _short(err: BaseException) -> str:
    return " ".join(str(err).split())[:200] or type(err).__name__
