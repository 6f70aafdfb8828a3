"""Shared fixtures: tiny Measurement Sets built once per session, a fresh copy per test."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")

SMALL_MS_PARAMS = dict(field="3c196", duration=4 * 120 / 3600, interval=120.0,
                       freq_min=150e6, nchan=4, chan_width=195312.5,
                       stations="CS00[1-3]HBA*")


def _build(path: Path, **params) -> Path:
    from msleak.telescope.simulate import simulate

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
