"""A petal's coordinates s and x (:func:`pipeline.flower.axis.find_axes`).

Along edges (the paper's): the cross-section coordinate from shortest paths along edges
(:func:`edge_cross_section`). Along the surface (``find_axes(surface=True)``, what the
shell model runs on): the base edge (:func:`base_edge`), the distance from it
(:func:`base_distance`) and to the tip point (:func:`tip_distance`), and the
cross-section coordinate from the midrib curve (:func:`cross_section`), all from
distances along the surface (the heat method, :mod:`pipeline.mesh.geodesic`), so that
s and x converge as the mesh is refined."""

from __future__ import annotations

import numpy as np
from scipy.sparse.csgraph import dijkstra

from pipeline.mesh.geodesic import heat_distance, heat_distances, signed_heat_distances
from pipeline.mesh.remesh import boundary_loops, outline_corners
from pipeline.mesh.topology import boundary_vertices

#: the cross-section coordinate from the mean of Neumann and Dirichlet heat where the
#: petal's half-width is at least RIM_MEAN[1] mean edges, from Neumann heat alone where it
#: is under RIM_MEAN[0] (a tip narrower than an edge or two, where the Dirichlet heat is
#: all rim), blended linearly between (see :func:`cross_section`)
RIM_MEAN = (1.0, 2.0)


def _over_the_rim(g, sign, rim, s, widths: bool = False):
    """``x``: each vertex's distance ``g`` from the axis over the rim's at the same ``s``
    on its side (``sign``: -1, +1, or 0 on the axis), clipped to [0, 1] and signed.
    ``widths``: also return that rim distance per vertex (0 on the axis)."""
    xs = np.zeros(len(s))
    wide = np.zeros(len(s))
    for sg in (-1.0, 1.0):
        ring = rim & (sign == sg)
        here = sign == sg
        if not ring.any() or not here.any():
            continue
        order = np.argsort(s[ring], kind="stable")
        width = np.interp(s[here], s[ring][order], g[ring][order])
        wide[here] = width
        xs[here] = sg * np.clip(g[here] / np.maximum(width, 1e-12), 0.0, 1.0)
        xs[ring] = sg
    return (xs, wide) if widths else xs


def edge_cross_section(graph, axis, rim, side, s) -> np.ndarray:
    """The paper's cross-section coordinate: the distance along edges (``graph``, the
    petal's edge lengths) from the axis vertices ``axis``, signed by ``side`` (the
    signed distance to the center plane) and over the rim's (``rim``) at the same s on
    the same side: 0 on the axis, -1 and +1 on the two rims."""
    g = dijkstra(graph, indices=np.flatnonzero(axis), min_only=True)
    return _over_the_rim(g, np.where(axis, 0.0, np.sign(side)), rim, s)


def base_distance(pts, faces, end, base) -> np.ndarray:
    """``(n,)`` the distance along the surface (the heat method) from the base edge
    ``end`` (bool), or from the fixed vertices ``base`` where the edge has fewer than two
    vertices: from the edge, not from the fixed set, whose reach up the rim depends on
    where the vertices fall. Zero everywhere if every vertex is fixed."""
    if base.all():  # no tip beyond the base (the caller refuses the petal)
        return np.zeros(len(pts))
    source = end if end.sum() >= 2 else base
    return np.maximum(heat_distance(pts, faces, source), 0.0)


def _chain(loop, first: int, last: int, step: int) -> np.ndarray:
    """The loop's vertices from position ``first`` to ``last`` stepping by ``step``."""
    out, k = [loop[first]], first
    while k != last:
        k = (k + step) % len(loop)
        out.append(loop[k])
    return np.asarray(out, dtype=np.int64)


def tip_distance(dist, side, faces, fallback: float) -> float:
    """The distance from the base to the tip *point*, where the rim crosses the center
    plane farthest from the base (``dist`` interpolated along the boundary edge that
    crosses it), not to the tip vertex, which lies up to half an edge off it: s is then
    1 at the same point of the petal at any resolution. ``fallback`` where no boundary
    edge crosses the plane."""
    best = 0.0
    for loop in boundary_loops(faces):
        a, b = loop, np.roll(loop, -1)
        sa, sb = side[a], side[b]
        cross = (sa * sb <= 0.0) & (sa != sb)
        if not cross.any():
            continue
        t = sa[cross] / (sa[cross] - sb[cross])
        best = max(best, float(np.max((1.0 - t) * dist[a[cross]] + t * dist[b[cross]])))
    return best if best > 0.0 else fallback


def base_edge(pts, faces, rim, proj, reach, corner=None) -> np.ndarray:
    """``(n,) bool`` the petal's base edge: the stretch of rim through its vertex
    nearest the base end (least ``proj``) up to the corners (turns of :data:`OUTLINE_CORNER`
    or more, or ``corner`` (n,) where given) on either side, none farther than ``reach``
    along the petal. A petal whose base has no such corners (a pointed or rounded base):
    the rim within 1% of ``reach`` of the end, and at least that vertex."""
    out = np.zeros(len(pts), dtype=bool)
    if not rim.any():
        return out
    start = int(np.flatnonzero(rim)[np.argmin(proj[rim])])
    corner = outline_corners(pts, faces) if corner is None else np.asarray(corner, bool)
    for loop in boundary_loops(faces):
        at = np.flatnonzero(loop == start)
        if len(at) == 0:
            continue
        n, ends = len(loop), {}
        for step in (1, -1):  # the first corner each way along the rim, within reach
            k = int(at[0])
            for _ in range(n - 1):
                k = (k + step) % n
                if proj[loop[k]] > proj.min() + reach:
                    break
                if corner[loop[k]]:
                    ends[step] = k
                    break
        if corner[start]:  # the base edge runs one way from it: the lower chain
            chains = [_chain(loop, int(at[0]), k, step) for step, k in ends.items()]
        elif len(ends) == 2:
            chains = [_chain(loop, ends[-1], ends[1], 1)]
        else:
            chains = []
        if chains:
            best = min(chains, key=lambda c: proj[c].max())
            out[best] = True
            return out
    out[rim & (proj <= proj.min() + 0.01 * reach)] = True
    out[start] = True
    return out


def cross_section(pts, faces, rim, side, s) -> np.ndarray:
    """The cross-section coordinate of a petal's vertices: the geodesic distance from the
    midrib (the curve where the surface crosses the center plane: ``side``, the signed
    distance to the plane, is 0), signed by the side, over the rim's at the same s on
    the same side (``rim``: the boundary vertices off the base). 0 on the midrib, -1
    and +1 on the two rims.

    The distance is taken from the midrib curve itself (where it crosses the
    triangles) along the surface, signed (the heat method,
    :func:`pipeline.mesh.geodesic.signed_heat_distance`), not from the vertices next to
    it along edges: the coordinate converges as the mesh is refined, on any
    triangulation. A uniform error of the distances cancels in the ratio.

    The heat's fall-off bends near the rim with Neumann conditions (a first-order
    error: x 2.4% high at 300 vertices, 1.2% at 1,200, against the petal's x at
    19,200); the mean of the Neumann and the Dirichlet heat (Crane et al.) takes it
    away (0.7 and 0.4%). But where the petal is narrower than an edge or two (a coarse
    tip), nearly every vertex is on the rim, the Dirichlet heat is held at zero there,
    and its x is noise (a tip vertex of the water lily moved 0.2). So x is the mean's
    where the half-width is :data:`RIM_MEAN` [1] mean edges or more, Neumann's under
    [0], blended between."""
    f = np.asarray(faces, dtype=np.int64)
    distances = signed_heat_distances(pts, f, side, boundary=boundary_vertices(f, len(pts)))
    g = next(distances)
    if g is None:  # the plane misses the petal: from the vertex nearest it
        load = (np.abs(side) == np.abs(side).min()).astype(np.float64)
        g = heat_distances(pts, faces, [load])[0]
        return _over_the_rim(np.maximum(g, 0.0), np.sign(side), rim, s)
    x, width = _over_the_rim(np.maximum(np.sign(side) * g, 0.0), np.sign(side), rim, s,
                             widths=True)
    h = float(np.mean([np.linalg.norm(pts[f[:, k]] - pts[f[:, (k + 1) % 3]], axis=1).mean()
                       for k in range(3)]))
    weight = np.clip((width / h - RIM_MEAN[0]) / (RIM_MEAN[1] - RIM_MEAN[0]), 0.0, 1.0)
    if not weight.any():
        return x
    mean = next(distances)  # (the same factorizations)
    xm = _over_the_rim(np.maximum(np.sign(side) * mean, 0.0), np.sign(side), rim, s)
    return (1.0 - weight) * x + weight * xm
