"""``msleak sky``: generate, crop, re-centre, convert, export and plot sky cubes."""

from __future__ import annotations

import logging
import math
from pathlib import Path

import click

from msleak.cli._common import FloatList

__all__ = ["sky"]

log = logging.getLogger(__name__)

#: options that only make sense when generating a cube
_GENERATION_OPTIONS = ("npix", "freq_min", "nchan", "chan_width", "seed", "depth_pc",
                       "ncells_los", "cell_perp_pc", "b_regular", "b_random_rms", "b_index",
                       "solenoidal", "ne_mean", "ne_sigma", "ne_index", "ncr_sigma",
                       "ncr_index", "electron_index", "outer_scale_pc", "p_rms", "ref_freq")


def _phase_centre(ctx, param, value):
    if value is None:
        return None
    ra, dec = value
    if not -90.0 <= dec <= 90.0:
        raise click.BadParameter(f"declination {dec} deg is outside -90..90")
    return ra % 360.0, dec


def _positive(ctx, param, value):
    if value is not None and not value > 0:
        raise click.BadParameter(f"must be > 0, got {value}")
    return value


def _skymodel_paths(path: Path, nchan: int, channel: int | None) -> list[tuple[int, Path]]:
    if channel is not None or nchan == 1:
        return [(channel or 0, path)]
    return [(k, path.with_name(f"{path.stem}_ch{k:03d}{path.suffix}")) for k in range(nchan)]


def _is_fits(path: Path) -> bool:
    with open(path, "rb") as fh:
        return fh.read(9) == b"SIMPLE  ="


def _skymodel_input(path, out, fov, crop_npix, phase_centre, skymodel, plot_path, overwrite):
    """A makesourcedb input: select a field of view and write it again (--skymodel)."""
    import numpy as np

    from msleak.io.skymodel import read_skymodel, write_skymodel

    sources = read_skymodel(path)  # reports a malformed file first
    if out is not None or plot_path is not None or crop_npix is not None:
        raise click.UsageError("a makesourcedb input can only be selected (--fov with "
                               "--phase-centre) and written with --skymodel")
    if skymodel is None:
        raise click.UsageError("give --skymodel OUT.skymodel for a makesourcedb input")
    if fov is not None:
        if phase_centre is None:
            raise click.UsageError("--fov on a makesourcedb input needs --phase-centre")
        half = math.radians(fov) / 2
        l_, m_, n_ = sources.lmn(math.radians(phase_centre[0]), math.radians(phase_centre[1]))
        sources = sources.select((np.abs(l_) <= half) & (np.abs(m_) <= half) & (n_ > 0))
    write_skymodel(skymodel, sources, overwrite=overwrite, comment=f"from {path}")
    click.echo(f"wrote {skymodel}: {len(sources)} point sources")


@click.command("sky")
@click.argument("out", required=False, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--crop", "--input", "input_path", type=click.Path(dir_okay=False, path_type=Path),
              help="Work on this existing FITS cube (any cube with RA/Dec + FREQ [+ STOKES] "
                   "axes) instead of generating one: crop it (--fov/--crop-npix), re-centre it "
                   "(--phase-centre), convert it (--units), export it (--skymodel) or plot it. "
                   "A makesourcedb file can be checked and cut to --fov about --phase-centre "
                   "(written with --skymodel).")
@click.option("--fov", type=float, default=None, callback=_positive,
              help="Field of view a side, deg. Generating: the cube size [default 15]. "
                   "With --crop: the centred crop (pixels = fov/pixel rounded to the nearest "
                   "integer of the cube's parity).")
@click.option("--crop-npix", type=int, default=None,
              help="Crop to this many pixels a side (centred; same parity as the cube), "
                   "e.g. 28 or 16 for the paper's 9 and 4 deg crops of the default cube.")
@click.option("--npix", type=click.IntRange(2, None), default=50, show_default=True,
              help="Pixels a side of the generated cube.")
@click.option("--freq-min", type=float, default=150e6, show_default=True, callback=_positive,
              help="Centre of the first channel, Hz.")
@click.option("--nchan", type=click.IntRange(1, None), default=50, show_default=True,
              help="Number of channels.")
@click.option("--chan-width", type=float, default=195312.5, show_default=True,
              callback=_positive, help="Channel width (and spacing), Hz.")
@click.option("--seed", type=click.IntRange(0, None), default=None,
              help="Random seed (non-negative integer) for a reproducible cube [default: "
                   "fresh entropy, recorded in the header as MSLEAK SEED].")
@click.option("--phase-centre", type=FloatList(2), default=None, callback=_phase_centre,
              metavar="RA_DEG,DEC_DEG",
              help="Centre of the cube, J2000 deg [default 0,90 (NCP) when generating; "
                   "with --crop: re-centre the cube's grid there].")
@click.option("--units", type=click.Choice(["K", "Jy/pixel"]), default=None,
              help="Brightness unit of the written cube [default K; with --crop the input's]. "
                   "Jy/pixel uses S = 2 k_B T Omega_pix / lambda^2.")
@click.option("--depth-pc", type=float, default=1000.0, show_default=True, callback=_positive,
              help="Depth of the emitting and rotating slab along the line of sight, pc.")
@click.option("--ncells-los", type=click.IntRange(2, None), default=100, show_default=True,
              help="Cells along the line of sight.")
@click.option("--cell-perp-pc", type=float, default=None, callback=_positive,
              help="Transverse cell size, pc [default: depth / ncells, cubic cells; smaller values "
                   "give smoother maps but less Faraday-depth spread across the field].")
@click.option("--b-regular", type=FloatList(3), default="1.0,1.0,0.2", show_default=True,
              metavar="BE,BN,BPAR",
              help="Regular magnetic field: east, north, line-of-sight (towards the observer) "
                   "components, microgauss.")
@click.option("--b-random-rms", type=float, default=2.5, show_default=True,
              help="rms |B| of the random (turbulent) field, microgauss.")
@click.option("--b-index", type=float, default=11 / 3, show_default=True,
              help="3-D power-spectrum index of the random field, P(k) ~ k^-index "
                   "(11/3: Kolmogorov).")
@click.option("--solenoidal/--no-solenoidal", default=True, show_default=True,
              help="Make the random field divergence-free.")
@click.option("--ne-mean", type=float, default=0.01, show_default=True,
              help="Mean thermal electron density, cm^-3.")
@click.option("--ne-sigma", type=float, default=0.5, show_default=True,
              help="Log-normal width (std of ln n_e) of the thermal electrons.")
@click.option("--ne-index", type=float, default=11 / 3, show_default=True,
              help="3-D power-spectrum index of ln n_e.")
@click.option("--ncr-sigma", type=float, default=0.5, show_default=True,
              help="Log-normal width of the cosmic-ray electron density.")
@click.option("--ncr-index", type=float, default=11 / 3, show_default=True,
              help="3-D power-spectrum index of ln n_CR.")
@click.option("--electron-index", type=float, default=2.1, show_default=True,
              help="Cosmic-ray energy index p (N(E) ~ E^-p); brightness T ~ nu^-(p+3)/2.")
@click.option("--outer-scale-pc", type=float, default=None, callback=_positive,
              help="Outer scale of all random fields, pc [default: none, pure power laws].")
@click.option("--p-rms", type=float, default=3.0, show_default=True, callback=_positive,
              help="rms polarized brightness |P| over the map at --ref-freq, K (sets the "
                   "emissivity scale).")
@click.option("--ref-freq", type=float, default=150e6, show_default=True, callback=_positive,
              help="Frequency at which --p-rms holds, Hz.")
@click.option("--skymodel", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Also write the voxels as makesourcedb point sources (Jy) for DP3: one file "
                   "per channel, NAME_chNNN.skymodel, unless --skymodel-channel is given.")
@click.option("--skymodel-channel", type=click.IntRange(0, None), default=None,
              help="Write only this channel (0-based) to the --skymodel file, flat spectra.")
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False, path_type=Path),
              default=None, help="Figure (PNG/PDF): Q and U slices, one pixel's spectrum "
                                 "and the angular power spectrum of P.")
@click.option("--plot-channel", type=click.IntRange(0, None), default=0, show_default=True,
              help="Channel (0-based) of the slices and power spectrum in --plot.")
@click.option("--plot-pixel", type=FloatList(2), default=None, metavar="X,Y",
              help="Pixel (0-based x,y) whose spectrum --plot shows [default: the centre].")
@click.option("--overwrite", is_flag=True, help="Replace existing output files.")
@click.pass_context
def sky(ctx: click.Context, out, input_path, fov, crop_npix, npix, freq_min, nchan, chan_width,
        seed, phase_centre, units, depth_pc, ncells_los, cell_perp_pc, b_regular, b_random_rms,
        b_index, solenoidal, ne_mean, ne_sigma, ne_index, ncr_sigma, ncr_index,
        electron_index, outer_scale_pc, p_rms, ref_freq, skymodel, skymodel_channel,
        plot_path, plot_channel, plot_pixel, overwrite):
    """Diffuse polarized Galactic foreground cubes (Q, U) with differential Faraday
    rotation, after Jelic et al. (2008, 2010), written as FITS (RA---SIN, DEC--SIN, FREQ,
    STOKES); or crop / re-centre / convert / export / plot an existing cube.

    \b
    Examples:
      msleak sky sky.fits --seed 1                       # 15 deg, 50x50 px, 150-160 MHz
      msleak sky sky.fits --seed 1 --plot sky.png --skymodel sky.skymodel
      msleak sky --crop sky.fits --fov 4 sky4.fits       # inner 4 deg
      msleak sky --crop sky.fits --crop-npix 28 sky28.fits
      msleak sky --crop sky.fits --phase-centre 123.4,48.2 --units Jy/pixel sky3c196.fits
      msleak sky --crop sky.fits --skymodel-channel 0 --skymodel ch0.skymodel
    """
    from msleak.errors import InputError
    from msleak.io.fits import read_cube, write_cube
    from msleak.io.products import command_line
    from msleak.sky.cube import convert_units, crop, recentre

    outputs = [p for p in (out, skymodel, plot_path) if p is not None]
    if not outputs:
        raise click.UsageError("nothing to do: give OUT.fits, --skymodel or --plot")
    for p in (out, skymodel):
        if p is not None and p.exists() and not overwrite:
            raise InputError(f"{p} exists; choose another name or pass --overwrite")
    if input_path is not None:
        given = [name for name in _GENERATION_OPTIONS
                 if ctx.get_parameter_source(name) is click.core.ParameterSource.COMMANDLINE]
        if given:
            raise click.UsageError(f"--{given[0].replace('_', '-')} is a generation option "
                                   "and cannot be used with --crop/--input")
        if input_path.is_file() and not _is_fits(input_path):
            return _skymodel_input(input_path, out, fov, crop_npix, phase_centre, skymodel,
                                   plot_path, overwrite)
        cube = read_cube(input_path)
        if phase_centre is not None:
            cube = recentre(cube, math.radians(phase_centre[0]), math.radians(phase_centre[1]))
        if fov is not None and crop_npix is not None:
            raise click.UsageError("give --fov or --crop-npix, not both")
        if fov is not None:
            cube = crop(cube, fov_deg=fov)
    else:
        if out is None:
            raise click.UsageError("give OUT.fits to generate a cube (or --crop IN.fits)")
        from msleak.sky.foreground import ForegroundParams, generate_foreground_cube

        params = ForegroundParams(
            depth_pc=depth_pc, ncells_los=ncells_los, cell_perp_pc=cell_perp_pc,
            b_regular_ug=tuple(b_regular), b_random_rms_ug=b_random_rms, b_index=b_index,
            solenoidal=solenoidal, ne_mean_cm3=ne_mean, ne_sigma_ln=ne_sigma,
            ne_index=ne_index, ncr_sigma_ln=ncr_sigma, ncr_index=ncr_index,
            electron_index=electron_index, outer_scale_pc=outer_scale_pc, p_rms_k=p_rms,
            ref_freq_hz=ref_freq)
        centre = phase_centre or (0.0, 90.0)
        cube = generate_foreground_cube(
            npix=npix, fov_deg=fov if fov is not None else 15.0, freq_min_hz=freq_min,
            nchan=nchan, chan_width_hz=chan_width,
            phase_centre=(math.radians(centre[0]), math.radians(centre[1])), seed=seed,
            params=params)
    if crop_npix is not None:
        cube = crop(cube, npix=crop_npix)
    if units is not None:
        cube = convert_units(cube, units)
    history = command_line()
    if out is not None:
        write_cube(cube, out, overwrite=overwrite, history=history)
        meta = cube.meta
        extra = ""
        if "PHIMIN" in meta and input_path is None:
            extra = (f"; rms |P| {meta['PRMS150']:g} K at {ref_freq / 1e6:g} MHz, Faraday "
                     f"depth {meta['PHIMIN']:.1f}..{meta['PHIMAX']:.1f} rad/m^2, seed "
                     f"{meta['SEED']}")
        ny, nx = cube.npix
        click.echo(f"wrote {out}: {','.join(cube.stokes)} x {cube.data.shape[1]} channels x "
                   f"{ny}x{nx} px in {cube.units}{extra}")
    if skymodel is not None:
        from msleak.io.skymodel import write_skymodel
        from msleak.sky.sources import sources_from_cube

        nchan_cube = cube.data.shape[1]
        if skymodel_channel is not None and skymodel_channel >= nchan_cube:
            raise InputError(f"--skymodel-channel {skymodel_channel} is outside "
                             f"0..{nchan_cube - 1}")
        sources = sources_from_cube(cube)
        ny, nx = cube.npix
        names = tuple(f"v{iy:03d}_{ix:03d}" for iy in range(ny) for ix in range(nx))
        sources = type(sources)(ra=sources.ra, dec=sources.dec, freq=sources.freq,
                                stokes=sources.stokes, names=names)
        targets = _skymodel_paths(skymodel, nchan_cube, skymodel_channel)
        for channel, path in targets:
            write_skymodel(path, sources, channel=channel, overwrite=overwrite,
                           comment=f"from {input_path or out}; voxel v<y>_<x> = pixel (x, y)")
        click.echo(f"wrote {len(targets)} makesourcedb file(s) of {len(sources)} sources: "
                   f"{targets[0][1]}{' ...' if len(targets) > 1 else ''}")
    if plot_path is not None:
        from msleak.plot.sky import plot_sky_cube

        pixel = None if plot_pixel is None else (int(plot_pixel[0]), int(plot_pixel[1]))
        plot_sky_cube(cube, plot_path, channel=plot_channel, pixel=pixel)
        click.echo(f"wrote {plot_path}")
