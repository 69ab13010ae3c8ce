"""Growth, prescribed in time: the schedule A(t) (Eq. 6: rest lengths ``L0 (1 + A alpha)``)
and the curl (Eq. 11: rest dihedral angles ``theta0 (1 - B beta)``, B = A), compiled.
The growth ratios alpha themselves are a property of the model (``bloom growth``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
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


@njit(cache=True)
def curl_rest_angles(theta0, factor, cos_t, sin_t):
    """Rest angles of the curl effect (Eq. 11): ``theta0 (1 - B beta)``, as cos and sin.
    ``factor`` is ``B(t) beta``."""
    keep = 1.0 - factor
    for k in range(theta0.shape[0]):
        a = keep * theta0[k]
        cos_t[k] = math.cos(a)
        sin_t[k] = math.sin(a)


@dataclass
class Curl:
    theta0: np.ndarray  #: (H,) rest dihedral angle at t = 0
    beta: float
    cos_t: np.ndarray  #: (H,) work arrays: cos and sin of the rest angle at the current step
    sin_t: np.ndarray

    @classmethod
    def build(cls, rest_angle: np.ndarray, beta: float) -> Curl:
        theta0 = np.ascontiguousarray(rest_angle, dtype=np.float64)
        return cls(theta0, float(beta), np.cos(theta0), np.sin(theta0))
