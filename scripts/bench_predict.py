#!/usr/bin/env python
"""Benchmark ``msleak predict`` at the paper's scale, side by side with DP3.

Default set-up (docs/science.md section 2, issue 5): NCP field (``--field 3c196`` for the other one), 48 LOFAR HBA core fields (CS*HBA*),
50 channels of 195.3125 kHz from 150 MHz, 120 s slots, 2500 polarized point sources on a
50 x 50 grid over 15 x 15 deg (a makesourcedb file both tools read), the full LOFAR beam
per station with the phase-centre correction. On one MS of ``--slots`` time slots:

* msleak predict (complex64, the default) in a subprocess: time per slot, setup time, the
  stage breakdown, peak memory (max RSS), the extrapolated 13 h NCP run (390 slots);
* msleak predict --double on the same MS: the measured relative error of complex64;
* DP3 predict (usebeammodel, beammode=full) + applybeam (invert) into another column of the
  same MS, same sky: time per slot, peak memory, the msleak/DP3 speed ratio and the
  relative rms difference of the visibilities;
* throughput in source-visibilities per second (sources x rows x channels / time; a
  "visibility" is one row and channel, all four correlations) and the fraction of the
  machine's measured matrix-multiply peak: a numpy complex64/complex128 matmul of the
  same shape as msleak's per-(time, channel) product, (2 nst x 2 nsrc) @ (2 nsrc x 2 nst),
  timed on a stack of channels with NumPy's BLAS threads.

``--full`` also runs msleak on a real 13 h NCP MS (390 slots) instead of extrapolating.
Prints a table, then the results as one JSON line (last; ``scripts/bench`` reads it), and
writes them to ``--json`` or DIR/bench_predict.json with ``--outdir DIR`` (the MS and sky
are kept in DIR/predict). ``--quick``: 14 stations, 400 sources, 10 channels, 2 slots.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CHILD = r"""
import json, resource, sys, time
t0 = time.perf_counter()
from msleak.verbs.predict import predict
r = predict(sys.argv[1], sys.argv[2], column=sys.argv[3], beam=sys.argv[4],
            double=sys.argv[5] == "1", progress=False, scheduler="sync")
print(json.dumps({"wall": time.perf_counter() - t0, "seconds": r.seconds,
                  "timings": r.timings, "rows": r.rows_written, "slots": r.n_slots,
                  "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""

DP3_CHILD = r"""
import json, resource, sys, time
import dp3
t0 = time.perf_counter()
sys.argv = ["DP3", sys.argv[1]]
code = dp3.entrypoint()
print(json.dumps({"wall": time.perf_counter() - t0, "code": code,
                  "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def grid_skymodel(path: Path, n_side: int, fov_deg: float, ra0: float, dec0: float,
                  seed: int = 1) -> int:
    """A makesourcedb file of n_side^2 point sources with random Q, U (Jy) on a square grid
    of ``fov_deg`` about (ra0, dec0) (rad), read alike by msleak and DP3; returns the count."""
    rng = np.random.default_rng(seed)
    pix = fov_deg / n_side
    lines = ["format = Name, Type, Ra, Dec, I, Q, U, V, ReferenceFrequency='150e6', "
             "SpectralIndex='[]'"]
    k = 0
    for iy in range(n_side):
        for ix in range(n_side):
            l = np.radians((ix - (n_side - 1) / 2) * pix)
            m = np.radians((iy - (n_side - 1) / 2) * pix)
            n = np.sqrt(1 - l * l - m * m)
            dec = np.arcsin(m * np.cos(dec0) + n * np.sin(dec0))
            ra = ra0 + np.arctan2(l, n * np.cos(dec0) - m * np.sin(dec0))
            q, u = rng.normal(0, 1, 2)
            lines.append(f"s{k}, POINT, {float(np.degrees(ra))!r}deg, "
                         f"{float(np.degrees(dec))!r}deg, 0.0, {float(q)!r}, {float(u)!r}, 0.0")
            k += 1
    path.write_text("\n".join(lines) + "\n")
    return k


def _run_json(code: str, *args, env=None) -> dict:
    proc = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True,
                          text=True, env=env)
    if proc.returncode != 0:
        raise RuntimeError(f"benchmark child failed:\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _matmul_rate(nst: int, nsrc: int, nchan: int, dtype) -> float:
    """Measured flop rate (8 n m k per complex gemm) of numpy matmul of the same shape."""
    rng = np.random.default_rng(0)
    n, k = 2 * nst, 2 * nsrc
    nstack = min(nchan, 16)
    x = (rng.standard_normal((nstack, n, k)) + 1j * rng.standard_normal((nstack, n, k))).astype(dtype)
    y = np.conj(np.swapaxes(x, -1, -2)).copy()
    np.matmul(x, y)
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        np.matmul(x, y)
        best = min(best, time.perf_counter() - t0)
    return 8.0 * n * n * k * nstack / best


def _simulate(path: Path, hours: float, args) -> None:
    from msleak.verbs.simulate import simulate

    simulate(path, field=args.field, duration=hours, interval=args.interval, nchan=args.nchan,
             freq_min=150e6, chan_width=195312.5, stations=args.stations,
             overwrite=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--slots", type=int, default=4, help="time slots of the comparison MS")
    ap.add_argument("--field", default="ncp", help="ncp (default) or 3c196")
    ap.add_argument("--stations", default="CS*HBA*", help="station pattern (48 HBA fields)")
    ap.add_argument("--nside", type=int, default=50, help="sources per side (2500 = 50^2)")
    ap.add_argument("--fov", type=float, default=15.0, help="sky grid width, deg")
    ap.add_argument("--nchan", type=int, default=50)
    ap.add_argument("--interval", type=float, default=120.0)
    ap.add_argument("--beam", default="everybeam")
    ap.add_argument("--no-dp3", action="store_true", help="skip DP3")
    ap.add_argument("--full", action="store_true", help="also run the real 13 h NCP MS")
    ap.add_argument("--workdir", default=None, help="keep the MS and sky here")
    ap.add_argument("--json", default=None, help="write the results as JSON here")
    ap.add_argument("--outdir", default=None,
                    help="work in DIR/predict and write DIR/bench_predict.json")
    ap.add_argument("--quick", action="store_true", help="a small smoke run")
    args = ap.parse_args(argv)
    if args.outdir:
        args.workdir = args.workdir or str(Path(args.outdir) / "predict")
        args.json = args.json or str(Path(args.outdir) / "bench_predict.json")
    if args.quick:
        args.stations, args.nside, args.nchan, args.slots = "CS00[1-7]HBA*", 20, 10, 2
    os.environ.setdefault("NUMBA_CACHE_DIR", str(Path(sys.prefix) / "numba-cache"))

    import casacore.tables as pt

    from dp3run import dp3_available, dp3_environment

    work = Path(args.workdir or tempfile.mkdtemp(prefix="msleak_bench_predict_"))
    work.mkdir(parents=True, exist_ok=True)
    ms = work / "bench.ms"
    _simulate(ms, args.slots * args.interval / 3600, args)
    with pt.table(str(ms), ack=False) as t:
        nrow = t.nrows()
        nant = len(set(t.getcol("ANTENNA1")) | set(t.getcol("ANTENNA2")))
    with pt.table(str(ms / "FIELD"), ack=False) as t:
        ra0, dec0 = t.getcell("PHASE_DIR", 0).reshape(-1)[:2]
    sky = work / "sky.skymodel"
    nsrc = grid_skymodel(sky, args.nside, args.fov, ra0, dec0)
    out: dict = {"stations": nant, "sources": nsrc, "channels": args.nchan, "slots": args.slots,
                 "rows": nrow, "beam": args.beam, "centre_correction": True,
                 "cores": os.cpu_count()}

    _run_json(CHILD, ms, sky, "WARMUP", args.beam, "0")  # numba cache / page cache warm-up
    single = _run_json(CHILD, ms, sky, "MSLEAK", args.beam, "0")
    double = _run_json(CHILD, ms, sky, "MSLEAK_DOUBLE", args.beam, "1")
    per_slot = (single["seconds"] - single["timings"]["setup"]) / single["slots"]
    out["msleak"] = {**single, "per_slot_s": per_slot,
                     "ncp_13h_extrapolated_s": single["timings"]["setup"] + 390 * per_slot}
    out["msleak_double"] = {**double, "per_slot_s": (double["seconds"] - double["timings"]["setup"])
                            / double["slots"]}
    with pt.table(str(ms), ack=False) as t:
        a, b = t.getcol("MSLEAK"), t.getcol("MSLEAK_DOUBLE")
    out["complex64_vs_complex128"] = {
        "rel_rms": float(np.sqrt(np.mean(np.abs(a - b) ** 2) / np.mean(np.abs(b) ** 2))),
        "max_abs_over_max": float(np.abs(a - b).max() / np.abs(b).max()),
        "stokes_i_rel_rms": float(np.sqrt(np.mean(np.abs((a - b)[..., 0] + (a - b)[..., 3]) ** 2)
                                          / np.mean(np.abs(b[..., 0] + b[..., 3]) ** 2)))}

    vis = nsrc * nrow * args.nchan
    out["throughput_source_vis_per_s"] = vis / single["seconds"]
    nst = nant
    gemm_flops = 8.0 * (2 * nst) ** 2 * (2 * nsrc) * args.nchan * single["slots"]
    for name, dtype, run in (("complex64", np.complex64, single),
                             ("complex128", np.complex128, double)):
        peak = _matmul_rate(nst, nsrc, args.nchan, dtype)
        out[f"matmul_peak_gflops_{name}"] = peak / 1e9
        out[f"fraction_of_matmul_peak_{name}"] = {
            "end_to_end": gemm_flops / run["seconds"] / peak,
            "kernel": gemm_flops / run["timings"]["kernel"] / peak}

    if not args.no_dp3 and dp3_available():
        lines = [f"msin={ms}", "msout=.", "msout.datacolumn=DP3", "steps=[predict,applybeam]",
                 "predict.type=predict", f"predict.sourcedb={sky}", "predict.usebeammodel=true",
                 "predict.beammode=full", "applybeam.type=applybeam", "applybeam.invert=true",
                 "applybeam.beammode=full"]
        parset = work / "dp3.parset"
        parset.write_text("\n".join(lines) + "\n")
        dp3 = _run_json(DP3_CHILD, parset, env=dp3_environment())
        with pt.table(str(ms), ack=False) as t:
            ref = t.getcol("DP3")
        dp3["per_slot_s"] = dp3["wall"] / args.slots
        out["dp3"] = dp3
        out["speedup_vs_dp3"] = dp3["wall"] / single["wall"]
        out["speedup_vs_dp3_per_slot"] = dp3["per_slot_s"] / per_slot
        out["rel_rms_vs_dp3"] = float(np.sqrt(np.mean(np.abs(a - ref) ** 2)
                                              / np.mean(np.abs(ref) ** 2)))
        # Stokes I = (XX + YY) / 2 does not depend on the polarization basis at the phase
        # centre, which is undefined at a celestial pole (see docs/predict.md)
        i_a, i_ref = a[..., 0] + a[..., 3], ref[..., 0] + ref[..., 3]
        out["stokes_i_rel_rms_vs_dp3"] = float(np.sqrt(np.mean(np.abs(i_a - i_ref) ** 2)
                                                       / np.mean(np.abs(i_ref) ** 2)))
        out["dp3_ncp_13h_extrapolated_s"] = 390 * dp3["per_slot_s"]

    if args.full:
        full_ms = work / "ncp13h.ms"
        _simulate(full_ms, 13.0, args)
        full = _run_json(CHILD, full_ms, sky, "MSLEAK", args.beam, "0")
        out["msleak_full_13h"] = full
        if "dp3" in out:
            out["speedup_full_13h_vs_dp3_extrapolated"] = (
                full["slots"] * out["dp3"]["per_slot_s"] / full["wall"])

    _report(out)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2))
    print(json.dumps(out))
    return 0


def _report(out: dict) -> None:
    m = out["msleak"]
    print(f"msleak predict benchmark: {out['stations']} stations, {out['sources']} sources, "
          f"{out['channels']} channels, {out['slots']} x 120 s slots, beam {out['beam']} "
          f"+ centre correction, {out['cores']} cores")
    print(f"  msleak complex64   {m['per_slot_s']:.3f} s/slot  (setup {m['timings']['setup']:.2f} s;"
          f" beam {m['timings'].get('beam', 0) / m['slots']:.3f}, kernel "
          f"{m['timings'].get('kernel', 0) / m['slots']:.3f}, write "
          f"{m['timings'].get('write', 0) / m['slots']:.3f} s/slot), peak RSS {m['maxrss_mb']:.0f} MB")
    print(f"  13 h NCP (390 slots) extrapolated: {m['ncp_13h_extrapolated_s']:.0f} s")
    d = out["msleak_double"]
    print(f"  msleak complex128  {d['per_slot_s']:.3f} s/slot, peak RSS {d['maxrss_mb']:.0f} MB")
    e = out["complex64_vs_complex128"]
    print(f"  complex64 error vs complex128: rel rms {e['rel_rms']:.2e}, max/max "
          f"{e['max_abs_over_max']:.2e}, Stokes I rel rms {e['stokes_i_rel_rms']:.2e}")
    print(f"  throughput {out['throughput_source_vis_per_s']:.3g} source-visibilities/s")
    for name in ("complex64", "complex128"):
        f = out[f"fraction_of_matmul_peak_{name}"]
        print(f"  matmul peak {name}: {out[f'matmul_peak_gflops_{name}']:.1f} GFLOP/s; msleak "
              f"reaches {100 * f['end_to_end']:.0f}% end to end, {100 * f['kernel']:.0f}% in "
              "its kernel (gemm-equivalent flops)")
    if "dp3" in out:
        p = out["dp3"]
        print(f"  DP3 predict+applybeam {p['per_slot_s']:.2f} s/slot (13 h: "
              f"{out['dp3_ncp_13h_extrapolated_s'] / 60:.0f} min), peak RSS {p['maxrss_mb']:.0f} MB")
        print(f"  speed-up vs DP3: {out['speedup_vs_dp3']:.1f}x end to end, "
              f"{out['speedup_vs_dp3_per_slot']:.1f}x per slot; rel rms difference "
              f"{out['rel_rms_vs_dp3']:.2e} (Stokes I {out['stokes_i_rel_rms_vs_dp3']:.2e})")
    if "msleak_full_13h" in out:
        f = out["msleak_full_13h"]
        print(f"  real 13 h NCP run: {f['wall']:.0f} s ({f['slots']} slots; beam "
              f"{f['timings'].get('beam', 0):.0f} s, kernel {f['timings'].get('kernel', 0):.0f} s), "
              f"peak RSS {f['maxrss_mb']:.0f} MB")
        if "speedup_full_13h_vs_dp3_extrapolated" in out:
            print(f"  speed-up of the real 13 h run vs DP3's per-slot time x {f['slots']}: "
                  f"{out['speedup_full_13h_vs_dp3_extrapolated']:.1f}x")


if __name__ == "__main__":
    sys.exit(main())
