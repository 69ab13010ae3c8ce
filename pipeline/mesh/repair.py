"""Repairs of what modelling tools commonly leave in a sheet: edges shared by three or
more faces (a rib or a fin modelled onto a petal, petals welded along a seam) and
vertices where separate fans of faces meet (petals touching at a point, the centre of
a flower whose petals share one vertex).

Small functions over ``(V, 3)`` vertex and ``(F, 3)`` face arrays, as gpytoolbox's.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from pipeline.mesh import clean, topology
from pipeline.mesh.remesh import boundary_loops


def corner_fans(faces: np.ndarray) -> np.ndarray:
    """``(3F,)`` fan label of each face corner (corner ``k F + i`` is vertex ``k`` of face
    ``i``): two corners at the same vertex are in one fan when their faces are linked
    through a chain of edges with exactly two faces around that vertex. A vertex of a
    manifold sheet has one fan; a bowtie vertex has two or more."""
    f = np.asarray(faces, dtype=np.int64)
    m = len(f)
    if m == 0:
        return np.zeros(0, dtype=np.int64)
    he, _ = topology.half_edges(f)
    _, he_edge, count = topology.unique_edges(f)
    order = np.argsort(he_edge, kind="stable")
    se = he_edge[order]
    first = np.flatnonzero(np.r_[True, se[1:] != se[:-1]])
    pair = count[se[first]] == 2
    a, b = order[first[pair]], order[first[pair] + 1]
    face_a, face_b = a % m, b % m
    links = []
    for end in (0, 1):
        vert = he[a, end]
        ka = np.argmax(f[face_a] == vert[:, None], axis=1)
        kb = np.argmax(f[face_b] == vert[:, None], axis=1)
        links.append(np.stack([ka * m + face_a, kb * m + face_b], axis=1))
    link = np.concatenate(links)
    g = sp.coo_matrix((np.ones(len(link)), (link[:, 0], link[:, 1])), shape=(3 * m, 3 * m))
    return connected_components(g, directed=False)[1]


def split_fans(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Give every fan of a vertex its own copy of the vertex, so that pieces that touch
    only at vertices come apart. Returns ``(vertices, faces, copies made)``; a vertex
    keeps its index for its first fan (in face order), copies are appended in order."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    m = len(f)
    if m == 0:
        return v, f, 0
    fan = corner_fans(f)
    corner_vertex = f.T.ravel()
    # corners in face order (face i's corners before face i+1's), so the first fan met
    # keeps the index
    order = np.lexsort((np.arange(3 * m) // m, np.arange(3 * m) % m))
    pairs, first = np.unique(np.stack([corner_vertex[order], fan[order]], axis=1), axis=0,
                             return_index=True)
    pairs = pairs[np.argsort(first, kind="stable")]
    seen = np.zeros(len(v), dtype=bool)
    new_index = {}
    extra = []
    for vert, label in pairs.tolist():
        if not seen[vert]:
            seen[vert] = True
            new_index[(vert, label)] = vert
        else:
            new_index[(vert, label)] = len(v) + len(extra)
            extra.append(vert)
    if not extra:
        return v, f, 0
    out = np.array([new_index[(a, b)] for a, b in zip(corner_vertex.tolist(), fan.tolist(),
                                                        strict=True)])
    return np.vstack([v, v[extra]]), out.reshape(3, m).T.copy(), len(extra)


def _wings(v: np.ndarray, f: np.ndarray, a: int, b: int, around: list[int]) -> np.ndarray:
    """Unit direction from edge ``(a, b)`` into each face of ``around``, across the edge."""
    e = v[b] - v[a]
    e = e / max(np.linalg.norm(e), 1e-300)
    out = []
    for t in around:
        (o,) = [x for x in f[t].tolist() if x not in (a, b)]
        w = v[o] - v[a]
        w = w - (w @ e) * e
        out.append(w / max(np.linalg.norm(w), 1e-300))
    return np.array(out)


def resolve_nonmanifold_edges(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, int]:
    """Drop faces until no edge has more than two: at an edge with three or more, the
    two faces through which the surface goes on most nearly straight (their directions
    across the edge most nearly opposite) stay, the others (a fin, a rib's wall, a
    second sheet welded on) go. Returns ``(faces, faces dropped)``; faces keep their
    order."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    keep = np.ones(len(f), dtype=bool)
    for _ in range(len(f)):
        idx = np.flatnonzero(keep)
        sub = f[idx]
        edges, he_edge, count = topology.unique_edges(sub)
        bad = np.flatnonzero(count > 2)
        if len(bad) == 0:
            break
        m = len(sub)
        around: dict[int, list[int]] = {}
        for k in np.flatnonzero(np.isin(he_edge, bad)).tolist():
            around.setdefault(int(he_edge[k]), []).append(k % m)
        dropped_now = False
        for e in sorted(around):
            faces_e = sorted(t for t in around[e] if keep[idx[t]])
            if len(faces_e) <= 2:
                continue
            a, b = edges[e]
            w = _wings(v, sub, int(a), int(b), faces_e)
            c = w @ w.T
            c[np.tril_indices(len(faces_e))] = np.inf
            i, j = np.unravel_index(np.argmin(c), c.shape)
            for k, t in enumerate(faces_e):
                if k not in (i, j):
                    keep[idx[t]] = False
                    dropped_now = True
        if not dropped_now:
            break
    return f[keep], int(np.sum(~keep))


def _fans_at(faces: np.ndarray, vertex: int) -> int:
    """How many separate fans of faces meet at ``vertex`` (1 on a sound sheet)."""
    around = faces[np.any(faces == vertex, axis=1)]
    if len(around) == 0:
        return 0
    fan = corner_fans(around)
    corner = around.T.ravel() == vertex
    return len(np.unique(fan[corner]))


#: rim vertices closer than this times the sheet's mean edge, two steps apart along the
#: rim, are the two lips of a slit
ZIP = 0.05


def zip_slits(vertices: np.ndarray, faces: np.ndarray, tolerance: float | None = None):
    """Close slits: where the rim runs into the sheet and straight back out (a sliver
    dropped between two sides of a mid-surface, an unwelded seam ending inside a
    sheet), the two lips' rim vertices next to the slit's end are merged, and again,
    until the lips part by more than ``tolerance`` (default :data:`ZIP` times the mean
    edge). The slit's end becomes an inside vertex. A merge that would make an edge of
    three faces, or a vertex where two fans of faces meet (a pinch), is not made.
    Returns ``(vertices, faces, vertices merged)``; vertices keep their order, merged ones
    are dropped."""

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).copy()
    if len(f) == 0:
        return v, f, 0
    tol = ZIP * clean.mean_edge_length(v, f) if tolerance is None else float(tolerance)
    refused: set[tuple[int, int]] = set()
    merged = 0
    for _ in range(len(v)):
        found = None
        for loop in boundary_loops(f):
            if len(loop) < 4:
                continue
            a, b = loop, np.roll(loop, -2)
            gap = np.linalg.norm(v[a] - v[b], axis=1)
            for k in np.argsort(gap, kind="stable").tolist():
                if gap[k] >= tol:
                    break
                pair = (int(min(a[k], b[k])), int(max(a[k], b[k])))
                if pair not in refused:
                    found = pair
                    break
            if found:
                break
        if found is None:
            break
        keep, gone = found
        g = np.where(f == gone, keep, f)
        g = g[(g[:, 0] != g[:, 1]) & (g[:, 1] != g[:, 2]) & (g[:, 2] != g[:, 0])]
        _, _, count = topology.unique_edges(g)
        if len(g) == 0 or np.any(count > 2) or _fans_at(g, keep) > 1:
            refused.add(found)
            continue
        f = g
        merged += 1
    used = np.zeros(len(v), dtype=bool)
    used[f.ravel()] = True
    remap = np.cumsum(used) - 1
    return v[used], remap[f], merged


def manifold_fans(faces: np.ndarray, vertex_count: int) -> np.ndarray:
    """(F,) bool: faces to keep so that every vertex has a single fan (no bowties).

    At a vertex where faces meet only at that vertex, the fan of largest face count is
    kept (ties: the one with the lowest face index).
    """
    nf = len(faces)
    keep = np.ones(nf, dtype=bool)
    for _ in range(10):
        idx = np.flatnonzero(keep)
        f = faces[idx]
        corner_vertex = f.T.ravel()  # corner k*nf' + i: vertex k of face i
        m = len(f)
        fan = corner_fans(f)
        fans_per_vertex = np.zeros(vertex_count, dtype=np.int64)
        uniq = np.unique(np.stack([corner_vertex, fan], axis=1), axis=0)
        np.add.at(fans_per_vertex, uniq[:, 0], 1)
        bad_vertices = np.flatnonzero(fans_per_vertex > 1)
        if bad_vertices.size == 0:
            break
        fan_size = np.bincount(fan, minlength=3 * m)
        for vert in bad_vertices:
            corners = np.flatnonzero(corner_vertex == vert)
            fans = fan[corners]
            # the largest fan wins; among equals the one whose first corner comes first
            best = fans[np.lexsort((corners % m, -fan_size[fans]))[0]]
            keep[idx[corners[fans != best] % m]] = False
    return keep
