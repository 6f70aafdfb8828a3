"""The sky stage as Python verbs (docs/sky.md): :func:`make_sky` generates a polarized
foreground cube, or crops, re-centres and converts an existing one, and returns the sky
Dataset (docs/products.md); :func:`select_skymodel` cuts a makesourcedb sky to a field.
"""

from __future__ import annotations

import inspect
import math
import os
from pathlib import Path
from typing import Sequence

import numpy as np
import xarray as xr

from msleak.errors import InputError
from msleak.io.fits import cube_from_dataset, dataset_from_cube, is_fits, read_cube, write_cube
from msleak.io.products import call_record, refuse_existing
from msleak.io.skymodel import read_sky, write_skymodel
from msleak.sky.cube import SkyCube, Units, convert_units, recentre
from msleak.sky.cube import crop as crop_cube
from msleak.sky.foreground import ForegroundParams, generate_foreground_cube
from msleak.sky.sources import PointSources, sources_from_cube

__all__ = ["make_sky", "select_skymodel", "skymodel_paths", "GENERATION_OPTIONS"]

#: options of :func:`make_sky` that only apply when generating (refused with ``crop``)
GENERATION_OPTIONS = ("npix", "freq_min", "nchan", "chan_width", "seed", "depth_pc",
                      "ncells_los", "cell_perp_pc", "b_regular", "b_random_rms", "b_index",
                      "solenoidal", "ne_mean", "ne_sigma", "ne_index", "ncr_sigma",
                      "ncr_index", "electron_index", "outer_scale_pc", "p_rms", "ref_freq")


def make_sky(output: str | os.PathLike | None = None, *, fov: float | None = None,
             npix: int = 50, freq_min: float = 150e6, nchan: int = 50,
             chan_width: float = 195312.5, seed: int | None = None,
             phase_centre: tuple[float, float] | None = None,
             units: Units | None = None, depth_pc: float = 1000.0,
             ncells_los: int = 100, cell_perp_pc: float | None = None,
             b_regular: Sequence[float] = (1.0, 1.0, 0.2), b_random_rms: float = 2.5,
             b_index: float = 11 / 3, solenoidal: bool = True, ne_mean: float = 0.01,
             ne_sigma: float = 0.5, ne_index: float = 11 / 3, ncr_sigma: float = 0.5,
             ncr_index: float = 11 / 3, electron_index: float = 2.1,
             outer_scale_pc: float | None = None, p_rms: float = 3.0,
             ref_freq: float = 150e6, crop: str | os.PathLike | xr.Dataset | None = None,
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
    depth_pc ... ref_freq : the model's physics (pc, microgauss, cm^-3, K, Hz)
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
        cube = _input_cube(crop)
        if centre is not None:
            cube = recentre(cube, math.radians(centre[0]), math.radians(centre[1]))
        if fov is not None and crop_npix is not None:
            raise InputError("give --fov or --crop-npix, not both")
        if fov is not None:
            cube = crop_cube(cube, fov_deg=fov)
    else:
        params = ForegroundParams(
            depth_pc=depth_pc, ncells_los=ncells_los, cell_perp_pc=cell_perp_pc,
            b_regular_ug=tuple(b_regular), b_random_rms_ug=b_random_rms, b_index=b_index,
            solenoidal=solenoidal, ne_mean_cm3=ne_mean, ne_sigma_ln=ne_sigma,
            ne_index=ne_index, ncr_sigma_ln=ncr_sigma, ncr_index=ncr_index,
            electron_index=electron_index, outer_scale_pc=outer_scale_pc, p_rms_k=p_rms,
            ref_freq_hz=ref_freq)
        ra0, dec0 = centre or (0.0, 90.0)
        cube = generate_foreground_cube(
            npix=npix, fov_deg=15.0 if fov is None else fov, freq_min_hz=freq_min,
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


def select_skymodel(path: str | os.PathLike, output: str | os.PathLike, *,
                    fov: float | None = None, phase_centre: tuple[float, float] | None = None,
                    overwrite: bool = False) -> PointSources:
    """Check a makesourcedb sky, keep the sources within ``fov`` (deg) about
    ``phase_centre`` ((RA, Dec) deg, :func:`msleak.io.skymodel.read_sky`) and write
    them to the makesourcedb file ``output``; returns the sources written.
    """
    if Path(path).is_file() and is_fits(path):
        raise InputError(f"{path} is a FITS cube; export its voxels with --skymodel "
                         "(make_sky(crop=..., skymodel=...))")
    _refuse_existing([output], overwrite)
    sources = read_sky(path, fov_deg=fov, phase_centre=_phase_centre(phase_centre))
    write_skymodel(output, sources, overwrite=overwrite, comment=f"from {path}")
    return sources


def skymodel_paths(path: str | os.PathLike, nchan: int, channel: int | None
                   ) -> list[tuple[int, Path]]:
    """(channel, file) pairs of a ``--skymodel`` export: NAME_chNNN per channel, or the
    file itself for one channel (``channel`` given or a single-channel cube).

    Raises
    ------
    InputError
        If ``channel`` is outside the cube's channels.
    """
    path = Path(path)
    if channel is not None and not 0 <= channel < nchan:
        raise InputError(f"--skymodel-channel {channel} is outside 0..{nchan - 1}")
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
    defaults = inspect.signature(make_sky).parameters
    for name in GENERATION_OPTIONS:
        value, default = options[name], defaults[name].default
        if isinstance(value, (list, tuple, np.ndarray)):
            value = tuple(float(v) for v in value)
        if value != default:
            raise InputError(f"--{name.replace('_', '-')} is a generation option and cannot "
                             "be used with --crop")


def _input_cube(crop: str | os.PathLike | xr.Dataset) -> SkyCube:
    if isinstance(crop, xr.Dataset):
        return cube_from_dataset(crop)
    path = Path(crop)
    if path.is_file() and not is_fits(path):
        raise InputError(f"{path} is not a FITS cube; a makesourcedb sky is cut with "
                         "--skymodel OUT (select_skymodel)")
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
