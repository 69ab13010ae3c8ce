"""Isotropic remeshing of petal sheets, boundary included.

The interior is remeshed by gpytoolbox's Botsch-Kobbelt remesher (split, collapse,
flip, tangential relaxation, projection onto the input), which keeps boundary
vertices fixed and never splits a boundary edge. A petal's rim matters as much as its
inside (the growth is boundary-dominant), so the boundary is first brought to the
target length here with the same rules the remesher uses inside: split edges longer
than 4/3 h at their midpoint, collapse edges shorter than 4/5 h unless that would make
a neighbouring boundary edge longer than 4/3 h, flip a face or break the mesh. Corner
vertices (a sharp turn of the rim: a petal's tip, the ends of a cut) never move.

The module is long because the rim pass and the improvement pass (:func:`improve`:
moves, collapses, splits and clips towards the quality bound) are one remesher: they
share the quality measures and the rules for what a move may do to the rim.
"""

from __future__ import annotations

import warnings

import numpy as np

from pipeline.mesh import topology

SPLIT, COLLAPSE = 4.0 / 3.0, 4.0 / 5.0

#: The quality bound every petal leaves the remesh stage with: no triangle angle below
#: MIN_ANGLE degrees, except a triangle's angle at a *corner*, a boundary vertex whose rim
#: angle (the sum of its triangles' angles there: how wide the sheet opens at it) is
#: below CORNER x MIN_ANGLE. At such a vertex (a petal's tip, a needle) the rim itself
#: bounds what the triangles there can have; their other angles still count. Degenerate
#: triangles measure 0 and inverted ones (see :func:`inverted_faces`) count as 0 too.
#: 20 deg keeps the explicit step's stability limit (shortest altitude) and the hinges'
#: normals usable; the Botsch-Kobbelt remesher reaches about 30 inside a sheet.
MIN_ANGLE = 20.0
CORNER = 2.0
#: ... and no edge shorter than MIN_EDGE times the sheet's mean edge. A cluster of tiny
#: triangles with good angles (a tip that kept every point of a dense rim) is as bad for
#: the simulator as a sliver: its hinges are 1/MIN_EDGE^2 as stiff, and under
#: compression a tiny triangle flattens, its bending force becomes singular and the
#: dynamic integrators gain energy.
MIN_EDGE = 0.25
RIM_TURN = 10.0  #: degrees: :func:`improve` may remove a rim vertex where the rim turns less
#: :func:`isotropic` first halves every edge (midpoints) while the mean edge is over
#: COARSE times the target, at most MAX_UPSAMPLE times
COARSE, MAX_UPSAMPLE = 2.0, 8
#: :func:`drop_flaps` drops pieces that hang on a sheet by a vertex while they hold less
#: than this share of its area
FLAP = 0.05


def clean_mean_edge(vertices: np.ndarray, faces: np.ndarray) -> float:
    """The mean length of a mesh's edges (each once)."""
    edges, _, _ = topology.unique_edges(faces)
    return float(np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1).mean())


def triangle_angles(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(F, 3)`` angles in degrees at each face's corners (0 for a degenerate face).

    atan2 of |cross| and dot, not arccos of a normalized dot: no division, so a
    zero-length edge gives 0 rather than NaN, and slivers keep their precision."""
    p = np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64)]
    out = np.empty(p.shape[:2])
    for k in range(3):
        a, b = p[:, (k + 1) % 3] - p[:, k], p[:, (k + 2) % 3] - p[:, k]
        out[:, k] = np.arctan2(np.linalg.norm(topology.cross(a, b), axis=1),
                                 np.einsum("ij,ij->i", a, b))
    return np.degrees(out)


def inverted_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(F,) bool``: faces wound against a neighbour (both run their shared edge the
    same way) or folded over their neighbours: the face's normal points away from the
    sum of its edge-neighbours' unit normals (the sheet's tangent plane there)."""
    f = np.asarray(faces, dtype=np.int64)
    he, _, _, _, a, b = topology.interior_pairs(f)
    nf = len(f)
    bad = np.zeros(nf, dtype=bool)
    wrong = he[a, 0] == he[b, 0]
    bad[a[wrong] % nf] = bad[b[wrong] % nf] = True
    n = topology.face_normals(vertices, f)
    length = np.linalg.norm(n, axis=1)
    unit = n / np.where(length > 0.0, length, 1.0)[:, None]
    around = np.zeros_like(unit)
    np.add.at(around, a % nf, unit[b % nf])
    np.add.at(around, b % nf, unit[a % nf])
    lone = ~np.any(around != 0.0, axis=1)  # no neighbour (or all degenerate): nothing to fold over
    return bad | (~lone & (np.einsum("ij,ij->i", unit, around) <= 0.0))


def sharp_corners(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(V,) bool``: boundary vertices whose rim angle is below ``CORNER * MIN_ANGLE``."""
    f = np.asarray(faces, dtype=np.int64)
    rim = np.zeros(len(vertices))
    np.add.at(rim, f.ravel(), triangle_angles(vertices, f).ravel())
    return topology.boundary_vertices(f, len(vertices)) & (rim < CORNER * MIN_ANGLE)


def corner_angles(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(F, 3) bool``: the face angles :data:`MIN_ANGLE` does not apply to (those at a
    :func:`sharp_corners` vertex)."""
    return sharp_corners(vertices, faces)[np.asarray(faces, dtype=np.int64)]


def face_quality(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(F,)`` each face's smallest angle in degrees, corners excepted (see
    :data:`MIN_ANGLE`); 0 for degenerate and inverted faces."""
    angles = triangle_angles(vertices, faces)
    angles[corner_angles(vertices, faces)] = 180.0
    worst = angles.min(axis=1)
    worst[inverted_faces(vertices, faces)] = 0.0
    return worst


def quality(vertices: np.ndarray, faces: np.ndarray) -> float:
    """The mesh's smallest triangle angle in degrees away from corners, 0 if any face
    is degenerate or inverted: a mesh meets the bound when ``quality >= MIN_ANGLE``."""
    return float(face_quality(vertices, faces).min()) if len(faces) else 0.0


def edge_ratio(vertices: np.ndarray, faces: np.ndarray) -> float:
    """The sheet's shortest edge over its mean edge: it meets the bound when
    ``edge_ratio >= MIN_EDGE``."""
    edges, _, _ = topology.unique_edges(np.asarray(faces, dtype=np.int64))
    if len(edges) == 0:
        return 0.0
    length = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
    return float(length.min() / length.mean())


def meets_bound(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Whether a sheet meets both bounds: :data:`MIN_ANGLE` and :data:`MIN_EDGE`."""
    return quality(vertices, faces) >= MIN_ANGLE and edge_ratio(vertices, faces) >= MIN_EDGE


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


#: an ear on the rim (a face whose one vertex is in no other face) sharper than this is
#: dropped after remeshing: a thick petal's mid-surface can keep a needle or a flat cap
#: on its rim that no move mends when the mesh must stay mirror-paired (the lotus: 56
#: of its 73 faces under 10 deg), and growth crushes it
EAR_ANGLE = 10.0


def drop_ears(vertices: np.ndarray, faces: np.ndarray, angle: float = EAR_ANGLE):
    """The sheet without its ears on the rim (a face with a vertex in no other face, its
    two edges at that vertex on the rim) whose smallest angle is under ``angle``
    degrees, and without the vertices they held: ``(vertices, faces, dropped)``. Ears
    are dropped a round at a time, all of a round at once (a mirror-paired mesh loses
    both of a pair: it stays paired), until none is left; a face that is the sheet's
    last stays."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    dropped = 0
    while len(f) > 1:
        uses = np.bincount(f.ravel(), minlength=len(v))
        ear = (uses[f] == 1).any(axis=1) & (triangle_angles(v, f).min(axis=1) < angle)
        if not ear.any() or ear.all():
            break
        f = f[~ear]
        dropped += int(ear.sum())
    if not dropped:
        return vertices, faces, 0
    used, remap = topology.used_vertices(f, len(v))
    return v[used], remap[f], dropped


def drop_rim_folds(vertices: np.ndarray, faces: np.ndarray):
    """The sheet without the faces folded over their neighbours on its rim
    (:func:`inverted_faces` with an edge on the rim: a mirrored tip that crumpled), or
    passing through the sheet with a vertex on its rim (:func:`self_crossed_faces`: a rim
    the mid-surface of a fused solid tucked under itself), and the faces that share a
    vertex with them (the fold's own neighbours cross it), then without the ears that
    leaves (:func:`drop_ears`) and the vertices no face holds: ``(vertices, faces,
    dropped)``. A fold inside the sheet is left (a warning's)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    _, he_edge, count = topology.unique_edges(f)
    on_rim = (count[he_edge] == 1).reshape(3, -1).any(axis=0)
    rim_vertex = topology.boundary_vertices(f, len(v))
    folded = (inverted_faces(v, f) & on_rim) | (self_crossed_faces(v, f) & rim_vertex[f].any(axis=1))
    if not folded.any() or folded.all():
        return vertices, faces, 0
    around = np.zeros(len(v), dtype=bool)
    around[f[folded].ravel()] = True
    gone = around[f].any(axis=1)
    if gone.all():
        return vertices, faces, 0
    used, remap = topology.used_vertices(f[~gone], len(v))
    v, f, ears = drop_ears(v[used], remap[f[~gone]])
    return v, f, int(gone.sum()) + ears


def self_crossed_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(F,) bool``: the faces of a sheet that pass through it, an edge of one through
    another that shares no vertex with it (ipctk's exact test): the face and the faces of
    the edge."""
    from pipeline.mesh.ipc import ipctk
    from pipeline.mesh.separate import crossings

    f = np.asarray(faces, dtype=np.int64)
    out = np.zeros(len(f), dtype=bool)
    if len(f) < 2:
        return out
    edges, he_edge, _ = topology.unique_edges(f)
    X = np.asfortranarray(vertices, dtype=np.float64)  # (ipctk's test first: in C++, and
    # it leaves out what shares a vertex; the pairs only where it finds one)
    E32, F32 = np.asfortranarray(edges, dtype=np.int32), np.asfortranarray(f, dtype=np.int32)
    if not ipctk().has_intersections(ipctk().CollisionMesh(X, E32, F32), X):
        return out
    found = crossings(np.asarray(vertices, dtype=np.float64), f, edges, np.arange(len(vertices)))
    if not len(found):
        return out
    apart = ~np.any(edges[found[:, 0]][:, :, None] == f[found[:, 1]][:, None, :], axis=(1, 2))
    found = found[apart]
    out[found[:, 1]] = True
    out[np.flatnonzero(np.isin(he_edge, found[:, 0])) % len(f)] = True
    return out


def drop_flaps(vertices: np.ndarray, faces: np.ndarray, most: float = FLAP):
    """The sheet without the pieces that hang on it by a vertex only (faces joined to the
    rest across no edge: what dropping a rim fold can leave, or a bow-tie of the input),
    where together they hold less than ``most`` of its area: ``(vertices, faces,
    dropped)``, the largest piece kept. Such a flap starts within a hair of the sheet
    (the lotus's: 0.002 edges from its neighbour), too near for contact to keep the petal
    off itself, and folds through it as the petal grows. Larger pieces are left (a
    sheet cut in two is the petal stage's to find)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    piece = topology.face_components(f)
    if len(f) == 0 or piece.max() == 0:
        return vertices, faces, 0
    area = np.bincount(piece, weights=0.5 * np.linalg.norm(topology.face_normals(v, f), axis=1))
    keep = piece == int(np.argmax(area))
    if area.sum() - area.max() >= most * area.sum():
        return vertices, faces, 0
    used, remap = topology.used_vertices(f[keep], len(v))
    return v[used], remap[f[keep]], int(np.sum(~keep))


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


def pinched_rim(faces: np.ndarray, vertex_count: int) -> int:
    """How many vertices the rim passes through more than once (two boundary edges leave
    them the same way round): where a sheet's outline touches itself."""
    he, _ = topology.half_edges(faces)
    _, he_edge, count = topology.unique_edges(faces)
    out = np.bincount(he[count[he_edge] == 1, 0], minlength=vertex_count)
    return int(np.sum(out > 1))


#: the turn (deg) at which a petal's outline has a corner: its base edge ends there
#: (:func:`pipeline.flower.coords.base_edge`), and a finer mesh draws no curve through it
#: (:func:`pipeline.mesh.subdivide.subdivide`)
OUTLINE_CORNER = 30.0


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


def outline_corners(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(V,) bool``: the outline's corners (turns of
    :data:`OUTLINE_CORNER` or more). A mesh cut finer keeps these
    as its corners at every level (:meth:`pipeline.sim.build.Prepared.refined`): the
    curve through a coarse rim rounds a corner a little at each cut, and a Poisson-disc
    petal's base corner, turning 39.6 deg at 100 vertices, turned 29.2 after two cuts,
    no corner by the turn; the axis stage's base edge, which ends at corners, shrank to
    one vertex and the petal's clamp and ``s`` moved (6.5 deg less open)."""
    return corner_vertices(vertices, faces, OUTLINE_CORNER)


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


def _collapse_short(v: np.ndarray, f: np.ndarray, fixed: np.ndarray, h: float,
                    pinned: np.ndarray | None = None):
    """Collapse boundary edges shorter than 4/5 h where that keeps the mesh sound.

    An edge between two ``fixed`` vertices (two corners) stays, unless it is shorter than
    :data:`MIN_EDGE` h: a notch in the outline below the mesh's resolution (a modelling
    tool's sliver, a mid-surface's torn rim). Its ends merge at its middle, or at the
    end that is ``pinned`` (a vertex the caller fixed; two pinned ends stay)."""
    pinned = np.zeros(len(v), dtype=bool) if pinned is None else pinned.copy()
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
        notch = fixed[a] and fixed[b]
        if a in touched or b in touched or (notch and (length >= MIN_EDGE * h
                                                        or (pinned[a] and pinned[b]))):
            continue
        p, n = prev[a], nxt[b]
        if p in (b, n):  # a loop of 3 or fewer edges stays
            continue
        if notch:
            pos = v[a] if pinned[a] else v[b] if pinned[b] else 0.5 * (v[a] + v[b])
        else:
            pos = v[a] if fixed[a] else v[b] if fixed[b] else 0.5 * (v[a] + v[b])
        if (np.linalg.norm(v[p] - pos) > SPLIT * h or np.linalg.norm(v[n] - pos) > SPLIT * h):
            continue
        fa = [i for i in vertex_faces[a] if alive[i]]
        fb = [i for i in vertex_faces[b] if alive[i]]
        shared = [i for i in fa if i in fb]
        if len(shared) != 1:
            continue
        (o,) = [x for x in faces[shared[0]].tolist() if x not in (a, b)]
        if boundary[o] and o not in (p, n):  # an ear (o next on the rim) may go: a tip's
            continue  # last short edge is often one; any other rim vertex would pinch
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
        pinned[a] = pinned[a] or pinned[b]
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
    return v[used], remap[faces], fixed[used], pinned[used], collapsed


def resample_boundary(vertices: np.ndarray, faces: np.ndarray, h: float,
                      fixed: np.ndarray | None = None, passes: int = 12):
    """Split and collapse boundary edges towards length ``h`` (see the module notes).

    ``fixed`` marks vertices that must not move (corners are added to it). Returns
    ``(vertices, faces, fixed)``.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    pinned = np.zeros(len(v), dtype=bool) if fixed is None else np.asarray(fixed, dtype=bool)
    fixed = outline_corners(v, f) | pinned
    for _ in range(passes):
        v, f, fixed, split = _split_long(v, f, fixed, h)
        pinned = np.r_[pinned, np.zeros(len(v) - len(pinned), dtype=bool)]
        v, f, fixed, pinned, collapsed = _collapse_short(v, f, fixed, h, pinned)
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
        if todo.size == 0:
            break
        todo = todo[np.argsort(-total[todo], kind="stable")]
        existing = set(map(tuple, np.sort(he, axis=1).tolist()))
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

    pinched = pinched_rim(faces, len(vertices))
    if pinched:  # gpytoolbox's remesher runs out of memory on such a rim (a lotus mid-surface)
        raise ValueError(f"its rim touches itself at {pinched} vertex(es): not a sheet the "
                         "remesher can take")
    v, f = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    fixed = np.zeros(len(v), dtype=bool) if fixed is None else np.asarray(fixed, dtype=bool)
    for _ in range(MAX_UPSAMPLE):  # far coarser than h: the remesher's splits alone leave slivers
        if clean_mean_edge(v, f) <= COARSE * h:
            break
        # midpoints (the surface unchanged; the input's vertices first, in order): the
        # remesher moves only vertices inside the sheet, and a petal of a few triangles
        # has none (the daisy bush's 6-triangle petals: 255 of 378 triangles under the
        # bound after it, and minutes in improve)
        v, f = gpytoolbox.subdivide(v, f, iters=1)
        v, f = np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)
        fixed = np.r_[fixed, np.zeros(len(v) - len(fixed), dtype=bool)]
    v, f, fixed = resample_boundary(v, f, h, fixed)
    for rounds in range(3):
        feature = np.flatnonzero(fixed)
        # the remesher returns feature vertices first, in order, then the others
        try:
            with warnings.catch_warnings():  # (a sheet with no inner vertex: a no-op, said
                # once per petal of a branch's thousands)
                warnings.filterwarnings("ignore", "All vertices in the input mesh",
                                        UserWarning)
                v, f = gpytoolbox.remesh_botsch(v, f.astype(np.int32), iterations, float(h),
                                                True, feature=feature.astype(np.int32))
        except (MemoryError, RuntimeError) as exc:
            raise ValueError(f"the remesher failed ({type(exc).__name__}: {exc})") from None
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


def _worst(v: np.ndarray, faces: np.ndarray, sharp: np.ndarray) -> float:
    """Smallest angle of ``faces`` away from ``sharp`` vertices; -1 if one of them has
    no area (compiled: :func:`pipeline.mesh.placing.worst_angles`)."""
    from pipeline.mesh.placing import worst_angles

    if len(faces) == 0:
        return 180.0
    return float(worst_angles(v, np.ascontiguousarray(faces, dtype=np.int64), sharp, -1,
                              v[:1], False)[0])


def _worst_moved(v: np.ndarray, faces: np.ndarray, sharp: np.ndarray, i: int,
                 places: np.ndarray) -> np.ndarray:
    """(C,) :func:`_worst` of ``faces`` (each has vertex ``i``) with ``i`` moved to each of
    ``places (C, 3)``; -1 also where a face turned against its normal before the move."""
    from pipeline.mesh.placing import worst_angles

    return worst_angles(v, np.ascontiguousarray(faces, dtype=np.int64), sharp, int(i),
                        np.ascontiguousarray(places, dtype=np.float64), True)


class _Incident:
    """The faces at each vertex, in face order (``incident[i]`` is a list), kept as two
    arrays: one sort of the faces' corners instead of a Python list per vertex."""

    def __init__(self, faces: np.ndarray, vertex_count: int):
        corner = faces.ravel()
        order = np.argsort(corner, kind="stable")
        self.face = order // 3
        self.start = np.r_[0, np.cumsum(np.bincount(corner, minlength=vertex_count))]

    def __getitem__(self, i: int) -> list:
        return self.face[self.start[i]:self.start[i + 1]].tolist()


class _Improver:
    """The state of :func:`improve`: positions, faces and which vertex may do what."""

    def __init__(self, v, f, fixed, slide):
        self.v, self.f, self.fixed, self.slide = v, f, fixed, slide

    def refresh(self, flip: bool = True) -> None:
        """Everything derived from the faces, recomputed over arrays (no loop over the
        faces in Python: this runs after every change tried)."""
        if flip:
            self.f = delaunay_flips(self.v, self.f)
        n = len(self.v)
        edges, _, count = topology.unique_edges(self.f)
        rim_edges = edges[count == 1]
        self.rim_edges = set(map(tuple, rim_edges.tolist()))
        self.boundary = np.zeros(n, dtype=bool)
        self.boundary[rim_edges.ravel()] = True
        rim = np.zeros(n)
        np.add.at(rim, self.f.ravel(), triangle_angles(self.v, self.f).ravel())
        self.sharp = self.boundary & (rim < CORNER * MIN_ANGLE)  # sharp_corners
        # a rim vertex where the rim runs straight on (within RIM_TURN) may go: the
        # outline moves by a sliver at most
        self.straight = self.boundary & ~self.fixed & (np.abs(rim - 180.0) < RIM_TURN)
        self.incident = _Incident(self.f, n)

    def region(self, vertices) -> np.ndarray:
        return self.f[sorted({t for i in vertices for t in self.incident[i]})]

    def attempt(self, change, around: list[int]) -> bool:
        """Make a topological ``change`` (a function of the arrays returning them changed,
        or None), move the vertices around it to their best places, and keep it only if
        the smallest angle there went up; otherwise undo it."""
        saved = (self.v, self.f, self.fixed, self.slide)
        before = _worst(self.v, self.region([i for i in around if i < len(self.v)]), self.sharp)
        changed = change(self.v.copy(), self.f.copy(), self.fixed.copy(), self.slide.copy())
        if changed is None:
            return False
        self.v, self.f, self.fixed, self.slide = changed
        self.refresh(flip=False)
        near = [i for i in around if i < len(self.v) and self.incident[i]]
        ring = sorted({x for t in self.region(near).tolist() for x in t})
        for i in ring:
            self.relocate(i)
        if _worst(self.v, self.region(ring), self.sharp) > before + 1e-9 and not np.any(
                inverted_faces(self.v, self.region(ring))):
            return True
        self.v, self.f, self.fixed, self.slide = saved
        self.refresh(flip=False)
        return False

    def candidates(self, i: int, ring: np.ndarray) -> np.ndarray:
        """(C, 3) places to try for vertex ``i``, in the order they are tried."""
        v = self.v
        if self.boundary[i]:
            if not self.slide[i]:
                return np.zeros((0, 3))
            # along the rim only, towards either rim neighbour: a seam vertex stays exactly on
            # the plane (its coordinate across the plane is 0 at both ends of the step)
            others = sorted({int(x) for x in ring.ravel()} - {i})
            along = [j for j in others if (min(i, j), max(i, j)) in self.rim_edges]
            return np.array([v[i] + t * (v[j] - v[i]) for j in along
                             for t in (0.1, 0.2, 0.3, 0.4)]).reshape(-1, 3)
        normal = topology.face_normals(v, ring).sum(axis=0)
        normal /= max(np.linalg.norm(normal), 1e-300)
        others = np.unique(ring)
        others = others[others != i]
        # the apex that makes each face equilateral over its far edge
        at = np.argmax(ring == i, axis=1)
        rows = np.arange(len(ring))
        a, b = ring[rows, (at + 1) % 3], ring[rows, (at + 2) % 3]
        e = v[b] - v[a]
        side = np.cross(normal, e)
        apex = 0.5 * (v[a] + v[b]) + np.sqrt(3.0) / 2.0 * side / np.maximum(
            np.linalg.norm(side, axis=1), 1e-300)[:, None] * np.linalg.norm(e, axis=1)[:, None]
        targets = np.vstack([v[others].mean(axis=0), apex])
        d = targets - v[i]
        d -= normal * (d @ normal)[:, None]  # in the tangent plane
        return (v[i] + d[:, None, :] * np.array([1.0, 0.5, 0.25])[None, :, None]).reshape(-1, 3)

    def relocate(self, i: int) -> bool:
        """Move vertex ``i`` to the candidate place that most raises the smallest angle of
        its faces (all candidates scored in one batch), if any does."""
        if self.fixed[i]:
            return False
        ring = self.f[self.incident[i]]
        places = self.candidates(i, ring)
        if len(places) == 0:
            return False
        best = _worst(self.v, ring, self.sharp)
        scores = _worst_moved(self.v, ring, self.sharp, i, places)
        best_pos = None
        for k, score in enumerate(scores.tolist()):
            if score > best + 1e-9:
                best, best_pos = score, places[k]
        if best_pos is not None:
            self.v[i] = best_pos
        return best_pos is not None

    def collapse(self, a: int, b: int) -> bool:
        """Merge ``b`` into ``a`` (which keeps its place)."""
        if self.fixed[b] or (self.boundary[b] and not (self.slide[b] or self.straight[b])):
            return False
        if self.boundary[a] and self.boundary[b] and (min(a, b), max(a, b)) not in self.rim_edges:
            return False
        fa, fb = self.incident[a], self.incident[b]
        shared = [t for t in fb if t in fa]
        ring_a = {x for t in fa for x in self.f[t].tolist()} - {a}
        ring_b = {x for t in fb for x in self.f[t].tolist()} - {b}
        opposite = {x for t in shared for x in self.f[t].tolist()} - {a, b}
        if ring_a & ring_b != opposite:  # link condition
            return False

        def change(v, f, fixed, slide):
            f[f == b] = a
            return v, np.delete(f, shared, axis=0), fixed, slide

        return self.attempt(change, sorted(ring_a | ring_b | {a}))

    def clip(self, t: int) -> bool:
        """Drop face ``t`` if it is an ear: a rim vertex's only face, its third edge
        inside the sheet (a needle or a flat spike on the rim, which no move, collapse
        or split mends: its base edge joins two rim vertices across the sheet). The
        tip goes with it; the outline loses the ear's sliver of area."""
        tri = self.f[t].tolist()
        tips = [i for i in tri if len(self.incident[i]) == 1 and not self.fixed[i]]
        if len(tips) != 1:
            return False
        a, b = (i for i in tri if i != tips[0])
        if (min(a, b), max(a, b)) in self.rim_edges:
            return False

        def change(v, f, fixed, slide):
            return v, np.delete(f, [t], axis=0), fixed, slide

        return self.attempt(change, [a, b])

    def split(self, a: int, b: int) -> bool:
        """Split edge ``a-b`` at its midpoint."""
        faces = [t for t in self.incident[a] if t in self.incident[b]]
        rim = len(faces) == 1
        m = len(self.v)

        def change(v, f, fixed, slide):
            new = []
            for t in faces:
                tri = f[t].tolist()
                k = tri.index(a)
                _, y, z = tri[k:] + tri[:k]  # rotated to start at a, winding kept
                new += [(a, m, z), (m, b, z)] if y == b else [(a, y, m), (m, y, b)]
            f = np.vstack([np.delete(f, faces, axis=0), np.asarray(new, dtype=np.int64)])
            return (np.vstack([v, 0.5 * (v[a] + v[b])]), f, np.r_[fixed, False],
                    np.r_[slide, rim and bool(slide[a] and slide[b])])

        around = sorted({x for t in faces for x in self.f[t].tolist()})
        return self.attempt(change, [*around, m])


def improve(vertices: np.ndarray, faces: np.ndarray, fixed: np.ndarray | None = None,
            slide: np.ndarray | None = None, passes: int = 30, moves_only: bool = False):
    """Raise a sheet's smallest angle towards :data:`MIN_ANGLE` by local changes.

    Delaunay flips; then, for each face below the bound, worst first: move one of its
    vertices in the tangent plane (a boundary vertex only if ``slide`` allows it, and
    then only along the rim), else drop it if it is an ear on the rim (``clip``), else
    collapse its shortest edge, else split its longest,
    each only where it raises the smallest angle of the faces it touches (so this
    ends). ``fixed`` vertices never move nor go; with ``moves_only`` the faces are kept
    as they are (no flips, collapses or splits: a mirror-paired mesh stays paired).
    Returns ``(vertices, faces, fixed,
    slide)`` with unused vertices dropped.
    """
    v = np.array(vertices, dtype=np.float64)
    work = _Improver(v, np.array(faces, dtype=np.int64),
                     np.zeros(len(v), dtype=bool) if fixed is None else np.array(fixed, dtype=bool),
                     np.zeros(len(v), dtype=bool) if slide is None else np.array(slide, dtype=bool))
    for _ in range(passes):
        work.refresh(flip=not moves_only)
        q = face_quality(work.v, work.f)
        bad = np.flatnonzero(q < MIN_ANGLE)
        if len(bad) == 0:
            break
        changed = False
        for t in bad[np.argsort(q[bad], kind="stable")].tolist():
            tri = work.f[t].tolist()
            if any([work.relocate(i) for i in tri]):
                changed = True
                continue
            if moves_only:
                continue
            if work.clip(t):
                changed = True
                break
            p = work.v[tri]
            length = np.linalg.norm(p - np.roll(p, -1, axis=0), axis=1)  # edge k: tri[k]-tri[k+1]
            k = int(np.argmin(length))
            a, b = tri[k], tri[(k + 1) % 3]
            if work.collapse(a, b) or work.collapse(b, a):
                changed = True
                break
            k = int(np.argmax(length))
            if work.split(tri[k], tri[(k + 1) % 3]):
                changed = True
                break
        if not changed:
            break
    f = work.f
    used = np.zeros(len(work.v), dtype=bool)
    used[f.ravel()] = True
    remap = np.cumsum(used) - 1
    return work.v[used], remap[f], work.fixed[used], work.slide[used]
