"""Isotropic remeshing of petal sheets, boundary included.

The interior is remeshed by gpytoolbox's Botsch-Kobbelt remesher (split, collapse,
flip, tangential relaxation, projection onto the input), which keeps boundary
vertices fixed and never splits a boundary edge. A petal's rim matters as much as its
inside (the growth is boundary-dominant), so the boundary is first brought to the
target length here with the same rules the remesher uses inside: split edges longer
than 4/3 h at their midpoint, collapse edges shorter than 4/5 h unless that would make
a neighbouring boundary edge longer than 4/3 h, flip a face or break the mesh. Corner
vertices (a sharp turn of the rim: a petal's tip, the ends of a cut) never move.
"""

from __future__ import annotations

import numpy as np

from . import topology

SPLIT, COLLAPSE = 4.0 / 3.0, 4.0 / 5.0


def target_for_vertices(vertices: np.ndarray, faces: np.ndarray, count: int) -> float:
    """Edge length that gives about ``count`` vertices on this sheet.

    An equilateral mesh has one vertex per ``sqrt(3)/2 h^2`` of area inside, and half a
    vertex more per edge along the boundary: ``count = A/(c h^2) + P/(2h)``, solved for h.
    """
    area = 0.5 * float(np.linalg.norm(topology.face_normals(vertices, faces), axis=1).sum())
    edges, _, used = topology.unique_edges(faces)
    rim = edges[used == 1]
    perimeter = float(np.linalg.norm(vertices[rim[:, 0]] - vertices[rim[:, 1]], axis=1).sum())
    a = area / (np.sqrt(3.0) / 2.0)
    inv_h = (-perimeter / 2.0 + np.sqrt(perimeter ** 2 / 4.0 + 4.0 * a * count)) / (2.0 * a)
    return float(1.0 / inv_h)


def boundary_loops(faces: np.ndarray) -> list[np.ndarray]:
    """Each boundary loop as an ordered vertex array, following the faces' winding."""
    he, _ = topology.half_edges(faces)
    _, he_edge, count = topology.unique_edges(faces)
    nxt = {int(a): int(b) for a, b in he[count[he_edge] == 1]}
    loops, seen = [], set()
    for start in sorted(nxt):
        if start in seen:
            continue
        loop, a = [], start
        while a not in seen and a in nxt:
            seen.add(a)
            loop.append(a)
            a = nxt[a]
        loops.append(np.asarray(loop, dtype=np.int64))
    return loops


def corner_vertices(vertices: np.ndarray, faces: np.ndarray, angle_deg: float = 50.0) -> np.ndarray:
    """``(V,) bool``: boundary vertices where the rim turns by more than ``angle_deg``."""
    corner = np.zeros(len(vertices), dtype=bool)
    for loop in boundary_loops(faces):
        if len(loop) < 3:
            corner[loop] = True
            continue
        d_in = vertices[loop] - vertices[np.roll(loop, 1)]
        d_out = vertices[np.roll(loop, -1)] - vertices[loop]
        cos = np.einsum("ij,ij->i", d_in, d_out) / np.maximum(
            np.linalg.norm(d_in, axis=1) * np.linalg.norm(d_out, axis=1), 1e-300)
        corner[loop[cos < np.cos(np.radians(angle_deg))]] = True
    return corner


def _split_long(v: np.ndarray, f: np.ndarray, fixed: np.ndarray, h: float,
                boundary_only: bool = True):
    """Split edges longer than 4/3 h at their midpoint, at most one per face per pass."""
    he, opposite = topology.half_edges(f)
    _, he_edge, count = topology.unique_edges(f)
    nf = len(f)
    length = np.linalg.norm(v[he[:, 1]] - v[he[:, 0]], axis=1)
    kinds = (1,) if boundary_only else (1, 2)
    todo = np.flatnonzero(np.isin(count[he_edge], kinds) & (length > SPLIT * h))
    todo = todo[np.lexsort((he_edge[todo], -length[todo]))]
    halves: dict[int, list[int]] = {}
    for k in todo.tolist():
        halves.setdefault(int(he_edge[k]), []).append(k)
    new_v, new_f, used = [], [], set()
    faces = f.copy()
    for ks in halves.values():
        if any(k % nf in used for k in ks):
            continue
        m = len(v) + len(new_v)
        a, b = he[ks[0]]
        new_v.append(0.5 * (v[a] + v[b]))
        for k in ks:
            face = k % nf
            used.add(face)
            a, b = he[k]
            faces[face] = (a, m, opposite[k])
            new_f.append((m, b, opposite[k]))
    if not new_v:
        return v, f, fixed, 0
    return (np.vstack([v, new_v]), np.vstack([faces, new_f]),
            np.r_[fixed, np.zeros(len(new_v), dtype=bool)], len(new_v))


def _collapse_short(v: np.ndarray, f: np.ndarray, fixed: np.ndarray, h: float):
    """Collapse boundary edges shorter than 4/5 h where that keeps the mesh sound."""
    v = v.copy()
    faces = f.copy()
    boundary = topology.boundary_vertices(f, len(v))
    loops = boundary_loops(f)
    prev, nxt = {}, {}
    for loop in loops:
        for a, b in zip(loop.tolist(), np.roll(loop, -1).tolist(), strict=True):
            nxt[a], prev[b] = b, a
    vertex_faces = [[] for _ in range(len(v))]
    for i, tri in enumerate(faces.tolist()):
        for a in tri:
            vertex_faces[a].append(i)
    alive = np.ones(len(faces), dtype=bool)
    candidates = [(float(np.linalg.norm(v[b] - v[a])), a, b) for a, b in nxt.items()]
    candidates.sort()
    touched: set[int] = set()
    collapsed = 0
    for length, a, b in candidates:
        if length >= COLLAPSE * h:
            break
        if a in touched or b in touched or (fixed[a] and fixed[b]):
            continue
        p, n = prev[a], nxt[b]
        if p in (b, n):  # a loop of 3 or fewer edges stays
            continue
        pos = v[a] if fixed[a] else v[b] if fixed[b] else 0.5 * (v[a] + v[b])
        if (np.linalg.norm(v[p] - pos) > SPLIT * h or np.linalg.norm(v[n] - pos) > SPLIT * h):
            continue
        fa = [i for i in vertex_faces[a] if alive[i]]
        fb = [i for i in vertex_faces[b] if alive[i]]
        shared = [i for i in fa if i in fb]
        if len(shared) != 1:
            continue
        (o,) = [x for x in faces[shared[0]].tolist() if x not in (a, b)]
        if boundary[o]:
            continue
        ring_a = {x for i in fa for x in faces[i].tolist()} - {a}
        ring_b = {x for i in fb for x in faces[i].tolist()} - {b}
        if ring_a & ring_b != {o}:  # link condition
            continue
        moved = [i for i in set(fa) | set(fb) if i != shared[0]]
        before = topology.face_normals(v, faces[moved])
        after_faces = np.where(faces[moved] == b, a, faces[moved])
        trial = v.copy()
        trial[a] = pos
        after = topology.face_normals(trial, after_faces)
        if np.any(np.einsum("ij,ij->i", before, after) <= 0.0):
            continue
        v[a] = pos
        fixed[a] = fixed[a] or fixed[b]
        faces[moved] = after_faces
        alive[shared[0]] = False
        for i in moved:
            if i not in vertex_faces[a]:
                vertex_faces[a].append(i)
        nxt[a], prev[n] = n, a
        touched.update((a, b, p, n))
        collapsed += 1
    faces = faces[alive]
    used = np.zeros(len(v), dtype=bool)
    used[faces.ravel()] = True
    remap = np.cumsum(used) - 1
    return v[used], remap[faces], fixed[used], collapsed


def resample_boundary(vertices: np.ndarray, faces: np.ndarray, h: float,
                      fixed: np.ndarray | None = None, passes: int = 12):
    """Split and collapse boundary edges towards length ``h`` (see the module notes).

    ``fixed`` marks vertices that must not move (corners are added to it). Returns
    ``(vertices, faces, fixed)``.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    fixed = corner_vertices(v, f) | (np.zeros(len(v), dtype=bool) if fixed is None else fixed)
    for _ in range(passes):
        v, f, fixed, split = _split_long(v, f, fixed, h)
        v, f, fixed, collapsed = _collapse_short(v, f, fixed, h)
        if split == 0 and collapsed == 0:
            break
    return v, f, fixed


def _angle_at(v: np.ndarray, apex: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    x, y = v[a] - v[apex], v[b] - v[apex]
    cos = np.einsum("ij,ij->i", x, y) / np.maximum(
        np.linalg.norm(x, axis=1) * np.linalg.norm(y, axis=1), 1e-300)
    return np.arccos(np.clip(cos, -1.0, 1.0))


def delaunay_flips(vertices: np.ndarray, faces: np.ndarray, passes: int = 20) -> np.ndarray:
    """Flip interior edges whose two opposite angles add up to more than pi (the mesh's
    own Delaunay criterion), unless the flip would fold the surface or duplicate an edge.

    The remesher keeps boundary vertices where they are and flips only for valence, so
    triangles along a straight rim or cut (an "ear" of three rim vertices, a fan left by
    a boundary split) can stay needle-thin; these flips fix them."""
    f = np.asarray(faces, dtype=np.int64).copy()
    for _ in range(passes):
        he, opposite, he_edge, count, a, b = topology.interior_pairs(f)
        nf = len(f)
        i, j = he[a, 0], he[a, 1]
        o, o2 = opposite[a], opposite[b]
        total = _angle_at(vertices, o, i, j) + _angle_at(vertices, o2, i, j)
        todo = np.flatnonzero((total > np.pi + 1e-9) & (o != o2))
        todo = todo[np.argsort(-total[todo], kind="stable")]
        existing = {tuple(e) for e in np.sort(he, axis=1).tolist()}
        used, flipped = set(), 0
        for k in todo.tolist():
            t1, t2 = int(a[k] % nf), int(b[k] % nf)
            if t1 in used or t2 in used:
                continue
            vi, vj, vo, vo2 = int(i[k]), int(j[k]), int(o[k]), int(o2[k])
            if (min(vo, vo2), max(vo, vo2)) in existing:
                continue
            new = np.array([(vi, vo2, vo), (vj, vo, vo2)])
            before = topology.face_normals(vertices, f[[t1, t2]]).sum(axis=0)
            after = topology.face_normals(vertices, new)
            if np.any(after @ before <= 0.0):
                continue
            f[t1], f[t2] = new
            used.update((t1, t2))
            existing.add((min(vo, vo2), max(vo, vo2)))
            flipped += 1
        if flipped == 0:
            break
    return f


def isotropic(vertices: np.ndarray, faces: np.ndarray, h: float, *,
              fixed: np.ndarray | None = None, iterations: int = 10):
    """Remesh a sheet to edge length about ``h``, boundary included.

    Returns ``(vertices, faces, fixed)``; ``fixed`` flags the output vertices that were
    fixed on input (corners included), which the remesher keeps first and unmoved.
    """
    import gpytoolbox

    v, f, fixed = resample_boundary(vertices, faces, h, fixed)
    for rounds in range(3):
        feature = np.flatnonzero(fixed)
        # the remesher returns feature vertices first, in order, then the others
        v, f = gpytoolbox.remesh_botsch(v, f.astype(np.int32), iterations, float(h), True,
                                        feature=feature.astype(np.int32))
        v, f = np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)
        fixed = np.zeros(len(v), dtype=bool)
        fixed[:len(feature)] = True
        if rounds == 2:
            break
        # the remesher leaves long edges at the boundary: split them and go again
        v, f, fixed, split = _split_long(v, f, fixed, h, boundary_only=False)
        if split == 0:
            break
    return np.ascontiguousarray(v), delaunay_flips(v, f), fixed
