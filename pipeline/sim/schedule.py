"""The growth schedule A(t) (Eq. 6), compiled: the ramp shapes and a keyed table."""

from __future__ import annotations

from numba import njit

SCHEDULE_LINEAR = 0
SCHEDULE_SMOOTHSTEP = 1
SCHEDULE_SMOOTHERSTEP = 2
SCHEDULE_TABLE = 3  #: A given at evenly spaced times (a keyed schedule, see model.Control)
SCHEDULE_CODES = {"linear": SCHEDULE_LINEAR, "smoothstep": SCHEDULE_SMOOTHSTEP,
                  "smootherstep": SCHEDULE_SMOOTHERSTEP, "table": SCHEDULE_TABLE}


@njit(cache=True)
def schedule_value(kind, t, ramp_time):
    """A(t): rises from 0 at t = 0 to 1 at t = ramp_time, then holds at 1."""
    if ramp_time <= 0.0:
        return 1.0
    u = t / ramp_time
    if u <= 0.0:
        return 0.0
    if u >= 1.0:
        return 1.0
    if kind == SCHEDULE_LINEAR:
        return u
    if kind == SCHEDULE_SMOOTHSTEP:
        return u * u * (3.0 - 2.0 * u)
    return u * u * u * (u * (6.0 * u - 15.0) + 10.0)


@njit(cache=True)
def growth_value(kind, t, ramp_time, table):
    """A(t) of :func:`schedule_value`, or for ``kind == SCHEDULE_TABLE`` read from
    ``table``: A at ``len(table)`` evenly spaced times from 0 to ``ramp_time``, linear
    in between, held at the ends."""
    if kind != SCHEDULE_TABLE:
        return schedule_value(kind, t, ramp_time)
    n = len(table) - 1
    if n <= 0 or t <= 0.0:
        return table[0]
    u = t / ramp_time * n
    if u >= n:
        return table[n]
    k = int(u)
    f = u - k
    return table[k] if f == 0.0 else table[k] + f * (table[k + 1] - table[k])
