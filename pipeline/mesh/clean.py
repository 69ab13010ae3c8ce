"""Cleaning a triangle mesh: weld, drop degenerate and duplicate faces, orient, scale."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from pipeline.mesh import topology


@dataclass
class CleanReport:
    """What :func:`clean_mesh` changed, for the log and the artifact."""

    welded: int = 0
    degenerate_faces: int = 0
    duplicate_faces: int = 0
    #: of ``duplicate_faces``, those wound opposite to the copy kept (a stacked, flipped copy)
    opposite_duplicate_faces: int = 0
    unreferenced: int = 0
    flipped_faces: int = 0
    dust_pieces: int = 0  #: tiny connected pieces dropped (the remesh stage, per part)
    dust_faces: int = 0  #: their faces
    midsurfaces: int = 0  #: thick petals replaced by their mid-surface
    height_sheets: int = 0  #: petals sampled as height fields over their lobes (no mid-surface)
    ring_splits: int = 0  #: sheets that were several petals joined at a hub, split into them
    nonmanifold_edges: int = 0  #: edges of 3+ faces repaired (the remesh stage, per part)
    nonmanifold_faces: int = 0  #: faces dropped to repair them
    split_vertices: int = 0  #: vertex copies made where separate fans of faces met
    zipped_vertices: int = 0  #: rim vertices merged to close a slit in a sheet
    notes: list = field(default_factory=list)


def weld(vertices: np.ndarray, faces: np.ndarray, tolerance: float):
    """Merge vertices closer than ``tolerance``; the first vertex of a group is kept.

    Returns ``(vertices, faces, merged_count)``.
    """
    from scipy.spatial import cKDTree

    pairs = cKDTree(vertices).query_pairs(tolerance, output_type="ndarray")
    if len(pairs) == 0:
        return vertices, faces, 0
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    n = len(vertices)
    g = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label = connected_components(g, directed=False)
    _, first = np.unique(label, return_index=True)
    keep = np.sort(first)
    new_index = np.empty(n, dtype=np.int64)
    rank = np.empty(label.max() + 1, dtype=np.int64)
    rank[label[keep]] = np.arange(len(keep))
    new_index[:] = rank[label]
    return vertices[keep], new_index[faces], n - len(keep)


def orient_consistently(faces: np.ndarray, vertex_count: int) -> tuple[np.ndarray, int]:
    """Flip faces so that every edge-manifold component has one orientation.

    Each component is spanned by a tree of face adjacencies grown breadth-first from its
    lowest face; a face is flipped when it runs the same way as its parent in the tree
    along their edge (whether it is flipped is the parity of such mismatches on its path
    to the root, found by pointer jumping: a few passes over arrays, however large the
    mesh). Returns ``(faces, flipped_count)``; the first face of each component keeps its
    winding.
    """
    import scipy.sparse as sp
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    faces = faces.copy()
    nf = len(faces)
    if nf == 0:
        return faces, 0
    he, _, _, _, a, b = topology.interior_pairs(faces)
    fa, fb = a % nf, b % nf
    mismatch = he[a, 0] == he[b, 0]  # both faces run the edge the same way: mismatch
    link = fa != fb
    fa, fb, mismatch = fa[link], fb[link], mismatch[link]
    # a root joined to the first face of every component: one search covers them all
    _, comp = connected_components(sp.coo_matrix((np.ones(len(fa)), (fa, fb)), shape=(nf, nf)),
                                   directed=False)
    _, first = np.unique(comp, return_index=True)
    root = nf
    rows = np.r_[fa, fb, np.full(first.size, root)]
    cols = np.r_[fb, fa, first]
    graph = sp.coo_matrix((np.ones(rows.size), (rows, cols)), shape=(nf + 1, nf + 1)).tocsr()
    _, parent = breadth_first_order(graph, root, directed=True, return_predecessors=True)
    parent = parent[:nf]
    # the mismatch of each face with its parent (none for the first faces)
    key = np.minimum(fa, fb) * nf + np.maximum(fa, fb)
    order = np.argsort(key, kind="stable")
    child = np.flatnonzero(parent != root)
    pk = np.minimum(parent[child], child) * nf + np.maximum(parent[child], child)
    at = order[np.searchsorted(key[order], pk)]
    flip = np.zeros(nf, dtype=bool)
    flip[child] = mismatch[at]
    up = np.where(parent == root, np.arange(nf), parent)
    while True:  # pointer jumping: flip becomes the parity of the whole path to the root
        done = up[up] == up
        flip = flip ^ np.where(up != np.arange(nf), flip[up], False)
        if np.all(done):
            break
        up = up[up]
    faces[flip] = faces[flip][:, [0, 2, 1]]
    return faces, int(flip.sum())


def clean_mesh(vertices: np.ndarray, faces: np.ndarray, weld_tolerance: float = 1e-6):
    """Weld near-duplicate vertices (``weld_tolerance`` x bounding-box diagonal), drop
    degenerate and duplicate faces (a stacked copy too, whichever way it is wound) and
    unused vertices, and orient faces consistently.

    Returns ``(vertices, faces, CleanReport)``.
    """
    report = CleanReport()
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    diag = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    v, f, report.welded = weld(v, f, weld_tolerance * max(diag, 1e-300))
    # degenerate: repeated index, (numerically) zero area, or a sliver on the rim: height
    # under 1e-6 of its longest edge (three vertices collinear up to the file's rounding:
    # its hinge would have no usable normal, its apex no stiffness across) with two of
    # its edges on the boundary, so that dropping it leaves the sheet whole. A sliver
    # inside the sheet is kept (dropping it would cut a slit); remeshing removes it.
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0])
    area2 = np.linalg.norm(topology.face_normals(v, f), axis=1)
    p = v[f]
    longest2 = np.max(np.sum((p - np.roll(p, 1, axis=1)) ** 2, axis=2), axis=1)
    flat = area2 <= 1e-12 * max(diag, 1e-300) ** 2
    sliver = ~flat & (area2 <= 1e-6 * longest2)
    if sliver.any():
        _, he_edge, count = topology.unique_edges(f)
        on_rim = (count[he_edge] == 1).reshape(3, -1).sum(axis=0)  # half-edges: by corner
        flat |= sliver & (on_rim >= 2)
    bad = repeated | flat
    report.degenerate_faces = int(bad.sum())
    f = f[~bad]
    key = np.sort(f, axis=1)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    report.duplicate_faces = len(f) - len(first)
    if report.duplicate_faces:
        # a copy runs the same way as the kept face if it is a rotation of it
        kept = f[first[inverse.ravel()]]
        same = np.zeros(len(f), dtype=bool)
        for r in range(3):
            same |= np.all(np.roll(f, r, axis=1) == kept, axis=1)
        report.opposite_duplicate_faces = int((~same).sum())
    f = f[np.sort(first)]
    used = np.zeros(len(v), dtype=bool)
    used[f.ravel()] = True
    report.unreferenced = int((~used).sum())
    remap = np.cumsum(used) - 1
    v, f = v[used], remap[f]
    if len(f):
        f, report.flipped_faces = orient_consistently(f, len(v))
    return v, f, report


def mean_edge_length(vertices: np.ndarray, faces: np.ndarray) -> float:
    edges, _, _ = topology.unique_edges(faces)
    return float(np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1).mean())


#: :func:`layered_fraction` looks for the faces behind this many faces at a time
LAYERED_BLOCK = 512


def layered_fraction(vertices: np.ndarray, faces: np.ndarray) -> tuple[float, float]:
    """How much of a sheet is two layers: ``(area fraction, median gap)``.

    A face counts as layered when another face of the same sheet, not touching it,
    faces the opposite way right behind it (along its normal, within a few edge lengths
    or a tenth of the sheet's size). A slab cut open along a slit is layered almost
    everywhere; a cupped or folded petal only along a fold.
    """
    from scipy.spatial import cKDTree

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    fn = topology.face_normals(v, f)
    area = np.linalg.norm(fn, axis=1)
    n = fn / np.maximum(area, 1e-300)[:, None]
    c = v[f].mean(axis=1)
    edge = mean_edge_length(v, f)
    diag = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    tree = cKDTree(c)
    radius = min(0.1 * diag, 10.0 * edge)
    layered = np.zeros(len(f), dtype=bool)
    gaps = []
    # the pairs within the radius, a block of faces at a time: a 100,000-face sheet has
    # tens of millions of them, too many to hold at once
    for start in range(0, len(f), LAYERED_BLOCK):
        block = np.arange(start, min(start + LAYERED_BLOCK, len(f)))
        found = tree.query_ball_point(c[block], radius)
        i = np.repeat(block, [len(x) for x in found])
        j = np.fromiter(itertools.chain.from_iterable(found), dtype=np.int64, count=len(i))
        keep = j > i  # each pair once, as query_pairs gives it
        i, j = i[keep], j[keep]
        if len(i) == 0:
            continue
        d = c[j] - c[i]
        along = np.abs(np.einsum("ij,ij->i", d, n[i]))
        lateral = np.linalg.norm(d - along[:, None] * n[i] * np.sign(np.einsum("ij,ij->i", d, n[i]))[:, None],
                                 axis=1)
        touching = (f[i][:, :, None] == f[j][:, None, :]).any(axis=(1, 2))
        behind = (np.einsum("ij,ij->i", n[i], n[j]) < -0.5) & (lateral < 0.5 * along + edge) & ~touching
        layered[i[behind]] = True
        layered[j[behind]] = True
        gaps.append(along[behind])
    gap = np.concatenate(gaps) if gaps else np.zeros(0)
    return float(area[layered].sum() / area.sum()), float(np.median(gap)) if gap.size else 0.0
