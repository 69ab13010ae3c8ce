"""The compiled kernels of the effects that are not collisions: curl's rest angles
(Eq. 11), the center-plane constraint, and connection springs."""

from __future__ import annotations

import math

from numba import njit

from .elastic import _edge_vector, _spring


@njit(cache=True)
def curl_rest_angles(theta0, factor, cos_t, sin_t):
    """Rest angles of the curl effect (Eq. 11): ``theta0 (1 - B beta)``, as cos and sin.
    ``factor`` is ``B(t) beta``."""
    keep = 1.0 - factor
    for k in range(theta0.shape[0]):
        a = keep * theta0[k]
        cos_t[k] = math.cos(a)
        sin_t[k] = math.sin(a)


@njit(cache=True)
def project_out_normals(F, idx, normals):
    """Remove each listed vertex's component along its (unit) normal from ``F``: with
    forces and velocities free of it, the vertex keeps its distance to its plane."""
    for k in range(idx.shape[0]):
        v = idx[k]
        dot = F[v, 0] * normals[k, 0] + F[v, 1] * normals[k, 1] + F[v, 2] * normals[k, 2]
        F[v, 0] -= dot * normals[k, 0]
        F[v, 1] -= dot * normals[k, 1]
        F[v, 2] -= dot * normals[k, 2]


@njit(cache=True)
def restore_plane(X, V, idx, normals, height):
    """Put each listed vertex back at its distance ``height`` along its normal and remove
    the normal component of its velocity (after a collision push)."""
    for k in range(idx.shape[0]):
        v = idx[k]
        off = X[v, 0] * normals[k, 0] + X[v, 1] * normals[k, 1] + X[v, 2] * normals[k, 2] - height[k]
        vn = V[v, 0] * normals[k, 0] + V[v, 1] * normals[k, 1] + V[v, 2] * normals[k, 2]
        for c in range(3):
            X[v, c] -= off * normals[k, c]
            V[v, c] -= vn * normals[k, c]


@njit(cache=True)
def connection_forces(X, pairs, rest, k, limit, alive, broken_step, step, F):
    """Springs between petals; one breaks for good when longer than ``limit`` (its own
    breaking length). Adds to ``F``; returns the energy of the intact springs."""
    energy = 0.0
    for c in range(pairs.shape[0]):
        if not alive[c]:
            continue
        i, j = pairs[c, 0], pairs[c, 1]
        dx, dy, dz, length = _edge_vector(X, i, j)
        if length > limit[c]:
            alive[c] = False
            broken_step[c] = step
            continue
        tension, en = _spring(length, rest[c], k)
        energy += en
        if length > 0.0:
            f = tension / length
            F[i, 0] += f * dx
            F[i, 1] += f * dy
            F[i, 2] += f * dz
            F[j, 0] -= f * dx
            F[j, 1] -= f * dy
            F[j, 2] -= f * dz
    return energy
