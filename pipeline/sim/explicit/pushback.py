"""The paper's collision response, compiled: vertex-triangle contacts between petals
found through a hashed uniform grid and pushed back to the side they belong on, and an
exact edge-through-triangle count for the report."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from pipeline.mesh.separate import joined_labels


@njit(cache=True, inline="always")
def _cell_hash(ix, iy, iz, size):
    return ((ix * 73856093) ^ (iy * 19349663) ^ (iz * 83492791)) % size


@njit(cache=True)
def build_face_grid(X, faces, inflate, cell, start, count, items):
    """A uniform grid over space, stored as a hash table of cells: every face is listed
    in every cell its bounding box (grown by ``inflate``) overlaps. Counting sort into
    ``start (S+1,)``, ``count (S,)`` and ``items``.

    A face whose box spans more than 3 cells along an axis (it has grown far beyond its
    rest size: the run is diverging) is left out, and so is everything when the
    listings exceed ``items``' capacity (the grid is then empty). Returns how many
    listings were left out: 0 when the grid is complete."""
    size = count.shape[0]
    count[:] = 0
    lost = 0
    for pass_ in range(2):
        if pass_ == 1:
            total = 0
            for b in range(size):
                total += count[b]
            if total > items.shape[0]:
                count[:] = 0
                start[:] = 0
                return lost + total - items.shape[0]
            start[0] = 0
            for b in range(size):
                start[b + 1] = start[b] + count[b]
                count[b] = 0
        for f in range(faces.shape[0]):
            a, b_, c = faces[f, 0], faces[f, 1], faces[f, 2]
            lo0 = min(X[a, 0], min(X[b_, 0], X[c, 0])) - inflate
            lo1 = min(X[a, 1], min(X[b_, 1], X[c, 1])) - inflate
            lo2 = min(X[a, 2], min(X[b_, 2], X[c, 2])) - inflate
            hi0 = max(X[a, 0], max(X[b_, 0], X[c, 0])) + inflate
            hi1 = max(X[a, 1], max(X[b_, 1], X[c, 1])) + inflate
            hi2 = max(X[a, 2], max(X[b_, 2], X[c, 2])) + inflate
            if not (hi0 - lo0 <= 3.0 * cell and hi1 - lo1 <= 3.0 * cell
                    and hi2 - lo2 <= 3.0 * cell):
                if pass_ == 0:
                    lost += 1
                continue
            for ix in range(int(math.floor(lo0 / cell)), int(math.floor(hi0 / cell)) + 1):
                for iy in range(int(math.floor(lo1 / cell)), int(math.floor(hi1 / cell)) + 1):
                    for iz in range(int(math.floor(lo2 / cell)), int(math.floor(hi2 / cell)) + 1):
                        key = _cell_hash(ix, iy, iz, size)
                        if pass_ == 0:
                            count[key] += 1
                        else:
                            items[start[key] + count[key]] = f
                            count[key] += 1
    return lost


@njit(cache=True)
def collide(X, V, inv_mass, faces, face_petal, vert_petal, side, near, normals, par, start,
            count, items, pair_start, pair_faces, best_face, best_dist, X_ref, counters):
    """One step of the collision effect.

    Near pairs (a vertex and the faces of other petals within ``margin + 2 slack`` of
    it) are found through the grid and kept, Verlet-list style, until some vertex has
    moved more than ``slack`` since: until then no vertex can have come within
    ``margin`` of a face that is not listed. So the grid is built rarely and each step
    tests only the pairs that are really near. ``counters``: [contacts, builds,
    overflow, listed pairs].
    """
    cell, offset, margin, slack = par[0], par[1], par[2], par[3]
    moved = counters[1] == 0
    if not moved:
        limit = slack * slack
        for v in range(X.shape[0]):
            dx = X[v, 0] - X_ref[v, 0]
            dy = X[v, 1] - X_ref[v, 1]
            dz = X[v, 2] - X_ref[v, 2]
            if dx * dx + dy * dy + dz * dz > limit:
                moved = True
                break
    if moved:
        reach = margin + offset + 2.0 * slack
        counters[2] += build_face_grid(X, faces, reach, cell, start, count, items)
        counters[2] += near_pairs(X, faces, face_petal, vert_petal, inv_mass, reach, cell, start,
                                  count, items, pair_start, pair_faces)
        counters[3] = pair_start[X.shape[0]]
        X_ref[:, :] = X
        counters[1] += 1
    face_unit_normals(X, faces, normals)
    counters[0] += resolve_collisions(X, V, inv_mass, faces, face_petal, vert_petal, side, near,
                                      normals, offset, margin, pair_start, pair_faces,
                                      best_face, best_dist)


@njit(cache=True)
def near_pairs(X, faces, face_petal, vert_petal, inv_mass, reach, cell, start, count, items,
               pair_start, pair_faces):
    """For every free vertex, the faces of other petals whose bounding box is within
    ``reach`` of it (read from the grid of :func:`build_face_grid`), as a CSR list in
    ``pair_start (V+1,)`` and ``pair_faces``. Returns how many pairs did not fit."""
    size = count.shape[0]
    capacity = pair_faces.shape[0]
    n = 0
    lost = 0
    for v in range(X.shape[0]):
        pair_start[v] = n
        if inv_mass[v] == 0.0:
            continue
        P = vert_petal[v]
        key = _cell_hash(int(math.floor(X[v, 0] / cell)), int(math.floor(X[v, 1] / cell)),
                         int(math.floor(X[v, 2] / cell)), size)
        for k in range(start[key], start[key + 1]):
            f = items[k]
            if face_petal[f] == P:
                continue
            gap = 0.0
            for c in range(3):
                lo = min(X[faces[f, 0], c], min(X[faces[f, 1], c], X[faces[f, 2], c]))
                hi = max(X[faces[f, 0], c], max(X[faces[f, 1], c], X[faces[f, 2], c]))
                if X[v, c] < lo:
                    gap = max(gap, lo - X[v, c])
                elif X[v, c] > hi:
                    gap = max(gap, X[v, c] - hi)
            if gap > reach:
                continue
            if n < capacity:
                pair_faces[n] = f
                n += 1
            else:
                lost += 1
    pair_start[X.shape[0]] = n
    return lost


@njit(cache=True)
def face_unit_normals(X, faces, normals):
    """Unit normal of every face (zero for a degenerate face)."""
    for f in range(faces.shape[0]):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        e0x, e0y, e0z = X[b, 0] - X[a, 0], X[b, 1] - X[a, 1], X[b, 2] - X[a, 2]
        e1x, e1y, e1z = X[c, 0] - X[a, 0], X[c, 1] - X[a, 1], X[c, 2] - X[a, 2]
        nx = e0y * e1z - e0z * e1y
        ny = e0z * e1x - e0x * e1z
        nz = e0x * e1y - e0y * e1x
        norm = math.sqrt(nx * nx + ny * ny + nz * nz)
        inv = 1.0 / norm if norm > 0.0 else 0.0
        normals[f, 0] = nx * inv
        normals[f, 1] = ny * inv
        normals[f, 2] = nz * inv


@njit(cache=True, inline="always")
def _prism_distance(X, faces, normals, f, v):
    """Distance of vertex v along face f's unit normal, whether v lies in f's prism, and
    its barycentric coordinates on the face (weights of the second and third corner)."""
    a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
    px, py, pz = X[v, 0] - X[a, 0], X[v, 1] - X[a, 1], X[v, 2] - X[a, 2]
    dist = px * normals[f, 0] + py * normals[f, 1] + pz * normals[f, 2]
    e0x, e0y, e0z = X[b, 0] - X[a, 0], X[b, 1] - X[a, 1], X[b, 2] - X[a, 2]
    e1x, e1y, e1z = X[c, 0] - X[a, 0], X[c, 1] - X[a, 1], X[c, 2] - X[a, 2]
    d00 = e0x * e0x + e0y * e0y + e0z * e0z
    d01 = e0x * e1x + e0y * e1y + e0z * e1z
    d11 = e1x * e1x + e1y * e1y + e1z * e1z
    d20 = px * e0x + py * e0y + pz * e0z
    d21 = px * e1x + py * e1y + pz * e1z
    denom = d00 * d11 - d01 * d01
    if denom <= 0.0:
        return dist, False, 0.0, 0.0
    bv = (d11 * d20 - d01 * d21) / denom
    bw = (d00 * d21 - d01 * d20) / denom
    return dist, bv >= 0.0 and bw >= 0.0 and bv + bw <= 1.0, bv, bw


@njit(cache=True)
def nearest_faces(X, faces, face_petal, normals, reach, pair_start, pair_faces, v, best_face,
                  best_dist):
    """For vertex v and each petal, the near face whose prism holds v at the smallest
    distance (|distance| <= ``reach``): ``best_face[Q]`` (-1 if none), ``best_dist[Q]``."""
    best_face[:] = -1
    for k in range(pair_start[v], pair_start[v + 1]):
        f = pair_faces[k]
        Q = face_petal[f]
        dist, inside, _, _ = _prism_distance(X, faces, normals, f, v)
        if inside and abs(dist) <= reach and (best_face[Q] < 0 or abs(dist) < abs(best_dist[Q])):
            best_face[Q] = f
            best_dist[Q] = dist


@njit(cache=True)
def resolve_collisions(X, V, inv_mass, faces, face_petal, vert_petal, side, near, normals,
                       offset, margin, pair_start, pair_faces, best_face, best_dist):
    """Vertex-triangle contacts between petals, among the near pairs of :func:`near_pairs`.

    For a vertex and another petal Q, the face that counts is the nearest one whose
    prism holds the vertex (a petal's surface near a vertex, not every face plane
    around it). ``side[v, Q]`` (+-1) is the side of Q (along its normals) that v belongs
    on, taken from the bud; ``near[v, Q]`` says whether v was over or under Q (within
    ``margin``, in a prism) at the last step. A vertex that comes near Q around its rim,
    not through it, takes the side it arrives on. A vertex that has gone through (by up
    to ``margin``) is a contact: it is moved back to ``offset`` on its side and its
    velocity toward the face, relative to the face, is removed. ``best_face`` and
    ``best_dist`` are ``(P,)`` work arrays. Returns the number of contacts.
    """
    contacts = 0
    for v in range(X.shape[0]):
        if inv_mass[v] == 0.0:
            continue
        if pair_start[v] == pair_start[v + 1]:
            near[v, :] = 0
            continue
        nearest_faces(X, faces, face_petal, normals, margin, pair_start, pair_faces, v,
                      best_face, best_dist)
        for Q in range(best_face.shape[0]):
            f = best_face[Q]
            if f < 0:
                near[v, Q] = 0
                continue
            if near[v, Q] == 0:
                near[v, Q] = 1
                side[v, Q] = 1.0 if best_dist[Q] >= 0.0 else -1.0
            sg = side[v, Q]
            dist = sg * best_dist[Q]
            if dist >= 0.0:
                continue
            contacts += 1
            # an inelastic contact between the vertex and the face's point under it: the
            # gap is closed and the approaching velocity removed, shared by inverse mass
            # (momentum is kept), so two petals pressed together do not pump energy in
            nx, ny, nz = sg * normals[f, 0], sg * normals[f, 1], sg * normals[f, 2]
            _, _, bv, bw = _prism_distance(X, faces, normals, f, v)
            a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
            ba = 1.0 - bv - bw
            wv, wa, wb, wc = inv_mass[v], ba * inv_mass[a], bv * inv_mass[b], bw * inv_mass[c]
            denom = wv + ba * wa + bv * wb + bw * wc
            move = (offset - dist) / denom
            X[v, 0] += wv * move * nx
            X[v, 1] += wv * move * ny
            X[v, 2] += wv * move * nz
            for corner, wk in ((a, wa), (b, wb), (c, wc)):
                X[corner, 0] -= wk * move * nx
                X[corner, 1] -= wk * move * ny
                X[corner, 2] -= wk * move * nz
            vn = 0.0
            for k in range(3):
                vn += (V[v, k] - ba * V[a, k] - bv * V[b, k] - bw * V[c, k]) * (nx, ny, nz)[k]
            if vn < 0.0:
                j = -vn / denom
                for k in range(3):
                    nk = (nx, ny, nz)[k]
                    V[v, k] += wv * j * nk
                    V[a, k] -= wa * j * nk
                    V[b, k] -= wb * j * nk
                    V[c, k] -= wc * j * nk
    return contacts


@njit(cache=True)
def edges_through_faces(X, edges, edge_petal, faces, face_petal, cell, start, count, items):
    """How many edges pass through a face of another petal (segment-triangle
    intersection, Moller-Trumbore), with faces found through :func:`build_face_grid`
    (built with no inflation). Sheets that have gone through each other cross here."""
    size = count.shape[0]
    crossed = 0
    for e in range(edges.shape[0]):
        i, j = edges[e, 0], edges[e, 1]
        P = edge_petal[e]
        dx, dy, dz = X[j, 0] - X[i, 0], X[j, 1] - X[i, 1], X[j, 2] - X[i, 2]
        hit = False
        for ix in range(int(math.floor(min(X[i, 0], X[j, 0]) / cell)),
                        int(math.floor(max(X[i, 0], X[j, 0]) / cell)) + 1):
            for iy in range(int(math.floor(min(X[i, 1], X[j, 1]) / cell)),
                            int(math.floor(max(X[i, 1], X[j, 1]) / cell)) + 1):
                for iz in range(int(math.floor(min(X[i, 2], X[j, 2]) / cell)),
                                int(math.floor(max(X[i, 2], X[j, 2]) / cell)) + 1):
                    key = _cell_hash(ix, iy, iz, size)
                    for k in range(start[key], start[key + 1]):
                        f = items[k]
                        if face_petal[f] == P or hit:
                            continue
                        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
                        e1x, e1y, e1z = X[b, 0] - X[a, 0], X[b, 1] - X[a, 1], X[b, 2] - X[a, 2]
                        e2x, e2y, e2z = X[c, 0] - X[a, 0], X[c, 1] - X[a, 1], X[c, 2] - X[a, 2]
                        px = dy * e2z - dz * e2y
                        py = dz * e2x - dx * e2z
                        pz = dx * e2y - dy * e2x
                        det = e1x * px + e1y * py + e1z * pz
                        if abs(det) < 1e-14:
                            continue
                        inv = 1.0 / det
                        tx, ty, tz = X[i, 0] - X[a, 0], X[i, 1] - X[a, 1], X[i, 2] - X[a, 2]
                        u = (tx * px + ty * py + tz * pz) * inv
                        if u < 0.0 or u > 1.0:
                            continue
                        qx = ty * e1z - tz * e1y
                        qy = tz * e1x - tx * e1z
                        qz = tx * e1y - ty * e1x
                        w = (dx * qx + dy * qy + dz * qz) * inv
                        if w < 0.0 or u + w > 1.0:
                            continue
                        t = (e2x * qx + e2y * qy + e2z * qz) * inv
                        if 0.0 <= t <= 1.0:
                            hit = True
        if hit:
            crossed += 1
    return crossed


@dataclass
class Collisions:
    faces: np.ndarray  #: (F, 3)
    face_petal: np.ndarray  #: (F,)
    vertex_petal: np.ndarray  #: (V,)
    side: np.ndarray  #: (V, P) +-1: the side of petal Q (along its normals) vertex v belongs on
    params: np.ndarray  #: (cell size, offset, margin, slack)
    normals: np.ndarray  #: (F, 3) work array: unit face normals at the current step
    start: np.ndarray  #: grid work arrays: hash table of cells, counting sort
    count: np.ndarray
    items: np.ndarray
    reference: np.ndarray  #: (V, 3) positions when the grid was last built
    pair_start: np.ndarray  #: (V+1,) near pairs (CSR): faces near each vertex
    pair_faces: np.ndarray
    best_face: np.ndarray  #: (P,) work arrays of the nearest face per petal
    best_dist: np.ndarray
    near: np.ndarray  #: (V, P) int8: vertex was over or under that petal at the last step
    #: gap the quasi-static solver's contact barrier keeps between petals (mesh units);
    #: the push-back above does not use it
    thickness: float
    #: (K, 2) petal pairs left through each other as modelled (no contact between the
    #: two), or None. The push-back keeps its sides per label, so for it
    #: ``vertex_petal`` and ``face_petal`` join the petals of such pairs, and of chains of
    #: them, in one label; the quasi-static solver's barrier reads :attr:`petal` and the
    #: pairs themselves (:class:`pipeline.sim.terms.contact.Contact`)
    left: np.ndarray | None = None
    petal: np.ndarray | None = None  #: (V,) each vertex's petal
    #: ``(V,)`` each vertex's flower in a file of many, or None (one flower): flowers bloom
    #: as problems apart (each from its own bud, and staggered in time by the scene, so
    #: their petals are never in one equilibrium), contact kept within each flower
    vertex_flower: np.ndarray | None = None
    #: the quasi-static solver's contact is on the first ``in_contact`` vertices only
    #: (``faces`` on them: a mesh cut finer for the solve keeps its contact on the coarse
    #: mesh's triangles), or None: all
    in_contact: int | None = None

    @classmethod
    def build(cls, vertices, faces, petal, *, offset: float, max_edge: float,
              thickness: float, margin: float = 0.2, slack: float = 0.1,
              pushback: bool = True, left=None) -> Collisions:
        """Which side of another petal a vertex belongs on is the side it is on when it
        comes near that petal (within the margin, over or under one of its faces): the
        kernel records it then. For vertices near another petal in the bud that is the
        bud's side (inner petals inside outer ones, an imbricate rim in its order), taken
        at the first step; for the others, the side they arrive on, round the petal's
        rim, as the bud opens. Petals that touch in the bud start with no contact.

        ``pushback``: allocate the push-back's ``(V, P)`` arrays (``side``, ``near``); the
        quasi-static solver's contact does not read them (False: empty), and at a branch's
        50,000 vertices and 5,000 petals they would take 2 GB. ``left``: :attr:`left`."""
        v = np.asarray(vertices, dtype=np.float64)
        f = np.ascontiguousarray(faces, dtype=np.int64)
        own = np.ascontiguousarray(petal, dtype=np.int64)
        left = None if left is None or not len(left) else np.asarray(left, dtype=np.int64)
        petal = own if left is None else joined_labels(own, max(int(own.max()), int(left.max())) + 1,
                                                       left)
        count = int(petal.max()) + 1
        size = 4 * len(f) + 1
        cell = max_edge + 2.0 * (margin + offset + slack)
        rows, cols = (len(v), count) if pushback else (0, 0)
        return cls(f, np.ascontiguousarray(petal[f[:, 0]]), petal, np.ones((rows, cols)),
                   np.array([cell, offset, margin, slack]), np.zeros((len(f), 3)),
                   np.zeros(size + 1, dtype=np.int64), np.zeros(size, dtype=np.int64),
                   np.zeros(27 * len(f), dtype=np.int64), v.copy(),
                   np.zeros(len(v) + 1, dtype=np.int64), np.zeros(64 * len(v), dtype=np.int64),
                   np.zeros(count, dtype=np.int64), np.zeros(count),
                   np.zeros((rows, cols), dtype=np.int8), float(thickness), left=left, petal=own)

    def near_pairs(self, X, reach: float) -> int:
        """List the near pairs at ``X`` (as the kernel does when it rebuilds)."""
        free = np.ones(len(X))
        cell = self.params[0]
        lost = build_face_grid(X, self.faces, reach, cell, self.start, self.count, self.items)
        return lost + near_pairs(X, self.faces, self.face_petal, self.vertex_petal, free,
                                         reach, cell, self.start, self.count, self.items,
                                         self.pair_start, self.pair_faces)

