"""Does the same petal bloom the same at any resolution and on any triangulation?

The default petal scene (``assets/petal.obj``, 317 vertices) at about 300, 1200 and 4800
vertices, each on two triangulations of the same surface:

- *regular*: ``bloom remesh --set remesh.petal_vertices=N`` (isotropic, symmetrized);
- *irregular*: Poisson-disc samples of the surface, Delaunay-triangulated (made here
  from the asset's own flat pattern, so that every point lies exactly on the asset's
  piecewise-flat surface), remeshed with ``remesh.symmetrize = false`` (its triangles
  kept).

then ``bloom axis``, ``bloom growth`` and ``bloom simulate`` with the scene's config
and the given ``--set`` overrides. Prints, per run, the final opening, the largest
opening difference over the frames against the finest regular run, and the RMS
distance of the final shape from it (area-weighted over the surface, points matched by
their (s, x) of axis.h5), in percent of the petal length (the rest bud's chord from the
base's centre to the tip). Run (about 10 minutes on 2 cores)::

    .venv/bin/python -m tests.bloom_convergence OUTDIR [--set simulate.model=shell ...]
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
COUNTS = (300, 1200, 4800)


def asset_pattern():
    """``(flat (V, 2), vertices (V, 3), faces)``: assets/petal.obj and the flat petal it
    was bent from (``bloom asset petal --petals 1 --vertices 320 --seed 0``, its header),
    with the same faces: a piecewise-linear map of the flat petal onto the asset."""
    from pipeline.mesh import procedural
    from pipeline.io.meshfile import read_mesh

    seen = {}
    bend = procedural.bend_into_bud

    def spy(points, *args, **kwargs):
        seen["flat"] = np.array(points)
        return bend(points, *args, **kwargs)

    procedural.bend_into_bud = spy
    try:
        v, f, _ = procedural.bud(1, 320, 0)
    finally:
        procedural.bend_into_bud = bend
    V, F = read_mesh(ROOT / "assets" / "petal.obj")
    if not (np.array_equal(f, F) and np.abs(v - V).max() < 1e-8):
        raise RuntimeError("assets/petal.obj is not the procedural petal of its header")
    return seen["flat"], V, F


def _boundary_loop(faces) -> np.ndarray:
    from pipeline.mesh.remesh import boundary_loops

    loops = boundary_loops(faces)
    return max(loops, key=len)


def irregular_petal(count: int, seed: int = 1):
    """``(vertices (V, 3), faces)``: about ``count`` Poisson-disc samples of the asset's
    surface, Delaunay-triangulated in its flat pattern; the rim sampled along the
    asset's own rim (its corners kept), so the surface is the asset's."""
    from matplotlib.path import Path as Polygon
    from scipy.spatial import Delaunay, cKDTree

    flat, V, F = asset_pattern()
    loop = _boundary_loop(F)
    poly = flat[loop]
    area = 0.5 * abs(np.sum(poly[:, 0] * np.roll(poly[:, 1], -1) - np.roll(poly[:, 0], -1) * poly[:, 1]))
    perimeter = np.linalg.norm(np.roll(poly, -1, axis=0) - poly, axis=1).sum()
    rng = np.random.default_rng(seed)
    h = np.sqrt(area / (0.75 * count))
    for _ in range(6):  # the spacing that gives about `count` vertices
        pts2, pts3 = _sample(flat, V, loop, poly, h, rng, Polygon, cKDTree)
        h *= np.sqrt(len(pts2) / count)
        rng = np.random.default_rng(seed)
    pts2, pts3 = _sample(flat, V, loop, poly, h, rng, Polygon, cKDTree)
    tri = Delaunay(pts2).simplices
    inside = Polygon(poly).contains_points(pts2[tri].mean(axis=1), radius=-1e-9 * perimeter)
    tri = tri[inside]
    a = pts2[tri]
    cross = (a[:, 1, 0] - a[:, 0, 0]) * (a[:, 2, 1] - a[:, 0, 1]) - (a[:, 1, 1] - a[:, 0, 1]) * (a[:, 2, 0] - a[:, 0, 0])
    tri[cross < 0] = tri[cross < 0][:, [0, 2, 1]]
    # orient as the asset (its faces' flat winding)
    b = flat[F]
    c0 = (b[:, 1, 0] - b[:, 0, 0]) * (b[:, 2, 1] - b[:, 0, 1]) - (b[:, 1, 1] - b[:, 0, 1]) * (b[:, 2, 0] - b[:, 0, 0])
    if np.mean(c0) < 0:
        tri = tri[:, [0, 2, 1]]
    return pts3, np.ascontiguousarray(tri, dtype=np.int64)


def _sample(flat, V, loop, poly, h, rng, Polygon, cKDTree):
    """Rim samples every ~h along the flat rim (corners kept) and Poisson-disc interior
    samples at least 0.75 h apart, in the flat pattern and lifted onto the surface."""
    from matplotlib.tri import Triangulation

    n = len(loop)
    seg = np.roll(poly, -1, axis=0) - poly
    turn = np.abs(np.arctan2(np.cross(seg, np.roll(seg, -1, axis=0)),
                             np.einsum("ij,ij->i", seg, np.roll(seg, -1, axis=0))))
    corner = np.roll(turn, 1) > np.radians(30.0)  # turn at vertex k between seg k-1 and k
    starts = np.flatnonzero(corner)
    if len(starts) == 0:
        starts = np.array([0])
    rim2, rim3 = [], []
    for a, b in zip(starts, np.roll(starts, -1), strict=True):
        idx = [(a + k) % n for k in range(((b - a) % n) or n + 1)] + [b % n]
        p2, p3 = flat[loop[idx]], V[loop[idx]]
        seglen = np.linalg.norm(np.diff(p2, axis=0), axis=1)
        t = np.r_[0.0, np.cumsum(seglen)]
        m = max(1, int(round(t[-1] / h)))
        at = np.linspace(0.0, t[-1], m + 1)[:-1]
        rim2.append(np.c_[np.interp(at, t, p2[:, 0]), np.interp(at, t, p2[:, 1])])
        rim3.append(np.c_[[np.interp(at, t, p3[:, k]) for k in range(3)]].T)
    rim2, rim3 = np.vstack(rim2), np.vstack(rim3)
    lo, hi = poly.min(axis=0), poly.max(axis=0)
    cand = rng.uniform(lo, hi, size=(int(20 * np.prod(hi - lo) / h ** 2) + 16, 2))
    cand = cand[Polygon(poly).contains_points(cand)]
    cand = cand[cKDTree(rim2).query(cand)[0] >= 0.6 * h]
    pairs = cKDTree(cand).query_pairs(0.75 * h, output_type="ndarray")
    nbr = [[] for _ in range(len(cand))]
    for i, j in pairs:
        nbr[i].append(j)
        nbr[j].append(i)
    taken = np.zeros(len(cand), dtype=bool)
    blocked = np.zeros(len(cand), dtype=bool)
    for k in range(len(cand)):
        if not blocked[k]:
            taken[k] = True
            blocked[nbr[k]] = True
    inner2 = cand[taken]
    _, _, F = asset_pattern()
    tri = Triangulation(flat[:, 0], flat[:, 1], F)
    which = tri.get_trifinder()(inner2[:, 0], inner2[:, 1])
    keep = which >= 0
    inner2, which = inner2[keep], which[keep]
    a, b, c = flat[F[which, 0]], flat[F[which, 1]], flat[F[which, 2]]
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    l1 = ((inner2[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (inner2[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])) / det
    l2 = ((b[:, 0] - a[:, 0]) * (inner2[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (inner2[:, 0] - a[:, 0])) / det
    l0 = 1.0 - l1 - l2
    inner3 = (l0[:, None] * V[F[which, 0]] + l1[:, None] * V[F[which, 1]]
              + l2[:, None] * V[F[which, 2]])
    return np.vstack([rim2, inner2]), np.vstack([rim3, inner3])


def write_obj(path: Path, vertices, faces) -> None:
    lines = [f"v {x:.12g} {y:.12g} {z:.12g}" for x, y, z in vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")


def chain(out: Path, mesh: Path, sets: list[str], remesh_sets: list[str]) -> None:
    """The pipeline's stages on ``mesh`` into ``out``."""
    bloom = str(ROOT / ".venv" / "bin" / "bloom")
    cfg = ["--config", str(ROOT / "configs" / "petal.toml")]
    out.mkdir(parents=True, exist_ok=True)
    extra = [x for s in sets for x in ("--set", s)]
    steps = [
        [bloom, "remesh", str(mesh), *cfg, *[x for s in remesh_sets for x in ("--set", s)],
         "--out", str(out / "remesh.h5")],
        [bloom, "axis", str(out / "remesh.h5"), *cfg, *extra, "--out", str(out / "axis.h5")],
        [bloom, "growth", str(out / "axis.h5"), *cfg, *extra, "--out", str(out / "growth.h5")],
        [bloom, "simulate", str(out / "growth.h5"), *cfg, *extra, "--no-progress",
         "--out", str(out / "sim.h5")],
    ]
    for cmd in steps:
        subprocess.run([*cmd, "--overwrite"], check=True, capture_output=True, text=True)


def load(d: Path) -> dict:
    import h5py

    with h5py.File(d / "sim.h5") as h:
        P = h["frames/positions"][:] / h.attrs["scale"]  # (input units: comparable)
        return dict(P=P, s=h["axis/s"][:], x=h["axis/x"][:], faces=h["mesh/faces"][:],
                    base=h["axis/base"][:], tip=int(h["axis/tip"][0]),
                    opening=h["diagnostics/opening_angle"][:])


def rms_difference(run: dict, ref: dict, frame: int = -1) -> float:
    """RMS over ``run``'s surface (vertex areas of its rest state) of the distance from
    each vertex to the point of ``ref`` at the same (s, x) (linear interpolation in
    ``ref``'s (s, x); nearest where outside its hull)."""
    from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator

    sx = np.c_[ref["s"], ref["x"]]
    target = np.c_[run["s"], run["x"]]
    Y = LinearNDInterpolator(sx, ref["P"][frame])(target)
    bad = ~np.all(np.isfinite(Y), axis=1)
    Y[bad] = NearestNDInterpolator(sx, ref["P"][frame])(target[bad])
    X0, F = run["P"][0], run["faces"]
    area = 0.5 * np.linalg.norm(np.cross(X0[F[:, 1]] - X0[F[:, 0]], X0[F[:, 2]] - X0[F[:, 0]]), axis=1)
    w = np.zeros(len(X0))
    for k in range(3):
        np.add.at(w, F[:, k], area / 3.0)
    d2 = np.sum((run["P"][frame] - Y) ** 2, axis=1)
    return float(np.sqrt(np.sum(w * d2) / w.sum()))


def petal_length(run: dict) -> float:
    X = run["P"][0]
    return float(np.linalg.norm(X[run["tip"]] - X[run["base"]].mean(axis=0)))


def table(runs: dict[str, dict], reference: str) -> list[str]:
    ref = runs[reference]
    L = petal_length(ref)
    lines = ["| run | vertices | final opening | max opening difference | RMS shape difference |",
             "|---|---|---|---|---|"]
    for name, r in runs.items():
        d_open = float(np.abs(r["opening"] - ref["opening"]).max())
        lines.append(f"| {name} | {r['P'].shape[1]} | {r['opening'][-1]:.2f} deg | "
                     f"{d_open:.2f} deg | {100 * rms_difference(r, ref) / L:.2f}% |")
    return lines


def main(argv: list[str]) -> None:
    out = Path(argv[0])
    sets = [a for a in argv[1:] if a != "--set"]
    out.mkdir(parents=True, exist_ok=True)
    runs = {}
    for n in COUNTS:
        chain(out / f"regular{n}", ROOT / "assets" / "petal.obj", sets,
              [f"remesh.petal_vertices={n}"])
        runs[f"regular {n}"] = load(out / f"regular{n}")
        mesh = out / f"irregular{n}.obj"
        write_obj(mesh, *irregular_petal(n))
        chain(out / f"irregular{n}", mesh, sets, ["remesh.symmetrize=false"])
        runs[f"irregular {n}"] = load(out / f"irregular{n}")
    print("\n".join(table(runs, f"regular {COUNTS[-1]}")))


if __name__ == "__main__":
    main(sys.argv[1:])
