"""``msleak ps``: cylindrical, spherical and 1D power spectra of a delay cube."""

from __future__ import annotations

import click

from msleak.cli._common import FloatList


@click.command()
@click.argument("delay", type=click.Path())
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Output power spectra (HDF5, docs/products.md 'ps').")
@click.option("--cosmology", default="Planck18", show_default=True,
              help="astropy cosmology name (Planck18, Planck15, WMAP9, ...).")
@click.option("--bins", "n_perp", type=click.IntRange(min=1), default=None,
              help="Number of |b| (k_perp) bins over the uv range [default: one per cell].")
@click.option("--bin-width", "bin_width", type=float, default=None, metavar="LAMBDA",
              help="Linear |b| bins of this width (wavelengths) from the uv minimum "
              "(overrides --bins/--log-bins).")
@click.option("--log-bins", is_flag=True, help="Logarithmic k_perp bins.")
@click.option("--sph-bins", "n_sph", type=click.IntRange(min=1), default=12, show_default=True,
              help="Number of logarithmic bins of the spherical average.")
@click.option("--kperp-1d", "kperp_1d", type=FloatList(2), default="0.02,0.1",
              show_default=True, metavar="MIN,MAX",
              help="k_perp range (Mpc^-1) averaged in the 1D PS versus k_par.")
@click.option("--primary-theta", "primary_theta_deg", type=float, default=None, metavar="DEG",
              help="Angle of the primary wedge line [default: half the field of view].")
@click.option("--beam-area", "beam_area_sr", type=float, default=None, metavar="SR",
              help="Omega (sr) for mK^2 Mpc^3 [default: the cube's beam_area_sr].")
@click.option("--cross/--auto", "cross", default=None,
              help="Cross-power of the two halves (default when the cube has them) or "
              "auto-power |V~|^2.")
@click.option("--plot", "plot", type=click.Path(dir_okay=False), default=None,
              help="Also draw the 2D PS of I, Q, U, P with both wedge lines (PNG/PDF).")
@click.option("--stokes", "plot_stokes", default="I,Q,U,P", show_default=True,
              help="Stokes panels of --plot.")
def ps(delay, output, cosmology, n_perp, bin_width, log_bins, n_sph, kperp_1d, primary_theta_deg,
       beam_area_sr, cross, plot, plot_stokes):
    """Power spectra of the delay cube DELAY: P3D = |V~|^2 / window_norm (or the
    cross-power of two halves) per uv cell, cylindrical average in |b| annuli with +-delay
    folded, spherical average and 1D PS vs k_par; k_perp = 2 pi |b| / D_c,
    k_par = 2 pi tau H0 f21 E(z) / (c (1+z)^2); units mK^2 Mpc^3 (docs/ps.md).

    \b
    Example:
      msleak ps delay.h5 -o ps.h5 --plot ps.png
    """
    from msleak.io.products import open_product, save_product
    from msleak.ps.spectra import power_spectrum

    if not 0 <= kperp_1d[0] < kperp_1d[1]:
        raise click.BadParameter("need 0 <= MIN < MAX", param_hint="--kperp-1d")
    if primary_theta_deg is not None and not 0 <= primary_theta_deg <= 90:
        raise click.BadParameter("must be within 0..90 degrees", param_hint="--primary-theta")
    dl = open_product(delay, "delay", required=("vis", "weight"))
    ds = power_spectrum(dl, cosmology=cosmology, n_perp=n_perp, log_perp=log_bins,
                        n_sph=n_sph, kperp_1d=tuple(kperp_1d),
                        primary_theta_deg=primary_theta_deg, beam_area_sr=beam_area_sr,
                        cross=cross, bin_width=bin_width)
    save_product(ds, output, "ps")
    click.echo(f"power spectra {output}: z = {ds.attrs['redshift']:.3f}, "
               f"{ds.sizes['k_perp']} k_perp x {ds.sizes['k_par']} k_par bins, "
               f"units {ds.attrs['units']}")
    if plot:
        from msleak.plot.ps import plot_ps2d

        labels = [s.strip().upper() for s in plot_stokes.split(",") if s.strip()]
        bad = [s for s in labels if s not in list(ds["stokes"].values)]
        if bad:
            raise click.BadParameter(f"unknown Stokes {bad}", param_hint="--stokes")
        plot_ps2d(ds, plot, stokes=labels)
        click.echo(f"figure {plot}")
