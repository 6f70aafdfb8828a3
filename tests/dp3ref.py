"""Run DP3 (PyPI package ``dp3``) as the independent reference for ``msleak predict``.

DP3 ``predict`` with ``usebeammodel=true, beammode=full`` computes
V_pq = sum_s J_p(s) B_s J_q(s)^H exp(...) for point sources of a makesourcedb file, and
``applybeam`` with ``invert=true`` at the phase centre applies J_p(s0)^-1 . J_q(s0)^-H:
together they are msleak's default (centre-corrected) predict. Used by the tests and by
``scripts/bench_predict.py``; not part of the package.

The wheel needs three things from the environment, which :func:`dp3_environment` sets:
``OPENBLAS_NUM_THREADS=1``, ``EVERYBEAM_DATADIR`` (EveryBeam's coefficient files) and
``AIPSPATH``/``CASACORE_DATADIR`` pointing at python-casacore's measures data.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from msleak.errors import ConfigurationError

__all__ = ["dp3_available", "dp3_environment", "run_dp3_predict"]


def dp3_available() -> bool:
    """True when the ``dp3`` Python package is importable."""
    import importlib.util

    return importlib.util.find_spec("dp3") is not None


def dp3_environment(threads: int | None = None) -> dict:
    """Environment for a DP3 subprocess (see module docstring)."""
    import casacore

    from msleak._everybeam import everybeam_datadir

    casacore_dir = Path(casacore.__file__).parent
    env = dict(os.environ)
    env["OPENBLAS_NUM_THREADS"] = "1"
    env["EVERYBEAM_DATADIR"] = str(everybeam_datadir())
    if "AIPSPATH" not in env:       # msleak's import sets it (msleak.io.casacore_data)
        env["AIPSPATH"] = str(casacore_dir)
        env["CASACORE_DATADIR"] = str(casacore_dir / "data")
    if threads:
        env["OMP_NUM_THREADS"] = str(threads)
    return env


def run_dp3_predict(ms: str | os.PathLike, skymodel: str | os.PathLike, column: str, *,
                    centre_correction: bool = True, threads: int | None = None,
                    workdir: str | os.PathLike | None = None) -> float:
    """Predict ``skymodel`` into ``column`` of ``ms`` with DP3; returns the wall time (s).

    ``centre_correction`` adds ``applybeam`` (invert, full beam, at the phase centre).
    """
    if not dp3_available():
        raise ConfigurationError("the dp3 package is not installed (pip install dp3)")
    steps = ["predict"] + (["applybeam"] if centre_correction else [])
    lines = [f"msin={Path(ms).resolve()}", "msout=.", f"msout.datacolumn={column}",
             f"steps=[{','.join(steps)}]",
             "predict.type=predict", f"predict.sourcedb={Path(skymodel).resolve()}",
             "predict.usebeammodel=true", "predict.beammode=full"]
    if centre_correction:
        lines += ["applybeam.type=applybeam", "applybeam.invert=true",
                  "applybeam.beammode=full"]
    if threads:
        lines.append(f"numthreads={int(threads)}")
    workdir = Path(workdir) if workdir else Path(ms).resolve().parent
    parset = workdir / f"dp3_{column}.parset"
    parset.write_text("\n".join(lines) + "\n")
    code = "import sys, dp3; sys.argv = ['DP3'] + sys.argv[1:]; sys.exit(dp3.entrypoint())"
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code, str(parset)], env=dp3_environment(threads),
                          capture_output=True, text=True, cwd=workdir)
    elapsed = time.perf_counter() - start
    if proc.returncode != 0:
        tail = " | ".join((proc.stderr or proc.stdout).strip().splitlines()[-3:])
        raise ConfigurationError(f"DP3 failed (exit {proc.returncode}): {tail}")
    return elapsed
