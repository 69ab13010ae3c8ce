"""How thick a surface is: the distance from each face to the layer behind it."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pipeline.mesh import topology

#: a face counts as having a layer behind it when that layer's normal is within this
#: angle of its own (either way round), i.e. the two are roughly parallel
PARALLEL_DEGREES = 60.0
#: ... and the layer is nearer than this fraction of the part's width
THIN = 0.25


class Thickness(NamedTuple):
    """Result of :func:`thickness`."""

    face_thickness: np.ndarray  #: (F,) distance to the layer behind, inf where none
    opposite_face: np.ndarray  #: (F,) int, the face hit behind (-1 where none)
    direction: np.ndarray  #: (F,) +1 if that layer is along the face's normal, -1 against, 0
    width: np.ndarray  #: (F,) width (second PCA extent) of the face's connected component
    layered: np.ndarray  #: (F,) bool, a roughly parallel layer within THIN x width
    relative_thickness: float  #: area-weighted median of thickness / width over layered faces
    layered_fraction: float  #: fraction of the area that is layered


def _component_width(vertices: np.ndarray, faces: np.ndarray,
                     label: np.ndarray | None = None) -> np.ndarray:
    """(F,) second principal extent (max - min along the second PCA axis) per component.

    One pass over all components at once (sums by component, a batched 3 x 3 eigen
    solve), so a part of thousands of pieces costs what one piece of that size does."""
    label = topology.components(faces, len(vertices)) if label is None else label
    count = int(label.max()) + 1 if len(label) else 0
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.ravel()] = True
    idx = np.flatnonzero(used)
    lab = label[idx]
    pts = vertices[idx]
    n, _, centred, _, vecs = topology.grouped_moments(pts, lab, count)
    second = vecs[:, :, 1][lab]  # eigh sorts ascending: the middle one is the second axis
    along = np.einsum("ij,ij->i", centred, second)
    high = np.full(count, -np.inf)
    low = np.full(count, np.inf)
    np.maximum.at(high, lab, along)
    np.minimum.at(low, lab, along)
    width = np.where(n >= 3, high - low, 0.0)
    return width[label[faces[:, 0]]]


def _inward(vertices: np.ndarray, faces: np.ndarray, label: np.ndarray | None = None) -> np.ndarray:
    """(F,) +1 where the inside of the face's closed component is along its normal, -1
    where against it, 0 for faces of open (or non-manifold) components. The signed
    volumes of all components are summed in one pass."""
    from pipeline.mesh import clean

    oriented, _ = clean.orient_consistently(faces, len(vertices))
    flipped = np.any(oriented != faces, axis=1)
    vlabel = topology.components(faces, len(vertices)) if label is None else label
    face_label = vlabel[faces[:, 0]]
    count = int(face_label.max()) + 1 if len(face_label) else 0
    _, he_edge, edge_count = topology.unique_edges(faces)
    open_edge = (edge_count[he_edge] != 2).reshape(3, -1).any(axis=0)
    is_open = np.bincount(face_label, weights=open_edge, minlength=count) > 0
    # about each component's mean corner, for precision (a closed surface's volume does
    # not depend on the origin)
    corners = vertices[oriented]
    centre = np.stack([np.bincount(face_label, weights=corners[:, :, k].sum(axis=1),
                                   minlength=count) for k in range(3)], 1)
    centre /= np.maximum(3.0 * np.bincount(face_label, minlength=count), 1.0)[:, None]
    p = corners - centre[face_label][:, None, :]
    volume = np.bincount(face_label, weights=np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])),
                         minlength=count)
    inward = np.where(is_open, 0, np.where(volume > 0, -1, 1))[face_label]
    return np.where(flipped, -inward, inward)


#: rounds of casting again, from just past the hit, a ray that hit another component
#: (``own_component``): petals pushed through each other, a petal's base buried in the
#: receptacle
RECASTS = 4


def thickness(vertices: np.ndarray, faces: np.ndarray, *, own_component: bool = False) -> Thickness:
    """Distance from every face to the roughly parallel surface behind it.

    A ray leaves each face's centroid along its normal, both ways; the nearest first hit
    on a face whose normal is within ``PARALLEL_DEGREES`` of this face's (either
    orientation) is the face's thickness. Faces of a closed component look only inward
    (into the material, by the sign of its volume), so two closed parts facing each
    other across a gap are not one thin layer. On a thin shell (a solidified petal, a
    flattened box or tube, two layers) the two sides see each other a thickness apart;
    the rim strip, caps and side walls see across the whole part, and a solid (a
    sphere, a cube) is as thick as it is wide.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
        One connected component or a few; winding need not be consistent.
    own_component : bool
        Measure each connected component as if alone: a ray that first hits another
        component goes on through it (cast again from just past the hit, up to
        ``RECASTS`` times). For the pieces of a part measured in one pass.

    Returns
    -------
    Thickness
        ``face_thickness (F,)`` (inf where nothing parallel is behind), ``opposite_face
        (F,)``, ``direction (F,)``, ``width (F,)``, ``layered (F,) bool`` and the summary
        ``relative_thickness`` (area-weighted median of thickness / width over layered
        faces; inf if none) and ``layered_fraction`` (area fraction layered).

    Notes
    -----
    Scale-free: thickness is compared with the width (second PCA extent) of the face's
    own connected component, so many tiny closed boxes (voxels) are each as thick as
    they are wide, not a thin part. Ray casting uses gpytoolbox (Embree). Rays start a
    hair (1e-9 of the bounding-box diagonal) off the face, so a face never hits itself;
    zero-area faces get no thickness.
    Embree's single-precision hit distance is recomputed in double on the hit face's plane.
    """
    import gpytoolbox

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"expected vertices (V, 3) and faces (F, 3), got {v.shape} and {f.shape}")
    nf = len(f)
    if nf == 0:
        empty = np.zeros(0)
        return Thickness(empty, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), empty,
                         np.zeros(0, dtype=bool), np.inf, 0.0)
    fn = topology.face_normals(v, f)
    area2 = np.linalg.norm(fn, axis=1)
    diag = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    ok = area2 > 1e-14 * diag * diag
    n = fn / np.where(ok, area2, 1.0)[:, None]
    centroid = v[f].mean(axis=1)
    eps = 1e-9 * diag
    vlabel = topology.components(f, len(v))
    inward = _inward(v, f, vlabel)
    origins = np.concatenate([centroid + eps * n, centroid - eps * n])
    dirs = np.concatenate([n, -n])
    ts, ids, _ = gpytoolbox.ray_mesh_intersect(origins, dirs, v, f)
    ts = np.asarray(ts, dtype=np.float64).reshape(-1)
    ids = np.asarray(ids, dtype=np.int64).reshape(-1)
    own = np.tile(np.arange(nf), 2)
    if own_component:
        comp = vlabel[f[:, 0]]
        for _ in range(RECASTS):
            foreign = np.flatnonzero((ids >= 0) & (comp[np.maximum(ids, 0)] != comp[own]))
            if foreign.size == 0:
                break
            start = origins[foreign] + (ts[foreign] + eps)[:, None] * dirs[foreign]
            t2, i2, _ = gpytoolbox.ray_mesh_intersect(start, dirs[foreign], v, f)
            t2 = np.asarray(t2, dtype=np.float64).reshape(-1)
            i2 = np.asarray(i2, dtype=np.int64).reshape(-1)
            ts[foreign] = np.where(i2 >= 0, ts[foreign] + eps + t2, np.inf)
            ids[foreign] = i2
        ids = np.where((ids >= 0) & (comp[np.maximum(ids, 0)] != comp[own]), -1, ids)
    hit = (ids >= 0) & (ids != own) & np.isfinite(ts) & np.tile(ok, 2)
    cos = np.zeros(2 * nf)
    cos[hit] = np.abs(np.einsum("ij,ij->i", n[own[hit]], n[ids[hit]]))
    hit &= cos >= np.cos(np.radians(PARALLEL_DEGREES))
    # a closed component is material inside: only look inward, never across the air
    hit &= np.concatenate([inward >= 0, inward <= 0])
    # Embree works in single precision: redo the hit in double, on the hit face's plane
    o, d, j = np.tile(centroid, (2, 1))[hit], dirs[hit], ids[hit]
    ts[hit] = np.einsum("ij,ij->i", v[f[j, 0]] - o, n[j]) / np.einsum("ij,ij->i", d, n[j])
    dist = np.where(hit, ts, np.inf).reshape(2, nf)
    back = dist[1] < dist[0]  # ties (both equal) go to +normal, deterministically
    face_thickness = np.where(back, dist[1], dist[0])
    opposite = np.where(back, ids[nf:], ids[:nf])
    direction = np.where(back, -1, 1)
    found = np.isfinite(face_thickness)
    opposite = np.where(found, opposite, -1)
    direction = np.where(found, direction, 0)

    width = _component_width(v, f, vlabel)
    layered = found & (face_thickness < THIN * width)
    area = 0.5 * area2
    total = float(area.sum())
    fraction = float(area[layered].sum() / total) if total > 0 else 0.0
    relative = np.inf
    if layered.any():
        r = face_thickness[layered] / width[layered]
        order = np.argsort(r, kind="stable")
        cum = np.cumsum(area[layered][order])
        relative = float(r[order][np.searchsorted(cum, 0.5 * cum[-1])])
    return Thickness(face_thickness, opposite, direction, width, layered, relative, fraction)
