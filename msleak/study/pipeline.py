"""The steps of the leakage study (``msleak paper``, docs/paper.md): every stage is one
msleak command line, run or, when up to date, skipped (:mod:`msleak.study.steps`)."""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path

from msleak.errors import InputError
from msleak.study.config import StudyConfig
from msleak.study.extents import ExtentRun, allsky_step, extent_steps
from msleak.study.report import write_report
from msleak.study.steps import Step, StepRunner, predict_precision

__all__ = ["study_steps", "run_study", "study_resolution", "STUDY_FILE"]

log = logging.getLogger(__name__)
#: the resolution of the study in OUTDIR (docs/paper.md "Observation resolution")
STUDY_FILE = ".msleak-study.json"


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
        for label, npix in cfg.fields_of_view:
            if npix == cfg.sky_npix:
                crops[seed, label] = cube
                continue
            crops[seed, label] = sky / f"sky_{label}{sfx}.fits"
            steps.append(Step(f"sky-crop-{label}{sfx}",
                              ["sky", "--crop", cube, "--crop-npix", str(npix),
                               crops[seed, label], "--overwrite"],
                              inputs=[cube], outputs=[crops[seed, label]]))
    return steps, crops


def _field_steps(cfg: StudyConfig, fld: str, crops: dict, fig: Path) -> list[Step]:
    """Simulate, one predict and one grid of every realisation and field of view (the beam
    evaluated once), beam maps, then transform and PS of each, and the leakage."""
    fdir = Path(cfg.outdir) / fld
    ms = fdir / f"{fld}.ms"
    runs = [(seed, label, cfg.suffix(seed)) for seed in cfg.realisations
            for label, _ in cfg.fields_of_view]
    column = {(seed, label): f"MODEL_{label.upper()}{sfx.upper()}" for seed, label, sfx in runs}
    steps = [Step(f"simulate-{fld}", ["simulate", ms, "--field", fld, *cfg.simulate_args,
                                      "--overwrite"], outputs=[ms])]
    predict = ["predict", ms, "--beam", cfg.beam, *predict_precision(cfg.double),
               *cfg.predict_args]
    grid = ["grid", ms, "--overwrite", *cfg.grid_args]
    for seed, label, sfx in runs:
        predict += ["--sky", crops[seed, label], "--column", column[seed, label]]
        grid += ["--column", column[seed, label], "-o", fdir / f"grid_{label}{sfx}.h5"]
    steps.append(Step(f"predict-{fld}", predict, inputs=sorted(set(crops.values())),
                      outputs=[ms], after=[f"simulate-{fld}"]))
    steps.append(Step(f"grid-{fld}", grid, outputs=[fdir / f"grid_{label}{sfx}.h5"
                                                    for _, label, sfx in runs],
                      after=[f"predict-{fld}"], reads=[ms]))
    # listed after predict, so that with several workers it reads the MS beside grid, not
    # while predict writes it (steps.dependencies)
    steps.append(Step(f"beam-{fld}", ["beam", ms, "-o", fig / f"beam_{fld}.png", "--beam",
                                      cfg.beam, "--overwrite"],
                      outputs=[fig / f"beam_{fld}.png"], after=[f"simulate-{fld}"],
                      reads=[ms]))
    ps_files = []
    for seed, label, sfx in runs:
        delay = fdir / f"delay_{label}{sfx}.h5"
        ps = fdir / f"ps_{label}{sfx}.h5"
        plot = [] if sfx else ["--plot", fig / f"ps_{fld}_{label}.png"]
        steps += [Step(f"transform-{fld}-{label}{sfx}",
                       ["transform", fdir / f"grid_{label}{sfx}.h5", "-o", delay,
                        "--overwrite"],
                       inputs=[fdir / f"grid_{label}{sfx}.h5"], outputs=[delay]),
                  Step(f"ps-{fld}-{label}{sfx}", ["ps", delay, "-o", ps, "--overwrite",
                                                  *cfg.ps_args, *plot],
                       inputs=[delay], outputs=[ps])]
        ps_files.append(ps)
    leak_dir = fdir / "leakage"
    leak_args = ["leakage", *ps_files, "--labels", ",".join(label for _, label, _ in runs),
                 "--realisations", ",".join(str(seed) for seed, _, _ in runs),
                 "--field-name", fld.upper(), "-o", leak_dir, "--overwrite"]
    expected = []
    if fld in cfg.observed:
        q_cube, u_cube = cfg.observed[fld]
        obs_grid, obs_delay, obs_ps = (fdir / f"observed_{x}.h5" for x in ("grid", "delay", "ps"))
        steps += [
            Step(f"observed-grid-{fld}", ["grid", "--image", q_cube, "--image", u_cube,
                                          "--stokes", "Q,U", "--fov", "4", "-o", obs_grid,
                                          "--overwrite", *cfg.grid_args],
                 inputs=[q_cube, u_cube], outputs=[obs_grid]),
            Step(f"observed-transform-{fld}", ["transform", obs_grid, "-o", obs_delay,
                                               "--overwrite"],
                 inputs=[obs_grid], outputs=[obs_delay]),
            Step(f"observed-ps-{fld}", ["ps", obs_delay, "-o", obs_ps, "--overwrite",
                                        *cfg.ps_args],
                 inputs=[obs_delay], outputs=[obs_ps]),
        ]
        leak_args += ["--expected", str(obs_ps)]
        expected = [obs_ps]
    steps.append(Step(f"leakage-{fld}", leak_args, inputs=[*ps_files, *expected],
                      outputs=[leak_dir / "stats.csv", leak_dir / "estimates.csv"]))
    return steps


def _budget_steps(cfg: StudyConfig, fld: str, crops: dict) -> list[Step]:
    """The instrument's budget runs of one field (docs/paper.md, "The instrument's budget"):
    the first sky at the largest field of view predicted through each corruption and
    realisation, as :func:`budget_steps` lays them out."""
    fdir = Path(cfg.outdir) / fld
    label = cfg.fields_of_view[0][0]
    budget = Budget(ms=fdir / f"{fld}.ms", outdir=fdir, sky=crops[cfg.seed, label],
                    label=label, name=fld, predict=["--beam", cfg.beam,
                                                    *predict_precision(cfg.double),
                                                    *cfg.predict_args],
                    grid=cfg.grid_args, ps=cfg.ps_args, ideal_column=f"MODEL_{label.upper()}",
                    after=(f"beam-{fld}", f"predict-{fld}"), field_name=fld.upper())
    return budget_steps(budget, cfg.corruptions(), cfg.noise_sefd)


@dataclass(frozen=True)
class Budget:
    """Where and how the budget runs of one MS go: the MS and the directory of their
    products, the sky and its label, the options of predict, grid and ps, the column of the
    ideal prediction of that sky (the noise is added to it), the steps to run after (the
    last one writing the MS, the one writing the ideal column), the name in the tables."""

    ms: Path
    outdir: Path
    sky: Path
    label: str
    name: str
    predict: list
    grid: list
    ps: list
    ideal_column: str
    after: tuple
    field_name: str
    leakage: tuple = ()


def budget_steps(b: Budget, runs: list, noise_sefd) -> list[Step]:
    """Each corruption and realisation of ``runs`` (``(kind, r, predict options)``) predicted
    into ``MODEL_<KIND><r>`` (noise: ``noise_sefd`` added to the ideal column, gridded in
    even/odd halves), gridded, transformed, and one leakage result per kind in
    ``leakage_<kind>``."""
    if not runs:
        return []
    column = {(kind, r): f"MODEL_{kind.upper()}{r}" for kind, r, _ in runs}
    steps, previous = [], b.after[0]
    for kind, r, extra in runs:
        if kind == "noise":
            continue
        steps.append(Step(f"predict-{b.name}-{kind}{r}", ["predict", b.ms, *b.predict,
                                                          "--sky", b.sky, "--column",
                                                          column[kind, r], *extra],
                          inputs=[b.sky], outputs=[b.ms], after=[previous]))
        previous = steps[-1].name
    for kind, r, _ in runs:        # the ideal column of the sky plus noise of seed r
        if kind == "noise":
            steps.append(Step(f"noise-{b.name}-{r}", [
                "noise", b.ms, "--sefd", f"{noise_sefd:g}", "--seed", str(r), "--from",
                b.ideal_column, "--column", column[kind, r]], outputs=[b.ms],
                after=[previous, *b.after[1:]]))
            previous = steps[-1].name
    kinds = {kind: [(k, r) for k, r, _ in runs if k == kind] for kind, _, _ in runs}
    for kind, keys in kinds.items():
        steps += _budget_products(b, kind, keys, column, previous)
    return steps


def _budget_products(b: Budget, kind: str, keys: list, column: dict, previous: str
                     ) -> list[Step]:
    """Grid (one pass over the MS), transform, ps and leakage of one kind's runs; the noise
    runs' grid also holds the ideal column in even/odd halves as realisation 0, the
    noiseless reference of the smallest detectable L_I (not in the leakage result)."""
    split = ["--split", "even-odd"] if kind == "noise" else []
    gridded = [(kind, 0)] + keys if kind == "noise" else keys
    column = {**column, (kind, 0): b.ideal_column}
    args = ["grid", b.ms, "--overwrite", *b.grid, *split]
    for key in gridded:
        args += ["--column", column[key], "-o", b.outdir / f"grid_{kind}{key[1]}.h5"]
    steps = [Step(f"grid-{b.name}-{kind}", args, reads=[b.ms], after=[previous],
                  outputs=[b.outdir / f"grid_{kind}{r}.h5" for _, r in gridded])]
    ps_files = []
    for _, r in gridded:
        grid, delay, ps = (b.outdir / f"{x}_{kind}{r}.h5" for x in ("grid", "delay", "ps"))
        steps += [Step(f"transform-{b.name}-{kind}{r}", ["transform", grid, "-o", delay,
                                                         "--overwrite"],
                       inputs=[grid], outputs=[delay]),
                  Step(f"ps-{b.name}-{kind}{r}", ["ps", delay, "-o", ps, "--overwrite",
                                                  *b.ps], inputs=[delay], outputs=[ps])]
        ps_files += [ps] if r else []
    leak = b.outdir / f"leakage_{kind}"
    steps.append(Step(f"leakage-{b.name}-{kind}", [
        "leakage", *ps_files, "--labels", ",".join([b.label] * len(keys)),
        "--realisations", ",".join(str(r) for _, r in keys), "--field-name", b.field_name,
        "-o", leak, "--overwrite", *b.leakage], inputs=ps_files,
        outputs=[leak / "stats.csv", leak / "estimates.csv"]))
    return steps


def study_steps(cfg: StudyConfig) -> list[Step]:
    """Every step of the study, in order."""
    out = Path(cfg.outdir)
    fig = out / "figures"
    steps, crops = _sky_steps(cfg, out / "sky", fig)
    for fld in cfg.fields:
        steps += _field_steps(cfg, fld, crops, fig)
    for fld in cfg.fields:
        steps += _budget_steps(cfg, fld, crops)
    if cfg.extents:
        runs = extent_runs(cfg)
        steps += [allsky_step(path, cfg.nside, seed, cfg.allsky_args)
                  for seed, path in runs[0].skies.items()]
        for run in runs:
            steps += extent_steps(run)
    return steps


def extent_runs(cfg: StudyConfig) -> list[ExtentRun]:
    """The extent runs of every field (docs/paper.md, "L_I against the sky's extent")."""
    sky = Path(cfg.outdir) / "sky"
    skies = {seed: sky / f"allsky{cfg.suffix(seed)}.skyh5" for seed in cfg.realisations}
    return [ExtentRun(name=fld, label=f"LOFAR {fld.upper()}", ms=Path(cfg.outdir) / fld /
                      f"{fld}.ms", outdir=Path(cfg.outdir) / fld,
                      predict=["--beam", cfg.beam, *predict_precision(cfg.double)],
                      grid=cfg.grid_args, ps=cfg.ps_args, skies=skies, extents=cfg.extents,
                      after=f"predict-{fld}", field_name=fld.upper()) for fld in cfg.fields]


def study_resolution(outdir: Path) -> str | None:
    """The resolution of the study already in ``outdir`` (``OUTDIR/.msleak-study.json``;
    ``"paper"`` for a study made before msleak recorded it), or None if there is none."""
    out = Path(outdir)
    path = out / STUDY_FILE
    if path.exists():
        try:
            return str(json.loads(path.read_text())["resolution"])
        except (ValueError, KeyError, TypeError):
            raise InputError(f"{path} is unreadable; remove it, or give another "
                             "OUTDIR") from None
    if (out / ".msleak-steps.json").exists():
        return "paper"
    return None


def _claim_outdir(cfg: StudyConfig, overwrite: bool) -> None:
    """Refuse a study of another resolution in OUTDIR (its products have the same names)
    unless ``overwrite``; record this study's resolution."""
    out = Path(cfg.outdir)
    made = study_resolution(out)
    if made is not None and made != cfg.resolution and not overwrite:
        raise InputError(f"{out} holds a resolution {made} study; give another OUTDIR "
                         f"for resolution {cfg.resolution}, or overwrite to replace it",
                         param=("resolution", "overwrite"))
    if made != cfg.resolution:
        (out / STUDY_FILE).write_text(json.dumps({"resolution": cfg.resolution}) + "\n")


def run_study(cfg: StudyConfig, invoke, overwrite: bool = False, workers: int = 1) -> Path:
    """Run (or resume) the study with ``invoke(args)`` running one msleak command line;
    ``overwrite`` reruns every step; at most ``workers`` steps run at once (``invoke`` must
    then be thread-safe, e.g. :class:`msleak.study.steps.ProcessInvoker`). A study of
    another resolution already in ``cfg.outdir`` is refused (InputError) unless
    ``overwrite``. Returns the path of ``report.md``."""
    out = Path(cfg.outdir)
    out.mkdir(parents=True, exist_ok=True)
    _claim_outdir(cfg, overwrite)
    for sub in ("sky", "figures", *cfg.fields):
        (out / sub).mkdir(exist_ok=True)
    runner = StepRunner(out, overwrite=overwrite)
    t0 = time.perf_counter()
    steps = study_steps(cfg)
    runner.run_all(steps, invoke, workers=workers)
    return write_report(cfg, steps, runner.log, time.perf_counter() - t0)
