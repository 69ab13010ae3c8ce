"""The step of the dynamic integrators (Eq. 7-8): :func:`advance`, compiled, which runs
the terms' kernels (:mod:`pipeline.sim.terms`) and the paper's push-back
(:mod:`pipeline.sim.explicit.pushback`) in one loop.

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

from pipeline.sim.explicit.pushback import collide
from pipeline.sim.terms.bending import _W_SIZE, _add_forces
from pipeline.sim.terms.center_plane import project_out_normals, restore_plane
from pipeline.sim.terms.connections import connection_forces
from pipeline.sim.terms.growth import curl_rest_angles, growth_value
from pipeline.sim.terms.shell_kernels import shell_forces


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
            hinge_k, schedule, ramp_time, table, step0, n_steps, h, eta, d, fx, speed_limit,
            shell):
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

    ``shell`` (a :class:`~pipeline.sim.terms.shell.KernelShell`): where ``shell.on``, the
    elastic forces are the shell's (membrane and bending of each face, its curl decaying
    the rest curvature) instead of the springs and hinges.

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
        if shell.on:
            P = shell.points
            for v in range(X.shape[0]):
                P[v, 0] = X[v, 0]
                P[v, 1] = X[v, 1]
                P[v, 2] = X[v, 2]
            energy = shell_forces(P, shell.faces, shell.opposite, shell.ghost, shell.crease,
                                  shell.face_edges, rest0, growth, shell.young, shell.bend,
                                  shell.nu, shell.form, shell.bloom_form, shell.det0, A,
                                  1.0 - A * shell.beta, Fn, shell.scratch)
        else:
            if curl_on:
                curl_rest_angles(theta0, A * beta, cos_t, sin_t)
            energy = _add_forces(X, edges, rest0, growth, edge_k, hinges, c0, s0, hinge_k, A,
                                 Fn, W)
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
