"""The nearest point of a triangle mesh to query points: :func:`closest_points` (exact,
over all triangles or a subset) and :func:`nearest_among` (over given candidate pairs).
Both break ties toward the lower face index, so the answer does not depend on the
search's order. Used to bind a user's mesh to the sheet (:mod:`pipeline.io.binding`) and
to find where petals pass through each other (:mod:`pipeline.mesh.separate`)."""

from __future__ import annotations

from itertools import chain

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

#: points are bound in chunks of this many (bounds the memory of the candidate pairs)
CHUNK = 4096


@njit(cache=True)
def _closest_bary(p, a, b, c):
    """Barycentric coordinates of the point of triangle ``a, b, c`` closest to ``p``
    (Ericson, Real-Time Collision Detection, 5.1.5); a degenerate triangle gives its
    nearest corner."""
    ab0, ab1, ab2 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    ac0, ac1, ac2 = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    ap0, ap1, ap2 = p[0] - a[0], p[1] - a[1], p[2] - a[2]
    d1 = ab0 * ap0 + ab1 * ap1 + ab2 * ap2
    d2 = ac0 * ap0 + ac1 * ap1 + ac2 * ap2
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0
    bp0, bp1, bp2 = p[0] - b[0], p[1] - b[1], p[2] - b[2]
    d3 = ab0 * bp0 + ab1 * bp1 + ab2 * bp2
    d4 = ac0 * bp0 + ac1 * bp1 + ac2 * bp2
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0 and d1 - d3 != 0.0:
        t = d1 / (d1 - d3)
        return 1.0 - t, t, 0.0
    cp0, cp1, cp2 = p[0] - c[0], p[1] - c[1], p[2] - c[2]
    d5 = ab0 * cp0 + ab1 * cp1 + ab2 * cp2
    d6 = ac0 * cp0 + ac1 * cp1 + ac2 * cp2
    if d6 >= 0.0 and d5 <= d6:
        return 0.0, 0.0, 1.0
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0 and d2 - d6 != 0.0:
        t = d2 / (d2 - d6)
        return 1.0 - t, 0.0, t
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0 and (d4 - d3) + (d5 - d6) != 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return 0.0, 1.0 - t, t
    denom = va + vb + vc
    if denom != 0.0 and np.isfinite(denom):
        v, w = vb / denom, vc / denom
        return 1.0 - v - w, v, w
    best, k = np.inf, 0  # degenerate: the nearest corner
    for j, corner in enumerate((a, b, c)):
        d = (p[0] - corner[0]) ** 2 + (p[1] - corner[1]) ** 2 + (p[2] - corner[2]) ** 2
        if d < best:
            best, k = d, j
    return (1.0 if k == 0 else 0.0), (1.0 if k == 1 else 0.0), (1.0 if k == 2 else 0.0)


@njit(cache=True)
def _nearest_kernel(q, X, F, rows, cand, face, bary, dist, has):
    for k in range(len(rows)):
        r, f = rows[k], cand[k]
        a, b, c = X[F[f, 0]], X[F[f, 1]], X[F[f, 2]]
        u, v, w = _closest_bary(q[r], a, b, c)
        d = 0.0
        for i in range(3):
            d += (u * a[i] + v * b[i] + w * c[i] - q[r, i]) ** 2
        d = np.sqrt(d)
        if not has[r] or d < dist[r] or (d == dist[r] and f < face[r]):
            has[r] = True
            face[r], dist[r] = f, d
            bary[r, 0], bary[r, 1], bary[r, 2] = u, v, w


class Triangles:
    """Some triangles of a mesh (``ids`` of ``faces``), ready for closest-point queries:
    :meth:`nearest`. Exact: the closest point is no further than the nearest corner
    (d0), in a triangle whose centre is within ``radius`` of every point of it (its
    corners' largest distance from the centre, the largest over the triangles); so every
    triangle whose centre is within ``d0 + radius`` is measured (a k-d tree of corners,
    one of centres)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, ids: np.ndarray):
        self.X = np.ascontiguousarray(vertices, dtype=np.float64)
        self.F = np.ascontiguousarray(faces, dtype=np.int64)
        self.ids = np.asarray(ids, dtype=np.int64)
        if len(self.ids) == 0:
            raise ValueError("no triangles to find the nearest point on")
        tri = self.X[self.F[self.ids]]
        centre = tri.mean(axis=1)
        self.radius = float(np.max(np.linalg.norm(tri - centre[:, None], axis=2)))
        self.corners = cKDTree(self.X[np.unique(self.F[self.ids])])
        self.centres = cKDTree(centre)

    def nearest(self, q: np.ndarray, reach: float = np.inf):
        """The nearest point of these triangles to each of ``q`` (n, 3) that can be within
        ``reach``: ``(row, face, bary, distance)`` as :func:`nearest_among` (``row`` into
        ``q``; a point further than ``reach`` may be among them, none nearer is left out)."""
        q = np.asarray(q, dtype=np.float64)
        d0, _ = self.corners.query(q)
        # (no corner within reach + radius: every point of every triangle is beyond reach)
        can = np.flatnonzero(d0 - 2.0 * self.radius <= reach)
        near = self.centres.query_ball_point(q[can], (d0[can] + self.radius) * (1 + 1e-9))
        count = np.fromiter(map(len, near), dtype=np.int64, count=len(near))
        cand = np.fromiter(chain.from_iterable(near), dtype=np.int64, count=int(count.sum()))
        return nearest_among(q, self.X, self.F, np.repeat(can, count), self.ids[cand])


def closest_points(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                   allowed: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """For each point, the closest point on the triangles ``faces`` (only those where
    ``allowed``, a ``(F,) bool``): ``(face (n,), bary (n, 3))``, exact (:class:`Triangles`).
    Ties go to the lower face index, so the answer does not depend on the search's order."""
    P = np.asarray(points, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    found = Triangles(vertices, F, np.flatnonzero(np.ones(len(F), dtype=bool)
                                                  if allowed is None else allowed))
    face = np.empty(len(P), dtype=np.int64)
    bary = np.empty((len(P), 3))
    for lo in range(0, len(P), CHUNK):
        r, f, b, _ = found.nearest(P[lo:lo + CHUNK])
        face[lo + r], bary[lo + r] = f, b
    return face, bary


def nearest_among(q: np.ndarray, vertices: np.ndarray, faces: np.ndarray, rows: np.ndarray,
                  cand: np.ndarray):
    """The nearest of some candidate triangles to each query point: the pairs
    ``(rows[k], cand[k])`` say that triangle ``cand[k]`` is a candidate for point
    ``q[rows[k]]``. Returns ``(row, face, bary, distance)``, one entry per row that has
    candidates, in row order; ties go to the lower face index (so the answer does not
    depend on the candidates' order)."""
    n = len(q)
    face = np.zeros(n, dtype=np.int64)
    bary = np.zeros((n, 3))
    dist = np.zeros(n)
    has = np.zeros(n, dtype=np.bool_)
    _nearest_kernel(np.ascontiguousarray(q, dtype=np.float64),
                    np.ascontiguousarray(vertices, dtype=np.float64),
                    np.ascontiguousarray(faces, dtype=np.int64),
                    np.asarray(rows, dtype=np.int64), np.asarray(cand, dtype=np.int64),
                    face, bary, dist, has)
    r = np.flatnonzero(has)
    return r, face[r], bary[r], dist[r]
