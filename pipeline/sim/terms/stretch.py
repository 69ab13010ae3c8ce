"""Stretch (Eq. 2, 6): a spring on every edge, ``1/2 K_s (l - L)^2`` with the rest length
``L = L0 (1 + A(t) alpha)`` growing with the growth A(t) (Eq. 6; the wrinkles of Eq. 12
are in alpha and K_s of the boundary edges). Forces (:func:`stretch_forces`), the Hessian
(:func:`stretch_terms`: each spring's block, :func:`pipeline.sim.terms.spring._spring_block`)
and the term (:class:`Stretch`)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numba import njit

from pipeline.mesh.hinge import _edge_vector, _vertex
from pipeline.sim.blocks import blocks_matrix
from pipeline.sim.terms.spring import _pull, _spring, _spring_block
from pipeline.sim.terms.term import Term


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
            _pull(F, i, j, tension / length, dx, dy, dz)
    return energy


@njit(cache=True, nogil=True)
def stretch_forces(X, edges, rest0, growth, stiffness, A, F):
    """Add the stretch forces of every edge to ``F``; return the stretch energy (Eq. 2)."""
    return _stretch_range(X, edges, rest0, growth, stiffness, A, F, 0, edges.shape[0])


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
        along, across = _spring_block(length, rest, k)
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


class Stretch(Term):
    """Springs on the edges (Eq. 2): ``1/2 k (l - L)^2``, ``L = L0 (1 + A alpha)`` (Eq. 6)."""

    name = "stretch"

    def __init__(self, edges, rest0, growth, stiffness, vertex_count: int):
        self.edges, self.rest0, self.growth, self.stiffness = edges, rest0, growth, stiffness
        self.vertex_count, self.A = vertex_count, 0.0

    @classmethod
    def of(cls, model) -> Stretch:
        return cls(model.edge_indices, model.edge_rest_length, model.edge_growth,
                   model.edge_stiffness, model.vertex_count)

    def at(self, growth: float) -> Stretch:
        self.A = float(growth)
        return self

    def forces(self, X, F) -> float:
        return stretch_forces(X, self.edges, self.rest0, self.growth, self.stiffness, self.A, F)

    def hessian(self, X, project: bool = False) -> sp.csr_matrix:
        return blocks_matrix(
            self.vertex_count, self.edges, np.zeros((0, 4), dtype=np.int64),
            lambda data, es, hs_: stretch_terms(X, self.edges, self.rest0, self.growth,
                                                   self.stiffness, self.A, data, es))
