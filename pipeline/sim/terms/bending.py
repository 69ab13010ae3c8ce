"""Bending (Eq. 3, 11): an angular spring across every interior edge (a hinge),
``K_b (1 - cos(theta - theta0))``, its rest angle decaying with the curl (Eq. 11).

The hinge loop (:func:`_add_forces`) is also where the stretch springs of the hinges'
edges are evaluated (edge h rides with hinge h, sharing its edge vector and a division:
the order :meth:`Model.build <pipeline.sim.model.Model.build>` gives the edges), with the
one spring kernel (:func:`pipeline.sim.terms.spring._spring`); the other edges go
through :func:`pipeline.sim.terms.stretch._stretch_range`. Gradient: the discrete-shells
one (:func:`_hinge_block`); Hessian: its exact derivative (:func:`hinge_theta_derivatives`,
:func:`bending_terms`). Bending energy is evaluated without trigonometry:
``cos(theta - theta0) = cos theta cos theta0 + sin theta sin theta0``, with the rest
angle's cosine and sine cached."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numba import njit

from pipeline.mesh.hinge import _hinge_angle, _hinge_normals, _hinge_vectors, _vertex
from pipeline.sim.blocks import blocks_matrix
from pipeline.sim.terms.growth import curl_rest_angles
from pipeline.sim.terms.spring import _spring
from pipeline.sim.terms.stretch import _stretch_range
from pipeline.sim.terms.term import Term

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
        tension, spring_energy = _spring(elen, rest, ks)
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
        W[12 * _BLOCK + t] = spring_energy + bend


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


@njit(cache=True, inline="always")
def _cross_matrix(M, r, c, s, v0, v1, v2):
    """``M[r, c] = s [v]x`` (so that ``M[r, c] w = s v x w``)."""
    M[r, c, 0, 0] = 0.0
    M[r, c, 0, 1] = -s * v2
    M[r, c, 0, 2] = s * v1
    M[r, c, 1, 0] = s * v2
    M[r, c, 1, 1] = 0.0
    M[r, c, 1, 2] = -s * v0
    M[r, c, 2, 0] = -s * v1
    M[r, c, 2, 1] = s * v0
    M[r, c, 2, 2] = 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def hinge_theta_derivatives(X, i, j, k, l, g, H, work):
    """Signed dihedral angle of one hinge as (cos, sin), its gradient ``g (4, 3)`` and
    Hessian ``H (4, 4, 3, 3)`` (blocks in the order i, j, k, l). ``work (7, 4, 3, 3)``
    is scratch. Returns (cos theta, sin theta, ok); ``ok`` is False for a degenerate
    hinge (then g and H are zero)."""
    (ex, ey, ez, ax, ay, az, bx, by, bz,
     n1x, n1y, n1z, n2x, n2y, n2z) = _hinge_vectors(X, i, j, k, l)
    n1sq = n1x * n1x + n1y * n1y + n1z * n1z
    n2sq = n2x * n2x + n2y * n2y + n2z * n2z
    esq = ex * ex + ey * ey + ez * ez
    if n1sq <= 0.0 or n2sq <= 0.0 or esq <= 0.0:
        g[:, :] = 0.0
        H[:, :, :, :] = 0.0
        return 1.0, 0.0, False
    cos_t, sin_t, elen, _, _ = _hinge_angle(bx, by, bz, n1x, n1y, n1z, n2x, n2y, n2z,
                                            n1sq, n2sq, esq)
    e = (ex, ey, ez)
    a = (ax, ay, az)
    n1 = (n1x, n1y, n1z)
    n2 = (n2x, n2y, n2z)
    eh = (ex / elen, ey / elen, ez / elen)
    lk = (ax * ex + ay * ey + az * ez) / esq
    cvec = (bx + ex, by + ey, bz + ez)  # x_l - x_i
    ll = (cvec[0] * ex + cvec[1] * ey + cvec[2] * ez) / esq
    gk = (-elen * n1x / n1sq, -elen * n1y / n1sq, -elen * n1z / n1sq)
    gl = (-elen * n2x / n2sq, -elen * n2y / n2sq, -elen * n2z / n2sq)
    for c in range(3):
        g[0, c] = -(1.0 - lk) * gk[c] - (1.0 - ll) * gl[c]
        g[1, c] = -lk * gk[c] - ll * gl[c]
        g[2, c] = gk[c]
        g[3, c] = gl[c]
    # work[0, y] = dn1/dx_y and work[1, y] = dn2/dx_y, as cross-product matrices (every
    # entry below is set, but those that are zero: dn1/dx_l, dn2/dx_k and the rows'
    # entries of the vertices they do not depend on)
    work[0, 3] = 0.0
    work[1, 2] = 0.0
    for c in range(3):
        work[2, 2, 0, c] = 0.0
        work[2, 3, 0, c] = 0.0
        work[3, 3, 0, c] = 0.0
        work[4, 2, 0, c] = 0.0
    _cross_matrix(work, 0, 0, 1.0, ax - ex, ay - ey, az - ez)
    _cross_matrix(work, 0, 1, -1.0, ax, ay, az)
    _cross_matrix(work, 0, 2, 1.0, ex, ey, ez)
    _cross_matrix(work, 1, 0, -1.0, bx, by, bz)
    _cross_matrix(work, 1, 1, 1.0, ex + bx, ey + by, ez + bz)
    _cross_matrix(work, 1, 3, -1.0, ex, ey, ez)
    # rows (in [m, y, 0, :]): work[2] = d|e|/dx_y, work[3] = dlambda_k/dx_y,
    # work[4] = dlambda_l/dx_y
    for c in range(3):
        work[2, 0, 0, c] = -eh[c]
        work[2, 1, 0, c] = eh[c]
        work[3, 0, 0, c] = (-(e[c] + a[c]) + 2.0 * lk * e[c]) / esq
        work[3, 1, 0, c] = (a[c] - 2.0 * lk * e[c]) / esq
        work[3, 2, 0, c] = e[c] / esq
        work[4, 0, 0, c] = (-(e[c] + cvec[c]) + 2.0 * ll * e[c]) / esq
        work[4, 1, 0, c] = (cvec[c] - 2.0 * ll * e[c]) / esq
        work[4, 3, 0, c] = e[c] / esq
    # work[5, y] = d g_k / dx_y, work[6, y] = d g_l / dx_y, from
    # d(n / |n|^2) = (I - 2 n n^T / |n|^2) dn / |n|^2
    s1 = elen / n1sq
    s2 = elen / n2sq
    for y in range(4):
        for r in range(3):
            for c in range(3):
                p1 = 0.0
                p2 = 0.0
                for m in range(3):
                    delta = 1.0 if r == m else 0.0
                    p1 += (delta - 2.0 * n1[r] * n1[m] / n1sq) * work[0, y, m, c]
                    p2 += (delta - 2.0 * n2[r] * n2[m] / n2sq) * work[1, y, m, c]
                work[5, y, r, c] = -n1[r] * work[2, y, 0, c] / n1sq - s1 * p1
                work[6, y, r, c] = -n2[r] * work[2, y, 0, c] / n2sq - s2 * p2
    for y in range(4):
        for r in range(3):
            for c in range(3):
                hk = work[5, y, r, c]
                hl = work[6, y, r, c]
                H[2, y, r, c] = hk
                H[3, y, r, c] = hl
                H[0, y, r, c] = (-(1.0 - lk) * hk + gk[r] * work[3, y, 0, c]
                                 - (1.0 - ll) * hl + gl[r] * work[4, y, 0, c])
                H[1, y, r, c] = (-lk * hk - gk[r] * work[3, y, 0, c]
                                 - ll * hl - gl[r] * work[4, y, 0, c])
    return cos_t, sin_t, True


@njit(cache=True, nogil=True, error_model="numpy")
def bending_terms(X, hinges, cos0, sin0, stiffness, data, slots, work):
    """Add each hinge's Hessian blocks to ``data``. ``slots[h, 4 r + c]`` is the block of
    vertex pair (r, c), r, c in i, j, k, l."""
    g = np.empty((4, 3))
    Ht = np.empty((4, 4, 3, 3))
    for h in range(hinges.shape[0]):
        v = hinges[h]
        cos_t, sin_t, ok = hinge_theta_derivatives(X, v[0], v[1], v[2], v[3], g, Ht, work)
        if not ok:
            continue
        kb = stiffness[h]
        d1 = kb * (sin_t * cos0[h] - cos_t * sin0[h])  # psi'
        d2 = kb * (cos_t * cos0[h] + sin_t * sin0[h])  # psi''
        for r in range(4):
            for q in range(4):
                block = slots[h, 4 * r + q]
                for a in range(3):
                    for b in range(3):
                        data[block, a, b] += d2 * g[r, a] * g[q, b] + d1 * Ht[r, q, a, b]


class Bending(Term):
    """Angular springs across interior edges (Eq. 3): ``K_b (1 - cos(theta - theta0))``.
    With curl, the rest angles decay with the growth, ``theta0 (1 - A beta)`` (Eq. 11)."""

    name = "bending"

    def __init__(self, hinges, rest_cos, rest_sin, stiffness, vertex_count: int, curl=None):
        self.hinges, self.stiffness, self.curl = hinges, stiffness, curl
        self.vertex_count = vertex_count
        self.cos0, self.sin0 = rest_cos, rest_sin
        self._rest = (rest_cos, rest_sin)

    @classmethod
    def of(cls, model, curl=None) -> Bending:
        """``curl``: the scene's :class:`~pipeline.sim.effects.Curl`, or None."""
        return cls(model.hinge_indices, model.hinge_rest_cos, model.hinge_rest_sin,
                   model.hinge_stiffness, model.vertex_count, curl)

    def at(self, growth: float) -> Bending:
        if self.curl is None:
            self.cos0, self.sin0 = self._rest
        else:
            c = self.curl
            curl_rest_angles(c.theta0, growth * c.beta, c.cos_t, c.sin_t)
            self.cos0, self.sin0 = c.cos_t, c.sin_t
        return self

    def forces(self, X, F) -> float:
        return bending_forces(X, self.hinges, self.cos0, self.sin0, self.stiffness, F)

    def hessian(self, X, project: bool = False) -> sp.csr_matrix:
        work = np.zeros((7, 4, 3, 3))
        return blocks_matrix(
            self.vertex_count, np.zeros((0, 2), dtype=np.int64), self.hinges,
            lambda data, es, hs_: bending_terms(X, self.hinges, self.cos0, self.sin0,
                                                   self.stiffness, data, hs_, work))
