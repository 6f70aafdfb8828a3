"""Angles as casacore's MVAngle reads and writes them, for makesourcedb sky models
(docs/sky.md): RA ``hh:mm:ss.sss``, Dec ``+dd.mm.ss.sss``, or a number with a unit.
"""

from __future__ import annotations

import math
import re

__all__ = ["parse_angle", "format_ra", "format_dec"]

_UNITS = {"deg": math.pi / 180, "d": math.pi / 180, "rad": 1.0, "arcmin": math.pi / 10800,
          "arcsec": math.pi / 648000, "h": math.pi / 12, "": 1.0}


def parse_angle(text: str, *, allow_colon: bool = True) -> float:
    """An angle as casacore's MVAngle reads it, in radians (see module doc).

    Raises
    ------
    ValueError
        If the text is not an angle.
    """
    s = text.strip()
    if not s:
        raise ValueError("empty angle")
    sign = -1.0 if s[0] == "-" else 1.0
    body = s[1:] if s[0] in "+-" else s
    if ":" in body:
        if not allow_colon:
            raise ValueError(f"colons are not allowed in a declination ({text!r}); "
                             "use +dd.mm.ss.sss")
        parts = body.split(":")
        return sign * _sexagesimal(parts, text) * math.pi / 12
    if body.count(".") >= 2:
        return sign * _sexagesimal(body.split(".", 2), text) * math.pi / 180
    m = re.fullmatch(r"(\d*)([hHdD])(?:(\d*)[mM]?)?(?:(\d*\.?\d*)[sS]?)?", body)
    if m and m.group(1):
        scale = math.pi / 12 if m.group(2) in "hH" else math.pi / 180
        val = float(m.group(1)) + float(m.group(3) or 0) / 60 + float(m.group(4) or 0) / 3600
        return sign * val * scale
    m = re.fullmatch(r"([0-9]*\.?[0-9]+(?:[eE][-+]?\d+)?)\s*([a-zA-Z]*)", body)
    if m and m.group(2).lower() in _UNITS:
        return sign * float(m.group(1)) * _UNITS[m.group(2).lower()]
    raise ValueError(f"{text!r} is not an angle")


def _sexagesimal(parts, text) -> float:
    vals = []
    for p in parts:
        p = p.strip()
        vals.append(float(p) if p else 0.0)
    if len(vals) > 3 or any(v < 0 for v in vals):
        raise ValueError(f"{text!r} is not an angle")
    while len(vals) < 3:
        vals.append(0.0)
    return vals[0] + vals[1] / 60 + vals[2] / 3600


def format_ra(ra: float, decimals: int = 6) -> str:
    """RA (rad) as ``hh:mm:ss.ssssss`` in [0, 24h)."""
    unit = 10**decimals
    total = int(round((math.degrees(ra) % 360.0) / 15.0 * 3600 * unit)) % (24 * 3600 * unit)
    sec_units = total % (60 * unit)
    minutes = (total // (60 * unit)) % 60
    hours = total // (3600 * unit)
    return f"{hours:02d}:{minutes:02d}:{sec_units // unit:02d}.{sec_units % unit:0{decimals}d}"


def format_dec(dec: float, decimals: int = 5) -> str:
    """Dec (rad) as ``+dd.mm.ss.sssss`` (the sign always written)."""
    unit = 10**decimals
    deg = math.degrees(dec)
    sign = "-" if deg < 0 else "+"
    total = int(round(abs(deg) * 3600 * unit))
    sec_units = total % (60 * unit)
    minutes = (total // (60 * unit)) % 60
    degrees = total // (3600 * unit)
    frac = f"{sec_units % unit:0{decimals}d}"
    return f"{sign}{degrees:02d}.{minutes:02d}.{sec_units // unit:02d}.{frac}"
