"""Petal axis, base, tip, center plane and cross-section coordinates.

Per petal (a connected component):

- center plane: the petal's mirror plane (:func:`symmetry.mirror_plane`);
- base: the end attached to the receptacle. With several petals, the center planes
  all contain the flower's axis; their least-squares intersection gives it, and each
  petal's base is the end nearer that axis. A lone petal's base is its narrow end.
  The fixed base vertices are the boundary vertices within ``base_fraction`` of the
  petal's length from that end;
- tip: the far end of the axis: of the axis vertices, the one farthest from the base
  along the mesh;
- s: distance from the base along the mesh, over the tip's (0 at the base, 1 at the
  tip and beyond: a petal's corners may reach a little farther than its tip);
- x: cross-section coordinate: distance along the mesh from the axis vertices, signed
  by the side of the center plane and divided by the boundary's distance at the same s
  on the same side (0 on the axis, +-1 on the two boundary curves).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse.csgraph import dijkstra

from . import symmetry, topology


@dataclass
class PetalAxes:
    base: np.ndarray  #: (V,) bool, fixed base vertices
    on_axis: np.ndarray  #: (V,) bool, vertices on or of an edge crossing the center plane
    tip: np.ndarray  #: (P,) int, tip vertex of each petal
    plane: np.ndarray  #: (P, 4) unit normal and offset of each center plane
    x: np.ndarray  #: (V,) cross-section coordinate in [-1, 1]
    s: np.ndarray  #: (V,) normalized distance from the base in [0, 1]
    flower_axis: np.ndarray  #: (6,) point and unit direction of the flower's axis (nan if unknown)
    widened: tuple = ()  #: petals whose base was on a line and got more fixed vertices


#: a petal's fixed base vertices must stray at least this far (fraction of the petal's
#: length) from their own line: a base on a line leaves the petal free to turn about it
#: (a zero-stiffness mode, and a stiffness that vanishes with the width as it shrinks).
#: The project's buds' bases stray 0.016-0.021; a flat petal's straight base row, 0.
MIN_BASE_WIDTH = 0.005
#: how far along the petal (fraction of its length) a base may be widened
BASE_REACH = 0.25


class WeakBase(ValueError):
    """A petal whose base cannot be widened to :data:`MIN_BASE_WIDTH`."""

    def __init__(self, petal: int, count: int, width: float):
        self.petal, self.count, self.width = petal, count, width
        super().__init__(f"petal {petal}'s base is a line: its {count} fixed vertices stray "
                         f"{width:.2g} of its length from one line (at least "
                         f"{MIN_BASE_WIDTH:g} is needed, and no vertices near the base end "
                         "widen it), so the petal would spin about that line")


def base_width(fixed: np.ndarray, points: np.ndarray) -> float:
    """How far the fixed points stray from their own line: the largest distance of one
    from the line through their centroid along their principal direction, over the
    extent of ``points`` (the petal) along its principal direction. Scale-free; 0 for
    points on a line (or fewer than three)."""
    fixed = np.asarray(fixed, dtype=np.float64)
    pts = np.asarray(points, dtype=np.float64)
    if len(fixed) < 3 or len(pts) < 2:
        return 0.0
    centred = fixed - fixed.mean(axis=0)
    direction = np.linalg.svd(centred, full_matrices=False)[2][0]
    off = centred - np.outer(centred @ direction, direction)
    along = np.linalg.svd(pts - pts.mean(axis=0), full_matrices=False)[2][0]
    length = float(np.ptp(pts @ along))
    return float(np.linalg.norm(off, axis=1).max() / length) if length > 0.0 else 0.0


def _widen_base(base: np.ndarray, boundary: np.ndarray, proj: np.ndarray, pts: np.ndarray,
                sub, limit: float) -> bool:
    """Add vertices to ``base`` (in place), nearest the base end first (by ``proj``),
    until it strays :data:`MIN_BASE_WIDTH` from a line: boundary vertices first, then
    rings of interior vertices around the base, none farther than ``limit`` along the
    axis. Returns whether it got there (``base`` is then the smallest such set)."""
    if base_width(pts[base], pts) >= MIN_BASE_WIDTH:
        return True
    near = proj <= limit
    for v in np.flatnonzero(boundary & near & ~base)[np.argsort(proj[boundary & near & ~base],
                                                                kind="stable")]:
        base[v] = True
        if base_width(pts[base], pts) >= MIN_BASE_WIDTH:
            return True
    while True:  # interior rings: the neighbours of the base, nearest the end first
        ring = np.zeros(len(base), dtype=bool)
        ring[sub[np.flatnonzero(base)].indices] = True
        ring &= near & ~base
        if not ring.any():
            return False
        for v in np.flatnonzero(ring)[np.argsort(proj[ring], kind="stable")]:
            base[v] = True
            if base_width(pts[base], pts) >= MIN_BASE_WIDTH:
                return True


def flower_axis(planes: np.ndarray) -> np.ndarray | None:
    """The line where the petals' center planes (nearly) meet, as ``(point, direction)``.

    None when fewer than two planes or when they are (nearly) parallel.
    """
    if len(planes) < 2:
        return None
    n = planes[:, :3]
    w, vecs = np.linalg.eigh(n.T @ n)
    if w[1] < 0.05 * w[2]:  # all normals nearly parallel: no common line
        return None
    direction = vecs[:, 0]
    point, *_ = np.linalg.lstsq(np.vstack([n, direction]), np.r_[planes[:, 3], 0.0], rcond=None)
    return np.r_[point, direction]


def _distance_to_line(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    p, d = line[:3], line[3:]
    r = points - p
    return np.linalg.norm(r - np.outer(r @ d, d), axis=1)


def _petal_ends(points: np.ndarray, plane: np.ndarray):
    """Unit length direction (in the center plane) and the projections along it."""
    n = plane[:3]
    c = points.mean(axis=0)
    flat = (points - c) - np.outer((points - c) @ n, n)
    _, _, vt = np.linalg.svd(flat, full_matrices=False)
    direction = vt[0] - n * (vt[0] @ n)
    direction /= np.linalg.norm(direction)
    return direction, (points - c) @ direction


def _end_width(points: np.ndarray, proj: np.ndarray, plane: np.ndarray, low_end: bool) -> float:
    span = proj.max() - proj.min()
    near = proj <= proj.min() + 0.15 * span if low_end else proj >= proj.max() - 0.15 * span
    across = points[near] @ plane[:3]
    return float(across.max() - across.min())


def find_axes(vertices: np.ndarray, faces: np.ndarray, petal: np.ndarray, *,
              base_mode: str = "auto", base_fraction: float = 0.04,
              planes: np.ndarray | None = None) -> PetalAxes:
    """Axes of every petal of a cleaned mesh (see the module docstring).

    ``base_mode``: auto, narrow, wide, or a direction (+x ... -z) the base end lies
    towards. ``planes``: the petals' center planes if known (remesh records them).
    """
    v = np.asarray(vertices, dtype=np.float64)
    nv = len(v)
    count = int(petal.max()) + 1
    edges, _, _ = topology.unique_edges(faces)
    boundary = topology.boundary_vertices(faces, nv)
    graph = topology.edge_graph(v, edges)

    if planes is None:
        planes = np.array([symmetry.mirror_plane(v[petal == p])[0] for p in range(count)])
    planes = np.array(planes, dtype=np.float64)
    axis_line = flower_axis(planes) if base_mode == "auto" else None

    base = np.zeros(nv, dtype=bool)
    widened = []
    on_axis = np.zeros(nv, dtype=bool)
    tips = np.zeros(count, dtype=np.int64)
    x = np.zeros(nv)
    s = np.zeros(nv)
    for p in range(count):
        idx = np.flatnonzero(petal == p)
        pts = v[idx]
        direction, proj = _petal_ends(pts, planes[p])
        if axis_line is not None:
            lo = _distance_to_line(pts[[np.argmin(proj)]], axis_line)[0]
            hi = _distance_to_line(pts[[np.argmax(proj)]], axis_line)[0]
            base_low = lo <= hi
        elif base_mode in ("auto", "narrow", "wide"):
            narrow_low = (_end_width(pts, proj, planes[p], True)
                          <= _end_width(pts, proj, planes[p], False))
            base_low = narrow_low if base_mode != "wide" else not narrow_low
        else:
            toward = np.zeros(3)
            toward["xyz".index(base_mode[1])] = 1.0 if base_mode[0] == "+" else -1.0
            base_low = pts[np.argmin(proj)] @ toward >= pts[np.argmax(proj)] @ toward
        if not base_low:
            proj = -proj
            direction = -direction
        span = proj.max() - proj.min()
        bnd = boundary[idx]
        mine_base = bnd & (proj <= proj.min() + base_fraction * span)
        if mine_base.sum() < 3:  # a petal held by fewer than 3 vertices can spin
            order = np.argsort(np.where(bnd, proj, np.inf), kind="stable")
            mine_base[order[:3]] = True
        sub = graph[idx][:, idx].tocsr()
        # held on a line, it could spin about it: widen the base, within a quarter of the
        # petal (or base_fraction: the fixed part should stay a base, not become the petal)
        reach = proj.min() + max(BASE_REACH, base_fraction) * span
        count = int(mine_base.sum())
        if not _widen_base(mine_base, bnd, proj, pts, sub, reach):
            raise WeakBase(p, int(mine_base.sum()), base_width(pts[mine_base], pts))
        if mine_base.sum() > count:
            widened.append(p)
        base[idx] = mine_base

        dist_base = dijkstra(sub, indices=np.flatnonzero(mine_base), min_only=True)

        # the axis: vertices on the center plane and the ends of edges crossing it
        side = pts @ planes[p][:3] - planes[p][3]
        mine_axis = np.abs(side) <= 1e-6 * span
        side[mine_axis] = 0.0  # on the plane up to rounding: not a crossing
        local_edges = np.searchsorted(idx, edges[np.isin(edges[:, 0], idx)])
        crossing = side[local_edges[:, 0]] * side[local_edges[:, 1]] < 0
        mine_axis[local_edges[crossing].ravel()] = True
        if not mine_axis.any():
            mine_axis[np.argmin(np.abs(side))] = True
        # the tip: the axis's far end
        tip_local = int(np.flatnonzero(mine_axis)[np.argmax(dist_base[mine_axis])])
        tips[p] = idx[tip_local]
        s[idx] = np.minimum(dist_base / dist_base[tip_local], 1.0)

        # orient the plane normal: (normal, base->tip chord, outward) right-handed
        chord = pts[tip_local] - pts[mine_base].mean(axis=0)
        outward = pts[mine_axis].mean(axis=0) - pts.mean(axis=0)
        if np.cross(chord, outward) @ planes[p][:3] < 0:
            planes[p] = -planes[p]
            side = -side
        on_axis[idx] = mine_axis

        # cross-section coordinate
        g = dijkstra(sub, indices=np.flatnonzero(mine_axis), min_only=True)
        sign = np.where(mine_axis, 0.0, np.sign(side))
        xs = np.zeros(len(idx))
        rim = bnd & ~mine_base & ~mine_axis
        for sg in (-1.0, 1.0):
            ring = rim & (sign == sg)
            here = sign == sg
            if not ring.any() or not here.any():
                continue
            order = np.argsort(s[idx][ring], kind="stable")
            width = np.interp(s[idx][here], s[idx][ring][order], g[ring][order])
            xs[here] = sg * np.clip(g[here] / np.maximum(width, 1e-12), 0.0, 1.0)
            xs[ring] = sg
        x[idx] = xs

    line = axis_line if axis_line is not None else np.full(6, np.nan)
    return PetalAxes(base, on_axis, tips, planes, x, s, line, tuple(widened))
