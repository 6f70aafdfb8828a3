"""The instrument's budget of ``msleak paper`` (--ionosphere, --beam-errors, --noise): the
steps it adds, and against answers known in advance: an ionosphere of RM 0 and beam errors
of zero give the ideal instrument's L_I, and the report's table holds the medians the
leakage steps wrote."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from click.testing import CliRunner

from msleak.cli import cli
from msleak.errors import InputError
from msleak.study.config import StudyConfig
from msleak.study.pipeline import study_steps

TINY = ["--field", "3c196", "--stations", "CS00[1-4]HBA*", "--duration", "1",
        "--interval", "600", "--nchan", "16", "--workers", "1"]


def test_budget_steps(tmp_path):
    cfg = StudyConfig(outdir=tmp_path, fields=("3c196",), ionosphere="random",
                      beam_errors="failed=0.1,rotation=1", noise_sefd=2500.0,
                      instrument_seeds=2)
    steps = {s.name: s for s in study_steps(cfg)}
    args = [str(a) for a in steps["predict-3c196-ionosphere2"].args]
    assert args[args.index("--ionosphere") + 1] == "random:2"
    args = [str(a) for a in steps["predict-3c196-beam_errors1"].args]
    assert args[args.index("--beam-errors") + 1] == "failed=0.1,rotation=1,seed=1"
    noise = [str(a) for a in steps["noise-3c196-2"].args]
    assert noise[:2] == ["noise", str(tmp_path / "3c196" / "3c196.ms")]
    assert noise[noise.index("--from") + 1] == "MODEL_15DEG"
    assert "even-odd" in [str(a) for a in steps["grid-3c196-noise"].args]
    leak = [str(a) for a in steps["leakage-3c196-ionosphere"].args]
    assert leak[leak.index("--realisations") + 1] == "1,2"
    assert not any(name.startswith("predict-3c196-") for name in
                   (s.name for s in study_steps(StudyConfig(outdir=tmp_path,
                                                            fields=("3c196",)))))


def test_a_model_ionosphere_is_one_run(tmp_path):
    cfg = StudyConfig(outdir=tmp_path, fields=("3c196",), ionosphere="spinifex",
                      instrument_seeds=3)
    runs = [s for s in study_steps(cfg) if s.name.startswith("predict-3c196-ionosphere")]
    assert [s.name for s in runs] == ["predict-3c196-ionosphere1"]
    args = [str(a) for a in runs[0].args]
    assert args[args.index("--ionosphere") + 1] == "spinifex"


@pytest.mark.parametrize("kwargs,message", [
    (dict(beam_errors="failed=0.1,seed=3"), "draws beam_errors' seed per realisation"),
    (dict(beam_errors="broken=1"), "give failed=FRACTION"),
    (dict(ionosphere="nowhere.csv"), "neither random, spinifex, ionex:PATH nor a CSV table"),
    (dict(ionosphere="spinifex:uqr"), "download an IONEX file yourself"),
    (dict(ionosphere="ionex:nowhere.inx"), "no IONEX file nowhere.inx"),
    (dict(noise_sefd=0.0), "noise_sefd must be positive"),
    (dict(instrument_seeds=0), "instrument_seeds must be at least 1"),
])
def test_bad_budget_settings(tmp_path, kwargs, message):
    with pytest.raises(InputError, match=message):
        StudyConfig(outdir=tmp_path, **kwargs)


def _medians(path):
    with open(path) as fh:
        return [float(r["median"]) for r in csv.DictReader(fh) if r["label"] == "15deg"]


def test_null_corruptions_give_the_ideal_leakage_and_the_report_tabulates_them(tmp_path):
    out = tmp_path / "study"
    rm0 = tmp_path / "rm0.csv"
    rm0.write_text("time,station,rm\n0,*,0\n1e12,*,0\n")
    result = CliRunner().invoke(cli, ["-q", "paper", str(out), *TINY, "--ionosphere",
                                      str(rm0), "--beam-errors", "failed=0,rotation=0",
                                      "--noise", "3000", "--instrument-seeds", "2"])
    assert result.exit_code == 0, result.output
    fdir = out / "3c196"
    ideal = _medians(fdir / "leakage" / "stats.csv")
    assert len(ideal) == 1
    for kind in ("ionosphere", "beam_errors"):
        np.testing.assert_allclose(_medians(fdir / f"leakage_{kind}" / "stats.csv"),
                                   ideal[0], rtol=1e-12)
    noisy = _medians(fdir / "leakage_noise" / "stats.csv")
    assert len(noisy) == 2 and noisy[0] != noisy[1]
    report = (out / "report.md").read_text()
    assert "The instrument's budget at 15deg" in report
    assert f"| ideal instrument, first sky | 1 | {ideal[0]:.3g} |" in report
    assert f"| thermal noise (even/odd cross power), first sky | 2 | " \
           f"{np.mean(noisy):.3g} ± {np.std(noisy):.2g} |" in report
    from msleak.io.products import open_product
    from msleak.leakage.detectable import detectable_leakage

    # the report's line is the detectable L_I of these spectra (its numerics are checked
    # against known answers in tests/leakage/test_detectable.py), against the noiseless
    # column gridded in even/odd halves like the noisy ones, for the 1 h observed
    l_min = detectable_leakage(open_product(fdir / "ps_noise0.h5"),
                               [open_product(fdir / f"ps_noise{r}.h5") for r in (1, 2)])
    line = next(x for x in report.splitlines() if x.startswith("Smallest L_I detectable"))
    assert "SEFD 3000 Jy, 1 h," in line and f"median {np.median(l_min):.3g} %" in line
    steps = {s.name: s for s in study_steps(StudyConfig(
        outdir=out, fields=("3c196",), noise_sefd=3000.0, instrument_seeds=2))}
    leak = [str(a) for a in steps["leakage-3c196-noise"].args]
    assert leak[leak.index("--realisations") + 1] == "1,2"       # not the reference
    assert not any("ps_noise0" in a for a in leak)


# --- msleak forecast's budget ---------------------------------------------------------

def test_forecast_budget_steps_model_beam_errors_only_where_the_beam_has_them(tmp_path):
    from msleak.study.config import Instrument
    from msleak.study.forecast import ForecastConfig, forecast_steps

    cfg = ForecastConfig(outdir=tmp_path, telescopes=("lofar", "hera"), quick=True,
                         instrument=Instrument(ionosphere="random",
                                               beam_errors="failed=0.1", seeds=2),
                         noise={"lofar": 4000.0})
    names = {s.name for s in forecast_steps(cfg)}
    assert {"predict-lofar-beam_errors2", "predict-hera-ionosphere2", "noise-lofar-2",
            "leakage-hera-ionosphere"} <= names
    assert not any(n.startswith(("predict-hera-beam", "noise-hera")) for n in names)
    noise = next(s for s in forecast_steps(cfg) if s.name == "noise-lofar-1")
    args = [str(a) for a in noise.args]
    assert args[args.index("--sefd") + 1] == "4000"
    assert args[args.index("--from") + 1] == f"MODEL_S{cfg.seed}"
    with pytest.raises(InputError, match="noise is given for mwa"):
        ForecastConfig(outdir=tmp_path, telescopes=("lofar",), quick=True,
                       noise={"mwa": 1.0})


def test_forecast_null_corruptions_give_the_ideal_leakage(tmp_path):
    out = tmp_path / "fc"
    rm0 = tmp_path / "rm0.csv"
    rm0.write_text("time,station,rm\n0,*,0\n1e12,*,0\n")
    result = CliRunner().invoke(cli, ["-q", "forecast", str(out), "--quick", "--telescopes",
                                      "lofar", "--seeds", "1", "--workers", "1",
                                      "--ionosphere", str(rm0), "--beam-errors",
                                      "failed=0,rotation=0", "--instrument-seeds", "2"])
    assert result.exit_code == 0, result.output
    tdir = out / "lofar"
    with open(tdir / "leakage" / "stats.csv") as fh:
        ideal = float(next(csv.DictReader(fh))["median"])
    for kind, n in (("ionosphere", 1), ("beam_errors", 2)):
        with open(tdir / f"leakage_{kind}" / "stats.csv") as fh:
            medians = [float(r["median"]) for r in csv.DictReader(fh)]
        assert len(medians) == n
        np.testing.assert_allclose(medians, ideal, rtol=1e-12)
    report = (out / "forecast.md").read_text()
    assert f"| LOFAR HBA | ideal instrument | 1 | {ideal:.3g} |" in report
    assert f"| LOFAR HBA | beam-model errors | 2 | {ideal:.3g} ± 0 |" in report
