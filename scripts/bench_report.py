"""docs/benchmarks.md from the results of scripts/bench (bench-output/bench.json).

Usage: scripts/bench_report.py [bench-output/bench.json] [docs/benchmarks.md]
(``scripts/bench`` calls :func:`write_markdown` itself; run this to redo the Markdown.)
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def _f(x, fmt=".1f", missing="-"):
    return missing if x is None else format(x, fmt)


def _stage_rows(stages: dict) -> list:
    rows = ["| stage | command | wall (s) | peak memory (MiB) | notes |", "|---|---|---|---|---|"]
    for name, r in stages.items():
        note = f"MS {r['size_mib']:.0f} MiB on disk" if r.get("size_mib") else ""
        if r["exit"]:
            note = f"FAILED (exit {r['exit']})"
        cmd = r["command"].split(" -m msleak -q ", 1)[-1]
        rows.append(f"| {name} | `msleak {cmd}` | {r['wall_s']:.1f} | "
                    f"{_f(r['peak_rss_mib'], '.0f')} | {note} |")
    return rows


def _predict_peer(r: dict) -> list:
    m = r["msleak"]
    lines = [f"Same MS and sky for both: {r['stations']} stations, {r['sources']} sources, "
             f"{r['channels']} channels, {r['slots']} slots of 120 s ({r['rows']} rows), "
             f"beam {r['beam']} with the phase-centre correction, {r['cores']} cores.", "",
             "| | per 120 s slot (s) | 13 h NCP, 390 slots (s) | peak memory (MiB) |",
             "|---|---|---|---|",
             f"| msleak predict (complex64) | {m['per_slot_s']:.3f} | "
             f"{m['ncp_13h_extrapolated_s']:.0f} (extrapolated) | {m['maxrss_mb']:.0f} |",
             f"| msleak predict --double | {r['msleak_double']['per_slot_s']:.3f} | | "
             f"{r['msleak_double']['maxrss_mb']:.0f} |"]
    if "dp3" in r:
        d = r["dp3"]
        lines += [f"| DP3 predict + applybeam | {d['per_slot_s']:.3f} | "
                  f"{r['dp3_ncp_13h_extrapolated_s']:.0f} (extrapolated) | "
                  f"{d['maxrss_mb']:.0f} |", "",
                  f"**msleak / DP3: {r['speedup_vs_dp3_per_slot']:.1f}x faster per slot, "
                  f"{r['speedup_vs_dp3']:.1f}x end to end on this MS** (process start and "
                  f"set-up included). Relative rms difference of the visibilities "
                  f"{r['rel_rms_vs_dp3']:.1e} (Stokes I {r['stokes_i_rel_rms_vs_dp3']:.1e}; "
                  "see docs/predict.md for the pole basis)."]
    else:
        lines += ["", "DP3 is not installed (`pip install dp3`): no comparison."]
    e = r["complex64_vs_complex128"]
    lines += ["", f"complex64 vs complex128: relative rms {e['rel_rms']:.1e}, max error "
              f"{e['max_abs_over_max']:.1e} of the peak. Throughput "
              f"{r['throughput_source_vis_per_s']:.2e} source-visibilities/s; the kernel runs "
              f"at {100 * r['fraction_of_matmul_peak_complex64']['kernel']:.0f}% of the "
              f"measured numpy matmul peak ({r['matmul_peak_gflops_complex64']:.0f} GFLOP/s)."]
    return lines


def _process_rows(r: dict) -> list:
    lines = [f"One whole process each (start to exit: interpreter, imports, set-up, beam, "
             f"writes) on the same MS ({r['ms']}: {r['slots']} slots, {r['rows']} rows) and "
             f"makesourcedb sky ({r['sources']} sources), numba's cache warm.", "",
             "| process | wall (s) | CPU (s) | peak memory (MiB) |", "|---|---|---|---|"]
    for key, name in (("msleak", "msleak predict"), ("dp3", "DP3 predict + applybeam")):
        if key in r:
            p = r[key]
            lines.append(f"| {name} | {p['wall_s']:.1f} | {_f(p['cpu_s'])} | "
                         f"{_f(p['peak_rss_mib'], '.0f')} |")
    if "speedup_wall" in r:
        lines += ["", f"**msleak / DP3, whole process: {r['speedup_wall']:.1f}x wall, "
                      f"{r['speedup_cpu']:.1f}x CPU.** Stokes I relative rms difference "
                      f"{r['stokes_i_rel_rms']:.1e}."]
    return lines


def _beam_peer(r: dict) -> list:
    lines = [f"One time slot, {r['stations']} stations x {r['channels']} channels, "
             f"{r['threads']} threads; EveryBeam direct timed on "
             f"{r['results'][0]['direct_directions_timed']} directions and scaled linearly "
             "(one call per direction).", "",
             "| directions | msleak fast (s) | fast complex64 (s) | fast + centre correction (s) "
             "| EveryBeam direct (s) | speed-up | max relative difference |",
             "|---|---|---|---|---|---|---|"]
    for x in r["results"]:
        lines.append(f"| {x['directions']} | {x['fast_s']:.3f} | {x['fast_complex64_s']:.3f} | "
                     f"{x['fast_corrected_s']:.3f} | {x['direct_s']:.2f} | "
                     f"**{x['speedup']:.0f}x** | {x['max_rel_diff']:.1e} |")
    return lines


def _ps_peer(r: dict) -> list:
    img = r.get("image", {})
    lines = ["A 128^2-pixel, 50-channel K image cube (2 arcmin pixels), 30-180 wavelengths, "
             "Blackman-Harris window, Planck18, bins of one cell."]
    if "ps_eor_s" not in img:
        return lines + ["", f"msleak grid --image + transform + ps: {img.get('msleak_s')} s; "
                        f"ps_eor: {img.get('ps_eor', 'not run')}."]
    ratio = img["ps_eor_s"] / img["msleak_s"] if img["msleak_s"] else float("nan")
    lines += ["", "| | wall (s) |", "|---|---|",
              f"| msleak grid --image + transform + ps (3 processes) | {img['msleak_s']:.2f} |",
              f"| ps_eor CartImageCube -> get_ps2d (in process) | {img['ps_eor_s']:.2f} |", "",
              f"Time ratio ps_eor / msleak {ratio:.2f}. Power ratio msleak / ps_eor: median "
              f"{img['power_ratio_median']:.3f} (16-84%: "
              f"{img['power_ratio_p16_p84'][0]:.3f}-{img['power_ratio_p16_p84'][1]:.3f}); "
              f"k_perp bin lower edges agree to {img['k_perp_max_rel_diff']:.1e} (ps_eor labels "
              f"bins by their lower edge), k_par to {img['k_par_max_rel_diff']:.1e} (relative; "
              "ps_eor's delay resolution uses a bandwidth of (N-1) channels, msleak's N). The "
              "power ratio's trend with k_perp is not explained yet."]
    return lines


def _scheduler_rows(s: dict) -> list:
    rows = ["| run | scheduler | wall (s) | peak memory of the largest process (MiB) | "
            "max relative difference vs sync |", "|---|---|---|---|---|"]
    for name, r in s.items():
        what, sched = name.rsplit("_", 1)
        diff = r.get("max_rel_diff_vs_sync")
        rows.append(f"| {what} | {sched} | {r['wall_s']:.1f} | {_f(r['peak_rss_mib'], '.0f')} | "
                    f"{'-' if diff is None else format(diff, '.1e')} |")
    return rows


def _scaling_rows(r: dict) -> list:
    b = r["base"]
    lines = [f"Base: {b['sources']} sources, {b['stations']} stations (HBA fields), "
             f"{b['times']} slots of 120 s, {b['channels']} channels; one factor varied at a "
             f"time; scheduler {r['scheduler']}; best of 2 runs. predict: the chunk loop "
             "(beam, kernel, UVW read, write; sky and beam set-up excluded); grid: the whole "
             "msleak.grid call.", "",
             "| step | varied | N | time (s) | log-log slope |", "|---|---|---|---|---|"]
    for what in ("predict", "grid"):
        for factor, x in r[what].items():
            ns = ", ".join(str(p[0]) for p in x["points"])
            ts = ", ".join(f"{p[1]:.3f}" for p in x["points"])
            lines.append(f"| {what} | {factor} | {ns} | {ts} | **{x['slope']:.2f}** |")
    lines += ["", "Reading the slopes: the predict work is linear in sources, times and channels "
              "and, for the kernel, quadratic in stations, but at these sizes the beam "
              "evaluation (linear in stations) and per-chunk costs that do not grow with "
              "sources or stations (UVW read and station fit, writes, the beam at the phase "
              "centre) still weigh, so slopes below 1 mean fixed costs, not a better "
              "algorithm. grid time is mostly the per-channel FFTs of the gridder's image "
              "box, which do not grow with rows: it is linear in channels and nearly flat in "
              "stations and times until the visibilities dominate (paper MS: 440 k rows in "
              "about 16 s)."]
    return lines


def _multisky_rows(runs: dict) -> list:
    lines = ["Skies: 5 seeds x the study's 3 fields of view (15, 9 and 4 deg: 2500, 784 and 256 "
             "sources), each into its own column, on the paper's NCP MS; `msleak predict` of n "
             "skies evaluates the beam once per chunk on the union of their directions. DP3: "
             "one predict + applybeam run per sky, its time estimated from its time per slot "
             "for 2500 sources measured in this run (scripts/bench_multisky.py says how).", "",
             "| skies | sources | msleak wall (s) | x one sky | peak memory (MiB) | "
             "DP3 estimate (s) | msleak / DP3 speed-up |", "|---|---|---|---|---|---|---|"]
    for r in runs.values():
        if "n_skies" not in r:
            continue
        lines.append(f"| {r['n_skies']} | {r['n_sources']} | {r['wall_s']:.1f} | "
                     f"{r['ratio_to_one_sky']:.2f} | {_f(r['peak_rss_mib'], '.0f')} | "
                     f"{_f(r.get('dp3_estimate_s'), '.0f')} | "
                     f"{_f(r.get('speedup_vs_dp3'), '.1f')} |")
    return lines


def _study_rows(runs: dict) -> list:
    lines = ["`msleak paper OUTDIR --seeds N --overwrite`: both fields, 3 fields of view, N sky "
             "realisations, every step rerun (simulate, sky, beam maps, predict, grid, "
             "transform, ps, leakage, figures, report). Peak memory: of the "
             "whole process tree (the worker processes summed). DP3 column: the estimated "
             "time of DP3 predict + applybeam for the same predictions alone.", "",
             "| seeds | --workers | wall (s) | wall (min) | peak memory (MiB) | DP3 predict "
             "estimate (s) |", "|---|---|---|---|---|---|"]
    for r in runs.values():
        lines.append(f"| {r.get('seeds', '?')} | {r.get('workers', 'default')} | "
                     f"{r['wall_s']:.0f} | {r['wall_s'] / 60:.1f} | "
                     f"{_f(r['peak_rss_mib'], '.0f')} | "
                     f"{_f(r.get('dp3_predict_estimate_s'), '.0f')} |"
                     + (f" FAILED (exit {r['exit']})" if r["exit"] else ""))
    return lines


def _verdict(ok) -> str:
    return "**PASS**" if ok else ("FAIL" if ok is False else "FAIL (not measured: stage failed)")


def _degrid_rows(g: dict) -> list:
    f = g.get("figures", {})
    sizes = f.get("sizes", [])
    lines = [f"`msleak -v predict MS --sky SKY --method direct|degrid --double --double-column` "
             f"(complex128 arithmetic and columns, each run its own process and column, "
             f"numba's cache warm) on an NCP MS ({f.get('ms', '?')}: {f.get('stations', '?')} "
             f"stations, {f.get('slots', '?')} slots of 120 s, {f.get('rows', '?')} rows, "
             f"{f.get('channels', '?')} channels), skies `msleak sky --npix N --seed 1` over "
             f"15 deg (N = {', '.join(map(str, sizes)) or '?'}); the largest with "
             f"`--memory-limit {f.get('memory_limit', '?')}`.", "",
             "| run | pixels | wall (s) | CPU (s) | peak memory (MiB) | subgrid chosen "
             "(`-v` log) |", "|---|---|---|---|---|---|"]
    for name, r in g.items():
        if "wall_s" not in r or "method" not in r:
            continue
        sub = "; ".join(x for x in r.get("log", []) if x.startswith("degrid ")) or "-"
        lines.append(f"| {r['method']} | {r['npix']} x {r['npix']} | {r['wall_s']:.1f} | "
                     f"{_f(r['cpu_s'])} | {_f(r['peak_rss_mib'], '.0f')} | {sub} |"
                     + (f" FAILED (exit {r['exit']})" if r["exit"] else ""))
    skies = [f"{n[4:]} px {r['wall_s']:.0f} s" for n, r in g.items()
             if n.startswith("sky_") and "wall_s" in r]
    if skies:
        lines += ["", f"Sky generation (`msleak sky`, not part of the figures): "
                      f"{', '.join(skies)}."]
    acc = f.get("accuracy")
    lines += ["", "| figure | value | goal | |", "|---|---|---|---|"]
    if acc:
        lines += [f"| relative rms, degrid - direct, {sizes[0]} x {sizes[0]}, all "
                  f"correlations | {_f(acc['rel_rms'], '.1e')} | | |",
                  f"| relative rms, degrid - direct, {sizes[0]} x {sizes[0]}, Stokes I "
                  f"(XX + YY) | {_f(acc['stokes_i_rel_rms'], '.1e')} | | |"]
    else:
        lines.append("| relative rms, degrid - direct | not measured (a predict failed) | | |")
    for key, fmt in (("ratio", ".2f"), ("wall", ".0f"), ("peak", ".0f")):
        x = f.get("goals", {}).get(key)
        if x:
            lines.append(f"| {x['what']} | {_f(x['value'], fmt)} | {x['goal']} | "
                         f"{_verdict(x['pass'])} |")
    if f.get("cpu_ratio") is not None:
        lines.append(f"| CPU(degrid {sizes[1]}) / CPU(direct {sizes[0]}) | "
                     f"{f['cpu_ratio']:.2f} | | |")
    load = f.get("load_avg_start_end")
    if load:
        lines += ["", f"Load average {load[0]:.1f} before and {load[1]:.1f} after these "
                      "runs (wall times stretch when it exceeds the cores; CPU times less)."]
    lines += ["", "Relative rms: sqrt(sum |degrid - direct|^2 / sum |direct|^2) over "
              "every row and channel (Stokes I: of XX + YY). The goals are set for the paper MS "
              "(13 h, 48 stations, skies of 50, 225 and 512 pixels)"
              + ("; this --quick run checks them on small inputs, which says little about "
                 "the paper scale." if f.get("quick") else ".")]
    return lines


def _allsky_rows(r: dict) -> list:
    runs, f = r.get("runs", {}), r.get("figures", {})
    lines = [f"`msleak predict MS --sky ALL.skyh5` (every pixel above the horizon, the direct "
             f"sum; defaults: complex64, phase-centre correction, threads), each run one whole "
             f"process, numba's cache warm; MSs of {f.get('stations', '?')} stations (LOFAR "
             f"HBA core fields, NCP; HERA's innermost dishes, EoR0, `--beam uvbeam`), "
             f"{f.get('slots', '?')} slots of {f.get('interval_s', 120):g} s, "
             f"{f.get('channels', '?')} channels; Q/U skies from `msleak sky --healpix NSIDE`. "
             "Against matvis (CPU): a Stokes I sky on the HERA MS, msleak with "
             "`--no-centre-correction`, matvis in a driver process of scripts/bench_allsky.py "
             "(reads the MS and the SkyH5 file, writes a column), each at its default "
             "precision (complex64).", "",
             "| run | pixels | wall (s) | CPU (s) | peak memory (MiB) |", "|---|---|---|---|---|"]
    for name, x in runs.items():
        if name.startswith("sky_") or "wall_s" not in x:
            continue
        lines.append(f"| {name} | {x.get('pixels', '?')} | {x['wall_s']:.1f} | "
                     f"{_f(x.get('cpu_s'))} | {_f(x.get('peak_rss_mib'), '.0f')} |"
                     + (f" FAILED (exit {x['exit']})" if x["exit"] else ""))
    acc = f.get("msleak_vs_matvis")
    lines += ["", "| figure | value | goal | |", "|---|---|---|---|",
              f"| matvis / msleak, wall | {_f(f.get('matvis_over_msleak_wall'), '.2f')} | | |",
              f"| matvis / msleak, CPU | {_f(f.get('matvis_over_msleak_cpu'), '.2f')} | | |",
              f"| relative rms msleak - matvis, all correlations | "
              f"{_f((acc or {}).get('rel_rms'), '.1e')} | | |",
              f"| relative rms msleak - matvis, Stokes I (XX + YY) | "
              f"{_f((acc or {}).get('stokes_i_rel_rms'), '.1e')} | | |",
              f"| LOFAR larger / smaller NSIDE, wall | {_f(f.get('lofar_wall_ratio'), '.2f')} "
              f"| | |"]
    for x in f.get("goals", {}).values():
        lines.append(f"| {x['what']} | {_f(x['value'], '.2f' if 'matvis' in x['what'] else '.0f')}"
                     f" | {x['goal']} | {_verdict(x['pass'])} |")
    load = f.get("load_avg_start_end")
    if load:
        lines += ["", f"Load average {load[0]:.1f} before and {load[1]:.1f} after the timed "
                      "runs (wall times stretch when it exceeds the cores; CPU times less)."]
    if f.get("quick"):
        lines += ["", "A --quick run: small inputs, which say little about the full-scale "
                      "goals (NSIDE 128 under 15 min and 8 GiB, NSIDE 256 under 1 h)."]
    return lines


def write_markdown(results: dict, path: Path) -> None:
    m = results["machine"]
    la0, la1 = m.get("load_avg_start"), m.get("load_avg_end")
    lines = [
        "# msleak benchmarks", "",
        f"Measured by `scripts/bench{' --quick' if results.get('quick') else ''}` on "
        f"{results['date']}: {m['cpus']} cores ({m.get('cpu', 'processor not recorded')}), "
        f"Python {m['python']}, {m['platform']}.",
        "",
        "**The machine is shared** with other engineers' builds and test runs (load average "
        + (f"{la0[0]:.1f} at the start, {la1[0]:.1f} at the end of the run" if la0 and la1
           else "not recorded")
        + "), so wall times vary by 20 % or more between runs; ratios of runs made side by "
        "side in the same run are more stable than absolute times. Each stage runs as its own "
        "process; wall time and peak resident memory (of the largest process of the stage) "
        "come from `/usr/bin/time -v`.", "",
        "Paper scale (docs/science.md section 2-3): NCP field, 13 h of 120 s slots, the 48 LOFAR HBA core "
        "fields (1128 baselines), 50 channels of 195.3125 kHz from 150 MHz, a 50 x 50-pixel "
        "Q/U cube over 15 deg (2500 point sources), the LOFAR beam with the phase-centre "
        "correction, 30-180 wavelengths. Rerun with `scripts/bench` (about 15 min; "
        "`--quick` for a smoke run, `--only STAGE,...` for parts); raw numbers in "
        "`bench-output/bench.json`.", "",
        "## Stages (default options: `--scheduler threads` on all cores)", "",
        *_stage_rows(results["stages"])]
    peers = results.get("peers", {})
    for key, title, fn in (("predict_vs_dp3", "predict vs DP3 predict + applybeam", _predict_peer),
                           ("beam_vs_everybeam", "Beam vs EveryBeam direct", _beam_peer),
                           ("ps_image_vs_ps_eor", "Power spectrum of an image cube vs ps_eor",
                            _ps_peer)):
        r = peers.get(key)
        if not r:
            continue
        lines += ["", f"## {title}", ""]
        if r.get("result"):
            try:
                lines += fn(r["result"])
            except (KeyError, TypeError, IndexError) as err:
                lines.append(f"(incomplete result: {err!r})")
        else:
            lines.append(f"FAILED (exit {r['exit']}): {r.get('stderr', '')[-300:]}")
        lines.append(f"\nWhole script: {r['wall_s']:.0f} s, peak {_f(r['peak_rss_mib'], '.0f')} "
                     f"MiB (`{r['command']}`).")
    if peers.get("predict_process"):
        lines += ["", "## predict vs DP3, whole process", "",
                  *_process_rows(peers["predict_process"])]
    if results.get("schedulers"):
        lines += ["", "## Schedulers (docs/parallel.md)", "",
                  "predict of a 1 h NCP MS (30 slots, paper sky and stations) and grid of the "
                  "paper MS with each local dask scheduler (`--workers` = all cores). The "
                  "difference is the largest absolute difference over the peak (predict: "
                  "complex64 visibilities; grid: the gridded cube).", "",
                  *_scheduler_rows(results["schedulers"])]
    if results.get("multisky"):
        lines += ["", "## Many skies in one predict", "", *_multisky_rows(results["multisky"])]
    if results.get("study"):
        lines += ["", "## The whole study, one and five sky realisations", "",
                  *_study_rows(results["study"])]
    if results.get("degrid"):
        lines += ["", "## Degrid predict against the direct predict", "",
                  *_degrid_rows(results["degrid"])]
    allsky = peers.get("allsky")
    if allsky:
        lines += ["", "## All-sky HEALPix predict, and against matvis", ""]
        lines += (_allsky_rows(allsky["result"]) if allsky.get("result") else
                  [f"FAILED (exit {allsky['exit']}): {allsky.get('stderr', '')[-300:]}"])
    sc = peers.get("scaling", {}).get("result")
    if sc:
        lines += ["", "## Scaling of predict and grid", "", *_scaling_rows(sc)]
    if results.get("notes"):
        lines += ["", "## Notes", "", *[f"* {n}" for n in results["notes"]]]
    path.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    src = Path(sys.argv[1] if len(sys.argv) > 1 else "bench-output/bench.json")
    dst = Path(sys.argv[2] if len(sys.argv) > 2 else "docs/benchmarks.md")
    write_markdown(json.loads(src.read_text()), dst)
