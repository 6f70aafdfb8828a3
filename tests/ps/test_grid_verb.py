"""The Python verb ``msleak.grid`` against ``msleak grid``, the MS selection (--field ID|NAME,
--spw), existing outputs, per-channel image stacks and the provenance of the uv cube.

MSs are built with tests/casa_ms.py, independently of ``msleak simulate``.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import casacore.tables as pt
import numpy as np
import pytest
from click.testing import CliRunner

import msleak
from casa_ms import build_ms
from ms_helpers import copy_spectral_window, phase_centre, write_sky
from msleak.cli import cli
from msleak.errors import InputError
from msleak.io.products import history_lines, open_product

UV = (1.0, 200.0)
DNU = 195312.5
FREQ0 = 150e6


def _random_data(ms, seed=0):
    rng = np.random.default_rng(seed)
    with pt.table(str(ms), readonly=False, ack=False) as t:
        d = t.getcol("DATA")
        t.putcol("DATA", rng.normal(size=d.shape) + 1j * rng.normal(size=d.shape))
        w = t.getcol("WEIGHT_SPECTRUM")
        t.putcol("WEIGHT_SPECTRUM", rng.uniform(0.5, 2.0, w.shape))
    return ms


@pytest.fixture(scope="module")
def random_ms(tmp_path_factory):
    return _random_data(build_ms(tmp_path_factory.mktemp("verb") / "r.ms", ntime=6, nchan=4))


def _invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _one_line_error(result, pattern):
    assert result.exit_code == 2, (result.output, result.exception)
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("msleak: error:"), result.output
    assert pattern in lines[0], lines[0]


@pytest.mark.parametrize("gridder", ["cell", "wgrid"])
def test_verb_equals_cli(random_ms, tmp_path, gridder):
    """The same options through the verb and the command give the same cube (exact), and
    the verb returns what it writes."""
    out = tmp_path / "cli.h5"
    r = _invoke("grid", random_ms, "--uv-range", "1,200", "--gridder", gridder, "-o", out)
    assert r.exit_code == 0, r.output
    from_cli = open_product(out, "uvcube")
    got = msleak.grid(random_ms, uv_range=UV, gridder=gridder)
    written = msleak.grid(random_ms, uv_range=UV, gridder=gridder, output=tmp_path / "v.h5")
    for name in ("vis", "weight", "u", "v", "freq"):
        np.testing.assert_array_equal(got[name].values, from_cli[name].values)
        np.testing.assert_array_equal(written[name].values, from_cli[name].values)
    assert written.attrs["history"] == open_product(tmp_path / "v.h5").attrs["history"]
    assert got["vis"].attrs["units"] == "Jy" and got["weight"].attrs["units"] == "1"
    assert got["freq"].attrs["units"] == "Hz"
    assert got["u"].attrs["units"] == got["v"].attrs["units"] == "1"
    assert from_cli.attrs["source"] == str(Path(random_ms).resolve())
    command = written.attrs["command"]
    assert command.startswith(f"msleak.grid({str(random_ms)!r}, output=")
    assert "uv_range=(1.0, 200.0)" in command
    assert (f"gridder={gridder!r}" in command) == (gridder != "wgrid")  # defaults left out
    assert written.attrs["history"].endswith(command)


def _add_spectral_window(ms, shift_hz):
    """Append SPECTRAL_WINDOW row 1 (row 0 shifted by ``shift_hz``) and DATA_DESCRIPTION
    row 1; then make row 0 (the main table's) name spectral window 1 and row 1 name 0."""
    copy_spectral_window(ms, shift_hz)
    with pt.table(f"{ms}/DATA_DESCRIPTION", readonly=False, ack=False) as t:
        t.addrows(1)
        t.putcol("SPECTRAL_WINDOW_ID", np.array([1, 0], np.int32))
        t.putcol("POLARIZATION_ID", np.array([0, 0], np.int32))


def test_spw_is_looked_up_and_field_taken_by_name(random_ms, tmp_path):
    """--spw 1 selects the rows of the DATA_DESCRIPTION row naming spectral window 1 (here
    DATA_DESC_ID 0, 10 MHz higher); --field TARGET is FIELD_ID 0."""
    ms = tmp_path / "spw.ms"
    shutil.copytree(random_ms, ms)
    _add_spectral_window(ms, 10e6)
    by_name = msleak.grid(ms, uv_range=UV, gridder="cell", field="TARGET", spw=1)
    by_id = msleak.grid(ms, uv_range=UV, gridder="cell", field=0, spw="1")
    np.testing.assert_array_equal(by_name["vis"].values, by_id["vis"].values)
    np.testing.assert_allclose(by_name["freq"].values, FREQ0 + 10e6 + DNU * np.arange(4),
                               rtol=0, atol=1e-3)
    assert (by_name.attrs["spw_id"], by_name.attrs["ddid"], by_name.attrs["field_id"]) == (1, 0, 0)
    with pytest.raises(InputError, match="no cross-correlation rows for field 0, spectral "
                                         "window 0; choose others with `field`, `spw`"):
        msleak.grid(ms, uv_range=UV, gridder="cell", spw=0)
    _one_line_error(_invoke("grid", ms, "--spw", "5", "-o", tmp_path / "g.h5"),
                    "no spectral window 5 in the DATA_DESCRIPTION table (spectral windows: "
                    "0, 1); give one with --spw")
    _one_line_error(_invoke("grid", ms, "--field", "NOPE", "-o", tmp_path / "g.h5"),
                    "no field named 'NOPE' (fields: 0:TARGET); give --field ID or NAME")
    _one_line_error(_invoke("grid", ms, "--spw", "x", "-o", tmp_path / "g.h5"),
                    "--spw 'x' is not a spectral-window id")
    assert not (tmp_path / "g.h5").exists()


def test_existing_output_is_refused_before_any_work(random_ms, tmp_path, monkeypatch):
    from msleak.verbs import grid_tasks

    out = tmp_path / "g.h5"
    out.write_text("keep me")

    def no_gridding(*args, **kwargs):
        raise AssertionError("a chunk was gridded")

    monkeypatch.setattr(grid_tasks, "_grid_task", no_gridding)
    _one_line_error(_invoke("grid", random_ms, "-o", out),
                    f"{out} exists; choose another name or pass --overwrite")
    with pytest.raises(InputError, match="exists; choose another name or pass overwrite"):
        msleak.grid(random_ms, output=out)
    assert out.read_text() == "keep me"
    monkeypatch.undo()
    r = _invoke("grid", random_ms, "--uv-range", "1,200", "--gridder", "cell", "-o", out,
                "--overwrite")
    assert r.exit_code == 0, r.output
    assert open_product(out, "uvcube").attrs["gridder"] == "cell"


def test_verb_outputs_pair_with_columns(random_ms, tmp_path):
    with pytest.raises(InputError, match="2 columns but 1 outputs given"):
        msleak.grid(random_ms, column=["DATA", "WEIGHT_SPECTRUM"], output=tmp_path / "a.h5")
    with pytest.raises(InputError, match="column DATA is given twice"):
        msleak.grid(random_ms, column=["DATA", "DATA"])


@pytest.mark.parametrize("kwargs, message", [
    (dict(image="x.fits", output=["a.h5", "b.h5"]),
     "image makes one uv cube but 2 outputs are given; give one"),
    (dict(), "give either a Measurement Set or image (not both)"),
    (dict(cell=-1.0), "cell must be a positive number of wavelengths, got -1.0"),
    (dict(uv_range=(30.0,)), "uv_range needs MIN,MAX (wavelengths)"),
    (dict(uv_range=(180.0, 30.0)), "uv_range 180,30: empty range"),
    (dict(beam_area_model="gauss"), "unknown beam_area_model 'gauss': use auto, "
                                    "everybeam, dipole, airy"),
    (dict(gridder="fft"), "unknown gridder 'fft': use 'wgrid' or 'cell'"),
    (dict(split="odd"), "unknown split 'odd': use even-odd or first-second"),
    (dict(chunk_rows=0), "chunk_rows must be positive"),
    (dict(epsilon=float("nan")), "epsilon must be a relative accuracy between 0 and 1, "
                                 "got nan"),
    (dict(epsilon=0.0), "epsilon must be a relative accuracy between 0 and 1, got 0"),
    (dict(epsilon=1.0), "epsilon must be a relative accuracy between 0 and 1, got 1"),
    (dict(epsilon=1e-15), "epsilon 1e-15: this ducc0's gridder has no kernel this "
                          "accurate"),
])
def test_verb_option_errors(random_ms, kwargs, message):
    """Each refused before any MS row is read (one line, naming the parameters)."""
    ms = None if "image" in kwargs or not kwargs else random_ms
    with pytest.raises(InputError) as err:
        msleak.grid(ms, **kwargs)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_stokes_of_images_must_share_channels(channel_images, tmp_path):
    whole, per_channel = channel_images
    u_short = [p for p in per_channel if "-U-" in p.name and "0005" not in p.name]
    q_all = [p for p in per_channel if "-Q-" in p.name]
    with pytest.raises(InputError, match="the images give Stokes U other channels than "
                                         "Stokes Q; give every Stokes parameter the same"):
        msleak.grid(image=q_all + u_short)
    with pytest.raises(InputError, match="stokes 'Q,X': use I, Q, U or V"):
        msleak.grid(image=whole, stokes="Q,X")


# ---------------------------------------------------------------- per-channel images
def _write_image(path, planes, stokes_code, freq0, dl_deg=0.1, dfreq=DNU):
    """(chan, y, x) Jy/pixel -> FITS with RA---SIN, DEC--SIN, FREQ, STOKES axes, as WSClean
    writes them."""
    from astropy.io import fits

    n = planes.shape[-1]
    hdr = fits.Header()
    hdr["CTYPE1"], hdr["CRPIX1"], hdr["CRVAL1"], hdr["CDELT1"] = "RA---SIN", n / 2 + 1, 10.0, -dl_deg
    hdr["CTYPE2"], hdr["CRPIX2"], hdr["CRVAL2"], hdr["CDELT2"] = "DEC--SIN", n / 2 + 1, 50.0, dl_deg
    hdr["CTYPE3"], hdr["CRPIX3"], hdr["CRVAL3"], hdr["CDELT3"] = "FREQ", 1, freq0, dfreq
    hdr["CTYPE4"], hdr["CRPIX4"], hdr["CRVAL4"], hdr["CDELT4"] = "STOKES", 1, stokes_code, 1
    hdr["BUNIT"] = "JY/PIXEL"
    fits.PrimaryHDU(data=planes[None], header=hdr).writeto(path)
    return path


@pytest.fixture
def channel_images(tmp_path):
    """Q and U cubes (6 channels) written whole and as WSClean per-channel images."""
    rng = np.random.default_rng(5)
    nchan = 6
    freq = FREQ0 + DNU * np.arange(nchan)
    cubes = {s: rng.normal(size=(nchan, 32, 32)) for s in "QU"}
    whole = [_write_image(tmp_path / f"cube-{s}.fits", cubes[s], code, freq[0])
             for s, code in (("Q", 2), ("U", 3))]
    (tmp_path / "wsclean").mkdir()
    per_channel = [_write_image(tmp_path / "wsclean" / f"obs-{k:04d}-{s}-image.fits",
                                cubes[s][k:k + 1], code, freq[k])
                   for k in range(nchan) for s, code in (("Q", 2), ("U", 3))]
    return whole, per_channel


def test_per_channel_images_stack_to_the_cube(channel_images, tmp_path):
    """Per-channel images, in any order or as a glob, give exactly the uv cube of the
    whole cubes; `msleak grid --image GLOB` the same."""
    whole, per_channel = channel_images
    ref = msleak.grid(image=whole, fov=3.0)
    order = np.random.default_rng(2).permutation(len(per_channel))
    for images in ([per_channel[k] for k in order], per_channel[::-1],
                   str(tmp_path / "wsclean" / "obs-*-image.fits")):
        got = msleak.grid(image=images, fov=3.0)
        np.testing.assert_array_equal(got["vis"].values, ref["vis"].values)
        np.testing.assert_array_equal(got["freq"].values, ref["freq"].values)
    out = tmp_path / "g.h5"
    r = _invoke("grid", "--image", tmp_path / "wsclean" / "obs-*-[QU]-image.fits",
                "--fov", "3", "-o", out)
    assert r.exit_code == 0, r.output
    np.testing.assert_array_equal(open_product(out)["vis"].values, ref["vis"].values)
    assert open_product(out).attrs["source"].split("; ")[0] == str(per_channel[0])


def test_per_channel_image_errors(channel_images, tmp_path):
    _, per_channel = channel_images
    odd = tmp_path / "odd-0003-Q-image.fits"
    _write_image(odd, np.zeros((1, 32, 32)), 2, FREQ0 + 3 * DNU, dl_deg=0.11)
    images = [p for p in per_channel if "0003-Q" not in p.name] + [odd]
    _one_line_error(_invoke("grid", *sum((["--image", p] for p in images), []), "-o",
                            tmp_path / "g.h5"),
                    f"{odd}: pixel grid (size, increments, reference pixel or direction) "
                    f"differs from {images[0]}'s")
    twice = tmp_path / "again-0002-U-image.fits"
    shutil.copy(per_channel[2 * 2 + 1], twice)
    with pytest.raises(InputError, match=r"Stokes U at 150\.390625 MHz is also in"):
        msleak.grid(image=[*per_channel, twice])
    with pytest.raises(InputError, match="not evenly spaced"):
        msleak.grid(image=[p for p in per_channel if "0002" not in p.name])
    with pytest.raises(InputError, match="no file matches image"):
        msleak.grid(image=str(tmp_path / "none-*.fits"))


# ------------------------------------------------------------------------ provenance
def test_history_chain_holds_predict_then_grid(tmp_path):
    """A column written by `msleak predict` and gridded by `msleak grid` (separate
    processes, as a user runs them): the uv cube's history holds the predict command line
    (from the MS HISTORY), predict's provenance of the column, then the grid command."""
    ms = build_ms(tmp_path / "p.ms", ntime=4, nchan=3, ra_deg=253.0, dec_deg=0.0)
    ra, dec = phase_centre(ms)
    sky = write_sky(tmp_path / "s.skymodel", [(ra, dec, 1.0, 0.2, 0.1, 0.0)])
    exe = str(Path(sys.executable).parent / "msleak")
    predict = [exe, "predict", str(ms), "--sky", str(sky), "--beam", "none"]
    subprocess.run(predict, check=True, capture_output=True, cwd=tmp_path)
    grid = [exe, "grid", str(ms), "--column", "MODEL_DATA", "--uv-range", "1,200",
            "--gridder", "cell", "-o", str(tmp_path / "g.h5")]
    subprocess.run(grid, check=True, capture_output=True, cwd=tmp_path)
    chain = history_lines(open_product(tmp_path / "g.h5").attrs)
    at_predict = [k for k, line in enumerate(chain) if "msleak predict " + str(ms) in line]
    at_state = [k for k, line in enumerate(chain)
                if f"predict into {Path(ms).resolve()} column MODEL_DATA" in line]
    assert at_predict and at_state, chain
    assert chain[-1].endswith("msleak grid " + " ".join(grid[2:]))
    assert at_predict[0] < at_state[0] < len(chain) - 1


def test_rows_crossing_the_uv_range_are_counted(random_ms):
    """A row whose baseline is inside the uv range in some channels and outside in others
    (it enters or leaves the cube mid-band, a floor at high k_par, docs/ps.md) is counted
    in ``n_rows_crossing_uv_range``; the count is computed here from UVW and the channel
    frequencies (no sample of this MS is flagged)."""
    with pt.table(str(random_ms), ack=False) as t:
        uvw, a1, a2 = t.getcol("UVW"), t.getcol("ANTENNA1"), t.getcol("ANTENNA2")
    with pt.table(f"{random_ms}/SPECTRAL_WINDOW", ack=False) as t:
        freq = t.getcell("CHAN_FREQ", 0)
    length = np.hypot(uvw[:, 0], uvw[:, 1])[a1 != a2, None] * freq[None, :] / 299792458.0
    # a lower limit inside the band of a mid-length baseline: it crosses it
    mid = length[:, length.shape[1] // 2]
    lo = float(np.sort(mid)[mid.size // 2]) - 1e-9
    inside = (length >= lo) & (length <= 200.0)
    expected = int(np.count_nonzero(inside.any(axis=1) & ~inside.all(axis=1)))
    assert expected > 0
    cube = msleak.grid(random_ms, uv_range=(lo, 200.0), gridder="cell")
    assert cube.attrs["n_rows_crossing_uv_range"] == expected
    assert msleak.grid(random_ms, uv_range=UV, gridder="cell").attrs[
        "n_rows_crossing_uv_range"] == np.count_nonzero(
            ((length >= 1) & (length <= 200)).any(axis=1)
            & ~((length >= 1) & (length <= 200)).all(axis=1))
