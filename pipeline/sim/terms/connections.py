"""Connection springs between petals (the paper's Fig. 10, the lily's lock): springs from
an outer petal's rim to the nearest inner petal, each breaking for good past a critical
stretch. The pairs (:class:`Connections`), their forces in the explicit step
(:func:`connection_forces`, which also breaks them), their Hessian blocks
(:func:`connection_blocks`) and their term in the Newton energy (:class:`Springs`;
breaking is the solver's business there)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numba import njit

from pipeline.mesh import topology
from pipeline.mesh.hinge import _edge_vector
from pipeline.sim.terms.spring import _pull, _spring, _spring_block
from pipeline.sim.terms.term import Term


@dataclass
class Connections:
    pairs: np.ndarray  #: (C, 2) vertex pairs, the first on the outer petal's rim
    rest: np.ndarray  #: (C,) rest length (the initial distance)
    limit: np.ndarray  #: (C,) breaking length
    stiffness: float
    alive: np.ndarray  #: (C,) bool, updated by the kernel
    broken_step: np.ndarray  #: (C,) step at which each broke (-1: intact)

    @classmethod
    def build(cls, vertices, faces, petal, pinned, s, layer, *, stiffness: float,
              critical_stretch: float, max_distance: float, min_s: float) -> Connections:
        """Pairs chosen from the bud's geometry: every rim vertex of a petal (past
        ``min_s`` from its base) with the nearest vertex of an inner petal within
        ``max_distance``. A pair breaks when longer than ``critical_stretch`` times its
        rest length (at least one mean edge, so that touching pairs do not snap at once).
        """
        from scipy.spatial import cKDTree

        v = np.asarray(vertices, dtype=np.float64)
        rim = topology.boundary_vertices(faces, len(v)) & ~np.asarray(pinned, bool) & (s > min_s)
        pairs = []
        for p in range(int(petal.max()) + 1):
            inner = np.flatnonzero((layer[petal] < layer[p]) & ~np.asarray(pinned, bool))
            mine = np.flatnonzero(rim & (petal == p))
            if len(inner) == 0 or len(mine) == 0:
                continue
            dist, j = cKDTree(v[inner]).query(v[mine], distance_upper_bound=max_distance)
            ok = np.isfinite(dist)
            pairs += list(zip(mine[ok].tolist(), inner[j[ok]].tolist(), strict=True))
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        rest = np.linalg.norm(v[pairs[:, 0]] - v[pairs[:, 1]], axis=1)
        limit = critical_stretch * np.maximum(rest, 1.0)
        return cls(pairs, rest, limit, float(stiffness), np.ones(len(pairs), dtype=bool),
                   np.full(len(pairs), -1, dtype=np.int64))


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
            _pull(F, i, j, tension / length, dx, dy, dz)
    return energy


@njit(cache=True)
def connection_blocks(X, pairs, rest, k, alive, out):
    """The 3x3 Hessian block ``K`` of each intact connection spring into ``out (C, 3, 3)``
    (the spring adds ``K`` at (i, i) and (j, j), ``-K`` at (i, j) and (j, i))."""
    for c in range(pairs.shape[0]):
        out[c, :, :] = 0.0
        if not alive[c]:
            continue
        dx, dy, dz, length = _edge_vector(X, pairs[c, 0], pairs[c, 1])
        if length <= 0.0:
            continue
        u = (dx / length, dy / length, dz / length)
        along, across = _spring_block(length, rest[c], k)
        for a in range(3):
            for b in range(3):
                out[c, a, b] = along * u[a] * u[b] + (across if a == b else 0.0)


@dataclass
class Springs(Term):
    """The connection springs' energy for Newton: the intact ones of an
    :class:`effects.Connections` (which holds ``alive`` and ``broken_step``)."""

    name = "connections"
    connections: object  #: effects.Connections

    def _live(self):
        c = self.connections
        keep = np.flatnonzero(c.alive)
        return c.pairs[keep, 0], c.pairs[keep, 1], c.rest[keep]

    def forces(self, X, F) -> float:
        """Energy of the intact springs; adds their forces to ``F``."""
        i, j, rest = self._live()
        if len(i) == 0:
            return 0.0
        k = self.connections.stiffness
        d = X[j] - X[i]
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        stretch = length - rest
        f = np.where(length > 0.0, k * stretch / np.where(length > 0.0, length, 1.0), 0.0)
        push = f[:, None] * d
        np.add.at(F, i, push)
        np.subtract.at(F, j, push)
        return float(0.5 * k * np.sum(stretch * stretch))

    def hessian(self, X, project: bool = False) -> sp.csc_matrix | None:
        """Exact Hessian (3V x 3V) of the intact springs at X: per spring ``K`` on the
        (i, i), (j, j) blocks and ``-K`` on (i, j), (j, i), ``K = k [u u^T + (1 - L/l)
        (I - u u^T)]``."""
        i, j, rest = self._live()
        if len(i) == 0:
            return None
        k = self.connections.stiffness
        d = X[j] - X[i]
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        safe = np.where(length > 0.0, length, 1.0)
        u = d / safe[:, None]
        uu = u[:, :, None] * u[:, None, :]
        across = k * (1.0 - rest / safe)
        K = (k - across)[:, None, None] * uu + across[:, None, None] * np.eye(3)[None]
        K[length <= 0.0] = 0.0
        rows, cols, vals = [], [], []
        a3 = np.arange(3)
        for p, q, sign in ((i, i, 1.0), (j, j, 1.0), (i, j, -1.0), (j, i, -1.0)):
            rows.append((3 * p[:, None, None] + a3[None, :, None]).repeat(3, axis=2))
            cols.append((3 * q[:, None, None] + a3[None, None, :]).repeat(3, axis=1))
            vals.append(sign * K)
        n = 3 * len(X)
        return sp.coo_matrix((np.concatenate(vals).ravel(),
                              (np.concatenate(rows).ravel(), np.concatenate(cols).ravel())),
                             shape=(n, n)).tocsc()

    def over_limit(self, X) -> np.ndarray:
        """Indices of the intact springs longer than their breaking length at X."""
        c = self.connections
        d = X[c.pairs[:, 1]] - X[c.pairs[:, 0]]
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        return np.flatnonzero(c.alive & (length > c.limit))

    def scale(self, X, per_vertex) -> None:
        """Add the size of each vertex's spring forces to ``per_vertex`` (rounding)."""
        i, j, rest = self._live()
        if len(i) == 0:
            return
        k = self.connections.stiffness
        d = X[j] - X[i]
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        term = k * (length + rest + np.abs(X[i]).max(axis=1) + np.abs(X[j]).max(axis=1))
        np.add.at(per_vertex, i, term)
        np.add.at(per_vertex, j, term)
