"""Limiting BLAS threads while the precompute runs.

The precompute runs the modal analysis in a second thread beside the
subspace and clusters, and both call BLAS. OpenBLAS (numpy's and scipy's
wheels each carry one) starts a thread per core for every caller, so two
callers on two cores run four busy threads, which spin while they wait:
identical runs then took from 0.45 s to 4.4 s on a 225-vertex scene, worst
when anything else loads the machine. One BLAS thread per caller keeps the
two cores to the two threads of work (``benchmarks/bench_blas_threads.py``
measures it; ``docs/performance.md`` has the numbers).

With ``threadpoolctl`` installed (the ``fast`` extra) every BLAS and OpenMP
library it knows is limited; without it, the OpenBLAS libraries loaded in
the process are found (Linux: ``/proc/self/maps``) and limited through
their own ``openblas_set_num_threads``; elsewhere nothing is changed.
"""

from __future__ import annotations

import ctypes
import os
from contextlib import contextmanager

from .values import is_whole

__all__ = ["limited_blas_threads", "openblas_threads", "checked_thread_count"]

# OpenBLAS's own entry point, under the names its builds export it
# (scipy-openblas wheels add a prefix and, for 64-bit integers, a suffix)
_SETTERS = (
    "openblas_set_num_threads",
    "openblas_set_num_threads64_",
    "scipy_openblas_set_num_threads",
    "scipy_openblas_set_num_threads64_",
)


_MOST_THREADS = 2**31 - 1


def checked_thread_count(limit, name: str = "blas_threads") -> int | None:
    """A BLAS thread count: None (leave the libraries as they are) or a whole number >= 1; else a ValueError naming it.

    Parameters
    ----------
    limit : int or None
        The count to check: None, or a Python or numpy integer (not a bool).
    name : str
        The argument's name, for the error message.

    Returns
    -------
    limit : int or None
        ``limit`` as a Python int (None stays None).

    Raises
    ------
    ValueError
        ``limit`` is neither None nor a whole number >= 1.

    Examples
    --------
    >>> checked_thread_count(0)
    Traceback (most recent call last):
    ...
    ValueError: blas_threads must be None or a whole number of threads from 1 to 2147483647, got 0
    """
    if limit is None:
        return None
    # (at most 2^31 - 1: BLAS libraries take a C int, and 10**400 failed deep in ctypes)
    if not is_whole(limit) or not 1 <= limit <= _MOST_THREADS:
        raise ValueError(f"{name} must be None or a whole number of threads from 1 to {_MOST_THREADS}, got {limit!r}")
    return int(limit)


@contextmanager
def limited_blas_threads(limit: int | None = 1):
    """Run the block with at most ``limit`` threads in each BLAS library.

    Parameters
    ----------
    limit : int or None
        Threads per BLAS call; ``None`` changes nothing.

    Examples
    --------
    >>> import numpy as np
    >>> with limited_blas_threads(1):
    ...     _ = np.ones((200, 200)) @ np.ones((200, 200))
    """
    limit = checked_thread_count(limit, "limit")  # (threadpoolctl takes no numpy integer)
    if limit is None:
        yield
        return
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        libraries = _loaded_openblas()
        before = [lib.get() for lib in libraries]
        for lib in libraries:
            lib.set(limit)
        try:
            yield
        finally:
            for lib, count in zip(libraries, before):
                lib.set(count)
        return
    with threadpool_limits(limits=limit):
        yield


def openblas_threads() -> list[int]:
    """The thread count of each OpenBLAS library loaded in this process (Linux; else empty)."""
    return [lib.get() for lib in _loaded_openblas()]


class _OpenBLAS:
    def __init__(self, handle, setter: str):
        self._set = getattr(handle, setter)
        self._get = getattr(handle, setter.replace("set_num_threads", "get_num_threads"))
        self._set.argtypes, self._set.restype = [ctypes.c_int], None
        self._get.argtypes, self._get.restype = [], ctypes.c_int

    def get(self) -> int:
        return int(self._get())

    def set(self, count: int) -> None:
        self._set(int(count))


def _loaded_openblas() -> list[_OpenBLAS]:
    """The OpenBLAS libraries this process has loaded, each with its thread setter."""
    try:
        with open("/proc/self/maps") as maps:
            paths = {line.split()[-1] for line in maps if "openblas" in line.lower() and ".so" in line}
    except OSError:
        return []
    found = []
    for path in sorted(paths):
        try:
            handle = ctypes.CDLL(path, mode=os.RTLD_NOLOAD | os.RTLD_LOCAL)
        except OSError:
            continue
        setter = next((name for name in _SETTERS if hasattr(handle, name)), None)
        if setter is not None:
            found.append(_OpenBLAS(handle, setter))
    return found
