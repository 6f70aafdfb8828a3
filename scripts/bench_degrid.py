"""Stage group ``degrid`` of scripts/bench: ``msleak predict --method degrid`` against the
direct predict on an NCP MS, side by side in one run.

Runs (each its own process, complex128 arithmetic and columns, each into its own column):
the direct predict of the 50 x 50-pixel sky, and degrid of the 50-, 225- and 512-pixel
skies over 15 deg (``msleak sky --npix N --seed 1``; --quick: 50, 96 and 128 pixels on a
0.5 h MS of 7 stations), the largest with ``--memory-limit 6GB``. numba's cache is warmed
first, untimed, on a 6-minute MS of two stations.

Derived figures, each against the goal it is checked with:

* relative rms of the degrid column against the direct one at 50 pixels,
  sqrt(sum |degrid - direct|^2 / sum |direct|^2), over all correlations and for
  Stokes I (XX + YY);
* wall(degrid of the middle sky) / wall(direct 50), goal < 10: degridding a sky of 20
  times the pixels costs less than 10 times the direct predict of the paper's sky;
* wall and peak memory of the degrid of the largest sky, goals < 3600 s and < 8 GiB;
* the same ratio in CPU seconds and the load average around the runs, for wall times
  taken while other jobs shared the machine.

The goals are set for the paper MS (13 h, 48 stations); a --quick run checks the same
figures on its small inputs, which says little about the paper scale.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

#: sky sizes (pixels a side): the direct/degrid comparison, the ratio's sky, the largest
SIZES = (50, 225, 512)
QUICK_SIZES = (50, 96, 128)
QUICK_STATIONS = "CS00[1-7]HBA*"
#: goals (the project's targets for the paper MS)
GOAL_RATIO = 10.0
GOAL_WALL_S = 3600.0
GOAL_PEAK_MIB = 8 * 1024.0
MEMORY_LIMIT = "6GB"
#: -v log lines kept from each predict's stderr: the subgrid chosen and the method per sky
LOG_LINES = r"degrid \d+ x \d+ pixels: .*|sky .*predicted by .*"
COMMON = ["--double", "--double-column", "--no-progress", "--restart"]


def rel_rms(ms: Path, column: str, reference: str, rows: int = 20_000) -> dict:
    """Relative rms of ``column`` against ``reference`` in ``ms`` (read in row chunks):
    over all correlations, and for Stokes I (correlations 0 + 3: XX + YY), with the
    columns' value types (complex128 columns are 'dcomplex')."""
    import casacore.tables as pt
    import numpy as np

    num = den = num_i = den_i = 0.0
    with pt.table(str(ms), ack=False) as t:
        types = {c: t.getcoldesc(c)["valueType"] for c in (column, reference)}
        for start in range(0, t.nrows(), rows):
            n = min(rows, t.nrows() - start)
            a, b = t.getcol(column, start, n), t.getcol(reference, start, n)
            d = a - b
            num += float(np.sum(np.abs(d) ** 2))
            den += float(np.sum(np.abs(b) ** 2))
            num_i += float(np.sum(np.abs(d[..., 0] + d[..., 3]) ** 2))
            den_i += float(np.sum(np.abs(b[..., 0] + b[..., 3]) ** 2))
    return {"rel_rms": float(np.sqrt(num / den)) if den else None,
            "stokes_i_rel_rms": float(np.sqrt(num_i / den_i)) if den_i else None,
            "value_types": types}


def _remove_columns(ms: Path, columns: list[str]) -> None:
    import casacore.tables as pt

    with pt.table(str(ms), readonly=False, ack=False) as t:
        present = [c for c in columns if c in t.colnames()]
        if present:
            t.removecols(present)


def _check(value, goal: float) -> bool | None:
    return None if value is None else bool(value < goal)


def bench_degrid(stage, msleak: list, ms: Path, sky: Path, out: Path, results: dict,
                 quick: bool, hours: float | None, keep: bool) -> None:
    """Run the group's stages into ``results["degrid"]`` and add the derived figures as
    ``results["degrid"]["figures"]``.

    ``msleak`` is the command prefix without a verbosity flag (the stages run with ``-v``
    to log the subgrid chosen); ``ms`` the paper MS, used when ``hours`` is None and not
    ``quick``; ``sky`` the bench's 50 x 50-pixel sky. The columns written into the paper
    MS, or the fresh MS, are removed afterwards unless ``keep``."""
    import casacore.tables as pt
    import numpy as np

    work = out / "degrid"
    work.mkdir(exist_ok=True)
    group = results["degrid"] = {}  # measured as a whole, never merged
    small, mid, big = QUICK_SIZES if quick else SIZES
    stations = ["--stations", QUICK_STATIONS] if quick else []
    fresh = quick or hours is not None
    if fresh:
        hours = 0.5 if hours is None else hours
        ms = work / f"ncp_{hours:g}h.ms"
        subprocess.run([*msleak, "-q", "simulate", ms, "--field", "ncp", "--duration",
                        str(hours), *stations, "--overwrite"], check=True,
                       stdout=subprocess.DEVNULL)
    skies = {small: sky}
    for npix in (mid, big):
        skies[npix] = work / f"sky_{npix}.fits"
        stage(f"sky_{npix}", [*msleak, "-q", "sky", skies[npix], "--npix", str(npix),
                              "--seed", "1", "--overwrite"], "degrid")
    # numba's cache warmed, untimed, for both methods in complex128
    warm = work / "warm.ms"
    subprocess.run([*msleak, "-q", "simulate", warm, "--field", "ncp", "--duration", "0.1",
                    "--stations", "CS00[1-2]HBA*", "--overwrite"], check=True,
                   stdout=subprocess.DEVNULL)
    for method in ("direct", "degrid"):
        subprocess.run([*msleak, "-q", "predict", warm, "--sky", sky, "--method", method,
                        "--column", f"WARM_{method.upper()}", *COMMON], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    shutil.rmtree(warm, ignore_errors=True)
    with pt.table(str(ms), ack=False) as t:
        nrow, slots = t.nrows(), len(np.unique(t.getcol("TIME")))
        stations_n = len(np.unique(np.append(t.getcol("ANTENNA1"), t.getcol("ANTENNA2"))))
    with pt.table(str(ms / "SPECTRAL_WINDOW"), ack=False) as t:
        nchan = int(t.getcell("NUM_CHAN", 0))
    load_start = os.getloadavg()[0]
    runs = [("direct", small, []), ("degrid", small, []), ("degrid", mid, []),
            ("degrid", big, ["--memory-limit", MEMORY_LIMIT])]
    columns = []
    for method, npix, extra in runs:
        name = f"{method}_{npix}"
        column = f"BENCH_{method.upper()}_{npix}"
        columns.append(column)
        r = stage(name, [*msleak, "-v", "predict", ms, "--sky", skies[npix], "--method",
                         method, "--column", column, *COMMON, *extra], "degrid",
                  keep=LOG_LINES)
        r.update(method=method, npix=npix, column=column)
    ok = {k: v for k, v in group.items() if "method" in v and not v["exit"]}
    walls = {k: v["wall_s"] for k, v in ok.items()}
    f = {"ms": ms.name, "rows": nrow, "slots": slots, "stations": stations_n,
         "channels": nchan, "sizes": [small, mid, big], "quick": quick,
         "memory_limit": MEMORY_LIMIT,
         "load_avg_start_end": [round(load_start, 2), round(os.getloadavg()[0], 2)]}
    if walls.get(f"direct_{small}") and walls.get(f"degrid_{small}"):
        f["accuracy"] = rel_rms(ms, f"BENCH_DEGRID_{small}", f"BENCH_DIRECT_{small}")
    direct, degrid_mid = walls.get(f"direct_{small}"), walls.get(f"degrid_{mid}")
    ratio = round(degrid_mid / direct, 2) if direct and degrid_mid else None
    cpu = [ok.get(k, {}).get("cpu_s") for k in (f"degrid_{mid}", f"direct_{small}")]
    f["cpu_ratio"] = round(cpu[0] / cpu[1], 2) if all(cpu) else None
    big_run = group.get(f"degrid_{big}", {})
    big_ok = big_run and not big_run["exit"]
    big_wall = big_run["wall_s"] if big_ok else None
    big_peak = big_run["peak_rss_mib"] if big_ok else None
    f["goals"] = {
        "ratio": {"what": f"wall(degrid {mid}) / wall(direct {small})", "value": ratio,
                  "goal": f"< {GOAL_RATIO:g}", "pass": _check(ratio, GOAL_RATIO)},
        "wall": {"what": f"wall(degrid {big}) (s)", "value": big_wall,
                 "goal": f"< {GOAL_WALL_S:g} s", "pass": _check(big_wall, GOAL_WALL_S)},
        "peak": {"what": f"peak memory(degrid {big}) (MiB)", "value": big_peak,
                 "goal": "< 8 GiB (8192 MiB)", "pass": _check(big_peak, GOAL_PEAK_MIB)}}
    group["figures"] = f
    print(f"bench: degrid figures: {f}", file=sys.stderr, flush=True)
    if keep:
        return
    if fresh:
        shutil.rmtree(ms, ignore_errors=True)
    else:
        _remove_columns(ms, columns)

