"""Mirror planes of petals and symmetrization about them."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def reflect(points: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """Mirror ``points (N, 3)`` across ``plane = (nx, ny, nz, offset)`` (unit normal)."""
    n, d = plane[:3], plane[3]
    return points - 2.0 * (points @ n - d)[:, None] * n


def asymmetry(points: np.ndarray, plane: np.ndarray) -> float:
    """RMS distance from each mirrored point to the nearest original point."""
    dist, _ = cKDTree(points).query(reflect(points, plane))
    return float(np.sqrt(np.mean(dist ** 2)))


def mirror_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    """The plane a petal is (most nearly) mirror-symmetric about, and its asymmetry.

    Notes
    -----
    A mirror-symmetric point set has its centroid on the mirror plane and the plane's
    normal among the principal axes of its covariance; the candidate with the smallest
    :func:`asymmetry` is taken. The normal's sign is fixed so that its largest component
    is positive (the caller may orient it further).
    """
    p = np.asarray(points, dtype=np.float64)
    c = p.mean(axis=0)
    _, vecs = np.linalg.eigh(np.cov((p - c).T))
    best, best_err = None, np.inf
    for k in range(3):
        n = vecs[:, k]
        n = n * np.sign(n[np.argmax(np.abs(n))])
        plane = np.r_[n, n @ c]
        err = asymmetry(p, plane)
        if err < best_err - 1e-12:
            best, best_err = plane, err
    return best, best_err


def mirror_pairs(points: np.ndarray, plane: np.ndarray, faces: np.ndarray | None = None,
                 tolerance: float = 0.25) -> np.ndarray | None:
    """Index of each point's mirror partner, or None if the points do not pair up.

    Pairs must be mutual nearest neighbours after mirroring, closer than ``tolerance``
    (in mesh units), and, when ``faces`` is given, map every face onto a face.
    """
    tree = cKDTree(points)
    dist, partner = tree.query(reflect(points, plane))
    if np.any(dist > tolerance) or np.any(partner[partner] != np.arange(len(points))):
        return None
    if faces is not None:
        have = {tuple(sorted(f)) for f in faces.tolist()}
        if any(tuple(sorted(partner[f])) not in have for f in faces.tolist()):
            return None
    return partner


def symmetrize(points: np.ndarray, plane: np.ndarray, partner: np.ndarray) -> np.ndarray:
    """Average each point with its partner's mirror image: the result is exactly
    mirror-symmetric (up to rounding), and self-paired points land on the plane."""
    mirrored = reflect(points[partner], plane)
    return 0.5 * (points + mirrored)
