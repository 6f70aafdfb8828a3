"""Resumable steps for multi-stage runs (``msleak paper``; docs/paper.md "Resuming").

A step is one msleak command line with declared inputs and outputs. It is skipped when
its outputs exist and the fingerprint of its command, its inputs (size and modification
time of every file), the earlier steps it names in ``after`` and the msleak version
equals the one recorded in ``OUTDIR/.msleak-steps.json`` when the outputs were made.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shlex
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from msleak import __version__ as MSLEAK_VERSION
from msleak.errors import MsleakError

__all__ = ["Step", "StepRunner"]

log = logging.getLogger(__name__)


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

    @property
    def command(self) -> str:
        return "msleak " + " ".join(shlex.quote(str(a)) for a in self.args)


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
    """Run :class:`Step` objects in order, skipping those whose inputs are unchanged."""

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

    def fingerprint(self, step: Step) -> str:
        upstream = [self.state.get(name, {}).get("fingerprint", "never-run")
                     for name in step.after]
        blob = json.dumps([step.args, [_fingerprint_path(p) for p in step.inputs], upstream,
                           MSLEAK_VERSION], default=str)
        return hashlib.sha256(blob.encode()).hexdigest()

    def run(self, step: Step, invoke) -> bool:
        """Run ``step`` with ``invoke(args)`` unless it is up to date; True if it ran."""
        digest = self.fingerprint(step)
        record = self.state.get(step.name)
        done = (record is not None and record.get("fingerprint") == digest
                and all(Path(p).exists() for p in step.outputs))
        if done and not self.overwrite:
            log.info("skip %s (up to date)", step.name)
            self.log.append({"name": step.name, "command": step.command, "skipped": True,
                             "seconds": record.get("seconds", 0.0)})
            return False
        log.info("run  %s: %s", step.name, step.command)
        t0 = time.perf_counter()
        invoke(list(map(str, step.args)))
        seconds = time.perf_counter() - t0
        missing = [str(p) for p in step.outputs if not Path(p).exists()]
        if missing:
            raise MsleakError(f"step {step.name} did not produce {', '.join(missing)}")
        self.state[step.name] = {"fingerprint": self.fingerprint(step), "seconds": seconds,
                                 "command": step.command,
                                 "finished": time.strftime("%Y-%m-%dT%H:%M:%S")}
        self.outdir.mkdir(parents=True, exist_ok=True)
        tmp = self.state_file.with_suffix(".tmp")
        tmp.write_text(json.dumps(self.state, indent=1))
        os.replace(tmp, self.state_file)
        self.log.append({"name": step.name, "command": step.command, "skipped": False,
                         "seconds": seconds})
        return True

    def run_all(self, steps: Sequence[Step], invoke) -> list[dict]:
        for step in steps:
            self.run(step, invoke)
        return self.log
