"""Scoring places for a vertex: the smallest triangle angle of its faces with the vertex
moved to each place (compiled: :func:`pipeline.mesh.remesh.improve` asks this hundreds of
thousands of times on a studio-sized model)."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def worst_angles(v: np.ndarray, faces: np.ndarray, sharp: np.ndarray, i: int,
                 places: np.ndarray, check_normals: bool) -> np.ndarray:
    """(C,) for each of ``places (C, 3)``: the smallest angle in degrees of ``faces
    (R, 3)`` with vertex ``i`` moved there (``i`` = -1: none moved), angles at ``sharp
    (V,)`` vertices excepted; -1 where a face has no area or (``check_normals``) turned
    against its normal before the move.

    Notes
    -----
    The same arithmetic as :func:`pipeline.mesh.remesh.triangle_angles` (atan2 of the cross
    product's length and the dot product, in that order of operations), a place at a
    time, so the scores do not depend on how many places are asked at once.
    """
    count = places.shape[0]
    out = np.empty(count)
    p = np.empty((3, 3))
    normals = np.empty((faces.shape[0], 3))
    if check_normals:
        for r in range(faces.shape[0]):
            a, b, c = faces[r, 0], faces[r, 1], faces[r, 2]
            ex, ey, ez = v[b, 0] - v[a, 0], v[b, 1] - v[a, 1], v[b, 2] - v[a, 2]
            fx, fy, fz = v[c, 0] - v[a, 0], v[c, 1] - v[a, 1], v[c, 2] - v[a, 2]
            normals[r, 0] = ey * fz - ez * fy
            normals[r, 1] = ez * fx - ex * fz
            normals[r, 2] = ex * fy - ey * fx
    for c in range(count):
        worst = 180.0
        bad = False
        for r in range(faces.shape[0]):
            for k in range(3):
                src = faces[r, k]
                for d in range(3):
                    p[k, d] = places[c, d] if src == i else v[src, d]
            ex, ey, ez = p[1, 0] - p[0, 0], p[1, 1] - p[0, 1], p[1, 2] - p[0, 2]
            fx, fy, fz = p[2, 0] - p[0, 0], p[2, 1] - p[0, 1], p[2, 2] - p[0, 2]
            nx, ny, nz = ey * fz - ez * fy, ez * fx - ex * fz, ex * fy - ey * fx
            if nx == 0.0 and ny == 0.0 and nz == 0.0:
                bad = True
                break
            if check_normals and nx * normals[r, 0] + ny * normals[r, 1] + nz * normals[r, 2] <= 0.0:
                bad = True
                break
            for k in range(3):
                if sharp[faces[r, k]]:
                    continue
                k1, k2 = (k + 1) % 3, (k + 2) % 3
                ax, ay, az = p[k1, 0] - p[k, 0], p[k1, 1] - p[k, 1], p[k1, 2] - p[k, 2]
                bx, by, bz = p[k2, 0] - p[k, 0], p[k2, 1] - p[k, 1], p[k2, 2] - p[k, 2]
                cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
                angle = np.degrees(np.arctan2(np.sqrt(cx * cx + cy * cy + cz * cz),
                                              ax * bx + ay * by + az * bz))
                if angle < worst:
                    worst = angle
        out[c] = -1.0 if bad else worst
    return out
