"""A petal's sheet sampled as a height field over its own plane: for surfaces that have
no clean mid-surface (a coarse cage, a sheet with hems, a crumpled shell)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from pipeline.mesh import topology
from pipeline.mesh.repair import manifold_fans

#: grid nodes over the footprint's bounding box
CELLS = 1600
#: two hits at a node are distinct layers when further apart than this fraction of a cell
DISTINCT = 0.1
#: the part is two-sided (the sheet is halfway between) when this fraction of its
#: footprint has two distinct layers; otherwise the smoother of top and bottom is the sheet
TWO_SIDED = 0.5
#: rounds of smoothing the rim along itself (the grid leaves it in steps)
RIM_SMOOTHING = 4


class HeightSheet(NamedTuple):
    """Result of :func:`height_sheet`."""

    vertices: np.ndarray  #: (n, 3)
    faces: np.ndarray  #: (m, 3), one edge-connected, edge-manifold sheet, normal along ``normal``
    thickness: np.ndarray  #: (n,) distance between the outermost layers at each vertex
    normal: np.ndarray  #: (3,) the direction the heights are measured along
    two_sided: bool  #: the sheet is halfway between two layers (else it is one layer)
    relative_thickness: float  #: median distance between two layers / the footprint's width


def _frame(v: np.ndarray, f: np.ndarray):
    """The best-fit plane (:func:`pipeline.mesh.lobes.plane_frame`), right-handed, its
    normal along the faces' winding."""
    from pipeline.mesh.lobes import plane_frame

    centre, axes, _, _ = plane_frame(v, f)
    fn = topology.face_normals(v, f)
    axes[2] = np.cross(axes[0], axes[1])  # right-handed: a grid cell's winding gives +normal
    if axes[2] @ fn.sum(axis=0) < 0:  # the normal agrees with most of the faces' winding
        axes = np.array([axes[1], axes[0], -axes[2]])
    return centre, axes


def _rasterize(local: np.ndarray, f: np.ndarray, gu: np.ndarray, gw: np.ndarray):
    """(nu, nw) lowest and highest height of the surface over every grid node (+-inf where
    no triangle covers it)."""
    low = np.full((len(gu), len(gw)), np.inf)
    high = np.full((len(gu), len(gw)), -np.inf)
    spacing = gu[1] - gu[0] if len(gu) > 1 else 1.0
    for t in local[f]:
        (x0, y0, z0), (x1, y1, z1), (x2, y2, z2) = t
        det = (y1 - y2) * (x0 - x2) + (x2 - x1) * (y0 - y2)
        if abs(det) < 1e-12 * spacing * spacing:  # edge-on: seen as a line, covers nothing
            continue
        i0, i1 = np.searchsorted(gu, min(x0, x1, x2)), np.searchsorted(gu, max(x0, x1, x2), "right")
        j0, j1 = np.searchsorted(gw, min(y0, y1, y2)), np.searchsorted(gw, max(y0, y1, y2), "right")
        if i0 >= i1 or j0 >= j1:
            continue
        x, y = np.meshgrid(gu[i0:i1], gw[j0:j1], indexing="ij")
        l0 = ((y1 - y2) * (x - x2) + (x2 - x1) * (y - y2)) / det
        l1 = ((y2 - y0) * (x - x2) + (x0 - x2) * (y - y2)) / det
        l2 = 1.0 - l0 - l1
        inside = (l0 >= -1e-9) & (l1 >= -1e-9) & (l2 >= -1e-9)
        z = l0 * z0 + l1 * z1 + l2 * z2
        lo, hi = low[i0:i1, j0:j1], high[i0:i1, j0:j1]
        lo[inside] = np.minimum(lo[inside], z[inside])
        hi[inside] = np.maximum(hi[inside], z[inside])
    return low, high


def _roughness(height: np.ndarray, inside: np.ndarray) -> float:
    both_u = inside[1:, :] & inside[:-1, :]
    both_w = inside[:, 1:] & inside[:, :-1]
    return float(np.sum(np.diff(height, axis=0)[both_u] ** 2) + np.sum(np.diff(height, axis=1)[both_w] ** 2))


def _grid_faces(inside: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Node numbering and two triangles per grid cell whose four nodes are inside."""
    index = np.full(inside.shape, -1, dtype=np.int64)
    index[inside] = np.arange(int(inside.sum()))
    cell = inside[:-1, :-1] & inside[1:, :-1] & inside[:-1, 1:] & inside[1:, 1:]
    a, b = index[:-1, :-1][cell], index[1:, :-1][cell]
    c, d = index[:-1, 1:][cell], index[1:, 1:][cell]
    return index, np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


def _largest_piece(f: np.ndarray, n: int) -> np.ndarray:
    """Faces of the largest edge-connected piece (pieces touching at a corner are apart)."""
    _, _, _, _, a, b = topology.interior_pairs(f)
    nf = len(f)
    from scipy.sparse.csgraph import connected_components

    g = sp.coo_matrix((np.ones(len(a)), (a % nf, b % nf)), shape=(nf, nf))
    _, label = connected_components(g, directed=False)
    keep = f[label == np.argmax(np.bincount(label))]
    # a node where two cells meet only at a corner (the grid's checkerboard): the
    # larger fan keeps it
    return keep[manifold_fans(keep, n)]


def _smooth_rim(points: np.ndarray, f: np.ndarray, rounds: int) -> np.ndarray:
    edges, _, count = topology.unique_edges(f)
    rim = edges[count == 1]
    if len(rim) == 0:
        return points
    n = len(points)
    adj = sp.coo_matrix((np.ones(2 * len(rim)), (np.r_[rim[:, 0], rim[:, 1]], np.r_[rim[:, 1], rim[:, 0]])),
                        shape=(n, n)).tocsr()
    degree = np.asarray(adj.sum(axis=1)).ravel()
    on = degree == 2  # a rim vertex with two rim neighbours (a corner of two loops stays)
    p = points.copy()
    for _ in range(rounds):
        mean = (adj @ p) / np.maximum(degree, 1)[:, None]
        p[on] += 0.5 * (mean[on] - p[on])
    return p


def height_sheet(vertices: np.ndarray, faces: np.ndarray, cells: int = CELLS,
                 margin: int = 1) -> HeightSheet:
    """The sheet of a petal-like surface, sampled as heights over its best-fit plane.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
        One petal's surface in any state: a thin shell, one sheet with its edges folded
        under (a hem), a coarse or crumpled cage, open or closed, manifold or not.
    cells : int
        About how many grid nodes cover the footprint's bounding box.
    margin : int
        Grid nodes taken off the footprint's rim: the outermost row is where a hem's wall
        or a tilted rim is seen edge-on, and with 1 two petals cut from one surface stay
        two nodes apart.

    Returns
    -------
    HeightSheet

    Raises
    ------
    ValueError
        When the faces cover no grid cell (a surface seen edge-on from its own plane).

    Notes
    -----
    The plane is the area-weighted best fit through the face centroids; heights are
    along its normal. Every triangle is rasterized over a square grid, keeping at each
    node the lowest and the highest height of the surface there. Where most of the
    footprint has two distinct layers (``TWO_SIDED``), the sheet is halfway between them
    (a solidified petal); otherwise it is whichever of the top and the bottom is
    smoother (a single sheet whose edges fold under: its top; folded over: its bottom).
    The footprint is eroded by ``margin`` nodes (so that two petals cut from one surface
    do not touch), and the largest edge-connected piece is kept: the sheet loses a rim of
    one to two grid cells (measured: 85% of a hemmed test petal's area is kept). The rim,
    stepped by the grid, is smoothed along itself. ``relative_thickness`` tells a solid
    (a box, a sphere: as thick as wide) from a petal; the caller decides. Valid where the
    petal is a height field over its plane: a petal curled past a right angle is
    flattened onto its plane.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        raise ValueError("no faces")
    centre, axes = _frame(v, f)
    local = (v - centre) @ axes.T
    used = np.unique(f)
    lo, hi = local[used, :2].min(axis=0), local[used, :2].max(axis=0)
    if not min(hi - lo) > 1e-9 * max(hi - lo):
        raise ValueError("the surface covers no area seen from its own plane")
    spacing = float(np.sqrt(np.prod(hi - lo) / cells))
    nu, nw = (np.ceil((hi - lo) / spacing).astype(np.int64) + 1)
    gu, gw = lo[0] + spacing * np.arange(nu), lo[1] + spacing * np.arange(nw)
    low, high = _rasterize(local, f, gu, gw)
    covered = np.isfinite(low)
    if not covered.any():
        raise ValueError("the surface covers no area seen from its own plane")
    distinct = covered & (high - low > DISTINCT * spacing)
    two_sided = bool(distinct.sum() > TWO_SIDED * covered.sum())
    width = float(min(hi - lo))
    relative = float(np.median((high - low)[distinct]) / width) if distinct.any() else 0.0
    low, high = np.where(covered, low, 0.0), np.where(covered, high, 0.0)
    if two_sided:
        height = 0.5 * (low + high)
    else:
        height = high if _roughness(high, covered) <= _roughness(low, covered) else low
    inside = covered.copy()
    for _ in range(margin):
        was = inside.copy()
        inside[1:, :] &= was[:-1, :]
        inside[:-1, :] &= was[1:, :]
        inside[:, 1:] &= was[:, :-1]
        inside[:, :-1] &= was[:, 1:]
    index, grid_f = _grid_faces(inside)
    if len(grid_f) == 0:
        raise ValueError("the surface is too narrow seen from its own plane")
    u, w = np.meshgrid(gu, gw, indexing="ij")
    points = centre + np.stack([u[inside], w[inside], height[inside]], axis=1) @ axes
    thick = (high - low)[inside]
    grid_f = _largest_piece(grid_f, len(points))
    keep = np.unique(grid_f)
    points, thick = points[keep], thick[keep]
    sheet_f = np.searchsorted(keep, grid_f)
    points = _smooth_rim(points, sheet_f, RIM_SMOOTHING)
    return HeightSheet(points, sheet_f, thick, axes[2].copy(), two_sided, relative)
