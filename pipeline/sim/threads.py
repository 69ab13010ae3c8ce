"""The thread pool the simulator's independent work runs in: the solves of petals that
do not interact, the factorizations of the groups of one coupled Newton step, and the
pieces' (petals') forces and Hessians. The numba kernels release the GIL, and each
call's arithmetic is its own, so the results are the same bits with any number of
threads.

The solver's dot products of whole-mesh vectors are :func:`dot`'s, not numpy's: numpy's
``a @ b`` is OpenBLAS's ``ddot``, which splits a vector of 10,000 entries or more (a
mesh of 3,334 vertices) among as many threads as the machine has cores, so its bits
depend on the machine, and its threads spin for a while after each call, taking the
core that this pool's work needs (the lily's 3,897 vertices: 64 s of CPU for 35 s of
wall time, 38 s with one BLAS thread). Where the other core is busy, each call also
waits for it: 4.8 ms a call against 0.01 ms on one thread, measured under load."""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit

_POOL = None  #: the thread pool, made at its first use


def _forgotten() -> None:
    """In a forked child the parent's pool has no threads: a new one at the next use."""
    global _POOL
    _POOL = None


os.register_at_fork(after_in_child=_forgotten)
#: whether this thread is running a call of :func:`parallel_map` (a cluster of petals
#: solved in a pool thread maps its groups inline: waiting on the pool from the pool can
#: deadlock it)
_WORKER = threading.local()


def parallel_map(fn, items: list) -> list:
    """``[fn(x) for x in items]``, the calls overlapping in threads. For work apart
    whose heavy parts, the numba kernels (the factorization's too), release the GIL.
    Each call's arithmetic is its own, so the results are the same to the bit with any
    number of threads, and they come back in order (an exception: the first item's that
    raised). A call made from a pool thread (a cluster of petals' solver, mapping its
    groups) runs inline."""
    global _POOL
    if len(items) < 2 or getattr(_WORKER, "busy", False):
        return [fn(x) for x in items]
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=max(1, min(4, os.cpu_count() or 1)))

    def run(x):
        _WORKER.busy = True
        try:
            return fn(x)
        finally:
            _WORKER.busy = False

    return list(_POOL.map(run, items))


@njit(cache=True, nogil=True)
def dot(a: np.ndarray, b: np.ndarray) -> float:
    """``a . b`` of two vectors, summed in order on this thread: the same bits on any
    machine (numpy's ``a @ b`` runs in BLAS threads for long vectors: see the module
    docstring)."""
    total = 0.0
    for i in range(a.shape[0]):
        total += a[i] * b[i]
    return total
