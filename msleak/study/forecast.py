"""``msleak forecast``: the same sky realisations through LOFAR, SKA-Low, HERA and the MWA
with matched settings, and one table and figure comparing their leakage
(docs/telescopes.md).

Every stage is one msleak command line run (or skipped when up to date) by
:class:`msleak.study.steps.StepRunner`, as in ``msleak paper``.
"""

from __future__ import annotations

import csv
import logging
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from msleak import __version__
from msleak.constants import SPEED_OF_LIGHT
from msleak.errors import InputError
from msleak.io.products import open_product
from msleak.leakage.fraction import window_leakage
from msleak.plot.forecast import plot_forecast
from msleak.study.config import Instrument, check_extents
from msleak.study.extents import ExtentRun, allsky_step, extent_lines, extent_steps
from msleak.study.pipeline import Budget, budget_steps
from msleak.study.report import BUDGET_KINDS, detectable_text, spread_text, stats_rows
from msleak.study.steps import Step, StepRunner, predict_precision
from msleak.telescope.hera_mwa import HERA_DISH_DIAMETER_M, MWA_TILE_SIZE_M
from msleak.telescope.layouts import HBA_FIELD_DIAMETER
from msleak.telescope.observation import TELESCOPES, telescope_layout
from msleak.telescope.ska_low import STATION_DIAMETER_M

__all__ = ["Setup", "SETUPS", "ForecastConfig", "forecast_steps", "run_forecast"]

log = logging.getLogger(__name__)


#: channel width of every MS and sky of the forecast (the study's), Hz
_CHAN_WIDTH = 195312.5


#: the study's uv grid: 16-wavelength cells (a LOFAR HBA field, 30.75 m, at 155 MHz) and
#: baselines of 30-180 wavelengths, i.e. 1.875 to 11.25 cells
_STUDY_CELL, _STUDY_UV = 16.0, (30.0, 180.0)


@dataclass(frozen=True)
class Setup:
    """How one telescope observes in the forecast: its EoR field, beam model, band (from
    ``start_hz``, or ending at ``band_top_hz`` for a beam that stops there) and aperture
    (station or dish diameter, m)."""

    field: str
    beam: str
    label: str
    aperture_m: float
    start_hz: float = 150e6
    band_top_hz: float | None = None

    def freq_min(self, nchan: int) -> float:
        """First channel centre (Hz) of ``nchan`` channels."""
        if self.band_top_hz is None:
            return self.start_hz
        return min(self.start_hz, self.band_top_hz - (nchan - 1) * _CHAN_WIDTH)

    def uv_grid(self, nchan: int) -> tuple[float, tuple[float, float]]:
        """(cell, (uv_min, uv_max)) in wavelengths: one aperture diameter at the band's
        centre per cell, and the study's baseline range in those cells."""
        freq = self.freq_min(nchan) + 0.5 * (nchan - 1) * _CHAN_WIDTH
        cell = self.aperture_m * freq / SPEED_OF_LIGHT
        scale = cell / _STUDY_CELL
        return cell, (_STUDY_UV[0] * scale, _STUDY_UV[1] * scale)

    def grid_args(self, nchan: int) -> list:
        """``msleak grid``'s --cell and --uv-range of :meth:`uv_grid`."""
        cell, uv_range = self.uv_grid(nchan)
        return ["--cell", f"{cell:.6g}", "--uv-range", f"{uv_range[0]:.6g},{uv_range[1]:.6g}"]


#: LOFAR observes its 3C196 window, the southern arrays EoR0 near their zenith; HERA's
#: band starts at 135 MHz, earlier if needed to end inside its beam file (100-145 MHz),
#: the others start at 150 MHz.
SETUPS = {
    "lofar": Setup("3c196", "everybeam", "LOFAR HBA", HBA_FIELD_DIAMETER),
    "ska-low": Setup("eor0", "everybeam", "SKA-Low (approx. core)", STATION_DIAMETER_M),
    "hera": Setup("eor0", "uvbeam", "HERA", HERA_DISH_DIAMETER_M, 135e6, 145e6),
    "mwa": Setup("eor0", "hyperbeam", "MWA (analytic tile)", MWA_TILE_SIZE_M),
}

#: the sizes of ``--quick``, used for every setting the user leaves unset
_QUICK = {"stations": 8, "duration_h": 0.2, "interval_s": 360.0, "nchan": 10, "seeds": 2}
_FULL = {"stations": 48, "duration_h": 1.0, "interval_s": 120.0, "nchan": 50, "seeds": 3}


@dataclass
class ForecastConfig:
    """Parameters of the forecast; None takes the default, or ``quick``'s test size."""

    outdir: Path
    telescopes: tuple = tuple(TELESCOPES)
    seed: int = 2018
    seeds: int | None = None
    stations: int | None = None
    duration_h: float | None = None
    interval_s: float | None = None
    nchan: int | None = None
    quick: bool = False
    #: predict in complex128 arithmetic (docs/leakage.md, "The numerical floor")
    double: bool = True
    #: the instrument's budget runs of each telescope (its noise_sefd unused: see noise)
    instrument: Instrument = Instrument()
    #: thermal noise of the budget runs: an SEFD (Jy) for every telescope, or per telescope
    noise: float | dict | None = None
    #: L_I against the sky's extent: all-sky HEALPix skies of ``nside`` predicted within
    #: each extent (deg from the phase centre) besides the flat 15 deg sky; () for none
    extents: tuple = ()
    nside: int | None = None

    def __post_init__(self):
        self.telescopes = tuple(dict.fromkeys(self.telescopes))
        unknown = [t for t in self.telescopes if t not in SETUPS]
        if unknown or not self.telescopes:
            raise InputError(f"unknown telescope {unknown[0] if unknown else ''!r}: use "
                             f"{', '.join(SETUPS)}")
        for key, value in (_QUICK if self.quick else _FULL).items():
            if getattr(self, key) is None:
                setattr(self, key, value)
        if self.stations < 2 or self.seeds < 1 or self.nchan < 8:
            raise InputError("stations must be at least 2, seeds 1 and nchan 8",
                             param=("stations", "seeds", "nchan"))
        if not (self.duration_h > 0 and self.interval_s > 0
                and self.duration_h * 3600 >= self.interval_s):
            raise InputError(f"duration_h ({self.duration_h} h) and interval_s "
                             f"({self.interval_s} s) must be positive, the duration at least "
                             "one interval", param=("duration_h", "interval_s"))
        self._check_noise()
        self._check_extents()
        if "hera" in self.telescopes and SETUPS["hera"].freq_min(self.nchan) < 100e6:
            raise InputError(f"nchan {self.nchan} channels of {_CHAN_WIDTH / 1e3:g} kHz do "
                             "not fit HERA's beam file (100-145 MHz): use at most 231",
                             param="nchan")

    def _check_extents(self) -> None:
        self.extents, self.nside = check_extents(self.extents, self.nside, self.quick)

    def _check_noise(self) -> None:
        sefd = self.noise if isinstance(self.noise, dict) else \
            {t: self.noise for t in self.telescopes} if self.noise is not None else {}
        unknown = [t for t in sefd if t not in self.telescopes]
        if unknown:
            raise InputError(f"noise is given for {unknown[0]}, which the forecast does not "
                             f"run ({', '.join(self.telescopes)})", param="noise")
        self.instrument.check()
        for value in sefd.values():                  # each telescope's SEFD alone
            Instrument(noise_sefd=value).check()

    @property
    def realisations(self) -> list[int]:
        return [self.seed + k for k in range(self.seeds)]

    def instrument_of(self, tel: str) -> Instrument:
        """The budget runs' corruptions for ``tel``: beam errors only where its beam model
        has them (LOFAR HBA and SKA-Low through the EveryBeam path), its own SEFD."""
        sefd = self.noise.get(tel) if isinstance(self.noise, dict) else self.noise
        errors = self.instrument.beam_errors if SETUPS[tel].beam == "everybeam" else None
        return replace(self.instrument, beam_errors=errors, noise_sefd=sefd)

    @property
    def sky_args(self) -> list:
        """The study's cube, 50 pixels of 0.3 deg (15 deg); 20 (6 deg) with ``quick``."""
        return ["--npix", 20, "--fov", 6.0] if self.quick else ["--npix", 50, "--fov", 15.0]


def _sky_steps(cfg: ForecastConfig, sky: Path) -> tuple[list[Step], dict]:
    """One cube per realisation and band: ``{(seed, freq_min): path}``."""
    steps, cubes = [], {}
    for freq in sorted({SETUPS[t].freq_min(cfg.nchan) for t in cfg.telescopes}):
        for seed in cfg.realisations:
            cube = sky / f"sky_s{seed}_{freq / 1e6:g}MHz.fits"
            cubes[seed, freq] = cube
            steps.append(Step(f"sky-s{seed}-{freq / 1e6:g}MHz",
                              ["sky", cube, "--seed", seed, "--freq-min", freq,
                               "--nchan", cfg.nchan, "--chan-width", _CHAN_WIDTH,
                               *cfg.sky_args, "--overwrite"],
                              outputs=[cube]))
    return steps, cubes


def _telescope_steps(cfg: ForecastConfig, tel: str, cubes: dict) -> list[Step]:
    """Simulate, one predict and one grid of every realisation, PS, leakage."""
    setup = SETUPS[tel]
    tdir = Path(cfg.outdir) / tel
    ms = tdir / f"{tel}.ms"
    names = telescope_layout(tel).innermost(cfg.stations).names
    steps = [Step(f"simulate-{tel}",
                  ["simulate", ms, "--telescope", tel, "--field", setup.field,
                   "--duration", cfg.duration_h, "--interval", cfg.interval_s,
                   "--freq-min", setup.freq_min(cfg.nchan), "--nchan", cfg.nchan,
                   "--chan-width", _CHAN_WIDTH,
                   "--stations", ",".join(names), "--overwrite"], outputs=[ms])]
    predict = ["predict", ms, "--beam", setup.beam, *predict_precision(cfg.double)]
    grid = ["grid", ms, *setup.grid_args(cfg.nchan), "--overwrite"]
    for seed in cfg.realisations:
        predict += ["--sky", cubes[seed, setup.freq_min(cfg.nchan)], "--column",
                    f"MODEL_S{seed}"]
        grid += ["--column", f"MODEL_S{seed}", "-o", tdir / f"grid_s{seed}.h5"]
    steps += [Step(f"predict-{tel}", predict, after=[f"simulate-{tel}"], outputs=[ms],
                   inputs=[cubes[s, setup.freq_min(cfg.nchan)] for s in cfg.realisations]),
              Step(f"grid-{tel}", grid, after=[f"predict-{tel}"], reads=[ms],
                   outputs=[tdir / f"grid_s{s}.h5" for s in cfg.realisations])]
    for seed in cfg.realisations:
        grid_h5, delay, ps = (tdir / f"{x}_s{seed}.h5" for x in ("grid", "delay", "ps"))
        steps += [Step(f"transform-{tel}-s{seed}", ["transform", grid_h5, "-o", delay,
                                                    "--overwrite"],
                       inputs=[grid_h5], outputs=[delay]),
                  Step(f"ps-{tel}-s{seed}", ["ps", delay, "-o", ps, "--overwrite"],
                       inputs=[delay], outputs=[ps])]
    ps_files = [tdir / f"ps_s{s}.h5" for s in cfg.realisations]
    steps.append(Step(f"leakage-{tel}",
                      ["leakage", *ps_files, "--labels",
                       ",".join(f"s{s}" for s in cfg.realisations), "--realisations",
                       ",".join(map(str, cfg.realisations)), "--field-name", setup.label,
                       "-o", tdir / "leakage", "--no-pdf", "--overwrite"],
                      inputs=ps_files, outputs=[tdir / "leakage" / "leakage.h5"]))
    return steps


def extent_run(cfg: ForecastConfig, tel: str) -> ExtentRun:
    """The extent runs of ``tel``: its MS, beam, grid and the all-sky sky of its band."""
    setup = SETUPS[tel]
    freq = setup.freq_min(cfg.nchan)
    sky = Path(cfg.outdir) / "sky"
    return ExtentRun(
        name=tel, label=setup.label, ms=Path(cfg.outdir) / tel / f"{tel}.ms",
        outdir=Path(cfg.outdir) / tel,
        predict=["--beam", setup.beam, *predict_precision(cfg.double)],
        grid=setup.grid_args(cfg.nchan), ps=[],
        skies={s: sky / f"allsky_s{s}_{freq / 1e6:g}MHz.skyh5" for s in cfg.realisations},
        extents=cfg.extents, after=f"grid-{tel}", field_name=setup.label)


def _allsky_steps(cfg: ForecastConfig) -> list[Step]:
    """One all-sky HEALPix sky per realisation and band."""
    steps = {}
    for tel in cfg.telescopes:
        freq = SETUPS[tel].freq_min(cfg.nchan)
        for seed, path in extent_run(cfg, tel).skies.items():
            steps[path] = allsky_step(path, cfg.nside, seed, [
                "--freq-min", freq, "--nchan", cfg.nchan, "--chan-width", _CHAN_WIDTH])
    return list(steps.values())


def _budget_steps(cfg: ForecastConfig, tel: str, cubes: dict) -> list[Step]:
    """The instrument's budget runs of ``tel`` on the first sky realisation
    (:func:`msleak.study.pipeline.budget_steps`)."""
    setup, seed = SETUPS[tel], cfg.seed
    tdir = Path(cfg.outdir) / tel
    budget = Budget(ms=tdir / f"{tel}.ms", outdir=tdir, sky=cubes[seed, setup.freq_min(
        cfg.nchan)], label=f"s{seed}", name=tel, predict=["--beam", setup.beam,
                                                          *predict_precision(cfg.double)],
        grid=setup.grid_args(cfg.nchan), ps=[], ideal_column=f"MODEL_S{seed}",
        after=(f"grid-{tel}", f"predict-{tel}"),
        field_name=setup.label, leakage=("--no-pdf",))
    instrument = cfg.instrument_of(tel)
    return budget_steps(budget, instrument.runs(), instrument.noise_sefd)


def forecast_steps(cfg: ForecastConfig) -> list[Step]:
    """Every step of the forecast, in order."""
    steps, cubes = _sky_steps(cfg, Path(cfg.outdir) / "sky")
    if cfg.extents:
        steps += _allsky_steps(cfg)
    for tel in cfg.telescopes:
        steps += _telescope_steps(cfg, tel, cubes)
    for tel in cfg.telescopes:
        steps += _budget_steps(cfg, tel, cubes)
        if cfg.extents:
            steps += extent_steps(extent_run(cfg, tel))
    return steps


def _summary_row(cfg: ForecastConfig, tel: str) -> dict:
    """The table row of one telescope: mean +- std over realisations."""
    tdir = Path(cfg.outdir) / tel
    result = open_product(tdir / "leakage" / "leakage.h5", "leakage")
    medians = np.asarray(result["median"].values, dtype=float)
    pareto = np.asarray(result["pareto_median"].values, dtype=float)
    window = np.array([window_leakage(open_product(tdir / f"ps_s{s}.h5", "ps"))
                       for s in cfg.realisations])
    setup = SETUPS[tel]

    def spread(x):
        return float(np.nanstd(x, ddof=1)) if np.sum(np.isfinite(x)) > 1 else 0.0

    return {"telescope": tel, "label": setup.label, "field": setup.field.upper(),
            "beam": setup.beam, "stations": cfg.stations,
            "band_mhz": f"{setup.freq_min(cfg.nchan) / 1e6:g}-"   # first and last centres
                        f"{(setup.freq_min(cfg.nchan) + (cfg.nchan - 1) * _CHAN_WIDTH) / 1e6:.2f}",
            "realisations": len(cfg.realisations),
            "median": float(np.mean(medians)), "median_scatter": spread(medians),
            "pareto_median": float(np.mean(pareto)), "pareto_scatter": spread(pareto),
            "window": float(np.nanmean(window)) if np.isfinite(window).any() else float("nan"),
            "window_scatter": spread(window)}


def write_summary(cfg: ForecastConfig, rows: list[dict], log_: list[dict],
                  seconds: float) -> Path:
    """forecast.csv, figures/forecast.png and forecast.md; returns forecast.md."""
    out = Path(cfg.outdir)
    with (out / "forecast.csv").open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    fig = plot_forecast(rows, out / "figures" / "forecast.png")
    lines = [f"# Leakage forecast (msleak {__version__})", "",
             f"{len(cfg.realisations)} sky realisations (seeds "
             f"{cfg.realisations[0]}..{cfg.realisations[-1]}), the {cfg.stations} innermost "
             f"stations of each array, {cfg.duration_h:g} h centred on transit at "
             f"{cfg.interval_s:g} s, {cfg.nchan} channels of 195.3125 kHz; the beam at the "
             f"phase centre removed. L_I = 100 sqrt(P_I / P_P): the median over the 3D "
             "voxels, then mean +- standard deviation over the realisations; EoR window: "
             "100 sqrt(sum P_I / sum P_P) over the bins above the horizon wedge.", "",
             "| telescope | field | beam | band (MHz) | median L_I (%) | Pareto median (%) "
             "| EoR window L_I (%) |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['label']} | {r['field']} | {r['beam']} | {r['band_mhz']} | "
                     f"{r['median']:.3g} ± {r['median_scatter']:.2g} | "
                     f"{r['pareto_median']:.3g} ± {r['pareto_scatter']:.2g} | "
                     f"{r['window']:.3g} ± {r['window_scatter']:.2g} |")
    lines += _budget_lines(cfg)
    if cfg.extents:
        lines += extent_lines([extent_run(cfg, t) for t in cfg.telescopes], out, cfg.nside)
    lines += ["", f"![forecast]({fig.relative_to(out)})", "",
              f"## Commands ({seconds:.0f} s)", "", "```"]
    lines += [f"{s['command']}{'   # up to date, skipped' if s['skipped'] else ''}"
              for s in log_]
    lines += ["```", ""]
    path = out / "forecast.md"
    path.write_text("\n".join(lines))
    return path


def _budget_lines(cfg: ForecastConfig) -> list[str]:
    """The instrument's budget table of every telescope with budget runs, and the smallest
    L_I its thermal noise lets it detect."""
    lines, notes = [], []
    for tel in cfg.telescopes:
        tdir, label = Path(cfg.outdir) / tel, f"s{cfg.seed}"
        ideal = [r for r in stats_rows(tdir / "leakage" / "stats.csv") if r["label"] == label]
        found = [(text, rows) for kind, text in BUDGET_KINDS.items()
                 if (rows := stats_rows(tdir / f"leakage_{kind}" / "stats.csv"))]
        if not found or not ideal:
            continue
        for text, rows in [("ideal instrument", ideal), *found]:
            lines.append(f"| {SETUPS[tel].label} | {text} | {len(rows)} | "
                         f"{spread_text([float(r['median']) for r in rows])} | "
                         f"{spread_text([float(r['pareto_median']) for r in rows])} |")
        instrument = cfg.instrument_of(tel)
        if instrument.noise_sefd is not None:
            notes += [f"{SETUPS[tel].label}: " + text for text in detectable_text(
                tdir / "ps_noise0.h5", [tdir / f"ps_noise{r}.h5" for r in
                                          range(1, instrument.seeds + 1)],
                instrument.noise_sefd, tdir / f"{tel}.ms") if text]
    if not lines:
        return []
    skipped = [SETUPS[t].label for t in cfg.telescopes
               if cfg.instrument.beam_errors and SETUPS[t].beam != "everybeam"]
    return ["", "## The instrument's budget", "",
            f"L_I of the first sky realisation (seed {cfg.seed}): median over the 3D voxels, "
            "mean ± standard deviation over the realisations of each corruption alone "
            "(percent; docs/paper.md, \"The instrument's budget\")"
            + (f"; beam-model errors are not modelled for {', '.join(skipped)}"
               if skipped else "") + ".", "",
            "| telescope | varied | realisations | data median | Pareto median |",
            "|---|---|---|---|---|", *lines, "", *notes]


def run_forecast(cfg: ForecastConfig, invoke, overwrite: bool = False,
                 workers: int = 1) -> Path:
    """Run (or resume) the forecast with ``invoke(args)`` running one msleak command line;
    ``overwrite`` reruns every step; at most ``workers`` steps run at once (``invoke`` must
    then be thread-safe, e.g. :class:`msleak.study.steps.ProcessInvoker`). Returns the path
    of ``forecast.md``."""
    out = Path(cfg.outdir)
    for sub in ("sky", "figures", *cfg.telescopes):
        (out / sub).mkdir(parents=True, exist_ok=True)
    runner = StepRunner(out, overwrite=overwrite)
    t0 = time.perf_counter()
    runner.run_all(forecast_steps(cfg), invoke, workers=workers)
    rows = [_summary_row(cfg, tel) for tel in cfg.telescopes]
    return write_summary(cfg, rows, runner.log, time.perf_counter() - t0)
