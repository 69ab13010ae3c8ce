"""Whether one point set is a moved, turned and scaled copy of another (instancing)."""

from __future__ import annotations

import numpy as np

#: a copy lies on the moved original to within this fraction of its size (glTF's float32
#: node transforms leave about 1e-7)
TOLERANCE = 1e-6


def similarity(a: np.ndarray, b: np.ndarray, scaled: bool = True,
               tolerance: float = TOLERANCE):
    """The similarity transform that puts ``a`` on ``b`` point for point, if there is one.

    Parameters
    ----------
    a, b : (n, 3) float
        Two point sets in corresponding order (an instanced copy keeps its vertex order).
    scaled : bool
        Allow a uniform scale (else the scale is 1).
    tolerance : float
        Largest distance of a moved point from its partner, as a fraction of the diagonal
        of ``b``'s bounding box.

    Returns
    -------
    (s, R, t) or None
        ``b = s a R^T + t`` within the tolerance, ``R`` a rotation (det +1: a mirror
        image is not a copy, its faces are turned over), or None.

    Notes
    -----
    Umeyama's least-squares similarity (the SVD of the cross-covariance), then a check of
    every point. Deterministic; the cost is one 3 x 3 SVD and a pass over the points.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape or len(a) < 3:
        return None
    ma, mb = a.mean(axis=0), b.mean(axis=0)
    ca, cb = a - ma, b - mb
    var = float(np.sum(ca * ca))
    size = float(np.linalg.norm(np.ptp(b, axis=0)))
    if var <= 0.0 or size <= 0.0:
        return None
    u, w, vt = np.linalg.svd(ca.T @ cb)
    rot = vt.T @ u.T
    if np.linalg.det(rot) <= 0.0:
        return None
    s = float(w.sum() / var) if scaled else 1.0
    t = mb - s * ma @ rot.T
    if np.abs(s * a @ rot.T + t - b).max() > tolerance * size:
        return None
    return s, rot, t
