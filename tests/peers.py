"""Optional peers: the other codes (Python packages and executables) msleak is checked
against. A test that needs one calls :func:`require` or :func:`require_executable`: when
the peer is missing the test is skipped with a one-line reason, unless the environment
variable ``MSLEAK_REQUIRE_PEERS`` is ``1`` (CI installs every peer), in which case it fails.
"""

from __future__ import annotations

import importlib
import os
import shutil
from types import ModuleType
from typing import NoReturn

import pytest

#: environment variable that turns a missing peer from a skip into a failure
REQUIRE_PEERS = "MSLEAK_REQUIRE_PEERS"


def peers_required() -> bool:
    """Whether a missing peer is a failure (``MSLEAK_REQUIRE_PEERS=1``)."""
    return os.environ.get(REQUIRE_PEERS, "").strip() == "1"


def missing(what: str, reason: str) -> NoReturn:
    """Skip (or, with ``MSLEAK_REQUIRE_PEERS=1``, fail) because peer ``what`` is missing.

    Works at module level (during collection) as well as inside a test or fixture.
    """
    __tracebackhide__ = True  # report the caller's line, not this one
    if peers_required():
        pytest.fail(f"{what} is missing but {REQUIRE_PEERS}=1: {reason}", pytrace=False)
    pytest.skip(reason, allow_module_level=True)


def require(module: str, reason: str) -> ModuleType:
    """Import and return ``module`` (a dotted name), or :func:`missing` with ``reason``
    (one line: what the peer is for) when it cannot be imported."""
    __tracebackhide__ = True
    try:
        return importlib.import_module(module)
    except ImportError:
        missing(module, reason)


def require_executable(name: str, reason: str) -> str:
    """The full path of executable ``name`` on PATH, or :func:`missing` with ``reason``."""
    __tracebackhide__ = True
    path = shutil.which(name)
    if path is None:
        missing(name, reason)
    return path
