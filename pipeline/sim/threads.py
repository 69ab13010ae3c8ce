"""The thread pool the simulator's independent work runs in: the solves of petals that
do not interact, the factorizations of the groups of one coupled Newton step, and the
pieces' (petals') forces and Hessians. The numba kernels release the GIL, and each
call's arithmetic is its own, so the results are the same bits with any number of
threads."""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

_POOL = None  #: the thread pool, made at its first use
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
