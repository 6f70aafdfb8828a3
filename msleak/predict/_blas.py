"""Hermitian rank-k updates (BLAS ``cherk``/``zherk``) callable from numba kernels.

The predict kernel runs one small ``herk`` per (time, channel) inside a numba ``prange``
loop, so each core runs its own single-threaded BLAS call. Two details make that work:

* SciPy exports its BLAS through ``scipy.linalg.cython_blas``; the function addresses are
  registered with LLVM under fixed symbol names (:func:`llvmlite.binding.add_symbol`), so
  numba can cache the compiled kernels on disk (the address is resolved at load time).
* OpenBLAS would otherwise start its own threads inside every call and oversubscribe the
  cores; :func:`single_threaded_blas` pins it to one thread for the duration of a block.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
from typing import Iterator

__all__ = ["HERK_SYMBOLS", "register_herk", "single_threaded_blas"]

log = logging.getLogger(__name__)

#: LLVM symbol names under which the SciPy BLAS routines are registered.
HERK_SYMBOLS = {"c": "msleak_cherk", "z": "msleak_zherk"}

_registered = False


def register_herk() -> None:
    """Register SciPy's ``cherk`` and ``zherk`` with LLVM (idempotent)."""
    global _registered
    if _registered:
        return
    import llvmlite.binding as ll
    from numba.extending import get_cython_function_address

    for prefix, symbol in HERK_SYMBOLS.items():
        address = get_cython_function_address("scipy.linalg.cython_blas", f"{prefix}herk")
        ll.add_symbol(symbol, address)
    _registered = True


def _openblas_handles() -> list[tuple[ctypes.CDLL, str, str]]:
    """(library, setter, getter) for every OpenBLAS loaded in this process."""
    names = set()
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as maps:
            for line in maps:
                path = line.rstrip("\n").split(" ")[-1]
                if "openblas" in os.path.basename(path).lower() and path.startswith("/"):
                    names.add(path)
    except OSError:  # not Linux
        return []
    handles = []
    pairs = [("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
             ("scipy_openblas_set_num_threads", "scipy_openblas_get_num_threads"),
             ("openblas_set_num_threads64_", "openblas_get_num_threads64_"),
             ("openblas_set_num_threads", "openblas_get_num_threads")]
    for path in sorted(names):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for setter, getter in pairs:
            if hasattr(lib, setter) and hasattr(lib, getter):
                handles.append((lib, setter, getter))
                break
    return handles


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Limit BLAS to one thread per call inside the block (restored afterwards).

    Uses threadpoolctl when it is installed, else the OpenBLAS libraries loaded in the
    process (NumPy's and SciPy's wheels each bundle one). Without either, BLAS keeps its
    own threading (correct, possibly slower).
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        threadpool_limits = None
    if threadpool_limits is not None:
        with threadpool_limits(limits=1, user_api="blas"):
            yield
        return
    saved = []
    for lib, setter, getter in _openblas_handles():
        try:
            before = int(getattr(lib, getter)())
            getattr(lib, setter)(1)
            saved.append((lib, setter, before))
        except Exception:  # noqa: BLE001 - best effort, never fatal
            log.debug("could not limit threads of %s", lib)
    try:
        yield
    finally:
        for lib, setter, before in saved:
            getattr(lib, setter)(max(before, 1))
