"""Stages of scripts/bench for many skies: predict of 1, 3 and 15 skies in one pass on the
paper's NCP MS, and the whole study with one and with five sky realisations, each with
DP3's time for the same work (from DP3's measured time per baseline-slot and source,
measured side by side in the same run by scripts/bench_predict.py).

DP3 has no several-skies pass: each sky is one predict + applybeam run, whose cost grows
with the number of sources (one beam evaluation and one DFT per source). DP3's time for a
piece of work is therefore estimated as (rows / rows per slot) x (DP3 seconds per slot of
2500 sources) x (sources / 2500), summed over the skies; the estimate assumes a cost linear
in the sources, which DP3's per-source predict and beam make close to true.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

#: the study's fields of view: (label, pixels of the 50-pixel 15-deg cube)
FIELDS_OF_VIEW = (("15deg", 50), ("9deg", 28), ("4deg", 16))
SEEDS = (1, 2, 3, 4, 5)


def make_skies(stage, msleak: list, out: Path) -> list[tuple[Path, int]]:
    """The 15 skies (5 seeds x 3 fields of view) as FITS cubes; [(path, n_sources)]."""
    skies = []
    for seed in SEEDS:
        full = out / f"sky_s{seed}.fits"
        if not full.exists():
            stage(f"sky_s{seed}", [*msleak, "sky", full, "--seed", str(seed), "--overwrite"],
                  "multisky")
        for label, npix in FIELDS_OF_VIEW:
            cube = full if npix == 50 else out / f"sky_s{seed}_{label}.fits"
            if not cube.exists():
                stage(f"sky_s{seed}_{label}", [*msleak, "sky", cube, "--crop", full,
                                               "--crop-npix", str(npix), "--overwrite"],
                      "multisky")
            skies.append((cube, npix * npix))
    return skies


def warm_up(msleak: list, out: Path, skies: list) -> None:
    """Compile (and cache) numba's kernels on a 30 min MS, untimed, so that no timed run
    pays for compilation."""
    small = out / "ncp_warm.ms"
    subprocess.run([*msleak, "simulate", small, "--field", "ncp", "--duration", "0.5",
                    "--overwrite"], check=True)
    pairs = []
    for k, (cube, _) in enumerate(skies[:3]):
        pairs += ["--sky", cube, "--column", f"MODEL_WARM_{k}"]
    for given in (pairs[:4], pairs):
        subprocess.run([*msleak, "predict", small, *given, "--no-progress", "--restart"],
                       check=True)
    shutil.rmtree(small, ignore_errors=True)


def predict_many(stage, msleak: list, ms: Path, skies: list, counts=(1, 3, 15)) -> dict:
    """Time ``msleak predict`` of the first n skies in one pass, for each n in ``counts``
    (after :func:`warm_up`)."""
    warm_up(msleak, ms.parent, skies)
    results = {}
    for n in counts:
        pairs = []
        for k, (cube, _) in enumerate(skies[:n]):
            pairs += ["--sky", cube, "--column", f"MODEL_BENCH_{k}"]
        r = stage(f"predict_{n}_skies", [*msleak, "predict", ms, *pairs, "--no-progress",
                                         "--restart"], "multisky")
        r["n_skies"] = n
        r["n_sources"] = sum(s for _, s in skies[:n])
        results[n] = r
    one = results[counts[0]]["wall_s"]
    for n, r in results.items():
        r["ratio_to_one_sky"] = round(r["wall_s"] / one, 2)
    return results


def dp3_estimate(dp3_per_slot_2500: float, rows: int, rows_per_slot: int,
                 sources: list[int]) -> float:
    """DP3 predict + applybeam seconds for ``rows`` rows of every sky in ``sources``."""
    return sum(dp3_per_slot_2500 * rows / rows_per_slot * n / 2500 for n in sources)


def study(stage, msleak: list, out: Path, seeds: int, quick: bool = False,
          workers: int | None = None) -> dict:
    """Time the whole study (``msleak paper``, ``--quick`` if asked) with ``seeds`` sky
    realisations, every step rerun, with ``--workers`` if given (else its default)."""
    name = f"paper_seeds{seeds}" + (f"_workers{workers}" if workers else "")
    outdir = out / name
    r = stage(name, [*msleak, "paper", outdir, "--seeds", str(seeds), "--overwrite",
                     *(["--quick"] if quick else []),
                     *(["--workers", str(workers)] if workers else [])], "study")
    r["seeds"] = seeds
    r["workers"] = workers or "default"
    r["outdir"] = str(outdir)
    return r


def study_rows(outdir: Path) -> dict:
    """{field: (rows, rows per slot)} of the study's Measurement Sets."""
    import casacore.tables as pt
    import numpy as np

    found = {}
    for ms in sorted(Path(outdir).glob("*/*.ms")):
        with pt.table(str(ms), ack=False) as t:
            rows = t.nrows()
            per_slot = int(np.unique(t.getcol("TIME"), return_counts=True)[1].max())
        found[ms.parent.name] = (rows, per_slot)
    return found
