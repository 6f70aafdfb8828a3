"""Give casacore a current leap-second table (TAI_UTC) from the IERS list astropy ships.

casacore warns (three SEVERE lines on stderr) whenever its TAI_UTC table's VS_DATE is more
than 180 days old, and python-casacore's wheel carries the table of its build date. The
IERS leap-second list in the ``astropy-iers-data`` package is released far more often and
states its own validity ("File expires on ..."). When the user has not configured
casacore's data themselves, :func:`configure_casacore_measures` writes a TAI_UTC table from
that list into msleak's cache (once per list) and points casacore at it through
``AIPSPATH``, keeping python-casacore's data for every other table. Its VS_DATE is the
list's expiry less 180 days, so casacore's warning still appears, exactly when the list
has expired and a newly announced leap second could be missing. docs/conventions.md
("Leap seconds") says more.

It must run before casacore first reads its resource files, so ``msleak/io/__init__``
calls it; it imports neither casacore nor astropy in this process (the table is written by a
child process the first time).
"""

from __future__ import annotations

import hashlib
import importlib.util
import logging
import os
import subprocess
import sys
from pathlib import Path

__all__ = ["configure_casacore_measures", "casacore_root", "leap_second_file",
           "user_configured_casacore", "FRESHNESS_DAYS"]

log = logging.getLogger(__name__)

#: casacore's MeasTable::dUTC warns when its table's VS_DATE is older than this (days).
FRESHNESS_DAYS = 180
#: Bumped when the table layout written here changes (part of the cache key).
_TABLE_FORMAT = "1"
#: The user's own casacore resource files, read before AIPSPATH's (casacore's Aipsrc).
_USER_RC_FILES = (".casarc", ".casa/rc", ".aipsrc")


def _package_dir(name: str) -> Path | None:
    spec = importlib.util.find_spec(name)
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(list(spec.submodule_search_locations)[0])


def casacore_root() -> Path | None:
    """python-casacore's package folder (its default AIPSPATH), found without importing it."""
    return _package_dir("casacore")


def leap_second_file() -> Path | None:
    """The IERS leap-second list shipped by ``astropy-iers-data``, or None."""
    root = _package_dir("astropy_iers_data")
    path = root / "data" / "Leap_Second.dat" if root else None
    return path if path is not None and path.is_file() else None


def user_configured_casacore(environ=os.environ, home: Path | None = None) -> bool:
    """True when the user chose casacore's data: ``CASARCFILES`` set, ``AIPSPATH`` set to
    anything but python-casacore's own folder, or a ``measures.`` line in ~/.casarc,
    ~/.casa/rc or ~/.aipsrc."""
    if environ.get("CASARCFILES"):
        return True
    aipspath = environ.get("AIPSPATH")
    root = casacore_root()
    if aipspath and (root is None or Path(aipspath.split()[0]) != root):
        return True
    home = Path(environ.get("HOME", "~")).expanduser() if home is None else home
    for name in _USER_RC_FILES:
        try:
            lines = (home / name).read_text(errors="replace").splitlines()
        except OSError:
            continue
        if any(line.strip().startswith("measures.") for line in lines):
            return True
    return False


def _cache_dir(environ=os.environ) -> Path:
    if environ.get("MSLEAK_CACHE_DIR"):
        return Path(environ["MSLEAK_CACHE_DIR"])
    base = environ.get("XDG_CACHE_HOME") or Path(environ.get("HOME", "~")).expanduser() / ".cache"
    return Path(base) / "msleak"


#: Run in a child process (a casacore in this process would read its resource files before
#: AIPSPATH points at the new table): argv = [leap-second list, casacore data, output].
_WRITER = r"""
import sys
from datetime import datetime, timedelta, timezone
import numpy as np
from astropy.utils.iers import LeapSeconds
import casacore.tables as pt

source, casacore_data, out = sys.argv[1:4]
days = float(sys.argv[4])
old = pt.table(casacore_data + "/geodetic/TAI_UTC", ack=False)
mjd, dutc = old.getcol("MJD"), old.getcol("dUTC")
offset, mult = old.getcol("Offset"), old.getcol("Multiplier")
listed = LeapSeconds.from_iers_leap_seconds(source)
first = float(listed["mjd"][0])
keep = mjd < first
new_mjd = np.asarray(listed["mjd"], float)
new_dutc = np.asarray(listed["tai_utc"], float)
# the list must contain every integer step casacore already has, unchanged
n_old = int((~keep).sum())
if n_old > len(new_mjd) or not (np.array_equal(mjd[~keep], new_mjd[:n_old])
                                 and np.array_equal(dutc[~keep], new_dutc[:n_old])):
    sys.exit(3)
expires = datetime.strptime(listed.expires.strftime("%Y-%m-%d"), "%Y-%m-%d")
vs_date = (expires - timedelta(days=days)).strftime("%Y/%m/%d/%H:%M")
now = datetime.now(timezone.utc).strftime("%Y/%m/%d/%H:%M")
desc = pt.maketabdesc([pt.makescacoldesc(name, 0.0, keywords={"UNIT": unit})
                       for name, unit in (("MJD", "d"), ("dUTC", "s"), ("Offset", "d"),
                                          ("Multiplier", "s"))])
rows = len(mjd[keep]) + len(new_mjd)
with pt.table(out, desc, nrow=rows, ack=False) as t:
    t.putcol("MJD", np.concatenate([mjd[keep], new_mjd]))
    t.putcol("dUTC", np.concatenate([dutc[keep], new_dutc]))
    t.putcol("Offset", np.concatenate([offset[keep], np.full(len(new_mjd), first)]))
    t.putcol("Multiplier", np.concatenate([mult[keep], np.zeros(len(new_mjd))]))
    t.putinfo({"type": "IERS", "subType": "leapSecond",
               "readme": "TAI - UTC from the IERS leap-second list (msleak)"})
    t.putkeywords({"VS_CREATE": now, "VS_DATE": vs_date, "VS_VERSION": "msleak.1",
                   "VS_TYPE": "TAI_UTC difference from the IERS leap-second list",
                   "TAB_VERSION": "0001.0000", "MJD0": float(mjd[0]), "dMJD": 0.0,
                   "SOURCE": source, "EXPIRES": expires.strftime("%Y-%m-%d")})

"""


def _write_table(source: Path, casacore_data: Path, target: Path) -> bool:
    """Write the TAI_UTC table for ``source`` at ``target`` (atomically); True on success."""
    target.parent.mkdir(parents=True, exist_ok=True)
    partial = target.parent / f".{target.name}.{os.getpid()}.partial"
    env = {k: v for k, v in os.environ.items() if k not in ("AIPSPATH", "CASARCFILES")}
    try:
        done = subprocess.run([sys.executable, "-c", _WRITER, str(source), str(casacore_data),
                               str(partial), str(FRESHNESS_DAYS)], env=env,
                              capture_output=True, text=True, timeout=120)
    except (OSError, subprocess.SubprocessError) as err:
        log.debug("no leap-second table written: %s", err)
        return False
    if done.returncode != 0:
        log.debug("no leap-second table written (exit %d): %s", done.returncode,
                  done.stderr.strip()[-500:])
        _remove_tree(partial)
        return False
    try:
        partial.rename(target)
    except OSError:          # another process wrote it first
        _remove_tree(partial)
    return (target / "table.dat").is_file()


def _remove_tree(path: Path) -> None:
    import shutil

    shutil.rmtree(path, ignore_errors=True)


def configure_casacore_measures(environ=os.environ, source: Path | None = None) -> Path | None:
    """Point casacore at a TAI_UTC table made from the IERS leap-second list.

    Does nothing (returns None) when the user configured casacore's data
    (:func:`user_configured_casacore`), when python-casacore or the list is missing, or
    when the table cannot be written; otherwise sets ``environ["AIPSPATH"]`` to a folder
    whose ``.aipsrc`` names python-casacore's data and the new table, and returns it.
    """
    if user_configured_casacore(environ):
        return None
    root, source = casacore_root(), source or leap_second_file()
    if root is None or source is None or not (root / "data" / "geodetic").is_dir():
        return None
    data = root / "data"
    try:
        key = hashlib.sha256(source.read_bytes() + f"\0{data}\0{_TABLE_FORMAT}".encode())
        folder = _cache_dir(environ) / "casacore-measures" / key.hexdigest()[:16]
        table = folder / "TAI_UTC"
        if not (table / "table.dat").is_file() and not _write_table(source, data, table):
            return None
        rc = folder / ".aipsrc"
        text = f"measures.directory: {data}\nmeasures.tai_utc.directory: {folder}\n"
        if not rc.is_file() or rc.read_text() != text:
            partial = folder / f".aipsrc.{os.getpid()}"
            partial.write_text(text)
            partial.replace(rc)
    except OSError as err:
        log.debug("casacore keeps its own leap-second table: %s", err)
        return None
    environ["AIPSPATH"] = str(folder)
    environ["CASACORE_DATADIR"] = str(data)
    return folder
