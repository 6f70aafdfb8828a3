"""Driver of scripts/bench: build the paper-scale inputs, time every msleak stage with its
peers side by side, and write bench-output/bench.json and docs/benchmarks.md.

Each stage runs as its own process under /usr/bin/time -v (wall time, CPU time, peak
memory: the largest process's resident set, or the whole process tree's proportional set
size sampled every 0.2 s when that is larger). The per-topic scripts (scripts/bench_*.py,
each accepting ``--outdir DIR --quick`` and printing one JSON object as its last line) time
the peers:
EveryBeam direct (beam), DP3 predict + applybeam (predict), ps_eor (PS of an image cube),
and the scaling of predict and grid with sources, stations, times and channels.
scripts/bench_degrid.py holds the stage group ``degrid`` (``msleak predict --method degrid``
against the direct predict, and on skies of up to 512 x 512 pixels).
scripts/bench_allsky.py times ``msleak predict`` of all-sky HEALPix skies (NSIDE 128 and
256, LOFAR and HERA) and runs it side by side with matvis (stage ``allsky``).

Paper scale (docs/science.md section 2-3): NCP, 13 h of 120 s slots, the 48 LOFAR HBA core fields, 50
channels of 195.3125 kHz from 150 MHz, a 50 x 50-pixel Q/U sky cube over 15 deg (2500
sources), the LOFAR beam with the phase-centre correction, 30-180 wavelengths.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = ROOT / "scripts"


def _tree_pss_kib(pid: int) -> int:
    """Proportional set size (KiB) of ``pid`` and all its descendants, summed (shared pages
    counted once over the processes that share them), from /proc."""
    children: dict[int, list[int]] = {}
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            with open(f"/proc/{entry.name}/stat") as fh:
                ppid = int(fh.read().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        children.setdefault(ppid, []).append(int(entry.name))
    total, todo = 0, [pid]
    while todo:
        p = todo.pop()
        todo += children.get(p, [])
        try:
            with open(f"/proc/{p}/smaps_rollup") as fh:
                total += next(int(line.split()[1]) for line in fh if line.startswith("Pss:"))
        except (OSError, StopIteration):
            continue
    return total


def timed(cmd: list, cwd: Path, env: dict | None = None, keep: str | None = None) -> dict:
    """Run ``cmd`` under /usr/bin/time -v; wall seconds, peak resident memory (MiB), CPU
    seconds (user + system, a check on wall times taken while other jobs shared the
    machine), exit code, output. The peak is the larger of the largest single process's
    (time -v, RSS) and the whole process tree's proportional set size sampled every
    0.2 s, so commands that run steps in worker processes (msleak paper --workers) count
    them all. ``keep``: a regular expression; the stderr lines it matches are returned
    as ``log`` (each once, in order)."""
    t0 = time.perf_counter()
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen(["/usr/bin/time", "-v", *map(str, cmd)], cwd=cwd, env=env,
                                stdout=out, stderr=err, text=True)
        tree_kib = 0
        while proc.poll() is None:
            tree_kib = max(tree_kib, _tree_pss_kib(proc.pid))
            time.sleep(0.2)
        wall = time.perf_counter() - t0
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", stderr)
    cpu = [float(m) for m in re.findall(r"(?:User|System) time \(seconds\): ([\d.]+)",
                                        stderr)]
    largest_kib = int(rss.group(1)) if rss else 0
    log = {"log": grep_log(stderr, keep)} if keep else {}
    return {"command": " ".join(map(str, cmd)).replace(str(ROOT) + "/", ""),
            "wall_s": round(wall, 2),
            "peak_rss_mib": round(max(largest_kib, tree_kib) / 1024, 1) if rss else None,
            "peak_largest_process_mib": round(largest_kib / 1024, 1) if rss else None,
            "cpu_s": round(sum(cpu), 2) if cpu else None,
            "exit": proc.returncode, "stdout": stdout[-4000:],
            "stderr": stderr[-2000:] if proc.returncode else "", **log}


def grep_log(stderr: str, pattern: str) -> list[str]:
    """The distinct matches of ``pattern`` in ``stderr``, in order."""
    seen: list[str] = []
    for m in re.finditer(pattern, stderr):
        if m.group(0) not in seen:
            seen.append(m.group(0))
    return seen


def last_json(text: str):
    for line in reversed(text.strip().splitlines()):
        line = line.strip()
        if line.startswith("{"):
            try:
                return json.loads(line)
            except json.JSONDecodeError:
                return None
    return None


def du_mib(path: Path) -> float:
    total = sum(p.stat().st_size for p in Path(path).rglob("*") if p.is_file())
    return round(total / 2**20, 1)


def ensure_ps_eor() -> str:
    """'' if ps_eor imports (installed from PyPI into this environment if needed), else why not."""
    probe = [sys.executable, "-c", "import ps_eor"]
    if subprocess.run(probe, capture_output=True).returncode == 0:
        return ""
    print("bench: installing ps-eor (the PS peer) from PyPI", file=sys.stderr, flush=True)
    pip = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "ps-eor"],
                         capture_output=True, text=True)
    if pip.returncode == 0 and subprocess.run(probe, capture_output=True).returncode == 0:
        return ""
    return "ps_eor not installed and `pip install ps-eor` failed: " + \
        " ".join(pip.stderr.split())[-200:]


def compare_columns(ms: Path, a: str, b: str) -> float:
    """max |a - b| / max |b| of two columns of ``ms`` (read in row chunks)."""
    import casacore.tables as pt
    import numpy as np

    num = den = 0.0
    with pt.table(str(ms), ack=False) as t:
        for start in range(0, t.nrows(), 50_000):
            n = min(50_000, t.nrows() - start)
            x, y = t.getcol(a, start, n), t.getcol(b, start, n)
            num = max(num, float(np.abs(x - y).max()))
            den = max(den, float(np.abs(y).max()))
    return num / den if den else float("nan")


def compare_cubes(a: Path, b: Path) -> float:
    import numpy as np
    import xarray as xr

    with xr.open_dataset(a, engine="h5netcdf") as x, xr.open_dataset(b, engine="h5netcdf") as y:
        va, vb = x["vis"].values, y["vis"].values
    return float(np.abs(va - vb).max() / np.abs(vb).max())


def cpu_model() -> str:
    """The processor as /proc/cpuinfo names it, with its family and model numbers and
    whether it has AVX-512: machines of one kind differ up to twofold in speed."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return platform.processor() or "unknown"
    info = dict(re.findall(r"^(model name|cpu family|model|flags)\s*:\s*(.*)$", text, re.M))
    avx512 = "avx512f" in info.get("flags", "").split()
    return (f"{info.get('model name', 'unknown')} (family {info.get('cpu family', '?')}, "
            f"model {info.get('model', '?')}{', AVX-512' if avx512 else ''})")


def _dp3_per_slot(results: dict) -> float | None:
    """DP3's seconds per 120 s slot of the 48-station MS with 2500 sources, from this run."""
    peer = (results["peers"].get("predict_vs_dp3") or {}).get("result") or {}
    return (peer.get("dp3") or {}).get("per_slot_s")


def bench_many_skies(stage, msleak: list, ms: Path, out: Path, results: dict) -> None:
    """predict of 1, 3 and 15 skies in one pass on the NCP MS, and DP3's time for them."""
    import casacore.tables as pt
    import numpy as np
    from bench_multisky import dp3_estimate, make_skies, predict_many

    skies = make_skies(stage, msleak, out / "skies")
    runs = predict_many(stage, msleak, ms, skies)
    with pt.table(str(ms), ack=False) as t:
        rows = t.nrows()
        per_slot = int(np.unique(t.getcol("TIME"), return_counts=True)[1].max())
    dp3 = _dp3_per_slot(results)
    for n, r in runs.items():
        if dp3:
            r["dp3_estimate_s"] = round(dp3_estimate(dp3, rows, per_slot,
                                                     [s for _, s in skies[:n]]), 1)
            r["speedup_vs_dp3"] = round(r["dp3_estimate_s"] / r["wall_s"], 1)
        results["multisky"][f"predict_{n}_skies"] = r


def bench_predict_process(stage, msleak: list, ms: Path, out: Path, results: dict,
                          hours: float | None) -> None:
    """One whole ``msleak predict`` process against one whole ``DP3`` predict + applybeam
    process on the same MS and makesourcedb sky (2500 flat-spectrum Q/U sources over
    15 deg), each timed from start to exit: interpreter start, imports, set-up, beam,
    writes. ``hours`` None uses the paper MS, else a fresh NCP MS of that length."""
    import casacore.tables as pt
    import numpy as np
    from bench_predict import grid_skymodel

    from dp3run import dp3_available, dp3_environment

    work = out / "process"
    work.mkdir(exist_ok=True)
    if hours is not None:
        ms = work / f"ncp_{hours:g}h.ms"
        subprocess.run([*msleak, "simulate", ms, "--field", "ncp", "--duration", str(hours),
                        "--overwrite"], check=True, stdout=subprocess.DEVNULL)
    with pt.table(str(ms / "FIELD"), ack=False) as t:
        ra0, dec0 = t.getcell("PHASE_DIR", 0).reshape(-1)[:2]
    with pt.table(str(ms), ack=False) as t:
        nrow, slots = t.nrows(), len(np.unique(t.getcol("TIME")))
    sky = work / "sky.skymodel"
    nsrc = grid_skymodel(sky, 50, 15.0, ra0, dec0)
    r = {"ms": ms.name, "rows": nrow, "slots": slots, "sources": nsrc}
    # numba's cache warmed, untimed, on the first slots of the same MS
    warm = work / "warm.ms"
    subprocess.run([*msleak, "simulate", warm, "--field", "ncp", "--duration", "0.1",
                    "--overwrite"], check=True, stdout=subprocess.DEVNULL)
    subprocess.run([*msleak, "predict", warm, "--sky", sky, "--no-progress", "--restart"],
                   check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    shutil.rmtree(warm, ignore_errors=True)
    r["msleak"] = stage("predict_process_msleak", [*msleak, "predict", ms, "--sky", sky,
                                                   "--column", "MSLEAK_PROCESS",
                                                   "--no-progress", "--restart"], "peers")
    if dp3_available():
        parset = work / "dp3.parset"
        parset.write_text("\n".join([
            f"msin={ms}", "msout=.", "msout.datacolumn=DP3_PROCESS",
            "steps=[predict,applybeam]", "predict.type=predict", f"predict.sourcedb={sky}",
            "predict.usebeammodel=true", "predict.beammode=full", "predict.beamproximitylimit=0",
            "applybeam.type=applybeam",
            "applybeam.invert=true", "applybeam.beammode=full"]) + "\n")
        dp3 = [sys.executable, "-c", "import sys, dp3; sys.argv = ['DP3'] + sys.argv[1:]; "
               "sys.exit(dp3.entrypoint())", parset]
        r["dp3"] = stage("predict_process_dp3", dp3, "peers", env=dp3_environment())
        if not (r["msleak"]["exit"] or r["dp3"]["exit"]):
            r["speedup_wall"] = round(r["dp3"]["wall_s"] / r["msleak"]["wall_s"], 1)
            r["speedup_cpu"] = round(r["dp3"]["cpu_s"] / r["msleak"]["cpu_s"], 1)
            with pt.table(str(ms), ack=False) as t:
                a, b = t.getcol("MSLEAK_PROCESS"), t.getcol("DP3_PROCESS")
            r["stokes_i_rel_rms"] = float(np.sqrt(np.mean(np.abs(
                (a - b)[..., 0] + (a - b)[..., 3]) ** 2) / np.mean(np.abs(b[..., 0] + b[..., 3])
                                                                    ** 2)))
    results["peers"]["predict_process"] = r


def bench_study(stage, msleak: list, out: Path, results: dict, quick: bool) -> None:
    """The whole study with one and with five sky realisations (and one with --workers 1),
    and DP3's predict time."""
    from bench_multisky import FIELDS_OF_VIEW, dp3_estimate, study, study_rows

    dp3 = _dp3_per_slot(results)
    # the steps in turn in one process, for the gain of --workers (the default, 2)
    results["study"]["paper_seeds1_workers1"] = study(stage, msleak, out, 1, quick, workers=1)
    for seeds in (1, 5):
        r = study(stage, msleak, out, seeds, quick)
        if dp3 and not r["exit"]:
            sources = [npix * npix for _, npix in FIELDS_OF_VIEW] * seeds
            r["dp3_predict_estimate_s"] = round(sum(
                dp3_estimate(dp3, rows, per_slot, sources)
                for rows, per_slot in study_rows(out / f"paper_seeds{seeds}").values()), 1)
        results["study"][f"paper_seeds{seeds}"] = r


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="small inputs (a smoke run, minutes)")
    ap.add_argument("--only", default="", help="comma-separated stages or groups to run "
                    "(simulate, sky, beam, predict, grid, transform, ps, leakage, peers, "
                    "beam_peer, predict_peer, ps_peer, schedulers, predict_schedulers, "
                    "grid_schedulers, scaling, predict_process, multisky, study, degrid, allsky)")
    ap.add_argument("--process-hours", type=float, default=None,
                    help="predict_process on a fresh NCP MS of this many hours instead of "
                         "the paper MS (DP3 takes about 5 s per slot there: 35 min for 13 h)")
    ap.add_argument("--degrid-hours", type=float, default=None,
                    help="degrid on a fresh NCP MS of this many hours instead of the paper "
                         "MS (--quick: of 7 stations; default 0.5 h)")
    ap.add_argument("--outdir", default=str(ROOT / "bench-output"))
    ap.add_argument("--doc", default=str(ROOT / "docs" / "benchmarks.md"),
                    help="Markdown report ('' for none)")
    ap.add_argument("--keep", action="store_true", help="keep the Measurement Sets")
    args = ap.parse_args()
    only = set(filter(None, args.only.split(",")))
    out = Path(args.outdir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    results = {"machine": {"cpus": os.cpu_count(), "cpu": cpu_model(),
                           "python": sys.version.split()[0],
                           "platform": platform.platform(), "load_avg_start": os.getloadavg()},
               "date": time.strftime("%Y-%m-%d %H:%M"), "quick": args.quick,
               "stages": {}, "peers": {}, "schedulers": {}, "multisky": {}, "study": {},
               "degrid": {}, "notes": []}
    previous = out / "bench.json"
    if only and previous.exists():  # a partial rerun updates the last full results
        old = json.loads(previous.read_text())
        for group in ("stages", "peers", "schedulers", "multisky", "study", "degrid"):
            results[group] = old.get(group, {})
        results["notes"] = old.get("notes", [])
        results["notes"].append(
            f"{time.strftime('%Y-%m-%d %H:%M')}: rerun of {', '.join(sorted(only))} (`--only`; "
            f"load average {os.getloadavg()[0]:.1f} at its start)")
        results["date"] = old.get("date", results["date"])
        results["machine"] = {**results["machine"], **{k: v for k, v in old.get(
            "machine", {}).items() if k.startswith("load_avg")}}
    msleak = [sys.executable, "-m", "msleak", "-q"]
    stages = results["stages"]

    def want(*names):
        return not only or bool(only & set(names))

    def stage(name, cmd, group=None, env=None, keep=None):
        print(f"bench: {name} ...", file=sys.stderr, flush=True)
        r = timed(cmd, out, env, keep)
        (stages if group is None else results[group])[name] = r
        print(f"bench: {name}: {r['wall_s']:.1f} s, peak {r['peak_rss_mib']} MiB"
              + (f", FAILED exit {r['exit']}: {r['stderr'][-300:]}" if r["exit"] else ""),
              file=sys.stderr, flush=True)
        return r

    size = (["--duration", "2", "--stations", "CS00[1-7]HBA*"] if args.quick else [])
    ms = out / "ncp.ms"
    sky = out / "sky.fits"
    # 1. inputs at the paper's scale, timed as stages
    if want("simulate") or not (ms / "table.dat").exists():
        r = stage("simulate", [*msleak, "simulate", ms, "--field", "ncp", *size, "--overwrite"])
        r["size_mib"] = du_mib(ms) if ms.exists() else None
    if want("sky") or not sky.exists():
        stage("sky", [*msleak, "sky", sky, "--seed", "1", "--overwrite"])
    # 2. the chain, default options (scheduler threads on all cores)
    if want("beam"):
        stage("beam", [*msleak, "beam", ms, "-o", out / "beam.png", "--overwrite"])
    if want("predict"):
        stage("predict", [*msleak, "predict", ms, "--sky", sky, "--no-progress", "--restart"])
    if want("grid"):
        stage("grid", [*msleak, "grid", ms, "--column", "MODEL_DATA", "-o", out / "grid.h5",
                       "--overwrite"])
    if want("transform"):
        stage("transform", [*msleak, "transform", out / "grid.h5", "-o", out / "delay.h5",
                            "--overwrite"])
    if want("ps"):
        stage("ps", [*msleak, "ps", out / "delay.h5", "-o", out / "ps.h5",
                     "--plot", out / "ps.png", "--overwrite"])
    if want("leakage"):
        stage("leakage", [*msleak, "leakage", out / "ps.h5", "-o", out / "leakage",
                          "--field-name", "NCP", "--overwrite"])
    # 3. schedulers: predict of a 1 h MS and grid of the paper MS, sync / threads / processes
    if want("schedulers", "predict_schedulers"):
        small = out / "ncp_1h.ms"
        subprocess.run([*msleak, "simulate", small, "--field", "ncp", "--duration",
                        "0.5" if args.quick else "1", *size[2:], "--overwrite"], check=True)
        for sched in ("sync", "threads", "processes"):
            stage(f"predict_1h_{sched}", [*msleak, "predict", small, "--sky", sky,
                                          "--column", f"MODEL_{sched.upper()}",
                                          "--scheduler", sched, "--no-progress"], "schedulers")
        for sched in ("threads", "processes"):
            results["schedulers"][f"predict_1h_{sched}"]["max_rel_diff_vs_sync"] = \
                compare_columns(small, f"MODEL_{sched.upper()}", "MODEL_SYNC")
        if not args.keep:
            shutil.rmtree(small, ignore_errors=True)
    if want("schedulers", "grid_schedulers"):
        for sched in ("sync", "threads", "processes"):
            stage(f"grid_{sched}", [*msleak, "grid", ms, "--column", "MODEL_DATA", "-o",
                                    out / f"grid_{sched}.h5", "--scheduler", sched,
                                    "--overwrite"],
                  "schedulers")
        for sched in ("threads", "processes"):
            if (out / f"grid_{sched}.h5").exists() and (out / "grid_sync.h5").exists():
                results["schedulers"][f"grid_{sched}"]["max_rel_diff_vs_sync"] = \
                    compare_cubes(out / f"grid_{sched}.h5", out / "grid_sync.h5")
    # 4. peers side by side, and the scaling table
    quick = ["--quick"] if args.quick else []
    if want("peers", "beam_peer"):
        r = stage("beam_vs_everybeam", [sys.executable, SCRIPTS / "bench_beam.py",
                                        "--outdir", out, *quick], "peers")
        r["result"] = last_json(r["stdout"])
    if want("peers", "predict_peer", "multisky", "study"):
        r = stage("predict_vs_dp3", [sys.executable, SCRIPTS / "bench_predict.py",
                                     "--outdir", out, *quick], "peers")
        r["result"] = last_json(r["stdout"])
    if want("peers", "ps_peer"):
        why = ensure_ps_eor()
        if why:
            results["notes"].append(why)
        r = stage("ps_image_vs_ps_eor", [sys.executable, SCRIPTS / "bench_ps.py", "--outdir",
                                         out, "--skip-ms", *quick], "peers")
        r["result"] = last_json(r["stdout"])
    if want("scaling"):
        r = stage("scaling", [sys.executable, SCRIPTS / "bench_scaling.py", "--outdir", out,
                              *quick], "peers")
        r["result"] = last_json(r["stdout"])
    if want("peers", "predict_process"):
        bench_predict_process(stage, msleak, ms, out, results,
                              0.2 if args.quick else args.process_hours)
    if want("multisky") and not args.quick:
        bench_many_skies(stage, msleak, ms, out, results)
    if want("study"):
        bench_study(stage, msleak, out, results, args.quick)
    if want("allsky"):
        r = stage("allsky", [sys.executable, SCRIPTS / "bench_allsky.py", "--outdir", out,
                             *quick], "peers")
        r["result"] = last_json(r["stdout"])
    if want("degrid"):
        from bench_degrid import bench_degrid

        bench_degrid(stage, msleak[:-1], ms, sky, out, results, args.quick, args.degrid_hours,
                     args.keep)
    if not only:
        results["machine"]["load_avg_end"] = os.getloadavg()
    if not args.keep and not only:
        shutil.rmtree(out / "predict", ignore_errors=True)
    (out / "bench.json").write_text(json.dumps(results, indent=1, default=str))
    if args.doc:
        from bench_report import write_markdown

        write_markdown(results, Path(args.doc))
    summary = {k: {"wall_s": v["wall_s"], "peak_rss_mib": v["peak_rss_mib"], "exit": v["exit"]}
               for group in ("stages", "schedulers", "peers", "multisky", "study",
                             "degrid")
               for k, v in results[group].items() if "wall_s" in v}
    print(json.dumps(summary, indent=1))
    failed = [k for k, v in summary.items() if v["exit"]]
    if failed:
        print(f"bench: failed stages: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.path.insert(0, str(SCRIPTS))
    sys.exit(main())
