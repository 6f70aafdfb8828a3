"""Run DP3 (PyPI package ``dp3``) as an independent predict for msleak's scripts.

DP3 ``predict`` with ``usebeammodel=true, beammode=full`` computes
V_pq = sum_s J_p(s) B_s J_q(s)^H exp(...) for the point sources of a makesourcedb file,
and ``applybeam`` with ``invert=true`` (no direction: the phase centre) then applies
J_p(s0)^-1 . J_q(s0)^-H: together they are msleak's default, centre-corrected predict.
``beamproximitylimit=0``: each source gets its own beam, as in msleak (DP3 would otherwise
share one beam among sources closer than 60 arcsec).

A sky cube's voxels have tabulated spectra, which one makesourcedb source cannot hold, so
:func:`predict_cubes` writes one makesourcedb file per channel and sky (the sources
msleak predict itself reads from the cube, :func:`msleak.verbs.sky.read_sky`) and runs
DP3 once per channel on that channel only (``msin.startchan``), predicting every sky of
the run into its own column (a ``predict, applybeam, msout`` chain per sky).

The wheel needs three things from the environment, which :func:`dp3_environment` sets:
``OPENBLAS_NUM_THREADS=1``, ``EVERYBEAM_DATADIR`` (EveryBeam's coefficient files) and
``AIPSPATH``/``CASACORE_DATADIR`` pointing at python-casacore's measures data.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Sequence

import numpy as np

__all__ = ["dp3_available", "dp3_environment", "run_dp3", "run_dp3_predict", "predict_cubes"]

#: runs DP3's command line (``key=value`` arguments) through the wheel's entry point
_DP3_MAIN = "import sys, dp3; sys.argv = ['DP3'] + sys.argv[1:]; sys.exit(dp3.entrypoint())"


def dp3_available() -> bool:
    """True when the ``dp3`` Python package is importable."""
    return importlib.util.find_spec("dp3") is not None


def dp3_environment(threads: int | None = None) -> dict:
    """Environment for a DP3 subprocess (see the module docstring); ``threads`` sets
    ``OMP_NUM_THREADS``."""
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


def run_dp3(keys: Sequence[str], threads: int = 1, cwd: str | os.PathLike | None = None,
            timeout: float | None = None) -> float:
    """Run DP3 with the parset keys ``keys`` (``"key=value"`` strings) and ``threads``
    threads, in folder ``cwd``, for at most ``timeout`` seconds; returns the wall time in
    seconds.

    Raises
    ------
    RuntimeError
        If DP3 is not installed or exits with an error (its last lines in the message).
    """
    if not dp3_available():
        raise RuntimeError("the dp3 package is not installed (pip install dp3)")
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", _DP3_MAIN, *keys, f"numthreads={threads}"],
                          env=dp3_environment(threads), capture_output=True, text=True,
                          cwd=cwd, timeout=timeout)
    if proc.returncode != 0:
        tail = " | ".join((proc.stderr or proc.stdout).strip().splitlines()[-3:])
        raise RuntimeError(f"DP3 failed (exit {proc.returncode}): {tail}")
    return time.perf_counter() - start


def run_dp3_predict(ms: str | os.PathLike, skymodel: str | os.PathLike, column: str, *,
                    centre_correction: bool = True, threads: int = 1) -> float:
    """Predict the makesourcedb file ``skymodel`` into ``column`` of ``ms`` with DP3
    through the full LOFAR beam; ``centre_correction`` adds ``applybeam`` (invert, full
    beam, at the phase centre). Returns the wall time (s)."""
    steps = ["predict"] + (["applybeam"] if centre_correction else [])
    keys = [f"msin={Path(ms).resolve()}", "msout=.", f"msout.datacolumn={column}",
            f"steps=[{','.join(steps)}]", "predict.type=predict",
            f"predict.sourcedb={Path(skymodel).resolve()}", "predict.usebeammodel=true",
            "predict.beammode=full", "predict.beamproximitylimit=0"]
    if centre_correction:
        keys += ["applybeam.type=applybeam", "applybeam.invert=true", "applybeam.beammode=full"]
    return run_dp3(keys, threads=threads)


def _chain(name: str, skymodel: Path, column: str, last: bool) -> tuple[list[str], list[str]]:
    """Step names and keys of one sky: predict through the full beam, remove the beam at
    the phase centre, write ``column`` (the last sky's column is the run's msout)."""
    keys = [f"p{name}.type=predict", f"p{name}.sourcedb={skymodel}",
            f"p{name}.usebeammodel=true", f"p{name}.beammode=full",
            f"p{name}.beamproximitylimit=0",
            f"a{name}.type=applybeam", f"a{name}.invert=true", f"a{name}.beammode=full"]
    if last:
        return [f"p{name}", f"a{name}"], keys + [f"msout.datacolumn={column}"]
    keys += [f"o{name}.type=msout", f"o{name}.name=.", f"o{name}.datacolumn={column}"]
    return [f"p{name}", f"a{name}", f"o{name}"], keys


def predict_cubes(ms: str | os.PathLike, skies: Sequence[tuple[str | os.PathLike, str]],
                  threads: int = 1, progress=None) -> float:
    """Predict FITS sky cubes into columns of ``ms`` with DP3 predict + applybeam (the
    LOFAR beam of the MS through EveryBeam, the beam at the phase centre removed).

    Parameters
    ----------
    ms : Measurement Set whose channels are the cubes' channels (same frequencies)
    skies : (cube, column) pairs; each cube's voxels are re-centred on the MS's phase
        centre as msleak predict does, and written into ``column`` (complex64, as DP3
        writes it)
    threads : DP3 threads
    progress : optional callable ``progress(channel, nchan)`` after each channel

    Returns
    -------
    float
        Wall time of the DP3 runs, s.
    """
    import casacore.tables as pt

    from msleak.adapters.skymodel import write_skymodel
    from msleak.verbs.sky import read_sky

    ms = Path(ms).resolve()
    with pt.table(str(ms / "FIELD"), ack=False) as t:
        ra0, dec0 = np.degrees(t.getcell("PHASE_DIR", 0).reshape(-1)[:2])
    with pt.table(str(ms / "SPECTRAL_WINDOW"), ack=False) as t:
        chan_freq = t.getcell("CHAN_FREQ", 0)
    sources = [read_sky(cube, phase_centre=(ra0, dec0)) for cube, _ in skies]
    for (cube, _), src in zip(skies, sources):
        # 1e-6: the tolerance msleak predict itself applies to a cube's channels
        if src.freq.shape != chan_freq.shape or not np.allclose(src.freq, chan_freq,
                                                                rtol=1e-6):
            raise ValueError(f"{cube}: its channels are not the channels of {ms}")
    seconds = 0.0
    with tempfile.TemporaryDirectory(prefix="msleak_dp3_") as tmp:
        for channel in range(len(chan_freq)):
            steps, keys = [], [f"msin={ms}", "msout=.", f"msin.startchan={channel}",
                               "msin.nchan=1"]
            for k, ((_, column), src) in enumerate(zip(skies, sources)):
                path = write_skymodel(Path(tmp) / f"sky{k}.skymodel", src, channel=channel,
                                      overwrite=True)
                names, more = _chain(str(k), path, column, last=k == len(skies) - 1)
                steps += names
                keys += more
            seconds += run_dp3([*keys, f"steps=[{','.join(steps)}]"], threads=threads)
            if progress is not None:
                progress(channel, len(chan_freq))
    return seconds
