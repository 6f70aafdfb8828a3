"""Parallel and multi-Measurement-Set execution with dask (docs/parallel.md).

* :mod:`msleak.parallel.runner`: :func:`open_runner` gives a :class:`Runner` that runs
  independent chunk tasks on dask's ``sync``, ``threads`` or ``processes`` scheduler or on
  a dask.distributed cluster, and yields their results in order with bounded memory.
* :mod:`msleak.parallel.multims`: :func:`frequency_layout` puts the channels of several
  Measurement Sets (one per subband) on one regular frequency axis, with gaps and
  overlaps detected.

The numeric kernels stay pure; the chunk tasks live beside the code they parallelise
(:mod:`msleak.predict.chunks`, :mod:`msleak.verbs.grid_tasks`), the driver that writes or
folds their results runs in the calling process. dask.distributed is imported only for a
scheduler address.
"""

from msleak.parallel.multims import FrequencyLayout, frequency_layout
from msleak.parallel.runner import (CASACORE_LOCK, LOCAL_SCHEDULERS, Runner, WorkerLost,
                                    check_scheduler, cpu_count, open_runner, parse_memory,
                                    task_threads)

__all__ = ["Runner", "open_runner", "check_scheduler", "parse_memory", "task_threads", "cpu_count",
           "CASACORE_LOCK", "WorkerLost", "LOCAL_SCHEDULERS", "FrequencyLayout",
           "frequency_layout"]
