"""scripts/sensitivity.py's beam variants: each patch reaches the beam that msleak predict
evaluates, so a variant can never silently equal the unpatched run."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ms_helpers import table as _table

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "sensitivity.py"


@pytest.fixture(scope="module")
def sensitivity():
    spec = importlib.util.spec_from_file_location("sensitivity_script", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module                # dataclasses look their module up
    spec.loader.exec_module(module)
    yield module
    del sys.modules[spec.name]


def _predict(tmp_path, ms, column, prelude="", extra=()):
    """The script's predict command into ``column``, patched by ``prelude`` (in its own
    process, as the script runs it); the completed process."""
    from msleak import make_sky

    sky = tmp_path / "sky.fits"
    if not sky.exists():
        make_sky(sky, nchan=4, npix=8, seed=3)
    args = ["-q", "predict", str(ms), "--sky", str(sky), "--column", column, "--double",
            "--double-column", "--no-progress"]
    if prelude:
        return subprocess.run([sys.executable, "-c", prelude, *extra, *args],
                              capture_output=True, text=True)
    return subprocess.run([sys.executable, "-m", "msleak", *args], capture_output=True,
                          text=True)


def test_frozen_and_element_patches_change_the_prediction_as_they_say(
        sensitivity, small_lofar_ms, tmp_path):
    """Frozen at the middle time slot: equal to the real beam in that slot (to 1e-10 of the
    peak), different in the others. Element only: different everywhere. A prelude whose patch msleak never
    calls makes the run fail with the script's message."""
    ms = small_lofar_ms
    for column, prelude, extra in (
            ("BASE", "", ()),
            ("FROZEN", sensitivity.PATCH_FROZEN + sensitivity.RUN_CLI,
             (repr(sensitivity.frozen_time(ms, "frozen")),)),
            ("ELEMENT", sensitivity.PATCH_ELEMENT + sensitivity.RUN_CLI, ())):
        done = _predict(tmp_path, ms, column, prelude, extra)
        assert done.returncode == 0, done.stderr
    with _table(ms) as t:
        base, frozen, element = (t.getcol(c) for c in ("BASE", "FROZEN", "ELEMENT"))
        times = t.getcol("TIME")
    peak = np.abs(base).max()
    assert peak > 0
    mid = times == sensitivity.frozen_time(ms, "frozen")
    assert 0 < mid.sum() < times.size
    # the beam's coordinate map is fitted over a chunk's times: equal to 1e-13, not bitwise
    assert np.abs(frozen[mid] - base[mid]).max() <= 1e-10 * peak
    assert np.abs(frozen[~mid] - base[~mid]).max() > 1e-3 * peak
    assert np.abs(element - base).max() > 0.1 * peak
    unpatched = _predict(tmp_path, ms, "NONE", "import sys\nCALLS = []\n" + sensitivity.RUN_CLI)
    assert unpatched.returncode != 0
    assert "msleak never called the patched beam" in unpatched.stderr
