"""Mirror planes of petals and symmetrization about them.

Two ways to make a petal mirror-symmetric (the paper's Fig. 6):

- its vertices already pair up across the plane (:func:`mirror_pairs`): average each
  vertex with its partner's mirror image (:func:`symmetrize`), the mesh is kept;
- they do not (meshes from modelling tools, remeshed sheets): cut the petal along the
  plane, average the kept half with the mirror image of the other half, optionally
  remesh that half, and stitch it to its own mirror image (:func:`mirrored_mesh`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.spatial import cKDTree
from trimesh.triangles import closest_point

from pipeline.mesh import topology


def reflect(points: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """Mirror ``points (N, 3)`` across ``plane = (nx, ny, nz, offset)`` (unit normal)."""
    n, d = plane[:3], plane[3]
    return points - 2.0 * (points @ n - d)[:, None] * n


def asymmetry(points: np.ndarray, plane: np.ndarray) -> float:
    """RMS distance from each mirrored point to the nearest original point."""
    dist, _ = cKDTree(points).query(reflect(points, plane))
    return float(np.sqrt(np.mean(dist ** 2)))


#: a candidate plane that more than this fraction of the points mirror onto themselves
#: (each point's mirror image is nearest the point itself) holds the sheet: a flat sheet
#: is its own mirror image about the plane it lies in, but that plane is no center plane
SHEET_IN_PLANE = 0.5
#: a plane refined from another candidate replaces the first only where it is at most this
#: fraction as asymmetric: a different mirror plane, not the same one found a little
#: better (hallgeirl's tubes: 0.16-0.42 against 0.68-1.08; the Blender lily's tepals, a
#: plane 0.6-2.5 degrees off for a few percent, are left as they were)
ELSEWHERE = 0.75
#: asymmetries under this fraction of the points' largest coordinate are rounding (a
#: float32 file's 6e-8 of it), not shape: among planes that exact, the one along the
#: petal's length is taken (a rhombus kite 0.3 m from the origin: 3e-8 m)
EXACT = 1e-6


def mirror_plane(points: np.ndarray, refine: bool = True) -> tuple[np.ndarray, float]:
    """The plane a petal is (most nearly) mirror-symmetric about, and its asymmetry.

    Notes
    -----
    A mirror-symmetric point set has its centroid on the mirror plane and the plane's
    normal among the principal axes of its covariance; the candidate with the smallest
    :func:`asymmetry` is taken. The normal's sign is fixed so that its largest component
    is positive (the caller may orient it further). With ``refine``, the plane is then
    improved by :func:`refine_plane` (which matters for petals that are only nearly
    symmetric: their principal axes tilt away from the mirror plane); the other
    candidates are refined too, freely and with the normal kept across the petal's
    longest axis, and one at most :data:`ELSEWHERE` as asymmetric wins: reflective ICP
    from the best principal plane can settle on a plane across an oval petal's length
    (hallgeirl's tubes: 0.68-1.08 mean edges asymmetric) where one along it is more
    symmetric (0.16-0.42).

    The plane a flat sheet lies in is never taken (:func:`center_plane_fault`): the sheet
    is trivially its own mirror image there (dimontel's flat petal). Where every
    candidate is such a plane, the most symmetric is returned (the axis stage then says
    why it is no center plane).
    """
    p = np.asarray(points, dtype=np.float64)
    c = p.mean(axis=0)
    _, vecs = np.linalg.eigh(np.cov((p - c).T))
    tree = cKDTree(p)
    rough = []
    for k in range(3):
        n = vecs[:, k]
        n = n * np.sign(n[np.argmax(np.abs(n))])
        plane = np.r_[n, n @ c]
        rough.append((plane, asymmetry(p, plane), center_plane_fault(p, plane, tree) is None))
    best, best_err = None, np.inf
    for plane, err, sane in rough:
        if sane and err < best_err - 1e-12:
            best, best_err = plane, err
    longest = vecs[:, 2]
    floor = EXACT * float(np.abs(p).max())
    if best is not None and best_err <= floor:
        # exact to rounding: kept as found, not refined (refining weighs rounding). Where
        # it is symmetric both ways (a rhombus kite of 4 vertices), the plane along the
        # petal's length is its midrib's; float32 rounding chose the one across it
        along = [(plane, err) for plane, err, sane in rough
                 if sane and err <= floor and abs(plane[:3] @ longest) < 0.5]
        if along and abs(best[:3] @ longest) >= 0.5:
            best, best_err = min(along, key=lambda pe: pe[1])
        return best, best_err
    if best is None:  # only the sheet's own plane(s): the most symmetric, as it is
        for plane, err, _ in rough:
            if err < best_err - 1e-12:
                best, best_err = plane, err
        return best, best_err
    if refine and best_err > 0.0:
        plane = refine_plane(p, best)
        err = asymmetry(p, plane)
        if err < best_err and center_plane_fault(p, plane, tree) is None:
            best, best_err = plane, err
        others = [refine_plane(p, q) for q, _, sane in rough if sane and q is not best]
        others += [refine_plane(p, q, across=longest) for q, _, sane in rough
                   if sane and abs(q[:3] @ longest) < 0.5]
        first = best_err
        for plane in others:
            err = asymmetry(p, plane)
            if (err < min(best_err, ELSEWHERE * first) and
                    center_plane_fault(p, plane, tree) is None):
                best, best_err = plane, err
    return best, best_err


def center_plane_fault(points: np.ndarray, plane: np.ndarray,
                       tree: cKDTree | None = None) -> str | None:
    """Why ``plane`` cannot be the center plane of the petal ``points (N, 3)``, or None:
    it holds the sheet (more than :data:`SHEET_IN_PLANE` of the points are their own
    mirror image: nearer it than any other point is)."""
    p = np.asarray(points, dtype=np.float64)
    tree = cKDTree(p) if tree is None else tree
    _, j = tree.query(reflect(p, plane))
    itself = float(np.mean(j == np.arange(len(p))))
    if itself > SHEET_IN_PLANE:
        return (f"the sheet lies in it ({itself:.0%} of the vertices are their own mirror "
                "image)")
    return None


def refine_plane(points: np.ndarray, plane: np.ndarray, iterations: int = 30,
                 across: np.ndarray | None = None) -> np.ndarray:
    """Improve a mirror plane by reflective ICP.

    Each round pairs every point with the point nearest its mirror image and takes the
    plane that best bisects the pairs: its normal is the principal direction of the
    differences, its offset the mean of the midpoints along it. Stops when the plane
    no longer moves. The normal keeps the input's orientation. ``across``: a unit
    direction the plane keeps (the normal stays perpendicular to it).
    """
    tree = cKDTree(points)
    keep = None if across is None else np.eye(3) - np.outer(across, across)
    if keep is not None:
        n0 = keep @ plane[:3]
        plane = np.r_[n0 / np.linalg.norm(n0), plane[3]]
    for _ in range(iterations):
        _, j = tree.query(reflect(points, plane))
        d = points - points[j]
        m = d.T @ d if keep is None else keep @ (d.T @ d) @ keep
        w, vecs = np.linalg.eigh(m)
        n = vecs[:, 2]
        if w[2] <= 0.0:
            break
        n = n if n @ plane[:3] >= 0 else -n
        new = np.r_[n, float(np.mean(0.5 * (points + points[j]) @ n))]
        if np.allclose(new, plane, rtol=0.0, atol=1e-12):
            break
        plane = new
    return plane


def mirror_pairs(points: np.ndarray, plane: np.ndarray, faces: np.ndarray | None = None,
                 tolerance: float = 0.25) -> np.ndarray | None:
    """Index of each point's mirror partner, or None if the points do not pair up.

    Pairs must be mutual nearest neighbours after mirroring, closer than ``tolerance``
    (in mesh units), and, when ``faces`` is given, map every face onto a face.
    """
    tree = cKDTree(points)
    dist, partner = tree.query(reflect(points, plane))
    if np.any(dist > tolerance) or np.any(partner[partner] != np.arange(len(points))):
        return None
    if faces is not None:
        have = {tuple(sorted(f)) for f in faces.tolist()}
        if any(tuple(sorted(partner[f])) not in have for f in faces.tolist()):
            return None
    return partner


def symmetrize(points: np.ndarray, plane: np.ndarray, partner: np.ndarray) -> np.ndarray:
    """Average each point with its partner's mirror image: the result is exactly
    mirror-symmetric (up to rounding), and self-paired points land on the plane."""
    mirrored = reflect(points[partner], plane)
    return 0.5 * (points + mirrored)


def plane_frame(plane: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A rotation ``R`` (rows: normal, two tangents) and an origin on the plane, so that
    ``(p - origin) @ R.T`` has the signed distance to the plane as its first column."""
    n = np.asarray(plane[:3], dtype=np.float64)
    t1 = np.cross(n, np.eye(3)[np.argmin(np.abs(n))])
    t1 /= np.linalg.norm(t1)
    return np.vstack([n, t1, np.cross(n, t1)]), n * plane[3]


def clip(vertices: np.ndarray, faces: np.ndarray, u: np.ndarray):
    """The part of a mesh where ``u >= 0`` (``u`` per vertex), cut along ``u = 0``.

    Faces straddling the cut are clipped; a new vertex is made where an edge crosses
    (one per edge, shared by both faces, with ``u`` set to exactly 0). Returns
    ``(vertices, faces, u)`` with unused vertices dropped.
    """
    v = list(np.asarray(vertices, dtype=np.float64))
    uu = list(np.asarray(u, dtype=np.float64))
    made: dict[tuple[int, int], int] = {}

    def crossing(a: int, b: int) -> int:
        key = (min(a, b), max(a, b))
        if key not in made:
            t = uu[key[0]] / (uu[key[0]] - uu[key[1]])
            v.append(v[key[0]] + t * (v[key[1]] - v[key[0]]))
            uu.append(0.0)
            made[key] = len(v) - 1
        return made[key]

    out = []
    for tri in np.asarray(faces, dtype=np.int64).tolist():
        side = [uu[a] for a in tri]
        if min(side) >= 0.0:
            out.append(tri)
            continue
        if max(side) <= 0.0:
            continue
        poly = []
        for k in range(3):
            a, b = tri[k], tri[(k + 1) % 3]
            if uu[a] >= 0.0:
                poly.append(a)
            if (uu[a] > 0.0 > uu[b]) or (uu[a] < 0.0 < uu[b]):
                poly.append(crossing(a, b))
        out.extend([poly[0], poly[k], poly[k + 1]] for k in range(1, len(poly) - 1))
    v_arr, u_arr = np.asarray(v), np.asarray(uu)
    f_arr = np.asarray(out, dtype=np.int64).reshape(-1, 3)
    area = np.linalg.norm(topology.face_normals(v_arr, f_arr), axis=1)
    f_arr = f_arr[area > 0.0]
    used = np.zeros(len(v_arr), dtype=bool)
    used[f_arr.ravel()] = True
    remap = np.cumsum(used) - 1
    return v_arr[used], remap[f_arr], u_arr[used]


def closest_points(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray,
                   candidates: int = 8) -> np.ndarray:
    """For each point, the closest point on the triangles incident to its
    ``candidates`` nearest mesh vertices (exact for points near a fine mesh)."""

    k = min(candidates, len(vertices))
    _, near = cKDTree(vertices).query(points, k=k)
    near = near.reshape(len(points), k)
    incident = [[] for _ in range(len(vertices))]
    for i, tri in enumerate(faces.tolist()):
        for a in tri:
            incident[a].append(i)
    pairs = [(p, fi) for p in range(len(points)) for fi in sorted({f for a in near[p] for f in incident[a]})]
    pi = np.array([p for p, _ in pairs])
    fi = np.array([f for _, f in pairs])
    q = closest_point(vertices[faces[fi]], points[pi])
    dist = np.linalg.norm(q - points[pi], axis=1)
    order = np.lexsort((dist, pi))
    first = order[np.r_[True, pi[order][1:] != pi[order][:-1]]]
    return q[first]


#: a rim corner is snapped onto the center plane (:func:`mirrored_mesh`) only within this
#: share of the petal's largest distance from it (its half width)
CORNER_SHARE = 0.25


def mirrored_mesh(vertices: np.ndarray, faces: np.ndarray, plane: np.ndarray, *,
                  snap: float, remesh: Callable | None = None, snap_corners: float = 0.0):
    """A mirror-symmetric petal made from both halves of a petal about ``plane``.

    Vertices closer than ``snap`` to the plane are moved onto it, so the cut makes no
    slivers (before a remesh, which resamples the cut, a small snap distorts least), and
    so are sharp rim corners closer than ``snap_corners``.
    The half on the normal's side is cut off, each of its vertices is moved halfway
    to the mirror image of the other half, ``remesh(v, f, fixed)`` (if given)
    remeshes it with the ends of the cut fixed (``v`` in the plane's frame: its first
    coordinate is the distance to the plane, exactly 0 along the cut), and it is stitched to its mirror image
    along the cut. Returns ``(vertices, faces, partner)``: ``partner`` maps every vertex
    to its mirror image (itself on the plane).
    """
    R, origin = plane_frame(plane)
    local = (np.asarray(vertices, dtype=np.float64) - origin) @ R.T
    close = np.abs(local[:, 0]) < snap
    if snap_corners > 0.0:
        # a sharp rim corner near the plane is the petal's tip (or its base): left off the
        # plane, the mirrored petal gets two tips a sliver apart, with a notch between
        from pipeline.mesh.remesh import corner_vertices

        # ... but not a corner that is the petal's width (a low-poly kite's side corners,
        # its widest points, 0.4 of an edge off the plane: snapped, the half was a line)
        near = np.abs(local[:, 0]) < np.minimum(snap_corners, CORNER_SHARE * np.abs(local[:, 0]).max())
        close |= corner_vertices(vertices, faces) & near
    # never snap both ends of an edge that crosses the plane steeply (more across it than
    # along it): that would shorten it to its length along the plane (or merge its ends);
    # keep the end nearer the plane. An edge lying in the plane up to rounding (a midrib
    # at u = +-1e-16) is snapped whole: leaving one end off by 1e-16 would make a crossing
    # vertex on top of it for every edge from it to the other side.
    edges, _, _ = topology.unique_edges(faces)
    u = local[:, 0]
    du2 = (u[edges[:, 0]] - u[edges[:, 1]]) ** 2
    steep = 2.0 * du2 > np.sum((local[edges[:, 0]] - local[edges[:, 1]]) ** 2, axis=1)
    for _ in range(len(edges)):
        both = (close[edges[:, 0]] & close[edges[:, 1]] & (u[edges[:, 0]] * u[edges[:, 1]] < 0)
                & steep)
        if not both.any():
            break
        e = edges[np.flatnonzero(both)[0]]
        close[e[np.argmax(np.abs(u[e]))]] = False
    local[close, 0] = 0.0
    half_v, half_f, half_u = clip(local, faces, local[:, 0])
    half_v[:, 0] = half_u  # cut vertices exactly on the plane
    other_v, other_f, _ = clip(local * [-1.0, 1.0, 1.0], faces, -local[:, 0])
    if len(half_f) == 0 or len(other_f) == 0:
        raise ValueError("the petal lies on one side of its center plane")
    on_plane = half_v[:, 0] == 0.0
    target = closest_points(other_v, other_f, half_v)
    half_v = 0.5 * (half_v + target)
    half_v[on_plane, 0] = 0.0
    half_v[half_v[:, 0] < 0.0, 0] = 0.0
    if remesh is not None:
        boundary = topology.boundary_vertices(half_f, len(half_v))
        cut = boundary & (half_v[:, 0] == 0.0)
        edges, _, count = topology.unique_edges(half_f)
        rim_edges = edges[count == 1]
        ends = np.zeros(len(half_v), dtype=bool)
        mixed = cut[rim_edges[:, 0]] != cut[rim_edges[:, 1]]
        ends[rim_edges[mixed].ravel()] = True
        half_v, half_f, _ = remesh(half_v, half_f, ends & cut)
        half_v[np.abs(half_v[:, 0]) < 1e-12 * max(1.0, np.abs(half_v).max()), 0] = 0.0
    half_f = _flip_flat_faces(half_v[:, 0], half_f)
    boundary = topology.boundary_vertices(half_f, len(half_v))
    seam = boundary & (half_v[:, 0] == 0.0)
    n = len(half_v)
    partner = np.arange(n)
    copies = np.flatnonzero(~seam)
    partner[copies] = n + np.arange(len(copies))
    mirror_v = half_v[copies] * [-1.0, 1.0, 1.0]
    mirror_f = partner[half_f][:, [0, 2, 1]]
    v = np.vstack([half_v, mirror_v])
    f = np.vstack([half_f, mirror_f])
    partner = np.r_[partner, copies]
    _, _, count = topology.unique_edges(f)
    if np.any(count > 2):
        raise ValueError("the mirrored halves meet in more than a seam")
    return v @ R + origin, f, partner


def _flip_flat_faces(u: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Remove faces lying in the mirror plane (all three ``u == 0``) from a half.

    Such a face (an ear of the cut line) would coincide with its own mirror image. Its
    edge into the half is flipped, which makes two faces reaching off the plane; a face
    with no edge into the half is dropped.
    """
    f = faces.copy()
    for _ in range(len(f)):
        flat = np.flatnonzero((u[f] == 0.0).all(axis=1))
        if len(flat) == 0:
            break
        he, opposite = topology.half_edges(f)
        nf = len(f)
        t = int(flat[0])
        for k in (t, t + nf, t + 2 * nf):
            a, b = he[k]
            twin = np.flatnonzero((he[:, 0] == b) & (he[:, 1] == a))
            if len(twin) == 1 and u[opposite[twin[0]]] != 0.0:
                o, o2, t2 = opposite[k], opposite[twin[0]], int(twin[0] % nf)
                f[t], f[t2] = (a, o2, o), (b, o, o2)
                break
        else:
            f = np.delete(f, t, axis=0)
    return f
