"""``msleak sky``: generate, crop, re-centre, convert, export and plot sky cubes."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path
from typing import get_args

import click
from click.core import ParameterSource
from astropy.io import fits

from msleak.cli._common import FloatList
from msleak.cli._flags import flag_for
from msleak.errors import InputError
from msleak.io.fits import is_fits
from msleak.plot.sky import plot_sky
from msleak.sky.cube import Units
from msleak.sky.allsky import BOX_DEG, CELL_DEG
from msleak.sky.foreground import ForegroundParams
from msleak.verbs.allsky import make_allsky
from msleak.verbs.sky import make_sky, select_skymodel, skymodel_paths

__all__ = ["sky"]


def _skymodel_input(path, out, fov, crop_npix, phase_centre, skymodel, plot_path, overwrite):
    """A makesourcedb input: select a field of view and write it again (--skymodel)."""
    if out is not None or plot_path is not None or crop_npix is not None:
        raise click.UsageError("a makesourcedb input can only be selected (--fov with "
                               "--phase-centre) and written with --skymodel")
    if skymodel is None:
        raise click.UsageError("give --skymodel OUT.skymodel for a makesourcedb input")
    sources = select_skymodel(path, skymodel, fov=fov, phase_centre=phase_centre,
                              overwrite=overwrite)
    click.echo(f"wrote {skymodel}: {len(sources)} point sources")


def _report(ds, out, generated: bool) -> None:
    header = fits.Header.fromstring(ds.attrs["fits_header"], sep="\n")
    stokes = [s for s in ("I", "Q", "U", "V") if s in ds.data_vars]
    extra = ""
    if generated:
        extra = (f"; rms |P| {header['MSLEAK PRMS150']:g} K at "
                 f"{header['MSLEAK P_REF_FREQ_HZ'] / 1e6:g} MHz, Faraday depth "
                 f"{header['MSLEAK PHIMIN']:.1f}..{header['MSLEAK PHIMAX']:.1f} rad/m^2, "
                 f"seed {header['MSLEAK SEED']}")
    click.echo(f"wrote {out}: {','.join(stokes)} x {ds.sizes['freq']} channels x "
               f"{ds.sizes['y']}x{ds.sizes['x']} px in {ds.attrs['units']}{extra}")


#: options of ``msleak sky`` that make or shape a flat cube, refused with ``--healpix``
_FLAT_ONLY = ("input_path", "fov", "crop_npix", "npix", "phase_centre", "skymodel",
              "skymodel_channel", "plot_path", "channel", "pixel")


def _given(name: str) -> bool:
    """Whether the running command's option ``name`` was given on the command line."""
    ctx = click.get_current_context()
    return ctx.get_parameter_source(name) not in (ParameterSource.DEFAULT, None)


def _allsky(out, nside, cell_deg, box_deg, freq_min, nchan, chan_width, seed, units,
            overwrite, physics) -> None:
    """``msleak sky OUT.skyh5 --healpix NSIDE``: the whole sky, written as SkyH5."""
    given = [flag_for(name, sky) for name in _FLAT_ONLY if _given(name)]
    if given:
        raise InputError(f"{', '.join(given)} shape a flat cube and cannot be used with "
                         "--healpix")
    if out is None:
        raise click.UsageError("give OUT.skyh5 to write the --healpix sky")
    if units == "Jy/pixel":
        raise InputError("a --healpix sky is in K or Jy/sr: use --units K or --units Jy/sr")
    result = make_allsky(out, nside=nside, freq_min=freq_min, nchan=nchan,
                         chan_width=chan_width, seed=seed, units=units or "K",
                         params=ForegroundParams(**physics), cell_deg=cell_deg,
                         box_deg=box_deg, overwrite=overwrite)
    meta, sky_ = result.meta, result.sky
    click.echo(f"wrote {out}: Q,U x {sky_.freq_hz.size} channels x {sky_.npix} HEALPix "
               f"pixels (NSIDE {sky_.nside}, RING, ICRS) in {sky_.unit}; rms |P| "
               f"{meta['PRMSREF']:g} K at {physics['ref_freq_hz'] / 1e6:g} MHz over the "
               f"sphere, Faraday depth {meta['PHIMIN']:.1f}..{meta['PHIMAX']:.1f} rad/m^2, "
               f"seed {meta['SEED']}")


#: the foreground model's options of ``msleak sky``: field of
#: :class:`~msleak.sky.foreground.ForegroundParams` -> (flag, click type, metavar, help);
#: each default is the field's
_PHYSICS = {
    "depth_pc": ("--depth-pc", float, "PC",
                 "Depth of the emitting and rotating slab along the line of sight, pc."),
    "ncells_los": ("--ncells-los", click.IntRange(2, None), "N", "Cells along the line of sight."),
    "cell_perp_pc": ("--cell-perp-pc", float, "PC",
                     "Transverse cell size, pc [default: depth / ncells, cubic cells; smaller "
                     "values give smoother maps but less Faraday-depth spread across the "
                     "field]."),
    "b_regular_ug": ("--b-regular", FloatList(3), "BE,BN,BPAR",
                     "Regular magnetic field: east, north, line-of-sight (towards the "
                     "observer) components, microgauss."),
    "b_random_rms_ug": ("--b-random-rms", float, "UG",
                        "rms |B| of the random (turbulent) field, microgauss."),
    "b_index": ("--b-index", float, "X",
                "3-D power-spectrum index of the random field, P(k) ~ k^-index "
                "(11/3: Kolmogorov)."),
    "solenoidal": ("--solenoidal/--no-solenoidal", None, None,
                   "Make the random field divergence-free."),
    "ne_mean_cm3": ("--ne-mean", float, "CM-3", "Mean thermal electron density, cm^-3."),
    "ne_sigma_ln": ("--ne-sigma", float, "X",
                    "Log-normal width (std of ln n_e) of the thermal electrons."),
    "ne_index": ("--ne-index", float, "X", "3-D power-spectrum index of ln n_e."),
    "ncr_sigma_ln": ("--ncr-sigma", float, "X",
                     "Log-normal width of the cosmic-ray electron density."),
    "ncr_index": ("--ncr-index", float, "X", "3-D power-spectrum index of ln n_CR."),
    "electron_index": ("--electron-index", float, "X",
                       "Cosmic-ray energy index p (N(E) ~ E^-p); brightness T ~ nu^-(p+3)/2."),
    "outer_scale_pc": ("--outer-scale-pc", float, "PC",
                       "Outer scale of all random fields, pc [default: none, pure power "
                       "laws]."),
    "p_rms_k": ("--p-rms", float, "K",
                "rms polarized brightness |P| over the map at --ref-freq, K (sets the "
                "emissivity scale)."),
    "ref_freq_hz": ("--ref-freq", float, "HZ", "Frequency at which --p-rms holds, Hz."),
}


def physics_options(func):
    """The options of ``msleak sky`` for the foreground model, one per field of
    :class:`~msleak.sky.foreground.ForegroundParams` with the field's default, passed under
    the field's name."""
    for f in reversed(fields(ForegroundParams)):
        flag, kind, metavar, text = _PHYSICS[f.name]
        default = f.default
        if isinstance(default, tuple):
            default = ",".join(map(str, default))
        extra = {} if kind is None else {"type": kind, "metavar": metavar}
        func = click.option(flag, f.name, default=default, show_default=default is not None,
                            help=text, **extra)(func)
    return func



@click.command("sky")
@click.argument("out", required=False, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--crop", "input_path", type=click.Path(dir_okay=False, path_type=Path),
              help="Work on this existing FITS cube (any cube with RA/Dec + FREQ [+ STOKES] "
                   "axes) instead of generating one: crop it (--fov/--crop-npix), re-centre it "
                   "(--phase-centre), convert it (--units), export it (--skymodel) or plot it. "
                   "A makesourcedb file can be checked and cut to --fov about --phase-centre "
                   "(written with --skymodel).")
@click.option("--fov", type=float, default=None, metavar="DEG",
              help="Field of view a side, deg. Generating: the cube size [default 15]. "
                   "With --crop: the centred crop (pixels = fov/pixel rounded to the nearest "
                   "integer of the cube's parity).")
@click.option("--crop-npix", type=int, default=None, metavar="N",
              help="Crop to this many pixels a side (centred; same parity as the cube), "
                   "e.g. 28 or 16 for the paper's 9 and 4 deg crops of the default cube.")
@click.option("--npix", type=click.IntRange(2, None), default=50, show_default=True,
              metavar="N", help="Pixels a side of the generated cube.")
@click.option("--freq-min", type=float, default=150e6, show_default=True, metavar="HZ",
              help="Centre of the first channel, Hz.")
@click.option("--nchan", type=click.IntRange(1, None), default=50, show_default=True,
              metavar="N", help="Number of channels.")
@click.option("--chan-width", type=float, default=195312.5, show_default=True, metavar="HZ",
              help="Channel width (and spacing), Hz.")
@click.option("--seed", type=click.IntRange(0, None), default=None, metavar="N",
              help="Random seed (non-negative integer) for a reproducible cube [default: "
                   "fresh entropy, recorded in the header as MSLEAK SEED].")
@click.option("--phase-centre", type=FloatList(2), default=None, metavar="RA_DEG,DEC_DEG",
              help="Centre of the cube, J2000 deg [default 0,90 (NCP) when generating; "
                   "with --crop: re-centre the cube's grid there].")
@click.option("--units", type=click.Choice((*get_args(Units), "Jy/sr")), default=None,
              help="Brightness unit of the written cube [default K; with --crop the input's]. "
                   "Jy/pixel uses S = 2 k_B T Omega_pix / lambda^2; Jy/sr (the same per "
                   "steradian) is for --healpix skies only.")
@click.option("--healpix", "nside", type=int, default=None, metavar="N",
              help="Generate the whole sky instead of a cube: Q and U on every HEALPix pixel "
                   "of this NSIDE (a power of 2; RING, ICRS), each pixel one line of sight "
                   "through the slab, written as a pyradiosky SkyH5 file OUT.skyh5 (needs "
                   "pip install 'msleak[healpix]'). Takes the physics options, --freq-min, "
                   "--nchan, --chan-width, --seed, --units K|Jy/sr.")
@click.option("--cell-deg", type=float, default=CELL_DEG, show_default=True, metavar="DEG",
              help="With --healpix: the angle one transverse cell (--cell-perp-pc) subtends, "
                   "as the flat cube's pixel; sets the distance mapping angle to size.")
@click.option("--box-deg", type=float, default=BOX_DEG, show_default=True, metavar="DEG",
              help="With --healpix: the largest transverse scale of the random fields, as "
                   "the flat cube of this width (larger scales carry the power of its "
                   "uniform mode).")
@physics_options
@click.option("--skymodel", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Also write the voxels as makesourcedb point sources (Jy) for DP3: one file "
                   "per channel, NAME_chNNN.skymodel, unless --skymodel-channel is given.")
@click.option("--skymodel-channel", type=click.IntRange(0, None), default=None, metavar="N",
              help="Write only this channel (0-based) to the --skymodel file, flat spectra.")
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False, path_type=Path),
              default=None, help="Figure, format from the suffix (.png, .pdf): Q and U "
                                 "slices, one pixel's spectrum and the angular power "
                                 "spectrum of P.")
@click.option("--plot-channel", "channel", type=click.IntRange(0, None), default=0,
              show_default=True, metavar="N",
              help="Channel (0-based) of the slices and power spectrum in --plot.")
@click.option("--plot-pixel", "pixel", type=FloatList(2), default=None, metavar="X,Y",
              help="Pixel (0-based x,y indices) whose spectrum --plot shows [default: the "
                   "centre].")
@click.option("--overwrite", is_flag=True, help="Replace existing output files (cube, "
                                                "sky models, figure).")
def sky(out, input_path, fov, crop_npix, npix, freq_min, nchan, chan_width, seed,
        phase_centre, units, nside, cell_deg, box_deg, skymodel, skymodel_channel, plot_path,
        channel, pixel, overwrite, **physics):
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
      msleak sky all.skyh5 --healpix 64 --nchan 20 --seed 1   # the whole sky, SkyH5
    """
    if nside is not None:
        return _allsky(out, nside, cell_deg, box_deg, freq_min, nchan, chan_width, seed,
                       units, overwrite, physics)
    for name in ("cell_deg", "box_deg"):
        if _given(name):
            raise InputError(f"{flag_for(name, sky)} applies to --healpix skies only; add "
                             "--healpix NSIDE or drop it")
    if units == "Jy/sr":
        raise InputError("--units Jy/sr is for --healpix skies; a cube takes K or Jy/pixel")
    if out is None and skymodel is None and plot_path is None:
        raise click.UsageError("nothing to do: give OUT.fits, --skymodel or --plot")
    if input_path is not None and input_path.is_file() and not is_fits(input_path):
        return _skymodel_input(input_path, out, fov, crop_npix, phase_centre, skymodel,
                               plot_path, overwrite)
    if input_path is None and out is None:
        raise click.UsageError("give OUT.fits to generate a cube (or --crop IN.fits)")
    if plot_path is not None and plot_path.exists() and not overwrite:
        raise InputError(f"{plot_path} exists; choose another name or pass --overwrite")
    ds = make_sky(
        out, fov=fov, npix=npix, freq_min=freq_min, nchan=nchan, chan_width=chan_width,
        seed=seed, phase_centre=phase_centre, units=units,
        params=ForegroundParams(**physics), crop=input_path, crop_npix=crop_npix,
        skymodel=skymodel, skymodel_channel=skymodel_channel, overwrite=overwrite)
    if out is not None:
        _report(ds, out, generated=input_path is None)
    if skymodel is not None:
        targets = skymodel_paths(skymodel, ds.sizes["freq"], skymodel_channel)
        nsrc = ds.sizes["y"] * ds.sizes["x"]
        click.echo(f"wrote {len(targets)} makesourcedb file(s) of {nsrc} sources: "
                   f"{targets[0][1]}{' ...' if len(targets) > 1 else ''}")
    if plot_path is not None:
        pixel = None if pixel is None else (int(pixel[0]), int(pixel[1]))
        plot_sky(ds, plot_path, channel=channel, pixel=pixel)
        click.echo(f"wrote {plot_path}")
