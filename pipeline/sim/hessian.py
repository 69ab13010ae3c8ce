"""Hessian of the potential energy, assembled into a block-sparse matrix for the
quasi-static solver (numba, cached to disk).

The energy is the one of :mod:`kernels` (Eq. 2-3): ``1/2 K_s (l - L)^2`` per edge and
``psi(theta) = K_b (1 - cos(theta - theta0))`` per hinge, with the same hinge convention.

Hessians, per element
---------------------
- Spring, with ``u = d / l``: ``d^2E / dx_j^2 = K_s [u u^T + (1 - L / l)(I - u u^T)]``,
  and the ``i`` blocks by symmetry. Its eigenvalues are ``K_s`` (along u) and
  ``K_s (1 - L/l)`` (twice, across: negative for a compressed spring).
- Hinge: ``H = psi'' g g^T + psi' d^2theta``, ``g = grad theta``. ``d^2theta`` is the
  exact derivative of the discrete-shells gradient of :func:`kernels.bending_forces`
  (``g_k = -|e| n1 / |n1|^2``, ``g_l = -|e| n2 / |n2|^2``, ``g_i`` and ``g_j`` from the
  projections of ``k`` and ``l`` onto the edge), differentiated term by term.

The Hessian is exact (not made positive definite per element): the solver reads its
inertia from the factorization and shifts it where needed (:mod:`quasistatic`).

The matrix is stored as 3x3 blocks (scipy's BSR layout); ``slots`` map each element's
vertex pairs to their block, so assembly is one pass that allocates nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from .elastic import _edge_vector, _hinge_angle, _hinge_vectors


@njit(cache=True, nogil=True, error_model="numpy")
def stretch_terms(X, edges, rest0, growth, stiffness, A, data, slots):
    """Add each spring's Hessian blocks to ``data``. ``slots[e]`` holds the block index
    of (i,i), (i,j), (j,i), (j,j)."""
    for e in range(edges.shape[0]):
        dx, dy, dz, length = _edge_vector(X, edges[e, 0], edges[e, 1])
        if length <= 0.0:
            continue
        rest = rest0[e] * (1.0 + A * growth[e])
        k = stiffness[e]
        u0 = dx / length
        u1 = dy / length
        u2 = dz / length
        across = k * (1.0 - rest / length)
        along = k - across
        for a in range(3):
            ua = u0 if a == 0 else (u1 if a == 1 else u2)
            for b in range(3):
                ub = u0 if b == 0 else (u1 if b == 1 else u2)
                kab = along * ua * ub
                if a == b:
                    kab += across
                data[slots[e, 0], a, b] += kab
                data[slots[e, 1], a, b] -= kab
                data[slots[e, 2], a, b] -= kab
                data[slots[e, 3], a, b] += kab


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


@njit(cache=True, nogil=True, error_model="numpy")
def constrain(indptr, indices, data, pinned, plane_row, normals):
    """Restrict the Hessian to the free directions (the gradient is restricted alike by
    the solver): a pinned vertex's rows and columns become the identity; a center-plane
    vertex (``plane_row[v] >= 0``, unit normal ``normals[plane_row[v]]``) is projected
    onto its plane, ``P H P + n n^T`` with ``P = I - n n^T``, so that a Newton step never
    moves it along its normal."""
    for r in range(pinned.shape[0]):
        for p in range(indptr[r], indptr[r + 1]):
            col = indices[p]
            B = data[p]
            if pinned[r] or pinned[col]:
                B[:, :] = 0.0
                if r == col:
                    for a in range(3):
                        B[a, a] = 1.0
                continue
            if plane_row[r] >= 0:  # B <- P_r B
                n = normals[plane_row[r]]
                for b in range(3):
                    dot = n[0] * B[0, b] + n[1] * B[1, b] + n[2] * B[2, b]
                    for a in range(3):
                        B[a, b] -= n[a] * dot
            if plane_row[col] >= 0:  # B <- B P_c
                n = normals[plane_row[col]]
                for a in range(3):
                    dot = B[a, 0] * n[0] + B[a, 1] * n[1] + B[a, 2] * n[2]
                    for b in range(3):
                        B[a, b] -= dot * n[b]
            if r == col and plane_row[r] >= 0:
                n = normals[plane_row[r]]
                for a in range(3):
                    for b in range(3):
                        B[a, b] += n[a] * n[b]


@njit(cache=True, nogil=True, error_model="numpy")
def hessian(X, edges, rest0, growth, edge_k, hinges, cos0, sin0, hinge_k, A, data,
            edge_slots, hinge_slots, work):
    """Zero ``data``, then add the stretch and bending Hessians. (The energy and its
    gradient come from :func:`kernels.internal_forces`, the simulator's own.)"""
    data[:, :, :] = 0.0
    if edges.shape[0]:
        stretch_terms(X, edges, rest0, growth, edge_k, A, data, edge_slots)
    if hinges.shape[0]:
        bending_terms(X, hinges, cos0, sin0, hinge_k, data, hinge_slots, work)


def block_pattern(vertex_count: int, edges: np.ndarray, hinges: np.ndarray):
    """The BSR pattern (``indptr``, ``indices``) of the Hessian and each element's slots:
    ``edge_slots (E, 4)`` and ``hinge_slots (H, 16)``, block indices into ``data``."""
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    hinges = np.asarray(hinges, dtype=np.int64).reshape(-1, 4)
    n = vertex_count
    er = np.repeat(edges, 2, axis=1)  # (i, i, j, j)
    ec = np.tile(edges, (1, 2))  # (i, j, i, j)
    hr = np.repeat(hinges, 4, axis=1)
    hc = np.tile(hinges, (1, 4))
    diag = np.arange(n, dtype=np.int64)
    rows = np.concatenate([er.ravel(), hr.ravel(), diag])
    cols = np.concatenate([ec.ravel(), hc.ravel(), diag])
    key = np.unique(rows * n + cols)
    indices = (key % n).astype(np.int64)
    indptr = np.searchsorted(key // n, np.arange(n + 1)).astype(np.int64)
    edge_slots = np.searchsorted(key, er * n + ec).astype(np.int64)
    hinge_slots = np.searchsorted(key, hr * n + hc).astype(np.int64)
    return indptr, indices, np.ascontiguousarray(edge_slots), np.ascontiguousarray(hinge_slots)


@dataclass
class Part:
    """A part of the mesh that no element joins to another (a petal): its edges, its
    hinges and its blocks (index arrays), the static arrays of its elements, taken
    once, and its own scratch for the hinge kernel, so that parts can be assembled at
    once in threads (:meth:`terms.Elastic.assemble`)."""

    edges: np.ndarray
    hinges: np.ndarray
    blocks: np.ndarray
    static: tuple | None = None
    work: np.ndarray = field(default_factory=lambda: np.zeros((7, 4, 3, 3)))


@dataclass
class Blocks:
    """One model's Hessian as 3x3 blocks: the pattern, each element's slots and the
    arrays it is assembled into (built once; :meth:`assemble` allocates nothing). The
    quasi-static solver and the stable-step estimate each hold one."""

    indptr: np.ndarray
    indices: np.ndarray
    edge_slots: np.ndarray
    hinge_slots: np.ndarray
    data: np.ndarray  #: (nnz, 3, 3) the blocks, as last assembled
    work: np.ndarray  #: scratch of :func:`bending_terms`

    @classmethod
    def build(cls, model) -> Blocks:
        indptr, indices, eslots, hslots = block_pattern(
            model.vertex_count, model.edge_indices, model.hinge_indices)
        return cls(indptr, indices, eslots, hslots, np.zeros((len(indices), 3, 3)),
                   np.zeros((7, 4, 3, 3)))

    def assemble(self, model, X, A: float, cos0, sin0) -> None:
        """The Hessian at ``X``, growth ``A`` and rest angles ``cos0, sin0`` into ``data``."""
        hessian(X, model.edge_indices, model.edge_rest_length, model.edge_growth,
                model.edge_stiffness, model.hinge_indices, cos0, sin0, model.hinge_stiffness,
                A, self.data, self.edge_slots, self.hinge_slots, self.work)

    def matrix(self):
        """``data`` as a scipy BSR matrix (a view of the blocks, not a copy)."""
        import scipy.sparse as sp

        n = 3 * (len(self.indptr) - 1)
        return sp.bsr_matrix((self.data, self.indices, self.indptr), shape=(n, n))


@njit(cache=True, nogil=True, error_model="numpy")
def rounding_scale(X, edges, rest0, growth, edge_k, hinges, cos0, sin0, hinge_k, A, scale):
    """The size of what the force and energy kernels add and subtract, per vertex into
    ``scale (V,)`` (force units), and for the energy (returned): ``eps`` times these
    bounds what rounding alone can leave in the gradient and the energy, so the solver
    never asks for less (see :meth:`quasistatic.QuasiStatic._rounding`).

    Why each term: a spring's force ``K_s (l - L) d / l`` takes the difference of
    ``l`` and ``L`` (each rounded to ``eps`` of itself) and of coordinates (``eps |x|``),
    and a representable X is ``eps |x|`` from the exact equilibrium, which a spring
    turns into ``K_s eps |x|`` of force along it and ``K_s |1 - L/l| eps |x|`` across.
    A hinge's force ``psi' grad theta`` has ``psi' = K_b sin(theta - theta0)`` from a
    difference of products of size ``K_b``, and ``theta`` moves by ``sum |grad theta|
    eps |x|`` when its vertices move by their rounding. The energy adds ``K_b (1 - cos)``
    per hinge (a difference of size ``K_b``) and ``1/2 K_s (l - L)^2`` per spring (its
    rounding: ``K_s |l - L|`` times that of ``l - L``)."""
    scale[:] = 0.0
    energy = 0.0
    for e in range(edges.shape[0]):
        i = edges[e, 0]
        j = edges[e, 1]
        dx, dy, dz, length = _edge_vector(X, i, j)
        rest = rest0[e] * (1.0 + A * growth[e])
        k = abs(edge_k[e])
        xi = max(abs(X[i, 0]), abs(X[i, 1]), abs(X[i, 2]))
        xj = max(abs(X[j, 0]), abs(X[j, 1]), abs(X[j, 2]))
        across = abs(1.0 - rest / length) if length > 0.0 else 1.0
        term = k * (length + rest + (xi + xj) * (1.0 + across))
        scale[i] += term
        scale[j] += term
        stretch = abs(length - rest)
        energy += k * stretch * (0.5 * stretch + length + rest + xi + xj)
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
        kb = abs(hinge_k[h])
        energy += 2.0 * kb
        if n1sq <= 0.0 or n2sq <= 0.0 or esq <= 0.0:
            continue  # no bending force (the kernels skip it too)
        cos_t, sin_t, elen, _, _ = _hinge_angle(bx, by, bz, n1x, n1y, n1z, n2x, n2y, n2z,
                                                n1sq, n2sq, esq)
        dpsi = abs(kb * (sin_t * cos0[h] - cos_t * sin0[h]))
        # |grad theta| of k and l (|e| / |n|), and bounds for i and j (each takes a
        # share of both, by the projections of k and l onto the edge)
        gk = elen / math.sqrt(n1sq)
        gl = elen / math.sqrt(n2sq)
        lk = abs(ax * ex + ay * ey + az * ez) / esq
        ll = abs((bx + ex) * ex + (by + ey) * ey + (bz + ez) * ez) / esq
        gi = (1.0 + lk) * gk + (1.0 + ll) * gl
        gj = lk * gk + ll * gl
        move = 0.0  # how far theta moves when the four vertices move by their rounding
        g4 = (gi, gj, gk, gl)
        v4 = (i, j, k, l)
        for t in range(4):
            v = v4[t]
            move += g4[t] * max(abs(X[v, 0]), abs(X[v, 1]), abs(X[v, 2]))
        size = (kb + dpsi) * (1.0 + move)
        for t in range(4):
            scale[v4[t]] += g4[t] * size
        energy += dpsi * move
    return energy
