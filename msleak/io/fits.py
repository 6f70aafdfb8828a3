"""FITS sky cubes: write msleak's cubes, read any cube with celestial + FREQ (+ STOKES) axes.

Written layout (primary HDU, float32 by default)::

    NAXIS1 = nx  RA---SIN   CDELT1 < 0, deg
    NAXIS2 = ny  DEC--SIN   deg            (LONPOLE = 180)
    NAXIS3 = nchan FREQ     Hz, channel i at CRVAL3 + i * CDELT3
    NAXIS4 = nstokes STOKES Q, U = 2, 3 (FITS codes)
    BUNIT  = 'K' or 'JY/PIXEL'

plus the generator's parameters as ``HIERARCH MSLEAK ...`` cards (``MSLEAK POLFRAME =
'LOCAL-NORTH'``: Q and U are referred to the local celestial North of each pixel, the
FITS convention) and a HISTORY card with the command line. Cubes of an older msleak
generator (``MSLEAK GENERATR`` without ``MSLEAK POLFRAME``) held Q and U referred to the
image +y axis; :func:`read_cube` turns them to the local North, with a warning. Reading accepts any axis order, any celestial projection, CUNIT3 in any
frequency unit, degenerate extra axes, and a missing STOKES axis (then the cube is taken
to be the Stokes parameter given by ``stokes``, default I).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from msleak import __version__
from msleak.errors import InputError
from msleak.sky.cube import (POLFRAME, STOKES_CODES, SkyCube, rotate_polarization,
                             y_axis_position_angle)

__all__ = ["write_cube", "read_cube", "check_complete"]

_CODE_TO_STOKES = {v: k for k, v in STOKES_CODES.items()}

log = logging.getLogger(__name__)


def write_cube(cube: SkyCube, path: str | os.PathLike, *, overwrite: bool = False,
               dtype=np.float32, history: str | None = None) -> Path:
    """Write a :class:`SkyCube` as a 4-D FITS image (see module doc); returns the path.

    Raises
    ------
    InputError
        If the file exists and ``overwrite`` is false, if the channels are not evenly
        spaced, or if the Stokes labels are not consecutive FITS codes.
    """
    from astropy.io import fits

    path = Path(path)
    if path.exists() and not overwrite:
        raise InputError(f"{path} exists; choose another name or pass --overwrite")
    freq = np.asarray(cube.freq, float)
    if freq.size > 1:
        step = np.diff(freq)
        if not np.allclose(step, step[0], rtol=1e-9, atol=0):
            raise InputError("FITS cubes need evenly spaced channels")
        dfreq = float(step[0])
    else:
        dfreq = float(cube.meta.get("CHANWID", 1.0))
    codes = [STOKES_CODES[s] for s in cube.stokes]
    if any(b - a != 1 for a, b in zip(codes, codes[1:])):
        raise InputError(f"Stokes {cube.stokes} are not consecutive FITS codes")
    header = cube.wcs.to_header()
    for key in ("WCSAXES",):
        header.remove(key, ignore_missing=True)
    hdu = fits.PrimaryHDU(data=np.asarray(cube.data, dtype=dtype))
    hdr = hdu.header
    hdr.update(header)
    hdr["CTYPE3"], hdr["CRPIX3"], hdr["CRVAL3"], hdr["CDELT3"], hdr["CUNIT3"] = (
        "FREQ", 1.0, float(freq[0]), dfreq, "Hz")
    hdr["CTYPE4"], hdr["CRPIX4"], hdr["CRVAL4"], hdr["CDELT4"] = (
        "STOKES", 1.0, float(codes[0]), 1.0)
    hdr["SPECSYS"] = "TOPOCENT"
    hdr["BUNIT"] = "K" if cube.units == "K" else "JY/PIXEL"
    hdr["BTYPE"] = "Intensity"
    hdr["ORIGIN"] = f"msleak {__version__}"
    for key, value in cube.meta.items():
        if isinstance(value, (bool, np.bool_)):
            value = bool(value)
        elif isinstance(value, (np.integer,)):
            value = int(value)
        elif isinstance(value, (np.floating,)):
            value = float(value)
        elif not isinstance(value, (int, float, str)):
            value = str(value)
        hdr[f"HIERARCH MSLEAK {key}"] = value
    if history:
        for start in range(0, len(history), 70):
            hdr.add_history(history[start:start + 70])
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    hdu.writeto(tmp, overwrite=True)
    os.replace(tmp, path)
    return path


def _units(bunit: str | None) -> tuple[str, float]:
    if bunit is None or not str(bunit).strip():
        raise InputError("the cube has no BUNIT; set BUNIT to K or JY/PIXEL in its header")
    b = str(bunit).strip().upper().replace(" ", "")
    if b in ("K", "KELVIN"):
        return "K", 1.0
    if b == "MK":
        return "K", 1e-3
    if b in ("JY/PIXEL", "JY/PIX", "JY"):
        return "Jy/pixel", 1.0
    if b in ("MJY/PIXEL", "MJY/PIX"):
        return "Jy/pixel", 1e-3
    if "BEAM" in b:
        raise InputError(f"the cube is in {bunit}; convert it to JY/PIXEL or K first "
                         "(msleak does not know the restoring beam area)")
    raise InputError(f"unsupported BUNIT {bunit!r}; use K or JY/PIXEL")


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


def read_cube(path: str | os.PathLike, *, stokes: str = "I") -> SkyCube:
    """Read a FITS cube with two celestial axes, a FREQ axis and optionally STOKES.

    Parameters
    ----------
    path : FITS file; the first HDU with a >= 3-D image is used
    stokes : the Stokes parameter of a cube without a STOKES axis

    Raises
    ------
    InputError
        Not a FITS file, no celestial or FREQ axis, extra non-degenerate axes, NaN or
        infinite values, or an unsupported BUNIT.
    """
    from astropy.io import fits
    from astropy.wcs import WCS, FITSFixedWarning
    import warnings

    path = Path(path)
    if not path.exists():
        raise InputError(f"FITS cube {path} does not exist")
    try:
        hdul = fits.open(path, memmap=False)
    except (OSError, ValueError) as err:
        raise InputError(f"{path} is not a readable FITS file ({err})") from None
    with hdul:
        for h in hdul:
            check_complete(path, h)
        hdu = next((h for h in hdul if getattr(h, "data", None) is not None
                    and getattr(h, "is_image", False) and h.data.ndim >= 3), None)
        if hdu is None:
            raise InputError(f"{path} has no image with at least 3 axes (RA, Dec, FREQ)")
        header = hdu.header
        data = np.asarray(hdu.data, dtype=float)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FITSFixedWarning)
        try:
            wcs = WCS(header)
        except Exception as err:  # noqa: BLE001 - astropy/wcslib raise many types
            raise InputError(f"{path}: invalid WCS in the FITS header "
                             f"({' '.join(str(err).split())[:160]})") from None
    naxis = wcs.naxis
    if not wcs.has_celestial:
        raise InputError(f"{path} has no celestial (RA/Dec) axes")
    ctypes = [str(c).upper() for c in wcs.wcs.ctype]
    spec = [i for i, c in enumerate(ctypes) if c.startswith("FREQ")]
    if not spec:
        raise InputError(f"{path} has no FREQ axis (axes: {', '.join(ctypes)})")
    ispec = spec[0]
    istokes = next((i for i, c in enumerate(ctypes) if c == "STOKES"), None)
    ilon, ilat = wcs.wcs.lng, wcs.wcs.lat
    shape_fits = data.shape[::-1]  # FITS axis order
    used = {ilon, ilat, ispec} | ({istokes} if istokes is not None else set())
    for i in range(naxis):
        if i not in used and shape_fits[i] != 1:
            raise InputError(f"{path} has an extra axis {ctypes[i]} of length {shape_fits[i]}")
    bad = ~np.isfinite(data)
    if np.any(bad):
        raise InputError(f"{path} has {int(bad.sum())} NaN or infinite values; blank pixels "
                         "are not allowed in a sky cube")
    # frequencies (Hz: wcslib converts spectral units to SI)
    pix = np.zeros((shape_fits[ispec], naxis))
    pix[:, ispec] = np.arange(shape_fits[ispec])
    for i in range(naxis):
        if i != ispec:
            pix[:, i] = wcs.wcs.crpix[i] - 1
    world = wcs.wcs_pix2world(pix, 0)
    freq = world[:, ispec].astype(float)
    if not np.all(freq > 0):
        raise InputError(f"{path} has non-positive frequencies on its FREQ axis")
    if istokes is not None:
        pix = np.zeros((shape_fits[istokes], naxis))
        pix[:, istokes] = np.arange(shape_fits[istokes])
        codes = np.rint(wcs.wcs_pix2world(pix, 0)[:, istokes]).astype(int)
        try:
            labels = tuple(_CODE_TO_STOKES[int(c)] for c in codes)
        except KeyError:
            raise InputError(f"{path} has STOKES codes {list(codes)}; only I, Q, U, V "
                             "(1..4) are supported") from None
    else:
        if stokes not in STOKES_CODES:
            raise InputError(f"unknown Stokes parameter {stokes!r}")
        labels = (stokes,)
    # numpy axis of FITS axis i is naxis - 1 - i; bring to (stokes, freq, lat, lon)
    order = []
    order.append(naxis - 1 - istokes if istokes is not None else None)
    order += [naxis - 1 - ispec, naxis - 1 - ilat, naxis - 1 - ilon]
    rest = [a for a in range(naxis) if a not in order]
    if istokes is None:
        data = np.transpose(data, rest + order[1:])
        data = data.reshape(data.shape[-3:])[None]
    else:
        data = np.transpose(data, rest + order).reshape(
            (len(labels), shape_fits[ispec], shape_fits[ilat], shape_fits[ilon]))
    units, scale = _units(header.get("BUNIT"))
    if scale != 1.0:
        data = data * scale
    cel = wcs.celestial
    if cel.wcs.lng != 0:
        cel = cel.swapaxes(0, 1)
    cel.wcs.set()
    meta = {k[len("MSLEAK "):]: header[k] for k in header
            if isinstance(k, str) and k.startswith("MSLEAK ")}
    cube = SkyCube(data=np.ascontiguousarray(data), freq=freq, stokes=labels, wcs=cel,
                   units=units, meta=meta)
    if ("GENERATR" in meta and str(meta["GENERATR"]).startswith("msleak.sky.foreground")
            and "POLFRAME" not in meta and {"Q", "U"} & set(labels)):
        log.warning("%s was made by an older msleak with Q, U referred to the image +y "
                    "axis; turning them to the local North of each pixel (FITS convention)",
                    path)
        cube = rotate_polarization(cube, y_axis_position_angle(cel, cube.npix))
        cube.meta["POLFRAME"] = POLFRAME
    return cube
