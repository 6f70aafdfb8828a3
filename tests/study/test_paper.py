"""msleak paper end to end at a tiny size: every stage through the CLI, products, plausible
leakage, resume without recomputation, --overwrite recomputes."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys

import click
import numpy as np
import pytest
import xarray as xr
from click.testing import CliRunner

from msleak.cli import cli
from msleak.study.config import StudyConfig
from msleak.study.pipeline import study_steps

from ms_helpers import split_qu_cube

TINY = ["--field", "3c196", "--stations", "CS00[1-4]HBA*", "--duration", "1",
        "--interval", "600", "--nchan", "16"]
FOVS = ("15deg", "9deg", "4deg")
#: products of the same study run two ways, each in fresh processes (bit-identical at this
#: size when measured; the room is a margin for sums whose order the threads set)
RTOL_RUNS = 1e-6


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper") / "study"
    result = CliRunner().invoke(cli, ["-q", "paper", str(out), *TINY, "--workers", "2"])
    assert result.exit_code == 0, result.output
    return out


def test_every_product_exists_and_opens(study):
    assert (study / "3c196" / "3c196.ms" / "table.dat").exists()
    assert (study / "sky" / "sky.fits").exists()
    for fov in FOVS:
        grid = xr.open_dataset(study / "3c196" / f"grid_{fov}.h5", engine="h5netcdf")
        assert grid["vis"].dims == ("stokes", "freq", "v", "u") and grid.sizes["freq"] == 16
        delay = xr.open_dataset(study / "3c196" / f"delay_{fov}.h5", engine="h5netcdf")
        assert delay.sizes["delay"] == 16
        ps = xr.open_dataset(study / "3c196" / f"ps_{fov}.h5", engine="h5netcdf")
        assert ps["power"].dims == ("stokes", "k_par", "k_perp")
        assert list(ps["stokes"].values) == ["I", "Q", "U", "V", "P"]
        filled = ps["counts"].values > 0               # empty bins are NaN by design
        assert filled.sum() > 10
        assert np.all(np.isfinite(ps["power"].values[:, filled]))
        assert np.all(np.isnan(ps["power"].values[:, ~filled]))
    for png in ("sky.png", "beam_3c196.png", "ps1d_3c196.png", "ps_3c196_4deg.png"):
        assert (study / "figures" / png).stat().st_size > 10_000
    for png in ("leakage_maps.png", "leakage_hist.png"):
        assert (study / "3c196" / "leakage" / png).stat().st_size > 10_000
    report = (study / "report.md").read_text()
    assert "Per-field estimate" in report and "msleak predict" in report


def test_leakage_is_plausible(study):
    with open(study / "3c196" / "leakage" / "stats.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["label"] for r in rows] == list(FOVS)
    for r in rows:
        median, fitted = float(r["median"]), float(r["pareto_median"])
        for value in (float(r["mean"]), median, fitted):
            assert np.isfinite(value) and 0.001 < value < 10.0
        assert abs(fitted - median) / median < 0.2
        assert float(r["mean"]) > median                # heavy tail


def test_rerun_resumes_and_overwrite_recomputes(study):
    state = study / ".msleak-steps.json"
    before = json.loads(state.read_text())
    ps_mtime = (study / "3c196" / "ps_4deg.h5").stat().st_mtime_ns
    result = CliRunner().invoke(cli, ["-q", "paper", str(study), *TINY])
    assert result.exit_code == 0, result.output
    assert json.loads(state.read_text()) == before          # nothing ran again
    assert (study / "3c196" / "ps_4deg.h5").stat().st_mtime_ns == ps_mtime
    assert "(up to date, skipped)" in (study / "report.md").read_text()
    result = CliRunner().invoke(cli, ["-q", "paper", str(study), *TINY, "--workers", "2",
                                      "--overwrite"])
    assert result.exit_code == 0, result.output
    after = json.loads(state.read_text())
    assert all(after[name]["finished"] >= before[name]["finished"] for name in before)
    assert (study / "3c196" / "ps_4deg.h5").stat().st_mtime_ns > ps_mtime


@pytest.fixture(scope="module")
def study_seeds(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper_seeds") / "study"
    # a process of its own, as the one-seed study's steps are, so that nothing the test
    # process ran before can reach its numbers
    result = subprocess.run([sys.executable, "-m", "msleak", "-q", "paper", str(out), *TINY,
                             "--seeds", "3", "--workers", "1"], capture_output=True, text=True,
                            env={**os.environ, "MPLBACKEND": "Agg"}, timeout=900)
    assert result.returncode == 0, result.stderr
    return out


def test_seeds_give_distinct_estimates_and_their_mean_and_std(study, study_seeds):
    """--seeds 3: three sky realisations through one MS; three distinct per-field
    estimates, their mean and standard deviation in estimates.csv and report.md, and the
    first realisation equal to the one-seed study."""
    with open(study_seeds / "3c196" / "leakage" / "estimates.csv") as fh:
        est = list(csv.DictReader(fh))
    assert [r["realisation"] for r in est] == ["2018", "2019", "2020", "all"]
    values = np.array([float(r["estimate_data"]) for r in est[:3]])
    assert np.unique(np.round(values, 6)).size == 3
    assert float(est[3]["estimate_data"]) == pytest.approx(values.mean(), rel=1e-5)
    assert float(est[3]["realisation_std_data"]) == pytest.approx(values.std(ddof=1), rel=1e-4)
    with open(study_seeds / "3c196" / "leakage" / "stats.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["label"], r["realisation"]) for r in rows] == [
        (fov, str(seed)) for seed in (2018, 2019, 2020) for fov in FOVS]
    with open(study / "3c196" / "leakage" / "estimates.csv") as fh:
        single = list(csv.DictReader(fh))
    assert float(est[0]["estimate_data"]) == pytest.approx(float(single[0]["estimate_data"]),
                                                           rel=1e-6)
    report = (study_seeds / "report.md").read_text()
    assert "Over 3 realisations" in report
    assert f"{values.mean():.3g} ± {values.std(ddof=1):.2g} %" in report


def test_steps_at_once_give_the_products_of_steps_in_turn(study, study_seeds):
    """The one-seed study ran its steps in two worker processes (--workers 2), the
    three-seed one in turn in the msleak process (--workers 1); the first realisation's
    power spectra and leakage statistics agree to RTOL_RUNS."""
    for fov in FOVS:
        a = xr.open_dataset(study / "3c196" / f"ps_{fov}.h5", engine="h5netcdf")["power"].values
        b = xr.open_dataset(study_seeds / "3c196" / f"ps_{fov}.h5",
                            engine="h5netcdf")["power"].values
        filled = np.isfinite(b)
        assert np.array_equal(np.isfinite(a), filled)
        np.testing.assert_allclose(a[filled], b[filled], rtol=RTOL_RUNS,
                                   atol=1e-9 * np.abs(b[filled]).max())
    def rows(path, name):
        with open(path / "3c196" / "leakage" / name) as fh:
            return list(csv.DictReader(fh))

    for ra, rb in zip(rows(study, "stats.csv"), rows(study_seeds, "stats.csv")[:3]):
        assert (ra["label"], ra["realisation"]) == (rb["label"], rb["realisation"])
        assert float(ra["median"]) == pytest.approx(float(rb["median"]), rel=RTOL_RUNS)
    first_a, first_b = rows(study, "estimates.csv")[0], rows(study_seeds, "estimates.csv")[0]
    assert first_a["realisation"] == first_b["realisation"] == "2018"
    assert float(first_a["estimate_data"]) == pytest.approx(float(first_b["estimate_data"]),
                                                            rel=RTOL_RUNS)


def test_steps_that_rerun_pass_overwrite(tmp_path):
    """A step that reruns replaces its outputs: every command of the study but predict
    (which writes its own MS columns) carries --overwrite, and accepts it."""
    cfg = StudyConfig(outdir=tmp_path / "study", seeds=2,
                      observed={"ncp": ("q.fits", "u.fits")})
    steps = study_steps(cfg)
    assert {s.args[0] for s in steps} == {"sky", "simulate", "beam", "predict", "grid",
                                          "transform", "ps", "leakage"}
    for step in steps:
        command = cli.get_command(click.Context(cli), step.args[0])
        if step.args[0] == "predict":
            assert "--overwrite" not in step.args
        else:
            assert "--overwrite" in step.args, step.name
            assert "overwrite" in {p.name for p in command.params}, step.args[0]


def test_predicts_in_double_unless_no_double(tmp_path):
    """Every predict of the study runs in complex128 arithmetic into complex128 columns by
    default (complex64 rounding sets P_I of the faintest voxels, docs/leakage.md);
    --no-double drops both from each, and nothing else changes."""
    both = {}
    for double in (True, False):
        cfg = StudyConfig(outdir=tmp_path / "study", seeds=2, double=double)
        both[double] = [s.args for s in study_steps(cfg)]
        predicts = [a for a in both[double] if a[0] == "predict"]
        assert len(predicts) == 2
        assert all(("--double" in a) == ("--double-column" in a) == double for a in predicts)
    assert [[x for x in a if x not in ("--double", "--double-column")]
            for a in both[True]] == both[False]
    result = CliRunner().invoke(cli, ["paper", "--help"])
    text = " ".join(result.output.split())           # as click wraps it for the terminal
    assert "--double / --no-double" in text and "[default: double]" in text


def test_bad_observed_option(tmp_path):
    result = CliRunner().invoke(cli, ["paper", str(tmp_path / "x"), "--observed", "ncp=a.fits"])
    assert result.exit_code == 2
    assert "expected FIELD=Q.fits,U.fits" in result.output


def test_observed_grid_step_runs_on_plain_q_and_u_cubes(tmp_path, monkeypatch):
    """``--observed ncp=Q.fits,U.fits`` with cubes that have no STOKES axis (as imagers
    write them): the study's observed-grid command grids them as Q and U, equal to the
    grid of the combined Q,U cube."""
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    assert runner.invoke(cli, ["sky", "sky.fits", "--seed", "2", "--npix", "16",
                               "--nchan", "4"]).exit_code == 0
    split_qu_cube("sky.fits")
    cfg = StudyConfig(outdir=tmp_path / "study", fields=("ncp",),
                      observed={"ncp": ("Q.fits", "U.fits")})
    step = next(s for s in study_steps(cfg) if s.name == "observed-grid-ncp")
    args = [str(a) for a in step.args]
    args[args.index("-o") + 1] = "observed.h5"
    result = runner.invoke(cli, args)
    assert result.exit_code == 0, result.output
    ref = runner.invoke(cli, ["grid", "--image", "sky.fits", "--fov", "4", "-o", "ref.h5"])
    assert ref.exit_code == 0, ref.output
    with xr.open_dataset("observed.h5", engine="h5netcdf") as a, \
            xr.open_dataset("ref.h5", engine="h5netcdf") as b:
        for stokes in "QU":
            assert np.abs(b["vis"].sel(stokes=stokes).values).max() > 0
            np.testing.assert_array_equal(a["vis"].sel(stokes=stokes).values,
                                          b["vis"].sel(stokes=stokes).values)


def test_ctrl_c_stops_the_worker_steps_and_a_rerun_finishes(tmp_path):
    """SIGINT to `msleak paper --workers 2` while predict runs in a worker: exit 130 with
    the interrupt message, the finished steps recorded and the interrupted one not; the
    same command then finishes the study (no worker is left holding the MS). Ten times
    TINY's time slots make predict last 2.4 s (measured), far longer than the 0.2 s in
    which the study reacts to a Ctrl-C."""
    out = tmp_path / "study"
    cmd = [sys.executable, "-m", "msleak", "paper", str(out), *TINY, "--interval", "60",
           "--workers", "2"]
    env = {**os.environ, "MPLBACKEND": "Agg"}
    # a shell starts background jobs with SIGINT ignored, and Python then installs no
    # KeyboardInterrupt handler: give the study the default disposition
    proc = subprocess.Popen(cmd, env=env, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
                            text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    seen = []
    for line in proc.stderr:
        seen.append(line)
        if "INFO: run  predict-3c196" in line:
            proc.send_signal(signal.SIGINT)
            break
    _, rest = proc.communicate(timeout=120)
    assert proc.returncode == 130, "".join(seen) + rest
    assert "msleak: interrupted" in rest
    state = json.loads((out / ".msleak-steps.json").read_text())
    assert {"sky", "simulate-3c196"} <= set(state) and "predict-3c196" not in state
    rerun = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    assert rerun.returncode == 0, rerun.stderr
    state = json.loads((out / ".msleak-steps.json").read_text())
    assert {"predict-3c196", "grid-3c196", "leakage-3c196"} <= set(state)


@pytest.mark.parametrize("rows", [0, 12])
def test_report_explains_the_1d_floor_from_the_uv_range(tmp_path, rows):
    """The report's 1D PS caption names the rows that cross the uv-range limits within
    the band (they set the high-k_par floor, docs/ps.md), and is absent without them."""
    from msleak.io.products import save_product
    from msleak.study.report import _ps1d_caption

    cfg = StudyConfig(outdir=tmp_path, quick=True)
    label = cfg.fields_of_view[0][0]
    ps = xr.Dataset({"power": ("k", np.ones(2))},
                    attrs={"n_rows_crossing_uv_range": rows})
    save_product(ps, tmp_path / "ncp" / f"ps_{label}.h5", "ps", overwrite=False)
    caption = _ps1d_caption(cfg, "ncp")
    if rows:
        assert caption[0].startswith("The MS has 12 rows (baseline x time) whose length "
                                     "crosses 30 or 180 wavelengths within the band")
        assert caption[0].endswith("(docs/ps.md, \"A floor from the uv range\").")
    else:
        assert caption == []
