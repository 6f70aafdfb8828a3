"""What moves L_I: every configuration of docs/sensitivity.md, run with the msleak CLI.

Called by scripts/sensitivity. Each configuration is one chain simulate -> sky -> predict
(15, 9 and 4 deg skies in one pass) -> grid -> transform -> ps -> leakage, and its result
the per-field estimate msleak reports: the mean over the three fields of view of the data
median of L_I over the power-spectrum voxels, with the mean of their bootstrap errors.
Steps whose output exists are skipped, so an interrupted run resumes; results.json keeps
each finished configuration (keyed by factor, label and field).

Two variants need msleak internals and run the predict command in a Python process that
patches the beam model first (nothing in msleak changes):
  frozen beam   BeamModel.jones and jones_factors get every time replaced by one
                instant (the middle or the first time slot of the MS); UVW, phases and
                station coordinates keep the real track.
  element only  LofarFastBeam._jones returns the Hamaker element Jones of each station's
                field (no tile or station array factor), and _jones_factors None, so
                that predict asks for _jones.
A patched run fails if msleak never called the patched code.
The k-space regions (EoR window, wedge) are selected in this script from the PS product's
voxels with msleak.leakage's own functions (see region_stats).
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

QUICK_STATIONS = "CS00[1-7]HBA*,CS01[13]HBA*"
FOVS = (("15deg", 50), ("9deg", 28), ("4deg", 16))
PRESET_HOURS = {"ncp": 13.0, "3c196": 8.0}
FIELDS = ("ncp", "3c196")
SEEDS = (2018, 1, 2, 3, 4)
FACTOR_ORDER = ["baseline", "synthesis time", "beam", "integration", "stations", "grid",
                "region", "sky", "seeds"]

PATCH_FROZEN = """
import sys, numpy as np
from msleak.beam import base
T0 = float(sys.argv.pop(1))
CALLS = []
def frozen(method):
    def at_t0(self, time_mjd_s, *args, **kwargs):
        CALLS.append(1)
        t = np.atleast_1d(np.asarray(time_mjd_s, dtype=float))
        return method(self, np.full_like(t, T0), *args, **kwargs)
    return at_t0
base.BeamModel.jones = frozen(base.BeamModel.jones)
base.BeamModel.jones_factors = frozen(base.BeamModel.jones_factors)
"""

PATCH_ELEMENT = """
import sys, numpy as np
from msleak.beam import lofar_fast as lf
CALLS = []
def _jones(self, time, freq, ra, dec, stations, dtype):
    CALLS.append(1)
    out = np.empty((stations.size, time.size, freq.size, ra.size, 2, 2), dtype)
    first = [int(np.flatnonzero(self._field_station == s)[0]) for s in stations]
    for it, t in enumerate(time):
        d, _, _, ncp = self._directions(float(t), ra, dec)
        north, east = lf.sky_basis(d, ncp)
        cache = {}
        for i, f in enumerate(first):
            g = int(self._field_group[f])
            if g not in cache:
                cache[g] = lf.element_jones(self._group_response[g], self._group_axes[g],
                                            freq, d, north, east)
            out[i, it] = cache[g]
    return out
lf.LofarFastBeam._jones = _jones
lf.LofarFastBeam._jones_factors = lambda self, *args: None   # predict then calls _jones
"""

# runs the command after a patch; fails if msleak never called the patched code (its beam
# API changed), so a variant can never silently equal the unpatched run
RUN_CLI = """
from msleak.cli import cli
rc = cli.main(args=sys.argv[1:], prog_name="msleak", standalone_mode=False)
if rc:
    sys.exit(rc)
if not CALLS:
    sys.exit("scripts/sensitivity.py: msleak never called the patched beam; update the patch")
"""


@dataclass
class Config:
    """One configuration: factor, label and the options of each stage."""

    factor: str
    label: str
    field: str
    sim: dict = field(default_factory=dict)      # msleak simulate options
    sky: dict = field(default_factory=dict)      # msleak sky options (besides --seed)
    seed: int = 2018
    predict: dict = field(default_factory=dict)  # msleak predict options
    patch: str = ""                      # "", "frozen", "frozen-start" or "element"
    grid: dict = field(default_factory=dict)     # msleak grid options
    region: str = "all"                          # all | window | wedge

    @property
    def hours(self) -> float:
        return float(self.sim.get("duration", PRESET_HOURS[self.field]))


def opts(d: dict) -> list[str]:
    out = []
    for k, v in d.items():
        out += [f"--{k}"] if v is True else [f"--{k}", str(v)]
    return out


def key(d: dict) -> str:
    parts = [f"{k}{v}" if v is not True else k for k, v in sorted(d.items())]
    return "_".join(parts).replace("*", "x").replace("[", "").replace("]", "") \
        .replace(",", "+").replace("/", "") or "default"


class Runner:
    """Runs msleak commands once, logging each with its wall time to OUT/commands.tsv."""

    def __init__(self, out: Path):
        self.out = out
        self.log = out / "commands.tsv"

    def msleak(self, args: list, outputs: list[Path], prelude: str = "",
               extra: list | None = None) -> None:
        if all(Path(o).exists() for o in outputs):
            return
        args = [str(a) for a in args]
        print("+", " ".join(["msleak", *args]), flush=True)
        tick = time.perf_counter()
        if prelude:  # a patched beam: its own process, so the patch stays there
            subprocess.run([sys.executable, "-c", prelude + RUN_CLI, *(extra or []), "-q",
                            *args], check=True)
        else:  # msleak's click command in this process (saves the start-up per step)
            from msleak.cli import cli

            rc = cli.main(args=["-q", *args], prog_name="msleak", standalone_mode=False)
            if rc:  # msleak reports its error and returns the status; stop, mark nothing
                raise SystemExit(f"scripts/sensitivity.py: msleak {args[0]} failed (exit {rc}); "
                                 "rerun the script to resume")
        with open(self.log, "a") as fh:
            fh.write(f"{time.perf_counter() - tick:.1f}\t{' '.join(['msleak', *args])}\n")


def sky_cubes(run: Runner, c: Config, nchan: int) -> list[Path]:
    d = run.out / "sky" / f"seed{c.seed}_{key(c.sky)}"
    d.mkdir(parents=True, exist_ok=True)
    cube = d / "sky.fits"
    run.msleak(["sky", cube, "--seed", c.seed, "--nchan", nchan, *opts(c.sky), "--overwrite"],
               [cube])
    out = []
    for label, npix in FOVS:
        crop = d / f"sky_{label}.fits"
        if npix != 50:
            run.msleak(["sky", "--crop", cube, "--crop-npix", npix, crop, "--overwrite"], [crop])
        else:
            crop = cube
        out.append(crop)
    return out


def measurement_set(run: Runner, c: Config) -> Path:
    sim = {k: v for k, v in c.sim.items()
           if not (k == "duration" and float(v) == PRESET_HOURS[c.field])}
    ms = run.out / "ms" / f"{c.field}_{key(sim)}.ms"
    ms.parent.mkdir(parents=True, exist_ok=True)
    done = ms.with_suffix(".done")
    if not done.exists():
        run.msleak(["simulate", ms, "--field", c.field, *opts(sim), "--overwrite"], [done])
        done.touch()
    return ms


def frozen_time(ms: Path, patch: str) -> float:
    """The instant of a frozen beam: the middle time slot ("frozen") or the first one
    ("frozen-start") of the MS."""
    from casacore.tables import table

    with table(str(ms), ack=False) as t:
        times = np.unique(t.getcol("TIME"))
    return float(times[0] if patch == "frozen-start" else times[times.size // 2])


def predicted(run: Runner, c: Config, ms: Path, skies: list[Path]) -> list[str]:
    # "c128col": predicts in complex128 arithmetic into complex128 columns (--double
    # --double-column), not reused from runs that rounded to complex64
    pkey = f"seed{c.seed}_{key(c.sky)}_{key(c.predict)}_{c.patch or 'plain'}_c128col"
    tag = hashlib.sha1(pkey.encode()).hexdigest()[:8].upper()
    cols = [f"M{tag}_{label.upper()}" for label, _ in FOVS]
    done = ms.parent / f"{ms.stem}.{pkey}.done"
    args = ["predict", ms]
    for sky, col in zip(skies, cols):
        args += ["--sky", sky, "--column", col]
    args += [*opts(c.predict), "--double", "--double-column", "--no-progress"]
    prelude, extra = "", None
    if c.patch.startswith("frozen"):
        prelude, extra = PATCH_FROZEN, [repr(frozen_time(ms, c.patch))]
    elif c.patch == "element":
        prelude = PATCH_ELEMENT
    if not done.exists():
        run.msleak(args, [done], prelude, extra)
        done.write_text(json.dumps(cols))
    return cols


def spectra(run: Runner, c: Config, ms: Path, cols: list[str]) -> list[Path]:
    d = run.out / "runs" / ms.stem / f"{cols[0][:9]}_{key(c.grid)}"
    d.mkdir(parents=True, exist_ok=True)
    grids = [d / f"grid_{label}.h5" for label, _ in FOVS]
    args = ["grid", ms]
    for col, g in zip(cols, grids):
        args += ["--column", col, "-o", g]
    run.msleak([*args, *opts(c.grid)], grids)
    ps = []
    for (label, _), g in zip(FOVS, grids):
        delay, p = d / f"delay_{label}.h5", d / f"ps_{label}.h5"
        run.msleak(["transform", g, "-o", delay], [delay])
        run.msleak(["ps", delay, "-o", p], [p])
        ps.append(p)
    run.msleak(["leakage", *ps, "--labels", ",".join(lb for lb, _ in FOVS),
                "--field-name", c.field.upper(), "-o", d / "leakage", "--no-figures"],
               [d / "leakage" / "stats.csv"])
    return ps


def field_value(run: Runner, c: Config) -> dict:
    """Run one configuration; its per-field median L_I and error (percent)."""
    nchan = int(c.sim.get("nchan", 50))
    skies = sky_cubes(run, c, nchan)
    ms = measurement_set(run, c)
    cols = predicted(run, c, ms, skies)
    ps = spectra(run, c, ms, cols)
    if c.region == "all":
        with open(ps[0].parent / "leakage" / "stats.csv") as fh:
            rows = list(csv.DictReader(fh))
        med = [float(r["median"]) for r in rows]
        err = [float(r["median_err"]) for r in rows]
    else:
        med, err = zip(*(region_stats(p, c.region) for p in ps))
    return {"median": float(np.mean(med)), "err": float(np.mean(err)),
            "fov_medians": [round(m, 4) for m in med], "dir": str(ps[0].parent)}


def region_stats(ps_path: Path, region: str) -> tuple[float, float]:
    """Median L_I and its block-bootstrap error over the voxels of one k-space region.

    The voxels and bootstrap groups are msleak leakage's (leakage_voxels, voxel_groups:
    both mirrored voxels of every cell, P_P <= 0 and P_I < 0 masked, 2 x 2 cell blocks,
    200 resamples, seed 0); 'wedge' keeps |k_par| <= s k_perp, 'window' |k_par| > s k_perp,
    s the PS product's horizon wedge slope (wedge_slope_horizon)."""
    import xarray as xr
    from msleak.leakage.analysis import voxel_groups
    from msleak.leakage.fraction import leakage_fraction, voxel_power
    from msleak.leakage.stats import leakage_statistics

    with xr.open_dataset(ps_path, engine="h5netcdf") as ds:
        ds = ds.load()
    p_i, p_p = voxel_power(ds)
    L, mask = leakage_fraction(p_i, p_p, None, "mask")
    kpar = np.abs(ds["k_par3d"].values)[None, :, None]
    kperp = ds["k_perp_cell"].values[None, None, :]
    slope = float(ds.attrs["wedge_slope_horizon"])
    inside = np.broadcast_to(kpar <= slope * kperp, L.shape)[mask == 0]
    groups = voxel_groups(ds, "voxels", "mask", None, None, 2)
    sel = inside if region == "wedge" else ~inside
    st = leakage_statistics(L[mask == 0][sel], 100, 0.99, groups=groups[sel], n_boot=200,
                            seed=0)
    return st.median, st.median_err


def configurations(quick: bool) -> list[Config]:
    """Every configuration, in run order: the most telling first, so that an interrupted
    run has measured those."""
    red = {"stations": QUICK_STATIONS, "interval": 600}
    one_field = {"stations": QUICK_STATIONS.replace("HBA*", "HBA0"), "interval": 600}
    out: list[Config] = [Config("baseline", "reduced size", f, dict(red)) for f in FIELDS]
    for f in FIELDS:
        hours = (1, 2, 4, 8, 13) + ((24,) if f == "ncp" else ())
        out += [Config("synthesis time", f"{h} h", f, {**red, "duration": h}) for h in hours]
    out += [Config("beam", "frozen at mid time", f, dict(red), patch="frozen") for f in FIELDS]
    out += [Config("beam", "frozen at start time", f, dict(red), patch="frozen-start")
            for f in FIELDS]
    if not quick:
        out += [Config("baseline", "full scale", f, {}) for f in FIELDS]
    out.append(Config("beam", "frozen at mid time, 24 h (NCP only)", "ncp",
                      {**red, "duration": 24}, patch="frozen"))
    out += [Config("region", name, f, dict(red), region=r) for f in FIELDS
            for r, name in (("window", "EoR window"), ("wedge", "wedge"))]
    out += [Config("seeds", f"seed {s}", f, dict(red), seed=s) for s in SEEDS for f in FIELDS]
    for f in FIELDS:
        b = dict(red)
        out += [Config("beam", "element only", f, b, patch="element"),
                Config("beam", "no centre correction", f, b,
                       predict={"no-centre-correction": True}),
                Config("beam", "dipole", f, b, predict={"beam": "dipole"})]
    for f in FIELDS:
        b = dict(red)
        out += [Config("grid", "cell 8 lambda", f, b, grid={"cell": 8}),
                Config("grid", "cell 24 lambda", f, b, grid={"cell": 24}),
                Config("grid", "gridder cell", f, b, grid={"gridder": "cell"})]
    for f in FIELDS:
        out += [Config("stations", "9 fields (HBA0 of the 9 stations)", f, one_field),
                Config("integration", "120 s, 20 min", f,
                       {**red, "interval": 120, "duration": 1 / 3}),
                Config("integration", "10 s, 20 min", f,
                       {**red, "interval": 10, "duration": 1 / 3})]
    for f in FIELDS:
        b = dict(red)
        out += [Config("sky", "b-index 3 (flatter)", f, b, sky={"b-index": 3.0}),
                Config("sky", "b-index 4.5 (steeper)", f, b, sky={"b-index": 4.5}),
                Config("sky", "ne-mean 0.0025 (Faraday depths x1/4)", f, b,
                       sky={"ne-mean": 0.0025}),
                Config("sky", "ne-mean 0.04 (Faraday depths x4)", f, b,
                       sky={"ne-mean": 0.04})]
    out += [Config("integration", f"{dt} s, 20 min, beam frozen at mid time (3C196 only)",
                   "3c196", {**red, "interval": dt, "duration": 1 / 3}, patch="frozen")
            for dt in (120, 10)]
    out += [Config("stations", "48 fields, 600 s", f, {"interval": 600}) for f in FIELDS]
    out.append(Config("stations", "48 fields, 600 s, 24 h (NCP only)", "ncp",
                      {"interval": 600, "duration": 24}))
    return out


def write_table(results: list[dict], configs: list[Config], out: Path) -> None:
    cols = ["factor", "label", "field", "hours", "median", "err", "fov_medians", "seconds"]
    with open(out / "sensitivity.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, cols, extrasaction="ignore", lineterminator="\n")
        w.writeheader()
        w.writerows(results)
    by = {k: {} for k in sorted(dict.fromkeys((c.factor, c.label) for c in configs),
                                 key=lambda k: FACTOR_ORDER.index(k[0]))}
    for r in results:
        by.setdefault((r["factor"], r["label"]), {})[r["field"]] = r
    lines = ["| factor | configuration | NCP L_I (%) | 3C196 L_I (%) | NCP / 3C196 |",
             "|---|---|---:|---:|---:|"]
    for (fac, lab), d in by.items():
        cells = []
        for f in FIELDS:
            r = d.get(f)
            cells.append(f"{r['median']:.3f} ± {r['err']:.3f}" if r else "not run")
        ratio = (f"{d['ncp']['median'] / d['3c196']['median']:.2f}"
                 if "ncp" in d and "3c196" in d else "-")
        lines.append(f"| {fac} | {lab} | {cells[0]} | {cells[1]} | {ratio} |")
    scatter = {}
    for f in FIELDS:
        v = [r["median"] for r in results if r["factor"] == "seeds" and r["field"] == f]
        if len(v) > 1:
            scatter[f] = f"{np.mean(v):.3f} ± {np.std(v, ddof=1):.3f} ({len(v)})"
    if scatter:
        lines.append("| seeds | mean ± standard deviation (realisations) | "
                     + " | ".join(scatter.get(f, "not run") for f in FIELDS) + " | - |")
    (out / "sensitivity.md").write_text("\n".join(lines) + "\n")


def draw(results: list[dict], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    fig, (ax_t, ax_f) = plt.subplots(1, 2, figsize=(13, 7.5),
                                     gridspec_kw={"width_ratios": [1, 1.6]})
    colours = {"ncp": "tab:blue", "3c196": "tab:red"}
    for f in FIELDS:
        r = [x for x in results if x["factor"] == "synthesis time" and x["field"] == f]
        if r:
            ax_t.errorbar([x["hours"] for x in r], [x["median"] for x in r],
                          [x["err"] for x in r], marker="o", capsize=3, color=colours[f],
                          label=f.upper())
    for f in FIELDS:
        r = [x for x in results if x["label"] == "full scale" and x["field"] == f]
        if r:
            ax_t.errorbar([r[0]["hours"]], [r[0]["median"]], [r[0]["err"]], marker="s",
                          mfc="none", ms=10, capsize=3, color=colours[f], ls="none",
                          label=f"{f.upper()} full scale")
    ax_t.set_xscale("log")
    ax_t.set_xticks([1, 2, 4, 8, 13, 24], ["1", "2", "4", "8", "13", "24"])
    ax_t.set_xlabel("synthesis time (h)")
    ax_t.set_ylabel("per-field median L_I (%)")
    ax_t.set_title("synthesis time")
    ax_t.legend()
    rows = [r for r in results if r["factor"] != "synthesis time"]
    labels = sorted(dict.fromkeys((r["factor"], r["label"]) for r in rows),
                    key=lambda k: FACTOR_ORDER.index(k[0]))
    y = {lab: i for i, lab in enumerate(labels)}
    for k, f in enumerate(FIELDS):
        rr = [r for r in rows if r["field"] == f]
        ax_f.errorbar([r["median"] for r in rr], [y[(r["factor"], r["label"])] + 0.15 * (k - 0.5)
                                                  for r in rr],
                      xerr=[r["err"] for r in rr], fmt="o", capsize=2, color=colours[f],
                      label=f.upper())
        base = [r for r in rr if r["factor"] == "baseline" and r["label"] == "reduced size"]
        if base:
            ax_f.axvline(base[0]["median"], color=colours[f], ls=":", lw=1)
    ax_f.set_yticks(range(len(labels)), [f"{a}: {b}" for a, b in labels], fontsize=8)
    ax_f.invert_yaxis()
    ax_f.set_xscale("log")
    ax_f.xaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
    ax_f.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax_f.set_xticks([0.1, 0.2, 0.3, 0.5, 0.7, 1, 1.5, 2, 3, 5, 10])
    ax_f.grid(axis="x", alpha=0.3)
    ax_f.set_xlabel("per-field median L_I (%)  (dotted: reduced-size baseline)")
    ax_f.set_title("factors")
    ax_f.legend()
    fig.tight_layout()
    fig.savefig(out / "sensitivity.png", dpi=110)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("outdir")
    ap.add_argument("--quick", action="store_true",
                    help="skip the two full-scale baseline runs")
    ap.add_argument("--only", default="", help="factors to run, comma-separated")
    a = ap.parse_args(argv)
    out = Path(a.outdir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    run = Runner(out)
    only = {s.strip() for s in a.only.split(",") if s.strip()}
    done_file = out / "results.json"
    results = json.loads(done_file.read_text()) if done_file.exists() else []
    have = {(r["factor"], r["label"], r["field"]) for r in results}
    for c in configurations(a.quick):
        if only and c.factor not in only or (c.factor, c.label, c.field) in have:
            continue
        tick = time.perf_counter()
        print(f"== {c.factor}: {c.label} ({c.field})", flush=True)
        r = field_value(run, c)
        r.update(factor=c.factor, label=c.label, field=c.field, hours=c.hours,
                 seconds=round(time.perf_counter() - tick, 1))
        print(f"   L_I = {r['median']:.3f} ± {r['err']:.3f} %", flush=True)
        results.append(r)
        done_file.write_text(json.dumps(results, indent=1))
    order = {(c.factor, c.label, c.field): i for i, c in enumerate(configurations(a.quick))}
    results.sort(key=lambda r: order.get((r["factor"], r["label"], r["field"]), 1e9))
    write_table(results, configurations(a.quick), out)
    draw(results, out)
    print(f"wrote {out / 'sensitivity.md'}, sensitivity.csv, sensitivity.png")


if __name__ == "__main__":
    main()
