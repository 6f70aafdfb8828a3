"""FITS image cubes as ``msleak grid`` reads them (docs/grid.md): axes RA---*, DEC--*
(square pixels), FREQ (evenly spaced), optional STOKES (values 1..4 = I, Q, U, V) and any
other axis of length 1.
"""

from __future__ import annotations

import math
import os

import numpy as np

from msleak.errors import InputError
from msleak.io.fits import check_complete

__all__ = ["read_image_cube"]

_STOKES_CODES = {1: "I", 2: "Q", 3: "U", 4: "V"}


def read_image_cube(path: str | os.PathLike, stokes: str | None = None) -> dict:
    """Read a FITS image cube.

    Returns
    -------
    dict with ``cube`` {stokes: (chan, y, x) float array in the file's unit}, ``freq``
    (chan,) Hz, ``dl_x``, ``dl_y`` (signed pixel increments, rad), ``unit`` (BUNIT),
    ``bmaj_deg``, ``bmin_deg`` (the restoring beam's FWHM, BMAJ and BMIN, or None),
    ``ra_deg``, ``dec_deg`` and ``crpix_x``, ``crpix_y`` (the RA, Dec axes' reference
    values and pixels).
    """
    path = os.fspath(path)
    header, data = _read_hdu(path)
    naxis = header["NAXIS"]
    ctypes = [str(header.get(f"CTYPE{i}", "")).upper() for i in range(1, naxis + 1)]

    def find(prefix):
        hits = [i for i, c in enumerate(ctypes) if c.startswith(prefix)]
        return hits[0] if hits else None

    ax_f, ax_x, ax_y, ax_s = find("FREQ"), find("RA"), find("DEC"), find("STOKES")
    if ax_f is None:
        raise InputError(f"{path}: image has no FREQ axis (CTYPEs {', '.join(ctypes)}); "
                         "a spectral cube is needed for the delay transform")
    if ax_x is None or ax_y is None:
        raise InputError(f"{path}: image needs RA and DEC axes (CTYPEs {', '.join(ctypes)})")
    freq = _world(header, ax_f)
    if freq.size > 1 and not np.allclose(np.diff(freq), np.diff(freq)[0], rtol=1e-6):
        raise InputError(f"{path}: FREQ axis is not evenly spaced")
    # numpy axis order is the reverse of FITS order
    np_ax = {name: naxis - 1 - ax for name, ax in
             (("f", ax_f), ("y", ax_y), ("x", ax_x)) + ((("s", ax_s),) if ax_s is not None else ())}
    others = [a for a in range(naxis) if a not in np_ax.values()]
    if any(data.shape[a] != 1 for a in others):
        raise InputError(f"{path}: unexpected non-degenerate axes {ctypes}")
    order = [np_ax["s"]] if "s" in np_ax else []
    order += [np_ax["f"], np_ax["y"], np_ax["x"]] + others
    data = np.transpose(data, order).reshape(
        ([data.shape[np_ax["s"]]] if "s" in np_ax else [1])
        + [data.shape[np_ax["f"]], data.shape[np_ax["y"]], data.shape[np_ax["x"]]])
    labels = _stokes_labels(path, header, ax_s, stokes)
    return {
        "cube": {s: np.nan_to_num(data[i]) for i, s in enumerate(labels)},
        "freq": freq,
        "dl_x": math.radians(header.get(f"CDELT{ax_x + 1}")),
        "dl_y": math.radians(header.get(f"CDELT{ax_y + 1}")),
        "unit": str(header.get("BUNIT", "")).strip(),
        "bmaj_deg": header.get("BMAJ"), "bmin_deg": header.get("BMIN"),
        "ra_deg": float(header.get(f"CRVAL{ax_x + 1}", 0.0)),
        "dec_deg": float(header.get(f"CRVAL{ax_y + 1}", 0.0)),
        "crpix_x": float(header.get(f"CRPIX{ax_x + 1}", 1.0)),
        "crpix_y": float(header.get(f"CRPIX{ax_y + 1}", 1.0)),
    }


def _read_hdu(path: str) -> tuple:
    """The header and float64 data of the first HDU of ``path`` with 3 or more axes
    (every HDU checked complete)."""
    from astropy.io import fits

    if not os.path.exists(path):
        raise InputError(f"{path}: no such image cube")
    try:
        with fits.open(path) as hdul:
            for h in hdul:
                check_complete(path, h)
            hdu = next((h for h in hdul if h.data is not None and h.data.ndim >= 3), None)
            if hdu is None:
                raise InputError(f"{path}: no image cube (an HDU with 3 or more axes)")
            return hdu.header, np.asarray(hdu.data, dtype=np.float64)
    except OSError as err:
        raise InputError(f"{path}: not a readable FITS file ({err})") from err


def _world(header, ax: int) -> np.ndarray:
    """World coordinates of the pixels of FITS axis ``ax`` (0-based), linear."""
    n = header[f"NAXIS{ax + 1}"]
    return (header.get(f"CRVAL{ax + 1}", 0.0)
            + (np.arange(n) + 1 - header.get(f"CRPIX{ax + 1}", 1.0))
            * header.get(f"CDELT{ax + 1}", 1.0))


def _stokes_labels(path: str, header, ax_s: int | None, stokes: str | None) -> list[str]:
    """The Stokes label of each plane: from the STOKES axis, else ``stokes`` (default I)."""
    if ax_s is None:
        return [stokes or "I"]
    codes = [int(round(c)) for c in _world(header, ax_s)]
    bad = [c for c in codes if c not in _STOKES_CODES]
    if bad:
        raise InputError(f"{path}: STOKES axis values {bad} are not I, Q, U or V (1..4)")
    labels = [_STOKES_CODES[c] for c in codes]
    if stokes is not None and len(labels) == 1 and stokes != labels[0]:
        raise InputError(f"{path}: file holds Stokes {labels[0]}, not {stokes}")
    return labels
