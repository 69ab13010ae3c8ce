"""Test surfaces with exact continuum energies, and the bending candidates compared.

Meshes of a flat rectangle and a flat disc, *regular* (an equilateral lattice) and
*irregular* (Poisson-disc samples, Delaunay), at any spacing ``h``; maps of them onto a
cylinder and a spherical cap whose shell energy is known in closed form. Used by
``tests/test_shell.py``; run as a script it prints the comparison of the bending
discretizations that chose :mod:`pipeline.sim.terms.shell`'s (the evidence kept), or the
speed of the shell against the springs:

    .venv/bin/python -m tests.shell_study
    .venv/bin/python -m tests.shell_study speed
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy.integrate import quad
from scipy.spatial import Delaunay, cKDTree

from pipeline.mesh import topology

# --- meshes -------------------------------------------------------------------------------

def _lattice(width: float, height: float, h: float) -> np.ndarray:
    """An equilateral lattice of spacing ~h covering [0, width] x [0, height], its rows
    clipped to the rectangle and closed by points on its sides."""
    ny = max(1, int(round(height / (h * math.sqrt(3) / 2))))
    nx = max(1, int(round(width / h)))
    hx, dy = width / nx, height / ny
    pts = []
    for j in range(ny + 1):
        xs = np.arange(nx + 1) * hx
        if j % 2:
            xs = np.r_[0.0, xs[:-1] + 0.5 * hx, width]
        pts.append(np.c_[xs, np.full(len(xs), j * dy)])
    return np.vstack(pts)


def _poisson(lo, hi, h: float, rng, fixed: np.ndarray, inside=None) -> np.ndarray:
    """Poisson-disc samples (no two closer than 0.75 h, nor closer to ``fixed``) in the
    box [lo, hi], kept where ``inside``; ``fixed`` first."""
    r = 0.75 * h
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    n = int(12 * np.prod(hi - lo) / h ** 2) + 16
    cand = rng.uniform(lo, hi, size=(n, 2))
    if inside is not None:
        cand = cand[inside(cand)]
    if len(fixed):
        d, _ = cKDTree(fixed).query(cand)
        cand = cand[d >= r]
    pairs = cKDTree(cand).query_pairs(r, output_type="ndarray")
    # each candidate's neighbours (CSR): the greedy pass below takes a candidate unless a
    # taken one is within r, in the candidates' order
    both = np.concatenate([pairs, pairs[:, ::-1]]) if len(pairs) else np.zeros((0, 2), int)
    both = both[np.argsort(both[:, 0], kind="stable")]
    start = np.searchsorted(both[:, 0], np.arange(len(cand) + 1))
    nbr = both[:, 1]
    taken = np.zeros(len(cand), dtype=bool)
    blocked = np.zeros(len(cand), dtype=bool)
    for k in range(len(cand)):
        if blocked[k]:
            continue
        taken[k] = True
        blocked[nbr[start[k]:start[k + 1]]] = True
    return np.vstack([fixed, cand[taken]])


def _triangulate(points: np.ndarray, keep=None) -> np.ndarray:
    """Delaunay triangles, counter-clockwise, without slivers of the hull (and those
    whose centroid ``keep`` refuses)."""
    f = Delaunay(points).simplices.astype(np.int64)
    a, b, c = points[f[:, 0]], points[f[:, 1]], points[f[:, 2]]
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    f[cross < 0] = f[cross < 0][:, [0, 2, 1]]
    area = 0.5 * np.abs(cross)
    ok = area > 1e-3 * np.median(area)
    if keep is not None:
        ok &= keep((a + b + c) / 3.0)
    return np.ascontiguousarray(f[ok])


def _kept(make):
    """``make`` remembered by its arguments (the tests ask for the same meshes again);
    each call gets its own copies."""
    made = functools.lru_cache(maxsize=64)(make)

    @functools.wraps(make)
    def mesh(*args, **kwargs):
        p, f = made(*args, **kwargs)
        return p.copy(), f.copy()

    return mesh


@_kept
def rectangle(width: float, height: float, h: float, kind: str, seed: int = 0):
    """``(points (V, 2), faces (F, 3))`` of the rectangle [0, width] x [0, height]."""
    if kind == "regular":
        return (p := _lattice(width, height, h)), _triangulate(p)
    nx, ny = max(1, int(round(width / h))), max(1, int(round(height / h)))
    xs, ys = np.linspace(0, width, nx + 1), np.linspace(0, height, ny + 1)
    rim = np.vstack([np.c_[xs, np.zeros_like(xs)], np.c_[xs, np.full_like(xs, height)],
                     np.c_[np.zeros(ny - 1), ys[1:-1]], np.c_[np.full(ny - 1, width), ys[1:-1]]])
    p = _poisson((0, 0), (width, height), h, np.random.default_rng(seed), rim)
    return p, _triangulate(p)


@_kept
def disc(radius: float, h: float, kind: str, seed: int = 0):
    """``(points (V, 2), faces (F, 3))`` of the disc of ``radius`` about the origin: its
    rim sampled every ~h, its inside a lattice (regular) or Poisson-disc (irregular)."""
    n = max(6, int(round(2 * math.pi * radius / h)))
    t = np.arange(n) * 2 * math.pi / n
    rim = radius * np.c_[np.cos(t), np.sin(t)]

    def inside(q):
        return np.linalg.norm(q, axis=1) < radius - 0.5 * h

    if kind == "regular":
        p = _lattice(2 * radius, 2 * radius, h) - radius
        p = np.vstack([rim, p[inside(p)]])
    else:
        p = _poisson((-radius, -radius), (radius, radius), h, np.random.default_rng(seed), rim,
                     inside)
    return p, _triangulate(p, keep=lambda q: np.linalg.norm(q, axis=1) < radius)


# --- maps and their exact energies ----------------------------------------------------------

def flat(p: np.ndarray) -> np.ndarray:
    return np.c_[p, np.zeros(len(p))]


def roll(p: np.ndarray, radius: float) -> np.ndarray:
    """The plane rolled isometrically onto a cylinder of ``radius`` (axis along y)."""
    u, v = p[:, 0], p[:, 1]
    return np.c_[radius * np.sin(u / radius), v, radius * (1.0 - np.cos(u / radius))]


def cap(p: np.ndarray, radius: float) -> np.ndarray:
    """The disc onto a sphere of ``radius``: a point at distance r from the centre goes
    to geodesic distance r from the pole (radial lines keep their length)."""
    r = np.linalg.norm(p, axis=1)
    phi = np.arctan2(p[:, 1], p[:, 0])
    s = radius * np.sin(r / radius)
    return np.c_[s * np.cos(phi), s * np.sin(phi), radius * (1.0 - np.cos(r / radius))]


def cylinder_energy(area: float, bend: float, rest_curvature: float, curvature: float) -> float:
    """A sheet of rest curvature k0 (a cylinder, or flat) rolled to curvature k about the
    same axis: no strain, ``D/2 (k - k0)^2`` per area."""
    return 0.5 * bend * (curvature - rest_curvature) ** 2 * area


def cap_energy(disc_radius: float, sphere_radius: float, young: float, bend: float,
               nu: float) -> tuple[float, float]:
    """(membrane, bending) energy of :func:`cap` of a flat disc, for the St. Venant-
    Kirchhoff shell of :mod:`pipeline.sim.terms.shell`: in polar coordinates the map stretches
    only the circles, by ``s = R sin(r/R) / r``: ``E = diag(0, (s^2 - 1)/2)``, and
    ``M = abar^-1 b = diag(1, s^2) / R``."""
    lam = young * nu / (1 - nu ** 2)
    mu = young / (2 * (1 + nu))
    R = sphere_radius

    def s(r):
        return R * math.sin(r / R) / r if r > 0 else 1.0

    def membrane(r):
        e = 0.5 * (s(r) ** 2 - 1.0)
        return 2 * math.pi * r * (0.5 * lam + mu) * e * e

    def bending(r):
        m1, m2 = 1.0 / R, s(r) ** 2 / R
        return 2 * math.pi * r * 0.5 * bend * (nu * (m1 + m2) ** 2 + (1 - nu) * (m1 * m1 + m2 * m2))

    opts = dict(epsabs=0.0, epsrel=1e-12, limit=200)
    return quad(membrane, 0, disc_radius, **opts)[0], quad(bending, 0, disc_radius, **opts)[0]


# --- the shell of pipeline.sim.terms.shell on a bare mesh ---------------------------------------

def shell_term(rest: np.ndarray, faces: np.ndarray, young: float, bend: float, nu: float):
    """A :class:`pipeline.sim.terms.shell.ShellTerm` of a mesh at rest ``rest (V, 3)``, no growth,
    moduli given in mesh units."""
    from types import SimpleNamespace

    from pipeline.sim.terms import shell as sh

    edges, _, _ = topology.unique_edges(faces)
    rest0 = np.linalg.norm(rest[edges[:, 1]] - rest[edges[:, 0]], axis=1)
    model = SimpleNamespace(edge_indices=edges, edge_rest_length=rest0,
                            edge_growth=np.zeros(len(edges)), vertex_count=len(rest))
    data = sh.ShellData.build(rest, faces, model, stretch_modulus=1.0, thickness=0.1, poisson=nu)
    data.face_stretch[:] = young
    data.face_bending[:] = bend
    model.shell = data
    return sh.ShellTerm(model)


# --- the candidates that were not chosen (energies only, numpy) -----------------------------

def _areas(X, F):
    return 0.5 * np.linalg.norm(np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]]), axis=1)


def _dihedral(X, H):
    i, j, k, l = H.T
    e = X[j] - X[i]
    n1 = np.cross(e, X[k] - X[i])
    n2 = np.cross(X[l] - X[j], e)
    sin = np.einsum("ij,ij->i", np.cross(n1, n2), e) / np.linalg.norm(e, axis=1)
    return np.arctan2(sin, np.einsum("ij,ij->i", n1, n2))


def hinge_energy(rest, X, faces, bend):
    """Discrete shells (Grinspun et al. 2003): ``sum |e|^2 / (A1 + A2) (theta -
    theta0)^2 D/2``, rest lengths and areas. (Grinspun's weight is 3 |e|^2/(A1 + A2)
    with a unit that makes the constant 1/3 here: on a lattice it converges to ``D/2
    int k^2`` of a cylinder with this constant.)"""
    H, _ = topology.hinges(faces)
    he, opposite = topology.half_edges(faces)
    nf = len(faces)
    face_of = {(int(a), int(b)): k % nf for k, (a, b) in enumerate(he)}
    f1 = np.array([face_of[(int(i), int(j))] for i, j in H[:, :2]])
    f2 = np.array([face_of[(int(j), int(i))] for i, j in H[:, :2]])
    A = _areas(rest, faces)
    w = np.sum((rest[H[:, 1]] - rest[H[:, 0]]) ** 2, axis=1) / (A[f1] + A[f2])
    d = _dihedral(X, H) - _dihedral(rest, H)
    return 0.5 * bend * float(np.sum(w * d * d))


def _metric(X, F):
    e1, e2 = X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]]
    a = np.empty((len(F), 2, 2))
    a[:, 0, 0] = np.einsum("ij,ij->i", e1, e1)
    a[:, 1, 1] = np.einsum("ij,ij->i", e2, e2)
    a[:, 0, 1] = a[:, 1, 0] = np.einsum("ij,ij->i", e1, e2)
    return a


def _midedge_form(X, F, opp):
    """libshell's MidedgeAverage idea with unit normals: at each edge, the bisector of
    its two face normals; ``b_11 = 2 (n1 - n0).e1``, ``b_12 = 2 (n1 - n0).e2``,
    ``b_22 = 2 (n2 - n0).e2`` (a boundary edge: the face's own normal)."""
    q = X[F]
    nf = np.cross(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0])
    nf /= np.linalg.norm(nf, axis=1)[:, None]
    m = np.empty((len(F), 3, 3))
    for i in range(3):
        a, b = q[:, (i + 1) % 3], q[:, (i + 2) % 3]
        o = opp[:, i]
        ng = nf.copy()
        has = o >= 0
        ng[has] = np.cross(a[has] - b[has], X[o[has]] - b[has])
        ng[has] /= np.linalg.norm(ng[has], axis=1)[:, None]
        mid = nf + ng
        m[:, i] = mid / np.linalg.norm(mid, axis=1)[:, None]
    e1, e2 = q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]
    B = np.empty((len(F), 2, 2))
    B[:, 0, 0] = 2 * np.einsum("ij,ij->i", m[:, 1] - m[:, 0], e1)
    B[:, 0, 1] = B[:, 1, 0] = 2 * np.einsum("ij,ij->i", m[:, 1] - m[:, 0], e2)
    B[:, 1, 1] = 2 * np.einsum("ij,ij->i", m[:, 2] - m[:, 0], e2)
    return B


def midedge_energy(rest, X, faces, bend, nu):
    """The mid-edge average second fundamental form in the same Koiter energy."""
    from pipeline.sim.terms.shell import face_opposite

    opp = face_opposite(faces)
    a0 = _metric(rest, faces)
    M = np.linalg.solve(a0, _midedge_form(X, faces, opp) - _midedge_form(rest, faces, opp))
    tr = np.trace(M, axis1=1, axis2=2)
    tr2 = np.einsum("fij,fji->f", M, M)
    return float(np.sum(0.5 * np.sqrt(np.linalg.det(a0)) * 0.5 * bend
                        * (nu * tr ** 2 + (1 - nu) * tr2)))


def compare(spacings=(0.2, 0.1, 0.05, 0.025), bend=1.0, nu=0.3, surfaces=("cylinder", "cap"),
            kinds=("regular", "irregular")):
    """Rows (surface, kind, h, V, hinge/exact - 1, mid-edge/exact - 1, patch/exact - 1):
    the bending energy of a 1.5 x 1 sheet rolled to a cylinder of radius 1, and of a flat
    disc of radius 1 mapped to a sphere of radius 2 (bending only: the membrane is
    left out of all three)."""
    rows = []
    for kind in kinds if "cylinder" in surfaces else ():
        for h in spacings:
            p, f = rectangle(1.5, 1.0, h, kind)
            rest, X = flat(p), roll(p, 1.0)
            exact = cylinder_energy(_areas(rest, f).sum(), bend, 0.0, 1.0)
            patch = shell_term(rest, f, 0.0, bend, nu).energy(X)
            rows.append(("cylinder", kind, h, len(p), hinge_energy(rest, X, f, bend) / exact - 1,
                         midedge_energy(rest, X, f, bend, nu) / exact - 1, patch / exact - 1))
    for kind in kinds if "cap" in surfaces else ():
        for h in spacings:
            p, f = disc(1.0, h, kind)
            rest, X = flat(p), cap(p, 2.0)
            exact = cap_energy(1.0, 2.0, 0.0, bend, nu)[1]
            patch = shell_term(rest, f, 0.0, bend, nu).energy(X)
            rows.append(("cap", kind, h, len(p), hinge_energy(rest, X, f, bend) / exact - 1,
                         midedge_energy(rest, X, f, bend, nu) / exact - 1, patch / exact - 1))
    return rows


def speed(petals: int = 6, vertices: int = 2000, repeat: int = 30) -> dict:
    """Seconds (median of ``repeat``) of the springs' and the shell's forces and Hessian
    assembly on a procedural bud, in one process, and of one factorization (block LDL^T)
    of each Hessian (a petal's): the shell's pattern is wider. Ratios shell/springs."""
    import time

    from pipeline.sim.blocks import Blocks
    from pipeline.sim.build import Prepared
    from pipeline.sim.solver.ldl import BlockLDL
    from pipeline.sim.terms import shell as sh
    from pipeline.sim.terms.elastic import Elastic
    from tests.conftest import prepared

    v, f, p, axes, growth = prepared(petals, vertices)
    prep = Prepared.of(v, f, p, axes, growth)
    springs = prep.model(0.1, 0.0005)
    shell = prep.shell_model(27.3, 0.013, 1 / 3)
    X = v + np.random.default_rng(0).normal(scale=0.05, size=v.shape)
    paper_term = Elastic.of(springs).at(0.5)
    shell_term = sh.ShellTerm(shell).at(0.5)
    paper_blocks = Blocks.build(springs)
    shell_blocks = sh.ShellBlocks.build(shell)
    F = np.zeros_like(X)

    def clock(fn):
        fn()  # (compiled, warm)
        times = []
        for _ in range(repeat):
            t = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t)
        return float(np.median(times))

    out = {"vertices": len(v), "faces": len(f),
           "forces_springs": clock(lambda: paper_term.forces(X, F)),
           "forces_shell": clock(lambda: shell_term.forces(X, F)),
           "hessian_springs": clock(lambda: paper_term.assemble(X, paper_blocks)),
           "hessian_shell": clock(lambda: shell_term.assemble(X, shell_blocks)),
           "blocks_springs": len(paper_blocks.indices), "blocks_shell": len(shell_blocks.indices)}
    one = np.flatnonzero(p == 0)
    for name, blocks in (("springs", paper_blocks), ("shell", shell_blocks)):
        ldl = BlockLDL(blocks.indptr, blocks.indices, one)
        shift = np.full(3 * len(one), 10.0 * np.abs(blocks.data).max())  # (definite)
        out[f"factor_{name}"] = clock(lambda ldl=ldl, b=blocks, s=shift: ldl.factor(b.data, s))
        out[f"fill_{name}"] = ldl.nnz
    for key in ("forces", "hessian", "factor", "blocks", "fill"):
        out[f"{key}_ratio"] = out[f"{key}_shell"] / out[f"{key}_springs"]
    return out


if __name__ == "__main__":
    import sys

    if sys.argv[1:] == ["speed"]:
        for key, value in speed().items():
            print(f"{key}: {value:.4g}" if isinstance(value, float) else f"{key}: {value}")
        raise SystemExit
    print("| surface | mesh | h | V | hinge | mid-edge average | patch quadratic |")
    print("|---|---|---|---|---|---|---|")
    for s, k, h, n, a, b, c in compare((0.2, 0.1, 0.05, 0.025, 0.0125)):
        print(f"| {s} | {k} | {h:g} | {n} | {100 * a:+.2f}% | {100 * b:+.2f}% | {100 * c:+.2f}% |")
