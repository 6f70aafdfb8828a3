"""Run independent chunk tasks with dask and hand their results back in order.

:func:`open_runner` returns a :class:`Runner` for a scheduler (``sync``, ``threads``,
``processes``, or a dask.distributed address or ``Client``); :meth:`Runner.map` runs
``func(job, shared)`` for a stream of jobs and yields ``(job, result)`` in job order,
with at most ``window`` jobs in flight. Each task gets a share of the cores as kernel
(numba, ducc0) threads (:func:`task_threads`); chunks are sized with
:attr:`Runner.memory_per_task`. casacore calls inside tasks are serialised by
:data:`CASACORE_LOCK`.

Schedulers, thread budgets and memory: docs/parallel.md.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import os
import re
import threading
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Iterator

from msleak.errors import ConfigurationError, InputError

__all__ = ["Runner", "open_runner", "check_scheduler", "parse_memory", "task_threads",
           "cpu_count", "CASACORE_LOCK", "WorkerLost", "LOCAL_SCHEDULERS"]

log = logging.getLogger(__name__)

LOCAL_SCHEDULERS = ("threads", "processes", "sync")
_MEMORY_UNITS = {"": 1, "B": 1, "K": 1024, "KB": 1024, "KIB": 1024, "M": 1024**2,
                 "MB": 1024**2, "MIB": 1024**2, "G": 1024**3, "GB": 1024**3, "GIB": 1024**3,
                 "T": 1024**4, "TB": 1024**4, "TIB": 1024**4}
_ADDRESS = re.compile(r"^(tcp|tls|ucx|inproc|ws|wss)://\S+$|^[A-Za-z0-9_.\-]+:\d+$")

#: Serialises casacore calls made by tasks of the threaded scheduler (casacore is not
#: thread-safe); uncontended under the other schedulers.
CASACORE_LOCK = threading.RLock()

_TASK = threading.local()


class WorkerLost(ConfigurationError):
    """A dask worker died (or kept dying) while running a task."""


def cpu_count() -> int:
    """Cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def task_threads() -> int:
    """Kernel threads (numba, ducc0) the current task may use (all cores outside a task)."""
    return int(getattr(_TASK, "threads", 0) or cpu_count())


def check_scheduler(text: str) -> str:
    """Validate a ``--scheduler`` value: threads, processes, sync or a scheduler address."""
    value = str(text).strip()
    if value.lower() in LOCAL_SCHEDULERS:
        return value.lower()
    if _ADDRESS.match(value):
        return value
    raise InputError(f"{text!r} is not a scheduler: use threads, processes, sync or a dask "
                     "scheduler address such as tcp://host:8786")


def parse_memory(value: str | float) -> int:
    """A memory size in bytes: a number of bytes, or ``"2GB"``, ``"512M"``, ``"1.5G"``
    (binary units)."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        number, unit = float(value), ""
    else:
        match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*([A-Za-z]*)\s*",
                             str(value))
        if not match or match.group(2).upper() not in _MEMORY_UNITS:
            raise InputError(f"{value!r} is not a memory size (e.g. 2GB, 512MB, 4e9)")
        number, unit = float(match.group(1)), match.group(2).upper()
    if not number > 0:
        raise InputError("memory_limit must be positive", param="memory_limit")
    return int(number * _MEMORY_UNITS[unit])


def _numba_threads(n: int):
    """Set numba's (thread-local) thread count; returns the previous value or None."""
    try:
        import numba
    except ImportError:  # pragma: no cover - numba is a dependency
        return None
    previous = numba.get_num_threads()
    numba.set_num_threads(max(1, min(int(n), numba.config.NUMBA_NUM_THREADS)))
    return previous


def _run_task(func: Callable, job: Any, shared: Any, threads: Any) -> Any:
    """Call ``func(job, shared)`` with the task's kernel-thread budget set."""
    if isinstance(threads, dict):  # distributed: cores of this host / threads on this host
        try:
            from distributed import get_worker

            host = get_worker().address.rsplit(":", 1)[0]
            threads = max(1, cpu_count() // max(1, int(threads.get(host, 1))))
        except (ImportError, ValueError):
            threads = 1
    if not threads:
        return func(job, shared)
    previous_task = getattr(_TASK, "threads", 0)
    _TASK.threads = int(threads)
    previous = _numba_threads(threads)
    try:
        return func(job, shared)
    finally:
        _TASK.threads = previous_task
        if previous is not None:
            _numba_threads(previous)


def _numba_threadsafe() -> bool:
    """True when numba has a thread-safe threading layer (tbb or omp)."""
    for module in ("numba.np.ufunc.tbbpool", "numba.np.ufunc.omppool"):
        try:
            __import__(module)
            return True
        except ImportError:
            continue
    return False


@dataclass
class Runner:
    """Where and how chunk tasks run (make one with :func:`open_runner`).

    Attributes
    ----------
    kind : {'sync', 'threads', 'processes', 'distributed'}
    workers : int
        Tasks that run at the same time.
    task_threads : int or dict or None
        Kernel threads per task (None: the kernels' defaults, in the sync path).
    memory_per_task : float
        Bytes a task may use (chunk sizes are derived from it).
    """

    kind: str
    workers: int
    task_threads: Any
    memory_per_task: float
    address: str = ""
    client: Any = None
    pool: Any = None
    _owns_client: bool = field(default=False, repr=False)

    def describe(self) -> str:
        where = f" at {self.address}" if self.address else ""
        threads = ("default" if not self.task_threads else
                   "cores/threads per host" if isinstance(self.task_threads, dict)
                   else str(self.task_threads))
        return (f"dask scheduler {self.kind}{where}: {self.workers} task(s) at a time, "
                f"{threads} kernel thread(s) each, {self.memory_per_task / 2**20:.0f} MiB "
                "per task")

    def map(self, func: Callable, jobs: Iterable, *, shared: Any = None,
            window: int | None = None) -> Iterator[tuple[Any, Any]]:
        """Yield ``(job, func(job, shared))`` for every job, in the order of ``jobs``.

        ``jobs`` is consumed lazily (at most ``window`` jobs are in flight or waiting,
        default the number of concurrent tasks), so a generator that reads inputs and the
        consumer of the results both run in the calling thread. ``func`` must be a
        module-level function (picklable) for the processes and distributed schedulers.
        """
        window = max(1, int(window or self.workers))
        if self.kind == "sync":
            for job in jobs:
                yield job, _run_task(func, job, shared, self.task_threads)
        elif self.kind == "distributed":
            yield from self._map_distributed(func, jobs, shared, window)
        else:
            yield from self._map_local(func, jobs, shared, window)

    def _map_local(self, func, jobs, shared, window):
        import dask

        it = iter(jobs)
        while True:
            batch = list(itertools.islice(it, window))
            if not batch:
                return
            threads = self._batch_threads(len(batch))
            if len(batch) == 1:  # no point in a graph for one task
                results = [_run_task(func, batch[0], shared, threads)]
            else:
                tasks = [dask.delayed(_run_task, pure=False)(func, job, shared, threads)
                         for job in batch]
                results = dask.compute(*tasks, scheduler=self.kind, pool=self.pool,
                                       num_workers=self.workers, optimize_graph=False)
            yield from zip(batch, results)
            del results  # not kept while the next batch runs

    def _batch_threads(self, ntask: int) -> Any:
        """Kernel threads of each of ``ntask`` local tasks run together: a batch smaller
        than :attr:`workers` (a run of one chunk, the last chunks) shares the idle tasks'
        threads among its own, so that no core waits."""
        if not isinstance(self.task_threads, int) or ntask >= self.workers:
            return self.task_threads
        return max(1, min(cpu_count(), self.task_threads * self.workers // max(1, ntask)))

    def _map_distributed(self, func, jobs, shared, window):
        from distributed import KilledWorker

        client = self.client
        shared_f = (client.scatter(shared, broadcast=True, hash=False)
                    if shared is not None else None)
        pending: deque = deque()
        it = iter(jobs)
        counter = itertools.count()

        def fill():
            while len(pending) < window:
                try:
                    job = next(it)
                except StopIteration:
                    return
                fut = client.submit(_run_task, func, job, shared_f, self.task_threads,
                                    pure=False, key=f"msleak-{func.__name__}-{next(counter)}"
                                    f"-{os.getpid()}-{id(self)}", retries=0)
                pending.append((job, fut))

        try:
            fill()
            while pending:
                job, fut = pending.popleft()
                try:
                    result = fut.result()
                except KilledWorker as err:
                    raise WorkerLost(
                        f"a dask worker died while running task {_name(job)} at "
                        f"{self.address} ({' '.join(str(err).split())[:120]}); what was "
                        "done so far is saved, rerun the same command to continue") from None
                finally:
                    fut.release()
                fill()
                yield job, result
        finally:
            for _, fut in pending:
                fut.cancel()
            if shared_f is not None:
                with contextlib.suppress(Exception):
                    client.cancel(list(shared_f.values()) if isinstance(shared_f, dict)
                                  else [shared_f])


def _name(job: Any) -> str:
    return str(getattr(job, "name", "") or getattr(job, "index", "") or "?")


def _connect(address: Any):
    try:
        import distributed
    except ImportError as err:
        raise ConfigurationError("a scheduler address needs dask.distributed "
                                 "(pip install distributed)") from err
    if isinstance(address, distributed.Client):
        return address, False
    try:
        client = distributed.Client(address, set_as_default=False)
    except (OSError, TimeoutError) as err:
        raise ConfigurationError(f"cannot reach the dask scheduler at {address} "
                                 f"({' '.join(str(err).split())[:120]}); start it with "
                                 "`dask scheduler` and `dask worker ADDRESS`, or use "
                                 "`scheduler='threads'`") from None
    return client, True


@contextlib.contextmanager
def open_runner(scheduler: Any = "threads", workers: int | None = None,
                memory_limit: float = 2 * 1024**3) -> Iterator[Runner]:
    """A :class:`Runner` for ``scheduler`` (closed on exit).

    Parameters
    ----------
    scheduler : {'threads', 'processes', 'sync'} or str or distributed.Client
        A local dask scheduler, a dask.distributed scheduler address, or a Client.
        None means 'threads'.
    workers : int, optional
        Tasks at a time; default all cores (local) or every worker thread (distributed).
    memory_limit : float
        Bytes. Local schedulers share it among the ``workers`` tasks; on a distributed
        cluster it is the budget of each worker process (capped by the worker's own
        memory limit), shared among its threads.
    """
    if memory_limit is None or not memory_limit > 0:
        raise InputError("memory_limit must be positive", param="memory_limit")
    if workers is not None and int(workers) < 1:
        raise InputError(f"workers must be >= 1, got {workers}", param="workers")
    kind = scheduler if not isinstance(scheduler, str) else check_scheduler(scheduler or "threads")
    if scheduler is None:
        kind = "threads"
    cores = cpu_count()
    if kind == "sync":
        yield Runner("sync", 1, None, float(memory_limit))
        return
    if kind in ("threads", "processes"):
        n = int(workers or cores)
        if kind == "threads" and n > 1 and not _numba_threadsafe():
            log.warning("numba has no thread-safe threading layer (install tbb); running "
                        "one task at a time")
            n = 1
        pool = None
        if n > 1:
            if kind == "threads":
                from concurrent.futures import ThreadPoolExecutor

                pool = ThreadPoolExecutor(n, thread_name_prefix="msleak")
            else:
                import multiprocessing
                from concurrent.futures import ProcessPoolExecutor

                pool = ProcessPoolExecutor(n, mp_context=multiprocessing.get_context("spawn"))
        runner = Runner(kind, n, max(1, cores // n), float(memory_limit) / n, pool=pool)
        log.debug("%s", runner.describe())
        try:
            yield runner
        finally:
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)
        return
    client, owns = _connect(kind)
    try:
        info = client.scheduler_info(n_workers=-1) if _accepts_n_workers(client) else \
            client.scheduler_info()
        wk = info.get("workers", {})
        if not wk:
            raise ConfigurationError(f"the dask scheduler at {client.scheduler.address} has no "
                                     "workers; start some with `dask worker ADDRESS`")
        per_host: dict[str, int] = {}
        budgets = []
        for addr, w in wk.items():
            host = addr.rsplit(":", 1)[0]
            nthreads = max(1, int(w.get("nthreads", 1)))
            per_host[host] = per_host.get(host, 0) + nthreads
            limit = float(w.get("memory_limit") or 0) or float(memory_limit)
            budgets.append(min(limit, float(memory_limit)) / nthreads)
        total = sum(max(1, int(w.get("nthreads", 1))) for w in wk.values())
        runner = Runner("distributed", int(workers or total), per_host, min(budgets),
                        address=str(client.scheduler.address), client=client,
                        _owns_client=owns)
        log.debug("%s", runner.describe())
        yield runner
    finally:
        if owns:
            client.close()


def _accepts_n_workers(client) -> bool:
    import inspect

    try:
        return "n_workers" in inspect.signature(client.scheduler_info).parameters
    except (TypeError, ValueError):  # pragma: no cover
        return False
