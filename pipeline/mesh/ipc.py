"""ipctk (the contact library: exact crossing tests, distances, the barrier) on one
thread: :func:`ipctk`.

Its broad phase finds candidates in threads, in an order the scheduling decides, and
where several candidates give the same contact (a vertex nearest an edge that two faces
share) which one is kept follows that order: the rose bed's separation differed by 1e-14
from one run to the next. On one thread every list is the same every run."""

from __future__ import annotations

_SET = False  #: whether ipctk has been put on one thread


def ipctk():
    """The ipctk module, on one thread (set at the first call only: the call is not free)."""
    global _SET
    import ipctk as module

    if not _SET:
        module.set_num_threads(1)
        _SET = True
    return module
