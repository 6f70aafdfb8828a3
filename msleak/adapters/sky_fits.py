"""FITS sky cubes as :class:`~msleak.sky.cube.SkyCube`: write msleak's cubes, read any cube with celestial + FREQ (+ STOKES)
axes, and convert between :class:`~msleak.sky.cube.SkyCube` and the sky Dataset.

:func:`write_cube` writes a 4-D RA---SIN, DEC--SIN, FREQ, STOKES image with the
generator's parameters as ``HIERARCH MSLEAK`` cards; :func:`read_cube` reads any axis
order and projection (a cube without STOKES axis is the Stokes parameter ``stokes``,
default I); :func:`dataset_from_cube` and :func:`cube_from_dataset` convert to and from
the Python API's Dataset.

Written and accepted layouts: docs/sky.md ("FITS cubes") and docs/products.md.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
import xarray as xr
from astropy.io import fits
from astropy.wcs import WCS, FITSFixedWarning

from msleak import __version__
from msleak.errors import InputError
from msleak.io.fits import check_complete, is_fits
from msleak.sky.cube import STOKES_CODES, SkyCube

__all__ = ["write_cube", "read_cube", "check_complete", "is_fits", "dataset_from_cube",
           "cube_from_dataset"]

_CODE_TO_STOKES = {v: k for k, v in STOKES_CODES.items()}


def write_cube(cube: SkyCube, path: str | os.PathLike, *, overwrite: bool = False,
               dtype=np.float32, history: str | None = None) -> Path:
    """Write a :class:`SkyCube` as a 4-D FITS image (see module doc); returns the path.

    Raises
    ------
    InputError
        If the file exists and ``overwrite`` is false, if the channels are not evenly
        spaced, or if the Stokes labels are not consecutive FITS codes.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise InputError(f"{path} exists; choose another name or pass overwrite",
                         param="overwrite")
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
    hdu = fits.PrimaryHDU(data=np.asarray(cube.data, dtype=dtype))
    hdr = hdu.header
    hdr.update(_wcs_cards(cube))
    hdr["CTYPE3"], hdr["CRPIX3"], hdr["CRVAL3"], hdr["CDELT3"], hdr["CUNIT3"] = (
        "FREQ", 1.0, float(freq[0]), dfreq, "Hz")
    hdr["CTYPE4"], hdr["CRPIX4"], hdr["CRVAL4"], hdr["CDELT4"] = (
        "STOKES", 1.0, float(codes[0]), 1.0)
    hdr["SPECSYS"] = "TOPOCENT"
    hdr["BUNIT"] = "K" if cube.units == "K" else "JY/PIXEL"
    hdr["BTYPE"] = "Intensity"
    hdr["ORIGIN"] = f"msleak {__version__}"
    hdr.extend(_meta_cards(cube))
    if history:
        for start in range(0, len(history), 70):
            hdr.add_history(history[start:start + 70])
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    hdu.writeto(tmp, overwrite=True)
    os.replace(tmp, path)
    return path


def _wcs_cards(cube: SkyCube) -> fits.Header:
    """The celestial WCS cards of a cube."""
    header = cube.wcs.to_header()
    for key in ("WCSAXES", "SPECSYS"):
        header.remove(key, ignore_missing=True)
    return header


def _meta_cards(cube: SkyCube) -> fits.Header:
    """``cube.meta`` as ``HIERARCH MSLEAK`` cards."""
    header = fits.Header()
    for key, value in cube.meta.items():
        if isinstance(value, (bool, np.bool_)):
            value = bool(value)
        elif isinstance(value, np.integer):
            value = int(value)
        elif isinstance(value, np.floating):
            value = float(value)
        elif not isinstance(value, (int, float, str)):
            value = str(value)
        header[f"HIERARCH MSLEAK {key}"] = value
    return header


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
    path = Path(path)
    header, data = _read_image(path)
    wcs = _header_wcs(header, str(path))
    shape_fits = data.shape[::-1]
    ilon, ilat, ispec, istokes = _cube_axes(path, wcs, shape_fits)
    _check_finite(str(path), data)
    freq = _axis_world(wcs, shape_fits, ispec)
    if not np.all(freq > 0):
        raise InputError(f"{path} has non-positive frequencies on its FREQ axis")
    if istokes is None:
        if stokes not in STOKES_CODES:
            raise InputError(f"unknown Stokes parameter {stokes!r}")
        labels = (stokes,)
    else:
        labels = _stokes_labels(path, _axis_world(wcs, shape_fits, istokes))
    # numpy axis of FITS axis i is naxis - 1 - i; bring to (stokes, freq, lat, lon)
    naxis = wcs.naxis
    order = [naxis - 1 - i for i in (ispec, ilat, ilon)]
    if istokes is not None:
        order.insert(0, naxis - 1 - istokes)
    rest = [a for a in range(naxis) if a not in order]
    data = np.transpose(data, rest + order).reshape(
        (len(labels), shape_fits[ispec], shape_fits[ilat], shape_fits[ilon]))
    units, scale = _units(header.get("BUNIT"))
    cel = wcs.celestial
    if cel.wcs.lng != 0:
        cel = cel.swapaxes(0, 1)
    cel.wcs.set()
    return SkyCube(data=np.ascontiguousarray(data * scale if scale != 1.0 else data),
                   freq=freq, stokes=labels, wcs=cel, units=units, meta=_msleak_meta(header))


def _read_image(path: Path) -> tuple[fits.Header, np.ndarray]:
    """Header and float64 data of the first >= 3-D image HDU of a complete FITS file."""
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
        return hdu.header, np.asarray(hdu.data, dtype=float)


def _header_wcs(header: fits.Header, name: str) -> WCS:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FITSFixedWarning)
        try:
            return WCS(header)
        except Exception as err:  # noqa: BLE001 - astropy/wcslib raise many types
            raise InputError(f"{name}: invalid WCS in the FITS header "
                             f"({' '.join(str(err).split())[:160]})") from None


def _cube_axes(path: Path, wcs: WCS, shape_fits: tuple[int, ...]
               ) -> tuple[int, int, int, int | None]:
    """FITS axis indices (0-based) of longitude, latitude, FREQ and STOKES (or None)."""
    if not wcs.has_celestial:
        raise InputError(f"{path} has no celestial (RA/Dec) axes")
    ctypes = [str(c).upper() for c in wcs.wcs.ctype]
    spec = [i for i, c in enumerate(ctypes) if c.startswith("FREQ")]
    if not spec:
        raise InputError(f"{path} has no FREQ axis (axes: {', '.join(ctypes)})")
    istokes = next((i for i, c in enumerate(ctypes) if c == "STOKES"), None)
    axes = (wcs.wcs.lng, wcs.wcs.lat, spec[0], istokes)
    for i in range(wcs.naxis):
        if i not in axes and shape_fits[i] != 1:
            raise InputError(f"{path} has an extra axis {ctypes[i]} of length {shape_fits[i]}")
    return axes


def _axis_world(wcs: WCS, shape_fits: tuple[int, ...], axis: int) -> np.ndarray:
    """World values (SI: wcslib converts spectral units) along one FITS axis."""
    pix = np.tile(wcs.wcs.crpix - 1, (shape_fits[axis], 1))
    pix[:, axis] = np.arange(shape_fits[axis])
    return wcs.wcs_pix2world(pix, 0)[:, axis].astype(float)


def _stokes_labels(path: Path, codes: np.ndarray) -> tuple[str, ...]:
    codes = np.rint(codes).astype(int)
    try:
        return tuple(_CODE_TO_STOKES[int(c)] for c in codes)
    except KeyError:
        raise InputError(f"{path} has STOKES codes {list(codes)}; only I, Q, U, V "
                         "(1..4) are supported") from None


def _check_finite(name: str, data: np.ndarray) -> None:
    bad = ~np.isfinite(data)
    if np.any(bad):
        raise InputError(f"{name} has {int(bad.sum())} NaN or infinite values; blank pixels "
                         "are not allowed in a sky cube")


def _msleak_meta(header: fits.Header) -> dict:
    return {k[len("MSLEAK "):]: header[k] for k in header
            if isinstance(k, str) and k.startswith("MSLEAK ")}


def dataset_from_cube(cube: SkyCube) -> xr.Dataset:
    """The sky Dataset of a cube: what its FITS file holds (docs/products.md, "sky").

    Returns
    -------
    Dataset with one float32 variable per Stokes parameter of the cube, dims
    (freq, y, x), in ``units`` (K or Jy/pixel); coordinates ``freq`` (Hz), ``x``, ``y``
    (projection-plane offsets of the pixel centres from the reference pixel, deg, along
    the FITS axes: for msleak's SIN cubes x = l, east positive, and y = m), ``ra``, ``dec``
    (y, x) (deg, J2000, NaN outside the projection); attributes ``units`` and
    ``fits_header`` (the celestial WCS and ``HIERARCH MSLEAK`` cards, as text).
    """
    ny, nx = cube.npix
    scale, crpix = cube.wcs.pixel_scale_matrix, cube.wcs.wcs.crpix
    yy, xx = np.mgrid[0:ny, 0:nx].astype(float)
    ra, dec = cube.wcs.all_pix2world(xx, yy, 0)
    header = _wcs_cards(cube)
    header.extend(_meta_cards(cube))
    dims = ("freq", "y", "x")
    data_vars = {s: (dims, np.asarray(cube.data[k], dtype=np.float32),
                     {"units": cube.units, "long_name": f"Stokes {s}"})
                 for k, s in enumerate(cube.stokes)}
    coords = {
        "freq": ("freq", np.asarray(cube.freq, dtype=float), {"units": "Hz"}),
        "y": ("y", (np.arange(ny) - (crpix[1] - 1)) * scale[1, 1],
              {"units": "deg", "long_name": "offset along the FITS y axis"}),
        "x": ("x", (np.arange(nx) - (crpix[0] - 1)) * scale[0, 0],
              {"units": "deg", "long_name": "offset along the FITS x axis"}),
        "ra": (("y", "x"), np.mod(ra, 360.0), {"units": "deg"}),
        "dec": (("y", "x"), dec, {"units": "deg"}),
    }
    return xr.Dataset(data_vars, coords=coords, attrs={
        "units": cube.units, "fits_header": header.tostring(sep="\n")})


def cube_from_dataset(ds: xr.Dataset) -> SkyCube:
    """The :class:`SkyCube` of a sky Dataset (:func:`dataset_from_cube`), float64 data.

    Raises
    ------
    InputError
        No ``fits_header`` attribute or invalid WCS in it, no Stokes variable, or NaN or
        infinite values.
    """
    if "fits_header" not in ds.attrs:
        raise InputError("the sky Dataset has no fits_header attribute; make it with "
                         "msleak.make_sky")
    labels = tuple(s for s in STOKES_CODES if s in ds.data_vars)
    if not labels:
        raise InputError("the sky Dataset has no Stokes variable (I, Q, U or V)")
    header = fits.Header.fromstring(ds.attrs["fits_header"], sep="\n")
    wcs = _header_wcs(header, "the sky Dataset")
    wcs.wcs.set()
    data = np.stack([np.asarray(ds[s].transpose("freq", "y", "x").values, dtype=float)
                     for s in labels])
    _check_finite("the sky Dataset", data)
    return SkyCube(data=data, freq=np.asarray(ds["freq"].values, dtype=float),
                   stokes=labels, wcs=wcs, units=ds.attrs.get("units", ""),
                   meta=_msleak_meta(header))
