"""The sky verbs (docs/sky.md): :func:`make_sky` generates a polarized foreground cube, or
crops, re-centres and converts an existing one, writes it and returns the sky Dataset
(docs/products.md); :func:`select_skymodel` cuts a makesourcedb sky to a field;
:func:`read_sky` reads a FITS cube or a makesourcedb file as point sources.
"""

from __future__ import annotations

import math
import os
from dataclasses import fields
from pathlib import Path

import numpy as np
import xarray as xr

from msleak.adapters.sky_fits import (cube_from_dataset, dataset_from_cube, read_cube,
                                      write_cube)
from msleak.adapters.skymodel import read_skymodel, write_skymodel
from msleak.errors import InputError
from msleak.io.fits import is_fits
from msleak.io.products import call_record, refuse_existing
from msleak.sky.cube import SkyCube, Units, convert_units, recentre
from msleak.sky.cube import crop as crop_cube
from msleak.sky.foreground import ForegroundParams, generate_foreground_cube
from msleak.sky.sources import PointSources, sources_from_cube

__all__ = ["make_sky", "select_skymodel", "read_sky", "skymodel_paths", "GENERATION_OPTIONS"]

#: options of :func:`make_sky` that only apply when generating (refused with ``crop``);
#: ``params`` stands for each field of :class:`~msleak.sky.foreground.ForegroundParams`
GENERATION_OPTIONS = ("npix", "freq_min", "nchan", "chan_width", "seed", "params")

#: the generated cube's side (deg) when ``fov`` is not given
_DEFAULT_FOV = 15.0


def make_sky(output: str | os.PathLike | None = None, *, fov: float | None = None,
             npix: int = 50, freq_min: float = 150e6, nchan: int = 50,
             chan_width: float = 195312.5, seed: int | None = None,
             phase_centre: tuple[float, float] | None = None,
             units: Units | None = None, params: ForegroundParams | None = None,
             crop: str | os.PathLike | xr.Dataset | None = None,
             crop_npix: int | None = None, skymodel: str | os.PathLike | None = None,
             skymodel_channel: int | None = None, overwrite: bool = False) -> xr.Dataset:
    """Generate a diffuse polarized foreground cube (Q, U), or crop / re-centre / convert
    an existing cube (``crop``); the options are those of ``msleak sky`` (docs/sky.md).

    Parameters
    ----------
    output : FITS file to write (None: return only)
    fov : deg; generating: the cube's side [15]; with ``crop``: the centred crop
    npix, nchan : pixels a side and channels of the generated cube
    freq_min, chan_width : Hz; channel i is centred at freq_min + i chan_width
    seed : random seed (None: fresh entropy, recorded as ``MSLEAK SEED``)
    phase_centre : (RA, Dec) J2000, deg; generating: the cube centre [(0, 90)]; with
        ``crop``: re-centre the grid there
    units : "K" or "Jy/pixel" [K; with ``crop`` the input's]
    params : the model's physics (:class:`~msleak.sky.foreground.ForegroundParams`: pc,
        microgauss, cm^-3, K, Hz) [its defaults]
    crop : a FITS cube path or a sky Dataset to work on instead of generating
    crop_npix : centred crop to this many pixels a side (the cube's parity)
    skymodel : also write the voxels as makesourcedb files (one per channel,
        NAME_chNNN.skymodel, unless ``skymodel_channel`` is given)
    overwrite : replace existing output files

    Returns
    -------
    The sky Dataset (docs/products.md): Stokes variables (freq, y, x) float32 in
    ``units``, the values ``output`` holds.
    """
    options = locals()
    command = call_record(make_sky, dict(options))
    centre = _phase_centre(phase_centre)
    _refuse_existing([output], overwrite)
    if crop is not None:
        _refuse_generation_options(options)
        cube = _cropped(_input_cube(crop), centre, fov, crop_npix)
    else:
        ra0, dec0 = centre or (0.0, 90.0)
        cube = generate_foreground_cube(
            npix=npix, fov_deg=_DEFAULT_FOV if fov is None else fov, freq_min_hz=freq_min,
            nchan=nchan, chan_width_hz=chan_width,
            phase_centre=(math.radians(ra0), math.radians(dec0)), seed=seed, params=params)
    if crop_npix is not None:
        cube = crop_cube(cube, npix=crop_npix)
    if units is not None:
        cube = convert_units(cube, units)
    targets = [] if skymodel is None else skymodel_paths(skymodel, cube.data.shape[1],
                                                         skymodel_channel)
    _refuse_existing([path for _, path in targets], overwrite)
    if output is not None:
        write_cube(cube, output, overwrite=overwrite, history=command)
    source = crop if isinstance(crop, (str, os.PathLike)) else output
    _write_skymodels(cube, targets, f"from {source or 'msleak.make_sky'}")
    return dataset_from_cube(cube)


def _cropped(cube: SkyCube, centre: tuple[float, float] | None, fov: float | None,
             crop_npix: int | None) -> SkyCube:
    """``cube`` re-centred on ``centre`` (deg) and cropped to ``fov`` (deg)."""
    if centre is not None:
        cube = recentre(cube, math.radians(centre[0]), math.radians(centre[1]))
    if fov is not None and crop_npix is not None:
        raise InputError("give fov or crop_npix, not both", param=("fov", "crop_npix"))
    if fov is not None:
        cube = crop_cube(cube, fov_deg=fov)
    return cube


def select_skymodel(path: str | os.PathLike, output: str | os.PathLike, *,
                    fov: float | None = None, phase_centre: tuple[float, float] | None = None,
                    overwrite: bool = False) -> PointSources:
    """Check a makesourcedb sky, keep the sources within ``fov`` (deg) about
    ``phase_centre`` ((RA, Dec) deg, :func:`read_sky`) and write
    them to the makesourcedb file ``output``; returns the sources written.
    """
    if Path(path).is_file() and is_fits(path):
        raise InputError(f"{path} is a FITS cube; export its voxels with "
                         "make_sky(crop=..., skymodel=...)")
    if fov is not None and phase_centre is None:
        raise InputError("fov on a makesourcedb sky needs phase_centre",
                         param=("fov", "phase_centre"))
    _refuse_existing([output], overwrite)
    sources = read_sky(path, fov_deg=fov, phase_centre=_phase_centre(phase_centre))
    write_skymodel(output, sources, overwrite=overwrite, comment=f"from {path}")
    return sources


def read_sky(path: str | os.PathLike, *, fov_deg: float | None = None,
             phase_centre: tuple[float, float] | None = None) -> PointSources:
    """Read a sky as point sources: a FITS cube (one per voxel) or a makesourcedb file.

    Parameters
    ----------
    path : FITS cube or makesourcedb text file
    fov_deg : keep the central ``fov_deg`` x ``fov_deg`` (deg): a cube is cropped
        (:func:`msleak.sky.cube.crop`); a makesourcedb sky keeps the sources with |l| and
        |m| <= fov / 2 (rad, the half width of a SIN cube of that FoV) about
        ``phase_centre`` (then required)
    phase_centre : (RA, Dec) J2000, deg; a cube is first re-centred there
        (:func:`msleak.sky.cube.recentre`: the grid keeps its (l, m) geometry)
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"sky file {path} does not exist")
    if path.is_dir():
        raise InputError(f"sky {path} is a directory, not a FITS cube or makesourcedb file")
    centre = None if phase_centre is None else tuple(math.radians(a) for a in phase_centre)
    if is_fits(path):
        cube = read_cube(path)
        if centre is not None:
            cube = recentre(cube, *centre)
        if fov_deg is not None:
            cube = crop_cube(cube, fov_deg=fov_deg)
        return sources_from_cube(cube)
    sources = read_skymodel(path)
    if fov_deg is not None:
        if centre is None:
            raise InputError("fov_deg on a makesourcedb sky needs phase_centre",
                             param=("fov_deg", "phase_centre"))
        half = math.radians(fov_deg) / 2
        l_, m_, n_ = sources.lmn(*centre)
        sources = sources.select((np.abs(l_) <= half) & (np.abs(m_) <= half) & (n_ > 0))
    return sources


def skymodel_paths(path: str | os.PathLike, nchan: int, channel: int | None
                   ) -> list[tuple[int, Path]]:
    """(channel, file) pairs of a ``skymodel`` export of :func:`make_sky`: NAME_chNNN per channel, or the
    file itself for one channel (``channel`` given or a single-channel cube).

    Raises
    ------
    InputError
        If ``channel`` is outside the cube's channels.
    """
    path = Path(path)
    if channel is not None and not 0 <= channel < nchan:
        raise InputError(f"skymodel_channel {channel} is outside 0..{nchan - 1}",
                         param="skymodel_channel")
    if channel is not None or nchan == 1:
        return [(channel or 0, path)]
    return [(k, path.with_name(f"{path.stem}_ch{k:03d}{path.suffix}")) for k in range(nchan)]


def _phase_centre(value: tuple[float, float] | None) -> tuple[float, float] | None:
    if value is None:
        return None
    ra, dec = (float(v) for v in value)
    if not -90.0 <= dec <= 90.0:
        raise InputError(f"declination {dec} deg is outside -90..90")
    return ra % 360.0, dec


def _refuse_existing(paths, overwrite: bool) -> None:
    for path in paths:
        refuse_existing(path, overwrite)


def _refuse_generation_options(options: dict) -> None:
    """Refuse, with ``crop``, a generation option away from its default: one of
    :data:`GENERATION_OPTIONS` or a field of ``params``."""
    defaults = {name: make_sky.__kwdefaults__[name] for name in GENERATION_OPTIONS}
    for name in GENERATION_OPTIONS[:-1]:
        if options[name] != defaults[name]:
            _refuse_with_crop(name)
    given = options["params"]
    if given is not None:
        for f in fields(ForegroundParams):
            if getattr(given, f.name) != getattr(ForegroundParams(), f.name):
                _refuse_with_crop(f.name)


def _refuse_with_crop(name: str) -> None:
    raise InputError(f"{name} is a generation option and cannot be used with crop",
                     param=(name, "crop"))


def _input_cube(crop: str | os.PathLike | xr.Dataset) -> SkyCube:
    if isinstance(crop, xr.Dataset):
        return cube_from_dataset(crop)
    path = Path(crop)
    if path.is_file() and not is_fits(path):
        raise InputError(f"{path} is not a FITS cube; a makesourcedb sky is cut with "
                         "select_skymodel")
    return read_cube(path)


def _write_skymodels(cube: SkyCube, targets: list[tuple[int, Path]], comment: str) -> None:
    """Every voxel as a makesourcedb point source named v<y>_<x>, one file per target."""
    if not targets:
        return
    sources = sources_from_cube(cube)
    ny, nx = cube.npix
    names = tuple(f"v{iy:03d}_{ix:03d}" for iy in range(ny) for ix in range(nx))
    sources = PointSources(ra=sources.ra, dec=sources.dec, freq=sources.freq,
                           stokes=sources.stokes, names=names)
    for channel, path in targets:
        write_skymodel(path, sources, channel=channel, overwrite=True,
                       comment=f"{comment}; voxel v<y>_<x> = pixel (x, y)")
