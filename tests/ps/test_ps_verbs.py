"""The transform and power_spectrum verbs against the CLI, their errors, cosmology from
H0/Om0, little h, the CF layout and provenance of the ps product, and its figures."""

from __future__ import annotations

import re
import sys

import numpy as np
import pytest
import xarray as xr
from click.testing import CliRunner

import msleak
from msleak.cli import cli
from msleak.errors import InputError
from msleak.io.products import history_lines, open_product, save_product

NCHAN, DNU = 8, 195312.5
FREQ = 150e6 + DNU * np.arange(NCHAN)
CELL = 16.0


def _run(monkeypatch, *args):
    """The CLI in-process, with sys.argv set as a shell would (the product's command)."""
    args = [str(a) for a in args]
    monkeypatch.setattr(sys, "argv", ["msleak", *args])
    return CliRunner().invoke(cli, args)


def _as_params(text: str) -> str:
    """``text`` with each ``--flag`` written as its parameter (``--kperp-1d`` -> kperp_1d)."""
    return re.sub(r"--([a-z][a-z0-9-]*)", lambda m: m.group(1).replace("-", "_"), text)


def _error_line(result) -> str:
    lines = result.output.strip().splitlines()
    assert result.exit_code == 2 and len(lines) == 1, result.output
    assert lines[0].startswith("msleak: error: ")
    return lines[0]


def _cube(path, seed: int):
    """A K image cube (chan, y, x) of noise plus a smooth spectrum, FITS with a FREQ axis."""
    from astropy.io import fits

    n = 32
    rng = np.random.default_rng(seed)
    cube = rng.normal(size=(NCHAN, n, n)) + np.linspace(1, 2, NCHAN)[:, None, None]
    hdr = fits.Header()
    dl = np.degrees(1 / (n * CELL))
    for i, (ctype, crval, cdelt) in enumerate((("RA---SIN", 0.0, -dl), ("DEC--SIN", 90.0, dl)),
                                              start=1):
        hdr[f"CTYPE{i}"], hdr[f"CRPIX{i}"], hdr[f"CRVAL{i}"], hdr[f"CDELT{i}"] = \
            ctype, n / 2 + 1, crval, cdelt
    hdr["CTYPE3"], hdr["CRPIX3"], hdr["CRVAL3"], hdr["CDELT3"] = "FREQ", 1, FREQ[0], DNU
    hdr["BUNIT"] = "K"
    fits.PrimaryHDU(data=cube, header=hdr).writeto(path)
    return path


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """grid -> transform -> ps through the CLI (I, Q, U from three image cubes)."""
    d = tmp_path_factory.mktemp("chain")
    mp = pytest.MonkeyPatch()
    cubes = [_cube(d / f"{s}.fits", k) for k, s in enumerate("IQU")]
    steps = [["grid", *[a for c in cubes for a in ("--image", c)], "--stokes", "I,Q,U",
              "-o", d / "g.h5"],
             ["transform", d / "g.h5", "-o", d / "d.h5", "--window", "hann"],
             ["ps", d / "d.h5", "-o", d / "p.h5", "--cosmology", "WMAP9", "--bins", "6",
              "--kperp-1d", "0.03,0.09", "--primary-theta", "3"]]
    try:
        for args in steps:
            r = _run(mp, *args)
            assert r.exit_code == 0, r.output
    finally:
        mp.undo()
    return d


def test_transform_verb_equals_cli(chain, tmp_path):
    cli_ds = open_product(chain / "d.h5", "delay")
    uv = open_product(chain / "g.h5", "uvcube")
    for source in (chain / "g.h5", uv):
        ds = msleak.transform(source, window="hann")
        for name in ("vis", "weight", "window_values", "delay"):
            np.testing.assert_array_equal(ds[name].values, cli_ds[name].values)
        assert ds.attrs["window_norm"] == cli_ds.attrs["window_norm"]
    out = msleak.transform(uv, window="hann", output=tmp_path / "d.h5")
    written = open_product(tmp_path / "d.h5", "delay")
    assert written["vis"].equals(out["vis"])
    assert history_lines(written.attrs)[-1].endswith(
        f"msleak.transform(<Dataset>, window='hann', output='{tmp_path / 'd.h5'}')")
    with pytest.raises(InputError, match="exists; choose another name or pass overwrite"):
        msleak.transform(uv, output=tmp_path / "d.h5")
    msleak.transform(uv, window="none", output=tmp_path / "d.h5", overwrite=True)
    assert open_product(tmp_path / "d.h5", "delay").attrs["window"] == "none"


def test_power_spectrum_verb_equals_cli(chain):
    cli_ds = open_product(chain / "p.h5", "ps")
    for source in (chain / "d.h5", open_product(chain / "d.h5", "delay")):
        ds = msleak.power_spectrum(source, cosmology="WMAP9", bins=6, kperp_1d=(0.03, 0.09),
                                   primary_theta=3.0)
        for name in ("power", "power_sph", "power_1d", "power3d", "power3d_P_mirror",
                     "counts", "k_perp_bounds", "k_bounds", "k_par", "k_perp", "k_perp_cell"):
            np.testing.assert_array_equal(ds[name].values, cli_ds[name].values)
        assert ds.attrs["wedge_slope_primary"] == cli_ds.attrs["wedge_slope_primary"]


def test_history_chain_from_grid_to_ps(chain):
    lines = history_lines(open_product(chain / "p.h5", "ps").attrs)
    assert [line.split(": ", 1)[1].split()[:2] for line in lines[-3:]] == [
        ["msleak", "grid"], ["msleak", "transform"], ["msleak", "ps"]]
    assert history_lines(open_product(chain / "d.h5", "delay").attrs) == lines[:-1]


def test_ps_layout_is_cf(chain):
    """Cell and delay axes are coordinates; k_perp has CF bounds equal to 2 pi |b| / D_c of
    the |b| bin edges (6 linear bins over 30..180 wavelengths); every number has units."""
    from astropy.cosmology import WMAP9

    ds = open_product(chain / "p.h5", "ps")
    for name in ("u_cell", "v_cell", "k_perp_cell", "k_par3d", "b_lambda", "delay_folded"):
        assert name in ds.coords and name not in ds.data_vars
    assert "k_perp_lo" not in ds.variables and "k_lo" not in ds.variables
    assert ds["k_perp"].attrs["bounds"] == "k_perp_bounds"
    assert ds["k_perp_bounds"].dims == ("k_perp", "nv")
    dc = WMAP9.comoving_distance(ds.attrs["redshift"]).to_value("Mpc")
    edges = np.linspace(30.0, 180.0, 7)
    np.testing.assert_allclose(ds["k_perp_bounds"].values[:, 0], 2 * np.pi * edges[:-1] / dc,
                               rtol=1e-12)
    np.testing.assert_allclose(ds["k_perp_bounds"].values[:, 1], 2 * np.pi * edges[1:] / dc,
                               rtol=1e-12)
    np.testing.assert_allclose(ds["k_perp"].values, ds["k_perp_bounds"].values.mean(axis=1),
                               rtol=1e-12)
    assert ds["k"].attrs["bounds"] == "k_bounds"
    k_b = ds["k_bounds"].values
    np.testing.assert_allclose(ds["k"].values, np.sqrt(k_b[:, 0] * k_b[:, 1]), rtol=1e-12)
    bounds = {v.attrs["bounds"]: n for n, v in ds.variables.items() if "bounds" in v.attrs}
    for name, var in ds.variables.items():
        if var.dtype.kind in "fiuc":  # CF bounds take the units of their coordinate
            assert ds[bounds.get(name, name)].attrs.get("units"), f"{name} has no units"


def test_little_h_converts_exactly(chain):
    dl = open_product(chain / "d.h5", "delay")
    plain = msleak.power_spectrum(dl, kperp_1d=(0.03, 0.09))
    h = plain.attrs["h"]
    assert h == pytest.approx(0.6766, abs=1e-12)  # Planck18
    little = msleak.power_spectrum(dl, little_h=True, kperp_1d=(0.03 / h, 0.09 / h))
    assert little["power"].attrs["units"] == "mK^2 h^-3 Mpc^3"
    assert little.attrs["units"] == "mK^2 h^-3 Mpc^3" and little.attrs["little_h"] == 1
    for name in ("power", "power_sph", "power_1d", "power3d", "power3d_P_mirror"):
        np.testing.assert_allclose(little[name].values, plain[name].values * h ** 3,
                                   rtol=1e-14, atol=0)
    for name in ("k_par", "k_perp", "k", "k_perp_bounds", "k_bounds", "k_par3d", "k_perp_cell"):
        assert little[name].attrs["units"] == "h Mpc^-1"
        np.testing.assert_allclose(little[name].values, plain[name].values / h, rtol=1e-14)
    for name in ("delta2", "power_jy2", "counts_1d"):  # k^3 P and Jy^2 do not depend on h
        np.testing.assert_allclose(little[name].values, plain[name].values, rtol=1e-14)
    assert little.attrs["k_perp_min_1d"] == pytest.approx(0.03 / h, rel=1e-14)


def test_flat_lcdm_from_h0_om0_equals_astropy(chain, tmp_path):
    """--h0/--om0/--ob0/--tcmb0 give astropy's FlatLambdaCDM with those numbers; with
    Planck18's they equal Planck18 but for its 0.06 eV neutrino (and Neff 3.046)."""
    from astropy.cosmology import FlatLambdaCDM, Planck18

    from msleak.ps.cosmology import cosmo_at, make_cosmology

    p18 = dict(H0=67.66, Om0=0.30966, Ob0=0.04897, Tcmb0=2.7255)
    ours = make_cosmology(h0=67.66, om0=0.30966, ob0=0.04897, tcmb0=2.7255)
    direct = FlatLambdaCDM(**p18)
    nu = 0.5 * (FREQ[0] + FREQ[-1])
    z = 1420.405751768e6 / nu - 1
    c = cosmo_at(nu, ours)
    assert c.dc_mpc == pytest.approx(direct.comoving_distance(z).to_value("Mpc"), rel=1e-12)
    assert c.efunc == pytest.approx(direct.efunc(z), rel=1e-12)
    assert c.dh_mpc == pytest.approx(Planck18.hubble_distance.to_value("Mpc"), rel=1e-12)
    with_nu = FlatLambdaCDM(**p18, Neff=3.046, m_nu=[0, 0, 0.06])
    assert with_nu.comoving_distance(z) == Planck18.comoving_distance(z)
    ds = msleak.power_spectrum(chain / "d.h5", h0=67.66, om0=0.30966, ob0=0.04897,
                               tcmb0=2.7255)
    assert ds.attrs["cosmology"] == "FlatLambdaCDM" and ds.attrs["h"] == pytest.approx(0.6766)
    assert "H0=67.66 km/s/Mpc, Om0=0.30966, Ob0=0.04897, Tcmb0=2.7255 K" in \
        ds.attrs["cosmology_parameters"]
    assert ds.attrs["comoving_distance_mpc"] == pytest.approx(
        direct.comoving_distance(z).to_value("Mpc"), rel=1e-12)
    named = msleak.power_spectrum(chain / "d.h5", cosmology="Planck13",
                                  kperp_1d=np.array([0.03, 0.09]), output=tmp_path / "p.h5")
    assert named.attrs["cosmology"] == "Planck13"
    assert history_lines(open_product(tmp_path / "p.h5", "ps").attrs)[-1].endswith(
        f"msleak.power_spectrum('{chain / 'd.h5'}', cosmology='Planck13', "
        f"kperp_1d=array([0.03, 0.09]), output='{tmp_path / 'p.h5'}')")


def test_transform_names_everything_missing(tmp_path, monkeypatch):
    user = xr.Dataset({"vis": (("stokes", "freq", "v", "u"), np.zeros((1, 4, 3, 3), complex))},
                      coords={"stokes": ["I"], "freq": FREQ[:4], "v": [-16.0, 0, 16],
                              "u": [-16.0, 0, 16]})
    pattern = ("the uvcube Dataset lacks variable weight, attribute cell_lambda, attribute "
               "uv_min_lambda, attribute uv_max_lambda; make it with `msleak grid`")
    with pytest.raises(InputError, match=pattern):
        msleak.transform(user)
    user["weight"] = (("freq", "v", "u"), np.ones((4, 3, 3)))
    save_product(user, tmp_path / "g.h5", "uvcube", overwrite=False)
    line = _error_line(_run(monkeypatch, "transform", tmp_path / "g.h5", "-o", tmp_path / "d.h5"))
    assert line.endswith("g.h5 lacks attribute cell_lambda, attribute uv_min_lambda, attribute "
                         "uv_max_lambda; make it with `msleak grid` (docs/products.md 'uvcube')")
    with pytest.raises(InputError, match="must be a product path or an xarray.Dataset"):
        msleak.transform(np.zeros(3))


def test_power_spectrum_names_everything_missing(chain, tmp_path, monkeypatch):
    dl = open_product(chain / "d.h5", "delay")
    for key in ("window_norm", "bandwidth_hz"):
        del dl.attrs[key]
    with pytest.raises(InputError, match="the delay Dataset lacks attribute bandwidth_hz, "
                                         "attribute window_norm; make it with `msleak transform`"):
        msleak.power_spectrum(dl)
    save_product(dl, tmp_path / "d.h5", "delay", overwrite=False)
    line = _error_line(_run(monkeypatch, "ps", tmp_path / "d.h5", "-o", tmp_path / "p.h5"))
    assert "lacks attribute bandwidth_hz, attribute window_norm" in line


@pytest.mark.parametrize("args, kwargs, message", [
    (["--cosmology", "WMAP9", "--h0", "70", "--om0", "0.3"],
     dict(cosmology="WMAP9", h0=70, om0=0.3),
     "--cosmology and --h0/--om0 exclude each other"),
    (["--h0", "70"], dict(h0=70), "--h0 without --om0: a flat LambdaCDM needs both"),
    (["--om0", "0.3", "--tcmb0", "2.7"], dict(om0=0.3, tcmb0=2.7), "--om0/--tcmb0 without --h0"),
    (["--h0", "-70", "--om0", "0.3"], dict(h0=-70, om0=0.3),
     "--h0 -70: must be a positive finite number"),
    (["--h0", "70", "--om0", "0.3", "--ob0", "0.5"], dict(h0=70, om0=0.3, ob0=0.5),
     "baryonic density can not be larger than total matter density"),
    (["--cosmology", "Planck99"], dict(cosmology="Planck99"),
     "unknown cosmology 'Planck99': use one of WMAP1"),
    (["--kperp-1d", "0.1,0.02"], dict(kperp_1d=(0.1, 0.02)), "--kperp-1d 0.1,0.02: need"),
    (["--primary-theta", "95"], dict(primary_theta=95.0), "--primary-theta 95: must be within"),
    (["--beam-area", "-1"], dict(beam_area=-1.0), "--beam-area -1: must be a positive"),
    (["--bins", "0"], dict(bins=0), "--bins 0: must be a whole number >= 1"),
    (["--sph-bins", "0"], dict(sph_bins=0), "--sph-bins 0: must be a whole number >= 1"),
    (["--plot", "f.xyz"], dict(plot="f.xyz"), "unknown figure format 'xyz'"),
    (["--plot", "f.png", "--stokes", "I,X"], dict(plot="f.png", stokes="I,X"),
     "--stokes X: not in the delay cube (it has I,Q,U,V,P)"),
    (["--cross"], dict(cross=True), "cross-power asked but the delay cube has no vis_a"),
])
def test_ps_errors(chain, tmp_path, monkeypatch, args, kwargs, message):
    """The command names its flags; the function the same message with its parameters."""
    monkeypatch.chdir(tmp_path)
    line = _error_line(_run(monkeypatch, "ps", chain / "d.h5", "-o", "p.h5", *args))
    assert message in line
    with pytest.raises(InputError) as err:
        msleak.power_spectrum(chain / "d.h5", **kwargs)
    assert _as_params(message) in str(err.value)
    assert not (tmp_path / "p.h5").exists() and not (tmp_path / "f.png").exists()


def test_existing_outputs_refused_before_any_work(chain, tmp_path, monkeypatch):
    (tmp_path / "fig.png").write_bytes(b"mine")
    line = _error_line(_run(monkeypatch, "ps", chain / "d.h5", "-o", tmp_path / "p.h5",
                            "--plot", tmp_path / "fig.png"))
    assert line.endswith("fig.png exists; choose another name or pass --overwrite")
    assert not (tmp_path / "p.h5").exists() and (tmp_path / "fig.png").read_bytes() == b"mine"
    r = _run(monkeypatch, "ps", chain / "d.h5", "-o", tmp_path / "p.h5", "--plot",
             tmp_path / "fig.png", "--overwrite")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "fig.png").stat().st_size > 10_000
    _error_line(_run(monkeypatch, "transform", chain / "g.h5", "-o", tmp_path / "p.h5"))


def test_colour_limits_per_panel():
    from msleak.plot.ps import colour_limits

    lo, hi, extend = colour_limits(np.concatenate([np.arange(1.0, 1001.0), [np.nan, -1, 0]]))
    # numpy's linear percentiles of 1..1000: 1 % at 1 + 9.99, 99.5 % at 1 + 994.005
    assert (lo, hi, extend) == (pytest.approx(10.99), pytest.approx(995.005), "both")
    assert colour_limits(np.full(5, 4.0)) == (2.0, 8.0, "neither")
    assert colour_limits(np.zeros(5)) == (1.0, 10.0, "neither")


def _captured(monkeypatch):
    import msleak.plot.ps as plot_ps

    figures = []
    monkeypatch.setattr(plot_ps, "save_figure", lambda fig, path, pdf=False: figures.append(fig))
    return figures


def test_ps2d_panels_have_their_own_scale(chain, monkeypatch):
    """Stokes I 1e8 times brighter than Q: each panel's colour limits are those of its own
    values, and the title names field, uv cell size (with the field it is the Fourier
    dual of, degrees(1/16) = 3.58) and column."""
    from msleak.plot.ps import colour_limits, plot_ps2d

    ds = open_product(chain / "p.h5", "ps")
    ds["power"].loc[{"stokes": "I"}] = ds["power"].sel(stokes="I") * 1e8
    ds.attrs.update(field_name="NCP", column="MODEL_4DEG", cell_lambda=16.0, fov_deg=5.16)
    figures = _captured(monkeypatch)
    plot_ps2d(ds, "unused.png", stokes=("I", "Q"))
    fig = figures[0]
    panels = [ax for ax in fig.axes if ax.get_title() in ("Stokes I", "Stokes Q")]
    for ax, s in zip(panels, ("I", "Q")):
        norm = ax.collections[0].norm
        lo, hi, _ = colour_limits(ds["power"].sel(stokes=s).values)
        assert (norm.vmin, norm.vmax) == (pytest.approx(lo, rel=1e-12), pytest.approx(hi))
    assert panels[0].collections[0].norm.vmin > 1e6 * panels[1].collections[0].norm.vmax
    title = fig._suptitle.get_text()
    assert title.startswith("NCP, uv cell 16 λ (field 1/cell = 3.58°), column MODEL_4DEG;")
    assert "5.16" not in title


def test_ps1d_inputs_differ_by_line_style_and_marker(chain, monkeypatch):
    from msleak.plot.ps import plot_ps1d

    figures = _captured(monkeypatch)
    plot_ps1d([(chain / "p.h5", "a"), (chain / "p.h5", "b")], "unused.png", stokes=("Q", "U"))
    lines = figures[0].axes[0].lines
    assert [line.get_label() for line in lines] == ["a: Q", "a: U", "b: Q", "b: U"]
    for a, b in ((lines[0], lines[2]), (lines[1], lines[3])):  # same data, other input
        np.testing.assert_array_equal(a.get_ydata(), b.get_ydata())
        assert a.get_linestyle() != b.get_linestyle() and a.get_marker() != b.get_marker()


@pytest.mark.parametrize("rows", [0, 12])
def test_ps1d_names_rows_crossing_the_uv_range(chain, monkeypatch, rows):
    """Rows whose baseline crosses a uv-range limit within the band (counted by msleak
    grid) get a note on the 1D PS: they set its floor at high k_par (docs/ps.md)."""
    from msleak.plot.ps import plot_ps1d

    ds = open_product(chain / "p.h5", "ps")
    if rows:
        ds.attrs["n_rows_crossing_uv_range"] = rows
    figures = _captured(monkeypatch)
    plot_ps1d([(ds, "a")], "unused.png", stokes=("Q", "U"))
    notes = [t.get_text() for t in figures[0].axes[0].texts]
    assert notes == ([f"{rows} rows (baseline x time) cross the\nuv-range limits within the "
                      "band: in their\ncells a step in frequency sets a floor\nat high "
                      "$k_\\parallel$ (docs/ps.md)"] if rows else [])
