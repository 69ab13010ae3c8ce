"""Geodesic distance on a triangle mesh by the heat method (Crane, Weischedel and Wardetzky
2013), a distance that converges to the surface's own as the mesh is refined.

Shortest paths along edges (Dijkstra) do not: a path made of edges zigzags, and how much
longer it is than the geodesic depends on how the edges happen to run (a few percent,
and not less on a finer mesh). The heat method: diffuse heat from the sources for a
short time ``t ~ h^2``, take the direction in which the heat falls off, and find the
function whose gradient is that unit field (a Poisson problem). Both linear systems are
sparse and symmetric.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import factorized


def _operators(vertices: np.ndarray, faces: np.ndarray):
    """Cotangent Laplacian ``L`` (positive semi-definite), lumped mass ``m (V,)``,
    per-face gradient ``G (3F, V)`` (rows: x of every face, then y, then z) and face
    areas ``(F,)``."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    n, nf = len(v), len(f)
    p0, p1, p2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    normal = np.cross(p1 - p0, p2 - p0)
    double = np.linalg.norm(normal, axis=1)
    unit = normal / np.where(double > 0, double, 1.0)[:, None]
    rows, cols, vals = [], [], []
    grad = []
    for k in range(3):
        a, b, c = f[:, k], f[:, (k + 1) % 3], f[:, (k + 2) % 3]
        # cotangent of the angle at a, for the edge b-c
        u, w = v[b] - v[a], v[c] - v[a]
        cot = np.einsum("ij,ij->i", u, w) / np.where(double > 0, double, np.inf)
        rows += [b, c, b, c]
        cols += [c, b, b, c]
        vals += [-0.5 * cot, -0.5 * cot, 0.5 * cot, 0.5 * cot]
        # gradient of the hat function of corner a: (n x (x_c - x_b)) / (2 area)
        grad.append(np.cross(unit, v[c] - v[b]) / np.where(double > 0, double, np.inf)[:, None])
    L = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(n, n)).tocsc()
    area = 0.5 * double
    m = np.zeros(n)
    for k in range(3):
        np.add.at(m, f[:, k], area / 3.0)
    gr, gc, gv = [], [], []
    for d in range(3):
        for k in range(3):
            gr.append(d * nf + np.arange(nf))
            gc.append(f[:, k])
            gv.append(grad[k][:, d])
    G = sp.coo_matrix((np.concatenate(gv), (np.concatenate(gr), np.concatenate(gc))),
                      shape=(3 * nf, n)).tocsr()
    return L, m, G, area


class _Heat:
    """The factorized systems of the heat method on one mesh (``time``: the diffusion
    time in units of the mean edge length squared). Neumann heat; with ``boundary``
    (``(V,)`` bool, the mesh's rim) also the mean of the Neumann and the Dirichlet
    solutions (Crane et al.'s remedy for the fall-off of the heat bending near the rim),
    the Dirichlet system factorized at its first use."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, time: float,
                 boundary: np.ndarray | None = None):
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces, dtype=np.int64)
        L, m, self.G, self.area = _operators(v, f)
        self.n, self.nf = len(v), len(f)
        edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        h = float(np.linalg.norm(v[edges[:, 0]] - v[edges[:, 1]], axis=1).mean())
        self._A = (sp.diags(m) + time * h * h * L).tocsc()
        self._neumann = factorized(self._A)
        self._dirichlet = None
        self._inner = None
        if boundary is not None and np.any(boundary) and not np.all(boundary):
            self._inner = np.flatnonzero(~np.asarray(boundary, dtype=bool))
        self.keep = np.arange(1, self.n)  # L is singular (constants): hold vertex 0, shift
        self.poisson = factorized(L[self.keep][:, self.keep].tocsc())

    def heat(self, load: np.ndarray, mean: bool = False) -> np.ndarray:
        """``(V,)`` the heat from ``load`` after the diffusion time; ``mean``: the mean of
        the Neumann and the Dirichlet heat (Neumann's where there is no rim)."""
        u = self._neumann(load)
        if not mean or self._inner is None:
            return u
        if self._dirichlet is None:
            self._dirichlet = factorized(self._A[self._inner][:, self._inner].tocsc())
        d = np.zeros(self.n)
        d[self._inner] = self._dirichlet(load[self._inner])
        return 0.5 * (u + d)

    def gradient(self, u: np.ndarray) -> np.ndarray:
        """``(F, 3)`` the per-face gradient of the vertex function ``u``."""
        return (self.G @ u).reshape(3, self.nf).T

    def integrate(self, field: np.ndarray, load: np.ndarray) -> np.ndarray:
        """``(V,)`` the function whose gradient is closest to the per-face ``field``
        (a Poisson problem), zero where ``load`` is (its weighted mean)."""
        div = self.G.T @ (field * self.area[:, None]).T.ravel()
        phi = np.zeros(self.n)
        phi[self.keep] = self.poisson(div[self.keep])
        return phi - float(load @ phi) / float(load.sum())


def _unit(g: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(g, axis=1)
    return g / np.where(norm > 0, norm, 1.0)[:, None]


def heat_distances(vertices: np.ndarray, faces: np.ndarray, sources: list,
                   time: float = 1.0) -> list[np.ndarray]:
    """For each source in ``sources`` (an index array or bool mask of vertices, or a
    float load vector such as :func:`curve_load`'s), the ``(V,)`` geodesic distance
    from it along the surface (one connected piece). ``time``: the
    diffusion time in units of the mean edge length squared (Crane et al.'s ``m``; 1 is
    their choice). Neumann boundary conditions (the heat does not leave the sheet).

    Accuracy: the direction of the heat's fall-off is taken per triangle, and on an
    irregular mesh it scatters by a few degrees, so distances come out short by the mean
    of ``1 - cos`` of that scatter (0.7-0.9% measured on Poisson-disc and lattice meshes
    of a plane, whatever the spacing); a *ratio* of two such distances (the
    cross-section coordinate, s) converges under refinement: 1.9% -> 0.3% from h = 0.1
    to 0.0125 (``tests/test_geodesic.py``). A curve source that crosses triangles is
    better served by :func:`signed_heat_distance`: the distance's kink along the curve
    is not a piecewise-linear function there."""
    ops = _Heat(vertices, faces, time)
    out = []
    for chosen in sources:
        chosen = np.asarray(chosen)
        if chosen.dtype.kind == "f":  # a load vector: its weighted mean is the zero
            load = chosen
        else:
            load = np.zeros(ops.n)
            load[chosen] = 1.0
        out.append(ops.integrate(-_unit(ops.gradient(ops.heat(load))), load))
    return out


def signed_heat_distance(vertices: np.ndarray, faces: np.ndarray, level: np.ndarray,
                         time: float = 1.0) -> np.ndarray | None:
    """``(V,)`` the signed geodesic distance from the curve where the piecewise-linear
    ``level`` (per vertex) is zero, positive where ``level`` is (see
    :func:`signed_heat_distances`, the first it yields)."""
    return next(signed_heat_distances(vertices, faces, level, time))


def signed_heat_distances(vertices: np.ndarray, faces: np.ndarray, level: np.ndarray,
                          time: float = 1.0, boundary: np.ndarray | None = None):
    """Yields the ``(V,)`` signed geodesic distance from the curve where the
    piecewise-linear ``level`` (per vertex) is zero, positive where ``level`` is: the heat
    method's unit field, turned on the negative side so that it runs across the curve one
    way, and in the triangles the curve crosses the direction in which ``level`` grows;
    then the function with that gradient, zero on the curve. Yields None where ``level``
    does not change sign on the mesh (no curve). With ``boundary`` (``(V,)`` bool, the
    rim), it then yields the same from the mean of the Neumann and the Dirichlet heat
    (:class:`_Heat`), on the same factorizations, its own made only if asked for.

    The unsigned distance has a kink along the curve, which a piecewise-linear function
    represents only where the curve runs along edges: where it crosses triangles (an
    irregular mesh), the Poisson solution rounds the kink off, and the distance is short
    near the curve by a fraction of an edge (the cross-section coordinate was 3% low
    near the midrib of a 300-vertex Poisson-disc petal). The signed distance is smooth
    across the curve, so it is exact there to the mesh's order."""
    f = np.asarray(faces, dtype=np.int64)
    lv = np.asarray(level, dtype=np.float64)
    lv = np.where(lv == 0.0, np.finfo(np.float64).tiny, lv)
    load = curve_load(vertices, f, lv)
    if not load.sum() > 0.0:
        yield None
        return
    ops = _Heat(vertices, f, time, boundary)
    lf = lv[f]
    crossing = (lf.min(axis=1) < 0.0) & (lf.max(axis=1) > 0.0)
    across = _unit(ops.gradient(lv))[crossing]
    for mean in (False, True) if boundary is not None else (False,):
        field = -_unit(ops.gradient(ops.heat(load, mean)))
        field[lf.max(axis=1) < 0.0] *= -1.0
        field[crossing] = across
        yield ops.integrate(field, load)


def curve_load(vertices: np.ndarray, faces: np.ndarray, level: np.ndarray) -> np.ndarray:
    """``(V,)`` the load vector of the curve where the piecewise-linear function ``level``
    (per vertex) is zero: each face's segment of it, its length shared among the face's
    corners by their barycentric weights at the segment's middle. A source for
    :func:`heat_distances` that is the curve itself, wherever it crosses the triangles
    (not the vertices nearest it, a zigzag that depends on the mesh). A vertex exactly on
    the curve counts as just above it."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    s = np.asarray(level, dtype=np.float64)
    s = np.where(s == 0.0, np.finfo(np.float64).tiny, s)
    out = np.zeros(len(v))
    sf = s[f]
    crossing = np.flatnonzero((sf.min(axis=1) < 0.0) & (sf.max(axis=1) > 0.0))
    for k in crossing:
        ends, weights = [], []
        for a in range(3):
            b = (a + 1) % 3
            sa, sb = sf[k, a], sf[k, b]
            if (sa < 0.0) != (sb < 0.0):
                t = sa / (sa - sb)
                ends.append((1.0 - t) * v[f[k, a]] + t * v[f[k, b]])
                w = np.zeros(3)
                w[a], w[b] = 1.0 - t, t
                weights.append(w)
        length = float(np.linalg.norm(ends[1] - ends[0]))
        np.add.at(out, f[k], 0.5 * length * (weights[0] + weights[1]))
    return out


def heat_distance(vertices: np.ndarray, faces: np.ndarray, sources, time: float = 1.0):
    """``(V,)`` geodesic distance from ``sources`` (see :func:`heat_distances`)."""
    return heat_distances(vertices, faces, [sources], time)[0]
