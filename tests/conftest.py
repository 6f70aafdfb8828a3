"""Shared fixtures: tiny Measurement Sets built once per session, a fresh copy per test.

Tests download nothing, whatever the date: astropy's IERS auto-download is switched off
for the whole session, in this process and in every process a test starts (``msleak``
subprocesses) through an astropy configuration file in a session directory.

The test files are in one folder per package or stage of msleak (beam/, predict/, ps/, ...,
and cli/, peers/, safety/, package/ for the command line, the independent tools, data
safety and the whole package). The helper modules next to this file (ms_helpers.py,
casa_ms.py, faults.py, peer_sim.py, peers.py) are imported by name from every folder: pytest
puts this folder on sys.path when it imports this file.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from pathlib import Path

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")
# scripts/dp3run.py runs DP3 for the tests as for scripts/bench and scripts/crosscheck
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

#: astropy.cfg of the session: the bundled IERS and leap-second tables only (they expire;
#: once they have, astropy would otherwise try to download new ones)
ASTROPY_CFG = "[utils.iers.iers]\nauto_download = False\n"
_SESSION_ENV = ("XDG_CONFIG_HOME", "ASTROPY_CONFIG_DIR")
_CONFIG_HOME = pytest.StashKey[tuple]()


def pytest_configure(config):
    """Before collection: no IERS download here (``iers.conf``) nor in subprocesses, which
    read ``XDG_CONFIG_HOME/astropy/astropy.cfg`` (every astropy version msleak supports)
    or ``ASTROPY_CONFIG_DIR`` (astropy 8+; it would take precedence if a user had set it)."""
    from astropy.utils import iers

    config_home = tempfile.TemporaryDirectory(prefix="msleak-tests-config-")
    astropy_dir = Path(config_home.name) / "astropy"
    astropy_dir.mkdir()
    (astropy_dir / "astropy.cfg").write_text(ASTROPY_CFG)
    config.stash[_CONFIG_HOME] = (config_home, {k: os.environ.get(k) for k in _SESSION_ENV})
    os.environ["XDG_CONFIG_HOME"] = config_home.name
    os.environ["ASTROPY_CONFIG_DIR"] = str(astropy_dir)
    iers.conf.auto_download = False


def pytest_unconfigure(config):
    """Restore the environment and remove the session's configuration directory."""
    config_home, saved = config.stash.get(_CONFIG_HOME, (None, {}))
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value
    if config_home is not None:
        config_home.cleanup()


#: the test files that run longest (whole studies, killed and resumed runs, the CLI fuzz,
#: peers' chains: 14-90 s each on 2 cores), longest first, by file name (the name of a test
#: file is unique across the folders of tests/)
LONG_FILES = ("test_paper.py", "test_safety_kill.py", "test_forecast.py", "test_fuzz_cli.py",
              "test_cli_contract.py", "test_paper_resolution.py", "test_crosscheck.py",
              "test_docs_api.py", "test_parallel_local.py", "test_grid_memory.py",
              "test_predict_multisky.py", "test_parallel_cluster.py", "test_beam_basis.py")


def pytest_collection_modifyitems(config, items):
    """In pytest-xdist workers (scripts/test: ``--dist loadfile --no-loadscope-reorder``):
    the files of :data:`LONG_FILES` first, in that order, then the others as collected (the
    tests of a file keep their order). The workers take whole files in this order, so the
    short files fill in at the end and both finish at about the same time. Every worker
    collects the same order, as xdist requires."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return
    rank = {name: k for k, name in enumerate(LONG_FILES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


SMALL_MS_PARAMS = dict(field="3c196", duration=4 * 120 / 3600, interval=120.0,
                       freq_min=150e6, nchan=4, chan_width=195312.5,
                       stations="CS00[1-3]HBA*")


def _build(path: Path, **params) -> Path:
    from msleak.verbs.simulate import simulate

    return simulate(path, **params)


@pytest.fixture(scope="session")
def _small_lofar_ms_master(tmp_path_factory) -> Path:
    return _build(tmp_path_factory.mktemp("ms") / "small.ms", **SMALL_MS_PARAMS)


@pytest.fixture
def small_lofar_ms(_small_lofar_ms_master, tmp_path) -> Path:
    """A fresh copy of a tiny LOFAR MS: CS001-CS003 HBA0/HBA1 (6 antennas, 15 baselines),
    3C196 field, 4 x 120 s, 4 channels from 150 MHz, DATA zero, LOFAR beam tables."""
    dest = tmp_path / "small.ms"
    shutil.copytree(_small_lofar_ms_master, dest)
    return dest


@pytest.fixture
def make_ms(tmp_path):
    """Build an MS with ``simulate`` keyword arguments: ``make_ms(name="x.ms", **params)``."""

    def factory(name: str = "test.ms", **params) -> Path:
        merged = {**SMALL_MS_PARAMS, **params}
        return _build(tmp_path / name, **merged)

    return factory
