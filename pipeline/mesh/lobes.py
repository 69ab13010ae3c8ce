"""Petals joined in one surface: which lobe of a ring each face belongs to."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from pipeline.mesh import topology

#: faces farther from the axis than this fraction of the farthest make the angular profile
OUTER = 0.4
#: the profile is smoothed with a Gaussian of this many degrees
SMOOTH_DEGREES = 5.0
#: two neighbouring peaks are separate lobes when the profile between them falls under
#: this fraction of the lower peak
DEEP = 0.5
#: a peak lower than this fraction of the highest is noise, not a petal
MIN_PEAK = 0.2
#: fewer lobes than this is not a ring of petals (a single petal's base and tip are two)
MIN_LOBES = 3
#: seeds: outer faces within this many degrees of a lobe's peak
SEED_DEGREES = 10.0
#: the hub cut is never farther out than this fraction of the farthest face
HUB_MAX = 0.4


class Lobes(NamedTuple):
    """Result of :func:`lobes`."""

    label: np.ndarray  #: (F,) int, the lobe of each face, numbered by angle from the first peak
    count: int  #: number of lobes (1 when the surface is not a ring of petals)
    centre: np.ndarray  #: (3,) area-weighted centroid of the faces
    axis: np.ndarray  #: (3,) unit, the normal of the ring's best-fit plane
    radius: np.ndarray  #: (F,) distance of each face's centroid from the axis
    hub_radius: float  #: faces nearer the axis than this are where the lobes join (0 if one)


def plane_frame(v: np.ndarray, f: np.ndarray):
    """The area-weighted best-fit plane through the face centroids: ``(centre (3,), axes
    (3, 3) rows by decreasing spread (the last is the normal), face areas (F,), face
    centroids (F, 3))``."""
    area = 0.5 * np.linalg.norm(topology.face_normals(v, f), axis=1)
    centroid = v[f].mean(axis=1)
    centre = (centroid * area[:, None]).sum(axis=0) / max(area.sum(), np.finfo(float).tiny)
    spread = (centroid - centre) * np.sqrt(area)[:, None]
    # the thin SVD: its U is (F, 3), not (F, F) (100,000 faces made a 74 GiB U); rows of
    # zeros, which change nothing, make up three when there are fewer faces
    spread = np.vstack([spread, np.zeros((max(0, 3 - len(spread)), 3))])
    _, _, axes = np.linalg.svd(spread, full_matrices=False)
    return centre, axes, area, centroid


def angular_profile(angle_degrees: np.ndarray, weight: np.ndarray,
                    sigma: float = SMOOTH_DEGREES) -> np.ndarray:
    """(360,) weight per whole degree of angle, smoothed circularly by a Gaussian."""
    h = np.bincount(np.floor(angle_degrees).astype(np.int64) % 360, weights=weight, minlength=360)
    x = np.arange(-int(4 * sigma), int(4 * sigma) + 1)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    pad = len(x) // 2
    return np.convolve(np.r_[h[-pad:], h, h[:pad]], k / k.sum(), mode="same")[pad:-pad]


def profile_peaks(profile: np.ndarray, deep: float = DEEP) -> list[int]:
    """Indices of the peaks of a circular profile that are separate lobes.

    Local maxima under ``MIN_PEAK`` of the highest are dropped; the rest are merged,
    shallowest valley first, while the lowest point between two neighbouring peaks is at
    least ``deep`` times the lower of them (the lower peak goes).
    """
    d = np.asarray(profile, dtype=np.float64)
    n = len(d)
    peaks = [i for i in range(n) if d[i] > d[i - 1] and d[i] >= d[(i + 1) % n]
             and d[i] >= MIN_PEAK * d.max()]
    while len(peaks) >= 2:
        ratios = []
        for k, p in enumerate(peaks):
            q = peaks[(k + 1) % len(peaks)]
            idx = (p + np.arange(((q - p) % n or n) + 1)) % n
            ratios.append(d[idx].min() / max(min(d[p], d[q]), np.finfo(float).tiny))
        k = int(np.argmax(ratios))
        if ratios[k] < deep:
            break
        p, q = peaks[k], peaks[(k + 1) % len(peaks)]
        peaks.remove(p if d[p] < d[q] else q)
    return peaks


def _face_graph(f: np.ndarray, centroid: np.ndarray, vertex_count: int) -> sp.csr_matrix:
    """Faces sharing a vertex, weighted by the distance between their centroids."""
    nf = len(f)
    incidence = sp.csr_matrix((np.ones(3 * nf), (np.repeat(np.arange(nf), 3), f.ravel())),
                              shape=(nf, vertex_count))
    pairs = sp.triu(incidence @ incidence.T, k=1).tocoo()
    w = np.linalg.norm(centroid[pairs.row] - centroid[pairs.col], axis=1)
    w = np.maximum(w, 1e-12 * max(float(w.max(initial=0.0)), 1.0))  # 0 would mean "no edge"
    return sp.coo_matrix((w, (pairs.row, pairs.col)), shape=(nf, nf)).tocsr()


def lobes(vertices: np.ndarray, faces: np.ndarray, deep: float = DEEP) -> Lobes:
    """Split a surface that is several petals joined (a ring around an axis) into lobes.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
        Any triangles: one piece or several, open or closed, manifold or not.
    deep : float
        See :func:`profile_peaks`.

    Returns
    -------
    Lobes
        ``label (F,)`` and ``count``; one lobe (all zeros) when the surface is not a ring
        of at least ``MIN_LOBES`` petals.

    Notes
    -----
    The axis is the normal of the area-weighted best-fit plane through the face
    centroids (a ring of petals is wider than it is tall). The area of the faces beyond
    ``OUTER`` of the farthest radius, by angle around the axis, rises at each petal and
    falls between two; its separate peaks (:func:`profile_peaks`) are the lobes. Each lobe
    grows from the outer faces near its peak across the faces, nearest first (shortest
    paths over faces sharing a vertex), so a face goes to the petal it is part of even
    where petals overlap in angle; faces no path reaches go to the nearest peak by angle.
    The hub is where lobes meet: ``hub_radius`` is the largest distance from the axis of
    a face next to a face of another lobe, at most ``HUB_MAX`` of the farthest (petals
    that touch farther out are told apart by their labels alone).
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    centre, axes, area, centroid = plane_frame(v, f)
    axis, e1 = axes[2], axes[0]
    e2 = np.cross(axis, e1)
    d = centroid - centre
    radius = np.linalg.norm(d - np.outer(d @ axis, axis), axis=1)
    angle = np.degrees(np.arctan2(d @ e2, d @ e1)) % 360.0
    outer = radius > OUTER * radius.max()
    peaks = profile_peaks(angular_profile(angle[outer], area[outer]), deep)
    if len(peaks) < MIN_LOBES:
        return Lobes(np.zeros(len(f), dtype=np.int64), 1, centre, axis, radius, 0.0)
    gap = np.diff(np.r_[peaks, peaks[0] + 360]).min()
    graph = _face_graph(f, centroid, len(v))
    distance = np.full((len(peaks), len(f)), np.inf)
    by_angle = np.empty((len(peaks), len(f)))
    for k, p in enumerate(peaks):
        off = np.abs((angle - p + 180.0) % 360.0 - 180.0)
        by_angle[k] = off
        seeds = np.flatnonzero(outer & (off < min(SEED_DEGREES, 0.5 * gap)))
        if seeds.size:
            distance[k] = dijkstra(graph, directed=False, indices=seeds, min_only=True)
    label = np.argmin(distance, axis=0)
    lost = ~np.isfinite(distance.min(axis=0))
    label[lost] = np.argmin(by_angle[:, lost], axis=0)
    pairs = sp.triu(graph).tocoo()
    meet = label[pairs.row] != label[pairs.col]
    if meet.any():
        at = np.maximum(radius[pairs.row[meet]], radius[pairs.col[meet]])
        hub = min(float(at.max()), HUB_MAX * float(radius.max()))
    else:
        hub = 0.0
    return Lobes(label, len(peaks), centre, axis, radius, hub)
