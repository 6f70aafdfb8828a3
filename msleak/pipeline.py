"""The whole leakage study (``msleak paper``): every stage as a resumable msleak command.

For each field (NCP 13 h, 3C196 8 h) the study simulates the MS, predicts the same sky
cube (generated once) through the LOFAR beam with the phase-centre correction for each
field of view (15, 9 and 4 deg), grids, delay-transforms and computes the power spectra,
then the leakage statistics; it draws every figure of method.md section 8 and writes
``report.md``. Each stage is one msleak command line (listed in the report), so any stage
can be rerun by hand. A rerun skips stages whose inputs are unchanged
(:mod:`msleak.steps`).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

from msleak.steps import Step, StepRunner

__all__ = ["StudyConfig", "study_steps", "run_study", "FIELDS_OF_VIEW"]

log = logging.getLogger(__name__)

#: (label, crop in pixels of the 50-pixel 15-deg cube): the paper's 15, 9 and 4 deg fields
#: of view are 50, 28 and 16 pixels (0.3 deg pixels: 15, 8.4 and 4.8 deg a side).
FIELDS_OF_VIEW = (("15deg", 50), ("9deg", 28), ("4deg", 16))


@dataclass
class StudyConfig:
    """Parameters of the study; ``quick`` shrinks stations, times and channels."""

    outdir: Path
    quick: bool = False
    seed: int = 2018
    fields: tuple = ("ncp", "3c196")
    beam: str = "everybeam"
    observed: dict = field(default_factory=dict)   # field -> (Q.fits, U.fits)
    stations: str | None = None      # overrides of the study's size
    duration_h: float | None = None
    interval_s: float | None = None
    nchan: int | None = None

    @property
    def simulate_args(self) -> list:
        quick = {"stations": "CS00[1-7]HBA*,CS01[13]HBA*", "duration": 2.0, "interval": 600.0}
        given = {"stations": self.stations, "duration": self.duration_h,
                 "interval": self.interval_s}
        args = []
        for key, value in given.items():
            if value is None and self.quick:
                value = quick[key]
            if value is not None:
                args += [f"--{key}", str(value)]
        if self.nchan is not None:
            args += ["--nchan", str(self.nchan)]
        return args

    @property
    def sky_args(self) -> list:
        args = ["--seed", str(self.seed)]
        if self.nchan is not None:
            args += ["--nchan", str(self.nchan)]
        return args


def study_steps(cfg: StudyConfig) -> list[Step]:
    """Every step of the study, in order."""
    out = Path(cfg.outdir)
    fig = out / "figures"
    sky = out / "sky"
    steps: list[Step] = []
    sky_cube = sky / "sky.fits"
    steps.append(Step("sky", ["sky", sky_cube, *cfg.sky_args, "--overwrite",
                              "--plot", fig / "sky.png"],
                      outputs=[sky_cube, fig / "sky.png"]))
    crops = {}
    for label, npix in FIELDS_OF_VIEW:
        if npix == 50:
            crops[label] = sky_cube
            continue
        crops[label] = sky / f"sky_{label}.fits"
        steps.append(Step(f"sky-crop-{label}",
                          ["sky", "--crop", sky_cube, "--crop-npix", str(npix), crops[label],
                           "--overwrite"],
                          inputs=[sky_cube], outputs=[crops[label]]))
    for fld in cfg.fields:
        fdir = out / fld
        ms = fdir / f"{fld}.ms"
        steps.append(Step(f"simulate-{fld}",
                          ["simulate", ms, "--field", fld, *cfg.simulate_args, "--overwrite"],
                          outputs=[ms]))
        steps.append(Step(f"beam-{fld}", ["beam", ms, "-o", fig / f"beam_{fld}.png",
                                          "--beam", cfg.beam],
                          outputs=[fig / f"beam_{fld}.png"], after=[f"simulate-{fld}"]))
        ps_files = []
        for label, _ in FIELDS_OF_VIEW:
            column = f"MODEL_{label.upper()}"
            steps.append(Step(f"predict-{fld}-{label}",
                              ["predict", ms, "--sky", crops[label], "--beam", cfg.beam,
                               "--column", column],
                              inputs=[crops[label]], outputs=[ms],
                              after=[f"simulate-{fld}"]))
            grid = fdir / f"grid_{label}.h5"
            delay = fdir / f"delay_{label}.h5"
            ps = fdir / f"ps_{label}.h5"
            steps.append(Step(f"grid-{fld}-{label}",
                              ["grid", ms, "--column", column, "-o", grid],
                              outputs=[grid], after=[f"predict-{fld}-{label}"]))
            steps.append(Step(f"transform-{fld}-{label}", ["transform", grid, "-o", delay],
                              inputs=[grid], outputs=[delay]))
            steps.append(Step(f"ps-{fld}-{label}",
                              ["ps", delay, "-o", ps, "--plot", fig / f"ps_{fld}_{label}.png"],
                              inputs=[delay], outputs=[ps]))
            ps_files.append(ps)
        leak_dir = fdir / "leakage"
        leak_args = ["leakage", *ps_files, "--labels",
                     ",".join(label for label, _ in FIELDS_OF_VIEW),
                     "--field-name", fld.upper(), "-o", leak_dir]
        expected = []
        if fld in cfg.observed:
            q_cube, u_cube = cfg.observed[fld]
            obs_grid = fdir / "observed_grid.h5"
            obs_delay = fdir / "observed_delay.h5"
            obs_ps = fdir / "observed_ps.h5"
            steps += [
                Step(f"observed-grid-{fld}", ["grid", "--image", q_cube, "--image", u_cube,
                                              "--stokes", "Q,U", "--fov", "4",
                                              "-o", obs_grid],
                     inputs=[q_cube, u_cube], outputs=[obs_grid]),
                Step(f"observed-transform-{fld}", ["transform", obs_grid, "-o", obs_delay],
                     inputs=[obs_grid], outputs=[obs_delay]),
                Step(f"observed-ps-{fld}", ["ps", obs_delay, "-o", obs_ps],
                     inputs=[obs_delay], outputs=[obs_ps]),
            ]
            leak_args += ["--expected", str(obs_ps)]
            expected = [obs_ps]
        steps.append(Step(f"leakage-{fld}", leak_args, inputs=[*ps_files, *expected],
                          outputs=[leak_dir / "stats.csv"]))
    return steps


def run_study(cfg: StudyConfig, invoke, force: bool = False) -> Path:
    """Run (or resume) the study; returns the path of ``report.md``."""
    from msleak.report import write_report

    out = Path(cfg.outdir)
    out.mkdir(parents=True, exist_ok=True)
    for sub in ("sky", "figures", *cfg.fields):
        (out / sub).mkdir(exist_ok=True)
    runner = StepRunner(out, force=force)
    t0 = time.perf_counter()
    steps = study_steps(cfg)
    runner.run_all(steps, invoke)
    return write_report(cfg, steps, runner.log, time.perf_counter() - t0)
