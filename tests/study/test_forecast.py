"""``msleak forecast``: the EoR-window leakage against a hand computation, and the whole
forecast at test size through every telescope, its table against its own products."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import xarray as xr
from click.testing import CliRunner

from msleak.cli import cli
from msleak.io.products import open_product
from msleak.leakage.fraction import window_leakage


def _ps(p_i, p_p, counts, slope):
    k_par = np.array([0.0, 0.1, 0.2, 0.4])
    k_perp = np.array([0.01, 0.05, 0.1])
    power = np.stack([p_i, p_p])
    return xr.Dataset({"power_jy2": (("stokes", "k_par", "k_perp"), power),
                       "counts": (("k_par", "k_perp"), counts)},
                      coords={"stokes": ["I", "P"], "k_par": k_par, "k_perp": k_perp},
                      attrs={"wedge_slope_horizon": slope})


def test_window_leakage_by_hand():
    rng = np.random.default_rng(3)
    p_p = rng.uniform(1, 2, (4, 3))
    p_i = rng.uniform(0, 1e-4, (4, 3))
    counts = rng.integers(1, 5, (4, 3)).astype(float)
    counts[3, 0] = 0                       # an empty bin never counts
    ds = _ps(p_i, p_p, counts, slope=2.0)
    # above k_par = 2 k_perp: k_perp 0.01 -> k_par 0.1, 0.2 (0.4 is empty);
    # k_perp 0.05 -> 0.2, 0.4; k_perp 0.1 -> 0.4 (0.2 = 2 x 0.1 is on the line: out)
    def by_hand(cells):
        num = sum(counts[c] * p_i[c] for c in cells)
        return 100 * np.sqrt(num / sum(counts[c] * p_p[c] for c in cells))

    assert window_leakage(ds) == pytest.approx(
        by_hand([(1, 0), (2, 0), (2, 1), (3, 1), (3, 2)]), rel=1e-12)
    # steeper: k_par > 0.05, 0.25, 0.5 for the three k_perp
    assert window_leakage(_ps(p_i, p_p, counts, slope=5.0)) == pytest.approx(
        by_hand([(1, 0), (2, 0), (3, 1)]), rel=1e-12)
    assert np.isnan(window_leakage(_ps(p_i, p_p, counts, slope=1e3)))


APERTURE_M = {"lofar": 30.75, "ska-low": 38.0, "hera": 14.0, "mwa": 4.4}


def _read_csv(path):
    with open(path) as fh:
        return list(csv.DictReader(fh))


def test_forecast_quick_every_telescope(tmp_path):
    """The whole forecast at test size through the four telescopes: each table row is the
    mean and the scatter of its own leakage products, each MS holds the stations nearest
    its array's centre, and a rerun skips every step and gives the same table."""
    import casacore.tables as ct

    from msleak.telescope.observation import telescope_layout

    out = tmp_path / "fc"
    result = CliRunner().invoke(cli, ["forecast", str(out), "--quick", "--seeds", "2",
                                      "--telescopes", "lofar,ska-low,hera,mwa,hera"])
    assert result.exit_code == 0, result.output
    rows = {r["telescope"]: r for r in _read_csv(out / "forecast.csv")}
    assert list(rows) == ["lofar", "ska-low", "hera", "mwa"]      # the repeat counts once
    assert len(_read_csv(out / "forecast.csv")) == 4
    for tel, row in rows.items():
        leak = open_product(out / tel / "leakage" / "leakage.h5", "leakage")
        medians = leak["median"].values
        assert medians.size == 2
        assert float(row["median"]) == pytest.approx(medians.mean(), rel=1e-12)
        assert float(row["median_scatter"]) == pytest.approx(medians.std(ddof=1), rel=1e-9)
        windows = [window_leakage(open_product(out / tel / f"ps_s{s}.h5", "ps"))
                   for s in (2018, 2019)]
        assert float(row["window"]) == pytest.approx(np.mean(windows), rel=1e-12)
        assert 0 < float(row["median"]) < 100
        # one aperture (30.75, 38, 14, 4.4 m) per uv cell at the band centre, and the
        # study's 30-180 wavelengths in units of 16-wavelength cells
        grid = open_product(out / tel / "grid_s2018.h5", "uvcube")
        centre = grid["freq"].values.mean()
        cell = APERTURE_M[tel] * centre / 299_792_458.0
        assert grid.attrs["cell_lambda"] == pytest.approx(cell, rel=1e-5)
        assert grid.attrs["uv_min_lambda"] == pytest.approx(30 * cell / 16, rel=1e-5)
        assert grid.attrs["uv_max_lambda"] == pytest.approx(180 * cell / 16, rel=1e-5)
        lay = telescope_layout(tel)
        dist = np.linalg.norm(lay.positions - lay.positions.mean(axis=0), axis=1)
        nearest = {lay.names[i] for i in np.argsort(dist)[:8]}
        with ct.table(str(out / tel / f"{tel}.ms" / "ANTENNA"), ack=False) as t:
            assert set(t.getcol("NAME")) == nearest
    assert "HERA" in (out / "forecast.md").read_text()
    assert (out / "figures" / "forecast.png").stat().st_size > 0
    before = (out / "forecast.csv").read_text()
    again = CliRunner().invoke(cli, ["forecast", str(out), "--quick", "--seeds", "2",
                                     "--telescopes", "lofar,ska-low,hera,mwa"])
    assert again.exit_code == 0, again.output
    assert (out / "forecast.csv").read_text() == before
    commands = [line for line in (out / "forecast.md").read_text().splitlines()
                if line.startswith("msleak ")]
    assert commands and all(line.endswith("# up to date, skipped") for line in commands)


def test_forecast_refuses_unknown_telescope(tmp_path):
    result = CliRunner().invoke(cli, ["forecast", str(tmp_path / "x"), "--telescopes",
                                      "lofar,vla"])
    assert result.exit_code == 2
    assert "'vla' is not a telescope" in result.output


@pytest.mark.parametrize("args,message", [
    (["--quick", "--interval", "0"], "--duration (0.2 h) and --interval (0.0 s) must be positive"),
    (["--quick", "--duration", "0.01"], "the duration at least one interval"),
    (["--quick", "--nchan", "300"], "do not fit HERA's beam file (100-145 MHz)"),
])
def test_forecast_refuses_bad_settings_before_any_work(tmp_path, args, message):
    out = tmp_path / "x"
    result = CliRunner().invoke(cli, ["forecast", str(out), *args])
    assert result.exit_code == 2
    assert message in result.output
    assert not (out / "sky").exists()


def test_quick_keeps_the_settings_given():
    from msleak.study.forecast import ForecastConfig

    cfg = ForecastConfig(outdir="x", quick=True, nchan=12)
    assert (cfg.nchan, cfg.stations, cfg.seeds) == (12, 8, 2)
    assert ForecastConfig(outdir="x").stations == 48


def test_predicts_in_double_unless_no_double(tmp_path):
    """The forecast's predicts run in complex128 arithmetic into complex128 columns by
    default (complex64 rounding sets P_I of the faintest voxels, docs/leakage.md);
    --no-double drops both."""
    from msleak.study.forecast import ForecastConfig, forecast_steps

    for double in (True, False):
        cfg = ForecastConfig(outdir=tmp_path / "f", telescopes=("lofar",), quick=True,
                             double=double)
        predicts = [s.args for s in forecast_steps(cfg) if s.args[0] == "predict"]
        assert len(predicts) == 1
        assert ("--double" in predicts[0]) == ("--double-column" in predicts[0]) == double
    result = CliRunner().invoke(cli, ["forecast", "--help"])
    text = " ".join(result.output.split())           # as click wraps it for the terminal
    assert "--double / --no-double" in text and "[default: double]" in text
