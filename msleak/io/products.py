"""msleak's data products on disk: self-describing HDF5 files readable with xarray.

Every product is an :class:`xarray.Dataset` written with the h5netcdf engine (complex
values allowed), so ``xarray.open_dataset(path, engine="h5netcdf")`` opens it. Global
attributes always present:

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
           "call_record", "refuse_existing", "stamp", "history_lines", "wrong_input_message",
           "make_command", "product_name", "describe_path"]

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
        raise InputError(f"{path} exists; choose another name or pass overwrite",
                         param="overwrite")


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
        raise InputError(f"{path} exists; choose another name or pass overwrite",
                         param="overwrite")
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
        If ``path`` is missing, is not an msleak product (a Measurement Set, a FITS file,
        another file), is a product of another kind, was written by an incompatible format
        version, or lacks a required variable: one line saying what ``path`` is and which
        command makes the product asked for (:func:`wrong_input_message`).
    """
    path = Path(path)
    kinds = {kind} if isinstance(kind, str) else (set(kind) if kind else set())
    if not path.is_file() or _signature(path) != _HDF5_SIGNATURE:
        raise InputError(wrong_input_message(path, kinds))
    try:
        with xr.open_dataset(path, engine="h5netcdf") as ds:
            ds = ds.load()
    except Exception as err:  # h5py/h5netcdf raise many types for a bad file
        raise InputError(wrong_input_message(path, kinds, reason=_short(err))) from err
    found = ds.attrs.get("msleak_product")
    if found is None or (kinds and found not in kinds):
        raise InputError(wrong_input_message(path, kinds, found=found or ""))
    fmt = int(ds.attrs.get("msleak_format", 0))
    if fmt != FORMAT_VERSION:
        raise InputError(
            f"{path}: product format {fmt} written by msleak "
            f"{ds.attrs.get('msleak_version', '?')}, this msleak {__version__} reads format "
            f"{FORMAT_VERSION}; regenerate it with this version")
    missing = [name for name in required if name not in ds.variables]
    if missing:
        raise InputError(f"{path}: {found} product lacks {', '.join(missing)}; "
                         f"{_remake(found)}")
    return ds


#: product kind -> (the input it is made from, its name in messages, the command that
#: makes it from that input, its usual file name); the chain is
#: MS -> uvcube -> delay -> ps -> leakage, and MS -> beam
_MAKERS = {
    "uvcube": ("ms", "uv cube (grid product)", "msleak grid {} -o grid.h5", "grid.h5"),
    "delay": ("uvcube", "delay cube (transform product)", "msleak transform {} -o delay.h5",
              "delay.h5"),
    "ps": ("delay", "power-spectrum product", "msleak ps {} -o ps.h5", "ps.h5"),
    "leakage": ("ps", "leakage product", "msleak leakage {} -o leakage/",
                "leakage/leakage.h5"),
    "beam": ("ms", "beam product", "msleak beam {} -o beam.png", "beam.h5"),
}
#: placeholder of an input in the suggested commands
_INPUT_NAMES = {"ms": "MS", **{kind: spec[3] for kind, spec in _MAKERS.items()}}
_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
_FITS_SIGNATURE = b"SIMPLE  "


def product_name(kind: str) -> str:
    """How a product kind is named in messages, e.g. ``uv cube (grid product)``."""
    return _MAKERS[kind][1] if kind in _MAKERS else f"{kind} product"


def make_command(kind: str, have: str = "", path: str | os.PathLike | None = None) -> str:
    """The command(s) that make a ``kind`` product, in backquotes. When ``path`` holds an
    earlier stage of the chain (``have``: ``ms``, ``fits`` or a product kind), every step
    from it, e.g. `msleak grid obs.ms -o grid.h5`, then `msleak transform grid.h5 -o
    delay.h5`; otherwise the last step, from its usual input (`msleak transform grid.h5
    -o delay.h5`)."""
    chain = [kind]
    while _MAKERS[chain[0]][0] in _MAKERS:
        chain.insert(0, _MAKERS[chain[0]][0])
    first_input = _MAKERS[chain[0]][0]
    if path is not None and (have == first_input or (have == "fits" and chain[0] == "uvcube")):
        steps, src = chain, str(path)
    elif path is not None and have in chain[:-1]:
        steps, src = chain[chain.index(have) + 1:], str(path)
    else:
        steps, src = chain[-1:], _INPUT_NAMES[_MAKERS[kind][0]]
    commands = []
    for k in steps:
        template = ("msleak grid --image {} -o grid.h5" if have == "fits" and k == "uvcube"
                    and src == str(path) else _MAKERS[k][2])
        commands.append(f"`{template.format(src)}`")
        src = _MAKERS[k][3]
    return ", then ".join(commands)


def wrong_input_message(path: str | os.PathLike, kinds: Iterable[str] = (), *,
                        found: str = "", reason: str = "") -> str:
    """One line: what ``path`` is (missing, a Measurement Set, a FITS file, a product of
    another kind, ...), that it is not a product of ``kinds``, and the command that makes
    one. ``found``: the kind of the msleak product ``path`` holds (``""``: none);
    ``reason``: why an HDF5 file could not be read."""
    path = Path(path)
    kinds = sorted(kinds)
    wanted = " or ".join(product_name(k) for k in kinds) or "msleak product"
    have = ""
    if not path.exists():
        line = f"{path} does not exist"
    else:
        have, what = describe_path(path, found=found, reason=reason)
        line = f"{path} {what}, not a {wanted}"
    if len(kinds) == 1 and kinds[0] in _MAKERS:
        line += f"; make {'a ' + wanted if line.endswith('exist') else 'one'} with " \
                f"{make_command(kinds[0], have, path)}"
    return line


def describe_path(path: str | os.PathLike, *, found: str | None = None,
                  reason: str = "") -> tuple[str, str]:
    """(what it holds: ``ms``, ``fits``, a product kind or ``""``; words such as "is a FITS
    file") of an existing ``path``, for messages about wrong inputs. ``found``: the kind of
    the msleak product ``path`` holds (None: read it from the file); ``reason``: why an
    HDF5 file could not be read."""
    path = Path(path)
    if path.is_dir():
        return _directory_kind(path)
    head = _signature(path)
    if found is None and head == _HDF5_SIGNATURE and not reason:
        found = _product_kind(path)
    if found:
        return found, f"is a {product_name(found)}"
    if head.startswith(_FITS_SIGNATURE):
        return "fits", "is a FITS file"
    if head != _HDF5_SIGNATURE:
        return "", "is a text file" if _is_text(path) else "is a binary file of an unknown format"
    if reason:
        return "", f"is a damaged or truncated HDF5 file ({reason})"
    return "", "is an HDF5 file without msleak's msleak_product attribute"


def _product_kind(path: Path) -> str:
    """The ``msleak_product`` attribute of an HDF5 file ("" if none or unreadable)."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            kind = f.attrs.get("msleak_product", "")
    except OSError:
        return ""
    return kind.decode() if isinstance(kind, bytes) else str(kind)


def _directory_kind(path: Path) -> tuple[str, str]:
    """(``ms`` or ``""``, what the directory ``path`` is) for :func:`wrong_input_message`."""
    if not (path / "table.dat").exists():
        return "", "is a directory"
    try:
        info = (path / "table.info").read_text(errors="replace")
    except OSError:
        info = ""
    if "Measurement Set" in info or (path / "ANTENNA" / "table.dat").exists():
        return "ms", "is a Measurement Set"
    return "", "is a casacore table"


def _signature(path: Path) -> bytes:
    """The first 8 bytes of a file, where HDF5 and FITS files say what they are (b"" if
    unreadable)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(len(_HDF5_SIGNATURE))
    except OSError:
        return b""


def _is_text(path: Path) -> bool:
    """Whether the first kilobyte of ``path`` is UTF-8 text."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(1024)
        head.decode("utf-8")
    except (OSError, UnicodeDecodeError):
        return False
    return b"\0" not in head


def _remake(kind: str) -> str:
    """``regenerate it with ...``: the command that makes a product of ``kind``."""
    return f"regenerate it with {make_command(kind)}" if kind in _MAKERS else \
        "regenerate it with the msleak command that made it"


def _short(err: BaseException, limit: int = 120) -> str:
    """An exception's message on one line, cut at a word boundary to at most ``limit``
    characters (with "..." when cut)."""
    text = " ".join(str(err).split()) or type(err).__name__
    if len(text) <= limit:
        return text
    return text[:limit].rsplit(" ", 1)[0].rstrip(",;:(") + " ..."
