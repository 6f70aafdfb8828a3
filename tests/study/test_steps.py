"""Resumable steps: a step runs once, reruns when an input or upstream step changes."""

from __future__ import annotations

import json
import os

import pytest

from msleak.errors import MsleakError
from msleak.study import steps
from msleak.study.steps import Step, StepRunner


def _writer(calls):
    def invoke(args):
        calls.append(args)
        out = args[-1]
        with open(out, "a") as fh:
            fh.write("x")

    return invoke


def test_skip_rerun_overwrite(tmp_path):
    src = tmp_path / "in.txt"
    src.write_text("a")
    out = tmp_path / "out.txt"
    step = Step("copy", ["copy", str(out)], inputs=[src], outputs=[out])
    calls = []
    assert StepRunner(tmp_path).run(step, _writer(calls)) is True
    assert StepRunner(tmp_path).run(step, _writer(calls)) is False       # resumed: skipped
    assert len(calls) == 1
    src.write_text("changed input")
    assert StepRunner(tmp_path).run(step, _writer(calls)) is True        # input changed
    assert StepRunner(tmp_path, overwrite=True).run(step, _writer(calls)) is True
    assert len(calls) == 3
    out.unlink()
    assert StepRunner(tmp_path).run(step, _writer(calls)) is True        # output missing


def test_another_msleak_version_reruns(tmp_path, monkeypatch):
    out = tmp_path / "out.txt"
    step = Step("copy", ["copy", str(out)], outputs=[out])
    calls = []
    assert StepRunner(tmp_path).run(step, _writer(calls)) is True
    assert StepRunner(tmp_path).run(step, _writer(calls)) is False
    monkeypatch.setattr(steps, "MSLEAK_VERSION", "0.0.0-other")
    assert StepRunner(tmp_path).run(step, _writer(calls)) is True        # made by another msleak
    assert StepRunner(tmp_path).run(step, _writer(calls)) is False
    assert len(calls) == 2


def test_upstream_step_change_propagates(tmp_path):
    a_out, b_out = tmp_path / "a.txt", tmp_path / "b.txt"
    calls = []
    runner = StepRunner(tmp_path)
    a = Step("a", ["a", "--n", "1", str(a_out)], outputs=[a_out])
    b = Step("b", ["b", str(b_out)], outputs=[b_out], after=["a"])
    runner.run_all([a, b], _writer(calls))
    runner = StepRunner(tmp_path)
    runner.run_all([a, b], _writer(calls))
    assert len(calls) == 2
    a2 = Step("a", ["a", "--n", "2", str(a_out)], outputs=[a_out])   # new parameters
    StepRunner(tmp_path).run_all([a2, b], _writer(calls))
    assert len(calls) == 4                                            # both rerun


def test_missing_output_is_an_error(tmp_path):
    step = Step("none", ["noop", "x"], outputs=[tmp_path / "never"])
    with pytest.raises(MsleakError, match="did not produce"):
        StepRunner(tmp_path).run(step, lambda args: None)


# --- steps at once (workers > 1) ------------------------------------------------------

def test_dependencies_of_the_study_order_the_ms_writers_and_readers(tmp_path):
    """beam and grid read the MS that predict writes: both wait for it, not for each other;
    the two fields' chains and the transforms of one grid are independent."""
    from msleak.study.config import StudyConfig
    from msleak.study.pipeline import study_steps

    deps = steps.dependencies(study_steps(StudyConfig(outdir=tmp_path / "study")))
    assert "predict-ncp" in deps["beam-ncp"] and "predict-ncp" in deps["grid-ncp"]
    assert "grid-ncp" not in deps["beam-ncp"]
    assert deps["predict-ncp"] == {"simulate-ncp", "sky", "sky-crop-9deg", "sky-crop-4deg"}
    assert deps["predict-3c196"] == {"simulate-3c196", "sky", "sky-crop-9deg", "sky-crop-4deg"}
    assert deps["transform-ncp-9deg"] == {"grid-ncp"}
    assert deps["leakage-ncp"] == {f"ps-ncp-{fov}" for fov in ("15deg", "9deg", "4deg")}
    assert not any(name.endswith("ncp") for name in deps["leakage-3c196"] | deps["grid-3c196"])


def test_dependencies_follow_files_and_after(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    s = [Step("write-a", ["w", a], outputs=[a]),
         Step("read-a", ["r", a], inputs=[a], outputs=[b]),
         Step("uses-a", ["u"], reads=[a]),
         Step("rewrite-a", ["w2", a], outputs=[a]),                 # after its readers
         Step("named", ["n"], after=["write-a", "not-in-this-run", "free"]),
         Step("free", ["f"])]
    assert steps.dependencies(s) == {
        "write-a": set(), "read-a": {"write-a"}, "uses-a": {"write-a"},
        "rewrite-a": {"write-a", "read-a", "uses-a"}, "named": {"write-a"}, "free": set()}


class _Recorder:
    """A thread-safe invoke: records start and end of each command; ``block`` names the
    commands that must run at the same time (a barrier that times out otherwise)."""

    def __init__(self, block=(), fail=(), interrupt=(), after_failure=()):
        import threading
        self.lock = threading.Lock()
        self.events = []
        self.block, self.fail, self.interrupt = set(block), set(fail), set(interrupt)
        self.after_failure = set(after_failure)    # end only once a failure was raised
        self.failed = threading.Event()
        self.barrier = threading.Barrier(len(self.block), timeout=20) if block else None
        self.stopped = False

    def __call__(self, args):
        import time

        name = args[0]
        with self.lock:
            self.events.append(("start", name))
        if name in self.block:
            self.barrier.wait()
        if name in self.interrupt:
            raise KeyboardInterrupt
        if name in self.fail:
            self.failed.set()
            raise MsleakError(f"{name} failed")
        if name in self.after_failure:
            assert self.failed.wait(timeout=20)
            time.sleep(0.5)                        # the failure reaches the runner first
        for out in args[1:]:
            with open(out, "a") as fh:
                fh.write(name)
        with self.lock:
            self.events.append(("end", name))

    def stop(self):
        self.stopped = True


def _chain(tmp_path, prefix):
    a, b, c = (tmp_path / f"{prefix}{x}" for x in "abc")
    return [Step(f"{prefix}1", [f"{prefix}1", a], outputs=[a]),
            Step(f"{prefix}2", [f"{prefix}2", b], inputs=[a], outputs=[b]),
            Step(f"{prefix}3", [f"{prefix}3", c], inputs=[b], outputs=[c])]


def test_independent_chains_run_at_once_and_dependents_wait(tmp_path):
    s = _chain(tmp_path, "x") + _chain(tmp_path, "y")
    rec = _Recorder(block=("x2", "y2"))          # deadlocks (BrokenBarrierError) if serial
    log = StepRunner(tmp_path).run_all(s, rec, workers=2)
    assert [entry["name"] for entry in log] == [step.name for step in s]   # in step order
    order = rec.events
    for first, then in (("x1", "x2"), ("x2", "x3"), ("y1", "y2"), ("y2", "y3")):
        assert order.index(("end", first)) < order.index(("start", then))
    state = json.loads((tmp_path / ".msleak-steps.json").read_text())
    assert set(state) == {step.name for step in s}
    calls = []
    StepRunner(tmp_path).run_all(s, _writer(calls), workers=2)    # all up to date
    assert calls == []


def test_a_failure_stops_new_steps_and_a_rerun_resumes(tmp_path):
    s = _chain(tmp_path, "x") + _chain(tmp_path, "y")
    rec = _Recorder(block=("x1", "y1"), fail=("y1",), after_failure=("x1",))
    with pytest.raises(MsleakError, match="y1 failed"):
        StepRunner(tmp_path).run_all(s, rec, workers=2)
    assert ("start", "x2") not in rec.events                      # nothing new after it
    state = json.loads((tmp_path / ".msleak-steps.json").read_text())
    assert set(state) == {"x1"}                                   # the running one recorded
    calls = []
    StepRunner(tmp_path).run_all(s, _writer(calls), workers=2)
    assert sorted(c[0] for c in calls) == ["x2", "x3", "y1", "y2", "y3"]


def test_an_interrupt_stops_the_children_and_keeps_what_finished(tmp_path):
    s = _chain(tmp_path, "x") + _chain(tmp_path, "y")
    rec = _Recorder(interrupt=("x2",))
    with pytest.raises(KeyboardInterrupt):
        StepRunner(tmp_path).run_all(s, rec, workers=2)
    assert rec.stopped
    state = json.loads((tmp_path / ".msleak-steps.json").read_text())
    assert "x1" in state and "x2" not in state and "x3" not in state


def test_a_ctrl_c_handed_to_a_step_thread_stops_the_running_steps_at_once(tmp_path):
    """The kernel gives a process's SIGINT to any of its threads. One given to a thread
    that runs a step must stop the running steps at once (within 5 s here, against the
    30 s the step would last), not when they end."""
    import signal
    import threading
    import time

    released = threading.Event()

    class Invoke:
        stopped_after = None

        def __call__(self, args):
            time.sleep(0.5)                        # the runner is waiting for its steps
            signal.pthread_kill(threading.get_ident(), signal.SIGINT)   # to this thread
            released.wait(timeout=30)              # a long step, until stop() ends it

        def stop(self):
            self.stopped_after = time.monotonic() - t0
            released.set()

    invoke = Invoke()
    out = tmp_path / "a"
    # a shell starts background jobs with SIGINT ignored: Python's handler, as in a
    # terminal, for the length of the test
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        t0 = time.monotonic()
        with pytest.raises(KeyboardInterrupt):
            StepRunner(tmp_path).run_all([Step("a", ["a", out], outputs=[out])], invoke,
                                         workers=2)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert invoke.stopped_after is not None and invoke.stopped_after < 5


def test_process_invoker_runs_msleak_and_prefixes_its_output(tmp_path, capfd):
    out = tmp_path / "sky.fits"
    with steps.ProcessInvoker(["-q"], "paper", workers=1) as invoke:
        invoke(["sky", str(out), "--npix", "8", "--nchan", "4"], label="sky-step")
        assert out.exists()
        with pytest.raises(MsleakError,
                           match=r"failed \(exit 2\).*rerun `msleak paper` to resume"):
            invoke(["sky", str(out), "--npix", "8", "--nchan", "4"], label="again")
        invoke(["sky", str(out), "--npix", "8", "--nchan", "4", "--overwrite"],
               label="third")                      # the same worker goes on after a failure
    err = capfd.readouterr().err
    assert "[again] msleak: error:" in err and "--overwrite" in err


def sleep_step(args):
    """A worker's step that signals it started, then sleeps (for the stop test)."""
    import pathlib
    import time

    pathlib.Path(args[0]).touch()
    time.sleep(60)
    return 0


def test_process_invoker_stop_interrupts_a_running_step(tmp_path):
    import threading
    import time

    flag = tmp_path / "started"
    errors = []
    with steps.ProcessInvoker([], "paper", workers=1, run=sleep_step) as invoke:
        def run():
            try:
                invoke([str(flag)], label="sleeper")
            except MsleakError as err:
                errors.append(err)

        thread = threading.Thread(target=run)
        thread.start()
        for _ in range(600):
            if flag.exists():
                break
            time.sleep(0.05)
        assert flag.exists()
        t0 = time.monotonic()
        invoke.stop()
        thread.join(timeout=30)
        assert not thread.is_alive() and time.monotonic() - t0 < 10
    assert len(errors) == 1 and "(exit 130)" in str(errors[0])


def die_step(args):
    """A worker's step whose process is killed (as the out-of-memory killer would)."""
    import signal

    os.kill(os.getpid(), signal.SIGKILL)


def test_a_dead_worker_is_reported_and_replaced(tmp_path):
    with steps.ProcessInvoker([], "paper", workers=1, run=die_step) as invoke:
        with pytest.raises(MsleakError, match=r"worker process ended \(killed by signal 9; "
                                              r"out of memory\?\); rerun `msleak paper`"):
            invoke(["first"], label="first")
        invoke.run = ok_step                       # a new worker takes the slot
        invoke([str(tmp_path / "made")], label="second")
    assert (tmp_path / "made").exists()


def ok_step(args):
    """A worker's step that makes the file it is given."""
    import pathlib

    pathlib.Path(args[0]).touch()
    return 0
