"""What the shell's kernels (:mod:`pipeline.sim.terms.shell_kernels`) need of the mesh,
built once per model (plain numpy): each face's opposite vertices and boundary stand-ins
(its patch stencil, :func:`face_stencil`), the ghost rows where no vertex stands in, the
fixed anchors beyond a clamped base edge, each face's edges, and the Hessian's block
pattern with each face's slots (:func:`face_pattern`)."""

from __future__ import annotations

from itertools import combinations

import numpy as np

from pipeline.mesh import topology
from pipeline.mesh.hinge import dihedral_angles


def face_opposite(faces: np.ndarray) -> np.ndarray:
    """``(F, 3)`` the vertex across the edge opposite each corner (the third vertex of the
    face on the other side), -1 on the boundary (:func:`face_across`)."""
    return face_across(faces)[0]


def face_across(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(vertex (F, 3), face (F, 3))``: across the edge opposite each corner, the third
    vertex of the face on the other side and that face; -1 on the boundary.

    Notes
    -----
    Corner ``i``'s opposite edge runs ``q_{i+1} -> q_{i+2}``; the face across runs it the
    other way (a consistently oriented, edge-manifold mesh: ``topology.hinges`` checks)."""
    f = np.ascontiguousarray(faces, dtype=np.int64)
    he, opposite = topology.half_edges(f)  # (a,b),(b,c),(c,a); opposite c, a, b
    nf = len(f)
    n = int(f.max()) + 1 if f.size else 0
    key = he[:, 0] * n + he[:, 1]
    twin_key = he[:, 1] * n + he[:, 0]
    order = np.argsort(key, kind="stable")
    pos = np.minimum(np.searchsorted(key[order], twin_key), len(key) - 1)
    found = key[order][pos] == twin_key
    vertex = np.where(found, opposite[order][pos], -1)
    face = np.where(found, order[pos] % max(nf, 1), -1)
    # half-edge (a, b) of face f is the edge opposite corner c: corner 2; (b, c): 0; (c, a): 1
    out = np.empty((2, nf, 3), dtype=np.int64)
    for k, h in enumerate((vertex, face)):
        out[k, :, 2] = h[:nf]
        out[k, :, 0] = h[nf:2 * nf]
        out[k, :, 1] = h[2 * nf:]
    return out[0], out[1]


#: a boundary face's stand-in vertex must make its patch system at least this well
#: conditioned (``|det G|`` over the product of its rows' norms, 1 for orthogonal rows;
#: an interior face of a lattice scores 0.63); else the ghost row is kept
STENCIL_SCORE = 0.05


def _patch_rows(X, face, others) -> np.ndarray:
    """The patch system's rows of the points ``others`` for the face (rest geometry)."""
    q0, q1, q2 = X[face]
    e1, e2 = q1 - q0, q2 - q0
    a = np.array([[e1 @ e1, e1 @ e2], [e1 @ e2, e2 @ e2]])
    d = X[others] - q0
    xi = np.linalg.solve(a, np.stack([d @ e1, d @ e2]))
    l0 = 1.0 - xi[0] - xi[1]
    return np.stack([xi[0] * xi[1], xi[1] * l0, xi[0] * l0], axis=1)


#: a fold sharper than this between two faces (their normals' angle, rad) is a crease
#: (:func:`creases`): the default scenes' sharpest is 16 deg; a real lily's keeled midrib
#: of 45-60 deg at rest sharpens toward 90 on the way to its bud, where the patch fails
#: (docs/shell.md)
CREASE_ANGLE = np.radians(30.0)


def _below_crease(X, face, others) -> np.ndarray:
    """Which of ``others`` rise from the face's plane at less than :data:`CREASE_ANGLE`
    (seen from the face's centroid): a stand-in across a crease would fit the fold."""
    q0, q1, q2 = X[face]
    n = np.cross(q1 - q0, q2 - q0)
    n /= np.linalg.norm(n)
    d = X[others] - (q0 + q1 + q2) / 3.0
    h = np.abs(d @ n)
    return h <= np.tan(CREASE_ANGLE) * np.linalg.norm(d - np.outer(d @ n, n), axis=1)


def face_stencil(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(F, 3)``: the vertices each face's patch quadratic is fitted to besides its
    corners: the vertex across each edge (:func:`face_opposite`) and, where an edge is on
    the boundary (no vertex across), a stand-in: the vertex of a face around the face's
    corners that best conditions the fit (on the rest shape; -1 if none does, see
    :data:`STENCIL_SCORE`: then the edge's ghost row is used).

    Why: a ghost row (the surface continued flat across the rim) is wrong by O(1) on a
    strip of width h along the rim, and the energy converges only to first order (and
    the rim is where a petal's growth acts). A real vertex keeps the fit exact for any
    quadratic surface, the rim included: the energy of a rolled or capped sheet then
    converges to second order (``tests/test_shell.py``)."""
    X = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    opp = face_opposite(f)
    out = opp.copy()
    lone = np.flatnonzero((opp < 0).any(axis=1))
    if len(lone) == 0:
        return out
    corners = topology.by_label(f.ravel(), len(X))  # (each vertex's corners: face = // 3)
    taken = np.zeros(len(X), dtype=bool)
    for k in lone:
        face, row = f[k], opp[k]
        ring = np.unique(f[np.concatenate([corners[c] for c in face]) // 3])
        drop = np.r_[face, row[row >= 0]]
        taken[drop] = True
        cand = ring[~taken[ring]]
        taken[drop] = False
        cand = cand[_below_crease(X, face, cand)]
        missing = np.flatnonzero(row < 0)
        have = row[row >= 0]
        if len(cand) < len(missing):
            continue
        if len(missing) == 1:  # (the common case, all candidates at once)
            rows = _patch_rows(X, face, np.r_[have, cand])
            a, b, c = rows[0], rows[1], rows[2:]
            norm = np.linalg.norm(a) * np.linalg.norm(b) * np.linalg.norm(c, axis=1)
            score = np.abs(c @ np.cross(a, b)) / np.where(norm > 0.0, norm, np.inf)
            pick = int(np.argmax(score))
            if score[pick] > STENCIL_SCORE:
                out[k, missing[0]] = cand[pick]
            continue
        best, score = None, STENCIL_SCORE
        for combo in combinations(cand.tolist(), len(missing)):
            rows = _patch_rows(X, face, np.r_[have, combo].astype(np.int64))
            norm = np.prod(np.linalg.norm(rows, axis=1))
            s = abs(np.linalg.det(rows)) / norm if norm > 0.0 else 0.0
            if s > score:
                best, score = combo, s
        if best is not None:
            out[k, missing] = best
    return out


def creases(vertices: np.ndarray, faces: np.ndarray, opposite: np.ndarray,
            bending: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The folds of the rest surface too sharp for the patch quadratic: an interior edge
    whose two faces' normals turn more than :data:`CREASE_ANGLE` (a petal's keeled
    midrib, a pleat). Returns ``(crease (F, 3, 2), opposite (F, 3))``.

    Why: the patch is a height field over its face's plane. Across a fold of 90 deg the
    vertex beyond the edge stands straight above the edge's line: its row of the patch
    system tends to 0, the fitted curvature to infinity (a 90-108 deg midrib of a real
    lily gave curvatures of 1,200 per edge, forces 1e10 times the sheet's), and no
    equilibrium is found. A crease is instead a hinge, as in discrete shells
    (Grinspun et al. 2003): ``k (1 - cos(theta - theta0))`` with ``k = 3 D |e|^2 / (A1 +
    A2)`` (``D`` the two faces' mean bending modulus: the energy ``D/2 kappa^2`` of the
    fold spread over a strip of a third of the faces' heights), carried by the face of
    the lower index (``crease[f, i] = (k, theta0)``; 0 elsewhere), and both faces fit
    their patch as if the surface went on flat across the edge (its ghost row; in the
    returned ``opposite`` the other face no longer names the vertex across). A smooth
    surface has no crease once its mesh is fine enough; a real crease stays one at
    any resolution."""
    X = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    across, beyond = face_across(f)
    crease = np.zeros((len(f), 3, 2))
    opp = np.array(opposite, dtype=np.int64, copy=True)
    faces_, corners = np.nonzero(across >= 0)
    if len(faces_) == 0:
        return crease, opp
    a, b = f[faces_, (corners + 1) % 3], f[faces_, (corners + 2) % 3]
    q, o = f[faces_, corners], across[faces_, corners]
    other = beyond[faces_, corners]
    theta = dihedral_angles(X, np.stack([a, b, q, o], axis=1))
    carry = (np.abs(theta) > CREASE_ANGLE) & (faces_ < other)  # (the lower index carries it)
    if not carry.any():
        return crease, opp
    area = 0.5 * np.linalg.norm(np.cross(X[f[:, 1]] - X[f[:, 0]], X[f[:, 2]] - X[f[:, 0]]),
                                axis=1)
    face, i, other, o = faces_[carry], corners[carry], other[carry], o[carry]
    e = X[b[carry]] - X[a[carry]]
    stiff = (3.0 * 0.5 * (bending[face] + bending[other]) * np.sum(e * e, axis=1)
             / (area[face] + area[other]))
    crease[face, i, 0] = stiff
    crease[face, i, 1] = theta[carry]
    opp[other, np.argmax(f[other] == o[:, None], axis=1)] = -1  # (its corner across)
    return crease, opp


def crease_angles(vertices, faces: np.ndarray, opposite: np.ndarray,
                  crease: np.ndarray) -> np.ndarray:
    """``(F, 3)`` the dihedral angle at ``vertices`` of each crease a face carries (as
    :func:`creases` measures it; 0 where none)."""
    out = np.zeros(crease.shape[:2])
    face, corner = np.nonzero(crease[:, :, 0] > 0.0)
    if len(face):
        f = np.asarray(faces, dtype=np.int64)
        hinges = np.stack([f[face, (corner + 1) % 3], f[face, (corner + 2) % 3],
                           f[face, corner], opposite[face, corner]], axis=1)
        out[face, corner] = dihedral_angles(vertices, hinges)
    return out


def ghost_rows(vertices: np.ndarray, faces: np.ndarray, opposite: np.ndarray) -> np.ndarray:
    """``(F, 3, 3)``: for a boundary edge (no vertex across), the row of the patch system
    at the face's corner mirrored across that edge (in the rest face), whose height is 0:
    ``(l1 l2, l2 l0, l0 l1)`` at its barycentric coordinates. Other rows are 0 (unused)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    out = np.zeros((len(f), 3, 3))
    for i in range(3):
        lone = opposite[:, i] < 0
        if not lone.any():
            continue
        qi, a, b = v[f[lone, i]], v[f[lone, (i + 1) % 3]], v[f[lone, (i + 2) % 3]]
        t = b - a
        s = np.einsum("ij,ij->i", qi - a, t) / np.einsum("ij,ij->i", t, t)
        lam = np.empty((lone.sum(), 3))
        lam[:, i] = -1.0
        lam[:, (i + 1) % 3] = 2.0 * (1.0 - s)
        lam[:, (i + 2) % 3] = 2.0 * s
        out[lone, i, 0] = lam[:, 1] * lam[:, 2]
        out[lone, i, 1] = lam[:, 2] * lam[:, 0]
        out[lone, i, 2] = lam[:, 0] * lam[:, 1]
    return out


def clamped_anchors(vertices, faces, opposite, pinned):
    """Anchors for the fixed base edge: ``(faces (k,), corners (k,), points (k, 3))``.
    A boundary edge whose two ends are fixed is clamped: its face's patch is fitted, for
    that edge, to a fixed point, the face's third corner mirrored across the edge in
    the rest face's plane (the rest surface continued flat into the receptacle). The
    face then cannot turn about the edge without bending: a clamped edge, discretized
    as consistently as the rest of the patch (the fixed vertices alone make a hinge of
    a nearly straight base; a band of fixed vertices clamps wherever its last row
    happens to fall)."""
    X = np.asarray(vertices, dtype=np.float64)
    fixed = np.asarray(pinned, dtype=bool)
    faces_out, corners, points = [], [], []
    for i in range(3):
        a, b = faces[:, (i + 1) % 3], faces[:, (i + 2) % 3]
        held = (opposite[:, i] < 0) & fixed[a] & fixed[b] & ~fixed[faces[:, i]]
        for f in np.flatnonzero(held):
            q, p, r = X[faces[f, i]], X[a[f]], X[b[f]]
            t = r - p
            foot = p + (q - p) @ t / (t @ t) * t
            faces_out.append(f)
            corners.append(i)
            points.append(2.0 * foot - q)
    return (np.asarray(faces_out, dtype=np.int64), np.asarray(corners, dtype=np.int64),
            np.asarray(points, dtype=np.float64).reshape(-1, 3))


def face_edges(faces: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """``(F, 3)`` index into ``edges`` of the edge opposite each corner."""
    f = np.asarray(faces, dtype=np.int64)
    e = np.asarray(edges, dtype=np.int64)
    n = int(max(f.max(), e.max())) + 1
    ekey = np.minimum(e[:, 0], e[:, 1]) * n + np.maximum(e[:, 0], e[:, 1])
    order = np.argsort(ekey, kind="stable")
    out = np.empty((len(f), 3), dtype=np.int64)
    for i in range(3):
        a, b = f[:, (i + 1) % 3], f[:, (i + 2) % 3]
        key = np.minimum(a, b) * n + np.maximum(a, b)
        pos = np.minimum(np.searchsorted(ekey[order], key), len(e) - 1)
        if np.any(ekey[order][pos] != key):
            raise ValueError("a face's edge is not among the model's edges")
        out[:, i] = order[pos]
    return out


def face_pattern(vertex_count: int, faces: np.ndarray, opposite: np.ndarray,
                 extra_pairs: np.ndarray | None = None):
    """The BSR pattern (``indptr``, ``indices``) of the shell's Hessian and each face's
    slots ``(F, 36)``: the block of its vertex pair (r, c), r, c in q0, q1, q2, o0, o1,
    o2 (-1 where the face has no vertex across an edge). A face couples its corners with
    the vertices across its edges, so the pattern is wider than the springs' (a vertex
    meets its two-ring, in part). ``extra_pairs (k, 2)``: more vertex pairs to include
    (both orders)."""
    f = np.asarray(faces, dtype=np.int64)
    six = np.concatenate([f, np.asarray(opposite, dtype=np.int64)], axis=1)  # (F, 6)
    n = vertex_count
    rows = np.repeat(six, 6, axis=1)
    cols = np.tile(six, (1, 6))
    ok = (rows >= 0) & (cols >= 0) & (rows < n) & (cols < n)  # (not the fixed anchors)
    diag = np.arange(n, dtype=np.int64)
    r = [rows[ok], diag]
    c = [cols[ok], diag]
    if extra_pairs is not None and len(extra_pairs):
        p = np.asarray(extra_pairs, dtype=np.int64)
        r += [p[:, 0], p[:, 1]]
        c += [p[:, 1], p[:, 0]]
    key = np.unique(np.concatenate(r) * n + np.concatenate(c))
    indices = (key % n).astype(np.int64)
    indptr = np.searchsorted(key // n, np.arange(n + 1)).astype(np.int64)
    slots = np.where(ok, np.searchsorted(key, np.where(ok, rows * n + cols, 0)), -1)
    return indptr, indices, np.ascontiguousarray(slots.astype(np.int64))
