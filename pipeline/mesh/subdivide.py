"""A mesh cut finer with its own vertices kept: :func:`subdivide`.

Each triangle is cut in four at its edges' midpoints (the old vertices first, with their
indices, then one new vertex per edge), and each new vertex is lifted off the chord onto
the smooth surface through the old ones: the midpoint of the cubic that leaves each end
along that end's tangent plane (the edge curves of PN triangles, Vlachos et al. 2001),
``(a + b) / 2 - ((b - a).n_a n_a + (a - b).n_b n_b) / 8``, with angle-weighted vertex
normals (the six-petal bud at 50 vertices per petal 0.97 deg from its finest against
1.04 with area-weighted ones). On a circle this is the arc's midpoint to second order
(the chord's sagitta ``L^2 / 8R``), so a cupped petal stays cupped, where plain
midpoints would leave its facets flat.
"""

from __future__ import annotations

import numpy as np
import trimesh

from pipeline.mesh import topology


def subdivide(vertices: np.ndarray, faces: np.ndarray):
    """One 1:4 subdivision with the new vertices on the smooth surface.

    Returns ``(vertices (V + E, 3), faces (4F, 3), parent (E, 2))``: the old vertices
    first (the same indices), then one vertex per edge of ``faces`` (``parent``: its
    edge's two ends, ``i < j``); each face's four children keep its orientation, the
    middle one last."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    edges, he_edge, _ = topology.unique_edges(f)
    tri = trimesh.Trimesh(v, f, process=False)
    n = trimesh.geometry.weighted_vertex_normals(len(v), f, tri.face_normals, tri.face_angles)
    a, b = v[edges[:, 0]], v[edges[:, 1]]
    na, nb = n[edges[:, 0]], n[edges[:, 1]]
    lift = (np.einsum("ij,ij->i", b - a, na)[:, None] * na
            + np.einsum("ij,ij->i", a - b, nb)[:, None] * nb)
    mid = 0.5 * (a + b) - lift / 8.0
    count = len(f)
    m = len(v) + he_edge  # the new vertex on each half-edge: (a, b), (b, c), (c, a)
    ab, bc, ca = m[:count], m[count:2 * count], m[2 * count:]
    p, q, r = f[:, 0], f[:, 1], f[:, 2]
    children = np.concatenate([np.stack([p, ab, ca], axis=1), np.stack([ab, q, bc], axis=1),
                               np.stack([ca, bc, r], axis=1), np.stack([ab, bc, ca], axis=1)])
    return np.concatenate([v, mid]), children, edges

