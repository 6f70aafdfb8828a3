"""makesourcedb / BBS text sky models (the LOFAR format DP3 reads): point sources.

:func:`read_skymodel` reads a makesourcedb file into
:class:`~msleak.sky.sources.PointSources` with DP3's semantics (fluxes in Jy, frequencies
in Hz, RotationMeasure in rad m^-2, angles as casacore reads them); only point sources
are read; :func:`write_skymodel` writes point sources as DP3 reads them.

The accepted format, fields and spectral/polarization semantics: docs/sky.md
("Point sources for predict", "makesourcedb files").
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import numpy as np

from msleak import __version__
from msleak.constants import SPEED_OF_LIGHT
from msleak.errors import InputError
from msleak.io.angles import format_dec, format_ra, parse_angle
from msleak.sky.sources import PointSources

__all__ = ["read_skymodel", "write_skymodel", "KNOWN_FIELDS"]

KNOWN_FIELDS = ("Name", "Type", "RefType", "Ra", "Dec", "I", "Q", "U", "V", "SpectralIndex",
                "LogarithmicSI", "ReferenceFrequency", "MajorAxis", "MinorAxis",
                "Orientation", "OrientationIsAbsolute", "RotationMeasure",
                "PolarizedFraction", "PolarizationAngle", "ReferenceWavelength", "Patch",
                "Category", "IShapelet", "QShapelet", "UShapelet", "VShapelet")
_KNOWN = {f.lower(): f for f in KNOWN_FIELDS}

# ---------------------------------------------------------------------------- reading
def _split(line: str, lineno: int, path) -> list[str]:
    """Split on top-level commas (not inside [...] or quotes)."""
    out, depth, quote, start = [], 0, None, 0
    for i, ch in enumerate(line):
        if quote:
            if ch == quote:
                quote = None
        elif ch in "'\"":
            quote = ch
        elif ch == "[":
            depth += 1
        elif ch == "]":
            depth -= 1
            if depth < 0:
                raise InputError(f"{path}:{lineno}: unbalanced ']'")
        elif ch == "," and depth == 0:
            out.append(line[start:i].strip())
            start = i + 1
    if quote or depth:
        raise InputError(f"{path}:{lineno}: unbalanced {'quote' if quote else '['}")
    out.append(line[start:].strip())
    return out


def _unquote(v: str) -> str:
    if len(v) >= 2 and v[0] == v[-1] and v[0] in "'\"":
        return v[1:-1]
    return v


def _parse_format(text: str, lineno: int, path) -> list[tuple[str | None, str, bool]]:
    """[(canonical field or None, default value, fixed)] in column order."""
    fields = []
    for item in _split(text, lineno, path):
        m = re.fullmatch(r"([A-Za-z0-9_][A-Za-z0-9_:]*)?\s*(?:=\s*(fixed)?\s*(['\"])(.*)\3)?",
                         item.strip(), flags=re.IGNORECASE)
        if not m:
            raise InputError(f"{path}:{lineno}: cannot parse format item {item!r}")
        name = (m.group(1) or "").strip()
        canon = None if name.lower() in ("", "dummy") else _KNOWN.get(name.lower(), name)
        fields.append((canon, m.group(4) or "", bool(m.group(2))))
    names = [f[0] for f in fields if f[0]]
    for need in ("Ra", "Dec"):
        if need not in names:
            raise InputError(f"{path}:{lineno}: the format has no {need} field "
                             "(rah/decd style positions are not supported)")
    if "SpectralIndexDegree" in names:
        raise InputError(f"{path}:{lineno}: use SpectralIndex=[...] instead of "
                         "SpectralIndexDegree")
    return fields


_FORMAT_1 = re.compile(r"^\s*format\s*=(.*)$", re.IGNORECASE)
_FORMAT_2 = re.compile(r"^\s*#\s*\((.*)\)\s*=\s*format\s*$", re.IGNORECASE)


def read_skymodel(path: str | os.PathLike) -> PointSources:
    """Read the point sources of a makesourcedb text file (parametric PointSources).

    Raises
    ------
    InputError
        With ``path:line:`` for a missing format line, a malformed value, an unsupported
        source type or an inconsistent polarization specification.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise InputError(f"{path} is neither a FITS cube nor a makesourcedb text file") from None
    except OSError as err:
        raise InputError(f"cannot read sky model {path}: {err.strerror}") from None
    fmt = None
    rows: dict[str, list] = {k: [] for k in ("name", "ra", "dec", "iquv", "nu0", "si", "log",
                                              "rm", "pf", "pa", "qu_given", "refwl")}
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.rstrip("\r")
        m = _FORMAT_2.match(line) or _FORMAT_1.match(line)
        if m:
            fmt = _parse_format(m.group(1), lineno, path)
            continue
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        if fmt is None:
            raise InputError(f"{path}:{lineno}: text before any format line: neither a FITS "
                             "cube nor a makesourcedb sky model (which starts with "
                             "'format = Name, Type, Ra, Dec, I, ...')")
        _read_line(stripped, lineno, path, fmt, rows)
    if fmt is None:
        raise InputError(f"{path} has no format line: it is neither a FITS cube nor a "
                         "makesourcedb sky model")
    if not rows["name"]:
        raise InputError(f"{path} contains no point sources")
    return _assemble(rows)


def _read_line(line, lineno, path, fmt, rows):
    """Parse one source line into ``rows`` (patch lines are skipped)."""
    values = _split(line, lineno, path)
    if len(values) > len(fmt) and any(v for v in values[len(fmt):]):
        raise InputError(f"{path}:{lineno}: {len(values)} values for {len(fmt)} format fields")
    rec: dict[str, str] = {}
    for k, (canon, default, fixed) in enumerate(fmt):
        v = default if fixed else (values[k] if k < len(values) else "")
        if not v and default:
            v = default
        if canon:
            rec[canon] = _unquote(v.strip())
    where = f"{path}:{lineno}:"
    name = rec.get("Name", "")
    if not name:
        if rec.get("Patch"):
            return
        raise InputError(f"{where} Name a source needs a name")
    ra, dec = _position(rec, where)
    i = _number(rec, "I", where, 1.0)
    q, u, v = (_number(rec, s, where) for s in ("Q", "U", "V"))
    nu0 = _number(rec, "ReferenceFrequency", where, 0.0)
    si, log_si = _spectral_index(rec, where, nu0)
    rm, pf, pa, refwl = (_number(rec, s, where) for s in (
        "RotationMeasure", "PolarizedFraction", "PolarizationAngle", "ReferenceWavelength"))
    _check_polarization(where, i, q, u, nu0, rm, pf, pa, refwl)
    for key, value in (("name", name), ("ra", ra), ("dec", dec),
                       ("iquv", [i, q or 0.0, u or 0.0, v or 0.0]), ("nu0", nu0), ("si", si),
                       ("log", log_si), ("rm", np.nan if rm is None else rm),
                       ("pf", pf or 0.0), ("pa", pa or 0.0),
                       ("qu_given", q is not None or u is not None), ("refwl", refwl)):
        rows[key].append(value)


def _number(rec: dict, field: str, where: str, default: float | None = None):
    v = rec.get(field, "")
    if v == "":
        return default
    try:
        x = float(v)
    except ValueError:
        raise InputError(f"{where} {field} {v!r} is not a number") from None
    if not math.isfinite(x):
        raise InputError(f"{where} {field} {v!r} is not a finite number")
    return x


def _position(rec: dict, where: str) -> tuple[float, float]:
    """(RA, Dec) in rad of a point source record; checks Type and RefType."""
    stype = rec.get("Type", "").upper()
    if stype not in ("", "POINT"):
        raise InputError(f"{where} Type source type {rec['Type']!r} is not supported "
                         "(msleak reads point sources only)")
    reftype = rec.get("RefType", "") or "J2000"
    if reftype.upper() != "J2000":
        raise InputError(f"{where} RefType {reftype!r} is not supported (J2000 only)")
    try:
        ra = parse_angle(rec.get("Ra", ""), allow_colon=True)
    except ValueError as err:
        raise InputError(f"{where} Ra {err}") from None
    try:
        dec = parse_angle(rec.get("Dec", ""), allow_colon=False)
    except ValueError as err:
        raise InputError(f"{where} Dec {err}") from None
    if not (-math.pi / 2 - 1e-12 <= dec <= math.pi / 2 + 1e-12):
        raise InputError(f"{where} Dec {rec['Dec']!r} is outside -90..90 deg")
    return ra, dec


def _spectral_index(rec: dict, where: str, nu0: float) -> tuple[list[float], bool]:
    """The SpectralIndex terms and LogarithmicSI of a record."""
    si_text = rec.get("SpectralIndex", "").strip()
    si: list[float] = []
    if si_text:
        inner = si_text[1:-1] if si_text.startswith("[") and si_text.endswith("]") else si_text
        try:
            si = [float(x) for x in inner.split(",") if x.strip()]
        except ValueError:
            raise InputError(f"{where} SpectralIndex {si_text!r} is not a list of "
                             "numbers") from None
    if si and nu0 <= 0:
        raise InputError(f"{where} SpectralIndex given without a ReferenceFrequency")
    log_text = rec.get("LogarithmicSI", "").strip().lower()
    if log_text not in ("", "true", "false", "t", "f", "1", "0", "yes", "no", "y", "n"):
        raise InputError(f"{where} LogarithmicSI {log_text!r} is not a boolean")
    return si, log_text not in ("false", "f", "0", "no", "n")


def _check_polarization(where, i, q, u, nu0, rm, pf, pa, refwl) -> None:
    """DP3's rules for Q, U, RotationMeasure, PolarizedFraction/Angle."""
    either = (f"{where} RotationMeasure give either Q and U or PolarizedFraction and "
              "PolarizationAngle with a RotationMeasure")
    if rm is None:
        if pf is not None or pa is not None or refwl is not None:
            raise InputError(f"{where} RotationMeasure PolarizedFraction, "
                             "PolarizationAngle and ReferenceWavelength need a RotationMeasure")
    elif q is not None or u is not None:
        if q is None or u is None or pf is not None or pa is not None:
            raise InputError(either)
        if refwl is None and nu0 <= 0:
            raise InputError(f"{where} RotationMeasure needs a ReferenceFrequency or "
                             "ReferenceWavelength")
        if i == 0:
            raise InputError(f"{where} I a RotationMeasure source needs I != 0")
    else:
        if pf is None or pa is None:
            raise InputError(either)
        if refwl not in (None, 0.0):
            raise InputError(f"{where} ReferenceWavelength PolarizedFraction/"
                             "PolarizationAngle are defined at ReferenceWavelength = 0 only")


def _assemble(rows) -> PointSources:
    n = len(rows["name"])
    nterms = max((len(s) for s in rows["si"]), default=0)
    si = np.zeros((n, nterms))
    for k, s in enumerate(rows["si"]):
        si[k, :len(s)] = s
    iquv = np.array(rows["iquv"], float)
    nu0 = np.array(rows["nu0"], float)
    rm = np.array(rows["rm"], float)
    pf = np.array(rows["pf"], float)
    pa = np.array(rows["pa"], float)
    log_si = np.array(rows["log"], bool)
    for k in np.nonzero(np.isfinite(rm) & np.array(rows["qu_given"]))[0]:
        # DP3 calcRMParam: fraction of I at the RM reference wavelength, angle at lambda=0
        refwl = rows["refwl"][k]
        lam = refwl if refwl is not None else SPEED_OF_LIGHT / nu0[k]
        i_ref = iquv[k, 0]
        if si[k].any():
            if lam <= 0:
                raise InputError("no RM reference wavelength for a source with a spectral "
                                 "index")
            vv0 = (SPEED_OF_LIGHT / lam) / nu0[k]
            base = math.log10(vv0)
            i_ref *= vv0 ** float(np.polynomial.polynomial.polyval(base, si[k]))
        pf[k] = math.hypot(iquv[k, 1], iquv[k, 2]) / i_ref
        pa[k] = math.fmod(0.5 * math.atan2(iquv[k, 2], iquv[k, 1]) - lam * lam * rm[k], math.pi)
        if pa[k] < 0:
            pa[k] += math.pi
    return PointSources(ra=np.array(rows["ra"]), dec=np.array(rows["dec"]), ref_freq=nu0,
                        stokes_ref=iquv, spectral_index=si, log_si=log_si,
                        rotation_measure=rm, pol_fraction=pf, pol_angle=pa,
                        names=tuple(rows["name"]))


# ---------------------------------------------------------------------------- writing
def _g(x: float) -> str:
    return f"{x:.10g}"


def write_skymodel(path: str | os.PathLike, sources: PointSources, *,
                   channel: int | None = None, overwrite: bool = False,
                   name_prefix: str = "s", comment: str | None = None) -> Path:
    """Write point sources as a makesourcedb file DP3 reads.

    Tabulated sources (from a cube) have one spectrum value per sky channel, which one
    makesourcedb source cannot hold: one channel is written (``channel``, required when
    the sky has more than one), as flat-spectrum sources (no SpectralIndex) with
    ReferenceFrequency = that channel's frequency. Parametric sources are written with
    their spectral terms and rotation measures (Q, U given at ReferenceFrequency).

    Raises
    ------
    InputError
        If the file exists (without ``overwrite``) or ``channel`` is missing/out of range.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise InputError(f"{path} exists; choose another name or pass overwrite",
                         param="overwrite")
    n = len(sources)
    names = sources.names or tuple(f"{name_prefix}{k:0{max(4, len(str(n - 1)))}d}"
                                   for k in range(n))
    bad = [nm for nm in names if not re.fullmatch(r"[A-Za-z0-9_.+\-]+", nm)]
    if bad:
        raise InputError(f"source names must be letters, digits and _.+-: {bad[0]!r}")
    lines = [f"# written by msleak {__version__}: point sources, fluxes in Jy, J2000, "
             "I = (XX+YY)/2 convention"]
    if comment:
        lines += [f"# {c}" for c in comment.splitlines()]
    if sources.is_tabulated:
        lines += _tabulated_lines(sources, names, channel)
    else:
        lines += _parametric_lines(sources, names)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    tmp.write_text("\n".join(lines) + "\n")
    os.replace(tmp, path)
    return path


def _tabulated_lines(sources: PointSources, names, channel: int | None) -> list[str]:
    """Format and source lines of one channel of tabulated sources, flat spectra."""
    lines: list[str] = []
    nchan = len(sources.freq)
    if channel is None:
        if nchan != 1:
            raise InputError(f"the sky has {nchan} channels; makesourcedb holds one "
                             "spectrum per source: choose a channel")
        channel = 0
    if not 0 <= channel < nchan:
        raise InputError(f"channel {channel} is outside 0..{nchan - 1}")
    nu = float(sources.freq[channel])
    lines.append(f"# sky channel {channel}: {nu:.1f} Hz, flat spectra")
    lines.append("format = Name, Type, Ra, Dec, I, Q, U, V, ReferenceFrequency, "
                 "SpectralIndex='[]'")
    for k in range(len(sources)):
        i, q, u, v = sources.stokes[k, channel]
        lines.append(f"{names[k]}, POINT, {format_ra(sources.ra[k])}, "
                     f"{format_dec(sources.dec[k])}, {_g(i)}, {_g(q)}, {_g(u)}, {_g(v)}, "
                     f"{_g(nu)}, []")
    return lines


def _parametric_lines(sources: PointSources, names) -> list[str]:
    """Format and source lines of parametric sources (spectral terms, RM)."""
    lines: list[str] = []
    n = len(sources)
    rm = sources.rotation_measure if sources.rotation_measure is not None \
        else np.full(n, np.nan)
    has_rm = np.isfinite(rm)
    nu0 = sources.ref_freq
    pfpa = has_rm & (nu0 <= 0)
    any_lin = not np.all(sources.log_si)
    cols = "Name, Type, Ra, Dec, I, Q, U, V, ReferenceFrequency, SpectralIndex='[]'"
    if any_lin:
        cols += ", LogarithmicSI='true'"
    if has_rm.any():
        cols += ", RotationMeasure"
    if pfpa.any():
        cols += ", PolarizedFraction, PolarizationAngle"
    lines.append("format = " + cols)
    for k in range(n):
        i, q, u, v = sources.stokes_ref[k]
        if has_rm[k] and not pfpa[k]:
            lam2 = (SPEED_OF_LIGHT / nu0[k]) ** 2
            p = i * sources.pol_fraction[k]
            chi = 2 * (sources.pol_angle[k] + rm[k] * lam2)
            q, u = p * math.cos(chi), p * math.sin(chi)
        si = sources.spectral_index[k] if sources.spectral_index is not None else []
        si = list(si)
        while si and si[-1] == 0:
            si.pop()
        qs, us = ("", "") if pfpa[k] else (_g(q), _g(u))
        row = [names[k], "POINT", format_ra(sources.ra[k]), format_dec(sources.dec[k]),
               _g(i), qs, us, _g(v), _g(nu0[k]) if nu0[k] > 0 else "",
               "[" + ",".join(_g(x) for x in si) + "]"]
        if any_lin:
            row.append("true" if sources.log_si[k] else "false")
        if has_rm.any():
            row.append(_g(rm[k]) if has_rm[k] else "")
        if pfpa.any():
            row += ([_g(sources.pol_fraction[k]), _g(sources.pol_angle[k])] if pfpa[k]
                    else ["", ""])
        lines.append(", ".join(row))
    return lines
