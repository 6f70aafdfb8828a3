"""Driver of scripts/bench: runs each stage as a separate process under /usr/bin/time -v,
records wall time and peak memory, and runs the per-topic benchmark scripts
(scripts/bench_*.py), each of which prints one JSON object as its last line of output."""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "bench-output"


def timed(cmd: list[str], cwd: Path) -> dict:
    """Run ``cmd`` under /usr/bin/time -v; wall seconds, peak RSS (MiB), exit code, stdout."""
    t0 = time.perf_counter()
    proc = subprocess.run(["/usr/bin/time", "-v", *cmd], cwd=cwd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", proc.stderr)
    return {"command": " ".join(cmd), "wall_s": round(wall, 2),
            "peak_rss_mib": round(int(rss.group(1)) / 1024, 1) if rss else None,
            "exit": proc.returncode, "stdout": proc.stdout[-4000:],
            "stderr": proc.stderr[-2000:] if proc.returncode else ""}


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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="smaller inputs (a smoke run)")
    ap.add_argument("--only", default="", help="comma-separated stages to run")
    args = ap.parse_args()
    only = set(filter(None, args.only.split(",")))
    OUT.mkdir(exist_ok=True)
    results = {"machine": {"cpus": os.cpu_count(), "python": sys.version.split()[0],
                           "platform": platform.platform()},
               "date": time.strftime("%Y-%m-%d %H:%M"), "stages": {}}
    msleak = [sys.executable, "-m", "msleak", "-q"]

    def want(stage):
        return not only or stage in only

    if want("simulate"):
        for interval in ([120] if args.quick else [120, 10]):
            ms = OUT / f"ncp_{interval}s.ms"
            r = timed([*msleak, "simulate", str(ms), "--field", "ncp", "--interval",
                       str(interval), "--overwrite"], OUT)
            r["size_mib"] = du_mib(ms) if ms.exists() else None
            results["stages"][f"simulate_ncp_{interval}s"] = r
            if interval == 10 and ms.exists():
                subprocess.run(["rm", "-rf", str(ms)])
    for stage in ("beam", "predict", "ps", "leakage", "sky"):
        script = ROOT / "scripts" / f"bench_{stage}.py"
        if want(stage) and script.exists():
            cmd = [sys.executable, str(script), "--outdir", str(OUT)]
            if args.quick:
                cmd.append("--quick")
            r = timed(cmd, OUT)
            r["result"] = last_json(r["stdout"])
            results["stages"][stage] = r
    (OUT / "bench.json").write_text(json.dumps(results, indent=1))
    write_markdown(results, ROOT / "docs" / "benchmarks.md")
    print(json.dumps({k: {"wall_s": v["wall_s"], "peak_rss_mib": v["peak_rss_mib"],
                          "exit": v["exit"]} for k, v in results["stages"].items()}, indent=1))
    return 0 if all(v["exit"] == 0 for v in results["stages"].values()) else 1


def write_markdown(results: dict, path: Path) -> None:
    m = results["machine"]
    lines = ["# msleak benchmarks", "",
             f"Measured by `scripts/bench` on {results['date']} ({m['cpus']} cores, "
             f"Python {m['python']}, {m['platform']}). Each stage runs as its own process; "
             "wall time and peak resident memory come from `/usr/bin/time -v`.", "",
             "| stage | wall (s) | peak memory (MiB) | notes |", "|---|---|---|---|"]
    for name, r in results["stages"].items():
        note = ""
        if "size_mib" in r and r["size_mib"] is not None:
            note = f"MS size {r['size_mib']:.0f} MiB"
        if r["exit"]:
            note = f"FAILED (exit {r['exit']})"
        lines.append(f"| {name} | {r['wall_s']:.1f} | {r['peak_rss_mib']} | {note} |")
    for name, r in results["stages"].items():
        if r.get("result"):
            lines += ["", f"## {name}", "", "```json", json.dumps(r["result"], indent=1), "```"]
    path.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    sys.exit(main())
