"""The ``msleak sky`` command: outputs, crop/export/plot modes and every user error."""

import numpy as np
import pytest
from astropy.io import fits
from click.testing import CliRunner

from msleak.cli import cli
from msleak.adapters.sky_fits import read_cube
from msleak.adapters.skymodel import read_skymodel

SMALL = ["--npix", "8", "--nchan", "4", "--ncells-los", "16", "--seed", "3"]


def run(*args):
    return CliRunner().invoke(cli, ["sky", *map(str, args)])


@pytest.fixture
def cube_path(tmp_path):
    out = tmp_path / "sky.fits"
    res = run(out, *SMALL, "--phase-centre", "123.4,48.2")
    assert res.exit_code == 0, res.output
    return out


def test_generate_writes_cube(cube_path):
    h = fits.getheader(cube_path)
    assert (h["NAXIS1"], h["NAXIS2"], h["NAXIS3"], h["NAXIS4"]) == (8, 8, 4, 2)
    assert h["CTYPE1"] == "RA---SIN" and h["CTYPE3"] == "FREQ" and h["CTYPE4"] == "STOKES"
    assert h["CRVAL4"] == 2 and h["BUNIT"] == "K"
    assert np.isclose(h["CRVAL1"], 123.4) and np.isclose(h["CRVAL2"], 48.2)
    assert h["CRVAL3"] == 150e6 and h["CDELT3"] == 195312.5
    assert h["HIERARCH MSLEAK SEED"] == 3
    assert h["HIERARCH MSLEAK P_NCELLS_LOS"] == 16


def test_same_seed_same_file_data(tmp_path, cube_path):
    other = tmp_path / "again.fits"
    assert run(other, *SMALL, "--phase-centre", "123.4,48.2").exit_code == 0
    assert np.array_equal(fits.getdata(other), fits.getdata(cube_path))


def test_crop_units_skymodel_plot(tmp_path, cube_path):
    out = tmp_path / "crop.fits"
    sm = tmp_path / "crop.skymodel"
    png = tmp_path / "crop.png"
    res = run("--crop", cube_path, "--crop-npix", "4", "--units", "Jy/pixel", out,
              "--skymodel", sm, "--plot", png, "--phase-centre", "0,90")
    assert res.exit_code == 0, res.output
    c = read_cube(out)
    assert c.npix == (4, 4) and c.units == "Jy/pixel"
    assert np.allclose(c.wcs.wcs.crval, [0.0, 90.0])
    files = sorted(tmp_path.glob("crop_ch*.skymodel"))
    assert len(files) == 4
    s = read_skymodel(files[2])
    assert len(s) == 16
    assert np.allclose(s.at_frequencies([c.freq[2]])[:, 0, 1], c.data[0, 2].ravel(),
                       rtol=1e-6)
    assert png.stat().st_size > 10_000


def test_single_channel_skymodel_and_fov_crop(tmp_path, cube_path):
    sm = tmp_path / "one.skymodel"
    res = run("--crop", cube_path, "--fov", "9", "--skymodel", sm, "--skymodel-channel", "1")
    assert res.exit_code == 0, res.output
    # 8 pixels of 15/8 deg: 9 deg -> 4.8 -> nearest even 4 pixels
    assert len(read_skymodel(sm)) == 16


def test_skymodel_input_fov_selection(tmp_path):
    sm = tmp_path / "in.skymodel"
    sm.write_text("format = Name, Type, Ra, Dec, I\n"
                  "a, POINT, 00:00:00, +89.00.00, 1\nb, POINT, 00:00:00, +80.00.00, 1\n")
    out = tmp_path / "sel.skymodel"
    res = run("--crop", sm, "--fov", "4", "--phase-centre", "0,90", "--skymodel", out)
    assert res.exit_code == 0, res.output
    assert read_skymodel(out).names == ("a",)


def write_nofreq(path):
    h = fits.Header()
    h["CTYPE1"], h["CTYPE2"], h["CTYPE3"] = "RA---SIN", "DEC--SIN", "VRAD"
    h["BUNIT"] = "K"
    fits.PrimaryHDU(data=np.ones((2, 3, 3), np.float32), header=h).writeto(path)
    return path


def write_nan(path):
    h = fits.Header()
    h["CTYPE1"], h["CTYPE2"], h["CTYPE3"] = "RA---SIN", "DEC--SIN", "FREQ"
    h["CDELT1"], h["CDELT2"], h["CRVAL3"], h["CDELT3"], h["BUNIT"] = -1, 1, 1.5e8, 1e5, "K"
    d = np.ones((2, 3, 3), np.float32)
    d[1, 1, 1] = np.nan
    fits.PrimaryHDU(data=d, header=h).writeto(path)
    return path


@pytest.mark.parametrize("case,match", [
    ("notfits", "neither a FITS cube nor a makesourcedb"),
    ("nofreq", "no FREQ axis"),
    ("nan", "NaN"),
    ("bigfov", "larger than the cube"),
    ("badline", "bad.skymodel:2:"),
    ("baddec", "outside -90..90"),
    ("exists", "exists"),
    ("genopt", "generation option"),
    ("nothing", "nothing to do"),
    ("badchan", "outside 0..3"),
])
def test_errors_exit_2(tmp_path, cube_path, case, match):
    out = tmp_path / "o.fits"
    if case == "notfits":
        p = tmp_path / "junk.fits"
        p.write_text("not a cube\n")
        args = ["--crop", p, "--skymodel", tmp_path / "x.skymodel"]
    elif case == "nofreq":
        args = ["--crop", write_nofreq(tmp_path / "nf.fits"), out]
    elif case == "nan":
        args = ["--crop", write_nan(tmp_path / "nan.fits"), out]
    elif case == "bigfov":
        args = ["--crop", cube_path, "--fov", "20", out]
    elif case == "badline":
        p = tmp_path / "bad.skymodel"
        p.write_text("format = Name, Type, Ra, Dec, I\na, POINT, 01:00:00, +1.00.00, x\n")
        args = ["--crop", p, "--skymodel", tmp_path / "x.skymodel"]
    elif case == "baddec":
        args = [out, *SMALL, "--phase-centre", "10,95"]
    elif case == "exists":
        args = [cube_path, *SMALL]
    elif case == "genopt":
        args = ["--crop", cube_path, "--nchan", "3", out]
    elif case == "nothing":
        args = ["--crop", cube_path]
    else:
        args = ["--crop", cube_path, "--skymodel", tmp_path / "x.skymodel",
                "--skymodel-channel", "7"]
    res = run(*args)
    assert res.exit_code == 2, res.output
    assert match in res.output
    msg = [line for line in res.output.splitlines() if "rror" in line]
    assert len(msg) >= 1


def test_physics_options_are_the_foreground_parameters():
    """One option per ForegroundParams field, under the field's name, with its default:
    the command and make_sky(params=...) generate the same cube by default."""
    from dataclasses import fields

    import click

    from msleak.sky.foreground import ForegroundParams

    options = {p.name: p for p in cli.get_command(click.Context(cli), "sky").params}
    for f in fields(ForegroundParams):
        option = options[f.name]
        default = option.type_cast_value(click.Context(cli), option.default)
        expected = f.default
        assert (tuple(default) if isinstance(expected, tuple) else default) == expected, f.name
