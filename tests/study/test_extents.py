"""``msleak forecast --extents``: the all-sky skies within each extent, their table against
their own products, and the spectrum of the sky beyond 15 deg against a prediction of
exactly those pixels (gridding and the delay transform are linear)."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from click.testing import CliRunner

from msleak.cli import cli
from msleak.errors import InputError
from msleak.study.extents import beyond_ps, extent_label
from msleak.study.forecast import ForecastConfig, extent_run, forecast_steps


def test_extent_steps_and_settings(tmp_path):
    cfg = ForecastConfig(outdir=tmp_path, telescopes=("lofar",), quick=True, seeds=1,
                         extents=(90, 15, 4))
    assert cfg.extents == (4.0, 15.0, 90.0) and cfg.nside == 16
    steps = {s.name: s for s in forecast_steps(cfg)}
    predict = [str(a) for a in steps["predict-lofar-extents"].args]
    assert predict.count("--extent") == 3 and "15" in predict
    allsky = [str(a) for a in steps[f"allsky-allsky_s{cfg.seed}_150MHz"].args]
    assert allsky[2:4] == ["--healpix", "16"]
    assert extent_label(7.5) == "e7p5"
    for bad in (dict(extents=(0,)), dict(extents=(200,)), dict(extents=(15,), nside=12)):
        with pytest.raises(InputError):
            ForecastConfig(outdir=tmp_path, telescopes=("lofar",), quick=True, **bad)


def test_forecast_extents_and_the_sky_beyond_15_deg(tmp_path):
    from msleak.adapters.healpix import read_healpix
    from msleak.io.products import open_product
    from msleak.sky.healpix import HealpixSky
    from msleak.verbs.grid import grid
    from msleak.verbs.power import power_spectrum
    from msleak.verbs.predict import predict
    from msleak.verbs.transform import transform
    from ms_helpers import phase_centre

    out = tmp_path / "fc"
    result = CliRunner().invoke(cli, ["-q", "forecast", str(out), "--quick", "--telescopes",
                                      "lofar", "--seeds", "1", "--workers", "1", "--nside",
                                      "8", "--extents", "15,90", "--duration", "0.1"])
    assert result.exit_code == 0, result.output
    cfg = ForecastConfig(outdir=out, telescopes=("lofar",), quick=True, seeds=1,
                         extents=(15, 90), nside=8, duration_h=0.1)
    with open(out / "extents.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [float(r["extent_deg"]) for r in rows] == [15.0, 90.0]
    stats = list(csv.DictReader(open(out / "lofar" / "leakage_extent" / "stats.csv")))
    assert float(rows[0]["median"]) == pytest.approx(
        float(next(r["median"] for r in stats if r["label"] == "e15")), rel=1e-12)
    assert (out / "figures" / "extents.png").exists()
    assert "the sky beyond 15 deg" in (out / "forecast.md").read_text()
    # the pixels between 15 and 90 deg alone, predicted, gridded and transformed alike
    ms = out / "lofar" / "lofar.ms"
    sky = read_healpix(next((out / "sky").glob("allsky_*.skyh5")))
    ra, dec = sky.directions()
    ra0, dec0 = phase_centre(ms)
    cos_d = np.sin(dec) * np.sin(dec0) + np.cos(dec) * np.cos(dec0) * np.cos(ra - ra0)
    ring = np.degrees(np.arccos(np.clip(cos_d, -1, 1))) > 15
    beyond = HealpixSky(nside=sky.nside, order=sky.order, pixels=sky.pixels[ring],
                        freq_hz=sky.freq_hz, stokes=sky.stokes[:, :, ring], unit=sky.unit)
    predict(ms, beyond, column="MODEL_BEYOND", beam="everybeam", extent=90.0, double=True,
            double_column=True)
    uv = open_product(out / "lofar" / f"grid_e90_s{cfg.seed}.h5", "uvcube")
    cube = grid(ms, column="MODEL_BEYOND", cell=float(uv.attrs["cell_lambda"]),
                uv_range=(float(uv.attrs["uv_min_lambda"]), float(uv.attrs["uv_max_lambda"])))
    direct = power_spectrum(transform(cube))
    ours = beyond_ps(extent_run(cfg, "lofar"))
    for stokes in ("I", "P"):
        a = ours["power"].sel(stokes=stokes).values
        b = direct["power"].sel(stokes=stokes).values
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-9 * np.nanmax(np.abs(b)))


def test_paper_extents_for_every_field(tmp_path):
    from msleak.study.config import StudyConfig
    from msleak.study.pipeline import study_steps

    cfg = StudyConfig(outdir=tmp_path, fields=("ncp", "3c196"), quick=True, seeds=2,
                      extents=(15, 4))
    steps = {s.name: s for s in study_steps(cfg)}
    assert cfg.nside == 16 and {"allsky-allsky", "allsky-allsky_s2019"} <= set(steps)
    for fld in ("ncp", "3c196"):
        predict = [str(a) for a in steps[f"predict-{fld}-extents"].args]
        assert predict.count("--extent") == 4
        assert f"MODEL_E15_S{cfg.seed + 1}" in predict
    with pytest.raises(InputError, match="nside must be a power of 2"):
        StudyConfig(outdir=tmp_path, extents=(15,), nside=3)


def test_paper_extents_report(tmp_path):
    out = tmp_path / "study"
    result = CliRunner().invoke(cli, ["-q", "paper", str(out), "--field", "3c196",
                                      "--stations", "CS00[1-4]HBA*", "--duration", "1",
                                      "--interval", "600", "--nchan", "16", "--workers", "1",
                                      "--extents", "15,90", "--nside", "8"])
    assert result.exit_code == 0, result.output
    stats = list(csv.DictReader(open(out / "3c196" / "leakage_extent" / "stats.csv")))
    median = {r["label"]: float(r["median"]) for r in stats}
    report = (out / "report.md").read_text()
    for label, extent in (("e15", 15), ("e90", 90)):
        assert f"| LOFAR 3C196 | {extent} | {median[label]:.3g} ± 0 |" in report
    assert (out / "figures" / "beyond15_3c196.png").exists()
