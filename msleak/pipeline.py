"""The whole leakage study (``msleak paper``): every stage as a resumable msleak command.

For each field (NCP 13 h, 3C196 8 h) the study simulates the MS, predicts the same sky
cube (generated once) through the LOFAR beam with the phase-centre correction for each
field of view (15, 9 and 4 deg), grids, delay-transforms and computes the power spectra,
then the leakage statistics; it draws every figure of docs/science.md section 8 and writes
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
    #: sky realisations: seeds ``seed``, ``seed + 1``, ... through the same MSs and beams
    seeds: int = 1
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
    def realisations(self) -> list[int]:
        """The sky seeds of the study, the first one being ``seed``."""
        return [self.seed + k for k in range(self.seeds)]

    def suffix(self, seed: int) -> str:
        """File and column suffix of a realisation: none for the first seed."""
        return "" if seed == self.seed else f"_s{seed}"

    def sky_args(self, seed: int) -> list:
        args = ["--seed", str(seed)]
        if self.nchan is not None:
            args += ["--nchan", str(self.nchan)]
        return args


def _sky_steps(cfg: StudyConfig, sky: Path, fig: Path) -> tuple[list[Step], dict]:
    """The sky cube of every realisation and its crops; returns the steps and
    ``{(seed, fov label): cube}``."""
    steps, crops = [], {}
    for seed in cfg.realisations:
        sfx = cfg.suffix(seed)
        cube = sky / f"sky{sfx}.fits"
        plot = ["--plot", fig / "sky.png"] if not sfx else []
        steps.append(Step(f"sky{sfx}", ["sky", cube, *cfg.sky_args(seed), "--overwrite",
                                        *plot], outputs=[cube, *plot[1:]]))
        for label, npix in FIELDS_OF_VIEW:
            if npix == 50:
                crops[seed, label] = cube
                continue
            crops[seed, label] = sky / f"sky_{label}{sfx}.fits"
            steps.append(Step(f"sky-crop-{label}{sfx}",
                              ["sky", "--crop", cube, "--crop-npix", str(npix),
                               crops[seed, label], "--overwrite"],
                              inputs=[cube], outputs=[crops[seed, label]]))
    return steps, crops


def _field_steps(cfg: StudyConfig, fld: str, crops: dict, fig: Path) -> list[Step]:
    """Simulate, beam maps, one predict and one grid of every realisation and field of
    view (the beam evaluated once), then transform and PS of each, and the leakage."""
    fdir = Path(cfg.outdir) / fld
    ms = fdir / f"{fld}.ms"
    runs = [(seed, label, cfg.suffix(seed)) for seed in cfg.realisations
            for label, _ in FIELDS_OF_VIEW]
    column = {(seed, label): f"MODEL_{label.upper()}{sfx.upper()}" for seed, label, sfx in runs}
    steps = [Step(f"simulate-{fld}", ["simulate", ms, "--field", fld, *cfg.simulate_args,
                                      "--overwrite"], outputs=[ms]),
             Step(f"beam-{fld}", ["beam", ms, "-o", fig / f"beam_{fld}.png", "--beam", cfg.beam],
                  outputs=[fig / f"beam_{fld}.png"], after=[f"simulate-{fld}"])]
    predict = ["predict", ms, "--beam", cfg.beam]
    grid = ["grid", ms]
    for seed, label, sfx in runs:
        predict += ["--sky", crops[seed, label], "--column", column[seed, label]]
        grid += ["--column", column[seed, label], "-o", fdir / f"grid_{label}{sfx}.h5"]
    steps.append(Step(f"predict-{fld}", predict, inputs=sorted(set(crops.values())),
                      outputs=[ms], after=[f"simulate-{fld}"]))
    steps.append(Step(f"grid-{fld}", grid, outputs=[fdir / f"grid_{label}{sfx}.h5"
                                                    for _, label, sfx in runs],
                      after=[f"predict-{fld}"]))
    ps_files = []
    for seed, label, sfx in runs:
        delay = fdir / f"delay_{label}{sfx}.h5"
        ps = fdir / f"ps_{label}{sfx}.h5"
        plot = [] if sfx else ["--plot", fig / f"ps_{fld}_{label}.png"]
        steps += [Step(f"transform-{fld}-{label}{sfx}",
                       ["transform", fdir / f"grid_{label}{sfx}.h5", "-o", delay],
                       inputs=[fdir / f"grid_{label}{sfx}.h5"], outputs=[delay]),
                  Step(f"ps-{fld}-{label}{sfx}", ["ps", delay, "-o", ps, *plot],
                       inputs=[delay], outputs=[ps])]
        ps_files.append(ps)
    leak_dir = fdir / "leakage"
    leak_args = ["leakage", *ps_files, "--labels", ",".join(label for _, label, _ in runs),
                 "--realisations", ",".join(str(seed) for seed, _, _ in runs),
                 "--field-name", fld.upper(), "-o", leak_dir]
    expected = []
    if fld in cfg.observed:
        q_cube, u_cube = cfg.observed[fld]
        obs_grid, obs_delay, obs_ps = (fdir / f"observed_{x}.h5" for x in ("grid", "delay", "ps"))
        steps += [
            Step(f"observed-grid-{fld}", ["grid", "--image", q_cube, "--image", u_cube,
                                          "--stokes", "Q,U", "--fov", "4", "-o", obs_grid],
                 inputs=[q_cube, u_cube], outputs=[obs_grid]),
            Step(f"observed-transform-{fld}", ["transform", obs_grid, "-o", obs_delay],
                 inputs=[obs_grid], outputs=[obs_delay]),
            Step(f"observed-ps-{fld}", ["ps", obs_delay, "-o", obs_ps],
                 inputs=[obs_delay], outputs=[obs_ps]),
        ]
        leak_args += ["--expected", str(obs_ps)]
        expected = [obs_ps]
    steps.append(Step(f"leakage-{fld}", leak_args, inputs=[*ps_files, *expected],
                      outputs=[leak_dir / "stats.csv", leak_dir / "estimates.csv"]))
    return steps


def study_steps(cfg: StudyConfig) -> list[Step]:
    """Every step of the study, in order."""
    out = Path(cfg.outdir)
    fig = out / "figures"
    steps, crops = _sky_steps(cfg, out / "sky", fig)
    for fld in cfg.fields:
        steps += _field_steps(cfg, fld, crops, fig)
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
