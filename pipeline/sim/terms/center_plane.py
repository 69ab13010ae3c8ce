"""The center-plane constraint (the paper's Fig. 6): the free vertices on a petal's axis
keep their distance to its center plane, so asymmetric topology cannot skew its tip."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit


@dataclass
class CenterPlane:
    """Axis vertices keep their distance to their petal's center plane: no motion along
    its normal (a constraint: :meth:`project` takes that direction away; the explicit
    step projects forces with :func:`project_out_normals`)."""

    name = "center_plane"
    vertices: np.ndarray  #: (C,) constrained vertices (axis vertices that are not pinned)
    normals: np.ndarray  #: (C, 3) unit normal of each one's center plane
    height: np.ndarray  #: (C,) each one's distance along its normal at the start

    @classmethod
    def build(cls, positions, on_axis, pinned, petal, plane) -> CenterPlane:
        idx = np.flatnonzero(np.asarray(on_axis, bool) & ~np.asarray(pinned, bool))
        normals = np.asarray(plane, dtype=np.float64)[np.asarray(petal)[idx], :3]
        normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
        height = np.einsum("ij,ij->i", np.asarray(positions)[idx], normals)
        return cls(idx.astype(np.int64), np.ascontiguousarray(normals), height)

    def drift(self, positions) -> float:
        """Largest change of a constrained vertex's distance to its plane (should be ~0)."""
        if len(self.vertices) == 0:
            return 0.0
        now = np.einsum("ij,ij->i", np.asarray(positions)[self.vertices], self.normals)
        return float(np.abs(now - self.height).max())

    def project(self, vec) -> None:
        if len(self.vertices):
            v, n = self.vertices, self.normals
            vec[v] -= np.einsum("ij,ij->i", vec[v], n)[:, None] * n


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
