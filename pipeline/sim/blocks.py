"""The Hessian's block-sparse layout: one 3x3 block per pair of vertices that share an
element (scipy's BSR layout), and each element's ``slots`` into it, so that assembly is
one pass that allocates nothing. The quasi-static solver and the stable-step estimate
each hold one :class:`Blocks`; :func:`constrain` restricts it to the free directions."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from numba import njit


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


def blocks_matrix(vertex_count, edges, hinges, fill) -> sp.csr_matrix:
    """A (3V, 3V) matrix from 3x3 blocks that ``fill(data, edge_slots, hinge_slots)``
    adds into (the Hessian kernels' layout)."""
    indptr, indices, eslots, hslots = block_pattern(vertex_count, edges, hinges)
    data = np.zeros((len(indices), 3, 3))
    fill(data, eslots, hslots)
    n = 3 * vertex_count
    return sp.bsr_matrix((data, indices, indptr), shape=(n, n)).tocsr()


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
    faces: np.ndarray | None = None  #: a shell's faces in the part (:mod:`pipeline.sim.terms.shell`)


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

    def matrix(self):
        """``data`` as a scipy BSR matrix (a view of the blocks, not a copy)."""

        n = 3 * (len(self.indptr) - 1)
        return sp.bsr_matrix((self.data, self.indices, self.indptr), shape=(n, n))


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
