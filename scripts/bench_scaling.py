#!/usr/bin/env python
"""How `msleak predict` and `msleak grid` scale with sources, stations, times and channels.

From a base set-up (NCP field, 120 s slots, LOFAR beam with the phase-centre correction,
a grid of point sources over 10 x 10 deg), one factor at a time is multiplied by 2 and 4
(stations: 6, 14, 34, 48 HBA fields of the LOFAR core), the MS simulated once per set-up,
and the time measured in this process (best of ``--repeat``, after a warm-up that loads the
numba cache):

* predict: the chunk loop of :func:`msleak.predict.predict` (``seconds - setup``: UVW
  read, beam, kernel, write; the sky and beam-model set-up excluded), ``--scheduler``;
* grid: the whole :func:`msleak.grid` of MODEL_DATA (30-180 wavelengths).

The log-log slope d log(time) / d log(N) is fitted per factor (1 = linear). Sources do not
change the cost of gridding, so grid has no sources row. Prints a table, then the results
as one JSON line; ``--outdir DIR`` works in DIR/scaling and writes DIR/bench_scaling.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

STATIONS = {6: "CS00[1-3]HBA*", 14: "CS00[1-7]HBA*", 34: "CS0*HBA*", 48: "CS*HBA*"}


def _sky(path: Path, nside: int) -> int:
    from bench_predict import grid_skymodel as grid_sky

    return grid_sky(path, nside, 10.0, 0.0, np.pi / 2)


def _ms(work: Path, stations: str, slots: int, nchan: int) -> Path:
    from msleak.verbs.simulate import simulate

    name = f"s{stations.replace('*', 'x').replace('[', '').replace(']', '')}_t{slots}_c{nchan}.ms"
    path = work / name
    if not (path / "table.dat").exists():
        simulate(path, field="ncp", duration=slots * 120 / 3600, interval=120.0,
                 nchan=nchan, freq_min=150e6, chan_width=195312.5, stations=stations,
                 overwrite=True)
    return path


def _best(fn, repeat: int) -> float:
    return min(fn() for _ in range(repeat))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--outdir", default=None, help="work in DIR/scaling")
    ap.add_argument("--quick", action="store_true", help="smaller base and fewer points")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--scheduler", default="sync", help="predict/grid scheduler (sync)")
    args = ap.parse_args(argv)
    os.environ.setdefault("NUMBA_CACHE_DIR", str(Path(sys.prefix) / "numba-cache"))
    from msleak.verbs.predict import predict
    from msleak import grid

    outdir = Path(args.outdir or "bench-output")
    work = outdir / "scaling"
    work.mkdir(parents=True, exist_ok=True)
    if args.quick:
        base = {"sources": 100, "stations": 6, "times": 4, "channels": 8}
        points = {"sources": [100, 400], "stations": [6, 14], "times": [4, 8],
                  "channels": [8, 16]}
    else:
        base = {"sources": 900, "stations": 14, "times": 16, "channels": 32}
        points = {"sources": [225, 900, 3600], "stations": [6, 14, 34, 48],
                  "times": [8, 16, 32, 64], "channels": [16, 32, 64]}

    def setup(cfg):
        ms = _ms(work, STATIONS[cfg["stations"]], cfg["times"], cfg["channels"])
        nside = int(round(np.sqrt(cfg["sources"])))
        sky = work / f"sky{nside}.skymodel"
        if not sky.exists():
            _sky(sky, nside)
        return ms, sky

    def time_predict(ms, sky):
        r = predict(ms, sky, beam="everybeam", progress=False, scheduler=args.scheduler)
        return r.seconds - r.timings.get("setup", 0.0)

    def time_grid(ms):
        t0 = time.perf_counter()
        grid(ms, column="MODEL_DATA", uv_range=(30.0, 180.0), threads=1,
             scheduler=args.scheduler)
        return time.perf_counter() - t0

    ms0, sky0 = setup({**base, "stations": min(STATIONS), "times": 4})
    predict(ms0, sky0, progress=False)  # warm-up: numba cache, page cache
    out = {"base": base, "scheduler": args.scheduler, "cores": os.cpu_count(),
           "predict": {}, "grid": {}}
    for factor, values in points.items():
        rows_p, rows_g = [], []
        for value in values:
            cfg = {**base, factor: value}
            ms, sky = setup(cfg)
            tp = _best(lambda: time_predict(ms, sky), args.repeat)
            rows_p.append([value, round(tp, 4)])
            if factor != "sources":
                tg = _best(lambda: time_grid(ms), args.repeat)
                rows_g.append([value, round(tg, 4)])
            print(f"{factor:9s} {value:6d}: predict {tp:8.3f} s"
                  + (f"   grid {rows_g[-1][1]:8.3f} s" if factor != "sources" else ""),
                  file=sys.stderr, flush=True)
        out["predict"][factor] = {"points": rows_p, "slope": _slope(rows_p)}
        if rows_g:
            out["grid"][factor] = {"points": rows_g, "slope": _slope(rows_g)}
    (outdir / "bench_scaling.json").write_text(json.dumps(out, indent=1))
    for what in ("predict", "grid"):
        for factor, r in out[what].items():
            print(f"{what:8s} vs {factor:9s}: slope {r['slope']:.2f}  "
                  + ", ".join(f"{n}: {t:.3f} s" for n, t in r["points"]))
    print(json.dumps(out))
    return 0


def _slope(rows) -> float:
    n, t = np.log([r[0] for r in rows]), np.log([max(r[1], 1e-6) for r in rows])
    return round(float(np.polyfit(n, t, 1)[0]), 3)


if __name__ == "__main__":
    sys.exit(main())
