"""The open sheet halfway between the two sides of a thin shell."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from pipeline.mesh import clean, topology
from pipeline.mesh.repair import manifold_fans
from pipeline.mesh.thickness import thickness as measure_thickness

#: least fraction of the area with a parallel layer behind it for a part to be a shell
MIN_LAYERED = 0.3
#: largest median thickness / width for a part to be a thin shell
MAX_RELATIVE_THICKNESS = 0.2
#: two neighbouring layered faces are on the same side if their normals are this close
#: (a Solidify rim meets its sides at 90 degrees, a lens rim at a sharp crease)
SIDE_DEGREES = 60.0
#: a projected face is dropped when its area (signed, against its old normal) falls
#: under this fraction of the old: collapsed or flipped by the projection
MIN_AREA_RATIO = 0.05
#: rounds of moving a middle point along its segment to equal distances from both sides
MIDPOINT_ITERATIONS = 2
#: ``midsurface(many=True)``: a side is taken with the one behind it when its area is at
#: least this fraction of the largest side's
MANY_SIDES = 0.2


class Midsurface(NamedTuple):
    """Result of :func:`midsurface`."""

    vertices: np.ndarray  #: (n, 3) sheet vertices, halfway between the two sides
    faces: np.ndarray  #: (m, 3) one open, edge-manifold, consistently oriented sheet
    thickness: np.ndarray  #: (n,) distance between the two sides at each sheet vertex
    source: np.ndarray  #: (n,) int, the input vertex each sheet vertex was moved from
    side: np.ndarray  #: (F,) int8 per input face: 1 the kept side, -1 the other, 0 dropped
    relative_thickness: float  #: median thickness / width of the part (see thickness())
    layered_fraction: float  #: fraction of the input's area with a layer behind it


def _face_components(faces: np.ndarray, link: np.ndarray) -> np.ndarray:
    """Label of every face, faces ``link[:, 0]`` and ``link[:, 1]`` joined."""
    nf = len(faces)
    g = sp.coo_matrix((np.ones(len(link)), (link[:, 0], link[:, 1])), shape=(nf, nf))
    _, label = connected_components(g, directed=False)
    _, first = np.unique(label, return_index=True)  # number by first face: scipy-independent
    rank = np.empty_like(first)
    rank[np.argsort(first)] = np.arange(first.size)
    return rank[label]


def _adjacent_faces(faces: np.ndarray) -> np.ndarray:
    """(P, 2) pairs of faces sharing an edge used by exactly two faces."""
    nf = len(faces)
    _, _, _, _, a, b = topology.interior_pairs(faces)
    return np.stack([a % nf, b % nf], axis=1)


def _two_colouring(nodes: np.ndarray, same: np.ndarray, opposite: np.ndarray) -> np.ndarray:
    """(len(nodes),) bool: which of two sides each face is on, when the sides touch.

    A signed graph: ``same`` pairs (neighbours with close normals) want one side,
    ``opposite`` pairs (a face and the face its ray hits) want different sides. The
    eigenvector of the signed Laplacian's smallest eigenvalue is the best relaxed
    two-colouring (exact for a balanced graph); its sign splits the faces, cutting the
    few ``same`` links at a pointed tip where the rim strip is itself thin.
    """
    from scipy.sparse.linalg import eigsh

    k = len(nodes)
    rows = np.concatenate([same[:, 0], same[:, 1], opposite[:, 0], opposite[:, 1]])
    cols = np.concatenate([same[:, 1], same[:, 0], opposite[:, 1], opposite[:, 0]])
    w = np.concatenate([np.ones(2 * len(same)), -np.ones(2 * len(opposite))])
    a = sp.coo_matrix((w, (rows, cols)), shape=(k, k)).tocsr()
    degree = np.asarray(abs(a).sum(axis=1)).ravel()
    lap = (sp.diags(degree) - a).tocsc()
    shift = 1e-3 * max(float(degree.mean()), 1.0)
    v0 = np.linspace(1.0, 2.0, k)  # fixed start: the same input gives the same split
    _, vec = eigsh(lap, k=1, sigma=-shift, which="LM", v0=v0)
    x = vec[:, 0]
    return x > 0


def _pick_largest(area: np.ndarray, centroid: np.ndarray, size: float) -> int:
    """Index of the largest area; near ties (1e-6) broken by centroid, so that the choice
    does not depend on vertex order or winding (the two sides of a box are equal)."""
    best = int(np.argmax(area))
    for c in range(len(area)):
        if c == best or area[c] < area[best] * (1.0 - 1e-6):
            continue
        if area[c] > area[best] * (1.0 + 1e-6):
            best = c
            continue
        diff = centroid[c] - centroid[best]
        big = np.flatnonzero(np.abs(diff) > 1e-6 * size)
        if big.size and diff[big[0]] > 0:
            best = c
    return best


def midsurface(vertices: np.ndarray, faces: np.ndarray, many: bool = False) -> Midsurface:
    """The sheet halfway between the two sides of a thin shell.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
        One thick part, welded: a closed thin shell (Blender Solidify: two offset sides
        joined by a rim strip; a flattened box; a flattened tube with caps; a lens) or
        two open layers (a slab cut open by a slit, or two separate sides).
    many : bool
        Not only the largest side and the sides behind it, but every other pair of sides
        too (largest first, each at least ``MANY_SIDES`` of the largest's area): one
        sheet for each, apart. For petals fused into one solid (an OpenSCAD union of
        flattened spheres round a centre), whose sides join through the centre only
        where its faceting lets them.

    Returns
    -------
    Midsurface
        ``vertices (n, 3)``, ``faces (m, 3)``: a single open, edge-manifold sheet with
        no bowtie vertices, consistently oriented; ``thickness (n,)``: the distance
        between the two sides at each vertex; ``source (n,)``: the input vertex each
        sheet vertex comes from; ``side (F,)``: per input face, 1 on the kept side, -1
        on the other, 0 dropped (rim, caps, walls); and the part's ``relative_thickness`` and
        ``layered_fraction`` (:func:`pipeline.mesh.thickness.thickness`).

    Raises
    ------
    ValueError
        For what is not a thin part, saying why: no faces (a point cloud), too little
        of the surface with a parallel layer behind it (a sphere, a solid cube, voxel
        boxes: each as thick as wide), a median thickness over
        ``MAX_RELATIVE_THICKNESS`` of the width (a solid sculpture), or two sides that
        cannot be told apart.

    Notes
    -----
    1. Per face, :func:`thickness` finds the roughly parallel layer behind it. Faces
       with one (within a quarter of the width) are split into sides: neighbours whose
       normals differ by less than ``SIDE_DEGREES`` are on the same side, so the rim
       strip, caps and side walls, which see nothing thin behind them, separate the two.
    2. The largest side (by area; near ties broken by position, so the choice does not
       depend on vertex order or winding) is kept; the other side is the set of sides
       its rays land on.
    3. Each vertex of the kept side moves to the midpoint between itself and its
       closest point on the other side; ``thickness`` is that distance. On a shell of
       two parallel sides this is exactly halfway: the point is at half the thickness
       from the other side, and at most that from its own.
    4. Faces the projection collapses or flips (area under ``MIN_AREA_RATIO`` of the
       original, signed) are dropped, then bowtie vertices are resolved (largest fan
       kept) and the largest edge-connected piece is kept.

    The sheet's faces keep the kept side's winding made consistent; its normal points
    away from the other side, whatever the input's winding. Output vertices are in the
    order of their input vertices (``source`` is increasing).

    Size: the sheet covers the kept side. For a Solidify shell that is the whole
    original surface (the rim strip adds no area to the middle): measured area / the
    original sheet's 0.9998 on a cupped petal; for a box, the top's footprint (1.0);
    for a flattened tube, out to the edge of the ellipse (faces whose normal turns past
    ``PARALLEL_DEGREES`` are dropped, but the side's last vertices still reach it). On
    real models the sheet keeps 93-99% of the kept side's area (faces collapsed at a
    lens rim or a pointed tip are dropped). Measured in tests/test_midsurface.py.
    """
    import gpytoolbox

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must be (V, 3), got {v.shape}")
    if f.size == 0:
        raise ValueError("no faces: a point cloud (or an empty mesh) has no surface to take a "
                         "mid-surface of")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"faces must be (F, 3) triangles, got {f.shape}")
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError("faces index vertices that do not exist")
    # repeated corners and duplicated faces say nothing about the shape
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0])
    input_face = np.flatnonzero(~repeated)
    f = f[~repeated]
    _, first = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
    input_face = input_face[np.sort(first)]
    f = f[np.sort(first)]
    if len(f) == 0:
        raise ValueError("no faces with three distinct corners")
    f, _ = clean.orient_consistently(f, len(v))

    m = measure_thickness(v, f)
    if m.layered_fraction < MIN_LAYERED:
        raise ValueError(
            f"not a thin shell: only {m.layered_fraction:.0%} of the surface has a parallel "
            f"layer behind it within a quarter of the part's width (a solid such as a sphere "
            f"or a cube, or many small closed boxes, is about as thick as it is wide)")
    if m.relative_thickness > MAX_RELATIVE_THICKNESS:
        raise ValueError(
            f"not a thin shell: its median thickness is {m.relative_thickness:.2f} of its "
            f"width (over {MAX_RELATIVE_THICKNESS}): a solid, not a petal")

    fn = topology.face_normals(v, f)
    area2 = np.linalg.norm(fn, axis=1)
    n = fn / np.maximum(area2, np.finfo(float).tiny)[:, None]
    pairs = _adjacent_faces(f)
    same = (m.layered[pairs[:, 0]] & m.layered[pairs[:, 1]]
            & (np.einsum("ij,ij->i", n[pairs[:, 0]], n[pairs[:, 1]]) > np.cos(np.radians(SIDE_DEGREES))))
    side = _face_components(f, pairs[same])
    side = np.where(m.layered, side, -1)
    # a pointed tip's rim can be as thin across as the part is thick: there the two
    # sides run into each other through the rim; split such a side by two-colouring
    has_partner = m.layered & (m.opposite_face >= 0)
    has_partner[has_partner] &= m.layered[m.opposite_face[has_partner]]
    self_hit = has_partner.copy()
    self_hit[has_partner] = side[m.opposite_face[has_partner]] == side[has_partner]
    merged = np.unique(side[self_hit])
    if merged.size:
        cut = np.zeros(len(pairs), dtype=bool)
        for c in merged:
            nodes = np.flatnonzero(side == c)
            if self_hit[nodes].sum() < 0.25 * nodes.size:
                continue
            local = np.full(len(f), -1)
            local[nodes] = np.arange(nodes.size)
            inside = same & (side[pairs[:, 0]] == c)
            hitters = nodes[self_hit[nodes]]
            colour = _two_colouring(nodes, local[pairs[inside]],
                                    np.stack([local[hitters], local[m.opposite_face[hitters]]], axis=1))
            cut[np.flatnonzero(inside)] = colour[local[pairs[inside, 0]]] != colour[local[pairs[inside, 1]]]
        side = _face_components(f, pairs[same & ~cut])
        side = np.where(m.layered, side, -1)
    labels = np.unique(side[side >= 0])
    side_area = np.array([area2[side == c].sum() for c in labels])
    centroid = v[f].mean(axis=1)
    side_centroid = np.array([(centroid[side == c] * area2[side == c, None]).sum(axis=0)
                              / max(side_area[k], np.finfo(float).tiny)
                              for k, c in enumerate(labels)])
    diag = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    first = labels[_pick_largest(side_area, side_centroid, diag)]

    def sheet_of(keep_label):
        """The mid-surface of side ``keep_label`` and the sides its rays land on: ``(mid,
        faces into mid, gap, input vertices, kept faces, other faces)``."""
        kept = side == keep_label
        # the other side: every side the kept side's rays land on (10% of its area or more)
        target = m.opposite_face[kept]
        target_side = side[target]
        landed = np.zeros(len(labels))
        np.add.at(landed, np.searchsorted(labels, target_side[target_side >= 0]),
                  area2[kept][target_side >= 0])
        if landed[np.searchsorted(labels, keep_label)] > 0.5 * area2[kept].sum():
            raise ValueError("the two sides of the part cannot be told apart (its rim is as "
                             "smooth as its sides, or the part folds onto itself)")
        other_labels = labels[(landed >= 0.1 * area2[kept].sum()) & (labels != keep_label)]
        if other_labels.size == 0:
            raise ValueError("no opposite side found behind the largest side")
        other = np.isin(side, other_labels)

        # sheet faces are the kept side's; n points away from the other side
        sheet_f = f[kept]
        toward_other = m.direction[kept]
        if float(np.sum(area2[kept] * toward_other)) > 0:
            sheet_f = sheet_f[:, [0, 2, 1]]
        used = np.unique(sheet_f)
        p = v[used]
        other_f, kept_f = f[other], f[kept]

        def closest(points, side_faces):
            _, nearest, bary = gpytoolbox.squared_distance(points, v, side_faces, use_cpp=True)
            nearest = np.asarray(nearest, dtype=np.int64).reshape(-1)
            return np.einsum("ik,ikj->ij", np.asarray(bary, dtype=np.float64), v[side_faces[nearest]])

        q = closest(p, other_f)
        span = np.linalg.norm(q - p, axis=1)
        # The middle lies on the segment from p to its closest point q: there the distance
        # to the other side is exactly (1 - s)|pq|, and to p's own side c s |pq|, c = 1
        # for parallel sides, < 1 where they are not (a lens, a crease). Solving
        # c s = 1 - s with c measured at the current s puts the point at equal distances
        # without letting it slide along the sheet.
        frac = np.full(len(p), 0.5)
        for _ in range(MIDPOINT_ITERATIONS):
            mid = p + frac[:, None] * (q - p)
            own = np.linalg.norm(closest(mid, kept_f) - mid, axis=1)
            c = np.clip(own / np.maximum(frac * span, np.finfo(float).tiny), 0.0, 1.0)
            frac = np.where(span > 0, 1.0 / (1.0 + c), 0.5)
        mid = p + frac[:, None] * (q - p)
        gap = (1.0 - frac) * span + np.linalg.norm(closest(mid, kept_f) - mid, axis=1)

        local = np.searchsorted(used, sheet_f)
        old = topology.face_normals(v, sheet_f)
        new = topology.face_normals(mid, local)
        old_area2 = np.linalg.norm(old, axis=1)
        signed = np.einsum("ij,ij->i", new, old) / np.maximum(old_area2, np.finfo(float).tiny)
        good = signed > MIN_AREA_RATIO * old_area2
        local = local[good]
        local = local[manifold_fans(local, len(used))]
        if len(local) == 0:
            raise ValueError("the projection onto the middle collapsed every face")
        link = _adjacent_faces(local)
        piece = _face_components(local, link)
        piece_area = np.bincount(piece, weights=np.linalg.norm(topology.face_normals(mid, local), axis=1))
        local = local[piece == int(np.argmax(piece_area))]
        keep_v = np.unique(local)
        return mid[keep_v], np.searchsorted(keep_v, local), gap[keep_v], used[keep_v], kept, other

    made = [sheet_of(first)]
    if many:  # (each pair of sides its own sheet: the petals of one solid)
        taken = made[0][4] | made[0][5]
        for k in np.argsort(-side_area, kind="stable").tolist():
            c = labels[k]
            if side_area[k] < MANY_SIDES * side_area.max() or taken[side == c].any():
                continue
            try:
                piece = sheet_of(c)
            except ValueError:
                continue
            if (taken & piece[5]).any():  # (its other side is a sheet's already)
                continue
            made.append(piece)
            taken |= piece[4] | piece[5]
    at = np.cumsum([0] + [len(piece[0]) for piece in made])
    side_of_input = np.zeros(len(faces), dtype=np.int8)
    for piece in made:
        side_of_input[input_face[piece[4]]] = 1
        side_of_input[input_face[piece[5]]] = -1
    return Midsurface(np.concatenate([piece[0] for piece in made]),
                      np.concatenate([piece[1] + o for piece, o in zip(made, at[:-1], strict=True)]),
                      np.concatenate([piece[2] for piece in made]),
                      np.concatenate([piece[3] for piece in made]),
                      side_of_input, m.relative_thickness, m.layered_fraction)
