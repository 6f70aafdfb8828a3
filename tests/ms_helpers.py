"""Helpers shared by the tests that read Measurement Sets directly and need an independent
prediction of the visibilities (written here, not taken from msleak)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

C = 299_792_458.0


def table(path, readonly=True):
    import casacore.tables as pt

    return pt.table(str(path), readonly=readonly, ack=False)


def phase_centre(ms):
    with table(f"{ms}/FIELD") as t:
        ra, dec = t.getcell("PHASE_DIR", 0).reshape(-1)[:2]
    return float(ra), float(dec)


def channel_freqs(ms):
    with table(f"{ms}/SPECTRAL_WINDOW") as t:
        return np.asarray(t.getcell("CHAN_FREQ", 0), float)


def lm_to_radec(ra0, dec0, l, m):
    """(ra, dec) in rad of direction cosines (l East, m North) about the phase centre
    (ra0, dec0) in rad: the inverse of the SIN projection. Scalars or arrays."""
    n = np.sqrt(1 - l * l - m * m)
    dec = np.arcsin(m * np.cos(dec0) + n * np.sin(dec0))
    ra = ra0 + np.arctan2(l, n * np.cos(dec0) - m * np.sin(dec0))
    return ra, dec


def write_sky(path, sources):
    """makesourcedb file; sources = [(ra_rad, dec_rad, I, Q, U, V), ...] (bare numbers = rad)."""
    lines = ["format = Name, Type, Ra, Dec, I, Q, U, V"]
    for k, src in enumerate(sources):
        lines.append(f"s{k}, POINT, " + ", ".join(repr(float(x)) for x in src))
    path.write_text("\n".join(lines) + "\n")
    return path


def direct_dft(ms, sources):
    """Unbeamed visibilities (row, chan, 4) from UVW and frequencies, linear feeds:
    V = sum_s B_s exp(+2 pi i (u l + v m + w (n - 1))), (u, v, w) = UVW / lambda with the MS
    convention UVW = antenna2 - antenna1 (the convention DP3 uses, see test_predict_dp3)."""
    ra0, dec0 = phase_centre(ms)
    freq = channel_freqs(ms)
    with table(ms) as t:
        uvw = t.getcol("UVW")
    out = np.zeros((uvw.shape[0], freq.size, 4), complex)
    for ra, dec, i, q, u, v in sources:
        l = np.cos(dec) * np.sin(ra - ra0)
        m = np.sin(dec) * np.cos(dec0) - np.cos(dec) * np.sin(dec0) * np.cos(ra - ra0)
        n = np.sin(dec) * np.sin(dec0) + np.cos(dec) * np.cos(dec0) * np.cos(ra - ra0)
        phase = np.exp(2j * np.pi * (uvw @ np.array([l, m, n - 1.0]))[:, None]
                       * freq[None, :] / C)
        out += phase[:, :, None] * np.array([i + q, u + 1j * v, u - 1j * v, i - q])
    return out


def split_qu_cube(cube, prefix: str = "") -> tuple[str, str]:
    """Write the Q and U planes of an msleak sky cube as two cubes without a STOKES axis
    (as imagers write them): ``{prefix}Q.fits`` and ``{prefix}U.fits``."""
    from astropy.io import fits

    with fits.open(cube) as hdul:
        data, header = hdul[0].data, hdul[0].header
    assert header["CTYPE4"] == "STOKES" and header["CRVAL4"] == 2       # Q, U
    names = []
    for k, stokes in enumerate("QU"):
        single = header.copy()
        for key in ("CTYPE4", "CRVAL4", "CDELT4", "CRPIX4"):
            del single[key]
        names.append(f"{prefix}{stokes}.fits")
        fits.PrimaryHDU(data[k], single).writeto(names[-1])
    return names[0], names[1]


def copy_spectral_window(ms, shift_hz: float) -> None:
    """Append SPECTRAL_WINDOW row 1: a copy of row 0 with every frequency shifted by
    ``shift_hz`` (the DATA_DESCRIPTION rows are the caller's)."""
    with table(f"{ms}/SPECTRAL_WINDOW", readonly=False) as t:
        t.addrows(1)
        for col in t.colnames():
            if t.iscelldefined(col, 0):
                t.putcell(col, 1, t.getcell(col, 0))
        t.putcell("CHAN_FREQ", 1, t.getcell("CHAN_FREQ", 0) + shift_hz)
        t.putcell("REF_FREQUENCY", 1, t.getcell("REF_FREQUENCY", 0) + shift_hz)


def one_error_line(result) -> str:
    """The single ``msleak: error:`` line of a click result that exited with status 2."""
    assert result.exit_code == 2, (result.output, result.exception)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("msleak: error:"), lines
    assert "Traceback" not in result.output
    return lines[0]


def snapshot(ms: Path):
    """Columns, keywords (as text) and the sha256 of every file except table.lock."""
    with table(ms) as t:
        cols = t.colnames()
        keywords = repr(t.getkeywords())
        colkw = repr({c: t.getcolkeywords(c) for c in cols})
    files = {str(p.relative_to(ms)): hashlib.sha256(p.read_bytes()).hexdigest()
             for p in sorted(ms.rglob("*")) if p.is_file() and p.name != "table.lock"}
    return cols, keywords, colkw, files
