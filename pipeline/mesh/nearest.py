"""The nearest point of a triangle mesh to query points, among candidate triangles: the
kernel the binding (:mod:`pipeline.io.binding`) and the separation of petals
(:mod:`pipeline.mesh.separate`) share."""

from __future__ import annotations

import numpy as np
from numba import njit


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
