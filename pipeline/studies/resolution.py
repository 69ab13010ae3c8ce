"""Does the same flower bloom the same at any resolution and on any triangulation?
(``bloom study resolution``; issue 31.)

A scene whose mesh is a procedural asset (``bloom asset``, named in its header) is run
through remesh, axis, growth and simulate at several densities (``--counts``: vertices
per petal), each on two triangulations of the same surface:

- *regular*: the scene's own remesh at ``remesh.petal_vertices = N`` (isotropic,
  mirror-symmetric);
- *irregular*: Poisson-disc samples of each petal's flat pattern, Delaunay-triangulated
  and lifted onto the asset by its piecewise-linear map (every point lies on the asset's
  surface), remeshed with ``remesh.symmetrize = false`` (its triangles kept).

Each run is measured against the finest regular run: the largest difference of the mean
opening angle over the frames, and the RMS distance of the final shape from it
(area-weighted over the surface, points matched by their (s, x) of the axis stage, each
petal with its own), in percent of the petal length (the rest bud's chord from the base's
centre to the tip, mean over petals). Written to ``resolution.csv`` and, as error against
vertices per model and triangulation, ``resolution.png``.
"""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np

from pipeline.artifact import atomic_path
from pipeline.chain import run_scene
from pipeline.config import load_config
from pipeline.io.meshfile import read_mesh
from pipeline.mesh import procedural
from pipeline.mesh.remesh import boundary_loops
from pipeline.mesh.topology import stack

#: vertices per petal of the three densities the issue asks for (1x, 4x, 16x)
COUNTS = (300, 1200, 4800)


def asset_pattern(path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(flat (V, 2), vertices (V, 3), faces, petal)``: a procedural asset and the flat
    petals it was bent from (rebuilt from its header, ``bloom asset KIND --petals N
    --vertices M --seed S``), with the same faces: a piecewise-linear map of each flat
    petal onto the asset. Raises ValueError if the file is not that asset."""
    path = Path(path)
    header = path.read_text().splitlines()[0]
    m = re.search(r"bloom asset (petal|bud) --petals (\d+) --vertices (\d+) --seed (\d+)", header)
    if m is None:
        raise ValueError(f"{path}: not a procedural bud or petal (`bloom asset`): no flat "
                         "pattern to sample")
    petals, count, seed = int(m.group(2)), int(m.group(3)), int(m.group(4))
    seen = []
    bend = procedural.bend_into_bud

    def spy(points, *args, **kwargs):
        seen.append(np.array(points))
        return bend(points, *args, **kwargs)

    procedural.bend_into_bud = spy
    try:
        v, f, petal = procedural.bud(petals, count, seed)
    finally:
        procedural.bend_into_bud = bend
    V, F = read_mesh(path)[:2]
    flat = np.vstack(seen[-petals:])  # (an untangled bud is bent twice: the last ones)
    if not (np.array_equal(f, F) and np.abs(v - V).max() < 1e-8 and len(flat) == len(V)):
        raise ValueError(f"{path} is not the procedural asset of its header")
    return flat, V, F, np.asarray(petal)


def irregular_mesh(path, count: int, seed: int = 1):
    """``(vertices (V, 3), faces)``: about ``count`` Poisson-disc samples per petal of the
    asset's surface (:func:`asset_pattern`), Delaunay-triangulated in its flat pattern; the
    rim sampled along the asset's own rim (its corners kept)."""
    flat, V, F, petal = asset_pattern(path)
    sheets = []
    for p in range(int(petal.max()) + 1):
        idx = np.flatnonzero(petal == p)
        local = np.searchsorted(idx, F[np.all(petal[F] == p, axis=1)])
        sheets.append(_irregular_petal(flat[idx], V[idx], local, count, seed + p))
    vertices, faces, _ = stack(sheets)
    return vertices, faces


def _irregular_petal(flat, V, F, count, seed):
    from matplotlib.path import Path as Polygon
    from scipy.spatial import Delaunay

    loop = max(boundary_loops(F), key=len)
    poly = flat[loop]
    area = 0.5 * abs(np.sum(poly[:, 0] * np.roll(poly[:, 1], -1)
                            - np.roll(poly[:, 0], -1) * poly[:, 1]))
    perimeter = np.linalg.norm(np.roll(poly, -1, axis=0) - poly, axis=1).sum()
    h = np.sqrt(area / (0.75 * count))
    for _ in range(6):  # the spacing that gives about `count` vertices
        pts2, _ = _sample(flat, V, F, loop, poly, h, np.random.default_rng(seed))
        h *= np.sqrt(len(pts2) / count)
    pts2, pts3 = _sample(flat, V, F, loop, poly, h, np.random.default_rng(seed))
    tri = Delaunay(pts2).simplices
    inside = Polygon(poly).contains_points(pts2[tri].mean(axis=1), radius=-1e-9 * perimeter)
    tri = tri[inside]
    a = pts2[tri]
    cross = ((a[:, 1, 0] - a[:, 0, 0]) * (a[:, 2, 1] - a[:, 0, 1])
             - (a[:, 1, 1] - a[:, 0, 1]) * (a[:, 2, 0] - a[:, 0, 0]))
    tri[cross < 0] = tri[cross < 0][:, [0, 2, 1]]
    b = flat[F]  # orient as the asset (its faces' flat winding)
    c0 = ((b[:, 1, 0] - b[:, 0, 0]) * (b[:, 2, 1] - b[:, 0, 1])
          - (b[:, 1, 1] - b[:, 0, 1]) * (b[:, 2, 0] - b[:, 0, 0]))
    if np.mean(c0) < 0:
        tri = tri[:, [0, 2, 1]]
    return pts3, np.ascontiguousarray(tri, dtype=np.int64)


def _sample(flat, V, F, loop, poly, h, rng):
    """Rim samples every ~h along the flat rim (corners kept) and Poisson-disc interior
    samples at least 0.75 h apart, in the flat pattern and lifted onto the surface."""
    from matplotlib.path import Path as Polygon
    from matplotlib.tri import Triangulation
    from scipy.spatial import cKDTree

    n = len(loop)
    seg = np.roll(poly, -1, axis=0) - poly
    nxt = np.roll(seg, -1, axis=0)
    turn = np.abs(np.arctan2(seg[:, 0] * nxt[:, 1] - seg[:, 1] * nxt[:, 0],
                             np.einsum("ij,ij->i", seg, nxt)))
    corner = np.roll(turn, 1) > np.radians(30.0)  # turn at vertex k between seg k-1 and k
    starts = np.flatnonzero(corner)
    if len(starts) == 0:
        starts = np.array([0])
    rim2, rim3 = [], []
    for a, b in zip(starts, np.roll(starts, -1), strict=True):
        idx = [(a + k) % n for k in range(((b - a) % n) or n + 1)] + [b % n]
        p2, p3 = flat[loop[idx]], V[loop[idx]]
        t = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p2, axis=0), axis=1))]
        at = np.linspace(0.0, t[-1], max(1, int(round(t[-1] / h))) + 1)[:-1]
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
    which = Triangulation(flat[:, 0], flat[:, 1], F).get_trifinder()(inner2[:, 0], inner2[:, 1])
    inner2, which = inner2[which >= 0], which[which >= 0]
    a, b, c = flat[F[which, 0]], flat[F[which, 1]], flat[F[which, 2]]
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    l1 = ((inner2[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1])
          - (inner2[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])) / det
    l2 = ((b[:, 0] - a[:, 0]) * (inner2[:, 1] - a[:, 1])
          - (b[:, 1] - a[:, 1]) * (inner2[:, 0] - a[:, 0])) / det
    inner3 = ((1.0 - l1 - l2)[:, None] * V[F[which, 0]] + l1[:, None] * V[F[which, 1]]
              + l2[:, None] * V[F[which, 2]])
    return np.vstack([rim2, inner2]), np.vstack([rim3, inner3])


def write_obj(path: Path, vertices, faces) -> None:
    lines = [f"v {x:.12g} {y:.12g} {z:.12g}" for x, y, z in vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    Path(path).write_text("\n".join(lines) + "\n")


def load(folder: Path) -> dict:
    import h5py

    with h5py.File(Path(folder) / "sim.h5") as h:
        P = h["frames/positions"][:] / h.attrs["scale"]  # (input units: comparable)
        return dict(P=P, s=h["axis/s"][:], x=h["axis/x"][:], faces=h["mesh/faces"][:],
                    petal=h["mesh/petal"][:], base=h["axis/base"][:], tip=h["axis/tip"][:],
                    opening=h["diagnostics/opening_angle"][:],
                    summary=str(h.attrs.get("summary", "")))


def _matched(run: dict, ref: dict, frame: int) -> np.ndarray:
    """``(V, 3)`` the point of ``ref`` at each of ``run``'s vertices' (s, x), petal by
    petal (petals matched by the nearest centroid at rest): linear interpolation in
    ``ref``'s (s, x), nearest outside its hull."""
    from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator

    out = np.zeros((run["P"].shape[1], 3))
    ref_centres = np.array([ref["P"][0][ref["petal"] == q].mean(axis=0)
                            for q in range(int(ref["petal"].max()) + 1)])
    for p in range(int(run["petal"].max()) + 1):
        mine = run["petal"] == p
        q = int(np.argmin(np.linalg.norm(ref_centres - run["P"][0][mine].mean(axis=0), axis=1)))
        theirs = ref["petal"] == q
        sx = np.c_[ref["s"][theirs], ref["x"][theirs]]
        target = np.c_[run["s"][mine], run["x"][mine]]
        Y = LinearNDInterpolator(sx, ref["P"][frame][theirs])(target)
        bad = ~np.all(np.isfinite(Y), axis=1)
        Y[bad] = NearestNDInterpolator(sx, ref["P"][frame][theirs])(target[bad])
        out[mine] = Y
    return out


def rms_difference(run: dict, ref: dict, frame: int = -1) -> float:
    """RMS over ``run``'s surface (vertex areas of its rest state) of the distance from
    each vertex to the point of ``ref`` at the same (s, x) (:func:`_matched`)."""
    Y = _matched(run, ref, frame)
    X0, F = run["P"][0], run["faces"]
    area = 0.5 * np.linalg.norm(np.cross(X0[F[:, 1]] - X0[F[:, 0]], X0[F[:, 2]] - X0[F[:, 0]]),
                                axis=1)
    w = np.zeros(len(X0))
    for k in range(3):
        np.add.at(w, F[:, k], area / 3.0)
    d2 = np.sum((run["P"][frame] - Y) ** 2, axis=1)
    return float(np.sqrt(np.sum(w * d2) / w.sum()))


def petal_length(run: dict) -> float:
    """Mean over petals of the rest chord from the base's centre to the tip."""
    X = run["P"][0]
    return float(np.mean([np.linalg.norm(X[t] - X[run["base"] & (run["petal"] == p)].mean(axis=0))
                          for p, t in enumerate(run["tip"])]))


def measure(runs: dict[str, dict], reference: str) -> list[dict]:
    """Each run against ``runs[reference]``: rows of the table."""
    ref = runs[reference]
    length = petal_length(ref)
    rows = []
    for name, r in runs.items():
        frames = min(len(r["opening"]), len(ref["opening"]))
        rows.append({"run": name, "reference": name == reference,
                     "sound": r.get("summary", "sound").startswith("sound"),
                     "vertices": int(r["P"].shape[1]),
                     "opening": float(r["opening"][-1]),
                     "opening_difference": float(np.abs(r["opening"][:frames]
                                                        - ref["opening"][:frames]).max()),
                     "shape_difference": rms_difference(r, ref) / length})
    return rows


def resolution(out_dir, config, *, counts=COUNTS, overrides=(), kinds=("regular", "irregular"),
               models=(None,), echo=print) -> list[dict]:
    """Run the scene ``config`` at each of ``counts`` (vertices per petal) on each
    triangulation ``kinds`` into ``out_dir``, with each elastic model of ``models``
    (``simulate.model``; None: the scene's own), measure each against the finest regular
    run of its model, write ``resolution.csv`` and ``resolution.png`` and return the rows."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cfg = load_config(config, tuple(overrides))
    asset = Path(cfg["scene.mesh"])
    if not asset.is_absolute() and cfg.path is not None:
        asset = (Path(cfg.path).parent / asset).resolve()
    if "irregular" in kinds:  # (the same irregular meshes for every model)
        for n in counts:
            write_obj(out / f"irregular{n}.obj", *irregular_mesh(asset, n))
    rows = []
    for model in models:
        name = model or cfg["simulate.model"]
        chosen = () if model is None else (f"simulate.model={model}",)
        runs = {}
        for n in counts:
            for kind in kinds:
                folder = out / (f"{kind}{n}" if len(models) == 1 else f"{name}_{kind}{n}")
                if kind == "regular":
                    sets = [f"remesh.petal_vertices={n}"]
                else:
                    sets = [f"scene.mesh={out / f'irregular{n}.obj'}", "remesh.symmetrize=false",
                            "remesh.max_petal_vertices=0"]  # (its own triangles, at any count)
                run_scene(config, folder, overrides=(*overrides, *chosen, *sets))
                runs[f"{kind} {n}"] = load(folder)
                run = runs[f"{kind} {n}"]
                echo(f"{name}, {kind} {n}: {run['P'].shape[1]} vertices, opening "
                     f"{run['opening'][-1]:.2f} deg" + ("" if run["summary"].startswith("sound")
                                                        else f"; {run['summary']}"))
        rows += [{"model": name, **r} for r in measure(runs, f"regular {max(counts)}")]
    with open(out / "resolution.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    plot(rows, out / "resolution.png", f"Same surface, other meshes: {Path(config).stem}")
    return rows


def plot(rows: list[dict], path, title: str) -> None:
    """Each run's difference from its model's finest regular run against its vertices,
    log-log: the opening (deg, largest over the frames) and the final shape (RMS, percent
    of the petal length); one curve per model and triangulation (the reference, 0,
    left out)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), dpi=110)
    draw(axes, rows)
    fig.suptitle(f"{title} (against each model's finest regular mesh; dotted: 1 deg, 2%)")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def draw(axes, rows: list[dict]) -> None:
    """:func:`plot`'s two panels on ``axes`` (opening, shape), also drawn beside the
    cost curves of ``accuracy.png`` (:func:`pipeline.studies.accuracy.plot`)."""
    from matplotlib import ticker

    keys = dict.fromkeys((r["model"], r["run"].split()[0]) for r in rows)
    for (model, kind), style in zip(keys, ("o-", "s--", "^-", "v--"), strict=False):
        pts = sorted((r["vertices"], r["opening_difference"], 100 * r["shape_difference"])
                     for r in rows if r["model"] == model and r["run"].startswith(kind)
                     and not r["reference"])
        if not pts:
            continue
        n, opening, shape = zip(*pts, strict=True)
        axes[0].loglog(n, opening, style, label=f"{model}, {kind}")
        axes[1].loglog(n, shape, style, label=f"{model}, {kind}")
    axes[0].axhline(1.0, color="grey", lw=0.8, ls=":")
    axes[1].axhline(2.0, color="grey", lw=0.8, ls=":")
    axes[0].set_ylabel("largest opening difference over the frames (deg)")
    axes[1].set_ylabel("RMS shape difference (% of the petal length)")
    for ax in axes:
        ax.set_xlabel("vertices")
        ax.legend(fontsize=8)
        # plain numbers on the log axes (the errors span about one decade: minor ticks too)
        ax.xaxis.set_major_formatter(ticker.FormatStrFormatter("%g"))
        ax.xaxis.set_minor_formatter(ticker.NullFormatter())
        ax.yaxis.set_major_formatter(ticker.FormatStrFormatter("%g"))
        ax.yaxis.set_minor_formatter(ticker.FormatStrFormatter("%g"))
        ax.set_xticks(sorted({r["vertices"] for r in rows if r["model"] == rows[0]["model"]
                              and r["run"].startswith("regular")}))


def table(rows: list[dict]) -> list[str]:
    """The rows as a Markdown table."""
    lines = ["| model | run | vertices | final opening | max opening difference | RMS shape "
             "difference |", "|---|---|---|---|---|---|"]
    for r in rows:
        diff = ("(reference) | (reference)" if r["reference"] else
                f"{r['opening_difference']:.2f} deg | {100 * r['shape_difference']:.2f}%")
        lines.append(f"| {r['model']} | {r['run']}{'' if r.get('sound', True) else ' (unsound)'} "
                     f"| {r['vertices']} | {r['opening']:.2f} deg | {diff} |")
    return lines
