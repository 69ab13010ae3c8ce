"""Compiled force and integration kernels (numba, cached to disk).

These loops are the product: they run hundreds of thousands of times per bloom. They
work on plain contiguous arrays and write into arrays the caller owns; nothing is
allocated per step (the force loop's one small work block is taken once per call).
Accumulation order is fixed (serial accumulation, no fastmath), so results are
bit-reproducible; the loops the compiler vectorizes only compute each element on its own,
with the same IEEE operations as scalar code, and sum nothing across elements.

Conventions
-----------
- ``X, V, F``: ``(V, 3) float64`` positions, velocities, forces.
- ``edges``: ``(E, 2) int64``; rest length of edge e at time t is
  ``rest0[e] * (1 + A(t) * growth[e])`` (Eq. 6). Fastest when edge h is hinge h's edge
  ``(i, j)`` (the order of :meth:`Model.build <pipeline.sim.model.Model.build>`); any
  order gives the same forces.
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


@njit(cache=True, error_model="numpy")
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


@njit(cache=True)
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


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
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


@njit(cache=True)
def bending_forces(X, hinges, cos0, sin0, stiffness, F):
    """Add the bending forces of every hinge to ``F``; return the bending energy (Eq. 3).
    See :func:`_hinge_block` for the gradient."""
    return _add_forces(X, np.empty((0, 2), dtype=np.int64), np.empty(0), np.empty(0),
                       np.empty(0), hinges, cos0, sin0, stiffness, 0.0, F,
                       np.empty(_W_SIZE))


@njit(cache=True)
def internal_forces(X, edges, rest0, growth, edge_k, hinges, cos0, sin0, hinge_k, A, F):
    """Zero ``F``, then add stretch and bending forces; return the potential energy."""
    F[:, :] = 0.0
    return _add_forces(X, edges, rest0, growth, edge_k, hinges, cos0, sin0, hinge_k, A, F,
                       np.empty(_W_SIZE))


@njit(cache=True, error_model="numpy")
def _positions(X, V, F, inv_mass, h, half_hh):
    """Eq. 7 on flat ``(3V,)`` views: ``X += h V + h^2/2 M^-1 F``. Flat, with the stride
    3 a constant, the compiler vectorizes it."""
    for v in range(inv_mass.shape[0]):
        w = half_hh * inv_mass[v]
        b = 3 * v
        X[b] += h * V[b] + w * F[b]
        X[b + 1] += h * V[b + 1] + w * F[b + 1]
        X[b + 2] += h * V[b + 2] + w * F[b + 2]


@njit(cache=True, error_model="numpy")
def _velocities(V, F, F_next, inv_mass, h, d, eta, eta_next):
    """Eq. 8 on flat ``(3V,)`` views; zeroes ``F`` (used up) for the next step's forces.
    Returns the largest squared speed (exact whatever the order it is taken in, so four
    running maxima break the dependency chain)."""
    nv = inv_mass.shape[0]
    for v in range(nv):
        hw = h * inv_mass[v]
        b = 3 * v
        V[b] = d * V[b] + hw * (eta * F[b] + eta_next * F_next[b])
        V[b + 1] = d * V[b + 1] + hw * (eta * F[b + 1] + eta_next * F_next[b + 1])
        V[b + 2] = d * V[b + 2] + hw * (eta * F[b + 2] + eta_next * F_next[b + 2])
        F[b] = 0.0
        F[b + 1] = 0.0
        F[b + 2] = 0.0
    f0 = 0.0
    f1 = 0.0
    f2 = 0.0
    f3 = 0.0
    quads = nv // 4
    for u in range(quads):
        b = 12 * u
        s0 = V[b] * V[b] + V[b + 1] * V[b + 1] + V[b + 2] * V[b + 2]
        s1 = V[b + 3] * V[b + 3] + V[b + 4] * V[b + 4] + V[b + 5] * V[b + 5]
        s2 = V[b + 6] * V[b + 6] + V[b + 7] * V[b + 7] + V[b + 8] * V[b + 8]
        s3 = V[b + 9] * V[b + 9] + V[b + 10] * V[b + 10] + V[b + 11] * V[b + 11]
        if s0 > f0:
            f0 = s0
        if s1 > f1:
            f1 = s1
        if s2 > f2:
            f2 = s2
        if s3 > f3:
            f3 = s3
    for v in range(4 * quads, nv):
        b = 3 * v
        s0 = V[b] * V[b] + V[b + 1] * V[b + 1] + V[b + 2] * V[b + 2]
        if s0 > f0:
            f0 = s0
    if f1 > f0:
        f0 = f1
    if f2 > f0:
        f0 = f2
    if f3 > f0:
        f0 = f3
    return f0


@njit(cache=True, error_model="numpy")
def advance(X, V, F, F_next, inv_mass, edges, rest0, growth, edge_k, hinges, cos0, sin0,
            hinge_k, schedule, ramp_time, table, step0, n_steps, h, eta, d, fx, speed_limit):
    """Advance ``n_steps`` steps from step index ``step0`` (time ``step0 * h``).

    The semi-implicit scheme of the paper, with one force evaluation per step::

        X[n+1] = X[n] + h V[n] + h^2/2 M^-1 f(X[n])                          (Eq. 7)
        V[n+1] = d V[n] + h M^-1 [eta f(X[n]) + (1 - eta) f(X[n+1])]        (Eq. 8)

    ``d = 1`` is Eq. 8 (``eta = 1/2`` is velocity Verlet); ``eta = 1/2, d < 1`` is the
    explicit damping of Eq. 9. ``f(X[n+1])`` uses the rest lengths of ``t[n+1]`` and is
    reused as the next step's ``f(X[n])``. ``F`` holds ``f(X[step0])`` on entry and
    ``f(X[step0 + n_steps])`` on return (so does ``F_next``, the work array). Pinned
    vertices have ``inv_mass = 0``: their forces are ignored and their positions never
    change (Eq. 10).

    ``fx`` is the effects' :class:`~pipeline.sim.effects.Bundle` (fields by name); an effect that
    is off is skipped by one branch per step and runs no loop. Within a step: positions
    (Eq. 7), collisions push vertices back, curl sets the rest angles of ``t[n+1]``,
    forces (springs, hinges, connection springs; the center-plane constraint removes
    the plane-normal component of its vertices' forces), velocities (Eq. 8).

    Divergence guard: a step whose energy is not finite, or after which a vertex moves
    faster than ``speed_limit`` (mesh units per unit time), ends the call at once.
    Returns ``(potential energy at the last step taken, steps taken)``.

    ``F`` and ``F_next`` swap roles every step instead of being copied, and the array
    whose forces have been used is zeroed in the velocity pass, ready to take the next
    step's forces.
    """
    if n_steps <= 0:
        return 0.0, n_steps
    half_hh = 0.5 * h * h
    eta_next = 1.0 - eta
    limit_sq = speed_limit * speed_limit
    energy = 0.0
    curl_on, theta0, beta, cos_t, sin_t = (fx.curl_on, fx.curl_theta0, fx.curl_beta,
                                           fx.curl_cos, fx.curl_sin)
    plane_on, plane_idx, plane_n, plane_h = (fx.plane_on, fx.plane_vertices, fx.plane_normals,
                                             fx.plane_height)
    conn_on, conn_pairs, conn_rest, conn_k, conn_limit, conn_alive, conn_broken = (
        fx.conn_on, fx.conn_pairs, fx.conn_rest, fx.conn_k, fx.conn_limit, fx.conn_alive,
        fx.conn_broken)
    coll_on, faces, face_petal, vert_petal, side, normals, coll_par = (
        fx.coll_on, fx.coll_faces, fx.coll_face_petal, fx.coll_vertex_petal, fx.coll_side,
        fx.coll_normals, fx.coll_params)
    start, count, items, X_ref, counters = (fx.grid_start, fx.grid_count, fx.grid_items,
                                            fx.grid_reference, fx.counters)
    pair_start, pair_faces, best_face, best_dist, near = (
        fx.pair_start, fx.pair_faces, fx.best_face, fx.best_dist, fx.coll_near)
    c0, s0 = (cos_t, sin_t) if curl_on else (cos0, sin0)
    W = np.empty(_W_SIZE)  # the one allocation: per call, not per step
    Fc = F  # f(X[n])
    Fn = F_next  # f(X[n+1]), accumulated into zeros
    Fn[:, :] = 0.0
    Xf = X.reshape(X.size)  # flat views for the per-vertex loops
    Vf = V.reshape(V.size)
    Fcf = F.reshape(F.size)
    Fnf = F_next.reshape(F_next.size)
    swapped = False  # whether Fc is F_next
    taken = n_steps
    for n in range(n_steps):
        _positions(Xf, Vf, Fcf, inv_mass, h, half_hh)
        if coll_on:
            collide(X, V, inv_mass, faces, face_petal, vert_petal, side, near, normals, coll_par,
                    start, count, items, pair_start, pair_faces, best_face, best_dist, X_ref,
                    counters)
            if plane_on:  # a push must not move an axis vertex off its plane
                restore_plane(X, V, plane_idx, plane_n, plane_h)
        t = (step0 + n + 1) * h
        A = growth_value(schedule, t, ramp_time, table)
        if curl_on:
            curl_rest_angles(theta0, A * beta, cos_t, sin_t)
        energy = _add_forces(X, edges, rest0, growth, edge_k, hinges, c0, s0, hinge_k, A, Fn, W)
        if conn_on:
            energy += connection_forces(X, conn_pairs, conn_rest, conn_k, conn_limit,
                                        conn_alive, conn_broken, step0 + n + 1, Fn)
        if plane_on:
            project_out_normals(Fn, plane_idx, plane_n)
        fastest = _velocities(Vf, Fcf, Fnf, inv_mass, h, d, eta, eta_next)
        Fc, Fn = Fn, Fc
        Fcf, Fnf = Fnf, Fcf
        swapped = not swapped
        if not (math.isfinite(energy) and fastest <= limit_sq):
            taken = n + 1
            break
    if swapped:
        F[:, :] = F_next
    else:
        F_next[:, :] = F
    return energy, taken


# --- effects ---------------------------------------------------------------------------

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


@njit(cache=True, inline="always")
def _cell_hash(ix, iy, iz, size):
    return ((ix * 73856093) ^ (iy * 19349663) ^ (iz * 83492791)) % size


@njit(cache=True)
def build_face_grid(X, faces, inflate, cell, start, count, items):
    """A uniform grid over space, stored as a hash table of cells: every face is listed
    in every cell its bounding box (grown by ``inflate``) overlaps. Counting sort into
    ``start (S+1,)``, ``count (S,)`` and ``items``.

    A face whose box spans more than 3 cells along an axis (it has grown far beyond its
    rest size: the run is diverging) is left out, and so is everything when the
    listings exceed ``items``' capacity (the grid is then empty). Returns how many
    listings were left out: 0 when the grid is complete."""
    size = count.shape[0]
    count[:] = 0
    lost = 0
    for pass_ in range(2):
        if pass_ == 1:
            total = 0
            for b in range(size):
                total += count[b]
            if total > items.shape[0]:
                count[:] = 0
                start[:] = 0
                return lost + total - items.shape[0]
            start[0] = 0
            for b in range(size):
                start[b + 1] = start[b] + count[b]
                count[b] = 0
        for f in range(faces.shape[0]):
            a, b_, c = faces[f, 0], faces[f, 1], faces[f, 2]
            lo0 = min(X[a, 0], min(X[b_, 0], X[c, 0])) - inflate
            lo1 = min(X[a, 1], min(X[b_, 1], X[c, 1])) - inflate
            lo2 = min(X[a, 2], min(X[b_, 2], X[c, 2])) - inflate
            hi0 = max(X[a, 0], max(X[b_, 0], X[c, 0])) + inflate
            hi1 = max(X[a, 1], max(X[b_, 1], X[c, 1])) + inflate
            hi2 = max(X[a, 2], max(X[b_, 2], X[c, 2])) + inflate
            if not (hi0 - lo0 <= 3.0 * cell and hi1 - lo1 <= 3.0 * cell
                    and hi2 - lo2 <= 3.0 * cell):
                if pass_ == 0:
                    lost += 1
                continue
            for ix in range(int(math.floor(lo0 / cell)), int(math.floor(hi0 / cell)) + 1):
                for iy in range(int(math.floor(lo1 / cell)), int(math.floor(hi1 / cell)) + 1):
                    for iz in range(int(math.floor(lo2 / cell)), int(math.floor(hi2 / cell)) + 1):
                        key = _cell_hash(ix, iy, iz, size)
                        if pass_ == 0:
                            count[key] += 1
                        else:
                            items[start[key] + count[key]] = f
                            count[key] += 1
    return lost


@njit(cache=True)
def collide(X, V, inv_mass, faces, face_petal, vert_petal, side, near, normals, par, start,
            count, items, pair_start, pair_faces, best_face, best_dist, X_ref, counters):
    """One step of the collision effect.

    Near pairs (a vertex and the faces of other petals within ``margin + 2 slack`` of
    it) are found through the grid and kept, Verlet-list style, until some vertex has
    moved more than ``slack`` since: until then no vertex can have come within
    ``margin`` of a face that is not listed. So the grid is built rarely and each step
    tests only the pairs that are really near. ``counters``: [contacts, builds,
    overflow, listed pairs].
    """
    cell, offset, margin, slack = par[0], par[1], par[2], par[3]
    moved = counters[1] == 0
    if not moved:
        limit = slack * slack
        for v in range(X.shape[0]):
            dx = X[v, 0] - X_ref[v, 0]
            dy = X[v, 1] - X_ref[v, 1]
            dz = X[v, 2] - X_ref[v, 2]
            if dx * dx + dy * dy + dz * dz > limit:
                moved = True
                break
    if moved:
        reach = margin + offset + 2.0 * slack
        counters[2] += build_face_grid(X, faces, reach, cell, start, count, items)
        counters[2] += near_pairs(X, faces, face_petal, vert_petal, inv_mass, reach, cell, start,
                                  count, items, pair_start, pair_faces)
        counters[3] = pair_start[X.shape[0]]
        X_ref[:, :] = X
        counters[1] += 1
    face_unit_normals(X, faces, normals)
    counters[0] += resolve_collisions(X, V, inv_mass, faces, face_petal, vert_petal, side, near,
                                      normals, offset, margin, pair_start, pair_faces,
                                      best_face, best_dist)


@njit(cache=True)
def near_pairs(X, faces, face_petal, vert_petal, inv_mass, reach, cell, start, count, items,
               pair_start, pair_faces):
    """For every free vertex, the faces of other petals whose bounding box is within
    ``reach`` of it (read from the grid of :func:`build_face_grid`), as a CSR list in
    ``pair_start (V+1,)`` and ``pair_faces``. Returns how many pairs did not fit."""
    size = count.shape[0]
    capacity = pair_faces.shape[0]
    n = 0
    lost = 0
    for v in range(X.shape[0]):
        pair_start[v] = n
        if inv_mass[v] == 0.0:
            continue
        P = vert_petal[v]
        key = _cell_hash(int(math.floor(X[v, 0] / cell)), int(math.floor(X[v, 1] / cell)),
                         int(math.floor(X[v, 2] / cell)), size)
        for k in range(start[key], start[key + 1]):
            f = items[k]
            if face_petal[f] == P:
                continue
            gap = 0.0
            for c in range(3):
                lo = min(X[faces[f, 0], c], min(X[faces[f, 1], c], X[faces[f, 2], c]))
                hi = max(X[faces[f, 0], c], max(X[faces[f, 1], c], X[faces[f, 2], c]))
                if X[v, c] < lo:
                    gap = max(gap, lo - X[v, c])
                elif X[v, c] > hi:
                    gap = max(gap, X[v, c] - hi)
            if gap > reach:
                continue
            if n < capacity:
                pair_faces[n] = f
                n += 1
            else:
                lost += 1
    pair_start[X.shape[0]] = n
    return lost


@njit(cache=True)
def face_unit_normals(X, faces, normals):
    """Unit normal of every face (zero for a degenerate face)."""
    for f in range(faces.shape[0]):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        e0x, e0y, e0z = X[b, 0] - X[a, 0], X[b, 1] - X[a, 1], X[b, 2] - X[a, 2]
        e1x, e1y, e1z = X[c, 0] - X[a, 0], X[c, 1] - X[a, 1], X[c, 2] - X[a, 2]
        nx = e0y * e1z - e0z * e1y
        ny = e0z * e1x - e0x * e1z
        nz = e0x * e1y - e0y * e1x
        norm = math.sqrt(nx * nx + ny * ny + nz * nz)
        inv = 1.0 / norm if norm > 0.0 else 0.0
        normals[f, 0] = nx * inv
        normals[f, 1] = ny * inv
        normals[f, 2] = nz * inv


@njit(cache=True, inline="always")
def _prism_distance(X, faces, normals, f, v):
    """Distance of vertex v along face f's unit normal, whether v lies in f's prism, and
    its barycentric coordinates on the face (weights of the second and third corner)."""
    a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
    px, py, pz = X[v, 0] - X[a, 0], X[v, 1] - X[a, 1], X[v, 2] - X[a, 2]
    dist = px * normals[f, 0] + py * normals[f, 1] + pz * normals[f, 2]
    e0x, e0y, e0z = X[b, 0] - X[a, 0], X[b, 1] - X[a, 1], X[b, 2] - X[a, 2]
    e1x, e1y, e1z = X[c, 0] - X[a, 0], X[c, 1] - X[a, 1], X[c, 2] - X[a, 2]
    d00 = e0x * e0x + e0y * e0y + e0z * e0z
    d01 = e0x * e1x + e0y * e1y + e0z * e1z
    d11 = e1x * e1x + e1y * e1y + e1z * e1z
    d20 = px * e0x + py * e0y + pz * e0z
    d21 = px * e1x + py * e1y + pz * e1z
    denom = d00 * d11 - d01 * d01
    if denom <= 0.0:
        return dist, False, 0.0, 0.0
    bv = (d11 * d20 - d01 * d21) / denom
    bw = (d00 * d21 - d01 * d20) / denom
    return dist, bv >= 0.0 and bw >= 0.0 and bv + bw <= 1.0, bv, bw


@njit(cache=True)
def nearest_faces(X, faces, face_petal, normals, reach, pair_start, pair_faces, v, best_face,
                  best_dist):
    """For vertex v and each petal, the near face whose prism holds v at the smallest
    distance (|distance| <= ``reach``): ``best_face[Q]`` (-1 if none), ``best_dist[Q]``."""
    best_face[:] = -1
    for k in range(pair_start[v], pair_start[v + 1]):
        f = pair_faces[k]
        Q = face_petal[f]
        dist, inside, _, _ = _prism_distance(X, faces, normals, f, v)
        if inside and abs(dist) <= reach and (best_face[Q] < 0 or abs(dist) < abs(best_dist[Q])):
            best_face[Q] = f
            best_dist[Q] = dist


@njit(cache=True)
def resolve_collisions(X, V, inv_mass, faces, face_petal, vert_petal, side, near, normals,
                       offset, margin, pair_start, pair_faces, best_face, best_dist):
    """Vertex-triangle contacts between petals, among the near pairs of :func:`near_pairs`.

    For a vertex and another petal Q, the face that counts is the nearest one whose
    prism holds the vertex (a petal's surface near a vertex, not every face plane
    around it). ``side[v, Q]`` (+-1) is the side of Q (along its normals) that v belongs
    on, taken from the bud; ``near[v, Q]`` says whether v was over or under Q (within
    ``margin``, in a prism) at the last step. A vertex that comes near Q around its rim,
    not through it, takes the side it arrives on. A vertex that has gone through (by up
    to ``margin``) is a contact: it is moved back to ``offset`` on its side and its
    velocity toward the face, relative to the face, is removed. ``best_face`` and
    ``best_dist`` are ``(P,)`` work arrays. Returns the number of contacts.
    """
    contacts = 0
    for v in range(X.shape[0]):
        if inv_mass[v] == 0.0:
            continue
        if pair_start[v] == pair_start[v + 1]:
            near[v, :] = 0
            continue
        nearest_faces(X, faces, face_petal, normals, margin, pair_start, pair_faces, v,
                      best_face, best_dist)
        for Q in range(best_face.shape[0]):
            f = best_face[Q]
            if f < 0:
                near[v, Q] = 0
                continue
            if near[v, Q] == 0:
                near[v, Q] = 1
                side[v, Q] = 1.0 if best_dist[Q] >= 0.0 else -1.0
            sg = side[v, Q]
            dist = sg * best_dist[Q]
            if dist >= 0.0:
                continue
            contacts += 1
            # an inelastic contact between the vertex and the face's point under it: the
            # gap is closed and the approaching velocity removed, shared by inverse mass
            # (momentum is kept), so two petals pressed together do not pump energy in
            nx, ny, nz = sg * normals[f, 0], sg * normals[f, 1], sg * normals[f, 2]
            _, _, bv, bw = _prism_distance(X, faces, normals, f, v)
            a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
            ba = 1.0 - bv - bw
            wv, wa, wb, wc = inv_mass[v], ba * inv_mass[a], bv * inv_mass[b], bw * inv_mass[c]
            denom = wv + ba * wa + bv * wb + bw * wc
            move = (offset - dist) / denom
            X[v, 0] += wv * move * nx
            X[v, 1] += wv * move * ny
            X[v, 2] += wv * move * nz
            for corner, wk in ((a, wa), (b, wb), (c, wc)):
                X[corner, 0] -= wk * move * nx
                X[corner, 1] -= wk * move * ny
                X[corner, 2] -= wk * move * nz
            vn = 0.0
            for k in range(3):
                vn += (V[v, k] - ba * V[a, k] - bv * V[b, k] - bw * V[c, k]) * (nx, ny, nz)[k]
            if vn < 0.0:
                j = -vn / denom
                for k in range(3):
                    nk = (nx, ny, nz)[k]
                    V[v, k] += wv * j * nk
                    V[a, k] -= wa * j * nk
                    V[b, k] -= wb * j * nk
                    V[c, k] -= wc * j * nk
    return contacts


@njit(cache=True)
def edges_through_faces(X, edges, edge_petal, faces, face_petal, cell, start, count, items):
    """How many edges pass through a face of another petal (segment-triangle
    intersection, Moller-Trumbore), with faces found through :func:`build_face_grid`
    (built with no inflation). Sheets that have gone through each other cross here."""
    size = count.shape[0]
    crossed = 0
    for e in range(edges.shape[0]):
        i, j = edges[e, 0], edges[e, 1]
        P = edge_petal[e]
        dx, dy, dz = X[j, 0] - X[i, 0], X[j, 1] - X[i, 1], X[j, 2] - X[i, 2]
        hit = False
        for ix in range(int(math.floor(min(X[i, 0], X[j, 0]) / cell)),
                        int(math.floor(max(X[i, 0], X[j, 0]) / cell)) + 1):
            for iy in range(int(math.floor(min(X[i, 1], X[j, 1]) / cell)),
                            int(math.floor(max(X[i, 1], X[j, 1]) / cell)) + 1):
                for iz in range(int(math.floor(min(X[i, 2], X[j, 2]) / cell)),
                                int(math.floor(max(X[i, 2], X[j, 2]) / cell)) + 1):
                    key = _cell_hash(ix, iy, iz, size)
                    for k in range(start[key], start[key + 1]):
                        f = items[k]
                        if face_petal[f] == P or hit:
                            continue
                        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
                        e1x, e1y, e1z = X[b, 0] - X[a, 0], X[b, 1] - X[a, 1], X[b, 2] - X[a, 2]
                        e2x, e2y, e2z = X[c, 0] - X[a, 0], X[c, 1] - X[a, 1], X[c, 2] - X[a, 2]
                        px = dy * e2z - dz * e2y
                        py = dz * e2x - dx * e2z
                        pz = dx * e2y - dy * e2x
                        det = e1x * px + e1y * py + e1z * pz
                        if abs(det) < 1e-14:
                            continue
                        inv = 1.0 / det
                        tx, ty, tz = X[i, 0] - X[a, 0], X[i, 1] - X[a, 1], X[i, 2] - X[a, 2]
                        u = (tx * px + ty * py + tz * pz) * inv
                        if u < 0.0 or u > 1.0:
                            continue
                        qx = ty * e1z - tz * e1y
                        qy = tz * e1x - tx * e1z
                        qz = tx * e1y - ty * e1x
                        w = (dx * qx + dy * qy + dz * qz) * inv
                        if w < 0.0 or u + w > 1.0:
                            continue
                        t = (e2x * qx + e2y * qy + e2z * qz) * inv
                        if 0.0 <= t <= 1.0:
                            hit = True
        if hit:
            crossed += 1
    return crossed


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
        cos_out[h], sin_out[h], _, _, _ = _hinge_angle(bx, by, bz, n1x, n1y, n1z,
                                                       n2x, n2y, n2z, n1sq, n2sq, esq)


def dihedral_angles(X, hinges):
    """Signed dihedral angle of every hinge in (-pi, pi] (the measure of Eq. 3)."""
    cos_t = np.empty(len(hinges))
    sin_t = np.empty(len(hinges))
    hinge_cos_sin(np.ascontiguousarray(X, dtype=np.float64),
                  np.ascontiguousarray(hinges, dtype=np.int64), cos_t, sin_t)
    return np.arctan2(sin_t, cos_t)
