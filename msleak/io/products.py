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
import os
import sys
from pathlib import Path
from typing import Iterable

import xarray as xr

from msleak import __version__
from msleak.errors import InputError

__all__ = ["FORMAT_VERSION", "CF_CONVENTIONS", "save_product", "open_product", "command_line",
           "history_lines"]

#: Layout version of every product kind written by this msleak.
FORMAT_VERSION = 1
#: the CF conventions version the products' attributes follow where they can
CF_CONVENTIONS = "CF-1.10"

#: errno values of a write the user can fix: no space, quota, file too large, read-only
#: file system, permission denied.
_WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EACCES,
                 errno.EPERM}


def command_line() -> str:
    """The command line of this process, for provenance."""
    return " ".join([Path(sys.argv[0]).name, *sys.argv[1:]])


def history_lines(attrs: dict) -> list[str]:
    """The ``history`` chain stored in a product's (or dataset's) attributes."""
    text = attrs.get("history", "")
    return [line for line in str(text).splitlines() if line.strip()]


def save_product(ds: xr.Dataset, path: str | os.PathLike, kind: str, *,
                 overwrite: bool = True, history: Iterable[str] = ()) -> Path:
    """Write ``ds`` as an msleak product of the given kind; returns the path.

    ``history`` is the chain of the inputs (e.g. :func:`history_lines` of the input
    product); this write's own line (time, version, command) is appended to it, and to
    whatever ``ds.attrs["history"]`` already holds when ``history`` is empty.

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
    ds.attrs.setdefault("command", command_line())
    chain = list(history) or history_lines(ds.attrs)
    chain.append(f"{ds.attrs['created']} msleak {__version__}: {ds.attrs['command']}")
    ds.attrs["history"] = "\n".join(chain)
    ds.attrs["Conventions"] = CF_CONVENTIONS
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
