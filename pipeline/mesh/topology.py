"""Mesh topology over plain arrays: edges, boundaries, hinges, components.

All functions take ``faces (F, 3) int`` (and the vertex count where needed) and return
arrays; they never modify their inputs.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numba import njit


def half_edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Directed edges of every face and the vertex opposite each.

    Returns ``(he (3F, 2), opposite (3F,))``; for face ``(a, b, c)`` the half-edges are
    ``(a, b), (b, c), (c, a)`` with opposite vertices ``c, a, b``.
    """
    f = np.asarray(faces, dtype=np.int64)
    he = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    opposite = np.concatenate([f[:, 2], f[:, 0], f[:, 1]])
    return he, opposite


def unique_edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Undirected edges, each once, sorted.

    Returns ``(edges (E, 2), he_edge (3F,), count (E,))``: edges with ``i < j`` in
    lexicographic order, the edge index of every half-edge, and how many faces use
    each edge (1 on the boundary, 2 inside, more where the mesh is non-manifold).
    """
    he, _ = half_edges(faces)
    if not len(he):
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(
            0, dtype=np.int64)
    # (compiled: a petal's remesh asks this for every change it tries, tens of thousands
    # of times on a branch of blossoms)
    return _unique_edges(np.ascontiguousarray(he))


@njit(cache=True)
def _unique_edges(he):
    """:func:`unique_edges` of the half-edges ``he (3F, 2)``: each edge as one int64,
    ``i n + j`` (sorts as ``(i, j)`` does), sorted stably; the same arrays as
    ``np.unique(code, return_inverse=True, return_counts=True)``."""
    m = he.shape[0]
    n = 0
    for k in range(m):
        n = max(n, he[k, 0] + 1, he[k, 1] + 1)
    code = np.empty(m, dtype=np.int64)
    for k in range(m):
        i, j = he[k, 0], he[k, 1]
        code[k] = min(i, j) * n + max(i, j)
    order = np.argsort(code, kind="mergesort")
    he_edge = np.empty(m, dtype=np.int64)
    uniq = np.empty(m, dtype=np.int64)
    count = np.zeros(m, dtype=np.int64)
    e = -1
    for r in range(m):
        c = code[order[r]]
        if e < 0 or c != uniq[e]:
            e += 1
            uniq[e] = c
        he_edge[order[r]] = e
        count[e] += 1
    edges = np.empty((e + 1, 2), dtype=np.int64)
    for k in range(e + 1):
        edges[k, 0] = uniq[k] // n
        edges[k, 1] = uniq[k] % n
    return edges, he_edge, count[:e + 1].copy()


def boundary_vertices(faces: np.ndarray, vertex_count: int) -> np.ndarray:
    """``(V,) bool``: vertices on an edge used by exactly one face."""
    edges, _, count = unique_edges(faces)
    flag = np.zeros(vertex_count, dtype=bool)
    flag[edges[count == 1].ravel()] = True
    return flag


def interior_pairs(faces: np.ndarray):
    """The two half-edges of every edge used by exactly two faces.

    Returns ``(he, opposite, he_edge, count, a, b)``: the half-edges and opposite
    vertices of :func:`half_edges`, the edge of each half-edge and face count per edge
    (:func:`unique_edges`), and for every interior edge the indices ``a, b`` of its two
    half-edges (``a`` the one listed first).
    """
    he, opposite = half_edges(faces)
    edges, he_edge, count = unique_edges(faces)
    order = np.argsort(he_edge, kind="stable")
    sorted_edge = he_edge[order]
    first = np.flatnonzero(np.r_[True, sorted_edge[1:] != sorted_edge[:-1]])
    interior = count[sorted_edge[first]] == 2
    return he, opposite, he_edge, count, order[first[interior]], order[first[interior] + 1]


def hinges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Interior edges with their two opposite vertices, oriented for the signed angle.

    Returns ``(hinges (H, 4), edge_index (H,))``. Row ``(i, j, k, l)``: the edge ``i-j``,
    ``k`` opposite it in the face that runs ``i -> j``, ``l`` opposite it in the face
    that runs ``j -> i``. ``edge_index`` points into :func:`unique_edges`' edges.

    Notes
    -----
    Needs a consistently oriented, edge-manifold mesh: an interior edge whose two faces
    run the same way, or an edge with more than two faces, raises ``ValueError``.
    """
    he, opposite, he_edge, count, a, b = interior_pairs(faces)
    if np.any(count > 2):
        raise ValueError(f"{int(np.sum(count > 2))} non-manifold edges (used by 3+ faces)")
    if np.any(he[a, 0] != he[b, 1]):
        raise ValueError("inconsistent face orientation (two faces run the same way along an edge)")
    out = np.stack([he[a, 0], he[a, 1], opposite[a], opposite[b]], axis=1)
    return out, he_edge[a]


def components(faces: np.ndarray, vertex_count: int) -> np.ndarray:
    """``(V,) int``: connected-component label of every vertex, numbered by first vertex.
    ``faces`` ``(k, m)``: triangles, or any cells of ``m`` vertices (edges: ``m = 2``)."""
    f = np.ascontiguousarray(faces, dtype=np.int64).reshape(len(faces), -1)
    return _components(f, int(vertex_count))


@njit(cache=True)
def _components(f, vertex_count):
    """:func:`components` (compiled: asked for every petal, and again as each is
    remeshed): union-find over the cells, then each label the rank of its component's
    first vertex."""
    root = np.arange(vertex_count)
    for r in range(f.shape[0]):
        for k in range(f.shape[1]):
            a, b = f[r, k], f[r, (k + 1) % f.shape[1]]
            while root[a] != a:
                root[a] = root[root[a]]
                a = root[a]
            while root[b] != b:
                root[b] = root[root[b]]
                b = root[b]
            if a != b:
                root[max(a, b)] = min(a, b)
    label = np.empty(vertex_count, dtype=np.int64)
    rank = np.full(vertex_count, -1, dtype=np.int64)
    count = 0
    for i in range(vertex_count):
        a = i
        while root[a] != a:
            a = root[a]
        if rank[a] < 0:
            rank[a] = count
            count += 1
        label[i] = rank[a]
    return label


def face_components(faces: np.ndarray) -> np.ndarray:
    """``(F,) int``: the piece of the sheet each face is in, faces joined across the edges
    they share (two pieces that meet at a vertex only are apart), numbered by first
    face."""
    f = np.ascontiguousarray(faces, dtype=np.int64)
    if len(f) == 0:
        return np.zeros(0, dtype=np.int64)
    _, he_edge, _ = unique_edges(f)
    face = np.tile(np.arange(len(f), dtype=np.int64), 3)  # (half-edges run edge-major)
    order = np.argsort(he_edge, kind="stable")
    same = np.flatnonzero(he_edge[order][1:] == he_edge[order][:-1])
    pairs = np.stack([face[order][same], face[order][same + 1]], axis=1)
    return _components(np.ascontiguousarray(pairs), len(f))


def edge_graph(vertices: np.ndarray, edges: np.ndarray) -> sp.csr_matrix:
    """Symmetric sparse matrix of edge lengths, for shortest paths along the mesh."""
    v = np.asarray(vertices, dtype=np.float64)
    length = np.linalg.norm(v[edges[:, 0]] - v[edges[:, 1]], axis=1)
    n = v.shape[0]
    g = sp.coo_matrix((np.r_[length, length], (np.r_[edges[:, 0], edges[:, 1]],
                                               np.r_[edges[:, 1], edges[:, 0]])), shape=(n, n))
    return g.tocsr()


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(n, 3)`` the cross products of the rows of ``a`` and ``b``: np.cross's arithmetic
    (the same bits) without its axis handling, which is most of its time on the small
    arrays of a petal's remesh (a rose bed's 250 petals called it 86,000 times)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(F, 3)`` area-weighted normals (length = 2 x area)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    return cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(V, 3)`` unit normals, area-weighted average of the incident faces."""
    fn = face_normals(vertices, faces)
    vn = np.zeros((len(vertices), 3))
    for c in range(3):
        np.add.at(vn, faces[:, c], fn)
    norm = np.linalg.norm(vn, axis=1, keepdims=True)
    return vn / np.where(norm > 0, norm, 1.0)


def stack(meshes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Meshes ``[(vertices (V_k, 3), faces (F_k, 3)), ...]`` as one: ``(vertices,
    faces, which)``, each mesh's faces shifted by the vertices before it, and ``which
    (V,)`` the index of the mesh each vertex came from."""
    meshes = [(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)) for v, f in meshes]
    if not meshes:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int64)
    counts = np.array([len(v) for v, _ in meshes], dtype=np.int64)
    offsets = np.r_[0, np.cumsum(counts)[:-1]]
    faces = np.vstack([f.reshape(-1, 3) + o for (_, f), o in zip(meshes, offsets, strict=True)])
    return (np.vstack([v.reshape(-1, 3) for v, _ in meshes]), faces,
            np.repeat(np.arange(len(meshes), dtype=np.int64), counts))


def used_vertices(faces: np.ndarray, vertex_count: int) -> tuple[np.ndarray, np.ndarray]:
    """``(used (V,) bool, remap (V,) int)``: the vertices some face holds, and each one's
    index once the others are dropped (``remap[faces]`` are the faces on ``v[used]``)."""
    used = np.zeros(vertex_count, dtype=bool)
    used[np.asarray(faces, dtype=np.int64).ravel()] = True
    return used, np.cumsum(used) - 1


def by_label(label: np.ndarray, count: int) -> list[np.ndarray]:
    """The indices holding each value of ``label`` under ``count``, ascending, in one sort
    (a mask per value would cost values times the array: a branch of a thousand
    blossoms' frames took a minute to stagger so)."""
    label = np.asarray(label)
    order = np.argsort(label, kind="stable")
    bounds = np.searchsorted(label[order], np.arange(count + 1))
    return [order[bounds[k]:bounds[k + 1]] for k in range(count)]


def label_means(points: np.ndarray, label: np.ndarray, count: int) -> np.ndarray:
    """``(count, 3)`` the mean of each label's points (0 for a label with none), in one
    pass over them."""
    n = np.bincount(label, minlength=count).astype(np.float64)
    mean = np.stack([np.bincount(label, weights=points[:, k], minlength=count) for k in range(3)], 1)
    return mean / np.maximum(n, 1.0)[:, None]


def grouped_moments(points: np.ndarray, label: np.ndarray, count: int):
    """Per label, in one pass over the points: ``(n (count,), mean (count, 3), centred
    (N, 3), cov (count, 3, 3), axes (count, 3, 3))``: how many points, their centroid,
    each point less its label's centroid, the scatter matrix and its eigenvectors (columns,
    by ascending eigenvalue)."""
    n = np.bincount(label, minlength=count).astype(np.float64)
    mean = label_means(points, label, count)
    centred = points - mean[label]
    cov = np.empty((count, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            cov[:, a, b] = cov[:, b, a] = np.bincount(label, weights=centred[:, a] * centred[:, b],
                                                      minlength=count)
    _, axes = np.linalg.eigh(cov)
    return n, mean, centred, cov, axes
