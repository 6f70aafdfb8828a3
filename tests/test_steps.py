"""Resumable steps: a step runs once, reruns when an input or upstream step changes."""

from __future__ import annotations

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
