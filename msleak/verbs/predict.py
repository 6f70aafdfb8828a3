"""The predict verb: skies + beam + MS metadata -> visibilities, written in time chunks or
returned (docs/predict.md).

A run predicts one or more skies, each into its own column, into one or more MSs. Every
input is checked and every sky read and prepared before the first write
(:mod:`msleak.verbs.predict_plan`); the time chunks (:mod:`msleak.verbs.predict_chunks`) are
computed on a dask scheduler and written by this process, MS after MS, in time order, with
the run state of each column kept up to date (:mod:`msleak.verbs.predict_run`). A refusal found
while running (an :class:`~msleak.errors.MsleakError` other than a lost worker) puts
every MS back as it was (:class:`msleak.io.columns.Rollback`); an interruption (Ctrl-C, a
kill, a lost worker, an unexpected failure) keeps what was written for a rerun.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import time as _time
from pathlib import Path
from typing import Sequence, Union

import numpy as np

from msleak.adapters.beams import beam_options
from msleak.errors import InputError, MsleakError
from msleak.io import columns as colio
from msleak.io.ms import append_history, check_ms, open_table, read_antennas
from msleak.io.products import call_record
from msleak.parallel import open_runner
from msleak.parallel.runner import WorkerLost, parse_memory
from msleak.predict.options import (MIN_ELEVATION_DEG, DegridOptions, Method,
                                    check_min_elevation)
from msleak.verbs import predict_chunks as chunks
from msleak.verbs import predict_run as runstate
from msleak.verbs.noise import add_noise, station_sefd
from msleak.verbs.predict_plan import PredictResult, make_plan, make_targets

__all__ = ["predict", "PredictResult"]

_DEGRID = DegridOptions()

log = logging.getLogger(__name__)

PathLike = Union[str, os.PathLike]


def predict(ms: PathLike | Sequence[PathLike], sky, *,
            column: str | None | Sequence[str] = "MODEL_DATA",
            fov: float | None | Sequence[float | None] = None, beam: str = "everybeam",
            diameter: float | None = None, element_model: str | None = None,
            beam_file: str | os.PathLike | None = None, min_elevation: float = MIN_ELEVATION_DEG,
            ionosphere: str | os.PathLike | None = None, beam_errors: str | None = None,
            centre_correction: bool = True, interpolate_frequency: bool = False,
            double: bool = False, double_column: bool = False, flat_spectrum: bool = False,
            field: int | str | Sequence[int | str] | None = None,
            spw: int | Sequence[int] | None = None, memory_limit: str | float = "2GB",
            overwrite_data: bool = False, restart: bool = False, scheduler="threads",
            workers: int | None = None, progress: bool = False,
            method: Method = _DEGRID.method, epsilon: float = _DEGRID.epsilon,
            nsub: int | None = _DEGRID.nsub,
            extent: float | None | Sequence[float | None] = None,
            noise: float | dict[str, float] | None = None, noise_seed: int = 0):
    """Predict beam-corrupted visibilities of one or several skies into columns of MSs.

    Parameters
    ----------
    ms : path or sequence of paths
        Measurement Set(s), written in place (e.g. one per subband; each gets every sky).
    sky : path, sky Dataset, SkyCube, PointSources, HealpixSky, or a sequence of them
        A FITS cube, makesourcedb file, HEALPix map or SkyH5 file, or in memory; several
        skies are predicted in one pass, each into its own column (docs/predict.md).
    column : str, sequence of str, or None
        Target column of each sky (all different), created like DATA if missing (DATA needs
        ``overwrite_data``); None: the MS is opened read-only, the visibilities returned.
    fov, extent : float or sequence of float, optional
        Keep the central ``fov`` x ``fov`` deg, and the pixels (HEALPix) or sources
        (makesourcedb) within ``extent`` deg of the phase centre; once or once per sky.
    beam, diameter, element_model, beam_file, ionosphere, beam_errors
        The station beam ('everybeam', 'everybeam-direct', 'uvbeam', 'hyperbeam',
        'dipole' or 'none') and its options, the ionospheric Faraday rotation in front of it
        and its errors (:func:`msleak.adapters.beams.load_beam`).
    noise, noise_seed
        Thermal noise added to each written column once predicted: the SEFD (Jy) of every
        station or per station name, and the seed (:func:`msleak.noise`).
    centre_correction, interpolate_frequency, double, double_column : bool
        Remove the beam at the phase centre, V' = J_p(s0)^-1 V J_q(s0)^-H; interpolate the
        sky linearly to the MS channels instead of requiring a match; complex128 arithmetic
        (default complex64); also complex128 columns (msleak grid reads them, DP3 and
        WSClean cannot; not DATA).
    field, spw : id or name, or a sequence of them, optional
        FIELD ids or names, SPECTRAL_WINDOW ids; default all present.
    memory_limit, scheduler, workers, progress, overwrite_data, restart
        Working-set budget ("2GB" or bytes) shared by the chunks in flight, where they run
        (docs/parallel.md), how many at once (default all cores), a progress bar on stderr;
        allow ``column="DATA"``; start over instead of resuming an interrupted run.
    method, epsilon, nsub
        How pixel skies are predicted (:class:`msleak.predict.options.DegridOptions`).
    min_elevation, flat_spectrum
        HEALPix skies: pixels below ``min_elevation`` deg (from the array centre) add
        nothing at that time; a map of one frequency holds at every channel.

    Returns
    -------
    PredictResult (one MS and one sky given singly), else a list, MS by MS, sky by sky; with
    ``column=None`` an ``xr.DataArray`` (row, chan, corr) per sky (a list when ``sky`` is a
    sequence), coordinates row, time (MJD s), antenna1, antenna2, freq (Hz), corr.
    """
    given = dict(locals())
    t_start = _time.perf_counter()
    single_ms = isinstance(ms, (str, os.PathLike))
    paths = _check_paths([ms] if single_ms else list(ms))
    min_elevation = check_min_elevation(min_elevation)
    targets = make_targets(sky, column, fov, overwrite_data, extent, flat_spectrum)
    budget = parse_memory(memory_limit)
    dtype = np.dtype(np.complex128 if double or double_column else np.complex64)
    runs = _make_runs(paths, targets, {**given, "min_elevation": min_elevation}, dtype)
    args = dict(dtype=dtype, centre_correction=centre_correction, beam=beam,
                progress=progress, t_start=t_start)
    one_sky = not isinstance(sky, (list, tuple))
    if targets[0].column is None:
        arrays = _predict_in_memory(runs[0], scheduler, workers, budget, **args)
        return arrays[0] if one_sky else arrays
    _run(runs, scheduler, workers, budget, restart=restart, **args)
    _add_noise(runs, noise, noise_seed)
    results = _append_history(runs, call_record(predict, given))
    return results[0] if single_ms and one_sky else results


def _make_runs(paths: list[Path], targets: list, given: dict, dtype: np.dtype) -> list:
    """Check the options and make the plan and run state of every MS."""
    g = given
    options = beam_options(g["beam"], diameter=g["diameter"], element_model=g["element_model"],
                           beam_file=g["beam_file"], ionosphere=g["ionosphere"],
                           beam_errors=g["beam_errors"])
    _check_options(paths, targets, g["double_column"], g["noise"],
                   g["field"] is not None or g["spw"] is not None)
    degrid = DegridOptions(g["method"], g["epsilon"], g["nsub"])
    return [runstate.new_run(make_plan(
        p, targets, beam=g["beam"], centre_correction=g["centre_correction"], dtype=dtype,
        interpolate_frequency=g["interpolate_frequency"], field_sel=g["field"],
        spw_sel=g["spw"], beam_options=options, double_column=g["double_column"],
        min_elevation=g["min_elevation"], degrid=degrid,
        flat_spectrum=g["flat_spectrum"])) for p in paths]


def _check_options(paths: list[Path], targets: list, double_column: bool, noise,
                   selected: bool) -> None:
    """Refuse options that do not go together; repair the MSs a killed run left (only
    when they are written)."""
    _check_noise(paths, targets, noise, selected)
    in_memory = targets[0].column is None
    if in_memory and len(paths) > 1:
        raise InputError("column=None returns the visibilities of one Measurement Set; "
                         "give one MS, or a column to write")
    if in_memory and double_column:
        raise InputError("double_column=True sets the type of the columns written; with "
                         "column=None use double=True (complex128 visibilities)")
    if double_column and any(t.column == "DATA" for t in targets):
        raise InputError("double_column makes new complex128 columns; DATA keeps its type: "
                         "use double to write DATA", param=("double_column", "double"))
    if not in_memory:
        for p in paths:
            colio.check_writable(p)
            colio.repair_interrupted(p)  # header files a killed run may have truncated


def _check_noise(paths: list[Path], targets: list, noise, selected: bool) -> None:
    """Refuse noise without a column to add it to, with a field or spw selection (the noise
    covers every row), or SEFDs that do not fit the MSs."""
    if noise is None:
        return
    if targets[0].column is None:
        raise InputError("noise is added to the columns predict writes; give a column, or "
                         "add noise to returned visibilities yourself", param="noise")
    if selected:
        raise InputError("noise covers every row of the MS, not only the selected `field` "
                         "or `spw`: predict every field and spw, or add the noise afterwards "
                         "with msleak noise", param="noise")
    for path in paths:
        station_sefd(noise, read_antennas(path).names)


def _add_noise(runs: list, sefd, seed: int) -> None:
    """Add the thermal noise to each column, from its first row: the noise starts once every
    column is predicted, so a column is noiseless whether this run wrote it or left it as
    an earlier, interrupted run of the same skies wrote it; nothing without ``sefd``."""
    for run in runs if sefd is not None else ():
        for target, result in zip(run.plan.targets, run.results):
            added = add_noise(run.plan.ms, target.column, sefd, seed, target.column,
                              start_over=True)
            result.noise_sigma_jy = added.sigma_jy


def _check_paths(ms_list: list) -> list[Path]:
    """The Measurement Sets of a run, checked to exist and to be given once."""
    paths = [check_ms(m) for m in ms_list]
    if not paths:
        raise InputError("no Measurement Set given")
    seen: set[Path] = set()
    for p in paths:
        if p.resolve() in seen:
            raise InputError(f"{p} is given twice")
        seen.add(p.resolve())
    return paths


@contextlib.contextmanager
def _runner(runs: list, scheduler, workers, budget: int):
    """The dask runner of a run; refuses the EveryBeam direct model off this process.
    A run whose skies are all degridded computes one chunk at a time on all cores
    (unless ``workers`` says otherwise): the degridder's kernel and FFTs are threaded,
    and a longer chunk shares its w-layer FFTs among more rows."""
    if workers is None and scheduler in ("threads", "sync") and all(
            sky.grid is not None for run in runs for comp in run.plan.skies.values()
            for sky in comp.skies):
        workers = 1
    with open_runner(scheduler, workers, budget) as runner:
        if runner.kind in ("processes", "distributed"):
            for run in runs:
                model = chunks.registered_beam(run.plan.beam_token)
                if type(model).__name__ == "EveryBeamDirect":
                    raise InputError("`beam='everybeam-direct'` reads the MS main table, "
                                     "which stays locked while predict writes it; use "
                                     "`scheduler='threads'` or `scheduler='sync'`")
        yield runner


def _run(runs: list, scheduler, workers, budget: int, *, dtype, centre_correction: bool,
         beam: str, restart: bool, progress: bool, t_start: float) -> None:
    """Create the columns, compute and write every chunk; undo the run if it is refused."""
    rollbacks: list[colio.Rollback] = []
    try:
        with _runner(runs, scheduler, workers, budget) as runner:
            runstate.create_columns(runs, rollbacks)
            for run in runs:
                run.timings["setup"] = _time.perf_counter() - t_start
            bar = _progress_bar(sum(r.plan.total_rows for r in runs), progress)
            jobs = _all_chunks(runs, runner, dtype, centre_correction, beam,
                               restart, bar, t_start)
            try:
                _write_chunks(runner, jobs, runs, bar, t_start)
            finally:
                bar.close()
                for run in runs:
                    if run.stack is not None:
                        run.stack.close()
                        run.stack = None
    except MsleakError as err:
        if not isinstance(err, WorkerLost):  # a refusal: undo; a lost worker: resumable
            for rollback in reversed(rollbacks):  # each puts back the table it found
                rollback.restore()
        raise
    finally:
        for rollback in rollbacks:
            rollback.close()


def _all_chunks(runs, runner, dtype, centre_correction, beam, restart, bar, t_start):
    """The chunks of every MS in write order; each MS is opened when its turn comes and
    finished right away when nothing is left to predict."""
    index = 0
    for k, run in enumerate(runs):
        runstate.start(run, restart, bar)
        previous = None
        for job in chunks.iter_chunks(k, run, runner.memory_per_task, dtype,
                                      centre_correction, beam, tasks=runner.workers):
            job.index = index
            index += 1
            if previous is not None:
                yield previous
            previous = job
        if previous is None:
            runstate.finish(run, t_start)
        else:
            previous.last = True
            yield previous


def _write_chunks(runner, jobs, runs: list, bar, t_start: float) -> None:
    """Compute the chunks on ``runner`` and write them in order, updating the run states."""
    with contextlib.closing(runner.map(chunks.chunk_task, jobs)) as done:
        for job, (vis, timings, n_per_baseline) in done:
            run = runs[job.plan]
            runstate.write_chunk(run, job, vis)
            del vis
            _account(run, job, timings, n_per_baseline)
            bar.update(int(job.rows.size))
            if job.last:
                runstate.finish(run, t_start)


def _account(run, job, timings: dict, n_per_baseline: int) -> None:
    """Add a task's stage timings, time slots and per-baseline rows to its run, and log
    its notes (sky index, line), the first of each sky (``run.noted``)."""
    run.rows_per_baseline += n_per_baseline
    for k, note in timings.pop("notes", []):
        if k not in run.noted:
            run.noted.add(k)
            log.warning("%s: %s", run.plan.targets[k].label, note)
    for key, value in timings.items():
        run.timings[key] = run.timings.get(key, 0.0) + value
    run.n_slots += int(job.times.size)


def _predict_in_memory(run, scheduler, workers, budget: int, *, dtype, centre_correction,
                       beam, progress, t_start) -> list:
    """Every chunk of one MS computed and gathered into one DataArray per sky (read-only)."""
    plan = run.plan
    _check_one_layout(plan)
    run.active = list(range(len(plan.targets)))
    parts: list = []
    with _runner([run], scheduler, workers, budget) as runner, open_table(plan.ms) as table:
        run.table = table
        run.timings["setup"] = _time.perf_counter() - t_start
        bar = _progress_bar(plan.total_rows, progress)
        try:
            jobs = chunks.iter_chunks(0, run, runner.memory_per_task, dtype,
                                      centre_correction, beam, tasks=runner.workers)
            with contextlib.closing(runner.map(chunks.chunk_task, _numbered(jobs))) as done:
                for job, (vis, timings, n_per_baseline) in done:
                    parts.append((job.rows, job.times[job.tidx], job.stations[job.p],
                                  job.stations[job.q], vis))
                    _account(run, job, timings, n_per_baseline)
                    bar.update(int(job.rows.size))
        finally:
            bar.close()
            run.table = None
    return _data_arrays(plan, parts)


def _numbered(jobs):
    for index, job in enumerate(jobs):
        job.index = index
        yield job


def _check_one_layout(plan) -> None:
    """Refuse a selection whose rows do not share one channel axis and correlation order."""
    freqs = {tuple(plan.spw_meta[plan.ddesc[d][0]].freq) for _, d in plan.groups}
    names = {tuple(plan.feeds[d].names) for _, d in plan.groups}
    if len(freqs) > 1 or len(names) > 1:
        raise InputError(f"{plan.ms}: the selected rows have different channels or "
                         "correlations, and column=None returns one (row, chan, corr) array; "
                         "select one spectral window with spw=")


def _data_arrays(plan, parts: list) -> list:
    """One DataArray (row, chan, corr) per sky from the chunks' rows, in row order."""
    import xarray as xr

    rows = np.concatenate([p[0] for p in parts])
    order = np.argsort(rows, kind="stable")
    coords = {"row": rows[order],
              "time": ("row", np.concatenate([p[1] for p in parts])[order]),
              "antenna1": ("row", np.concatenate([p[2] for p in parts])[order]),
              "antenna2": ("row", np.concatenate([p[3] for p in parts])[order]),
              "freq": ("chan", plan.spw_meta[plan.ddesc[plan.groups[0][1]][0]].freq),
              "corr": list(plan.feeds[plan.groups[0][1]].names)}
    out = []
    for k, target in enumerate(plan.targets):
        values = np.concatenate([p[4][k] for p in parts])[order]
        out.append(xr.DataArray(values, dims=("row", "chan", "corr"), coords=coords,
                                name="vis", attrs={**plan.settings[k], "units": "Jy",
                                                   "ms": str(plan.ms)}))
    return out


def _append_history(runs: list, command: str) -> list:
    """One MS HISTORY row per MS saying what the run wrote; the runs' results."""
    for run in runs:
        plan = run.plan
        skies = "; ".join(f"{t.label} -> {t.column}{' (unchanged)' if r.skipped else ''}"
                          for t, r in zip(plan.targets, run.results))
        s = plan.settings[0]
        noise = [f"; thermal noise of rms {r.noise_sigma_jy:.4g} Jy per part added"
                 for r in run.results if r.noise_sigma_jy][:1]
        append_history(plan.ms, f"predict: {skies}; beam {s['beam']}, centre correction "
                                f"{'on' if s['centre_correction'] else 'off'}, "
                                f"{s['precision']}{''.join(noise)}", command=command)
    return [res for run in runs for res in run.results]


class _NoBar:
    def update(self, n: int) -> None:
        pass

    def close(self) -> None:
        pass


def _progress_bar(total: int, enabled: bool):
    if not enabled:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, unit="row", desc="predict", file=sys.stderr, dynamic_ncols=True)
