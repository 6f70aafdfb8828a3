"""FITS files of any kind: recognise one, refuse one cut short (docs/products.md).

Sky cubes are read into msleak's types in :mod:`msleak.adapters.sky_fits`, image cubes
into arrays in :mod:`msleak.io.images`.
"""

from __future__ import annotations

import os

import numpy as np

from msleak.errors import InputError

__all__ = ["is_fits", "check_complete"]


def is_fits(path: str | os.PathLike) -> bool:
    """Whether the file starts like a FITS file (``SIMPLE  =``)."""
    with open(path, "rb") as fh:
        return fh.read(9) == b"SIMPLE  ="


def check_complete(path: str | os.PathLike, hdu) -> None:
    """Raise InputError if the data of ``hdu`` run past the end of the file.

    astropy pads a FITS file that was cut short (interrupted copy or download) with
    zeros and only warns; a sky or image cube with silently zeroed pixels must not be
    used.
    """
    info = hdu.fileinfo() if hasattr(hdu, "fileinfo") else None
    header = hdu.header
    if not info or "datLoc" not in info:
        return
    naxis = int(header.get("NAXIS", 0))
    shape = [int(header.get(f"NAXIS{i}", 0)) for i in range(1, naxis + 1)]
    nbytes = abs(int(header.get("BITPIX", 8))) // 8 * (int(np.prod(shape)) if shape else 0)
    need = int(info["datLoc"]) + nbytes
    size = os.path.getsize(path)
    if size < need:
        raise InputError(f"{path} is truncated: {size} bytes, its header announces {need} "
                         "(an interrupted copy or write?); get a complete copy")
