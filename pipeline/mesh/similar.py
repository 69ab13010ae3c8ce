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
#: vertex order), so this admits no other shape, only one within 0.1% of its size,
#: which blooms as it does.
AS_EXPORTED = 1e-3


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
    order, its faces the same array). Sets are indexed by their faces and by the shape of
    their spread (the ratios of their covariance's eigenvalues to its trace: a copy has the
    same), so a new set is compared only with the few of its shape: a thousand blossoms of
    one mesh structure but different shapes cost a look-up each, not a thousand
    comparisons."""

    #: the width of a bin of the spread's ratios, in tolerances: a copy's points within
    #: ``tolerance`` of its size move each ratio by at most about 4 tolerances, so a copy
    #: is in its original's bin or the next
    BIN = 5.0

    def __init__(self, scaled: bool = True, tolerance: float = AS_EXPORTED):
        self.scaled, self.tolerance = scaled, tolerance
        self.bins: dict = {}

    def _keys(self, points: np.ndarray, faces: np.ndarray):
        centred = points - points.mean(axis=0)
        w = np.linalg.eigvalsh(centred.T @ centred)
        trace = float(w.sum())
        ratios = w[1:] / trace if trace > 0.0 else np.zeros(2)
        cell = tuple(int(r) for r in np.floor(ratios / (self.BIN * self.tolerance)))
        structure = (len(points), len(faces), hash(np.ascontiguousarray(faces).tobytes()))
        return structure, cell

    def find(self, points, faces, accept=None):
        """``(payload, s, R, t)`` of a set added before that ``points`` (with ``faces``)
        is a copy of (``points = s original R^T + t``), or None. ``accept(payload, R)``,
        if given, must also agree (a petal's base at the same end)."""
        points = np.asarray(points, dtype=np.float64)
        structure, (a, b) = self._keys(points, faces)
        for da in (-1, 0, 1):
            for db in (-1, 0, 1):
                for original, its_faces, payload in self.bins.get((structure, (a + da, b + db)), ()):
                    if not np.array_equal(its_faces, faces):
                        continue
                    found = similarity(original, points, self.scaled, self.tolerance)
                    if found is not None and (accept is None or accept(payload, found[1])):
                        return (payload, *found)
        return None

    def add(self, points, faces, payload) -> None:
        """Remember ``points`` (with ``faces``) as an original, named by ``payload``."""
        points = np.asarray(points, dtype=np.float64)
        structure, cell = self._keys(points, faces)
        self.bins.setdefault((structure, cell), []).append((points, np.asarray(faces), payload))
