"""Run a block with single-threaded OpenBLAS (numpy's and scipy's bundled copies).

The fits make thousands of small BLAS/LAPACK calls. On a busy 2-core machine
OpenBLAS worker threads busy-wait for a core, which made a 4x4, 2000-line,
order-24 fit take 8x the CPU time of the single-threaded run. The number of
threads is restored on exit. Where the libraries or their thread setters
cannot be found (another BLAS, another OS), this does nothing.
"""

from __future__ import annotations

import ctypes
import functools
from collections.abc import Iterator
from contextlib import contextmanager

_SETTERS = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads",
            "openblas_set_num_threads64_", "openblas_set_num_threads")
_GETTERS = ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads",
            "openblas_get_num_threads64_", "openblas_get_num_threads")


@functools.lru_cache(maxsize=1)
def _openblas() -> tuple[tuple[object, object], ...]:
    # numpy and scipy are imported by now, so their OpenBLAS copies are mapped
    try:
        with open("/proc/self/maps", encoding="utf-8") as fh:
            paths = sorted({line.split()[-1] for line in fh
                            if "openblas" in line.lower() and ".so" in line})
    except OSError:
        return ()
    found = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        setter = next((getattr(lib, n) for n in _SETTERS if hasattr(lib, n)), None)
        getter = next((getattr(lib, n) for n in _GETTERS if hasattr(lib, n)), None)
        if setter is not None and getter is not None:
            getter.restype = ctypes.c_int
            found.append((setter, getter))
    return tuple(found)


@contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Context manager: OpenBLAS uses one thread inside the block."""
    libs = _openblas()
    old = [int(get()) for _, get in libs]
    for set_, _ in libs:
        set_(1)
    try:
        yield
    finally:
        for (set_, _), n in zip(libs, old):
            set_(max(n, 1))
