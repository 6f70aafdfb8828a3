"""docs/api.md's Python blocks run, in order, in one namespace; then the objects they made
are checked against the command line on the same inputs."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

DOC = Path(__file__).resolve().parents[2] / "docs" / "api.md"


def _blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", DOC.read_text(), flags=re.S)


@pytest.fixture(scope="module")
def walked(tmp_path_factory):
    """The namespace after every block of docs/api.md ran in a fresh directory."""
    import os

    work = tmp_path_factory.mktemp("api")
    here = os.getcwd()
    os.chdir(work)
    try:
        namespace: dict = {}
        for block in _blocks():
            exec(compile(block, str(DOC), "exec"), namespace)  # noqa: S102 - our own docs
    finally:
        os.chdir(here)
    return work, namespace


def test_the_page_has_the_whole_study():
    code = "\n".join(_blocks())
    for verb in ("simulate", "make_sky", "predict", "grid", "transform", "power_spectrum",
                 "leakage", "beam_maps"):
        assert f"msleak.{verb}(" in code


def test_the_walk_matches_the_command_line(walked):
    """The 15-deg power spectrum from the verbs equals the CLI chain on the same column."""
    work, ns = walked
    msleak = [sys.executable, "-m", "msleak", "-q"]
    col = ns["columns"]["15deg"]
    for cmd in (["grid", "ncp.ms", "--column", col, "-o", "g.h5"],
                ["transform", "g.h5", "-o", "d.h5"], ["ps", "d.h5", "-o", "p.h5"]):
        proc = subprocess.run([*msleak, *cmd], cwd=work, capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
    with xr.open_dataset(work / "p.h5", engine="h5netcdf") as cli:
        # the one-pass grid of three columns and the threaded scheduler sum the chunks in
        # another order than one column alone: equal to float64 rounding
        np.testing.assert_allclose(cli["power"].values, ns["ps"]["power"].values, rtol=1e-12)


def test_the_column_none_array_is_what_predict_writes(walked):
    from casacore.tables import table

    work, ns = walked
    with table(str(work / "ncp.ms"), ack=False) as t:
        written = t.getcol(ns["columns"]["4deg"])
    # the column came from the three-sky pass, whose beam is fitted on the union of the
    # skies' directions: equal to a one-sky run to complex64 rounding (docs/predict.md)
    vis = np.asarray(ns["vis"])
    assert np.abs(vis - written).max() <= 1e-6 * np.abs(written).max()


def test_leakage_of_the_three_fields_of_view(walked):
    _, ns = walked
    result = ns["result"]
    assert result["L_I"].sizes[result["L_I"].dims[0]] == 3
    values = result["L_I"].values
    assert np.isfinite(values).any() and (values[np.isfinite(values)] >= 0).all()


def test_the_history_runs_from_the_ms_to_the_spectrum(walked):
    _, ns = walked
    lines = ns["ps"].attrs["history"].splitlines()
    joined = "\n".join(lines)
    order = [joined.find(s) for s in ("simulated", "msleak.predict(", "msleak.grid(",
                                      "msleak.transform(", "msleak.power_spectrum(")]
    assert all(i >= 0 for i in order) and order == sorted(order), lines
