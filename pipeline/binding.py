"""Binding a mesh to the simulated sheet, and deforming it by the sheet's frames.

As Blender's Surface Deform and Houdini's Point Deform bind: each point of the user's
mesh is bound to the sheet's rest mesh by its closest point there (a triangle and
barycentric coordinates) and its offset from that point in the sheet's local frame. A
frame of the sheet moves the closest point with its triangle and turns the offset
with the frame, so a thick petal's two sides stay as far apart as they were, and a
point off the sheet's rim stays where it was relative to the rim.

The local frame at a point of a triangle: the normal is the barycentric blend of the
sheet's vertex normals (area-weighted), so it turns continuously from one triangle to
the next (no pop where two neighbouring points are bound to different triangles); the
first tangent is the triangle's first edge with its normal part removed; the second
completes the right-handed frame.

Notes
-----
Deforming the rest sheet gives every point back where it was (up to rounding): the
binding is exact at rest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .topology import vertex_normals

#: points are bound in chunks of this many (bounds the memory of the candidate pairs)
CHUNK = 4096


@dataclass
class Binding:
    face: np.ndarray  #: (n,) int64 the sheet triangle each point is bound to
    bary: np.ndarray  #: (n, 3) barycentric coordinates of its closest point there
    offset: np.ndarray  #: (n, 3) from the closest point, in the local frame (t1, t2, n)


def closest_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """``(n, 3)`` barycentric coordinates of the point of triangle ``a, b, c`` (each
    ``(n, 3)``) closest to ``p`` (Ericson, Real-Time Collision Detection, 5.1.5), for
    each row. A degenerate triangle gives one of its closest corners or edges."""
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    n = len(p)
    out = np.zeros((n, 3))
    done = np.zeros(n, dtype=bool)

    def take(mask, u, v, w):
        m = mask & ~done
        out[m, 0], out[m, 1], out[m, 2] = u[m], v[m], w[m]
        done[m] = True

    zero, one = np.zeros(n), np.ones(n)
    with np.errstate(divide="ignore", invalid="ignore"):
        take((d1 <= 0) & (d2 <= 0), one, zero, zero)  # vertex a
        take((d3 >= 0) & (d4 <= d3), zero, one, zero)  # vertex b
        t = d1 / (d1 - d3)
        take((vc <= 0) & (d1 >= 0) & (d3 <= 0), 1 - t, t, zero)  # edge ab
        take((d6 >= 0) & (d5 <= d6), zero, zero, one)  # vertex c
        t = d2 / (d2 - d6)
        take((vb <= 0) & (d2 >= 0) & (d6 <= 0), 1 - t, zero, t)  # edge ac
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        take((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), zero, 1 - t, t)  # edge bc
        denom = va + vb + vc
        v, w = vb / denom, vc / denom
        take(np.ones(n, dtype=bool), 1 - v - w, v, w)  # inside
    bad = ~np.all(np.isfinite(out), axis=1)  # a degenerate triangle: its nearest corner
    if bad.any():
        corners = np.stack([a[bad], b[bad], c[bad]], axis=1)
        k = np.argmin(np.linalg.norm(corners - p[bad, None], axis=2), axis=1)
        out[bad] = np.eye(3)[k]
    return out


def closest_points(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                   allowed: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """For each point, the closest point on the triangles ``faces`` (only those where
    ``allowed``, a ``(F,) bool``): ``(face (n,), bary (n, 3))``. Ties go to the lower
    face index, so the answer does not depend on the search's order.

    Exact: the closest vertex is at distance d0, so the closest point lies in a
    triangle with a vertex within ``d0 + longest edge`` of the point; all of those are
    measured."""
    from scipy.spatial import cKDTree

    P = np.asarray(points, dtype=np.float64)
    X = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    ids = np.flatnonzero(np.ones(len(F), dtype=bool) if allowed is None else allowed)
    if len(ids) == 0:
        raise ValueError("no triangles to bind to")
    used = np.unique(F[ids])
    tree = cKDTree(X[used])
    longest = float(np.max(np.linalg.norm(X[F[ids]] - X[F[ids][:, [1, 2, 0]]], axis=2)))
    incident = [[] for _ in range(len(X))]
    for f in ids.tolist():
        for k in F[f].tolist():
            incident[k].append(f)
    face = np.empty(len(P), dtype=np.int64)
    bary = np.empty((len(P), 3))
    for lo in range(0, len(P), CHUNK):
        q = P[lo:lo + CHUNK]
        d0, _ = tree.query(q)
        near = tree.query_ball_point(q, d0 * (1 + 1e-9) + longest + 1e-12)
        rows, cand = [], []
        for r, vs in enumerate(near):
            fs = sorted({f for k in vs for f in incident[used[k]]})
            rows += [r] * len(fs)
            cand += fs
        rows, cand = np.asarray(rows, dtype=np.int64), np.asarray(cand, dtype=np.int64)
        tri = X[F[cand]]
        b = closest_on_triangles(q[rows], tri[:, 0], tri[:, 1], tri[:, 2])
        dist = np.linalg.norm(np.einsum("ij,ijk->ik", b, tri) - q[rows], axis=1)
        order = np.lexsort((cand, dist, rows))  # per row: nearest first, then lowest face
        first = order[np.r_[True, rows[order][1:] != rows[order][:-1]]]
        face[lo + rows[first]] = cand[first]
        bary[lo + rows[first]] = b[first]
    return face, bary


def local_frames(vertices: np.ndarray, faces: np.ndarray, face: np.ndarray, bary: np.ndarray,
                 normals: np.ndarray | None = None) -> np.ndarray:
    """``(n, 3, 3)`` rows t1, t2, n of the local frame at each bound point (see the module
    notes); ``normals`` are the sheet's vertex normals (computed if not given)."""
    X = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    if normals is None:
        normals = vertex_normals(X, F)
    tri = F[face]
    n = np.einsum("ij,ijk->ik", bary, normals[tri])
    fn = np.cross(X[tri[:, 1]] - X[tri[:, 0]], X[tri[:, 2]] - X[tri[:, 0]])
    weak = np.linalg.norm(n, axis=1) < 1e-6  # normals cancel (a fold): the triangle's own
    n[weak] = fn[weak]
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    e = X[tri[:, 1]] - X[tri[:, 0]]
    t1 = e - n * np.einsum("ij,ij->i", e, n)[:, None]
    t1 /= np.maximum(np.linalg.norm(t1, axis=1, keepdims=True), 1e-300)
    t2 = np.cross(n, t1)
    return np.stack([t1, t2, n], axis=1)


def bind(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
         allowed: np.ndarray | None = None) -> Binding:
    """Bind ``points`` to the sheet ``vertices, faces`` (its triangles where ``allowed``)."""
    face, bary = closest_points(points, vertices, faces, allowed)
    X = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    on = np.einsum("ij,ijk->ik", bary, X[F[face]])
    frames = local_frames(X, F, face, bary)
    offset = np.einsum("ikj,ij->ik", frames, np.asarray(points, dtype=np.float64) - on)
    return Binding(face, bary, offset)


def deform(vertices: np.ndarray, faces: np.ndarray, binding: Binding,
           normals: np.ndarray | None = None) -> np.ndarray:
    """``(n, 3)`` the bound points on the sheet posed at ``vertices``."""
    X = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    on = np.einsum("ij,ijk->ik", binding.bary, X[F[binding.face]])
    frames = local_frames(X, F, binding.face, binding.bary, normals)
    return on + np.einsum("ikj,ik->ij", frames, binding.offset)


def rotations(vertices: np.ndarray, faces: np.ndarray, binding: Binding, rest_frames: np.ndarray,
              normals: np.ndarray | None = None) -> np.ndarray:
    """``(n, 3, 3)`` the rotation that takes each bound point's rest frame to its frame on
    the sheet posed at ``vertices`` (to turn the input's own normals with it)."""
    frames = local_frames(vertices, faces, binding.face, binding.bary, normals)
    return np.einsum("nki,nkj->nij", frames, rest_frames)


BIND_GROUP = "bind"


def bind_parts(asset, scale: float, vertices: np.ndarray, faces: np.ndarray,
               vertex_part: np.ndarray) -> dict[int, Binding]:
    """Bind each part of ``asset`` (:class:`pipeline.userasset.Asset`, input units) that
    has sheet vertices (``vertex_part``: the input part of each sheet vertex) to its own
    sheet triangles (mesh units: the input times ``scale``). Parts without a sheet (not
    petals) get no binding: they stay where they are."""
    F = np.asarray(faces, dtype=np.int64)
    face_part = np.asarray(vertex_part)[F[:, 0]] if len(F) else np.zeros(0, dtype=np.int64)
    face_piece = _pieces(len(vertices), F)[F[:, 0]] if len(F) else np.zeros(0, dtype=np.int64)
    out = {}
    for i, part in enumerate(asset.parts):
        allowed = face_part == i
        if allowed.any():
            points = np.asarray(part.points) * scale
            b = bind(points, vertices, F, allowed)
            _keep_to_own_petal(b, points, part.triangles(), vertices, F, allowed, face_piece)
            out[i] = b
    return out


def _pieces(count: int, triangles: np.ndarray) -> np.ndarray:
    """``(count,)`` connected piece of each vertex of a triangle mesh."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    T = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    graph = sp.coo_matrix((np.ones(2 * len(T)), (T[:, [0, 1]].ravel(), T[:, [1, 2]].ravel())),
                          shape=(count, count))
    return connected_components(graph, directed=False)[1]


def _keep_to_own_petal(b: Binding, points, triangles, vertices, faces, allowed,
                       face_piece) -> None:
    """Where most of a connected piece of the input is bound to one sheet petal, bind
    all of it to that petal (in place): a piece is one petal's surface (both sides of a
    thick one), and its points that lay closer to another petal, where petals overlap
    or meet at the hub, would otherwise follow that petal through the bloom and tear
    the surface. A piece no petal has most of (a sheet that was several petals, split
    by remesh) keeps each point's closest petal."""
    piece = _pieces(len(points), triangles)
    petal_of = face_piece[b.face]
    for c in np.unique(piece):
        idx = np.flatnonzero(piece == c)
        values, counts = np.unique(petal_of[idx], return_counts=True)
        main = values[np.argmax(counts)]
        if len(values) == 1 or 2 * counts.max() <= len(idx):
            continue
        stray = idx[petal_of[idx] != main]
        again = bind(points[stray], vertices, faces, allowed & (face_piece == main))
        b.face[stray], b.bary[stray], b.offset[stray] = again.face, again.bary, again.offset


def write_bindings(h5, bindings: dict[int, Binding]) -> None:
    """Store bindings under ``bind/<part>/`` (see :func:`read_bindings`)."""
    from .artifact import put

    group = h5.require_group(BIND_GROUP)
    group.attrs["doc"] = ("per input part that is a petal: its points (input/asset/<i>/points) "
                          "bound to the sheet's rest mesh (mesh/vertices, mesh/faces)")
    for i, b in sorted(bindings.items()):
        put(h5, f"{BIND_GROUP}/{i}/face", b.face, "(n,) sheet triangle (row of mesh/faces)")
        put(h5, f"{BIND_GROUP}/{i}/bary", b.bary, "(n, 3) barycentric coordinates of the closest point")
        put(h5, f"{BIND_GROUP}/{i}/offset", b.offset,
            "(n, 3) offset from it in the local frame (tangent, tangent, normal), mesh units")


def read_bindings(src) -> dict[int, Binding]:
    f = getattr(src, "file", src)
    if BIND_GROUP not in f:
        return {}
    return {int(k): Binding(g["face"][()], g["bary"][()], g["offset"][()])
            for k, g in f[BIND_GROUP].items()}


#: a point faces the other side across the sheet when its distance to it at rest is the
#: sum of the two offsets within this fraction, and their places on the sheet are closer
#: than this fraction of that distance
ACROSS = 0.2


def two_sided(points: np.ndarray, triangles: np.ndarray, b: Binding, sheet: np.ndarray,
              sheet_faces: np.ndarray, scale: float) -> np.ndarray:
    """Indices of a part's points that measure its thickness: on the sheet's positive
    side, bound inside a sheet triangle (:func:`interior`), and facing the part's
    negative side across the sheet at rest: the nearest point there is as far as the two
    offsets added (within ``ACROSS``) and lies over the same place of the sheet
    (``sheet``: its rest vertices, in the points' units; ``scale``: mesh units per
    those, the offsets' unit). A solidified petal's points are; a one-sided sheet's are not
    (its offsets are small and its nearest other faces lie beside it, not across), nor
    a hem's or a fold's. Empty: the part has no thickness to measure."""
    P = np.asarray(points, dtype=np.float64)
    T = np.asarray(triangles, dtype=np.int64)
    o = np.asarray(b.offset[:, 2], dtype=np.float64) / scale
    up = o > 0.0
    down_faces = np.all(~up[T], axis=1)
    mine = np.flatnonzero(up & interior(b))
    if len(mine) == 0 or not down_faces.any():
        return mine
    S, SF = np.asarray(sheet, dtype=np.float64), np.asarray(sheet_faces, dtype=np.int64)
    on = np.einsum("ij,ijk->ik", b.bary, S[SF[b.face]])  # each point's place on the sheet
    face, bary = closest_points(P[mine], P, T, down_faces)
    distance = np.linalg.norm(np.einsum("ij,ijk->ik", bary, P[T[face]]) - P[mine], axis=1)
    across = o[mine] - np.einsum("ij,ij->i", bary, o[T[face]])
    apart = np.linalg.norm(np.einsum("ij,ijk->ik", bary, on[T[face]]) - on[mine], axis=1)
    keep = ((across > 0.0) & (np.abs(distance - across) <= ACROSS * across)
            & (apart <= ACROSS * distance))
    return mine[keep]


def thickness(points: np.ndarray, triangles: np.ndarray, offset_normal: np.ndarray,
              which: np.ndarray) -> np.ndarray:
    """``(k,)`` a thick part's thickness at its points ``which`` (:func:`two_sided`):
    each one's distance to the nearest point of the part's negative side (its triangles
    with every corner on that side, by the sign of ``offset_normal``)."""
    P = np.asarray(points, dtype=np.float64)
    T = np.asarray(triangles, dtype=np.int64)
    down_faces = np.all(~(np.asarray(offset_normal) > 0.0)[T], axis=1)
    if len(which) == 0:
        return np.zeros(0)
    face, bary = closest_points(P[which], P, T, down_faces)
    return np.linalg.norm(np.einsum("ij,ijk->ik", bary, P[T[face]]) - P[which], axis=1)


def interior(b: Binding, margin: float = 1e-6) -> np.ndarray:
    """``(n,) bool``: points bound inside their triangle (their offset is along the normal
    only), not clamped to the sheet's rim."""
    return np.all(b.bary > margin, axis=1)
