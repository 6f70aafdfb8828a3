"""Resumable steps for multi-stage runs (``msleak paper``; docs/paper.md "Resuming").

A step is one msleak command line with declared inputs and outputs. It is skipped when
its outputs exist and the fingerprint of its command, its inputs (size and modification
time of every file), the earlier steps it names in ``after`` and the msleak version
equals the one recorded in ``OUTDIR/.msleak-steps.json`` when the outputs were made.

With ``workers > 1`` steps whose files do not overlap run at once (docs/paper.md "Steps at
once"): a step waits for every earlier step that writes a file it reads or writes, that
reads a file it writes, or that it names in ``after``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import queue
import shlex
import signal
import sys
import threading
import time
import traceback
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from msleak import __version__ as MSLEAK_VERSION
from msleak._callable import resolve
from msleak.errors import MsleakError

__all__ = ["Step", "StepRunner", "ProcessInvoker", "step_failed", "dependencies",
           "COMMAND_RUNNER",
           "predict_precision"]

log = logging.getLogger(__name__)
#: how often (s) the thread that runs steps at once looks for a Ctrl-C
_POLL_S = 0.2


@dataclass
class Step:
    """One command: ``args`` are the msleak arguments (without the program name)."""

    name: str
    args: list
    inputs: list = field(default_factory=list)
    outputs: list = field(default_factory=list)
    #: names of earlier steps whose results this step reads (used instead of fingerprinting
    #: files that later steps modify, such as a Measurement Set that gains columns)
    after: list = field(default_factory=list)
    #: files the step reads that are tracked through ``after`` rather than fingerprinted
    #: (the Measurement Set); they order the step against steps that write them
    reads: list = field(default_factory=list)

    @property
    def command(self) -> str:
        return "msleak " + " ".join(shlex.quote(str(a)) for a in self.args)


def predict_precision(double: bool) -> list[str]:
    """The predict options of a study's ``--double/--no-double``: complex128 arithmetic into
    complex128 columns, or neither."""
    return ["--double", "--double-column"] if double else []


def step_failed(args: Sequence[str], rc, command: str, rerun: str | None = None
                ) -> MsleakError:
    """The error of a step whose command exited with ``rc``; ``rerun`` is the command
    line that resumes (default ``msleak COMMAND``)."""
    return MsleakError(f"`msleak {' '.join(map(str, args))}` failed (exit {rc}); fix what it "
                       f"said above and rerun `{rerun or 'msleak ' + command}` to resume")


def dependencies(steps: Sequence[Step]) -> dict[str, set[str]]:
    """``{step name: names of the earlier steps it must wait for}``: those that write a file
    it reads or writes, that read a file it writes, or that it names in ``after`` (names
    not among the earlier steps only enter its fingerprint)."""
    def paths(items):
        return {os.path.abspath(p) for p in items}

    deps: dict[str, set[str]] = {}
    for i, step in enumerate(steps):
        mine_read = paths(step.inputs) | paths(step.reads)
        mine_written = paths(step.outputs)
        deps[step.name] = set(step.after) & {earlier.name for earlier in steps[:i]}
        for earlier in steps[:i]:
            written = paths(earlier.outputs)
            read = paths(earlier.inputs) | paths(earlier.reads)
            if written & (mine_read | mine_written) or read & mine_written:
                deps[step.name].add(earlier.name)
    return deps


def _fingerprint_path(path: Path) -> list:
    path = Path(path)
    if not path.exists():
        return [str(path), "missing"]
    if path.is_file():
        st = path.stat()
        return [str(path), st.st_size, int(st.st_mtime_ns)]
    entries = []
    for root, _, files in os.walk(path):
        for name in sorted(files):
            p = Path(root) / name
            st = p.stat()
            entries.append([str(p.relative_to(path)), st.st_size, int(st.st_mtime_ns)])
    return [str(path), sorted(entries)]


class StepRunner:
    """Run :class:`Step` objects, skipping those whose inputs are unchanged."""

    def __init__(self, outdir: Path, overwrite: bool = False):
        self.outdir = Path(outdir)
        self.state_file = self.outdir / ".msleak-steps.json"
        self.overwrite = overwrite
        self.state = {}
        if self.state_file.exists():
            try:
                self.state = json.loads(self.state_file.read_text())
            except json.JSONDecodeError:
                log.warning("%s is unreadable; every step will run again", self.state_file)
        self.log: list[dict] = []
        self._lock = threading.Lock()

    def fingerprint(self, step: Step) -> str:
        upstream = [self.state.get(name, {}).get("fingerprint", "never-run")
                    for name in step.after]
        blob = json.dumps([step.args, [_fingerprint_path(p) for p in step.inputs], upstream,
                           MSLEAK_VERSION], default=str)
        return hashlib.sha256(blob.encode()).hexdigest()

    def run(self, step: Step, invoke) -> bool:
        """Run ``step`` with ``invoke(args)`` unless it is up to date; True if it ran."""
        with self._lock:
            digest = self.fingerprint(step)
            record = self.state.get(step.name)
        done = (record is not None and record.get("fingerprint") == digest
                and all(Path(p).exists() for p in step.outputs))
        if done and not self.overwrite:
            log.info("skip %s (up to date)", step.name)
            with self._lock:
                self.log.append({"name": step.name, "command": step.command, "skipped": True,
                                 "seconds": record.get("seconds", 0.0)})
            return False
        log.info("run  %s: %s", step.name, step.command)
        t0 = time.perf_counter()
        if getattr(invoke, "labels_output", False):
            invoke(list(map(str, step.args)), label=step.name)
        else:
            invoke(list(map(str, step.args)))
        seconds = time.perf_counter() - t0
        missing = [str(p) for p in step.outputs if not Path(p).exists()]
        if missing:
            raise MsleakError(f"step {step.name} did not produce {', '.join(missing)}")
        with self._lock:
            self.state[step.name] = {"fingerprint": self.fingerprint(step), "seconds": seconds,
                                     "command": step.command,
                                     "finished": time.strftime("%Y-%m-%dT%H:%M:%S")}
            self.outdir.mkdir(parents=True, exist_ok=True)
            tmp = self.state_file.with_suffix(".tmp")
            tmp.write_text(json.dumps(self.state, indent=1))
            os.replace(tmp, self.state_file)
            self.log.append({"name": step.name, "command": step.command, "skipped": False,
                             "seconds": seconds})
        if getattr(invoke, "labels_output", False):
            log.info("done %s (%.1f s)", step.name, seconds)
        return True

    def run_all(self, steps: Sequence[Step], invoke, workers: int = 1) -> list[dict]:
        """Run every step; with ``workers > 1``, up to ``workers`` at once in the order of
        :func:`dependencies` (``invoke`` must then be safe to call from several threads).
        After a failure no further step starts; those running finish and are recorded,
        then the first error is raised. Returns the log in the order of ``steps``."""
        if workers <= 1:
            for step in steps:
                self.run(step, invoke)
        else:
            self._run_concurrently(steps, invoke, workers)
        order = {step.name: i for i, step in enumerate(steps)}
        self.log.sort(key=lambda entry: order.get(entry["name"], len(order)))
        return self.log

    def _run_concurrently(self, steps: Sequence[Step], invoke, workers: int) -> None:
        deps = dependencies(steps)
        pending, running, finished, errors = list(steps), {}, set(), []
        with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="msleak-step") as pool:
            try:
                while pending or running:
                    for step in list(pending):
                        if errors or len(running) >= workers:
                            break
                        if deps[step.name] <= finished:
                            pending.remove(step)
                            running[pool.submit(self.run, step, invoke)] = step
                    if not running:
                        break
                    # a timeout, not a bare wait: a SIGINT that the kernel hands to a step
                    # thread raises in this thread only once it runs Python code again
                    done, _ = wait(running, timeout=_POLL_S, return_when=FIRST_COMPLETED)
                    for future in done:
                        step = running.pop(future)
                        try:
                            future.result()
                            finished.add(step.name)
                        except Exception as err:  # noqa: BLE001 - raised after the others end
                            errors.append(err)
            except BaseException:
                stop = getattr(invoke, "stop", None)
                if stop is not None:
                    stop()
                raise
        if errors:
            raise errors[0]


#: the function that runs one msleak command line in a worker process (imported there)
COMMAND_RUNNER = "msleak.cli:run_command"


class ProcessInvoker:
    """``invoke(args, label)`` for steps run at once: each command line runs in one of up
    to ``workers`` msleak worker processes (started on first use, each importing msleak
    once, kept for later steps; ``close()`` ends them). The worker writes the step's
    output lines with ``[label]`` in front; a non-zero exit raises :func:`step_failed`.
    Workers run in their own session, so a Ctrl-C reaches them once, through ``stop()``,
    which interrupts every running step (each then leaves its files readable). A worker
    whose parent has gone interrupts its step itself.

    ``run(args)`` is the function a worker calls, returning an exit status: a module-level
    function, or its dotted path ``"module:function"``, imported by the worker; by default
    msleak's command line (:data:`COMMAND_RUNNER`, which the study names and never
    imports). ``rerun`` is the command line that
    resumes the run, named in errors (default ``msleak COMMAND``)."""

    labels_output = True

    def __init__(self, global_args: Sequence[str] = (), command: str = "paper",
                 workers: int = 2, run=None, rerun: str | None = None):
        import multiprocessing

        self.global_args = list(global_args)
        self.command = command
        self.rerun = rerun or f"msleak {command}"
        self.run = run or COMMAND_RUNNER
        self._context = multiprocessing.get_context("spawn")
        self._idle: queue.Queue = queue.Queue()
        for _ in range(workers):
            self._idle.put(None)                   # a slot; its process starts on first use
        self._busy: set = set()
        self._lock = threading.Lock()
        self._closed = False

    def _start(self):
        here, there = self._context.Pipe()
        # not a daemon: a step may start processes of its own (--scheduler processes)
        proc = self._context.Process(target=_worker_main, args=(there, self.run, os.getpid()))
        proc.start()
        there.close()
        return proc, here

    def __call__(self, args: Sequence[str], label: str | None = None) -> None:
        worker = self._idle.get()
        died = False
        try:
            if self._closed:                       # no new worker once stopping
                raise MsleakError(f"`{self.rerun}` is stopping")
            if worker is None or not worker[0].is_alive():
                worker = self._start()
            proc, conn = worker
            with self._lock:                       # stop() signals it, or it never runs
                if self._closed:
                    raise MsleakError(f"`{self.rerun}` is stopping")
                self._busy.add(proc)
            try:
                conn.send(([*self.global_args, *map(str, args)], f"[{label or args[0]}] "))
                rc = conn.recv()
            except (EOFError, OSError):            # the worker died (killed, out of memory)
                died = True
        finally:
            if worker is not None:
                with self._lock:
                    self._busy.discard(worker[0])
                if died or self._closed:
                    _end_worker(*worker)
                    worker = None
            self._idle.put(worker)
        if died:
            code = proc.exitcode
            how = f"killed by signal {-code}" if code is not None and code < 0 else \
                f"exit {code}"
            raise MsleakError(f"`msleak {' '.join(map(str, args))}` stopped: its worker "
                              f"process ended ({how}; out of memory?); rerun "
                              f"`{self.rerun}` to resume")
        if rc != 0:
            raise step_failed(args, rc, self.command, self.rerun)

    def stop(self) -> None:
        """Interrupt the running steps (SIGINT, as a Ctrl-C would); no step starts after."""
        with self._lock:
            self._closed = True
            busy = list(self._busy)
        for proc in busy:
            if proc.is_alive():
                os.kill(proc.pid, signal.SIGINT)

    def close(self) -> None:
        """End the idle worker processes; a busy one ends when its step returns."""
        self._closed = True
        while True:
            try:
                worker = self._idle.get_nowait()
            except queue.Empty:
                break
            if worker is not None:
                _end_worker(*worker)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _end_worker(proc, conn) -> None:
    try:
        conn.send(None)
    except OSError:
        pass
    proc.join(timeout=10)
    if proc.is_alive():
        proc.terminate()
        proc.join(timeout=5)
    conn.close()


class _Prefixed:
    """A text stream that puts ``prefix`` in front of every line written to ``stream``."""

    def __init__(self, stream, prefix: str):
        self.stream, self.prefix, self.at_start = stream, prefix, True

    def write(self, text: str) -> int:
        if not isinstance(text, str):              # a text stream (click probes with b"")
            raise TypeError(f"write() argument must be str, not {type(text).__name__}")
        out = []
        for line in text.splitlines(keepends=True):
            out.append((self.prefix if self.at_start else "") + line)
            self.at_start = line.endswith("\n")
        self.stream.write("".join(out))
        self.stream.flush()
        return len(text)

    def flush(self) -> None:
        self.stream.flush()

    def isatty(self) -> bool:
        return False

    def __getattr__(self, name):
        return getattr(self.stream, name)


def _worker_main(conn, run, parent: int) -> None:
    """A worker process: run each command line it is sent, send back its exit status,
    until sent ``None``. SIGINT (from ``ProcessInvoker.stop``) interrupts a running step;
    one that arrives between steps makes the next step return 130 without running. If
    the parent process goes, the running step is interrupted."""
    os.setsid()
    run = resolve(run) if isinstance(run, str) else run
    state = {"running": False, "interrupted": False}

    def on_sigint(signum, frame):
        state["interrupted"] = True
        if state["running"]:
            raise KeyboardInterrupt

    signal.signal(signal.SIGINT, on_sigint)

    def watch_parent():
        while os.getppid() == parent:
            time.sleep(1.0)
        os.kill(os.getpid(), signal.SIGINT)

    threading.Thread(target=watch_parent, daemon=True).start()
    out, err = sys.stdout, sys.stderr
    while True:
        try:
            task = conn.recv()
        except (EOFError, OSError):
            return
        if task is None:
            return
        args, prefix = task
        sys.stdout, sys.stderr = _Prefixed(out, prefix), _Prefixed(err, prefix)
        try:
            state["running"] = True                # from here a SIGINT interrupts the step
            if state["interrupted"]:
                raise KeyboardInterrupt
            rc = run(args)
        except KeyboardInterrupt:
            rc = 130
        except BaseException as error:  # noqa: BLE001 - reported, the worker goes on
            if "--debug" in args:
                traceback.print_exc()
            sys.stderr.write(f"msleak: unexpected failure: {type(error).__name__}: {error}\n")
            rc = 1
        finally:
            state["running"] = False
            sys.stdout, sys.stderr = out, err
        try:
            conn.send(rc)
        except OSError:                            # msleak paper itself has gone
            return
