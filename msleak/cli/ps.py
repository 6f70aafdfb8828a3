"""``msleak ps``: cylindrical, spherical and 1D power spectra of a delay cube."""

from __future__ import annotations

import click

from msleak.cli._common import FloatList, cosmology_options
from msleak.verbs.power import power_spectrum


@click.command()
@click.argument("delay", type=click.Path())
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Output power spectra (HDF5, docs/products.md 'ps').")
@click.option("--overwrite", is_flag=True,
              help="Replace OUTPUT and the --plot figure if they exist.")
@cosmology_options
@click.option("--little-h", "little_h", is_flag=True,
              help="k in h Mpc^-1 and P in mK^2 h^-3 Mpc^3 (as hera_pspec and ps_eor can); "
              "--kperp-1d is then in h Mpc^-1 too.")
@click.option("--bins", type=int, default=None, metavar="N",
              help="Number of |b| (k_perp) bins over the uv range [default: one per cell].")
@click.option("--bin-width", "bin_width", type=float, default=None, metavar="LAMBDA",
              help="Linear |b| bins of this width (wavelengths) from the uv minimum "
              "(overrides --bins/--log-bins).")
@click.option("--log-bins", "log_bins", is_flag=True, help="Logarithmic k_perp bins.")
@click.option("--sph-bins", "sph_bins", type=int, default=12, show_default=True, metavar="N",
              help="Number of logarithmic bins of the spherical average.")
@click.option("--kperp-1d", "kperp_1d", type=FloatList(2), default=None, metavar="MIN,MAX",
              help="k_perp range averaged in the 1D PS versus k_par, in Mpc^-1 (h Mpc^-1 "
              "with --little-h) [default: 0.02,0.1 Mpc^-1].")
@click.option("--primary-theta", "primary_theta", type=float, default=None, metavar="DEG",
              help="Angle of the primary wedge line [default: half the cube's "
              "primary_fwhm_deg, which msleak grid records for an MS as the FWHM of an Airy "
              "disc one cell wide (1.84 deg for 16-wavelength cells); half the field of view "
              "for image cubes].")
@click.option("--beam-area", "beam_area", type=float, default=None, metavar="SR",
              help="Omega (sr) for mK^2 Mpc^3 [default: the cube's beam_area_sr].")
@click.option("--cross/--no-cross", "cross", default=None,
              help="Cross-power of the two halves vis_a, vis_b, or auto-power |V~|^2 "
              "[default: cross-power when the cube has halves].")
@click.option("--plot", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Also draw the 2D PS with both wedge lines (format from the suffix: "
              ".png, .pdf, .svg).")
@click.option("--stokes", default="I,Q,U,P", show_default=True, metavar="S[,S...]",
              help="Stokes labels of the --plot panels.")
def ps(delay, output, overwrite, cosmology, h0, om0, ob0, tcmb0, little_h, bins, bin_width,
       log_bins, sph_bins, kperp_1d, primary_theta, beam_area, cross, plot, stokes):
    """Power spectra of the delay cube DELAY: P3D = |V~|^2 / window_norm (or the
    cross-power of two halves) per uv cell, cylindrical average in |b| annuli with +-delay
    folded, spherical average and 1D PS vs k_par; k_perp = 2 pi |b| / D_c,
    k_par = 2 pi tau H0 f21 E(z) / (c (1+z)^2); units mK^2 Mpc^3 (docs/ps.md).

    \b
    Examples:
      msleak ps delay.h5 -o ps.h5 --plot ps.png
      msleak ps delay.h5 -o ps_h.h5 --h0 70 --om0 0.3 --little-h
    """
    ds = power_spectrum(delay, cosmology=cosmology, h0=h0, om0=om0, ob0=ob0, tcmb0=tcmb0,
                        little_h=little_h, bins=bins, bin_width=bin_width, log_bins=log_bins,
                        sph_bins=sph_bins, kperp_1d=tuple(kperp_1d) if kperp_1d else None,
                        primary_theta=primary_theta, beam_area=beam_area, cross=cross,
                        plot=plot, stokes=stokes, output=output, overwrite=overwrite)
    click.echo(f"power spectra {output}: z = {ds.attrs['redshift']:.3f}, "
               f"{ds.sizes['k_perp']} k_perp x {ds.sizes['k_par']} k_par bins, "
               f"units {ds.attrs['units']}")
    if plot:
        click.echo(f"figure {plot}")
