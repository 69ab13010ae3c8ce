"""The measures the elastic energy is written in, compiled (numba, cached): edge vectors
and lengths, and the signed dihedral angle of a hinge.

A hinge is ``(i, j, k, l)``: the edge ``i-j``, ``k`` opposite it in the face
``i -> j -> k``, ``l`` opposite in the face ``j -> i -> l``. Its signed dihedral angle is
``theta = atan2((n1 x n2) . e_hat, n1 . n2)`` with ``n1 = e x (x_k - x_i)``,
``n2 = (x_l - x_j) x e``, ``e = x_j - x_i``; 0 when flat. These are the one place the
measures are computed: the rest state measured here and the forces of
:mod:`pipeline.sim.terms` agree to the bit, so a mesh at its own rest state feels
exactly zero force.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def _vertex(index):
    """A vertex index as unsigned: indexing with it needs no wraparound code for
    negative indices (vertex indices are never negative, Model.build checks)."""
    return np.uint64(index)


@njit(cache=True, inline="always")
def _edge_vector(X, i, j):
    """``x_j - x_i`` and its length: one place, so that rest lengths measured by
    :func:`edge_lengths` and lengths in :func:`stretch_forces` agree to the bit."""
    dx = X[j, 0] - X[i, 0]
    dy = X[j, 1] - X[i, 1]
    dz = X[j, 2] - X[i, 2]
    return dx, dy, dz, math.sqrt(dx * dx + dy * dy + dz * dz)


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
    n1x, n1y, n1z, n2x, n2y, n2z = _hinge_normals(ex, ey, ez, ax, ay, az, bx, by, bz)
    return ex, ey, ez, ax, ay, az, bx, by, bz, n1x, n1y, n1z, n2x, n2y, n2z


@njit(cache=True, inline="always")
def _hinge_normals(ex, ey, ez, ax, ay, az, bx, by, bz):
    """``n1 = e x a``, ``n2 = b x e``."""
    return (ey * az - ez * ay, ez * ax - ex * az, ex * ay - ey * ax,
            by * ez - bz * ey, bz * ex - bx * ez, bx * ey - by * ex)


@njit(cache=True, inline="always")
def _hinge_angle(bx, by, bz, n1x, n1y, n1z, n2x, n2y, n2z, n1sq, n2sq, esq):
    """cos and sin of the dihedral angle (``n1sq, n2sq, esq > 0``), and ``|e|``,
    ``1 / |e|^2`` and ``|e| / (|n1|^2 |n2|^2)`` for the gradient: two square roots and
    one division. The one place this is computed, so that a mesh at its own rest
    angles (:func:`hinge_cos_sin`) feels exactly zero force.

    ``sin theta = (n1 x n2) . e / (|n1| |n2| |e|)`` with ``n1 x n2 = -(n1 . b) e``
    (``e . n1 = 0``), so ``sin theta = -(n1 . b) |e| / (|n1| |n2|)``."""
    nn = n1sq * n2sq
    r = 1.0 / (nn * esq)
    elen = math.sqrt(esq)
    inv_nn = esq * r
    inv_p = math.sqrt(nn) * inv_nn  # 1 / (|n1| |n2|)
    cos_t = (n1x * n2x + n1y * n2y + n1z * n2z) * inv_p
    sin_t = -(n1x * bx + n1y * by + n1z * bz) * (elen * inv_p)
    return cos_t, sin_t, elen, nn * r, elen * inv_nn


@njit(cache=True, nogil=True)
def edge_lengths(X, edges, out):
    """Length of every edge into ``out (E,)``, with the same arithmetic as
    :func:`stretch_forces`, so a mesh at its own rest lengths feels exactly zero force."""
    for e in range(edges.shape[0]):
        out[e] = _edge_vector(X, edges[e, 0], edges[e, 1])[3]


@njit(cache=True, nogil=True)
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
        cos_out[h], sin_out[h], _, _, _ = _hinge_angle(bx, by, bz, n1x, n1y, n1z,
                                                       n2x, n2y, n2z, n1sq, n2sq, esq)


def dihedral_angles(X, hinges):
    """Signed dihedral angle of every hinge in (-pi, pi] (the measure of Eq. 3)."""
    cos_t = np.empty(len(hinges))
    sin_t = np.empty(len(hinges))
    hinge_cos_sin(np.ascontiguousarray(X, dtype=np.float64),
                  np.ascontiguousarray(hinges, dtype=np.int64), cos_t, sin_t)
    return np.arctan2(sin_t, cos_t)
