"""`msleak grid`, `transform`, `ps` end to end, the image-cube path and every input error."""

import numpy as np
import pytest
import xarray as xr
from click.testing import CliRunner

from msleak.cli import cli
from msleak.errors import InputError

NCHAN = 8
DNU = 195312.5
FREQ = 150e6 + DNU * np.arange(NCHAN)


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _write_cube(path, cube, dl_deg, bunit="JY/PIXEL", freq_axis=True, stokes=None):
    """cube (chan, y, x) -> FITS with RA---SIN, DEC--SIN, FREQ axes."""
    from astropy.io import fits

    n = cube.shape[-1]
    hdr = fits.Header()
    hdr["CTYPE1"], hdr["CRPIX1"], hdr["CRVAL1"], hdr["CDELT1"] = "RA---SIN", n / 2 + 1, 0.0, -dl_deg
    hdr["CTYPE2"], hdr["CRPIX2"], hdr["CRVAL2"], hdr["CDELT2"] = "DEC--SIN", n / 2 + 1, 90.0, dl_deg
    if freq_axis:
        hdr["CTYPE3"], hdr["CRPIX3"], hdr["CRVAL3"], hdr["CDELT3"] = "FREQ", 1, FREQ[0], DNU
        data = cube
    else:
        hdr["CTYPE3"], hdr["CRPIX3"], hdr["CRVAL3"], hdr["CDELT3"] = "VOPT", 1, 0.0, 1.0
        data = cube
    if stokes:
        hdr["CTYPE4"], hdr["CRPIX4"], hdr["CRVAL4"], hdr["CDELT4"] = "STOKES", 1, stokes, 1
        data = cube[None]
    hdr["BUNIT"] = bunit
    fits.PrimaryHDU(data=data, header=hdr).writeto(path, overwrite=True)
    return path


def _sky(n=32, seed=4):
    """A few point sources on pixel centres with random spectra (chan, y, x), Jy/pixel."""
    rng = np.random.default_rng(seed)
    cube = np.zeros((NCHAN, n, n))
    for _ in range(5):
        y, x = rng.integers(4, n - 4, 2)
        cube[:, y, x] += rng.uniform(0.5, 2) * (1 + 0.3 * np.sin(rng.uniform(0, 6) + np.arange(NCHAN)))
    return cube


def test_image_path_matches_visibility_path(tmp_path):
    """Same sky: FFT of the image cube vs. gridded visibilities sampled at cell centres."""
    from msleak.verbs.images import grid_image
    from msleak.ps.gridding import CellAccumulator, make_grid
    from msleak.verbs.power import power_spectrum
    from msleak.verbs.transform import transform
    from msleak.ps.uvcube import uvcube_dataset

    n, cell = 32, 16.0
    dl = 1 / (n * cell)  # rad: the image's cells are then 16 wavelengths
    sky = _sky(n)
    path = _write_cube(tmp_path / "q.fits", sky, np.degrees(dl), stokes=2)
    uv_img = grid_image([path], uv_range=(30, 180))
    assert uv_img.attrs["cell_lambda"] == pytest.approx(cell, rel=1e-9)
    # visibilities of the same sky (l = (x - n/2) * (-dl), m = (y - n/2) * dl) at every
    # cell centre of one Hermitian half, as a perfect array would measure them
    grid = make_grid(cell, 180.0)
    c = grid.centres
    uu, vv = (a.ravel() for a in np.meshgrid(c, c))
    half = (uu > 0) | ((uu == 0) & (vv > 0))
    uu, vv = uu[half], vv[half]
    x = np.arange(n) - n // 2
    l, m = -x * dl, x * dl
    ph_u = np.exp(-2j * np.pi * np.outer(uu, l))  # (row, x)
    ph_v = np.exp(-2j * np.pi * np.outer(vv, m))  # (row, y)
    vis_q = np.einsum("fyx,rx,ry->rf", sky, ph_u, ph_v)
    vis4 = np.zeros((4,) + vis_q.shape, complex)
    vis4[1] = vis_q
    acc = CellAccumulator(grid, NCHAN)
    u2 = np.repeat(uu[:, None], NCHAN, 1)
    v2 = np.repeat(vv[:, None], NCHAN, 1)
    acc.add(u2, v2, vis4, np.ones(u2.shape))
    vis, weight = acc.result()
    uv_vis = uvcube_dataset(vis, weight, FREQ, c, {
        "cell_lambda": cell, "uv_min_lambda": 30.0, "uv_max_lambda": 180.0,
        "fov_deg": np.degrees(1 / cell), "beam_area_sr": (1 / cell) ** 2})
    assert uv_img.attrs["beam_area_sr"] == pytest.approx(uv_vis.attrs["beam_area_sr"], rel=1e-9)
    ps_img = power_spectrum(transform(uv_img))
    ps_vis = power_spectrum(transform(uv_vis))
    np.testing.assert_allclose(ps_img["k_perp"], ps_vis["k_perp"], rtol=1e-12)
    np.testing.assert_allclose(ps_img["k_par"], ps_vis["k_par"], rtol=1e-12)
    for name in ("power", "power_jy2", "power_1d"):
        a, b = ps_img[name].sel(stokes=["Q", "P"]).values, ps_vis[name].sel(stokes=["Q", "P"]).values
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12 * np.nanmax(b))
    np.testing.assert_array_equal(ps_img["counts"], ps_vis["counts"])


def test_image_units_kelvin_and_jy_per_beam():
    from msleak.ps.image import beam_solid_angle, to_jy_per_pixel

    pix = 1e-6
    t = np.ones((2, 3, 3))
    freq = np.array([150e6, 160e6])
    got = to_jy_per_pixel(t, "K", freq, pix)
    expect = 2 * 1.380649e-23 * freq ** 2 / 299792458.0 ** 2 * pix / 1e-26
    np.testing.assert_allclose(got[:, 0, 0], expect, rtol=1e-12)
    beam = beam_solid_angle(0.1, 0.1)
    np.testing.assert_allclose(to_jy_per_pixel(t, "Jy/beam", freq, pix, beam), pix / beam)
    with pytest.raises(InputError, match="unit"):
        to_jy_per_pixel(t, "W/m2", freq, pix)


def test_cli_image_pipeline_and_plot(tmp_path):
    n = 32
    path = _write_cube(tmp_path / "i.fits", _sky(n), np.degrees(1 / (n * 16.0)), bunit="K")
    r = _run("grid", "--image", path, "-o", tmp_path / "g.h5")
    assert r.exit_code == 0, r.output
    r = _run("transform", tmp_path / "g.h5", "-o", tmp_path / "d.h5", "--window", "hann")
    assert r.exit_code == 0, r.output
    r = _run("ps", tmp_path / "d.h5", "-o", tmp_path / "p.h5", "--plot", tmp_path / "p.png")
    assert r.exit_code == 0, r.output
    ps = xr.open_dataset(tmp_path / "p.h5", engine="h5netcdf")
    assert ps.attrs["msleak_product"] == "ps" and ps["power"].attrs["units"] == "mK^2 Mpc^3"
    assert list(ps["stokes"].values) == ["I", "Q", "U", "V", "P"]
    assert ps["power3d"].dims == ("stokes", "delay3d", "cell")
    assert (tmp_path / "p.png").stat().st_size > 10_000
    from msleak.plot.ps import plot_ps1d

    assert plot_ps1d([(tmp_path / "p.h5", "a")], tmp_path / "one.png", stokes=["I"]).exists()


def test_cli_ms_pipeline(small_lofar_ms, tmp_path):
    r = _run("grid", small_lofar_ms, "--uv-range", "10,400", "--split", "even-odd",
             "-o", tmp_path / "g.h5")
    assert r.exit_code == 0, r.output
    g = xr.open_dataset(tmp_path / "g.h5", engine="h5netcdf")
    assert g["vis"].dims == ("stokes", "freq", "v", "u") and "vis_a" in g
    assert g.attrs["column"] == "DATA" and (g["weight"].values > 0).any()
    r = _run("transform", tmp_path / "g.h5", "-o", tmp_path / "d.h5",
             "--partial", "zero")
    assert r.exit_code == 0, r.output
    r = _run("ps", tmp_path / "d.h5", "-o", tmp_path / "p.h5")
    assert r.exit_code == 0, r.output
    ps = xr.open_dataset(tmp_path / "p.h5", engine="h5netcdf")
    assert ps.attrs["cross_power"] == 1


def _flag_all(ms):
    import casacore.tables as pt

    with pt.table(str(ms), readonly=False, ack=False) as t:
        f = t.getcol("FLAG")
        f[:] = True
        t.putcol("FLAG", f)


@pytest.mark.parametrize("case, pattern", [
    ("column", "no column 'NOPE_DATA'"),
    ("uvrange", "no unflagged sample has a baseline"),
    ("flagged", "are flagged"),
])
def test_cli_ms_errors(small_lofar_ms, tmp_path, case, pattern):
    import msleak

    args = ["grid", small_lofar_ms, "-o", tmp_path / "g.h5"]
    kwargs = {}
    if case == "column":
        args += ["--column", "NOPE_DATA"]
        kwargs["column"] = "NOPE_DATA"
    elif case == "uvrange":
        args += ["--uv-range", "100000,200000"]
        kwargs["uv_range"] = (1e5, 2e5)
    else:
        _flag_all(small_lofar_ms)
    r = _run(*args)
    assert r.exit_code == 2
    assert pattern in r.output and len(r.output.strip().splitlines()) == 1
    with pytest.raises(InputError, match=pattern):
        msleak.grid(small_lofar_ms, **kwargs)


def test_cli_image_without_freq_axis(tmp_path):
    from msleak.verbs.images import grid_image

    path = _write_cube(tmp_path / "nofreq.fits", _sky(), 0.1, freq_axis=False)
    r = _run("grid", "--image", path, "-o", tmp_path / "g.h5")
    assert r.exit_code == 2 and "no FREQ axis" in r.output
    assert len(r.output.strip().splitlines()) == 1
    with pytest.raises(InputError, match="no FREQ axis"):
        grid_image([path])


@pytest.mark.parametrize("args, pattern", [
    (["grid", "-o", "x.h5"], "either an MS or --image"),
    (["grid", "some.ms", "--uv-range", "180,30", "-o", "x.h5"], "empty range"),
    (["grid", "missing.ms", "-o", "x.h5"], "no such Measurement Set"),
    (["transform", "missing.h5", "-o", "x.h5"], "missing.h5 does not exist"),
    (["ps", "missing.h5", "-o", "x.h5", "--cosmology", "Planck18"], "missing.h5 does not exist"),
])
def test_cli_usage_errors(tmp_path, args, pattern):
    r = _run(*args)
    assert r.exit_code == 2 and pattern in r.output


def test_cli_wrong_product_kind(tmp_path):
    path = _write_cube(tmp_path / "i.fits", _sky(), np.degrees(1 / (32 * 16.0)))
    assert _run("grid", "--image", path, "-o", tmp_path / "g.h5").exit_code == 0
    r = _run("ps", tmp_path / "g.h5", "-o", tmp_path / "p.h5")
    assert r.exit_code == 2 and "not a delay cube (transform product)" in r.output
    r = _run("ps", tmp_path / "g.h5", "-o", tmp_path / "p.h5", "--cosmology", "Nope")
    assert r.exit_code == 2
