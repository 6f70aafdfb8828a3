"""The sky verb ``msleak.make_sky``, the sky Dataset and its FITS converters."""

import math

import numpy as np
import pytest
import xarray as xr
from astropy.io import fits
from click.testing import CliRunner

import msleak
from msleak.cli import cli
from msleak.errors import InputError
from msleak.adapters.sky_fits import cube_from_dataset, dataset_from_cube, read_cube, write_cube
from msleak.adapters.skymodel import read_skymodel
from msleak.sky.foreground import ForegroundParams
from msleak.verbs.sky import make_sky, read_sky, select_skymodel, skymodel_paths

SMALL = dict(npix=8, nchan=4, seed=3, params=ForegroundParams(ncells_los=16))
STEEP = dict(SMALL, params=ForegroundParams(ncells_los=16, b_index=3.2))
SMALL_CLI = ["--npix", "8", "--nchan", "4", "--ncells-los", "16", "--seed", "3"]


def run(*args):
    return CliRunner().invoke(cli, ["sky", *map(str, args)])


def cards(path):
    """Every header card as text but HISTORY and DATE (provenance of the run)."""
    return [str(c) for c in fits.getheader(path).cards if c.keyword not in ("HISTORY", "DATE")]


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """The same sky made by the CLI and by the verb (with and without output)."""
    d = tmp_path_factory.mktemp("sky")
    res = run(d / "cli.fits", *SMALL_CLI, "--phase-centre", "123.4,48.2", "--b-index", "3.2")
    assert res.exit_code == 0, res.output
    ds = make_sky(d / "api.fits", phase_centre=(123.4, 48.2), **STEEP)
    return d, ds


def test_verb_is_public():
    assert msleak.make_sky is make_sky


def test_verb_and_cli_write_the_same_file(made):
    d, _ = made
    assert cards(d / "api.fits") == cards(d / "cli.fits")
    assert np.array_equal(fits.getdata(d / "api.fits"), fits.getdata(d / "cli.fits"))


def test_returned_dataset_is_the_file(made):
    d, ds = made
    assert list(ds.data_vars) == ["Q", "U"] and ds["Q"].dims == ("freq", "y", "x")
    assert ds["Q"].dtype == np.float32 and ds["Q"].attrs["units"] == "K"
    data = fits.getdata(d / "cli.fits")                   # (stokes, freq, y, x)
    assert np.array_equal(ds["Q"].values, data[0]) and np.array_equal(ds["U"].values, data[1])
    assert np.array_equal(ds["freq"].values, 150e6 + np.arange(4) * 195312.5)
    header = fits.Header.fromstring(ds.attrs["fits_header"], sep="\n")
    assert header["MSLEAK SEED"] == 3 and header["MSLEAK P_B_INDEX"] == 3.2
    assert header["CRVAL1"] == 123.4 and header["CRVAL2"] == 48.2
    # return only: the same numbers
    again = make_sky(phase_centre=(123.4, 48.2), **STEEP)
    xr.testing.assert_identical(again, ds)


def test_dataset_fits_dataset_round_trip_is_exact(made, tmp_path):
    _, ds = made
    path = write_cube(cube_from_dataset(ds), tmp_path / "rt.fits")
    xr.testing.assert_identical(dataset_from_cube(read_cube(path)), ds)
    # and through the verb: crop=Dataset without changes writes and returns the same
    back = make_sky(tmp_path / "rt2.fits", crop=ds)
    xr.testing.assert_identical(back, ds)
    assert np.array_equal(fits.getdata(tmp_path / "rt2.fits"), fits.getdata(path))


def test_crop_of_a_dataset_equals_the_cli_crop(made, tmp_path):
    d, ds = made
    args = ["--crop-npix", "4", "--phase-centre", "0,90", "--units", "Jy/pixel"]
    res = run("--crop", d / "cli.fits", *args, tmp_path / "c.fits")
    assert res.exit_code == 0, res.output
    got = make_sky(crop=ds, crop_npix=4, phase_centre=(0, 90), units="Jy/pixel")
    xr.testing.assert_identical(got, dataset_from_cube(read_cube(tmp_path / "c.fits")))
    by_path = make_sky(crop=d / "cli.fits", crop_npix=4, phase_centre=(0, 90),
                       units="Jy/pixel")
    xr.testing.assert_identical(by_path, got)


def test_coordinates_are_sin_offsets_and_directions():
    # NCP, SIN: x = l = -(i - ref) pixel, y = m; ra = atan2(l, -m), dec = acos(|(l, m)|)
    npix, pix = 6, 2.0
    ds = make_sky(npix=npix, fov=npix * pix, nchan=1, params=ForegroundParams(ncells_los=4),
                  seed=1)
    ref = (npix - 1) / 2
    l_deg = -(np.arange(npix) - ref) * pix
    m_deg = (np.arange(npix) - ref) * pix
    assert np.allclose(ds["x"].values, l_deg, rtol=0, atol=1e-12)
    assert np.allclose(ds["y"].values, m_deg, rtol=0, atol=1e-12)
    l_, m_ = np.meshgrid(np.radians(l_deg), np.radians(m_deg))
    ra = np.degrees(np.arctan2(l_, -m_)) % 360
    dec = np.degrees(np.arccos(np.hypot(l_, m_)))
    assert np.abs(((ds["ra"].values - ra + 180) % 360) - 180).max() < 1e-9
    assert np.abs(ds["dec"].values - dec).max() < 1e-9
    assert ds["x"].attrs["units"] == "deg" and ds["freq"].attrs["units"] == "Hz"


def test_read_sky_takes_degrees(made):
    d, _ = made
    src = read_sky(d / "cli.fits", phase_centre=(123.4, 48.2))
    l_, m_, _ = src.lmn(math.radians(123.4), math.radians(48.2))
    y, x = np.mgrid[0:8, 0:8]
    pix = math.radians(15.0 / 8)
    assert np.abs(l_ + (x.ravel() - 3.5) * pix).max() < 1e-12
    assert np.abs(m_ - (y.ravel() - 3.5) * pix).max() < 1e-12


def test_skymodel_export_and_selection(made, tmp_path):
    _, ds = made
    sm = tmp_path / "s.skymodel"
    make_sky(crop=ds, skymodel=sm)
    paths = [p for _, p in skymodel_paths(sm, 4, None)]
    assert [p.name for p in paths] == [f"s_ch{k:03d}.skymodel" for k in range(4)]
    src = read_skymodel(paths[2])
    assert src.names[:2] == ("v000_000", "v000_001")
    # Q in Jy/pixel of channel 2 = the Jy/pixel cube's, to the 10 digits written
    jy = make_sky(crop=ds, units="Jy/pixel")
    assert np.allclose(src.stokes_ref[:, 1], jy["Q"].values[2].ravel(), rtol=1e-6, atol=0)
    # a makesourcedb file cut to 4 deg about the NCP keeps the source 1 deg away
    model = tmp_path / "in.skymodel"
    model.write_text("format = Name, Type, Ra, Dec, I\n"
                     "a, POINT, 00:00:00, +89.00.00, 1\nb, POINT, 00:00:00, +80.00.00, 1\n")
    kept = select_skymodel(model, tmp_path / "sel.skymodel", fov=4, phase_centre=(0, 90))
    assert kept.names == ("a",) and read_skymodel(tmp_path / "sel.skymodel").names == ("a",)


def test_errors(made, tmp_path):
    d, ds = made
    cases = [
        (lambda: make_sky(crop=ds, nchan=3), "nchan is a generation option"),
        (lambda: make_sky(d / "api.fits", **SMALL), "exists; choose another name or pass "
                                                    "overwrite"),
        (lambda: make_sky(phase_centre=(10, 95), **SMALL), "declination 95.0 deg is outside"),
        (lambda: make_sky(crop=ds, fov=4, crop_npix=4), "give fov or crop_npix, not both"),
        (lambda: make_sky(crop=ds, skymodel=tmp_path / "x.skymodel", skymodel_channel=4),
         "skymodel_channel 4 is outside 0..3"),
        (lambda: cube_from_dataset(ds.drop_attrs()), "no fits_header attribute"),
        (lambda: cube_from_dataset(ds.drop_vars(["Q", "U"])), "no Stokes variable"),
        (lambda: cube_from_dataset(ds.where(ds.x > 0)), "NaN or infinite values"),
        (lambda: select_skymodel(d / "cli.fits", tmp_path / "y.skymodel"), "is a FITS cube"),
    ]
    model = tmp_path / "m.skymodel"
    model.write_text("format = Name, Type, Ra, Dec, I\na, POINT, 00:00:00, +89.00.00, 1\n")
    cases += [
        (lambda: make_sky(crop=model), "is not a FITS cube"),
        (lambda: read_sky(model, fov_deg=4), "fov_deg on a makesourcedb sky needs phase_centre"),
    ]
    for call, match in cases:
        with pytest.raises(InputError, match=match.replace("(", r"\(").replace(".", r"\.")):
            call()
    assert not (tmp_path / "x.skymodel").exists()


def test_cli_refuses_an_existing_figure(made, tmp_path):
    d, _ = made
    png = tmp_path / "f.png"
    png.write_bytes(b"old")
    res = run("--crop", d / "cli.fits", "--plot", png)
    assert res.exit_code == 2 and "f.png exists; choose another name or pass --overwrite" in \
        res.output
    assert png.read_bytes() == b"old"
    res = run("--crop", d / "cli.fits", "--plot", png, "--overwrite")
    assert res.exit_code == 0, res.output
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_ell_tick_labels_do_not_overlap():
    from msleak.plot import new_figure
    from msleak.plot.sky import _angular_panel

    rng = np.random.default_rng(0)
    fig, ax = new_figure(figsize=(5.5, 4.6))
    p_map = rng.normal(size=(50, 50)) + 1j * rng.normal(size=(50, 50))
    _angular_panel(ax, p_map, math.radians(0.3), "K", 150.0)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    lo, hi = ax.get_xlim()
    boxes = [t.get_window_extent(renderer) for t in ax.get_xticklabels(minor=True)
             + ax.get_xticklabels() if t.get_text() and t.get_visible()
             and lo <= t.get_position()[0] <= hi]
    assert len(boxes) >= 3
    boxes.sort(key=lambda b: b.x0)
    assert all(a.x1 < b.x0 for a, b in zip(boxes, boxes[1:]))
