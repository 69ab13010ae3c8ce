"""Measurements of a bloom: opening angle per petal, energies."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class PetalFrames:
    """Per petal, what the opening angle is measured against (taken on the initial mesh).

    The opening angle is the rotation of the chord from the base's centre to the tip,
    within the plane of the initial chord and the petal's outward direction (from the
    petal's centroid toward its midrib, i.e. away from the cup); positive is outward.
    """

    base_centers: np.ndarray  #: (P, 3) centroid of each petal's fixed base vertices
    tips: np.ndarray  #: (P,) tip vertex index
    chord_dirs: np.ndarray  #: (P, 3) unit initial chord
    outward_dirs: np.ndarray  #: (P, 3) unit outward direction, perpendicular to the chord

    @classmethod
    def from_mesh(cls, vertices, petal, base, on_axis, tips, plane) -> PetalFrames:
        v = np.asarray(vertices, dtype=np.float64)
        count = int(petal.max()) + 1 if len(petal) else 0
        centers, chords, outs = [], [], []
        for p in range(count):
            mine = petal == p
            b = mine & base
            center = v[b].mean(axis=0) if b.any() else v[mine].mean(axis=0)
            chord = v[tips[p]] - center
            chord /= np.linalg.norm(chord)
            axis_pts = mine & on_axis
            ref = v[axis_pts].mean(axis=0) if axis_pts.any() else v[mine].mean(axis=0)
            out = ref - v[mine].mean(axis=0)
            out -= chord * (out @ chord)
            if np.linalg.norm(out) < 1e-9:  # a flat petal: take its normal (plane x chord)
                out = np.cross(plane[p, :3], chord)
            out /= np.linalg.norm(out)
            centers.append(center)
            chords.append(chord)
            outs.append(out)
        return cls(np.array(centers).reshape(-1, 3), np.asarray(tips, dtype=np.int64),
                   np.array(chords).reshape(-1, 3), np.array(outs).reshape(-1, 3))

    def opening_angles(self, X) -> np.ndarray:
        """``(P,)`` opening angle of each petal in degrees (0 on the initial mesh)."""
        chord = np.asarray(X)[self.tips] - self.base_centers
        along = np.einsum("ij,ij->i", chord, self.chord_dirs)
        out = np.einsum("ij,ij->i", chord, self.outward_dirs)
        return np.degrees(np.arctan2(out, along))
