"""Placeholder ANTENNA rows, as CASA and pyuvdata write them (never in the main table,
FLAG_ROW set, at the origin with DISH_DIAMETER 0), change nothing: on an MS built by
tests/casa_ms.py with a zenith phase centre, ``msleak beam``, ``msleak predict`` and
``msleak grid`` (+ transform, ps) give exactly what they give on the same MS without
placeholders, with no Python warning, and the diameter check concerns the used antennas
only. The known answers: the placeholder-free MS's products, the phase-centre identities
of a corrected beam (0 dB polarized beam, zero leakage) and equal diameters giving equal
results.
"""

from __future__ import annotations

import logging
import shutil
import warnings

import numpy as np
import pytest
import xarray as xr
from click.testing import CliRunner

from casa_ms import MSSpec, MWA_ITRF, _gmst_rad, build_ms
from ms_helpers import table, write_sky
from msleak.cli import cli
from msleak.errors import InputError
from msleak.io.ms import column_names, read_used_antennas

PLACEHOLDERS = ("unused", "flagged", "origin")
NUSED = len(MSSpec().enu)


def _zenith() -> tuple[float, float]:
    """(ra, dec) deg of the geocentric zenith of the MWA site at the middle integration."""
    spec = MSSpec()
    t_mid = spec.time0_s + spec.interval_s * (spec.ntime - 1) / 2
    lon = np.degrees(np.arctan2(MWA_ITRF[1], MWA_ITRF[0]))
    lat = np.degrees(np.arctan2(MWA_ITRF[2], np.hypot(MWA_ITRF[0], MWA_ITRF[1])))
    return float((np.degrees(_gmst_rad(t_mid)) + lon) % 360), float(lat)


RA0, DEC0 = _zenith()


def _run(args, expect=0):
    """The command line, with every Python warning an error; returns the click result."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = CliRunner().invoke(cli, [str(a) for a in args])
    assert result.exit_code == expect, (args, result.output, result.exception)
    return result


def _error_line(result) -> str:
    """The error line: the only line of an msleak error, the last of a click usage error."""
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert lines[-1].startswith(("msleak: error:", "Error:")), lines
    if lines[-1].startswith("msleak: error:"):
        assert len(lines) == 1, lines
    return lines[-1]


def _sky(path):
    ra, dec = np.radians(RA0), np.radians(DEC0)
    return write_sky(path, [(ra + 0.05, dec + 0.03, 1.0, 0.3, 0.2, 0.0),
                            (ra - 0.08, dec - 0.02, 2.0, -0.5, 0.1, 0.0),
                            (ra + 0.02, dec - 0.07, 0.5, 0.1, -0.3, 0.0)])


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """The same zenith MS without and with placeholder ANTENNA rows."""
    root = tmp_path_factory.mktemp("placeholders")
    plain = build_ms(root / "plain.ms", ra_deg=RA0, dec_deg=DEC0)
    ph = build_ms(root / "ph.ms", ra_deg=RA0, dec_deg=DEC0, placeholders=PLACEHOLDERS)
    return plain, ph


@pytest.fixture(scope="module")
def predicted(pair, tmp_path_factory):
    """Copies of ``pair`` with MODEL_DATA from ``msleak predict --beam dipole``."""
    root = tmp_path_factory.mktemp("predicted")
    sky = _sky(root / "sky.skymodel")
    out = []
    for ms in pair:
        dest = root / ms.name
        shutil.copytree(ms, dest)
        _run(["predict", dest, "--sky", sky, "--beam", "dipole"])
        out.append(dest)
    return out


def _read_product(path):
    with xr.open_dataset(path, engine="h5netcdf") as ds:
        return ds.load()


def _assert_same(a: xr.Dataset, b: xr.Dataset):
    assert sorted(a.data_vars) == sorted(b.data_vars)
    for name in a.data_vars:
        np.testing.assert_array_equal(a[name].values, b[name].values, err_msg=name)


def test_used_antennas_are_those_of_the_rows(pair):
    _, ph = pair
    with table(f"{ph}/ANTENNA") as t:
        assert t.nrows() == NUSED + len(PLACEHOLDERS)
        assert t.getcol("FLAG_ROW")[NUSED + 1]
        np.testing.assert_array_equal(t.getcol("POSITION")[NUSED + 2], 0.0)
    np.testing.assert_array_equal(read_used_antennas(ph), np.arange(NUSED))
    np.testing.assert_array_equal(read_used_antennas(ph, field_id=0, ddid=0), np.arange(NUSED))
    with pytest.raises(InputError, match="no rows for DATA_DESC_ID 1"):
        read_used_antennas(ph, ddid=1)


def test_beam_maps_ignore_placeholders(pair, tmp_path, caplog):
    caplog.set_level(logging.WARNING)
    products = []
    for ms in pair:
        product = tmp_path / f"{ms.stem}.h5"
        _run(["beam", ms, "-o", tmp_path / f"{ms.stem}.png", "--beam", "dipole",
              "--npix", 21, "--fov", 30, "--product", product])
        products.append(_read_product(product))
    plain, ph = products
    _assert_same(plain, ph)
    names = ",".join(f"Tile{k:03d}" for k in range(NUSED))
    assert plain.attrs["stations"] == ph.attrs["stations"] == names
    # a zenith transit at the middle time, and the identities of a corrected beam there
    assert np.abs(ph.hour_angle.values).max() < 0.05
    centre = tuple(int(c) for c in ph.attrs["centre_pixel"].split(","))
    np.testing.assert_allclose(ph.polarized_beam_db.values[:, centre[0], centre[1]], 0.0,
                               atol=1e-9)
    np.testing.assert_allclose(ph.leakage.values[:, centre[0], centre[1]], 0.0, atol=1e-12)
    assert ph.polarized_beam_db.values.max() < 1e-9
    assert np.all(np.isfinite(ph.mueller.values))
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]


def test_beam_of_one_station_ignores_placeholders(pair, tmp_path):
    products = []
    for ms in pair:
        product = tmp_path / f"{ms.stem}.h5"
        _run(["beam", ms, "-o", tmp_path / f"{ms.stem}.png", "--beam", "dipole",
              "--npix", 11, "--station", "Tile003", "--product", product])
        products.append(_read_product(product))
    _assert_same(*products)
    assert products[1].attrs["stations"] == "Tile003"
    refused = _run(["beam", pair[1], "-o", tmp_path / "x.png", "--beam", "dipole",
                    "--station", "Placeholder0"], expect=2)
    assert "not an antenna of the rows" in _error_line(refused)


def test_predict_ignores_placeholders(predicted):
    models = []
    for ms in predicted:
        with table(ms) as t:
            models.append(t.getcol("MODEL_DATA"))
    assert np.abs(models[0]).max() > 0.5
    np.testing.assert_array_equal(models[0], models[1])
    assert column_names(predicted[0]) == column_names(predicted[1])


def test_grid_beam_area_and_power_ignore_placeholders(predicted, tmp_path, caplog):
    caplog.set_level(logging.WARNING)
    out = {}
    for ms in predicted:
        grid, delay, ps = (tmp_path / f"{ms.stem}_{k}.h5" for k in ("grid", "delay", "ps"))
        _run(["grid", ms, "--column", "MODEL_DATA", "--uv-range", "1,200", "-o", grid])
        _run(["transform", grid, "-o", delay])
        _run(["ps", delay, "-o", ps])
        out[ms.stem] = (_read_product(grid), _read_product(ps))
    (grid0, ps0), (grid1, ps1) = out["plain"], out["ph"]
    # the MS's own dipole beam, not the Airy fallback
    assert grid0.attrs["beam_area_model"] == grid1.attrs["beam_area_model"] == "dipole"
    assert grid1.attrs["beam_area_sr"] == grid0.attrs["beam_area_sr"] > 0
    assert ps1.attrs["beam_area_sr"] == ps0.attrs["beam_area_sr"]
    _assert_same(grid0, grid1)
    _assert_same(ps0, ps1)
    assert np.nanmax(ps1.power.values) > 0
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]


def test_diameter_check_concerns_used_antennas(pair, predicted, tmp_path):
    """DISH_DIAMETER 0 on the used antennas (not only on the origin placeholder): the
    dipole beam is refused naming --diameter; --diameter 4.4 gives what the 4.4 m MS gives."""
    ms = build_ms(tmp_path / "nodiam.ms", ra_deg=RA0, dec_deg=DEC0, dish_diameter=0.0,
                  placeholders=PLACEHOLDERS)
    before = column_names(ms)
    line = _error_line(_run(["beam", ms, "-o", tmp_path / "b.png", "--beam", "dipole"],
                            expect=2))
    assert "Tile000" in line and "`--diameter M`" in line
    sky = _sky(tmp_path / "sky.skymodel")
    line = _error_line(_run(["predict", ms, "--sky", sky, "--beam", "dipole"], expect=2))
    assert "`--diameter M`" in line
    line = _error_line(_run(["grid", ms, "--beam-area-model", "dipole", "--uv-range", "1,200",
                             "-o", tmp_path / "g.h5"], expect=2))
    assert "`--beam-area-model airy`" in line and "`--beam-area SR`" in line
    assert "--diameter" not in line
    assert column_names(ms) == before and not (tmp_path / "g.h5").exists()
    line = _error_line(_run(["predict", ms, "--sky", sky, "--beam", "none",
                             "--diameter", "4.4"], expect=2))
    assert "--diameter" in line

    product = tmp_path / "given.h5"
    _run(["beam", ms, "-o", tmp_path / "given.png", "--beam", "dipole", "--diameter", 4.4,
          "--npix", 21, "--fov", 30, "--product", product])
    reference = tmp_path / "reference.h5"
    _run(["beam", pair[0], "-o", tmp_path / "reference.png", "--beam", "dipole",
          "--npix", 21, "--fov", 30, "--product", reference])
    _assert_same(_read_product(product), _read_product(reference))
    _run(["predict", ms, "--sky", _sky(tmp_path / "sky2.skymodel"), "--beam", "dipole",
          "--diameter", "4.4"])
    with table(ms) as t, table(predicted[0]) as r:
        np.testing.assert_array_equal(t.getcol("MODEL_DATA"), r.getcol("MODEL_DATA"))
