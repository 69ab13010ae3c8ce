"""Whether one point set is a moved, turned and scaled copy of another (instancing)."""

from __future__ import annotations

import numpy as np

#: a copy lies on the moved original to within this fraction of its size (glTF's float32
#: node transforms leave about 1e-7; Bloom's own copies, placed by the transform, 1e-15)
TOLERANCE = 1e-6
#: a copy in a file as artists export it: its vertices written out, not its transform.
#: An OBJ's 6 decimals (Blender's exporter) leave 5e-7 of the file's unit on every
#: coordinate, float32 6e-8 of the coordinate's size: in metres, a 5 mm petal on a branch
#: is a copy to 2e-4 of its size, not 1e-6. Copies are matched point for point (the same
#: vertex order), so this admits no other shape, only one within 0.03% of its size.
#: (At 1e-3 the water lily's 44 petals gave 28 copies, not 22, and its bloom took over
#: 900 s instead of 205: petals alike to 0.1% are not alike enough to bloom alike.)
AS_EXPORTED = 3e-4


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


class Copies:
    """The point sets seen so far, to find which one a new set is a copy of
    (:func:`similarity`: moved, turned and, if ``scaled``, scaled; its points in the same
    order, its faces the same array). Sets are indexed by their faces and by five numbers
    a copy shares with its original (:meth:`_features`), so a new set is compared only
    with the few of nearly its shape: a thousand blossoms of one mesh structure but
    different shapes cost a look-up each, not a thousand comparisons."""

    #: the width of an index cell, in tolerances: a copy whose points lie within
    #: ``tolerance`` of its size from its original's moves each feature by at most about
    #: 8 tolerances (a radius over the RMS radius, on a petal 3.5 times as long as that),
    #: under half a cell, so its original is in its cell or the next on its nearer side
    CELL = 20.0

    def __init__(self, scaled: bool = True, tolerance: float = AS_EXPORTED):
        self.scaled, self.tolerance = scaled, tolerance
        self.bins: dict = {}

    @staticmethod
    def _radii(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """What a moved, turned and scaled copy (its points in the same order) shares with
        its original: the two larger eigenvalues of its spread over their sum, and every
        vertex's distance from the centroid over the RMS distance."""
        centred = points - points.mean(axis=0)
        w = np.linalg.eigvalsh(centred.T @ centred)
        trace = float(w.sum())
        if trace <= 0.0:
            return np.zeros(2), np.zeros(len(points))
        return w[1:] / trace, np.linalg.norm(centred, axis=1) / np.sqrt(trace / len(points))

    @classmethod
    def _features(cls, points: np.ndarray) -> np.ndarray:
        """Five of those numbers: the two ratios, and the radii of three vertices (the
        first, one at a third, one at two thirds)."""
        ratios, radii = cls._radii(points)
        n = len(points)
        return np.r_[ratios, radii[[0, n // 3, (2 * n) // 3]]]

    def _cells(self, points: np.ndarray, faces: np.ndarray, near: bool):
        """The index keys of ``points``: its own cell, or (``near``) that and every cell
        one over on a feature's nearer side (32 in all)."""
        structure = (len(points), len(faces), hash(np.ascontiguousarray(faces).tobytes()))
        scaled = self._features(points) / (self.CELL * self.tolerance)
        own = np.floor(scaled).astype(np.int64)
        if not near:
            return [(structure, tuple(own.tolist()))]
        side = np.where(scaled - own < 0.5, -1, 1)
        keys = []
        for corner in range(1 << len(own)):
            step = np.array([(corner >> i) & 1 for i in range(len(own))]) * side
            keys.append((structure, tuple((own + step).tolist())))
        return keys

    def find(self, points, faces, accept=None):
        """``(payload, s, R, t)`` of a set added before that ``points`` (with ``faces``)
        is a copy of (``points = s original R^T + t``), or None. ``accept(payload, R)``,
        if given, must also agree (a petal's base at the same end)."""
        points = np.asarray(points, dtype=np.float64)
        if not self.bins:
            return None
        radii = self._radii(points)[1]
        for key in self._cells(points, faces, near=True):
            for original, its_faces, its_radii, payload in self.bins.get(key, ()):
                # (every radius within half a cell first: one pass, where the fit is an SVD)
                if (np.abs(its_radii - radii).max() > 0.5 * self.CELL * self.tolerance
                        or not np.array_equal(its_faces, faces)):
                    continue
                found = similarity(original, points, self.scaled, self.tolerance)
                if found is not None and (accept is None or accept(payload, found[1])):
                    return (payload, *found)
        return None

    def add(self, points, faces, payload) -> None:
        """Remember ``points`` (with ``faces``) as an original, named by ``payload``."""
        points = np.asarray(points, dtype=np.float64)
        key = self._cells(points, faces, near=False)[0]
        self.bins.setdefault(key, []).append((points, np.asarray(faces), self._radii(points)[1],
                                              payload))
