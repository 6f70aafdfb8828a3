"""Every user error of issue 10 through the command line: exit status 2, one line on
stderr starting ``msleak: error:`` (or click's ``Error:`` for usage errors), no
traceback, and nothing written into the MS. See docs/errors.md for the catalogue."""

from __future__ import annotations

import hashlib
import os
import shutil
import stat
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from msleak.cli import cli
from ms_helpers import phase_centre as _phase_centre, table as _table


def _sky(tmp, ms, name="sky.skymodel", flux="1.0, 0.3, 0.2, 0.0"):
    ra, dec = _phase_centre(ms)
    path = tmp / name
    path.write_text(f"format = Name, Type, Ra, Dec, I, Q, U, V\ns0, POINT, {ra!r}, {dec!r}, "
                    f"{flux}\n")
    return path


def _fits_sky(tmp, ms, name="sky.fits", freq_min=150e6, nchan=4, blank=False):
    from msleak.adapters.sky_fits import write_cube
    from msleak.sky.foreground import generate_foreground_cube

    ra, dec = _phase_centre(ms)
    cube = generate_foreground_cube(npix=8, fov_deg=3.0, freq_min_hz=freq_min, nchan=nchan,
                                    chan_width_hz=195312.5, phase_centre=(ra, dec), seed=1)
    path = tmp / name
    write_cube(cube, path, overwrite=True)
    if blank:   # a blanked pixel, as imagers write outside the primary beam
        from astropy.io import fits

        with fits.open(path, mode="update") as hdul:
            hdul[0].data.flat[7] = np.nan
    return path


def _digest(ms):
    out = hashlib.sha256()
    with _table(ms) as t:
        for c in ("DATA", "FLAG"):
            out.update(np.ascontiguousarray(t.getcol(c)).tobytes())
        out.update(" ".join(t.colnames()).encode())
    return out.hexdigest()


def _set_corr(ms, corr):
    with _table(f"{ms}/POLARIZATION", readonly=False) as t:
        t.putcell("CORR_TYPE", 0, np.array(corr, dtype=np.int32))


def _flag_all(ms):
    with _table(ms, readonly=False) as t:
        f = t.getcol("FLAG")
        f[:] = True
        t.putcol("FLAG", f)


def _truncate(path, keep):
    data = Path(path).read_bytes()
    Path(path).write_bytes(data[:keep])
    return path


def _read_only(ms):
    for p in [ms, *Path(ms).rglob("*")]:
        mode = p.stat().st_mode
        p.chmod(mode & ~(stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))


def _make_writable(ms):
    for p in [ms, *Path(ms).rglob("*")]:
        p.chmod(p.stat().st_mode | stat.S_IWUSR)


# Each case: (id, function(ms, tmp) -> argv, pattern expected in the one-line message)
def _cases():
    c = []

    def add(name, pattern):
        def deco(fn):
            c.append(pytest.param(fn, pattern, id=name))
            return fn
        return deco

    # --------------------------------------------------------- missing / non-MS paths
    @add("predict-missing-ms", "no such Measurement Set")
    def _(ms, tmp):
        return ["predict", tmp / "nope.ms", "--sky", _sky(tmp, ms), "--beam", "none"]

    @add("predict-file-not-ms", "is a text file, not a Measurement Set")
    def _(ms, tmp):
        (tmp / "file.ms").write_text("hello")
        return ["predict", tmp / "file.ms", "--sky", _sky(tmp, ms), "--beam", "none"]

    @add("grid-missing-ms", "no such Measurement Set")
    def _(ms, tmp):
        return ["grid", tmp / "nope.ms", "-o", tmp / "g.h5"]

    @add("grid-dir-not-ms", "not a Measurement Set")
    def _(ms, tmp):
        (tmp / "empty.ms").mkdir()
        return ["grid", tmp / "empty.ms", "-o", tmp / "g.h5"]

    @add("grid-incomplete-ms", "no FIELD subtable")
    def _(ms, tmp):
        shutil.rmtree(ms / "FIELD")
        return ["grid", ms, "-o", tmp / "g.h5"]

    @add("beam-missing-ms", "no such Measurement Set")
    def _(ms, tmp):
        return ["beam", tmp / "nope.ms", "-o", tmp / "b.png"]

    @add("predict-missing-sky", "does not exist")
    def _(ms, tmp):
        return ["predict", ms, "--sky", tmp / "nosky.fits", "--beam", "none"]

    # ------------------------------------------------------------- columns, CORR_TYPE
    @add("grid-no-such-column", "no column 'CORRECTED_DATA'")
    def _(ms, tmp):
        return ["grid", ms, "--column", "CORRECTED_DATA", "-o", tmp / "g.h5"]

    @add("predict-column-data-refused", "refusing to overwrite the DATA column")
    def _(ms, tmp):
        return ["predict", ms, "--sky", _sky(tmp, ms), "--beam", "none", "--column", "DATA"]

    @add("predict-metadata-column", "holds MS metadata")
    def _(ms, tmp):
        return ["predict", ms, "--sky", _sky(tmp, ms), "--beam", "none", "--column", "UVW"]

    @add("predict-bad-column-name", "invalid column name")
    def _(ms, tmp):
        return ["predict", ms, "--sky", _sky(tmp, ms), "--beam", "none", "--column", "MY-COL"]

    @add("predict-stokes-corr-types", "unsupported CORR_TYPE")
    def _(ms, tmp):
        _set_corr(ms, [1, 2, 3, 4])
        return ["predict", ms, "--sky", _sky(tmp, ms), "--beam", "none"]

    @add("grid-mixed-corr-types", "unsupported CORR_TYPE")
    def _(ms, tmp):
        _set_corr(ms, [9, 10, 11, 8])
        return ["grid", ms, "-o", tmp / "g.h5"]

    # ------------------------------------------------------- field / spw selection
    @add("predict-no-such-field", "no field 7")
    def _(ms, tmp):
        return ["predict", ms, "--sky", _sky(tmp, ms), "--beam", "none", "--field", "7"]

    @add("predict-no-such-field-name", "no field 'NCP'")
    def _(ms, tmp):
        return ["predict", ms, "--sky", _sky(tmp, ms), "--beam", "none", "--field", "NCP"]

    @add("predict-no-such-spw", "no spectral window 3")
    def _(ms, tmp):
        return ["predict", ms, "--sky", _sky(tmp, ms), "--beam", "none", "--spw", "3"]

    @add("grid-no-such-field", "FIELD_ID 4")
    def _(ms, tmp):
        return ["grid", ms, "--field", "4", "-o", tmp / "g.h5"]

    @add("grid-no-such-spw", "no spectral window 2")
    def _(ms, tmp):
        return ["grid", ms, "--spw", "2", "-o", tmp / "g.h5"]

    @add("grid-no-such-field-name", "no field named 'NOPE'")
    def _(ms, tmp):
        return ["grid", ms, "--field", "NOPE", "-o", tmp / "g.h5"]

    # ------------------------------------------------------------ flags and uv range
    @add("grid-all-flagged", "flagged")
    def _(ms, tmp):
        _flag_all(ms)
        return ["grid", ms, "-o", tmp / "g.h5"]

    @add("grid-uv-range-reversed", "--uv-range")
    def _(ms, tmp):
        return ["grid", ms, "--uv-range", "100,50", "-o", tmp / "g.h5"]

    @add("grid-uv-range-no-baselines", "widen --uv-range")
    def _(ms, tmp):
        return ["grid", ms, "--uv-range", "5000,6000", "-o", tmp / "g.h5"]

    @add("grid-uv-range-not-numbers", "not a comma-separated list")
    def _(ms, tmp):
        return ["grid", ms, "--uv-range", "a,b", "-o", tmp / "g.h5"]

    # --------------------------------------------------------------- sky problems
    @add("predict-sky-frequency-mismatch", "no sky channel")
    def _(ms, tmp):
        return ["predict", ms, "--sky", _fits_sky(tmp, ms, freq_min=160e6), "--beam", "none"]

    @add("predict-sky-nan-pixels", "NaN or infinite")
    def _(ms, tmp):
        return ["predict", ms, "--sky", _fits_sky(tmp, ms, blank=True), "--beam", "none"]

    @add("predict-skymodel-nan-flux", "not a finite number")
    def _(ms, tmp):
        return ["predict", ms, "--sky", _sky(tmp, ms, flux="nan, 0.3, 0.2, 0.0"),
                "--beam", "none"]

    @add("predict-skymodel-inf-flux", "not a finite number")
    def _(ms, tmp):
        return ["predict", ms, "--sky", _sky(tmp, ms, flux="1.0, inf, 0.2, 0.0"),
                "--beam", "none"]

    @add("predict-fits-truncated", "is truncated")
    def _(ms, tmp):
        return ["predict", ms, "--sky", _truncate(_fits_sky(tmp, ms), 7000), "--beam", "none"]

    @add("predict-fits-header-only", "not a readable FITS file")
    def _(ms, tmp):
        return ["predict", ms, "--sky", _truncate(_fits_sky(tmp, ms), 1000), "--beam", "none"]

    @add("sky-crop-truncated", "is truncated")
    def _(ms, tmp):
        return ["sky", "--crop", _truncate(_fits_sky(tmp, ms), 7000), "--fov", "1",
                tmp / "out.fits"]

    @add("grid-image-truncated", "is truncated")
    def _(ms, tmp):
        return ["grid", "--image", _truncate(_fits_sky(tmp, ms), 7000), "-o", tmp / "g.h5"]

    @add("predict-fov-negative", "--fov")
    def _(ms, tmp):
        return ["predict", ms, "--sky", _sky(tmp, ms), "--beam", "none", "--fov", "-3"]

    @add("predict-memory-limit", "not a memory size")
    def _(ms, tmp):
        return ["predict", ms, "--sky", _sky(tmp, ms), "--beam", "none",
                "--memory-limit", "lots"]

    # ---------------------------------------------------------- simulate sizes
    @add("simulate-duration-overflow", "time slots; at most")
    def _(ms, tmp):
        return ["simulate", tmp / "x.ms", "--stations", "CS001HBA*", "--duration", "1e308"]

    @add("simulate-no-disk-space", "not enough disk space for the Measurement Set")
    def _(ms, tmp):   # ~1e8 rows x 2000 channels: petabytes, refused before writing
        return ["simulate", tmp / "x.ms", "--duration", "2000", "--interval", "1",
                "--nchan", "2000"]

    @add("simulate-exists", "pass --overwrite")
    def _(ms, tmp):
        return ["simulate", ms, "--stations", "CS001HBA*", "--duration", "0.1"]

    # ---------------------------------------------------------- read-only MS
    @add("predict-read-only-ms", "read-only")
    def _(ms, tmp):
        _read_only(ms)
        return ["predict", ms, "--sky", _sky(tmp, ms), "--beam", "none"]

    return c


@pytest.mark.parametrize("make_args,pattern", _cases())
def test_ms_errors_one_line(small_lofar_ms, tmp_path, make_args, pattern):
    ms = small_lofar_ms
    args = [str(a) for a in make_args(ms, tmp_path)]
    before = _digest(ms) if (ms / "FIELD").exists() and os.access(ms, os.W_OK) else None
    try:
        result = CliRunner().invoke(cli, args)
    finally:
        _make_writable(ms)
    assert result.exit_code == 2, (args, result.output, result.exception)
    out = result.output.strip()
    assert "Traceback" not in out
    last = out.splitlines()[-1]
    assert last.startswith(("msleak: error:", "Error:")), out
    assert pattern in out, out
    if before is not None and (ms / "FIELD").exists():
        with _table(f"{ms}/POLARIZATION") as t:
            corr = list(t.getcell("CORR_TYPE", 0))
        if corr == [9, 10, 11, 12]:
            assert _digest(ms) == before, "a refused command changed the MS"
    assert not (tmp_path / "g.h5").exists()


# ---------------------------------------------------------- multiple fields and spws
def _two_fields(ms):
    """Copy FIELD row 0 to a second field 1 degree away; the second half of the rows
    observe it."""
    with _table(f"{ms}/FIELD", readonly=False) as t:
        t.addrows(1)
        for col in t.colnames():
            t.putcell(col, 1, t.getcell(col, 0))
        for col in ("PHASE_DIR", "DELAY_DIR", "REFERENCE_DIR"):
            if col in t.colnames():
                d = t.getcell(col, 1)
                d[..., 1] += np.radians(1.0)
                t.putcell(col, 1, d)
        t.putcell("NAME", 1, "OTHER")
    with _table(ms, readonly=False) as t:
        f = t.getcol("FIELD_ID")
        f[f.size // 2:] = 1
        t.putcol("FIELD_ID", f)


def test_multiple_fields_without_selection(small_lofar_ms, tmp_path):
    """Decided behaviour (docs/errors.md): predict without --field predicts every field
    (each about its own phase centre); grid without --field grids FIELD_ID 0 only (one
    phase centre per uv cube) and says which field it used; --field picks another."""
    import xarray as xr

    ms = small_lofar_ms
    _two_fields(ms)
    sky = _sky(tmp_path, ms)
    r = CliRunner().invoke(cli, ["predict", str(ms), "--sky", str(sky), "--beam", "none"])
    assert r.exit_code == 0, r.output
    with _table(ms) as t:
        model = t.getcol("MODEL_DATA")
        field = t.getcol("FIELD_ID")
    # the source is at field 0's centre: flat there, not at field 1's
    np.testing.assert_allclose(model[field == 0, :, 0], 1.3, atol=1e-5)
    assert np.abs(model[field == 1, :, 0] - 1.3).max() > 1e-3
    for fid in (0, 1):
        out = tmp_path / f"g{fid}.h5"
        args = ["grid", str(ms), "--column", "MODEL_DATA", "--uv-range", "1,200", "-o", str(out)]
        r = CliRunner().invoke(cli, args + (["--field", "1"] if fid else []))
        assert r.exit_code == 0, r.output
        with xr.open_dataset(out, engine="h5netcdf") as ds:
            assert ds.attrs["field_id"] == fid
            assert ds.attrs["field_name"] == ("OTHER" if fid else "3C196")


# ------------------------------------------------------------------ product files
@pytest.fixture(scope="module")
def products(tmp_path_factory, _small_lofar_ms_master):
    """A uv cube, delay cube and PS of the session MS (read only)."""
    from msleak.io.products import open_product, save_product
    from msleak.verbs.power import power_spectrum
    from msleak.verbs.transform import transform
    import msleak

    d = tmp_path_factory.mktemp("products")
    uv = msleak.grid(_small_lofar_ms_master, uv_range=(1.0, 200.0), gridder="cell")
    save_product(uv, d / "uv.h5", "uvcube", overwrite=False)
    dl = transform(open_product(d / "uv.h5", "uvcube"))
    save_product(dl, d / "delay.h5", "delay", overwrite=False)
    ps = power_spectrum(open_product(d / "delay.h5", "delay"))
    save_product(ps, d / "ps.h5", "ps", overwrite=False)
    return d


def _with_format(src, dst, fmt, version):
    import h5py

    shutil.copy(src, dst)
    with h5py.File(dst, "r+") as f:
        f.attrs["msleak_format"] = fmt
        f.attrs["msleak_version"] = version
    return dst


@pytest.mark.parametrize("command,kind", [("transform", "uv"), ("ps", "delay"),
                                          ("leakage", "ps")])
@pytest.mark.parametrize("fmt,version", [(99, "9.0"), (0, "0.0.1")], ids=["newer", "older"])
def test_product_from_other_version(products, tmp_path, command, kind, fmt, version):
    src = _with_format(products / f"{kind}.h5", tmp_path / f"{kind}.h5", fmt, version)
    out = ["-o", str(tmp_path / ("out" if command == "leakage" else "out.h5"))]
    r = CliRunner().invoke(cli, [command, str(src), *out])
    assert r.exit_code == 2, r.output
    last = r.output.strip().splitlines()[-1]
    assert last.startswith("msleak: error:") and f"product format {fmt}" in last
    assert "regenerate" in last and "Traceback" not in r.output


@pytest.mark.parametrize("command,kind", [("transform", "uv"), ("ps", "delay"),
                                          ("leakage", "ps")])
@pytest.mark.parametrize("damage", ["truncated", "garbage", "wrong-kind", "missing"])
def test_damaged_product(products, tmp_path, command, kind, damage):
    src = tmp_path / f"{kind}.h5"
    if damage == "truncated":
        _truncate(shutil.copy(products / f"{kind}.h5", src), 3000)
        pattern = "is a damaged or truncated HDF5 file ("
    elif damage == "garbage":
        src.write_bytes(b"\0" + os.urandom(4999))
        pattern = "is a binary file of an unknown format, not a"
    elif damage == "wrong-kind":
        other = {"uv": "ps", "delay": "uv", "ps": "delay"}[kind]
        shutil.copy(products / f"{other}.h5", src)
        pattern = "product), not a" if other != "ps" else "power-spectrum product, not a"
    else:
        pattern = "does not exist; make a"
    out = ["-o", str(tmp_path / ("out" if command == "leakage" else "out.h5"))]
    r = CliRunner().invoke(cli, [command, str(src), *out])
    assert r.exit_code == 2, r.output
    last = r.output.strip().splitlines()[-1]
    assert last.startswith(("msleak: error:", "Error:")) and "Traceback" not in r.output
    assert pattern in r.output, r.output


# what every product reader says of an input of the wrong kind: {p} is the input's path
_NEEDS = {"transform": "uv cube (grid product)", "ps": "delay cube (transform product)",
          "leakage": "power-spectrum product"}
_WRONG_INPUTS = {
    ("transform", "ms"): "{p} is a Measurement Set, not a uv cube (grid product); make one "
                         "with `msleak grid {p} -o grid.h5`",
    ("transform", "fits"): "{p} is a FITS file, not a uv cube (grid product); make one with "
                           "`msleak grid --image {p} -o grid.h5`",
    ("transform", "ps.h5"): "{p} is a power-spectrum product, not a uv cube (grid product); "
                            "make one with `msleak grid MS -o grid.h5`",
    ("transform", "text"): "{p} is a text file, not a uv cube (grid product); make one with "
                           "`msleak grid MS -o grid.h5`",
    ("transform", "missing"): "{p} does not exist; make a uv cube (grid product) with "
                              "`msleak grid MS -o grid.h5`",
    ("ps", "ms"): "{p} is a Measurement Set, not a delay cube (transform product); make one "
                  "with `msleak grid {p} -o grid.h5`, then `msleak transform grid.h5 -o "
                  "delay.h5`",
    ("ps", "fits"): "{p} is a FITS file, not a delay cube (transform product); make one with "
                    "`msleak grid --image {p} -o grid.h5`, then `msleak transform grid.h5 -o "
                    "delay.h5`",
    ("ps", "uv.h5"): "{p} is a uv cube (grid product), not a delay cube (transform product); "
                     "make one with `msleak transform {p} -o delay.h5`",
    ("ps", "ps.h5"): "{p} is a power-spectrum product, not a delay cube (transform product); "
                     "make one with `msleak transform grid.h5 -o delay.h5`",
    ("leakage", "ms"): "{p} is a Measurement Set, not a power-spectrum product; make one with "
                       "`msleak grid {p} -o grid.h5`, then `msleak transform grid.h5 -o "
                       "delay.h5`, then `msleak ps delay.h5 -o ps.h5`",
    ("leakage", "fits"): "{p} is a FITS file, not a power-spectrum product; make one with "
                         "`msleak grid --image {p} -o grid.h5`, then `msleak transform grid.h5 "
                         "-o delay.h5`, then `msleak ps delay.h5 -o ps.h5`",
    ("leakage", "delay.h5"): "{p} is a delay cube (transform product), not a power-spectrum "
                             "product; make one with `msleak ps {p} -o ps.h5`",
    ("leakage", "uv.h5"): "{p} is a uv cube (grid product), not a power-spectrum product; "
                          "make one with `msleak transform {p} -o delay.h5`, then `msleak ps "
                          "delay.h5 -o ps.h5`",
}


def _wrong_input(what, products, ms, tmp_path) -> Path:
    """An input of the kind ``what``: an MS, a FITS file, a text file, a missing path, or
    one of the ``products`` (uv.h5, delay.h5, ps.h5)."""
    if what == "ms":
        return Path(ms)
    if what == "fits":
        from astropy.io import fits

        fits.PrimaryHDU(np.zeros((2, 4, 4), np.float32)).writeto(tmp_path / "cube.fits")
        return tmp_path / "cube.fits"
    if what == "text":
        (tmp_path / "notes.txt").write_text("not a product\n")
        return tmp_path / "notes.txt"
    if what == "missing":
        return tmp_path / "missing.h5"
    return products / what


def _reader(command):
    """The library function behind ``command`` that opens its product input."""
    import msleak

    return {"transform": msleak.transform, "ps": msleak.power_spectrum,
            "leakage": msleak.leakage}[command]


@pytest.mark.parametrize("command,what", sorted(_WRONG_INPUTS))
def test_wrong_input_named_with_its_maker(products, _small_lofar_ms_master, tmp_path,
                                          command, what):
    """A product reader given an MS, a FITS cube, another product kind, a text file or a
    missing path says what it got and which command makes what it needs."""
    import re

    from msleak.errors import InputError

    src = _wrong_input(what, products, _small_lofar_ms_master, tmp_path)
    expected = _WRONG_INPUTS[command, what].format(p=src)
    with pytest.raises(InputError, match=f"^{re.escape(expected)}$"):
        _reader(command)(src)


@pytest.mark.parametrize("command,what", [(c, w) for c, w in sorted(_WRONG_INPUTS)
                                          if w in ("ms", "fits", "uv.h5", "delay.h5")])
def test_wrong_input_cli_one_line(products, _small_lofar_ms_master, tmp_path, command, what):
    """The same through the command line: exit status 2, the one line, no traceback."""
    src = _wrong_input(what, products, _small_lofar_ms_master, tmp_path)
    out = tmp_path / ("out" if command == "leakage" else "out.h5")
    r = CliRunner().invoke(cli, [command, str(src), "-o", str(out)])
    assert r.exit_code == 2, r.output
    assert r.output.strip().splitlines() == [
        "msleak: error: " + _WRONG_INPUTS[command, what].format(p=src)], r.output
    assert not out.exists()


_NOT_AN_MS = ("{p} {what}, not a Measurement Set (no casacore table there); give an MS, "
              "e.g. one `msleak simulate OUT.ms` makes")


@pytest.mark.parametrize("command", ["grid", "predict", "beam"])
@pytest.mark.parametrize("what, words", [("uv.h5", "is a uv cube (grid product)"),
                                         ("fits", "is a FITS file"),
                                         ("text", "is a text file")])
def test_ms_reader_names_what_it_got(products, _small_lofar_ms_master, tmp_path, command,
                                     what, words):
    """An MS reader given a product, a FITS cube or a text file says which it got."""
    src = _wrong_input(what, products, _small_lofar_ms_master, tmp_path)
    args = {"grid": ["-o", str(tmp_path / "g.h5")], "beam": ["-o", str(tmp_path / "b.png")],
            "predict": ["--sky", str(src), "--beam", "none"]}[command]
    r = CliRunner().invoke(cli, [command, str(src), *args])
    assert r.exit_code == 2, r.output
    assert r.output.strip().splitlines() == [
        "msleak: error: " + _NOT_AN_MS.format(p=src, what=words)], r.output


def test_nan_in_data_is_dropped_not_propagated(small_lofar_ms, tmp_path):
    """NaN/Inf visibilities in the MS (a bad correlator dump) get zero weight in grid:
    the grid is finite and equals the grid of the MS with those samples flagged."""
    import xarray as xr

    ms = small_lofar_ms
    rng = np.random.default_rng(2)
    with _table(ms, readonly=False) as t:
        shape = t.getcol("DATA").shape
        data = (rng.normal(size=shape) + 1j * rng.normal(size=shape)).astype(np.complex64)
        t.putcol("DATA", data)
    flagged = tmp_path / "flagged.ms"
    shutil.copytree(ms, flagged)
    bad = [(3, 1, 0), (10, 2, 3), (20, 0, 1)]
    with _table(ms, readonly=False) as t:
        d = t.getcol("DATA")
        d[bad[0]] = np.nan
        d[bad[1]] = np.inf
        d[bad[2]] = complex(np.nan, 1)
        t.putcol("DATA", d)
    with _table(flagged, readonly=False) as t:
        f = t.getcol("FLAG")
        for r_, c_, _ in bad:
            f[r_, c_, :] = True
        t.putcol("FLAG", f)
    grids = []
    for path, name in ((ms, "a"), (flagged, "b")):
        out = tmp_path / f"{name}.h5"
        r = CliRunner().invoke(cli, ["grid", str(path), "--gridder", "cell", "--uv-range",
                                     "1,200", "-o", str(out)])
        assert r.exit_code == 0, r.output
        with xr.open_dataset(out, engine="h5netcdf") as ds:
            grids.append(ds.load())
    assert np.all(np.isfinite(grids[0]["vis"]))
    np.testing.assert_allclose(grids[0]["vis"], grids[1]["vis"], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(grids[0]["weight"], grids[1]["weight"], rtol=1e-6)
