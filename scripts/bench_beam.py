#!/usr/bin/env python
"""Time the LOFAR beam per time slot: msleak's fast evaluator and EveryBeam direct.

Paper sizes: 48 HBA core fields x {2500, 784, 256} directions (50^2, 28^2, 16^2 pixels over
15, 9, 4 deg) x 50 channels.  Prints one JSON document on stdout::

    {"stations": 48, "channels": 50, "threads": 2, "results": [
        {"directions": 2500, "fast_s": ..., "fast_complex64_s": ...,
         "fast_corrected_s": ..., "direct_s": ..., "direct_extrapolated": true,
         "direct_directions_timed": 64, "speedup": ..., "max_rel_diff": ...}, ...]}

``fast_s`` is the best of ``--repeat`` runs of ``jones(...)`` for one time slot (complex128,
no correction), after a warm-up that compiles the numba kernels.  EveryBeam direct costs
exactly one call per direction, so by default it is timed on ``--direct-dirs`` directions
and scaled linearly (``direct_extrapolated``); ``--direct-dirs 0`` times all directions.
``max_rel_diff`` compares the two on the directions timed for both.

Usage: scripts/bench_beam.py [--sizes 2500,784,256] [--repeat 3] [--direct-dirs 64]
                             [--outdir DIR] [--quick]

The JSON document is printed on one line, last (``scripts/bench`` reads it); ``--outdir``
also writes it to DIR/bench_beam.json; ``--quick`` times 256 directions x 10 channels.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _grid(ra0, dec0, fov_deg, npix):
    from msleak.beam.maps import sin_grid

    _, _, ra, dec = sin_grid(ra0, dec0, fov_deg, npix)
    return ra.ravel(), dec.ravel()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", default="2500,784,256",
                        help="directions per time slot (perfect squares)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--direct-dirs", type=int, default=64,
                        help="directions to time EveryBeam direct on (0 = all)")
    parser.add_argument("--channels", type=int, default=50)
    parser.add_argument("--stations", default="CS*HBA*")
    parser.add_argument("--outdir", default=None, help="also write DIR/bench_beam.json")
    parser.add_argument("--quick", action="store_true", help="256 directions, 10 channels")
    args = parser.parse_args(argv)
    if args.quick:
        args.sizes, args.channels, args.repeat, args.direct_dirs = "256", 10, 1, 16

    import numba

    from msleak.adapters.beams import load_beam
    from msleak.adapters.everybeam import EveryBeamDirect
    from msleak.io.ms import read_spectral_windows, read_times
    from msleak.verbs.simulate import simulate

    fovs = {2500: 15.0, 784: 9.0, 256: 4.0}
    with tempfile.TemporaryDirectory(prefix="msleak-bench-beam-") as tmp:
        ms = simulate(Path(tmp) / "bench.ms", field="3c196", duration=2 * 120 / 3600,
                      interval=120.0, nchan=args.channels, stations=args.stations)
        freq = read_spectral_windows(ms)[0].freq
        t = read_times(ms)[:1]
        t0 = time.perf_counter()
        fast = load_beam("everybeam", ms)
        ra0, dec0 = fast.phase_centre
        fast.jones(t, freq[:2], [ra0], [dec0])      # compile / load the numba cache
        setup_s = time.perf_counter() - t0
        direct = EveryBeamDirect(ms)
        report = {"stations": fast.n_stations, "channels": int(freq.size),
                  "threads": numba.get_num_threads(), "cpus": os.cpu_count(),
                  "setup_and_compile_s": round(setup_s, 3), "results": []}
        for ndir in (int(s) for s in args.sizes.split(",")):
            npix = int(round(np.sqrt(ndir)))
            ra, dec = _grid(ra0, dec0, fovs.get(npix * npix, 15.0), npix)
            timings = {}
            for label, kwargs in (("fast_s", {}),
                                  ("fast_complex64_s", {"dtype": np.complex64}),
                                  ("fast_corrected_s", {"centre_correction": True})):
                best = np.inf
                for _ in range(args.repeat):
                    start = time.perf_counter()
                    jf = fast.jones(t, freq, ra, dec, **kwargs)
                    best = min(best, time.perf_counter() - start)
                    del jf
                timings[label] = round(best, 4)
            n_direct = ra.size if args.direct_dirs <= 0 else min(args.direct_dirs, ra.size)
            pick = np.linspace(0, ra.size - 1, n_direct).round().astype(int)
            start = time.perf_counter()
            jd = direct.jones(t, freq, ra[pick], dec[pick])
            direct_s = (time.perf_counter() - start) * ra.size / n_direct
            jf = fast.jones(t, freq, ra[pick], dec[pick])
            scale = np.abs(jd).max(axis=(-3, -2, -1), keepdims=True)
            report["results"].append({
                "directions": int(ra.size), **timings,
                "direct_s": round(direct_s, 3), "direct_extrapolated": n_direct < ra.size,
                "direct_directions_timed": int(n_direct),
                "speedup": round(direct_s / timings["fast_s"], 1),
                "max_rel_diff": float(f"{np.max(np.abs(jf - jd) / scale):.3g}"),
            })
            print(f"{ra.size} directions: fast {timings['fast_s']} s, direct {direct_s:.2f} s",
                  file=sys.stderr)
    if args.outdir:
        Path(args.outdir).mkdir(parents=True, exist_ok=True)
        (Path(args.outdir) / "bench_beam.json").write_text(json.dumps(report, indent=1))
    print(json.dumps(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
