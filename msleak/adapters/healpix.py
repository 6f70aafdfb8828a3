"""All-sky HEALPix skies from files as :class:`~msleak.sky.healpix.HealpixSky`: SkyH5
(pyradiosky) and HEALPix FITS maps.

:func:`read_healpix` picks the reader by content: an HDF5 file is SkyH5
(:func:`read_skyh5`), a FITS file with a HEALPix header (``PIXTYPE = 'HEALPIX'``) a map
(:func:`read_healpix_fits`: a table of Stokes columns as healpy writes it, with an optional
rotation-measure column, or an image cube of pixel x frequency x Stokes). Maps keep their
pixel grid and frame (ICRS, Galactic or ecliptic); predict turns their pixels into ICRS
point sources. Layouts, keywords and conventions: docs/sky.md ("HEALPix skies").
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np
from astropy.io import fits

from msleak.errors import InputError
from msleak.io.fits import check_complete, is_fits
from msleak.sky.healpix import HealpixSky

__all__ = ["read_healpix", "read_skyh5", "read_healpix_fits", "is_hdf5", "is_healpix_fits",
           "HEALPIX_UNSEEN"]

log = logging.getLogger(__name__)

#: the first bytes of every HDF5 file
_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
#: healpy's value for a pixel without data (``healpy.UNSEEN``)
HEALPIX_UNSEEN = -1.6375e30
#: FITS COORDSYS values -> msleak's frame names (C/Q: celestial, read as ICRS)
_COORDSYS = {"G": "galactic", "GALACTIC": "galactic", "E": "ecliptic", "ECLIPTIC": "ecliptic",
             "C": "icrs", "Q": "icrs", "CELESTIAL": "icrs", "EQUATORIAL": "icrs",
             "ICRS": "icrs", "FK5": "icrs", "J2000": "icrs"}
#: column names (upper case, '-' as '_') of each Stokes parameter in a map table
_STOKES_COLUMNS = {"I": ("I", "I_STOKES", "TEMPERATURE", "T", "I_POLARISATION"),
                   "Q": ("Q", "Q_STOKES", "Q_POLARISATION", "Q_POLARIZATION"),
                   "U": ("U", "U_STOKES", "U_POLARISATION", "U_POLARIZATION"),
                   "V": ("V", "V_STOKES", "V_POLARISATION", "V_POLARIZATION")}
_RM_COLUMNS = ("RM", "ROTATION_MEASURE")
#: brightness units -> (msleak unit, factor)
_UNITS = {"K": ("K", 1.0), "KELVIN": ("K", 1.0), "MK": ("K", 1e-3), "UK": ("K", 1e-6),
          "JY/SR": ("Jy/sr", 1.0), "MJY/SR": ("Jy/sr", 1e6)}
_RM_UNITS = ("RAD/M2", "RAD/M^2", "RAD/M**2", "RADM-2", "RAD.M-2", "RAD*M-2", "RAD/(M2)")
_FREQ_UNITS = {"HZ": 1.0, "KHZ": 1e3, "MHZ": 1e6, "GHZ": 1e9}


def is_hdf5(path: str | os.PathLike) -> bool:
    """Whether the file starts with the HDF5 signature."""
    with open(path, "rb") as fh:
        return fh.read(8) == _HDF5_SIGNATURE


def is_healpix_fits(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a FITS file with an HDU whose header says PIXTYPE = 'HEALPIX'."""
    if not is_fits(path):
        return False
    try:
        with fits.open(path, memmap=False, lazy_load_hdus=True) as hdul:
            return any(_healpix_header(hdu.header) for hdu in hdul)
    except (OSError, ValueError):
        return False


def _healpix_header(header) -> bool:
    return str(header.get("PIXTYPE", "")).strip().upper() == "HEALPIX"


def read_healpix(path: str | os.PathLike, *, flat_spectrum: bool = False) -> HealpixSky:
    """An all-sky sky from a SkyH5 or HEALPix FITS file (see module doc).

    Parameters
    ----------
    flat_spectrum : bool
        Use a map of one frequency (or none) at every channel, unchanged.
    """
    path = Path(path)
    if is_hdf5(path):
        return read_skyh5(path, flat_spectrum=flat_spectrum)
    if is_healpix_fits(path):
        return read_healpix_fits(path, flat_spectrum=flat_spectrum)
    raise InputError(f"{path} is neither a SkyH5 (HDF5) file nor a FITS file with a "
                     "HEALPix header (PIXTYPE = 'HEALPIX')")


# ---------------------------------------------------------------- SkyH5


def read_skyh5(path: str | os.PathLike, *, flat_spectrum: bool = False) -> HealpixSky:
    """A pyradiosky SkyH5 file of HEALPix components (spectral type full, subband or flat;
    K or Jy/sr; frame ICRS, FK5 J2000, Galactic).

    Raises
    ------
    InputError
        Not a SkyH5 file pyradiosky reads, point components, a spectral index, another
        frame or unit, or pyradiosky missing.
    """
    path = Path(path)
    try:
        from pyradiosky import SkyModel
    except ImportError as err:
        raise InputError(f"{path}: reading SkyH5 needs pyradiosky; pip install "
                         "'msleak[healpix]'") from err
    try:
        model = SkyModel.from_file(str(path), filetype="skyh5")
    except Exception as err:  # noqa: BLE001 - h5py/pyradiosky raise many kinds
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise InputError(f"{path}: not a SkyH5 file pyradiosky can read ({first})") from err
    if model.component_type != "healpix":
        raise InputError(f"{path}: holds {model.component_type} components; msleak reads "
                         "HEALPix SkyH5 skies (make a makesourcedb file of point sources)")
    unit, stokes = _skyh5_unit(path, model.stokes)
    freq, flat = _skyh5_spectrum(path, model, flat_spectrum)
    return HealpixSky(nside=int(model.nside), order=str(model.hpx_order).lower(),
                      pixels=np.asarray(model.hpx_inds), freq_hz=freq, stokes=stokes,
                      unit=unit, label=str(path), frame=_skyh5_frame(path, model.hpx_frame),
                      flat=flat)


def _skyh5_unit(path: Path, stokes) -> tuple[str, np.ndarray]:
    """(unit, values): a brightness in K or Jy/sr (or a multiple of either)."""
    import astropy.units as u

    for unit, target in (("K", u.K), ("Jy/sr", u.Jy / u.sr)):
        if stokes.unit.is_equivalent(target):
            return unit, np.asarray(stokes.to_value(target), dtype=float)
    raise InputError(f"{path}: Stokes in {stokes.unit}; msleak reads HEALPix brightness in "
                     "K or Jy/sr")


def _skyh5_spectrum(path: Path, model, flat_spectrum: bool) -> tuple[np.ndarray, bool]:
    """(channel frequencies (Hz), flat) of a SkyH5 sky."""
    kind = model.spectral_type
    if kind in ("full", "subband"):
        freq = np.asarray(model.freq_array.to_value("Hz"), dtype=float)
        flat = bool(flat_spectrum)
        if flat and freq.size != 1:
            raise InputError(f"{path}: flat_spectrum uses one map at every channel; this "
                             f"sky has {freq.size} channels", param="flat_spectrum")
        return freq, flat
    if kind == "flat":
        ref = getattr(model, "reference_frequency", None)
        value = (float(np.asarray(ref.to_value("Hz")).ravel()[0]) if ref is not None
                 else float("nan"))
        return np.array([value]), True
    raise InputError(f"{path}: spectral type {kind!r}; msleak reads full, subband or flat "
                     "HEALPix skies (evaluate it with SkyModel.at_frequencies first)")


def _skyh5_frame(path: Path, frame) -> str:
    """msleak's frame name of a SkyH5 HEALPix frame (FK5 J2000 is read as ICRS)."""
    name = str(getattr(frame, "name", frame)).lower()
    if name == "fk5":
        equinox = getattr(frame, "equinox", None)
        if equinox is not None and abs(float(equinox.jyear) - 2000.0) > 1e-6:
            raise InputError(f"{path}: FK5 frame of equinox {equinox}; msleak reads FK5 "
                             "J2000, ICRS or Galactic skies")
        return "icrs"
    if name in ("icrs", "galactic"):
        return name
    raise InputError(f"{path}: frame {name!r}; msleak reads ICRS, FK5 J2000 or Galactic "
                     "HEALPix skies")


# ---------------------------------------------------------------- FITS maps


def read_healpix_fits(path: str | os.PathLike, *, flat_spectrum: bool = False) -> HealpixSky:
    """A HEALPix FITS map: the first HDU with PIXTYPE = 'HEALPIX', either a binary table of
    Stokes columns (one map each, optional RM column, frequency from the FREQ keyword) or
    an image of pixel x FREQ x STOKES (docs/sky.md, "HEALPix skies").

    Raises
    ------
    InputError
        A header keyword or column missing or not understood (the message names it).
    """
    path = Path(path)
    with fits.open(path, memmap=False) as hdul:
        hdu = next((h for h in hdul if _healpix_header(h.header)), None)
        if hdu is None:
            raise InputError(f"{path} has no HDU with PIXTYPE = 'HEALPIX'")
        check_complete(path, hdu)
        header = hdu.header
        geometry = _geometry(path, header)
        cosmo = _cosmo_convention(path, header, hdul[0].header)
        if isinstance(hdu, fits.BinTableHDU):
            parts = _table_maps(path, hdu, hdul[0].header, flat_spectrum)
        elif hdu.is_image:
            parts = _image_maps(path, hdu, geometry[0], flat_spectrum)
        else:
            raise InputError(f"{path}: the HEALPix HDU is neither a binary table nor an image")
    nside, order, frame = geometry
    pixels, freq, stokes, unit, rm, flat = parts
    if cosmo:                         # U of the COSMO convention is -U of the IAU's
        stokes = stokes * np.array([1.0, 1.0, -1.0, 1.0])[:, None, None]
    pixels, stokes, rm = _drop_unseen(path, pixels, stokes, rm)
    return HealpixSky(nside=nside, order=order, pixels=pixels, freq_hz=freq, stokes=stokes,
                      unit=unit, label=str(path), frame=frame, flat=flat,
                      rotation_measure=rm)


def _cosmo_convention(path: Path, header, primary) -> bool:
    """Whether the maps' Q, U follow the COSMO convention (POLCCONV = 'COSMO', as Planck
    writes them: U of opposite sign); IAU when POLCCONV says so or is absent."""
    conv = str(header.get("POLCCONV", primary.get("POLCCONV", "IAU"))).strip().upper()
    if conv not in ("IAU", "COSMO"):
        raise InputError(f"{path}: POLCCONV is {conv!r}; give 'IAU' or 'COSMO' (the sign "
                         "convention of U)")
    return conv == "COSMO"


def _geometry(path: Path, header) -> tuple[int, str, str]:
    """(NSIDE, ordering, frame) from a HEALPix header."""
    nside = header.get("NSIDE")
    if not isinstance(nside, (int, np.integer)) or nside < 1:
        raise InputError(f"{path}: the HEALPix header has no NSIDE (a power of 2); set it")
    order = str(header.get("ORDERING", "")).strip().upper()
    if order not in ("RING", "NESTED"):
        said = f"ORDERING is {order!r}" if order else "no ORDERING"
        raise InputError(f"{path}: the HEALPix header has {said}; set it to RING or NESTED")
    coordsys = str(header.get("COORDSYS", "")).strip().upper()
    if coordsys not in _COORDSYS:
        said = f"COORDSYS is {coordsys!r}" if coordsys else "no COORDSYS"
        raise InputError(f"{path}: the HEALPix header has {said}; set it to G (Galactic), "
                         "C (celestial, ICRS/J2000) or E (ecliptic)")
    return int(nside), order.lower(), _COORDSYS[coordsys]


def _unit(path: Path, text, where: str) -> tuple[str, float]:
    """(msleak unit, factor) of a brightness unit string (``where`` names its keyword)."""
    raw = "" if text is None else str(text).strip()
    key = raw.upper().replace(" ", "").replace("_RJ", "")
    if key not in _UNITS:
        said = f"{where} is {raw!r}" if raw else f"{where} is not given"
        hint = (" (a CMB thermodynamic temperature, not a brightness temperature)"
                if "CMB" in key else "")
        raise InputError(f"{path}: {said}{hint}; msleak reads HEALPix brightness in K or "
                         "Jy/sr (set it to one)")
    return _UNITS[key]


def _map_frequency(path: Path, headers, rm: bool, flat_spectrum: bool, nmaps: int = 1
                   ) -> tuple[np.ndarray, bool]:
    """(frequency (Hz) of a one-frequency map, flat) from the FREQ keyword."""
    value = next((h["FREQ"] for h in headers if "FREQ" in h), None)
    if value is not None and (isinstance(value, str) or not np.isfinite(value) or value <= 0):
        raise InputError(f"{path}: header FREQ = {value!r} is not a frequency in Hz; set "
                         "FREQ to the map's frequency in Hz")
    if value is None and rm:
        raise InputError(f"{path}: a rotation-measure map needs the frequency of the Q, U "
                         "maps; set the header keyword FREQ (Hz)")
    if value is None and not flat_spectrum:
        raise InputError(f"{path}: the map has no frequency (header keyword FREQ, Hz); set "
                         "FREQ, or pass flat_spectrum to use it at every channel",
                         param="flat_spectrum")
    freq = np.array([float("nan") if value is None else float(value)])
    return freq, bool(flat_spectrum) and not rm


def _table_maps(path: Path, hdu, primary, flat_spectrum: bool) -> tuple:
    """Pixels, frequency, Stokes (4, 1, npix), unit, RM and flat of a map table."""
    names = {c.name.strip().upper().replace("-", "_"): c for c in hdu.columns}
    found = {s: next((names[n] for n in options if n in names), None)
             for s, options in _STOKES_COLUMNS.items()}
    if not any(found.values()):
        names_given = ", ".join(c.name for c in hdu.columns)
        raise InputError(f"{path}: no Stokes column among {names_given}; name them I, Q, U, "
                         "V (TTYPEn)")
    data = hdu.data
    nrow = None
    stokes, unit = None, None
    for k, column in enumerate(found.values()):
        if column is None:
            continue
        values = np.asarray(data[column.name], dtype=float).ravel()
        this, factor = _unit(path, column.unit, f"the unit (TUNIT) of column {column.name}")
        if unit is not None and this != unit:
            raise InputError(f"{path}: columns in K and in Jy/sr; give every Stokes column "
                             "the same kind of unit")
        if nrow is not None and values.size != nrow:
            raise InputError(f"{path}: column {column.name} has {values.size} values, the "
                             f"others {nrow}")
        unit, nrow = this, values.size
        stokes = np.zeros((4, 1, values.size)) if stokes is None else stokes
        stokes[k, 0] = np.where(_missing(values), values, values * factor)
    rm_col = next((names[n] for n in _RM_COLUMNS if n in names), None)
    rm = None
    if rm_col is not None:
        if str(rm_col.unit or "").strip() and str(rm_col.unit).strip().upper().replace(
                " ", "") not in _RM_UNITS:
            raise InputError(f"{path}: the unit of column {rm_col.name} is {rm_col.unit!r}; "
                             "a rotation measure is in rad/m2")
        rm = np.asarray(data[rm_col.name], dtype=float).ravel()
        if rm.size != nrow:
            raise InputError(f"{path}: column {rm_col.name} has {rm.size} values, the Stokes "
                             f"columns {nrow}")
    pixels = _table_pixels(path, hdu, names, nrow)
    freq, flat = _map_frequency(path, (hdu.header, primary), rm is not None, flat_spectrum)
    return pixels, freq, stokes, unit, rm, flat


def _table_pixels(path: Path, hdu, names: dict, nrow: int) -> np.ndarray:
    """Pixel numbers of a map table: its PIXEL column (EXPLICIT) or FIRSTPIX onwards."""
    scheme = str(hdu.header.get("INDXSCHM", "IMPLICIT")).strip().upper()
    if scheme == "EXPLICIT":
        if "PIXEL" not in names:
            raise InputError(f"{path}: INDXSCHM = 'EXPLICIT' needs a PIXEL column")
        pixels = np.asarray(hdu.data[names["PIXEL"].name], dtype=np.int64).ravel()
    else:
        pixels = int(hdu.header.get("FIRSTPIX", 0)) + np.arange(nrow, dtype=np.int64)
    if pixels.size != nrow:
        raise InputError(f"{path}: {pixels.size} pixel numbers for {nrow} values")
    if np.unique(pixels).size != pixels.size:
        raise InputError(f"{path}: a pixel number appears more than once")
    return pixels


def _axis_values(path: Path, header, axis: int, scale: dict | None = None) -> np.ndarray:
    """World values of image axis ``axis`` (1-based) from CRVAL/CDELT/CRPIX[/CUNIT]."""
    n = int(header[f"NAXIS{axis}"])
    crval, cdelt = header.get(f"CRVAL{axis}"), header.get(f"CDELT{axis}", 1.0)
    if crval is None:
        raise InputError(f"{path}: axis {axis} ({header.get(f'CTYPE{axis}')}) has no "
                         f"CRVAL{axis}")
    values = crval + (np.arange(n) + 1 - header.get(f"CRPIX{axis}", 1.0)) * cdelt
    if scale is not None:
        unit = str(header.get(f"CUNIT{axis}", "Hz")).strip().upper()
        if unit not in scale:
            raise InputError(f"{path}: CUNIT{axis} = {unit!r}; use Hz, kHz, MHz or GHz")
        values = values * scale[unit]
    return values


def _image_maps(path: Path, hdu, nside: int, flat_spectrum: bool) -> tuple:
    """Pixels, frequencies, Stokes (4, nchan, npix), unit, RM (None) and flat of an image
    cube: axis 1 the pixels, axes FREQ and STOKES."""
    header = hdu.header
    naxis = int(header.get("NAXIS", 0))
    types = {str(header.get(f"CTYPE{a}", "")).strip().upper(): a for a in range(2, naxis + 1)}
    if naxis < 2 or "STOKES" not in types or naxis > 2 + ("FREQ" in types):
        raise InputError(f"{path}: a HEALPix image needs axis 1 = pixels, a STOKES axis and "
                         "an optional FREQ axis (CTYPEn)")
    if int(header["NAXIS1"]) != 12 * nside ** 2:
        raise InputError(f"{path}: NAXIS1 = {header['NAXIS1']} pixels, NSIDE {nside} has "
                         f"{12 * nside ** 2}; an image holds the whole sphere")
    data = np.asarray(hdu.data, dtype=float)             # (..., npix), C order
    codes = np.rint(_axis_values(path, header, types["STOKES"])).astype(int)
    if not set(codes) <= {1, 2, 3, 4}:
        raise InputError(f"{path}: STOKES axis codes {sorted(set(codes))}; msleak reads "
                         "I, Q, U, V (1-4)")
    unit, factor = _unit(path, header.get("BUNIT"), "BUNIT")
    if "FREQ" in types:
        freq = _axis_values(path, header, types["FREQ"], _FREQ_UNITS)
        flat = bool(flat_spectrum)
        if flat and freq.size != 1:
            raise InputError(f"{path}: flat_spectrum uses one map at every channel; this "
                             f"image has {freq.size} channels", param="flat_spectrum")
    else:
        freq, flat = _map_frequency(path, (header,), False, flat_spectrum)
    # numpy axes run backwards: image axis a is numpy axis naxis - a; pixels last
    if "FREQ" in types:
        cube = np.transpose(data, (naxis - types["STOKES"], naxis - types["FREQ"], naxis - 1))
    else:
        cube = data[:, None, :]
    stokes = np.zeros((4, freq.size, 12 * nside ** 2))
    for k, code in enumerate(codes):
        stokes[code - 1] = np.where(_missing(cube[k]), cube[k], cube[k] * factor)
    return np.arange(12 * nside ** 2, dtype=np.int64), freq, stokes, unit, None, flat


def _missing(values: np.ndarray) -> np.ndarray:
    """Where a map has no value: NaN or healpy's UNSEEN."""
    return ~np.isfinite(values) | np.isclose(values, HEALPIX_UNSEEN, rtol=1e-5, atol=0)


def _drop_unseen(path: Path, pixels: np.ndarray, stokes: np.ndarray, rm):
    """The pixels with a value in every map (NaN and UNSEEN pixels left out, logged)."""
    bad = _missing(stokes).any(axis=(0, 1))
    if rm is not None:
        bad |= _missing(rm)
    if bad.all():
        raise InputError(f"{path}: every pixel is NaN or UNSEEN")
    if bad.any():
        log.info("%s: %d of %d pixels are NaN or UNSEEN; left out", path,
                 int(bad.sum()), bad.size)
        pixels, stokes = pixels[~bad], stokes[:, :, ~bad]
        rm = None if rm is None else rm[~bad]
    return pixels, stokes, rm
