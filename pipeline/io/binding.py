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
import scipy.sparse as sp

from pipeline.artifact import put
from pipeline.mesh.nearest import closest_points, nearest_among
from pipeline.mesh.topology import components, label_means, vertex_normals


@dataclass
class Binding:
    """A part's points bound to the sheet. A point with ``face`` -1 stays where it is (a
    piece of a petal's part that is no petal: the leaves and stem modelled in one mesh
    with the flower); its ``offset`` is then its place (mesh units)."""

    face: np.ndarray  #: (n,) int64 the sheet triangle each point is bound to (-1: it stays)
    bary: np.ndarray  #: (n, 3) barycentric coordinates of its closest point there
    offset: np.ndarray  #: (n, 3) from the closest point, in the local frame (t1, t2, n)


def local_frames(vertices: np.ndarray, faces: np.ndarray, face: np.ndarray, bary: np.ndarray,
                 normals: np.ndarray | None = None) -> np.ndarray:
    """``(n, 3, 3)`` rows t1, t2, n of the local frame at each bound point (see the module
    notes); ``normals`` are the sheet's vertex normals (computed if not given)."""
    X = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    if normals is None:
        normals = vertex_normals(X, F)
    stays = np.asarray(face) < 0  # (a point that stays: the identity frame, below)
    if stays.any():
        face, bary = np.where(stays, 0, face), np.where(stays[:, None], 1.0 / 3.0, bary)
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
    frames = np.stack([t1, t2, n], axis=1)
    frames[stays] = np.eye(3)
    return frames


def bind(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
         allowed: np.ndarray | None = None, normals: np.ndarray | None = None) -> Binding:
    """Bind ``points`` to the sheet ``vertices, faces`` (its triangles where ``allowed``);
    ``normals``: the sheet's vertex normals, if the caller has them (computed if not)."""
    face, bary = closest_points(points, vertices, faces, allowed)
    X = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    on = np.einsum("ij,ijk->ik", bary, X[F[face]])
    frames = local_frames(X, F, face, bary, normals)
    offset = np.einsum("ikj,ij->ik", frames, np.asarray(points, dtype=np.float64) - on)
    return Binding(face, bary, offset)


def deform(vertices: np.ndarray, faces: np.ndarray, binding: Binding,
           normals: np.ndarray | None = None) -> np.ndarray:
    """``(n, 3)`` the bound points on the sheet posed at ``vertices``."""
    X = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    on = np.einsum("ij,ijk->ik", binding.bary, X[F[binding.face]])
    frames = local_frames(X, F, binding.face, binding.bary, normals)
    out = on + np.einsum("ikj,ik->ij", frames, binding.offset)
    stays = binding.face < 0
    out[stays] = binding.offset[stays]
    return out


def rotations(vertices: np.ndarray, faces: np.ndarray, binding: Binding, rest_frames: np.ndarray,
              normals: np.ndarray | None = None) -> np.ndarray:
    """``(n, 3, 3)`` the rotation that takes each bound point's rest frame to its frame on
    the sheet posed at ``vertices`` (to turn the input's own normals with it)."""
    frames = local_frames(vertices, faces, binding.face, binding.bary, normals)
    return np.einsum("nki,nkj->nij", frames, rest_frames)


BIND_GROUP = "bind"


def bind_parts(asset, scale: float, vertices: np.ndarray, faces: np.ndarray,
               vertex_part: np.ndarray, kept: dict | None = None,
               unpicked: dict | None = None) -> dict[int, Binding]:
    """Bind each part of ``asset`` (:class:`pipeline.io.userasset.Asset`, input units) that
    has sheet vertices (``vertex_part``: the input part of each sheet vertex) to its own
    sheet triangles (mesh units: the input times ``scale``). Parts without a sheet (not
    petals) get no binding: they stay where they are; so do the pieces of a petal's part
    that are no petal (``kept``: part -> ``(vertices, faces)`` of those pieces, input
    units, as remesh keeps them): a piece of the part's mesh whose points are mostly
    theirs stays (``face`` -1), where bound to the nearest petal it would follow it
    through the bloom (a tulip's leaves, crumpling with its petals); and the pieces nearer
    the petal sheets ``scene.flower`` left out than the sheet they are bound to
    (``unpicked``: part -> ``(vertices, faces)``, input units; the other roses of a rose
    bed's one petal mesh, which bound to the picked rose swung with it across the
    picture)."""
    F = np.asarray(faces, dtype=np.int64)
    face_part = np.asarray(vertex_part)[F[:, 0]] if len(F) else np.zeros(0, dtype=np.int64)
    face_piece = components(F, len(vertices))[F[:, 0]] if len(F) else np.zeros(0, dtype=np.int64)
    # the sheet's normals once, not once per part (a branch of a thousand blossoms)
    normals = vertex_normals(np.asarray(vertices, dtype=np.float64), F)
    out = {}
    for i, part in enumerate(asset.parts):
        allowed = face_part == i
        if allowed.any():
            points = np.asarray(part.points) * scale
            b = bind(points, vertices, F, allowed, normals)
            piece = components(np.asarray(part.triangles(), dtype=np.int64).reshape(-1, 3),
                               len(points))
            stays = _not_petals(points / scale, piece, (kept or {}).get(i))
            if (unpicked or {}).get(i) is not None:
                stays |= _nearer_unpicked(points, piece, b, unpicked[i], scale)
            _keep_to_own_petal(b, points, piece, vertices, F, allowed, face_piece,
                               normals, stays)
            b.face[stays], b.bary[stays], b.offset[stays] = -1, 0.0, points[stays]
            out[i] = b
    return out


def _not_petals(points: np.ndarray, piece: np.ndarray, kept) -> np.ndarray:
    """``(n,) bool``: the points of the pieces of a part's mesh (``points``, input units;
    ``piece (n,)`` each one's connected piece) whose points are mostly among the vertices
    of ``kept``'s faces (the part's pieces that are no petal, :func:`bind_parts`; its
    vertex array may be the whole part's)."""
    stays = np.zeros(len(points), dtype=bool)
    if kept is None or len(kept[1]) == 0 or len(points) == 0:
        return stays
    from scipy.spatial import cKDTree

    kept_v = np.asarray(kept[0], dtype=np.float64)[np.unique(np.asarray(kept[1], dtype=np.int64))]
    span = float(np.ptp(np.vstack([points, kept_v]), axis=0).max()) or 1.0
    dist, _ = cKDTree(kept_v).query(points, distance_upper_bound=1e-9 * span)
    theirs = np.isfinite(dist)
    share = np.bincount(piece, weights=theirs) / np.maximum(np.bincount(piece), 1)
    return share[piece] > 0.5


def _nearer_unpicked(points, piece, b: Binding, unpicked, scale: float) -> np.ndarray:
    """``(n,) bool``: the points of the pieces (``piece (n,)``) whose points are mostly
    nearer the left-out sheets ``unpicked`` (input units) than to the sheet point ``b``
    binds them to (``points`` in mesh units)."""
    V = np.asarray(unpicked[0], dtype=np.float64) * scale
    F = np.asarray(unpicked[1], dtype=np.int64)
    face, bary = closest_points(points, V, F)
    other = np.linalg.norm(points - np.einsum("ij,ijk->ik", bary, V[F[face]]), axis=1)
    nearer = other < np.linalg.norm(b.offset, axis=1)
    share = np.bincount(piece, weights=nearer) / np.maximum(np.bincount(piece), 1)
    return share[piece] > 0.5


def _keep_to_own_petal(b: Binding, points, piece, vertices, faces, allowed,
                       face_piece, normals=None, stays=None) -> None:
    """Where most of a connected piece of the input is bound to one sheet petal, bind
    all of it to that petal (in place): a piece is one petal's surface (both sides of a
    thick one), and its points that lay closer to another petal, where petals overlap
    or meet at the hub, would otherwise follow that petal through the bloom and tear
    the surface. A piece no petal has most of (a sheet that was several petals, split
    by remesh) keeps each point's closest petal. ``piece (n,)``: each point's connected
    piece of the input."""
    petal_of = face_piece[b.face]
    for c in np.unique(piece if stays is None else piece[~stays]):
        idx = np.flatnonzero(piece == c)
        values, counts = np.unique(petal_of[idx], return_counts=True)
        main = values[np.argmax(counts)]
        if len(values) == 1 or 2 * counts.max() <= len(idx):
            continue
        stray = idx[petal_of[idx] != main]
        again = bind(points[stray], vertices, faces, allowed & (face_piece == main), normals)
        b.face[stray], b.bary[stray], b.offset[stray] = again.face, again.bary, again.offset


#: a point of a petal's part behind its petal's base that hangs off the sheet's rim by
#: more than this many of the sheet's thickness there (of its mean edges, for a sheet) is
#: the flower's hub, not the petal: :func:`hold_hub`
HUB_OFFSET = 2.0


def hold_hub(bindings: dict[int, Binding], vertices: np.ndarray, faces: np.ndarray,
             petal: np.ndarray, base: np.ndarray, thickness: np.ndarray | None = None) -> dict[int, int]:
    """Points of the petals' parts that belong to the flower's hub stay where they are
    (in place: ``face`` -1, ``offset`` their place); returns how many, by part.

    A flower modelled as one solid (an OpenSCAD union of petals round a centre sphere, a
    receptacle fused with its petals) has one part for all of it; its hub is no sheet,
    so its points were bound to the petals' rims near their bases, far off the sheet, and
    the bloom swung them with the petals' turning frames and tore the hub to shards. A
    hub point is one bound to a sheet's rim (not inside a triangle), more than
    :data:`HUB_OFFSET` of the sheet's thickness there off it, and behind its petal's
    fixed ``base``: on the side of the base's centre away from the petal's own centre,
    where the petal is held. ``vertices``, ``faces``: the sheet's rest mesh (mesh units);
    ``thickness (V,)``: a thick petal's (0 or None for sheets)."""
    X = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    petal = np.asarray(petal, dtype=np.int64)
    base = np.asarray(base, dtype=bool)
    count = int(petal.max()) + 1 if len(petal) else 0
    thick = np.zeros(len(X)) if thickness is None else np.asarray(thickness, dtype=np.float64)
    edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    length = np.linalg.norm(X[edges[:, 0]] - X[edges[:, 1]], axis=1)
    edge = (np.bincount(petal[edges[:, 0]], weights=length, minlength=count)
            / np.maximum(np.bincount(petal[edges[:, 0]], minlength=count), 1))
    held_base = np.bincount(petal[base], minlength=count)
    root = label_means(X[base], petal[base], count)
    ahead = label_means(X, petal, count) - root  # (from each petal's base toward the petal)
    normals = None  # (the sheet's, once: a branch of blossoms has thousands of parts)
    out = {}
    for i, b in bindings.items():
        bound = np.flatnonzero(b.face >= 0)
        if not len(bound):
            continue
        tri = F[b.face[bound]]
        p = petal[tri[:, 0]]
        off = ~interior(Binding(b.face[bound], b.bary[bound], b.offset[bound]))
        scale = np.maximum(np.einsum("ij,ij->i", b.bary[bound], thick[tri]), edge[p])
        off &= np.linalg.norm(b.offset[bound], axis=1) > HUB_OFFSET * scale
        off &= held_base[p] > 0
        if not off.any():
            continue
        mine = bound[off]
        if normals is None:
            normals = vertex_normals(X, F)
        place = deform(X, F, Binding(b.face[mine], b.bary[mine], b.offset[mine]), normals)
        behind = np.einsum("ij,ij->i", place - root[p[off]], ahead[p[off]]) < 0.0
        mine, place = mine[behind], place[behind]
        if len(mine):
            b.face[mine], b.bary[mine], b.offset[mine] = -1, 0.0, place
            out[i] = len(mine)
    return out


def write_bindings(h5, bindings: dict[int, Binding]) -> None:
    """Store bindings under ``bind/`` (see :func:`read_bindings`): each array once for
    all parts, concatenated, ``bind/part`` the parts bound and ``bind/offsets`` where
    each one's points start (a branch of 5,000 petal parts wrote 15,000 datasets)."""
    group = h5.require_group(BIND_GROUP)
    group.attrs["doc"] = ("per input part that is a petal (bind/part): its points "
                          "(input/asset/points, that part's run) bound to the sheet's rest mesh "
                          "(mesh/vertices, mesh/faces); bind/offsets: where each part's run "
                          "starts in face, bary and offset")
    order = sorted(bindings)
    runs = [bindings[i] for i in order]
    put(h5, f"{BIND_GROUP}/part", np.asarray(order, dtype=np.int64), "(B,) the parts bound")
    put(h5, f"{BIND_GROUP}/offsets", np.cumsum([0, *[len(b.face) for b in runs]]).astype(
        np.int64), "(B + 1,) where each part's points start")
    put(h5, f"{BIND_GROUP}/face", np.concatenate([b.face for b in runs]).astype(np.int64)
        if runs else np.zeros(0, dtype=np.int64), "(n,) sheet triangle (row of mesh/faces)")
    put(h5, f"{BIND_GROUP}/bary", np.concatenate([b.bary for b in runs]).reshape(-1, 3)
        if runs else np.zeros((0, 3)), "(n, 3) barycentric coordinates of the closest point")
    put(h5, f"{BIND_GROUP}/offset", np.concatenate([b.offset for b in runs]).reshape(-1, 3)
        if runs else np.zeros((0, 3)),
        "(n, 3) offset from it in the local frame (tangent, tangent, normal), mesh units")


def read_bindings(src) -> dict[int, Binding]:
    """The bindings :func:`write_bindings` stored, by part; also those of the layout an
    earlier version wrote (a group per part)."""
    f = getattr(src, "file", src)
    if BIND_GROUP not in f:
        return {}
    g = f[BIND_GROUP]
    if "part" not in g:
        return {int(k): Binding(b["face"][()], b["bary"][()], b["offset"][()])
                for k, b in g.items()}
    at, face, bary, offset = (g[n][()] for n in ("offsets", "face", "bary", "offset"))
    return {int(i): Binding(face[at[k]:at[k + 1]], bary[at[k]:at[k + 1]],
                            offset[at[k]:at[k + 1]]) for k, i in enumerate(g["part"][()])}


#: a point faces the other side across the sheet when its distance to it at rest is the
#: sum of the two offsets within this fraction, and their places on the sheet are closer
#: than this fraction of that distance
ACROSS = 0.2
#: Gauss-Newton steps that restore a thick part's thickness in a frame (see keep_thickness)
KEEP_STEPS = 3
#: their damping: the least-squares system's diagonal is raised by this (its entries are
#: dot products of unit vectors weighted by barycentric coordinates, so it is scale-free)
KEEP_DAMPING = 1e-3


@dataclass
class Sides:
    """A thick part's two sides, facing each other across the sheet (:func:`sides`)."""
    point: np.ndarray  #: (k,) the part's points that face its other side across the sheet
    positive: np.ndarray  #: (k,) bool: the point is on the sheet's positive side
    rest: np.ndarray  #: (k,) its distance to the other side at rest (the thickness there)
    rows: np.ndarray  #: (m,) a row of ``point`` ...
    faces: np.ndarray  #: (m,) ... and a triangle of the other side near it (candidates)


def sides(points: np.ndarray, triangles: np.ndarray, b: Binding, sheet: np.ndarray,
          sheet_faces: np.ndarray, scale: float) -> Sides:
    """The points of a part (``points``, ``triangles``: the input's, bound by ``b``) that
    face the part's other side across the sheet at rest, on both sides: bound inside a
    sheet triangle (:func:`interior`), their nearest point of the other side (its
    triangles with every corner there, by the sign of the normal offset) as far as the
    two offsets added (within ``ACROSS``) and over the same place of the sheet
    (``sheet``: its rest vertices, in the points' units; ``scale``: mesh units per
    those, the offsets' unit). A solidified petal's points are; a one-sided sheet's are
    not (its offsets are small and its nearest other faces lie beside it, not across),
    nor a hem's or a fold's. Each point's candidates for its nearest point in a frame
    are the other side's triangles within two rings of its nearest one at rest."""

    P = np.asarray(points, dtype=np.float64)
    T = np.asarray(triangles, dtype=np.int64)
    o = np.asarray(b.offset[:, 2], dtype=np.float64) / scale
    S, SF = np.asarray(sheet, dtype=np.float64), np.asarray(sheet_faces, dtype=np.int64)
    on = np.einsum("ij,ijk->ik", b.bary, S[SF[b.face]])  # each point's place on the sheet
    point, positive, rest, rows, faces = [], [], [], [], []
    count = 0
    for positive_side in (True, False):
        up = (o > 0.0) == positive_side
        other_side = np.all(~up[T] & (b.face[T] >= 0), axis=1)  # (not a piece that stays)
        mine = np.flatnonzero(up & interior(b))
        if len(mine) == 0 or not other_side.any():
            continue
        face, bary = closest_points(P[mine], P, T, other_side)
        near = np.einsum("ij,ijk->ik", bary, P[T[face]])
        distance = np.linalg.norm(near - P[mine], axis=1)
        across = np.abs(o[mine] - np.einsum("ij,ij->i", bary, o[T[face]]))
        apart = np.linalg.norm(np.einsum("ij,ijk->ik", bary, on[T[face]]) - on[mine], axis=1)
        keep = ((across > 0.0) & (np.abs(distance - across) <= ACROSS * across)
                & (apart <= ACROSS * distance))
        if not keep.any():
            continue
        # two rings of the other side's triangles (sharing a corner) about the nearest
        other = np.flatnonzero(other_side)
        corner = sp.csr_matrix((np.ones(3 * len(other)), (np.repeat(other, 3), T[other].ravel())),
                               shape=(len(T), len(P)))
        ring = (corner @ corner.T).astype(bool).astype(np.int8)
        ring2 = (ring @ ring).tocsr()[face[keep]]
        ring2.sort_indices()
        point.append(mine[keep])
        positive.append(np.full(int(keep.sum()), positive_side))
        rest.append(distance[keep])
        rows.append(count + np.repeat(np.arange(ring2.shape[0]), np.diff(ring2.indptr)))
        faces.append(ring2.indices.astype(np.int64))
        count += int(keep.sum())
    if not point:
        e = np.zeros(0, dtype=np.int64)
        return Sides(e, np.zeros(0, dtype=bool), np.zeros(0), e, e)
    return Sides(*(np.concatenate(a) for a in (point, positive, rest, rows, faces)))


def two_sided(points: np.ndarray, triangles: np.ndarray, b: Binding, sheet: np.ndarray,
              sheet_faces: np.ndarray, scale: float) -> np.ndarray:
    """Indices of a part's points that measure its thickness: those of :func:`sides` on
    the sheet's positive side. Empty: the part has no thickness to measure."""
    s = sides(points, triangles, b, sheet, sheet_faces, scale)
    return np.sort(s.point[s.positive])


def keep_thickness(points: np.ndarray, triangles: np.ndarray, s: Sides,
                   steps: int = KEEP_STEPS) -> np.ndarray:
    """A thick part's points in a frame (``points``, deformed through the binding) moved
    so that each point of ``s`` is again as far from the other side as at rest.

    The binding offsets both sides along the sheet's normals, which keeps each point's
    distance to the other side's *points*; but a coarse thick petal bent across few of its
    faces has flat faces that cut chords across the bend, so its sides' *surfaces* come
    closer (a point is t cos(theta/2) from the opposite chord) or part where it unbends.
    Each Gauss-Newton step linearises every point's distance to its nearest point of the
    other side (among its candidates), moving the point along the line to that nearest
    point and the other side's triangle corners with their own, and solves the damped
    least-squares system for the moves (damping ``KEEP_DAMPING`` on the moves from the
    deformed points, so the smallest move that restores the thickness is taken). Points
    not in ``s`` (rims, one-sided parts) are not moved. Deterministic: a fixed number of
    steps, a direct solve (qdldl's LDL^T of the damped normal equations, positive
    definite)."""
    import qdldl

    Q0 = np.asarray(points, dtype=np.float64)
    if len(s.point) == 0:
        return Q0
    T = np.asarray(triangles, dtype=np.int64)
    Q = Q0.copy()
    n = len(s.point)
    col = np.full(len(Q), -1, dtype=np.int64)
    col[s.point] = np.arange(n)
    identity = sp.identity(n, format="csc")
    for _ in range(steps):
        _, face, bary, distance = nearest_among(Q[s.point], Q, T, s.rows, s.faces)
        live = distance > 1e-9 * s.rest  # a point on the other side: no direction to move
        u = np.zeros((n, 3))
        u[live] = (Q[s.point[live]] - np.einsum("ij,ijk->ik", bary[live], Q[T[face[live]]])) \
            / distance[live, None]
        r = np.where(live, s.rest - distance, 0.0)
        I, J, V = [np.arange(n)], [np.arange(n)], [np.ones(n)]
        for k in range(3):
            c = col[T[face, k]]
            ok = np.flatnonzero((c >= 0) & live)
            I.append(ok)
            J.append(c[ok])
            V.append(-bary[ok, k] * np.einsum("ij,ij->i", u[ok], u[c[ok]]))
        A = sp.csr_matrix((np.concatenate(V), (np.concatenate(I), np.concatenate(J))),
                          shape=(n, n))
        moved = np.einsum("ij,ij->i", Q[s.point] - Q0[s.point], u)
        normal = sp.triu(A.T @ A + KEEP_DAMPING * identity, format="csc")
        normal.sort_indices()
        step = qdldl.Solver(normal).solve(A.T @ r - KEEP_DAMPING * moved)
        Q[s.point] += step[:, None] * u
    return Q


def thickness(points: np.ndarray, triangles: np.ndarray, offset_normal: np.ndarray,
              which: np.ndarray) -> np.ndarray:
    """``(k,)`` a thick part's thickness at its points ``which`` (:func:`two_sided`):
    each one's distance to the nearest point of the part's negative side (its triangles
    with every corner on that side, by the sign of ``offset_normal``; nan: a point on
    neither side, one that stays)."""
    P = np.asarray(points, dtype=np.float64)
    T = np.asarray(triangles, dtype=np.int64)
    down_faces = np.all((np.asarray(offset_normal) <= 0.0)[T], axis=1)
    if len(which) == 0:
        return np.zeros(0)
    face, bary = closest_points(P[which], P, T, down_faces)
    return np.linalg.norm(np.einsum("ij,ijk->ik", bary, P[T[face]]) - P[which], axis=1)


def interior(b: Binding, margin: float = 1e-6) -> np.ndarray:
    """``(n,) bool``: points bound inside their triangle (their offset is along the normal
    only), not clamped to the sheet's rim."""
    return np.all(b.bary > margin, axis=1)
