"""Petal axis, base, tip, center plane and cross-section coordinates.

Per petal (a connected component):

- center plane: the petal's mirror plane (:func:`symmetry.mirror_plane`);
- the flower's axis: given (``flower_axis``, a direction), or with several petals the
  least-squares intersection of their center planes (they all contain it). A given
  direction is taken through the point closest (least squares) to all center planes
  within the plane across it; where the planes do not fix that point (one petal, or
  petals sharing one plane), the petals' mean centroid fixes it (a lone petal: its
  base's centroid). The axis points from the receptacle toward the tips: a given
  direction as given; a found one by the petals (their tips rise along it) or, where
  they do not tell (a flat open flower), by ``up``;
- base: the end attached to the receptacle: with several petals (and an axis), the end
  nearer the flower's axis; a lone petal's, its narrow end, or with a given axis its
  end lowest along it. The fixed base vertices are the boundary vertices within
  ``base_fraction`` of the petal's length from that end (``base_region = "rim"``), all
  vertices there (``band``: the same at any resolution) or the base edge (``edge``);
- tip: the far end of the axis: of the axis vertices, the one farthest from the base
  along the mesh;
- s: distance from the base along the mesh, over the tip's (0 at the base, 1 at the
  tip and beyond: a petal's corners may reach a little farther than its tip);
- x: cross-section coordinate: distance along the mesh from the axis vertices, signed
  by the side of the center plane and divided by the boundary's distance at the same s
  on the same side (0 on the axis, +-1 on the two boundary curves). With ``surface=True``
  (the shell's) s and x are along the surface (:mod:`pipeline.flower.coords`): they
  converge as the mesh is refined; along edges they stay a few percent off.

It is long because it is one pass per petal (plane, ends, base, tip, s, x) whose parts
share the petal's arrays, with the checks that refuse a petal beside them.

Every petal's axis is checked sane, or the petal is refused (:class:`BadPetal`, naming
the key ``scene.exclude``): x reaches both -1 and +1, the on-axis vertices form a line
(none more than :data:`LINE_DEPTH` edges from a vertex off the axis, :func:`axis_depth`;
at most :data:`LINE_COUNT` of them per mean edge of the axis's length), and the axis
runs the petal's length (at least :data:`AXIS_REACH` of its extent). A recorded center
plane that cannot be one (the plane a flat sheet lies in:
:func:`symmetry.center_plane_fault`) is found again from the petal first.

Many flowers in one file (``flower``: remesh's ``flower/petal_flower``): each flower's
axis is found from its own petals' planes, and each petal's base is the end nearer its
own flower's axis (:attr:`PetalAxes.flower_axes`, (K, 6)).

The module is long because the base, the tip, s and x of a petal are found in one pass
over it that shares its edge graph and distances, and the checks that refuse an unsound
axis need those same distances.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse.csgraph import connected_components, dijkstra

from pipeline.directions import parse_direction
from pipeline.flower.coords import base_distance, base_edge, cross_section, edge_cross_section, tip_distance
from pipeline.mesh import symmetry, topology
from pipeline.mesh.similar import TOLERANCE as COPY
from pipeline.mesh.similar import Copies


@dataclass
class PetalAxes:
    base: np.ndarray  #: (V,) bool, fixed base vertices
    on_axis: np.ndarray  #: (V,) bool, on the center plane, or the nearer end of an edge crossing it
    tip: np.ndarray  #: (P,) int, tip vertex of each petal
    plane: np.ndarray  #: (P, 4) unit normal and offset of each center plane
    x: np.ndarray  #: (V,) cross-section coordinate in [-1, 1]
    s: np.ndarray  #: (V,) normalized distance from the base in [0, 1]
    flower_axis: np.ndarray  #: (6,) point and unit direction of the flower's axis (nan if unknown);
    #: with several flowers, that of the flower of most petals
    widened: tuple = ()  #: petals whose base was on a line and got more fixed vertices
    flower_axes: np.ndarray = None  #: (K, 6) each flower's axis, as flower_axis (nan if unknown)
    #: ``(petal, why)`` of each petal with no sound axis held as modelled (``hold_bad``)
    held: tuple = ()


#: a petal's fixed base vertices must stray at least this far (fraction of the petal's
#: length) from their own line: a base on a line leaves the petal free to turn about it
#: (a zero-stiffness mode, and a stiffness that vanishes with the width as it shrinks).
#: The project's buds' bases stray 0.016-0.021; a flat petal's straight base row, 0.
MIN_BASE_WIDTH = 0.005
#: how far along the petal (fraction of its length) a base may be widened
BASE_REACH = 0.25
#: the on-axis vertices of a sane axis are a line: none more than this many edges (along
#: the mesh) from a vertex off the axis (:func:`axis_depth` over hops: on the ten external
#: models' 50 petals every one is next to one; dimontel's sheet lying in its own plane
#: gave 3), ...
LINE_DEPTH = 2
#: ... and there are at most this many of them per mean edge of the axis's length (1.0-1.24
#: on those 50 petals, up to 2.1 where the plane zigzags through a regular grid;
#: dimontel's region, 5.3)
LINE_COUNT = 3.0
#: the axis runs the petal's length: from the base to the tip along the mesh, at least this
#: fraction of the petal's extent along its longest principal axis (0.92-1.18 on the ten
#: external models' 50 petals; hallgeirl's tubes when they were cut crosswise, 0.22-0.24
#: for four, 0.52 for the fifth: a guard against the gross case, not a proof)
AXIS_REACH = 0.5


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


def _band_by_rows(s: np.ndarray, edges: np.ndarray, band: float) -> np.ndarray:
    """The vertices of the band ``s <= band``, rounded to the nearest row: a vertex is in
    when the band reaches past half its spacing along s (its largest step in s to a
    neighbour), so that the band's last row of vertices lies on ``s = band`` on average,
    not up to an edge short of it (a clamp that moves with where vertices fall)."""
    step = np.zeros(len(s))
    ds = np.abs(s[edges[:, 0]] - s[edges[:, 1]])
    np.maximum.at(step, edges[:, 0], ds)
    np.maximum.at(step, edges[:, 1], ds)
    return s <= band + 0.5 * step


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


def axis_depth(graph, on_axis: np.ndarray) -> float:
    """How deep a set of axis vertices is: the largest distance along the mesh from one of
    them to the nearest vertex off the axis.

    Parameters
    ----------
    graph : (V, V) sparse, a petal's edge graph weighted by edge length
        (:func:`topology.edge_graph`).
    on_axis : (V,) bool, the on-axis vertices.

    Returns
    -------
    The distance, in the units of the graph's weights; 0 for no on-axis vertex, inf when
    every vertex is on the axis.

    Notes
    -----
    Every vertex of a line (the cut of a symmetrized petal, or the nearer ends of the
    edges crossing an unsymmetrized petal's center plane) has a neighbour off the axis:
    the depth is one edge. A region (a sheet lying in its
    center plane) is as deep as half its width. It does not depend on the plane that
    chose the vertices.
    """
    on_axis = np.asarray(on_axis, dtype=bool)
    if not on_axis.any():
        return 0.0
    if on_axis.all():
        return float("inf")
    reach = dijkstra(graph, indices=np.flatnonzero(~on_axis), min_only=True)
    return float(reach[on_axis].max())


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


_axis_from_planes = flower_axis  # find_axes's own argument is named flower_axis

#: a petal's center plane whose normal leans toward the flower's axis by more than this
#: (cosine) is no plane through the axis (:func:`_planes_about_axis`)
ACROSS_AXIS = 0.5


def _planes_about_axis(v: np.ndarray, petal: np.ndarray, planes: np.ndarray,
                       ids: np.ndarray | None = None) -> np.ndarray:
    """With three or more petals, a petal whose center plane's normal leans toward the
    axis the other petals' planes meet in (``|n . axis| > ACROSS_AXIS``) gets the plane
    through that axis and its centroid instead: a mirror plane found across a cupped
    petal's length, which an irregular triangulation can make look the more symmetric
    (a Poisson-disc bud6 petal at 200 vertices: normal 0.99 along the axis), would give
    the petal another base, tip and growth. The others keep theirs (so a bud whose
    planes all meet keeps its planes to the bit). ``ids``: the petal of each row of
    ``planes`` (default: row k is petal k), for one flower's petals of many."""
    line = flower_axis(planes)
    if line is None:
        return planes
    bad = np.abs(planes[:, :3] @ line[3:]) > ACROSS_AXIS
    if not bad.any() or 2 * bad.sum() >= len(planes):
        return planes
    line = flower_axis(planes[~bad])
    if line is None:
        return planes
    out = planes.copy()
    for p in np.flatnonzero(bad):
        c = v[petal == (p if ids is None else ids[p])].mean(axis=0)
        n = np.cross(line[3:], c - line[:3])
        size = np.linalg.norm(n)
        if not size > 1e-9 * max(1.0, float(np.abs(c).max())):  # (a petal on the axis)
            continue
        n = n / size
        n = n * np.sign(n[np.argmax(np.abs(n))])
        out[p] = np.r_[n, n @ c]
    return out


def _around_axis(planes: np.ndarray, centroids, ids, line: np.ndarray) -> np.ndarray:
    """Turn the center planes ``planes[ids]`` (in place) so that each normal points the same
    way around the flower's axis ``line`` (point, direction toward the tips): along
    ``direction x (centroid - point)``, counterclockwise seen from the tips. The cup's
    rule (a lone petal's) can flip on an irregular mesh of a shallow cup; the petal's x
    (signed by its plane) and the imperfection that picks a side then flip with it (a
    six-petal bud at 50 vertices a petal, matched to its finest mesh by (s, x): two
    petals 65% of a petal length off at rest). Returns ``(len(ids),) bool``: the petals
    turned so; one whose centroid is on the axis (within a millionth of its distance
    from the origin) is not."""
    done = np.zeros(len(ids), dtype=bool)
    for k, (p, c) in enumerate(zip(ids, centroids, strict=True)):
        around = np.cross(line[3:], np.asarray(c) - line[:3])
        if np.linalg.norm(around) > 1e-6 * max(1.0, float(np.abs(c).max())):
            done[k] = True
            if planes[p, :3] @ around < 0.0:
                planes[p] = -planes[p]
    return done


class BadPetal(ValueError):
    """A petal that has no sound axis: refused (one line naming the petal and, where one
    would help, the key)."""

    def __init__(self, petal: int, reason: str, key: str | None = None):
        self.petal, self.key, self.reason = petal, key, reason
        super().__init__(f"petal {petal}: {reason}")


def check_axes(axes: PetalAxes, petal: np.ndarray) -> None:
    """Raise :class:`BadPetal` for the first petal whose axes are not sound: a value not
    finite, x outside [-1, 1], s outside [0, 1], fewer than 3 base vertices, or no tip
    (a tip that is not one of its vertices, or is a base vertex)."""
    petal = np.asarray(petal)
    count = len(axes.tip)
    if not np.all(np.isfinite(axes.plane)):
        p = int(np.flatnonzero(~np.all(np.isfinite(axes.plane), axis=1))[0])
        raise BadPetal(p, "its center plane is not finite")
    # per petal, all at once (a mask per petal costs petals x vertices); then the first
    # petal that fails, with the first thing it fails
    finite = np.isfinite(axes.x) & np.isfinite(axes.s)
    bad_values = np.bincount(petal, weights=(~finite).astype(np.float64), minlength=count)
    lo = {k: np.full(count, np.inf) for k in "xs"}
    hi = {k: np.full(count, -np.inf) for k in "xs"}
    for k, values in (("x", axes.x), ("s", axes.s)):
        np.minimum.at(lo[k], petal[finite], values[finite])
        np.maximum.at(hi[k], petal[finite], values[finite])
    held = np.bincount(petal[axes.base], minlength=count)
    tip = np.asarray(axes.tip, dtype=np.int64)
    tip_ok = (tip >= 0) & (tip < len(petal))
    tip_ok[tip_ok] &= (petal[tip[tip_ok]] == np.flatnonzero(tip_ok)) & ~axes.base[tip[tip_ok]]
    fails = ((bad_values > 0) | (lo["x"] < -1.0) | (hi["x"] > 1.0) | (lo["s"] < 0.0)
             | (hi["s"] > 1.0) | (held < 3) | ~tip_ok)
    fails[[p for p, _ in axes.held]] = False  # (held as modelled: every vertex fixed)
    if not fails.any():
        return
    p = int(np.flatnonzero(fails)[0])
    if bad_values[p]:
        raise BadPetal(p, f"its x or s is not finite at {int(bad_values[p])} vertices")
    if lo["x"][p] < -1.0 or hi["x"][p] > 1.0:
        raise BadPetal(p, f"x in [{lo['x'][p]:.3g}, {hi['x'][p]:.3g}], outside [-1, 1]")
    if lo["s"][p] < 0.0 or hi["s"][p] > 1.0:
        raise BadPetal(p, f"s in [{lo['s'][p]:.3g}, {hi['s'][p]:.3g}], outside [0, 1]")
    if held[p] < 3:
        raise BadPetal(p, f"{int(held[p])} base vertices (at least 3 hold a petal)",
                       "axis.base_fraction")
    raise BadPetal(p, "no tip beyond its base", "axis.base_fraction")


def _plane_fault(points: np.ndarray, plane: np.ndarray) -> str | None:
    """:func:`symmetry.center_plane_fault` of a (unit-normal) plane for the petal ``points``."""
    return symmetry.center_plane_fault(points, _unit_plane(plane))


def _sound_plane(plane: np.ndarray) -> bool:
    n = plane[:3]
    return bool(np.all(np.isfinite(plane)) and np.linalg.norm(n) > 1e-9)


def _unit_plane(plane: np.ndarray) -> np.ndarray:
    """The plane with a unit normal (left as is, bit for bit, when it already has one)."""
    norm = np.linalg.norm(plane[:3])
    return plane if abs(norm - 1.0) <= 1e-9 else plane / norm


def _given_axis_point(planes: np.ndarray, direction: np.ndarray, centroid: np.ndarray):
    """The point of the line along ``direction`` closest (least squares) to all center
    planes, in the plane across ``direction`` through ``centroid``; along a direction
    the planes do not fix (their normals, projected across ``direction``, do not span
    it), ``centroid``'s coordinate is kept."""
    # an orthonormal basis across the direction
    helper = np.eye(3)[int(np.argmin(np.abs(direction)))]
    b1 = np.cross(direction, helper)
    b1 /= np.linalg.norm(b1)
    b2 = np.cross(direction, b1)
    basis = np.stack([b1, b2], axis=1)  # (3, 2)
    m = planes[:, :3] @ basis  # (P, 2): residual n.(c + B y) - d = m y - r
    r = planes[:, 3] - planes[:, :3] @ centroid
    w, vecs = np.linalg.eigh(m.T @ m)
    fixed = w >= 0.05 * len(planes)  # unit normals: each fixed direction gets ~P/2
    y = np.zeros(2)
    for k in np.flatnonzero(fixed):
        y += vecs[:, k] * (vecs[:, k] @ (m.T @ r)) / w[k]
    return centroid + basis @ y


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
    norm = np.linalg.norm(direction)
    if not norm > 1e-9:  # the points on a line along the normal: no length (the caller refuses)
        return np.full(3, np.nan), np.zeros(len(points))
    direction /= norm
    return direction, (points - c) @ direction


def _end_width(points: np.ndarray, proj: np.ndarray, plane: np.ndarray, low_end: bool) -> float:
    span = proj.max() - proj.min()
    near = proj <= proj.min() + 0.15 * span if low_end else proj >= proj.max() - 0.15 * span
    across = points[near] @ plane[:3]
    return float(across.max() - across.min())


def find_axes(vertices: np.ndarray, faces: np.ndarray, petal: np.ndarray, *,
              base_mode: str = "auto", base_fraction: float = 0.04, base_region: str = "rim",
              surface: bool = False, planes: np.ndarray | None = None, flower_axis=None,
              up: np.ndarray | None = None, flower: np.ndarray | None = None,
              progress=None, hold_bad: bool = False,
              held_rim: np.ndarray | None = None,
              corners: np.ndarray | None = None) -> PetalAxes:
    """Axes of every petal of a cleaned mesh (see the module docstring).

    ``base_mode``: auto, narrow, wide, or a direction (+x ... -z) the base end lies
    towards (it wins over the flower's axis for choosing the base end).
    ``base_region``: rim, band or edge (see the module notes). ``surface``: s and x
    along the surface (the shell's), else along edges (the paper's). ``planes``: the
    petals' center planes if known (remesh records them); a plane that is not finite or
    has no normal is found again from the petal. ``flower_axis``: None or "auto" (found
    from the center planes), or the direction of the flower's axis (a vector or a key
    value, see :func:`parse_direction`), pointing from the receptacle toward the tips.
    ``up``: the scene's up direction, which orients a found axis where the petals do not.
    ``flower``: (P,) the flower of each petal (remesh's ``flower/petal_flower``; None: one
    flower): each flower's axis is found from its own petals' planes, and each petal's
    base is the end nearer its own flower's axis. ``progress(what, done, total, detail)``
    is called per petal. ``hold_bad``: a petal with no sound axis is held as modelled
    (every vertex fixed, s and x 0; :attr:`PetalAxes.held` names it and why) instead of
    refused: a file of many flowers, where one blossom must not stop the others.
    ``held_rim``: (V,) the rims remesh cut (``mesh/cut_rim``: a petal's part buried in the
    centre cut away): such a petal's base is there, where it leaves the centre, not at
    the end of whatever the cut left of its old base end. ``corners``: (V,) the outline's
    corners, where known (a mesh cut finer keeps its coarse mesh's:
    :func:`pipeline.mesh.remesh.outline_corners`), else found by their turn.

    Raises :class:`BadPetal` (a petal with no sound axis) or :class:`WeakBase`.
    """
    v = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    petal = np.asarray(petal)
    held_rim = None if held_rim is None else np.asarray(held_rim, dtype=bool)
    nv = len(v)
    count = int(petal.max()) + 1
    if isinstance(flower_axis, str):
        given = parse_direction(flower_axis)
    elif flower_axis is None:
        given = None
    else:
        given = np.asarray(flower_axis, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(given)) or not np.any(given):
            raise ValueError(f"flower_axis: not a direction: {flower_axis!r}")
        given = given / np.linalg.norm(given)
    edges, _, _ = topology.unique_edges(faces)
    boundary = topology.boundary_vertices(faces, nv)

    sizes = np.bincount(petal, minlength=count)
    if np.any(sizes < 3):
        p = int(np.flatnonzero(sizes < 3)[0])
        raise BadPetal(p, f"{sizes[p]} vertices: no petal to hold (at least 3, and some beyond "
                       "its base)")
    # each petal's vertices and edges, by one sort (a mask per petal costs petals x vertices)
    v_order = np.argsort(petal, kind="stable")
    v_start = np.r_[0, np.cumsum(sizes)]
    members = [v_order[v_start[p]:v_start[p + 1]] for p in range(count)]
    edge_petal = petal[edges[:, 0]]
    e_order = np.argsort(edge_petal, kind="stable")
    e_start = np.r_[0, np.cumsum(np.bincount(edge_petal, minlength=count))]
    face_petal = petal[faces[:, 0]]
    f_order = np.argsort(face_petal, kind="stable")
    f_start = np.r_[0, np.cumsum(np.bincount(face_petal, minlength=count))]
    # petals found, for their copies (instanced blossoms): a copy takes its original's
    # axis moved, so that a base edge or a tip two vertices tie for at rounding is decided
    # alike on every copy, and copied blossoms bloom once
    done, ways = Copies(scaled=True, tolerance=COPY), {}
    if planes is None:
        planes = np.array([symmetry.mirror_plane(v[members[p]])[0] for p in range(count)])
    planes = np.array(planes, dtype=np.float64)
    for p in range(count):  # a plane of no normal (or not finite), or one that cannot be a
        # center plane (the plane a flat sheet lies in): found again from the petal
        if not _sound_plane(planes[p]) or _plane_fault(v[members[p]], planes[p]) is not None:
            planes[p] = symmetry.mirror_plane(v[members[p]])[0]
            if not _sound_plane(planes[p]):
                raise BadPetal(p, "no center plane: its vertices do not span a sheet")
        planes[p] = _unit_plane(planes[p])
    flower = np.zeros(count, dtype=np.int64) if flower is None else np.asarray(flower, dtype=np.int64)
    if flower.shape != (count,):
        raise ValueError(f"flower: one per petal ({count}), got {flower.shape}")
    flowers = int(flower.max()) + 1
    axis_lines, lowest = [], []
    around = np.zeros(count, dtype=bool)  # (petals whose planes point around their axis)
    for k in range(flowers):
        mine = np.flatnonzero(flower == k)
        if given is None and base_mode == "auto" and mine.size >= 3:
            planes[mine] = _planes_about_axis(v, petal, planes[mine], ids=mine)
        if given is not None:
            centroid = np.mean([v[members[p]].mean(axis=0) for p in mine], axis=0)
            axis_lines.append(np.r_[_given_axis_point(planes[mine], given, centroid), given])
        else:
            axis_lines.append(_axis_from_planes(planes[mine]) if base_mode == "auto" and mine.size
                              else None)
        # with one petal, no line tells its base: the end lowest along a given axis does
        lowest.append(given is not None and mine.size == 1)
        if axis_lines[-1] is not None and mine.size >= 2:
            around[mine] = _around_axis(planes, [v[members[p]].mean(axis=0) for p in mine],
                                        mine, axis_lines[-1])

    base = np.zeros(nv, dtype=bool)
    widened, as_modelled = [], []
    on_axis = np.zeros(nv, dtype=bool)
    tips = np.zeros(count, dtype=np.int64)
    x = np.zeros(nv)
    s = np.zeros(nv)
    for p in range(count):
        if progress is not None:
            progress("petal axes", p, count, f"petal {p}")
        try:
            axis_line, lowest_end = axis_lines[flower[p]], lowest[flower[p]]
            idx = members[p]
            pts = v[idx]
            mine_edges = e_order[e_start[p]:e_start[p + 1]]
            local_edges = np.searchsorted(idx, edges[mine_edges])
            sub = topology.edge_graph(pts, local_edges)
            pieces = connected_components(sub, directed=False)[0]
            if pieces > 1:  # distances along the mesh would be infinite between the pieces
                raise BadPetal(p, f"in {pieces} pieces (not connected along the mesh): a petal is "
                               "one connected sheet")
            direction, proj = _petal_ends(pts, planes[p])
            if not np.all(np.isfinite(direction)) or np.ptp(proj) <= 0.0:
                raise BadPetal(p, "no length in its center plane: its vertices do not span a sheet")
            cut = None if held_rim is None else held_rim[idx]
            if cut is not None and cut.sum() < 3:
                cut = None
            if cut is not None:  # (held where it leaves the centre)
                base_low = proj[cut].mean() <= proj.mean()
            elif base_mode == "auto" and lowest_end:
                span = proj.max() - proj.min()
                low_end = pts[proj <= proj.min() + 0.15 * span].mean(axis=0) @ given
                high_end = pts[proj >= proj.max() - 0.15 * span].mean(axis=0) @ given
                base_low = low_end <= high_end
            elif base_mode == "auto" and axis_line is not None:
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
            local_faces = np.searchsorted(idx, faces[f_order[f_start[p]:f_start[p + 1]]])
            source = None if cut is not None else done.find(
                pts, local_faces,  # (its base at the same end)
                accept=lambda q, rot, d=direction: ways[q] @ rot.T @ d > 0.0)
            if source is not None:  # a copy of petal q (moved, turned, scaled, its base the
                # same end): q's axis, moved (a near-tie at rounding is decided alike)
                q, scale, rot, t = source
                them = members[q]
                base[idx], on_axis[idx] = base[them], on_axis[them]
                s[idx], x[idx] = s[them], x[them]
                tips[p] = idx[np.searchsorted(them, tips[q])]
                normal = rot @ planes[q][:3]
                planes[p] = np.r_[normal, scale * planes[q][3] + normal @ t]
                if q in widened:
                    widened.append(p)
                continue
            span = proj.max() - proj.min()
            bnd = boundary[idx]
            end = base_edge(pts, local_faces, bnd, proj, base_fraction * span,
                            None if corners is None else corners[idx]) \
                if surface or base_region == "edge" else None
            if cut is not None:
                end = cut & bnd
                mine_base = end.copy()
            else:
                mine_base = end.copy() if base_region == "edge" else (  # (rim: the paper's)
                    (bnd | (base_region == "band")) & (proj <= proj.min() + base_fraction * span))
            if mine_base.sum() < 3:  # a petal held by fewer than 3 vertices can spin
                order = np.argsort(np.where(bnd, proj, np.inf), kind="stable")
                mine_base[order[:3]] = True
            # held on a line, it could spin about it: widen the base, within a quarter of the
            # petal (or base_fraction: the fixed part should stay a base, not become the petal)
            reach = proj.min() + max(BASE_REACH, base_fraction) * span
            held = int(mine_base.sum())
            if not _widen_base(mine_base, bnd, proj, pts, sub, reach):
                raise WeakBase(p, int(mine_base.sum()), base_width(pts[mine_base], pts))
            if mine_base.sum() > held:
                widened.append(p)
            base[idx] = mine_base
            dist_base = (base_distance(pts, local_faces, end, mine_base) if surface
                         else dijkstra(sub, indices=np.flatnonzero(mine_base), min_only=True))

            # the axis: vertices on the center plane and, of each edge crossing it, the end
            # nearer the plane (both ends would make a band two vertices wide)
            side = pts @ planes[p][:3] - planes[p][3]
            mine_axis = np.abs(side) <= 1e-6 * span
            side[mine_axis] = 0.0  # on the plane up to rounding: not a crossing
            cross = local_edges[side[local_edges[:, 0]] * side[local_edges[:, 1]] < 0]
            far_first = np.abs(side[cross[:, 0]]) > np.abs(side[cross[:, 1]])  # ties: the first
            mine_axis[np.where(far_first, cross[:, 1], cross[:, 0])] = True
            if not mine_axis.any():
                mine_axis[np.argmin(np.abs(side))] = True
            # the tip: the axis's far end (the petal's far end where the axis stays in the base)
            tip_local = int(np.flatnonzero(mine_axis)[np.argmax(dist_base[mine_axis])])
            if not dist_base[tip_local] > 0.0:
                tip_local = int(np.argmax(dist_base))
                if not dist_base[tip_local] > 0.0:
                    raise BadPetal(p, f"all its {len(idx)} vertices are base vertices: no tip beyond "
                                   "its base (a petal of a few triangles; remesh it finer)",
                                   "remesh.petal_vertices")
            tips[p] = idx[tip_local]
            # (along the surface, 1 at the tip point: the same point at any resolution)
            tip_at = tip_distance(dist_base, side, local_faces, dist_base[tip_local]) if surface \
                else dist_base[tip_local]
            s[idx] = np.minimum(dist_base / tip_at, 1.0)
            if surface and base_region == "band":
                # the band by s, to the nearest row of vertices (the clamp's last row lies
                # on the band's edge on average, at any resolution: not up to an edge short)
                banded = _band_by_rows(s[idx], local_edges, base_fraction) | end
                if not np.array_equal(banded, mine_base):
                    mine_base = banded
                    if not _widen_base(mine_base, bnd, proj, pts, sub, reach):
                        raise WeakBase(p, int(mine_base.sum()), base_width(pts[mine_base], pts))
                    base[idx] = mine_base

            # orient the plane normal: (normal, base->tip chord, outward) right-handed; in a
            # flower, around its axis (:func:`_around_axis`): the cup's outward side, from a
            # few midrib vertices, can flip on an irregular mesh of a shallow cup
            chord = pts[tip_local] - pts[mine_base].mean(axis=0)
            outward = pts[mine_axis].mean(axis=0) - pts.mean(axis=0)
            if not around[p] and np.cross(chord, outward) @ planes[p][:3] < 0:
                planes[p] = -planes[p]
                side = -side
            on_axis[idx] = mine_axis

            rim = bnd & ~mine_base & ~mine_axis  # the cross-section coordinate:
            xs = cross_section(pts, local_faces, rim, side, s[idx]) if surface \
                else edge_cross_section(sub, mine_axis, rim, side, s[idx])
            x[idx] = xs
            _check_line(p, pts, sub, local_edges, mine_axis, dist_base, tip_local, xs)
            done.add(pts, local_faces, p)
            ways[p] = direction
        except (BadPetal, WeakBase) as exc:
            if not hold_bad:
                raise
            # a file of many flowers: the petal stays as modelled (every vertex held, no
            # growth), named; one blossom of a thousand does not stop the others
            idx = members[p]
            base[idx], on_axis[idx], s[idx], x[idx] = True, False, 0.0, 0.0
            tips[p] = idx[-1]
            if p in widened:
                widened.remove(p)
            as_modelled.append((p, exc.reason if isinstance(exc, BadPetal) else
                                f"its base is a line ({exc.width:.2g} of its length off one)"))

    # each petal's base-to-tip chord
    base_centre = topology.label_means(v[base], petal[base], count)
    chords = v[tips] - base_centre
    chords[[p for p, _ in as_modelled]] = 0.0  # (a petal held as modelled tells no way up)
    lines = np.full((flowers, 6), np.nan)
    for k, axis_line in enumerate(axis_lines):
        if axis_line is None:
            continue
        mine = np.flatnonzero(flower == k)
        line = axis_line.copy()
        if given is None:
            line[3:] = _oriented(line[3:], chords[mine], up)
        elif mine.size == 1:  # a lone petal: the axis passes through its base
            line[:3] = base_centre[mine[0]]
        lines[k] = line
    largest = int(np.argmax(np.bincount(flower, minlength=flowers)))
    axes = PetalAxes(base, on_axis, tips, planes, x, s, lines[largest].copy(), tuple(widened), lines,
                     tuple(as_modelled))
    check_axes(axes, petal)
    return axes


def _check_line(p: int, pts: np.ndarray, sub, local_edges: np.ndarray, mine_axis: np.ndarray,
                dist_base: np.ndarray, tip_local: int, xs: np.ndarray) -> None:
    """Raise :class:`BadPetal` (key ``scene.exclude``) unless petal ``p``'s axis is sane
    (see the module notes): its on-axis vertices a line, x reaching both sides, the
    axis running its length."""
    mean_edge = float(np.linalg.norm(pts[local_edges[:, 0]] - pts[local_edges[:, 1]],
                                     axis=1).mean())
    length = float(dist_base[tip_local]) / mean_edge  # the axis, in mean edges
    count = int(mine_axis.sum())
    hops = sub.copy()
    hops.data[:] = 1.0
    depth = axis_depth(hops, mine_axis)
    if depth > LINE_DEPTH or count > LINE_COUNT * max(length, 1.0):
        raise BadPetal(p, f"its axis is a region, not a line: {count} of its {len(pts)} "
                       f"vertices lie on its center plane, {depth:.0f} edges deep (at most "
                       f"{LINE_DEPTH:g}), {count / max(length, 1.0):.1f} per mean edge of its "
                       f"length (at most {LINE_COUNT:g}); the plane lies along the sheet, not "
                       "across it", "scene.exclude")
    if xs.min() > -1.0 or xs.max() < 1.0:
        raise BadPetal(p, f"x in [{xs.min():.3g}, {xs.max():.3g}], not [-1, 1]: its rim lies "
                       "on one side of its center plane only", "scene.exclude")
    centred = pts - pts.mean(axis=0)
    extent = float(np.ptp(centred @ np.linalg.svd(centred, full_matrices=False)[2][0]))
    if dist_base[tip_local] < AXIS_REACH * extent:
        raise BadPetal(p, f"its axis is {dist_base[tip_local] / extent:.0%} as long as the petal "
                       f"(at least {AXIS_REACH:.0%}): its center plane cuts across it, not along "
                       "its midrib", "scene.exclude")


def _oriented(direction: np.ndarray, chords: np.ndarray, up: np.ndarray | None) -> np.ndarray:
    """A found axis direction pointed from the receptacle toward the tips: by the petals
    when their tips rise along it by a tenth of their base-to-tip ``chords (P, 3)``; else
    by ``up``."""
    rise = float((chords @ direction).sum())
    if abs(rise) >= 0.1 * float(np.linalg.norm(chords, axis=1).sum()):
        return direction if rise > 0 else -direction
    if up is not None and abs(float(np.asarray(up) @ direction)) > 1e-9:
        return direction if float(np.asarray(up) @ direction) > 0 else -direction
    return direction
