#!/usr/bin/env python
"""The leakage study fed by DP3: msleak's own predict against DP3 predict + applybeam.

Runs the steps of ``msleak paper`` (:func:`msleak.study.pipeline.study_steps`; without the
beam maps) at the ``--quick`` size by default: both fields, one sky realisation, 15, 9 and
4 deg fields of view predicted by msleak into ``MODEL_<FOV>``. Into the same Measurement
Sets DP3 predicts the same voxels (predict through the full LOFAR beam, then applybeam
with invert at the phase centre; :mod:`dp3run`) into ``DP3_<FOV>``, and the study's own
grid, transform, ps and leakage steps run on those columns into ``OUTDIR/<field>/dp3/``.
Two optional routes separate the causes of a difference: ``--turned`` (msleak's columns
with P = Q + iU turned in each time slot by its phase in DP3's columns) and ``--single``
(msleak's predict in complex64 arithmetic into complex64 columns).

Prints, per field and field of view, the median L_I over the 3D voxels of every route and
the per-field estimate (mean of the medians over the fields of view), with the relative
differences; then how the DP3 route differs from msleak's before the statistics: Stokes I
and P of the visibilities (relative rms; the power of the Stokes I difference over that
of msleak's Stokes I at the delays beyond a quarter of the range, and the same for
msleak's values rounded to complex64; the phase of P_DP3 / P_msleak per time slot and what
is left after turning by it), and the cylindrical
power spectra (median over the (k_perp, k_par) bins of the relative difference of P_I and
P_P; the k_par up to which P_I agrees within 1e-3). Writes the tables to
``OUTDIR/crosscheck.md`` and the numbers to ``OUTDIR/crosscheck.json``. Resumable as
``msleak paper`` is: a rerun skips every step whose inputs are unchanged.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from dp3run import dp3_available, predict_cubes  # noqa: E402

from msleak.study.config import FIELDS_OF_VIEW, StudyConfig  # noqa: E402
from msleak.study.pipeline import study_steps  # noqa: E402
from msleak.conventions import correlations_to_stokes, stokes_to_correlations  # noqa: E402,E501
from msleak.errors import MsleakError  # noqa: E402
from msleak.cli import run_command as run_msleak  # noqa: E402
from msleak.study.steps import (ProcessInvoker, Step, StepRunner,  # noqa: E402
                                predict_precision, step_failed)

#: first argument of the steps that run DP3 (every other step is an msleak command line)
DP3_STEP = "dp3-predict"
#: first argument of the steps that write msleak's P turned as DP3's (``turned_route``)
TURN_STEP = "turn-p"


def _dp3_args(args: list[str]) -> tuple[str, int, list[tuple[str, str]]]:
    """(MS, threads, [(cube, column), ...]) of a DP3 step's arguments."""
    ms, threads, skies = args[0], 1, []
    rest = args[1:]
    while rest:
        key, value, *rest = rest
        if key == "--threads":
            threads = int(value)
        elif key == "--sky":
            skies.append((value, None))
        elif key == "--column":
            skies[-1] = (skies[-1][0], value)
    return ms, threads, skies


class Invoker:
    """Runs a step: DP3 steps here, msleak command lines in this process (``workers`` 1)
    or in msleak worker processes (:class:`msleak.study.steps.ProcessInvoker`)."""

    labels_output = True

    def __init__(self, workers: int = 1, rerun: str = "scripts/crosscheck OUTDIR"):
        self.rerun = rerun
        self.workers = ProcessInvoker(["-q"], workers=workers, rerun=rerun) \
            if workers > 1 else None

    def __call__(self, args: list[str], label: str | None = None) -> None:
        if args[0] == DP3_STEP:
            ms, threads, skies = _dp3_args(args[1:])

            def progress(channel, nchan):
                if (channel + 1) % 10 == 0 or channel + 1 == nchan:
                    print(f"[{label}] DP3: {channel + 1}/{nchan} channels", flush=True)

            seconds = predict_cubes(ms, skies, threads=threads, progress=progress)
            print(f"[{label}] DP3 ran {seconds:.1f} s", flush=True)
        elif args[0] == TURN_STEP:
            ms, names = args[1], args[2:]
            turn_columns(ms, list(zip(names[::3], names[1::3], names[2::3])))
        elif self.workers is not None:
            self.workers(args, label=label)
        else:
            rc = run_msleak(["-q", *args])
            if rc != 0:
                raise step_failed(args, rc, "", self.rerun)

    def stop(self) -> None:
        """Interrupt the running msleak steps (a DP3 run finishes its channel)."""
        if self.workers is not None:
            self.workers.stop()

    def close(self) -> None:
        """End the msleak worker processes."""
        if self.workers is not None:
            self.workers.close()


def _to_route(value, fdir: Path, ms: Path, route: str):
    """An msleak-route argument as ``route``'s: products under ``fdir`` move to
    ``fdir/route``, columns ``MODEL_X`` become ``<ROUTE>_X``; everything else is kept."""
    if isinstance(value, Path) and value != ms and fdir in value.parents:
        return fdir / route / value.relative_to(fdir)
    if isinstance(value, str) and value.startswith("MODEL_"):
        return f"{route.upper()}_" + value[len("MODEL_"):]
    return value


def _without_figures(step: Step) -> Step:
    """``step`` without its figures: no ``--plot FIG``, ``leakage --no-figures``."""
    args, outputs = list(step.args), list(step.outputs)
    if "--plot" in args:
        at = args.index("--plot")
        outputs = [p for p in outputs if p != args[at + 1]]
        del args[at:at + 2]
    if args[0] == "leakage":
        args.append("--no-figures")
    return Step(step.name, args, inputs=step.inputs, outputs=outputs, after=step.after,
                reads=step.reads)


def _analysis(steps: list[Step], fld: str, fdir: Path, route: str) -> list[Step]:
    """The field's grid, transform, ps and leakage steps on the columns of ``route``
    (made by its step ``<route>-predict-<field>``)."""
    ms = fdir / f"{fld}.ms"
    own = {f"grid-{fld}", f"leakage-{fld}"}
    out = []
    for step in steps:
        if step.name in own or step.name.startswith((f"transform-{fld}-", f"ps-{fld}-")):
            step = _without_figures(step)          # the figures show msleak's route

            def moved(items):
                return [_to_route(a, fdir, ms, route) for a in items]

            after = [f"{route}-{a}" if a == f"predict-{fld}" else a for a in step.after]
            out.append(Step(f"{route}-{step.name}", moved(step.args),
                            inputs=moved(step.inputs), outputs=moved(step.outputs),
                            after=after, reads=step.reads))
    return out


def _skies(step: Step) -> list[tuple[Path, str]]:
    """The (cube, column) pairs of the study's predict step."""
    args = step.args
    values = [args[k + 1] for k in range(len(args) - 1) if args[k] in ("--sky", "--column")]
    return list(zip(values[::2], values[1::2]))


def dp3_route(steps: list[Step], fld: str, fdir: Path, threads: int = 1) -> list[Step]:
    """The DP3 route of one field: DP3 predicts the skies of the study's predict step into
    ``DP3_<FOV>``, then the field's grid, transform, ps and leakage steps run on those
    columns in ``fdir/dp3``."""
    ms = fdir / f"{fld}.ms"
    (predict,) = [s for s in steps if s.name == f"predict-{fld}"]
    args = [DP3_STEP, ms, "--threads", str(threads)]
    for cube, column in _skies(predict):
        args += ["--sky", cube, "--column", _to_route(column, fdir, ms, "dp3")]
    return [Step(f"dp3-predict-{fld}", args, inputs=predict.inputs, outputs=predict.outputs,
                 after=[f"simulate-{fld}"]), *_analysis(steps, fld, fdir, "dp3")]


def turned_route(steps: list[Step], fld: str, fdir: Path) -> list[Step]:
    """msleak's columns with P = Q + iU turned in each time slot by the phase it has in
    DP3's (``TURNED_<FOV>``), then the field's analysis on them in ``fdir/turned``: what
    the DP3 route's L_I would be if the tools differed only by that rotation."""
    ms = fdir / f"{fld}.ms"
    (predict,) = [s for s in steps if s.name == f"predict-{fld}"]
    args = [TURN_STEP, ms]
    for _, column in _skies(predict):
        args += [column, _to_route(column, fdir, ms, "dp3"),
                 _to_route(column, fdir, ms, "turned")]
    return [Step(f"turned-predict-{fld}", args, outputs=[ms],
                 after=[f"predict-{fld}", f"dp3-predict-{fld}"]),
            *_analysis(steps, fld, fdir, "turned")]


def single_route(steps: list[Step], fld: str, fdir: Path) -> list[Step]:
    """The study's predict in complex64 arithmetic into complex64 columns
    (``SINGLE_<FOV>``, as DP3 writes), then the field's analysis in ``fdir/single``."""
    ms = fdir / f"{fld}.ms"
    (predict,) = [s for s in steps if s.name == f"predict-{fld}"]
    double = predict_precision(True)
    args = [_to_route(a, fdir, ms, "single") for a in predict.args if a not in double]
    return [Step(f"single-predict-{fld}", args, inputs=predict.inputs, outputs=[ms],
                 after=[f"simulate-{fld}"]), *_analysis(steps, fld, fdir, "single")]


#: the optional routes: name -> steps of one field
EXTRA_ROUTES = {"turned": turned_route, "single": single_route}


def crosscheck_steps(cfg: StudyConfig, threads: int = 1, extra: tuple = (),
                     figures: bool = True) -> list[Step]:
    """The study's steps without the beam maps (and without any figure unless
    ``figures``), then each field's DP3 route and the ``extra`` routes (names of
    ``EXTRA_ROUTES``)."""
    if cfg.beam != "everybeam":
        raise ValueError("DP3 predicts through EveryBeam's LOFAR beam: use beam 'everybeam'")
    steps = [s if figures else _without_figures(s) for s in study_steps(cfg)
             if not s.name.startswith("beam-")]
    routes = []
    for fld in cfg.fields:
        routes += dp3_route(steps, fld, Path(cfg.outdir) / fld, threads)
    for name in extra:
        for fld in cfg.fields:
            routes += EXTRA_ROUTES[name](steps, fld, Path(cfg.outdir) / fld)
    return steps + routes


def _medians(leak_dir: Path) -> tuple[dict, float]:
    """({fov label: median L_I %}, mean of the medians %) from a leakage directory."""
    with open(leak_dir / "stats.csv") as fh:
        medians = {row["label"]: float(row["median"]) for row in csv.DictReader(fh)}
    with open(leak_dir / "estimates.csv") as fh:
        field = [float(r["estimate_data"]) for r in csv.DictReader(fh) if r["realisation"] == "all"]
    return medians, field[0]


def _stokes(vis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stokes I and P = Q + iU of (row, chan, XX XY YX YY) visibilities."""
    iquv = correlations_to_stokes(vis)
    return iquv[..., 0], iquv[..., 1] + 1j * iquv[..., 2]


def _slot_turns(pa: np.ndarray, pb: np.ndarray, times: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """(slot index per row, unit phase per slot) of sum(conj(pa) pb) over each time
    slot's rows and channels."""
    slot = np.unique(times, return_inverse=True)[1].reshape(-1)
    turn = np.zeros(slot.max() + 1, complex)
    np.add.at(turn, slot, np.sum(np.conj(pa) * pb, axis=1))
    return slot, np.exp(1j * np.angle(turn))


def turn_columns(ms: str | Path, triples: list[tuple[str, str, str]]) -> None:
    """For each (ours, theirs, out): write into the complex128 column ``out`` the
    visibilities of ``ours`` with P = Q + iU turned in each time slot by the phase of
    sum(conj(P_ours) P_theirs); Stokes I and V are kept."""
    import casacore.tables as pt

    from msleak.io.columns import ensure_data_column

    with pt.table(str(ms), readonly=False, ack=False) as t:
        times = t.getcol("TIME")
        for ours, theirs, out in triples:
            iquv = correlations_to_stokes(t.getcol(ours))
            pa, (_, pb) = iquv[..., 1] + 1j * iquv[..., 2], _stokes(t.getcol(theirs))
            slot, turn = _slot_turns(pa, pb, times)
            p = pa * turn[slot, None]              # Q + iU times exp(i phase)
            iquv[..., 1], iquv[..., 2] = p.real, p.imag
            ensure_data_column(t, out, like=ours, double=True)
            t.putcol(out, stokes_to_correlations(iquv))


def _high_delay_power(stokes_i: np.ndarray) -> float:
    """Mean power of the (row, chan) spectra's delay transforms (Blackman-Harris window)
    at the delays beyond a quarter of the range, where the leaked I is faintest."""
    from scipy.signal.windows import blackmanharris

    nchan = stokes_i.shape[1]
    power = np.abs(np.fft.fft(stokes_i * blackmanharris(nchan), axis=1)) ** 2
    return float(power[:, nchan // 4: nchan - nchan // 4 + 1].mean())


def compare_columns(ms: Path, ours: str, theirs: str) -> dict:
    """How column ``theirs`` differs from ``ours``: relative rms of Stokes I and of P; the
    power of the Stokes I difference over that of ``ours``' Stokes I at high delays
    (:func:`_high_delay_power`), and the same for ``ours`` rounded to complex64; the range
    over time slots of the phase of sum(conj(P_ours) P_theirs) (deg), and the relative rms
    of P_theirs - P_ours turned by that phase in each slot (what is left when P differs by
    a rotation only)."""
    import casacore.tables as pt

    with pt.table(str(ms / "POLARIZATION"), ack=False) as t:
        if list(t.getcell("CORR_TYPE", 0)) != [9, 10, 11, 12]:
            raise ValueError(f"{ms}: expected the correlations XX, XY, YX, YY")
    with pt.table(str(ms), ack=False) as t:
        a, b, times = t.getcol(ours), t.getcol(theirs), t.getcol("TIME")
    (ia, pa), (ib, pb) = _stokes(a), _stokes(b)

    def rel_rms(x, y):
        return float(np.sqrt(np.mean(np.abs(y - x) ** 2) / np.mean(np.abs(x) ** 2)))

    slot, turn = _slot_turns(pa, pb, times)
    high = _high_delay_power(ib - ia) / _high_delay_power(ia)
    rounded = _stokes(a.astype(np.complex64).astype(a.dtype))[0]
    rounding = _high_delay_power(rounded - ia) / _high_delay_power(ia)
    phases = np.degrees(np.angle(turn))
    return {"stokes_i_rel_rms": rel_rms(ia, ib), "p_rel_rms": rel_rms(pa, pb),
            "p_turned_rel_rms": rel_rms(pa * turn[slot, None], pb),
            "p_phase_deg": [float(phases.min()), float(phases.max())],
            "stokes_i_error_high_delay": float(high),
            "stokes_i_rounding_high_delay": float(rounding)}


#: P_I of a k_par row "agrees" when the median over its k_perp bins of |ratio - 1| is below
#: this: 1e-3 is ten times the relative rms of the routes' Stokes I visibilities
#: (1e-4 or less away from the pole), so only a floor or a real difference exceeds it
AGREE = 1e-3


def compare_powers(ours: Path, theirs: Path) -> dict:
    """Per field of view, from two ``leakage.h5`` files: the median over the cylindrical
    (k_perp, k_par) bins of |P_theirs / P_ours - 1| and of P_theirs / P_ours for Stokes I
    and P, and the largest k_par (Mpc^-1) up to which every k_par row's P_I agrees within
    ``AGREE``."""
    import xarray as xr

    out = {}
    with xr.open_dataset(ours, engine="h5netcdf") as a, \
            xr.open_dataset(theirs, engine="h5netcdf") as b:
        k_par = a["k_par"].values
        for k, label in enumerate(a["label"].values):
            entry = out.setdefault(str(label), {})
            for stokes in ("I", "P"):
                x = a[f"power_{stokes}"].values[k]
                y = b[f"power_{stokes}"].values[k]
                used = np.isfinite(x) & np.isfinite(y) & (x > 0)
                rel = np.where(used, np.abs(y / np.where(used, x, 1) - 1), np.nan)
                entry[f"power_{stokes}_bin_rel"] = float(np.nanmedian(rel))
                entry[f"power_{stokes}_median_ratio"] = float(np.median(y[used] / x[used]))
                if stokes == "I":
                    rows = np.nanmedian(rel, axis=1) < AGREE
                    n = len(rows) if rows.all() else int(np.argmin(rows))
                    entry["power_I_agrees_to_k_par"] = float(k_par[n - 1]) if n else None
    return out


def results(cfg: StudyConfig, extra: tuple = ()) -> list[dict]:
    """Per field: the medians per field of view and per-field estimates of msleak's
    route, DP3's and the ``extra`` routes, and how the DP3 route's visibilities and power
    spectra differ from msleak's."""
    routes = ["msleak", "dp3", *extra]
    rows = []
    for fld in cfg.fields:
        fdir = Path(cfg.outdir) / fld
        medians = {r: _medians(fdir / ("" if r == "msleak" else r) / "leakage")
                   for r in routes}
        powers = compare_powers(fdir / "leakage" / "leakage.h5",
                                fdir / "dp3" / "leakage" / "leakage.h5")
        fovs = []
        for label, _ in FIELDS_OF_VIEW:
            vis = compare_columns(fdir / f"{fld}.ms", f"MODEL_{label.upper()}",
                                  f"DP3_{label.upper()}")
            fovs.append({"fov": label, **{r: medians[r][0][label] for r in routes},
                         **vis, **powers[label]})
        rows.append({"field": fld.upper(), "fovs": fovs,
                     **{r: medians[r][1] for r in routes}})
    return rows


#: L_I columns of the table: (header, value of an entry); None when the route is absent
_COLUMNS = (
    ("L_I msleak (%)", lambda e: f"{e['msleak']:.4f}"),
    ("L_I DP3 (%)", lambda e: f"{e['dp3']:.4f}"),
    ("DP3 / msleak - 1", lambda e: f"{e['dp3'] / e['msleak'] - 1:+.2%}"),
    ("L_I msleak, P turned as DP3's (%)", lambda e: f"{e['turned']:.4f}"),
    ("DP3 / turned - 1", lambda e: f"{e['dp3'] / e['turned'] - 1:+.2%}"),
    ("L_I msleak, complex64 (%)", lambda e: f"{e['single']:.4f}"),
    ("complex64 / msleak - 1", lambda e: f"{e['single'] / e['msleak'] - 1:+.2%}"),
)


def table(rows: list[dict]) -> str:
    """The markdown tables of :func:`results`: L_I of the routes, then the differences
    of the DP3 route's visibilities and power spectra from msleak's."""
    def present(fn):
        try:
            fn(rows[0])
            return True
        except KeyError:
            return False

    cols = [(head, fn) for head, fn in _COLUMNS if present(fn)]
    lines = ["| field | field of view | " + " | ".join(h for h, _ in cols) + " |",
             "|---|---|" + "---:|" * len(cols)]
    for r in rows:
        for entry, label in [*((f, f["fov"]) for f in r["fovs"]), (r, "mean of the medians")]:
            lines.append(f"| {r['field']} | {label} | " + " | ".join(fn(entry) for _, fn in cols)
                         + " |")
    lines += ["", "| field | field of view | Stokes I rel. rms | Stokes I error power, "
              "high delays | the same, complex64 rounding | P rel. rms | "
              "phase of P_DP3 / P_msleak (deg) | "
              "P rel. rms after the turn | P_I per bin | P_P per bin | P_P median ratio | "
              "P_I within 1e-3 up to k_par (Mpc^-1) |",
              "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        for f in r["fovs"]:
            lo, hi = f["p_phase_deg"]
            k_par = f["power_I_agrees_to_k_par"]
            lines.append(f"| {r['field']} | {f['fov']} | {f['stokes_i_rel_rms']:.1e} | "
                         f"{f['stokes_i_error_high_delay']:.3g} | "
                         f"{f['stokes_i_rounding_high_delay']:.1e} | {f['p_rel_rms']:.1e} | "
                         f"{lo:+.1f} to {hi:+.1f} | "
                         f"{f['p_turned_rel_rms']:.1e} | {f['power_I_bin_rel']:.1e} | "
                         f"{f['power_P_bin_rel']:.1e} | {f['power_P_median_ratio']:.4f} | "
                         f"{'none' if k_par is None else f'{k_par:.3f}'} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("outdir", type=Path)
    ap.add_argument("--field", action="append", choices=("ncp", "3c196"),
                    help="field (repeatable; default both)")
    ap.add_argument("--seed", type=int, default=2018, help="sky seed (default 2018)")
    ap.add_argument("--stations", help="station pattern (default: msleak paper --quick's)")
    ap.add_argument("--duration", type=float, help="synthesis time, h (default 2)")
    ap.add_argument("--interval", type=float, help="integration, s (default 600)")
    ap.add_argument("--nchan", type=int, help="channels (default 50)")
    ap.add_argument("--workers", type=int, default=1, help="steps at once (default 1)")
    ap.add_argument("--dp3-threads", type=int, default=1, help="DP3 threads (default 1)")
    ap.add_argument("--turned", action="store_true",
                    help="also the study on msleak's columns with P turned as DP3's")
    ap.add_argument("--single", action="store_true",
                    help="also the study predicted by msleak in complex64, as DP3 writes")
    ap.add_argument("--no-figures", dest="figures", action="store_false",
                    help="draw no figure (msleak's route draws the study's by default)")
    ap.add_argument("--overwrite", action="store_true", help="rerun every step")
    args = ap.parse_args(argv)
    if not dp3_available():
        print("crosscheck: the dp3 package is not installed (pip install dp3)", file=sys.stderr)
        return 2
    cfg = StudyConfig(args.outdir, quick=True, seed=args.seed,
                      fields=tuple(args.field or ("ncp", "3c196")), stations=args.stations,
                      duration_h=args.duration, interval_s=args.interval, nchan=args.nchan)
    for sub in ("sky", "figures", *cfg.fields):
        (args.outdir / sub).mkdir(parents=True, exist_ok=True)
    extra = tuple(name for name in EXTRA_ROUTES if getattr(args, name))
    invoke = Invoker(args.workers, rerun=f"scripts/crosscheck {args.outdir}")
    try:
        StepRunner(args.outdir, overwrite=args.overwrite).run_all(
            crosscheck_steps(cfg, args.dp3_threads, extra, args.figures), invoke,
            workers=args.workers)
        rows = results(cfg, extra)
    except (MsleakError, RuntimeError, ValueError) as err:
        print(f"crosscheck: {err}", file=sys.stderr)
        return 1
    finally:
        invoke.close()
    text = table(rows)
    (args.outdir / "crosscheck.md").write_text(text)
    (args.outdir / "crosscheck.json").write_text(json.dumps(rows, indent=1) + "\n")
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
