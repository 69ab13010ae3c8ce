"""Stretch and bending: the petal's own elastic forces (Eq. 2-3), compiled.

Conventions: see :mod:`pipeline.sim.kernels`. Springs and hinges are evaluated in one
blocked pass (:func:`_add_forces`): a block of hinges gathers its vectors, computes its
bending terms and scatters them with its edge's stretch term. The measures the rest
state is taken from (:func:`edge_lengths`, :func:`hinge_cos_sin`) share the force loops'
arithmetic, so a mesh at rest has zero force to the bit.
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
def _spring(length, rest, k):
    """A spring ``k (length - rest)``: its tension and energy. One place for stretch and
    connection springs; the caller adds ``tension / length * d`` to ``F[i]`` and takes it
    from ``F[j]`` (``d = x_j - x_i``) when ``length > 0``.

    It takes no array on purpose: an array handed to an inlined helper that branches
    costs an atomic reference count increment and decrement per call (per edge)."""
    stretch = length - rest
    tension = k * stretch
    return tension, 0.5 * tension * stretch


@njit(cache=True, nogil=True, error_model="numpy")
def _stretch_range(X, edges, rest0, growth, stiffness, A, F, lo, hi):
    """Stretch forces of edges ``lo..hi-1`` added to ``F``; returns their energy."""
    energy = 0.0
    for e in range(lo, hi):
        i = _vertex(edges[e, 0])
        j = _vertex(edges[e, 1])
        dx, dy, dz, length = _edge_vector(X, i, j)
        tension, en = _spring(length, rest0[e] * (1.0 + A * growth[e]), stiffness[e])
        energy += en
        if length > 0.0:
            c = tension / length
            F[i, 0] += c * dx
            F[i, 1] += c * dy
            F[i, 2] += c * dz
            F[j, 0] -= c * dx
            F[j, 1] -= c * dy
            F[j, 2] -= c * dz
    return energy


@njit(cache=True, nogil=True)
def stretch_forces(X, edges, rest0, growth, stiffness, A, F):
    """Add the stretch forces of every edge to ``F``; return the stretch energy (Eq. 2)."""
    return _stretch_range(X, edges, rest0, growth, stiffness, A, F, 0, edges.shape[0])


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


# The hinge loop runs in blocks of _BLOCK hinges and three passes over a work array:
# a gather pass reads the vertices (scalar, indexed loads), a pass over contiguous rows
# does all the arithmetic (it has no indexed access, so LLVM vectorizes it: 8 hinges a
# time, square roots and divisions included, with the same IEEE results per hinge as a
# scalar loop), and a scatter pass adds the forces to F (scalar, in hinge order).
# Rows are _BLOCK apart, a compile-time constant, so the compiler sees they do not
# overlap. 13 rows of 256 doubles: 26 KB, in L1.
_BLOCK = 256
_W_ROWS = 13
_W_SIZE = _W_ROWS * _BLOCK


@njit(cache=True, nogil=True, error_model="numpy")
def _hinge_gather(X, edges, rest0, growth, edge_k, hinges, A, lo, n, W, F):
    """Rows 0-8: ``e, a, b`` of hinges ``lo..lo+n-1``; rows 9-10: rest length and
    stiffness of the spring of edge h when it is hinge h's edge ``(i, j)`` (0 if not: such
    an edge's spring is added to ``F`` here, and its energy returned)."""
    hs = hinges[lo:lo + n]  # block-local views: their indices t >= 0 need no wraparound
    ne = max(0, min(n, edges.shape[0] - lo))
    es = edges[lo:lo + ne]
    energy = 0.0
    for t in range(n):
        i = _vertex(hs[t, 0])
        j = _vertex(hs[t, 1])
        k = _vertex(hs[t, 2])
        l = _vertex(hs[t, 3])
        xi0 = X[i, 0]
        xi1 = X[i, 1]
        xi2 = X[i, 2]
        xj0 = X[j, 0]
        xj1 = X[j, 1]
        xj2 = X[j, 2]
        W[t] = xj0 - xi0  # as _edge_vector: rest lengths agree to the bit
        W[_BLOCK + t] = xj1 - xi1
        W[2 * _BLOCK + t] = xj2 - xi2
        W[3 * _BLOCK + t] = X[k, 0] - xi0
        W[4 * _BLOCK + t] = X[k, 1] - xi1
        W[5 * _BLOCK + t] = X[k, 2] - xi2
        W[6 * _BLOCK + t] = X[l, 0] - xj0
        W[7 * _BLOCK + t] = X[l, 1] - xj1
        W[8 * _BLOCK + t] = X[l, 2] - xj2
        if t < ne and es[t, 0] == hs[t, 0] and es[t, 1] == hs[t, 1]:
            W[9 * _BLOCK + t] = rest0[lo + t] * (1.0 + A * growth[lo + t])
            W[10 * _BLOCK + t] = edge_k[lo + t]
        else:
            W[9 * _BLOCK + t] = 0.0
            W[10 * _BLOCK + t] = 0.0
            if t < ne:
                energy += _stretch_range(X, edges, rest0, growth, edge_k, A, F, lo + t,
                                         lo + t + 1)
    return energy


@njit(cache=True, nogil=True, error_model="numpy")
def _hinge_block(W, cos0, sin0, hinge_k, n):
    """Forces on k, l, i, j of ``n`` hinges (and their edges' springs) from the rows of
    :func:`_hinge_gather`, into rows 0-11, and the energy into row 12. ``cos0, sin0,
    hinge_k`` start at the block's first hinge.

    The gradient of theta is the discrete-shells one: the opposite vertices move along
    their face normals, ``d theta / d x_k = -|e| n1 / |n1|^2`` and likewise for ``l``;
    ``j`` takes the parts of these given by the projections of ``k`` and ``l`` onto the
    edge, and ``i`` the rest, so that the forces sum to zero. A degenerate face (no
    normal) has no bending; its stretch springs restore it."""
    for t in range(n):
        ex = W[t]
        ey = W[_BLOCK + t]
        ez = W[2 * _BLOCK + t]
        ax = W[3 * _BLOCK + t]
        ay = W[4 * _BLOCK + t]
        az = W[5 * _BLOCK + t]
        bx = W[6 * _BLOCK + t]
        by = W[7 * _BLOCK + t]
        bz = W[8 * _BLOCK + t]
        rest = W[9 * _BLOCK + t]
        ks = W[10 * _BLOCK + t]
        n1x, n1y, n1z, n2x, n2y, n2z = _hinge_normals(ex, ey, ez, ax, ay, az, bx, by, bz)
        n1sq = n1x * n1x + n1y * n1y + n1z * n1z
        n2sq = n2x * n2x + n2y * n2y + n2z * n2z
        esq = ex * ex + ey * ey + ez * ez
        has_normals = n1sq > 0.0 and n2sq > 0.0 and esq > 0.0
        cos_t, sin_t, elen, inv_esq, g = _hinge_angle(bx, by, bz, n1x, n1y, n1z,
                                                      n2x, n2y, n2z, n1sq, n2sq, esq)
        kb = hinge_k[t]
        bend = kb * (1.0 - (cos_t * cos0[t] + sin_t * sin0[t]))
        dedt = kb * (sin_t * cos0[t] - cos_t * sin0[t])  # dE/dtheta
        w = dedt * g
        qk = w * n2sq  # dE/dtheta |e| / |n1|^2
        ql = w * n1sq
        pk = -qk * ((ax * ex + ay * ey + az * ez) * inv_esq)
        pl = -ql * ((bx * ex + by * ey + bz * ez) * inv_esq + 1.0)
        inv_e = elen * inv_esq
        alone = 1.0 / elen  # the spring's own 1/|e| when the hinge is degenerate
        if not has_normals:
            qk = 0.0
            ql = 0.0
            pk = 0.0
            pl = 0.0
            bend = 0.0
            inv_e = alone if elen > 0.0 else 0.0
        stretch = elen - rest
        tension = ks * stretch
        c = tension * inv_e
        fkx = qk * n1x
        fky = qk * n1y
        fkz = qk * n1z
        flx = ql * n2x
        fly = ql * n2y
        flz = ql * n2z
        fjx = pk * n1x + pl * n2x
        fjy = pk * n1y + pl * n2y
        fjz = pk * n1z + pl * n2z
        cx = c * ex
        cy = c * ey
        cz = c * ez
        W[t] = fkx
        W[_BLOCK + t] = fky
        W[2 * _BLOCK + t] = fkz
        W[3 * _BLOCK + t] = flx
        W[4 * _BLOCK + t] = fly
        W[5 * _BLOCK + t] = flz
        W[6 * _BLOCK + t] = cx - (fkx + flx + fjx)
        W[7 * _BLOCK + t] = cy - (fky + fly + fjy)
        W[8 * _BLOCK + t] = cz - (fkz + flz + fjz)
        W[9 * _BLOCK + t] = fjx - cx
        W[10 * _BLOCK + t] = fjy - cy
        W[11 * _BLOCK + t] = fjz - cz
        W[12 * _BLOCK + t] = 0.5 * tension * stretch + bend


@njit(cache=True, nogil=True, error_model="numpy")
def _hinge_scatter(hinges, lo, n, W, F):
    """Add the forces of :func:`_hinge_block` to ``F``, hinge by hinge; return their
    energy (summed in hinge order)."""
    hs = hinges[lo:lo + n]
    energy = 0.0
    for t in range(n):
        i = _vertex(hs[t, 0])
        j = _vertex(hs[t, 1])
        k = _vertex(hs[t, 2])
        l = _vertex(hs[t, 3])
        energy += W[12 * _BLOCK + t]
        F[k, 0] += W[t]
        F[k, 1] += W[_BLOCK + t]
        F[k, 2] += W[2 * _BLOCK + t]
        F[l, 0] += W[3 * _BLOCK + t]
        F[l, 1] += W[4 * _BLOCK + t]
        F[l, 2] += W[5 * _BLOCK + t]
        F[i, 0] += W[6 * _BLOCK + t]
        F[i, 1] += W[7 * _BLOCK + t]
        F[i, 2] += W[8 * _BLOCK + t]
        F[j, 0] += W[9 * _BLOCK + t]
        F[j, 1] += W[10 * _BLOCK + t]
        F[j, 2] += W[11 * _BLOCK + t]
    return energy


@njit(cache=True, nogil=True, error_model="numpy")
def _add_forces(X, edges, rest0, growth, edge_k, hinges, cos0, sin0, hinge_k, A, F, W):
    """Add stretch and bending forces to ``F``; return the potential energy. ``W`` is a
    work array of ``_W_SIZE`` doubles.

    Edge h is done with hinge h when it is hinge h's edge, in the same orientation (the
    order :meth:`Model.build <pipeline.sim.model.Model.build>` gives the edges: interior
    edges first, in hinge order): the edge vector and length are taken once and the
    spring shares the hinge's division. Any other edge is done on its own, so every
    input is handled."""
    nh = hinges.shape[0]
    ne = edges.shape[0]
    energy = 0.0
    for lo in range(0, nh, _BLOCK):
        n = min(_BLOCK, nh - lo)
        energy += _hinge_gather(X, edges, rest0, growth, edge_k, hinges, A, lo, n, W, F)
        _hinge_block(W, cos0[lo:lo + n], sin0[lo:lo + n], hinge_k[lo:lo + n], n)
        energy += _hinge_scatter(hinges, lo, n, W, F)
    if ne > nh:
        energy += _stretch_range(X, edges, rest0, growth, edge_k, A, F, nh, ne)
    return energy


@njit(cache=True, nogil=True)
def bending_forces(X, hinges, cos0, sin0, stiffness, F):
    """Add the bending forces of every hinge to ``F``; return the bending energy (Eq. 3).
    See :func:`_hinge_block` for the gradient."""
    return _add_forces(X, np.empty((0, 2), dtype=np.int64), np.empty(0), np.empty(0),
                       np.empty(0), hinges, cos0, sin0, stiffness, 0.0, F,
                       np.empty(_W_SIZE))


@njit(cache=True, nogil=True)
def internal_forces(X, edges, rest0, growth, edge_k, hinges, cos0, sin0, hinge_k, A, F):
    """Zero ``F``, then add stretch and bending forces; return the potential energy."""
    F[:, :] = 0.0
    return _add_forces(X, edges, rest0, growth, edge_k, hinges, cos0, sin0, hinge_k, A, F,
                       np.empty(_W_SIZE))


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
