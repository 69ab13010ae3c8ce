"""Stretch and bending in one pass (:class:`Elastic`): the form the solvers run. Its
forces are the hinge loop of :mod:`pipeline.sim.terms.bending` (each edge's spring rides
with its hinge), its Hessian the two terms' assembled into the solver's block pattern
(:func:`hessian`, :meth:`Elastic.assemble`), and :func:`rounding_scale` says how much of
a force rounding alone can leave (the solver's convergence floor)."""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from numba import njit

from pipeline.mesh.hinge import _edge_vector, _hinge_angle, _hinge_vectors
from pipeline.sim.blocks import Blocks, Part, block_pattern
from pipeline.sim.terms.bending import _W_SIZE, Bending, _add_forces, bending_terms
from pipeline.sim.terms.stretch import Stretch, stretch_terms
from pipeline.sim.terms.term import Term


@njit(cache=True, nogil=True)
def internal_forces(X, edges, rest0, growth, edge_k, hinges, cos0, sin0, hinge_k, A, F):
    """Zero ``F``, then add stretch and bending forces; return the potential energy."""
    F[:, :] = 0.0
    return _add_forces(X, edges, rest0, growth, edge_k, hinges, cos0, sin0, hinge_k, A, F,
                       np.empty(_W_SIZE))


@njit(cache=True, nogil=True, error_model="numpy")
def hessian(X, edges, rest0, growth, edge_k, hinges, cos0, sin0, hinge_k, A, data,
            edge_slots, hinge_slots, work):
    """Zero ``data``, then add the stretch and bending Hessians. (The energy and its
    gradient come from :func:`internal_forces`, the simulator's own.)"""
    data[:, :, :] = 0.0
    if edges.shape[0]:
        stretch_terms(X, edges, rest0, growth, edge_k, A, data, edge_slots)
    if hinges.shape[0]:
        bending_terms(X, hinges, cos0, sin0, hinge_k, data, hinge_slots, work)


@njit(cache=True, nogil=True, error_model="numpy")
def rounding_scale(X, edges, rest0, growth, edge_k, hinges, cos0, sin0, hinge_k, A, scale):
    """The size of what the force and energy kernels add and subtract, per vertex into
    ``scale (V,)`` (force units), and for the energy (returned): ``eps`` times these
    bounds what rounding alone can leave in the gradient and the energy, so the solver
    never asks for less (see :meth:`pipeline.sim.solver.newton.Newton.rounding`).

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


class Elastic(Term):
    """:class:`Stretch` and :class:`Bending` in one pass (each edge's spring rides with
    its hinge): the form the solvers run. Its Hessian is assembled into the solver's
    fixed block pattern (:class:`~pipeline.sim.blocks.Blocks`, :meth:`assemble`)."""

    name = "elastic"

    def __init__(self, stretch: Stretch, bending: Bending):
        self.stretch, self.bending = stretch, bending
        self._work = np.empty(_W_SIZE)
        self._blocks = None

    @classmethod
    def of(cls, model, curl=None) -> Elastic:
        return cls(Stretch.of(model), Bending.of(model, curl))

    @property
    def A(self) -> float:
        return self.stretch.A

    @property
    def units(self) -> tuple:
        """The energy terms it is made of."""
        return (self.stretch, self.bending)

    def at(self, growth: float) -> Elastic:
        self.stretch.at(growth)
        self.bending.at(growth)
        return self

    def forces(self, X, F) -> float:
        s, b = self.stretch, self.bending
        return _add_forces(X, s.edges, s.rest0, s.growth, s.stiffness, b.hinges, b.cos0, b.sin0,
                           b.stiffness, s.A, F, self._work)

    def assemble(self, X, blocks: Blocks, part: Part | None = None) -> None:
        """The Hessian at X into ``blocks`` (zeroed first): the solver's layout.
        ``part``: a part of the mesh that no other element touches (a petal): only its
        blocks are zeroed and assembled (the same sums, in the same order), with the
        part's own scratch; the others are left as they are."""
        s, b = self.stretch, self.bending
        if part is None:
            hessian(X, s.edges, s.rest0, s.growth, s.stiffness, b.hinges, b.cos0, b.sin0,
                       b.stiffness, s.A, blocks.data, blocks.edge_slots, blocks.hinge_slots,
                       blocks.work)
            return
        e, h = part.edges, part.hinges
        if part.static is None:
            part.static = (s.edges[e], s.rest0[e], s.growth[e], s.stiffness[e],
                           blocks.edge_slots[e], b.hinges[h], b.stiffness[h],
                           blocks.hinge_slots[h])
        edges, rest0, growth, stiffness, edge_slots, hinges, hinge_k, hinge_slots = part.static
        blocks.data[part.blocks] = 0.0
        if len(e):
            stretch_terms(X, edges, rest0, growth, stiffness, s.A, blocks.data, edge_slots)
        if len(h):
            bending_terms(X, hinges, b.cos0[h], b.sin0[h], hinge_k, blocks.data,
                             hinge_slots, part.work)

    def hessian(self, X, project: bool = False) -> sp.csr_matrix:
        s, b = self.stretch, self.bending
        if self._blocks is None:
            indptr, indices, es, hs_ = block_pattern(s.vertex_count, s.edges, b.hinges)
            self._blocks = Blocks(indptr, indices, es, hs_, np.zeros((len(indices), 3, 3)),
                                     np.zeros((7, 4, 3, 3)))
        self.assemble(X, self._blocks)
        return self._blocks.matrix().tocsr()

    def snapshot(self):
        """What a checkpoint keeps of this term: nothing (its rounding is of X alone)."""
        return None

    def restore(self, saved) -> None:
        pass

    def forget(self) -> None:
        """(Nothing kept from one evaluation to the next: see the shell's.)"""

    def rounding(self, X, per_vertex, fresh: bool = False) -> float:
        """What the force kernel adds and subtracts, per vertex into ``per_vertex``; the
        energy's rounding scale (see :func:`~pipeline.sim.hessian.rounding_scale`)."""
        s, b = self.stretch, self.bending
        return rounding_scale(X, s.edges, s.rest0, s.growth, s.stiffness, b.hinges, b.cos0,
                                 b.sin0, b.stiffness, s.A, per_vertex)
