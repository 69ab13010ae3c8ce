"""Compiled force and integration kernels (numba, cached to disk).

These loops are the product: they run hundreds of thousands of times per bloom. They
work on plain contiguous arrays, write into arrays the caller owns and allocate nothing.
Accumulation order is fixed (serial loops, no fastmath), so results are bit-reproducible.

Conventions
-----------
- ``X, V, F``: ``(V, 3) float64`` positions, velocities, forces.
- ``edges``: ``(E, 2) int64``; rest length of edge e at time t is
  ``rest0[e] * (1 + A(t) * growth[e])`` (Eq. 6).
- ``hinges``: ``(H, 4) int64`` rows ``(i, j, k, l)``: edge ``i-j``, ``k`` opposite in the
  face ``i -> j -> k``, ``l`` opposite in the face ``j -> i -> l``. The signed dihedral
  angle is ``theta = atan2((n1 x n2) . e_hat, n1 . n2)`` with ``n1 = e x (x_k - x_i)``,
  ``n2 = (x_l - x_j) x e``, ``e = x_j - x_i``; 0 when flat.
- Bending energy ``K_b (1 - cos(theta - theta0))`` (Eq. 3) is evaluated without trig:
  ``cos(theta - theta0) = cos theta cos theta0 + sin theta sin theta0``, with the rest
  angle's cosine and sine cached.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

SCHEDULE_LINEAR = 0
SCHEDULE_SMOOTHSTEP = 1
SCHEDULE_SMOOTHERSTEP = 2
SCHEDULE_CODES = {"linear": SCHEDULE_LINEAR, "smoothstep": SCHEDULE_SMOOTHSTEP,
                  "smootherstep": SCHEDULE_SMOOTHERSTEP}


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


@njit(cache=True, inline="always")
def _edge_vector(X, i, j):
    """``x_j - x_i`` and its length: one place, so that rest lengths measured by
    :func:`edge_lengths` and lengths in :func:`stretch_forces` agree to the bit."""
    dx = X[j, 0] - X[i, 0]
    dy = X[j, 1] - X[i, 1]
    dz = X[j, 2] - X[i, 2]
    return dx, dy, dz, math.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True)
def stretch_forces(X, edges, rest0, growth, stiffness, A, F):
    """Add the stretch forces of every edge to ``F``; return the stretch energy (Eq. 2)."""
    energy = 0.0
    for e in range(edges.shape[0]):
        i = edges[e, 0]
        j = edges[e, 1]
        dx, dy, dz, length = _edge_vector(X, i, j)
        rest = rest0[e] * (1.0 + A * growth[e])
        stretch = length - rest
        tension = stiffness[e] * stretch
        energy += 0.5 * tension * stretch
        if length > 0.0:
            c = tension / length
            F[i, 0] += c * dx
            F[i, 1] += c * dy
            F[i, 2] += c * dz
            F[j, 0] -= c * dx
            F[j, 1] -= c * dy
            F[j, 2] -= c * dz
    return energy


@njit(cache=True, inline="always")
def _hinge_vectors(X, i, j, k, l):
    """Edge ``e = x_j - x_i`` and the face normals ``n1 = e x (x_k - x_i)``,
    ``n2 = (x_l - x_j) x e`` of one hinge; also ``a = x_k - x_i`` and ``b = x_l - x_j``."""
    ex = X[j, 0] - X[i, 0]
    ey = X[j, 1] - X[i, 1]
    ez = X[j, 2] - X[i, 2]
    ax = X[k, 0] - X[i, 0]
    ay = X[k, 1] - X[i, 1]
    az = X[k, 2] - X[i, 2]
    bx = X[l, 0] - X[j, 0]
    by = X[l, 1] - X[j, 1]
    bz = X[l, 2] - X[j, 2]
    n1x = ey * az - ez * ay
    n1y = ez * ax - ex * az
    n1z = ex * ay - ey * ax
    n2x = by * ez - bz * ey
    n2y = bz * ex - bx * ez
    n2z = bx * ey - by * ex
    return ex, ey, ez, ax, ay, az, bx, by, bz, n1x, n1y, n1z, n2x, n2y, n2z


@njit(cache=True)
def bending_forces(X, hinges, cos0, sin0, stiffness, F):
    """Add the bending forces of every hinge to ``F``; return the bending energy (Eq. 3).

    The gradient of theta is the discrete-shells one: the opposite vertices move along
    their face normals, ``d theta / d x_k = -|e| n1 / |n1|^2`` and likewise for ``l``; the
    edge vertices take the balancing parts by the projections of ``k`` and ``l`` onto
    the edge, so that the forces sum to zero.
    """
    energy = 0.0
    for h in range(hinges.shape[0]):
        i = hinges[h, 0]
        j = hinges[h, 1]
        k = hinges[h, 2]
        l = hinges[h, 3]
        (ex, ey, ez, ax, ay, az, bx, by, bz,
         n1x, n1y, n1z, n2x, n2y, n2z) = _hinge_vectors(X, i, j, k, l)
        n1sq = n1x * n1x + n1y * n1y + n1z * n1z
        n2sq = n2x * n2x + n2y * n2y + n2z * n2z
        esq = ex * ex + ey * ey + ez * ez
        if n1sq <= 0.0 or n2sq <= 0.0 or esq <= 0.0:
            continue  # a degenerate face has no normal; its stretch springs restore it
        elen = math.sqrt(esq)
        inv = 1.0 / math.sqrt(n1sq * n2sq)
        cos_t = (n1x * n2x + n1y * n2y + n1z * n2z) * inv
        cx = n1y * n2z - n1z * n2y
        cy = n1z * n2x - n1x * n2z
        cz = n1x * n2y - n1y * n2x
        sin_t = (cx * ex + cy * ey + cz * ez) * inv / elen
        kb = stiffness[h]
        energy += kb * (1.0 - (cos_t * cos0[h] + sin_t * sin0[h]))
        dedt = kb * (sin_t * cos0[h] - cos_t * sin0[h])
        # gradients of theta
        sk = -elen / n1sq
        sl = -elen / n2sq
        gkx = sk * n1x
        gky = sk * n1y
        gkz = sk * n1z
        glx = sl * n2x
        gly = sl * n2y
        glz = sl * n2z
        lk = (ax * ex + ay * ey + az * ez) / esq
        ll = ((bx + ex) * ex + (by + ey) * ey + (bz + ez) * ez) / esq
        # force = -dE/dtheta * grad theta
        F[k, 0] -= dedt * gkx
        F[k, 1] -= dedt * gky
        F[k, 2] -= dedt * gkz
        F[l, 0] -= dedt * glx
        F[l, 1] -= dedt * gly
        F[l, 2] -= dedt * glz
        F[i, 0] += dedt * ((1.0 - lk) * gkx + (1.0 - ll) * glx)
        F[i, 1] += dedt * ((1.0 - lk) * gky + (1.0 - ll) * gly)
        F[i, 2] += dedt * ((1.0 - lk) * gkz + (1.0 - ll) * glz)
        F[j, 0] += dedt * (lk * gkx + ll * glx)
        F[j, 1] += dedt * (lk * gky + ll * gly)
        F[j, 2] += dedt * (lk * gkz + ll * glz)
    return energy


@njit(cache=True)
def internal_forces(X, edges, rest0, growth, edge_k, hinges, cos0, sin0, hinge_k, A, F):
    """Zero ``F``, then add stretch and bending forces; return the potential energy."""
    F[:, :] = 0.0
    energy = 0.0
    if edges.shape[0]:
        energy += stretch_forces(X, edges, rest0, growth, edge_k, A, F)
    if hinges.shape[0]:
        energy += bending_forces(X, hinges, cos0, sin0, hinge_k, F)
    return energy


@njit(cache=True)
def advance(X, V, F, F_next, inv_mass, edges, rest0, growth, edge_k, hinges, cos0, sin0,
            hinge_k, schedule, ramp_time, step0, n_steps, h, eta, d):
    """Advance ``n_steps`` steps from step index ``step0`` (time ``step0 * h``).

    The semi-implicit scheme of the paper, with one force evaluation per step::

        X[n+1] = X[n] + h V[n] + h^2/2 M^-1 f(X[n])                          (Eq. 7)
        V[n+1] = d V[n] + h M^-1 [eta f(X[n]) + (1 - eta) f(X[n+1])]        (Eq. 8)

    ``d = 1`` is Eq. 8 (``eta = 1/2`` is velocity Verlet); ``eta = 1/2, d < 1`` is the
    explicit damping of Eq. 9. ``f(X[n+1])`` uses the rest lengths of ``t[n+1]`` and is
    reused as the next step's ``f(X[n])``. ``F`` holds ``f(X[step0])`` on entry and
    ``f(X[step0 + n_steps])`` on return. Pinned vertices have ``inv_mass = 0``: their
    forces are ignored and their positions never change (Eq. 10).
    Returns the potential energy at the last step.
    """
    nv = X.shape[0]
    half_hh = 0.5 * h * h
    energy = 0.0
    for n in range(n_steps):
        for v in range(nv):
            w = inv_mass[v]
            X[v, 0] += h * V[v, 0] + half_hh * w * F[v, 0]
            X[v, 1] += h * V[v, 1] + half_hh * w * F[v, 1]
            X[v, 2] += h * V[v, 2] + half_hh * w * F[v, 2]
        t = (step0 + n + 1) * h
        A = schedule_value(schedule, t, ramp_time)
        energy = internal_forces(X, edges, rest0, growth, edge_k, hinges, cos0, sin0,
                                 hinge_k, A, F_next)
        for v in range(nv):
            hw = h * inv_mass[v]
            for c in range(3):
                V[v, c] = d * V[v, c] + hw * (eta * F[v, c] + (1.0 - eta) * F_next[v, c])
                F[v, c] = F_next[v, c]
    return energy


@njit(cache=True)
def edge_lengths(X, edges, out):
    """Length of every edge into ``out (E,)``, with the same arithmetic as
    :func:`stretch_forces`, so a mesh at its own rest lengths feels exactly zero force."""
    for e in range(edges.shape[0]):
        out[e] = _edge_vector(X, edges[e, 0], edges[e, 1])[3]


@njit(cache=True)
def hinge_cos_sin(X, hinges, cos_out, sin_out):
    """cos and sin of every hinge's dihedral angle, with the same arithmetic as
    :func:`bending_forces`, so a mesh at its own rest angles feels exactly zero force."""
    for h in range(hinges.shape[0]):
        (ex, ey, ez, ax, ay, az, bx, by, bz,
         n1x, n1y, n1z, n2x, n2y, n2z) = _hinge_vectors(X, hinges[h, 0], hinges[h, 1],
                                                        hinges[h, 2], hinges[h, 3])
        n1sq = n1x * n1x + n1y * n1y + n1z * n1z
        n2sq = n2x * n2x + n2y * n2y + n2z * n2z
        esq = ex * ex + ey * ey + ez * ez
        if n1sq <= 0.0 or n2sq <= 0.0 or esq <= 0.0:
            cos_out[h] = 1.0
            sin_out[h] = 0.0
            continue
        elen = math.sqrt(esq)
        inv = 1.0 / math.sqrt(n1sq * n2sq)
        cx = n1y * n2z - n1z * n2y
        cy = n1z * n2x - n1x * n2z
        cz = n1x * n2y - n1y * n2x
        cos_out[h] = (n1x * n2x + n1y * n2y + n1z * n2z) * inv
        sin_out[h] = (cx * ex + cy * ey + cz * ez) * inv / elen


def dihedral_angles(X, hinges):
    """Signed dihedral angle of every hinge in (-pi, pi] (the measure of Eq. 3)."""
    cos_t = np.empty(len(hinges))
    sin_t = np.empty(len(hinges))
    hinge_cos_sin(np.ascontiguousarray(X, dtype=np.float64),
                  np.ascontiguousarray(hinges, dtype=np.int64), cos_t, sin_t)
    return np.arctan2(sin_t, cos_t)
