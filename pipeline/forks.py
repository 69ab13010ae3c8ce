"""A pool of forked worker processes (:func:`pool`): petals remeshed side by side, a
file's flowers bloomed side by side. Forked, not spawned: a spawned worker imports the
command again (``python -m stages`` would run it again in the worker) and pays the
imports (seconds). A worker dies with the process that forked it: a run killed outright
(SIGKILL, a farm's time limit) leaves no worker behind holding its output pipes."""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal

_PARENT: int | None = None  #: the pid of the process whose pool a worker is in
#: a pool is started for at least this many tasks (fewer run in this process)
MANY = 8


def workers(setting: int) -> int:
    """How many processes a pool gets: ``setting`` (``remesh.workers``,
    ``simulate.workers``) if positive, else the CPUs this process may run on, at most 4."""
    if setting > 0:
        return int(setting)
    try:
        return max(1, min(4, len(os.sched_getaffinity(0))))
    except AttributeError:  # not Linux
        return max(1, min(4, os.cpu_count() or 1))


def can_fork() -> bool:
    """Whether this system starts processes by forking (Linux, not Windows)."""
    return "fork" in multiprocessing.get_all_start_methods()


def _die_with_parent(initializer) -> None:
    # a signal to stop (a farm's SIGTERM to the job's processes, Ctrl-C to the terminal's)
    # ends a worker at once: the parent's handler, inherited at the fork, would turn it
    # into an exception the pool hands back as a task's result, and the worker would go
    # on to its next task
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    try:  # Linux: the kernel kills the worker when its parent goes (prctl PR_SET_PDEATHSIG)
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))
    except (OSError, AttributeError):  # elsewhere, a worker outlives a killed parent
        pass
    if os.getppid() != _PARENT:  # the parent went before the prctl above
        os._exit(1)
    if initializer is not None:
        initializer()


@contextlib.contextmanager
def pool(workers: int, initializer=None):
    """A :class:`~concurrent.futures.ProcessPoolExecutor` of ``workers`` forked
    processes that die with this one, each started by ``initializer()`` if given, for a
    ``with`` block. Left by an exception (a SIGTERM or Ctrl-C in this process, an error),
    the tasks not started are cancelled and the workers killed, not waited for: a killed
    ``bloom simulate`` of a bed of roses went on blooming its flowers for 20 minutes."""
    from concurrent.futures import ProcessPoolExecutor

    global _PARENT
    _PARENT = os.getpid()
    executor = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork"),
                                   initializer=_die_with_parent, initargs=(initializer,))
    try:
        yield executor
    except BaseException:
        executor.shutdown(wait=False, cancel_futures=True)
        for child in multiprocessing.active_children():
            child.kill()
        raise
    executor.shutdown(wait=True)


def each(fn, count: int, workers: int):
    """``fn(k)`` for ``k`` in ``range(count)``, yielded in order: in this process, or
    (``workers`` > 1, at least :data:`MANY` tasks, a system that forks) in a pool of
    forked processes. ``fn`` (a module's function) reads task ``k`` from what the
    processes share at the fork (a module global set before this is called), so the
    tasks are not sent; each result depends on its task alone, the same bits either way."""
    if workers <= 1 or count < MANY or not can_fork():
        for k in range(count):
            yield fn(k)
        return
    with pool(min(workers, count)) as workers_:
        yield from workers_.map(fn, range(count), chunksize=max(1, count // (32 * workers)))
