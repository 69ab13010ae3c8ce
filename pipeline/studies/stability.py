"""Hard cases, each taken through the real stages (remesh, axis, growth, simulate), that
must either finish with finite, bounded results or stop early with a clear one-line
message (``make stability``; the fast ones also run in the tests).

For each case: the outcome, the largest vertex speed over the run, the energy drift
during the hold after growth stops (the largest rise of kinetic + potential energy over
its value when growth stopped, relative to it; Eq. 8 with eta < 1/2 only removes energy
then, so a rise means energy is being created), how far any vertex got from the bud
(largest distance from the origin over the initial one), and the wall time.
"""

from __future__ import annotations

import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np
from scipy.spatial import Delaunay, cKDTree

from pipeline.chain import run_scene
from pipeline.errors import BloomError
from pipeline.mesh import procedural
from pipeline.mesh.intersect import frame_intersections
from pipeline.mesh.topology import unique_edges

#: a finished case passes when these hold
MAX_ESCAPE = 3.0  #: no vertex further from the receptacle than 3x the bud's initial reach
MIN_OPENING = 10.0  #: degrees: a robustness case ("bloom") must open at least this much
MAX_DRIFT = 0.1  #: total energy may not rise by more than 10% during the hold (measured
#: energy of a vibrating mesh fluctuates a little; a steady rise is an instability)


@dataclass
class Case:
    name: str
    what: str
    mesh: str  #: a key of MESHES
    settings: dict = field(default_factory=dict)  #: dotted config keys
    expect: str = "finish"  #: finish, stop (a clean early stop is the right outcome), or
    #: bloom (finish, with the scene's default config, and open by at least MIN_OPENING)
    slow: bool = False


def _petal_points(vertices: int = 320, seed: int = 0):
    v, f, p = procedural.bud(1, vertices, seed)
    return v, f, p


def _skinny(seed: int = 0):
    """A petal with 120 edges split 1/40 of the way along: triangles of aspect ~40."""
    v, f, p = _petal_points(320, seed)
    v, f = list(v), [list(t) for t in f]
    rng = np.random.default_rng(seed)

    edges = unique_edges(np.asarray(f))[0]
    done = set()
    for e in rng.permutation(len(edges))[:400]:
        a, b = (int(x) for x in edges[e])
        if a in done or b in done:
            continue
        touching = [t for t in f if a in t and b in t]
        if len(touching) != 2:
            continue
        m = len(v)
        v.append(np.asarray(v[a]) + (np.asarray(v[b]) - np.asarray(v[a])) / 40.0)
        for t in touching:
            f.remove(t)
            i, j = t.index(a), t.index(b)
            ta, tb = list(t), list(t)
            ta[j] = m
            tb[i] = m
            f += [ta, tb]
        done.update((a, b))
        if len(done) >= 240:
            break
    v = np.asarray(v)
    return v, np.asarray(f), np.zeros(len(v), dtype=np.int64)


def _duplicates(seed: int = 0):
    """A petal whose every 5th vertex has an unwelded twin 1e-9 away used by some of its
    faces, plus sliver faces (three collinear vertices)."""
    v, f, p = _petal_points(320, seed)
    twins = np.arange(0, len(v), 5)
    extra = v[twins] + 1e-9
    index = {int(t): len(v) + k for k, t in enumerate(twins)}
    f = f.copy()
    for row in range(0, len(f), 3):
        f[row] = [index.get(int(x), int(x)) for x in f[row]]
    v = np.concatenate([v, extra])
    a, b = f[0, 0], f[0, 1]
    mid = len(v)
    v = np.concatenate([v, [(v[a] + v[b]) / 2]])
    f = np.concatenate([f, [[a, b, mid]]])
    return v, f, np.zeros(len(v), dtype=np.int64)


def _folded(seed: int = 0, angle_deg: float = 179.0):
    """A flat petal whose tip (past 85% of its length) is folded back by ``angle_deg``:
    the fold's hinges sit near the +-pi branch cut of the dihedral angle."""
    rng = np.random.default_rng(seed)
    pts, f = procedural.flat_petal(procedural.Outline(), 0.06, rng)
    u, s = pts[:, 0], pts[:, 1]
    s0, phi = 0.85, np.radians(angle_deg)
    beyond = np.maximum(s - s0, 0.0)
    y = np.where(s > s0, s0 + beyond * np.cos(phi), s)
    z = np.where(s > s0, beyond * np.sin(phi), 0.0)
    v = np.stack([u, y, z], axis=1)
    return v, f, np.zeros(len(v), dtype=np.int64)


def _crossing_bud(seed: int = 0):
    """A 6-petal bud whose layers are pushed into each other: petals start interpenetrating."""
    return procedural.bud(6, 1200, seed, procedural.BudShape(layer_gap=-0.04), crossing=True)


# --- unseen-style inputs: meshes as modelling tools and other people make them ----------

OUTLINE, SHAPE = procedural.Outline(), procedural.BudShape()


def quad_petal(rows: int = 14, cols: int = 8, seed: int = 0, outline=OUTLINE):
    """A flat petal ``(points (V, 2), faces)`` as a modelling tool makes it: a quad grid
    whose columns narrow to a tip (the last row is a fan to the tip vertex), each quad
    split along a random diagonal, so no two halves mirror each other."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, rows + 1)[:-1]
    u = 2.0 * np.arange(cols + 1) / cols - 1.0
    pts = np.stack([(outline.half_width(s)[:, None] * u[None, :]).ravel(),
                    np.repeat(s, cols + 1)], axis=1)
    tip = len(pts)
    pts = np.vstack([pts, [[0.0, 1.0]]])
    faces = []
    for i in range(rows - 1):
        for j in range(cols):
            a, b = i * (cols + 1) + j, i * (cols + 1) + j + 1
            c, d = b + cols + 1, a + cols + 1
            faces += [(a, b, c), (a, c, d)] if rng.random() < 0.5 else [(a, b, d), (b, c, d)]
    last = (rows - 1) * (cols + 1)
    faces += [(last + j, last + j + 1, tip) for j in range(cols)]
    return pts, np.asarray(faces, dtype=np.int64)


def scattered_petal(vertices: int = 300, seed: int = 0, outline=OUTLINE):
    """A flat petal ``(points, faces)``: Delaunay triangulation of random points inside
    the outline and on it (an asymmetric triangulation, as a scan or a retopology gives)."""
    rng = np.random.default_rng(seed)
    s_fine = np.linspace(0.0, 1.0, 2001)
    w = outline.half_width(s_fine)
    area = 2.0 * np.trapezoid(w, s_fine)
    spacing = np.sqrt(area / (0.866 * vertices))
    half = procedural._resample(np.stack([w, s_fine], axis=1), spacing)
    rim = np.vstack([half, (half * [-1.0, 1.0])[::-1][1:-1]])
    base = procedural._resample(np.array([[-outline.base_half_width, 0.0],
                                     [outline.base_half_width, 0.0]]), spacing)[1:-1]
    inner = np.stack([rng.uniform(-outline.max_half_width, outline.max_half_width, 8 * vertices),
                      rng.uniform(0.0, 1.0, 8 * vertices)], axis=1)
    inner = inner[np.abs(inner[:, 0]) < outline.half_width(inner[:, 1]) - 0.5 * spacing]
    inner = inner[inner[:, 1] > 0.5 * spacing]

    kept = [*rim, *base]
    tree = cKDTree(np.asarray(kept))
    for q in inner:  # dart throwing: a minimum distance, positions random
        if tree.query(q)[0] > 0.7 * spacing:
            kept.append(q)
            tree = cKDTree(np.asarray(kept)) if len(kept) % 64 == 0 else tree
    pts = np.asarray(kept)

    tri = Delaunay(pts).simplices
    c = pts[tri].mean(axis=1)
    tri = tri[np.abs(c[:, 0]) < outline.half_width(c[:, 1])]
    p = pts[tri]
    area2 = ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
             - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1]))
    tri = tri[np.abs(area2) > 1e-9]
    tri[area2[np.abs(area2) > 1e-9] < 0] = tri[area2[np.abs(area2) > 1e-9] < 0][:, [0, 2, 1]]
    used = np.unique(tri)
    remap = np.full(len(pts), -1)
    remap[used] = np.arange(len(used))
    return pts[used], remap[tri]


def jittered_petal(vertices: int = 320, seed: int = 0, amount: float = 0.3):
    """The project's own petal with every vertex moved at random by up to ``amount`` of
    the lattice spacing, in the plane and out of it: no mirror pairs left."""
    rng = np.random.default_rng(seed)
    spacing = procedural._spacing_for(procedural.Outline(), vertices, seed)
    pts, f = procedural.flat_petal(procedural.Outline(), spacing, rng)
    pts = pts + rng.uniform(-amount, amount, pts.shape) * spacing
    return pts, f


def bud_of(flat, petals: int, seed: int = 0, shape=SHAPE):
    """Bend the flat petals ``flat(p)`` into a closed bud, as :func:`procedural.bud` does
    (untangled, as it does, where they would cross)."""
    return procedural.bend_bud(lambda p, rng: flat(p), petals, seed, shape)


def three_vertex_base(seed: int = 0):
    """A lone petal whose base is one short edge: three boundary vertices (nearly) on a
    line hold it."""
    outline = procedural.Outline(base_half_width=0.012)
    pts, f = scattered_petal(300, seed, outline)
    return bud_of(lambda p: (pts, f), 1, seed)


def centimetres(seed: int = 0):
    """A quad-grid 6-petal bud written in centimetres: petals 4.5 cm long."""
    v, f, p = bud_of(lambda k: quad_petal(seed=seed + k), 6, seed)
    return 4.5 * v, f, p


MESHES = {
    "petal": lambda: _petal_points(320),
    "skinny": _skinny,
    "duplicates": _duplicates,
    "folded": _folded,
    "bud6": lambda: procedural.bud(6, 1200, 0),
    "crossing": _crossing_bud,
    "bud12": lambda: procedural.bud(12, 2400, 0),
    "quad petal": lambda: bud_of(lambda p: quad_petal(seed=p), 1),
    "quad bud6": lambda: bud_of(lambda p: quad_petal(seed=p), 6),
    "jittered": lambda: bud_of(lambda p: jittered_petal(seed=p), 1),
    "asymmetric bud6": lambda: bud_of(lambda p: scattered_petal(200, seed=p), 6),
    "quad bud12": lambda: bud_of(lambda p: quad_petal(18, 10, seed=p), 12),
    "bud5 5000": lambda: bud_of(lambda p: scattered_petal(1050, seed=p), 5),
    "three-vertex base": three_vertex_base,
    "centimetres": centimetres,
}

#: the hard cases of the paper's scheme (time steps, push-back, energy in the hold) run it
#: by name, on the paper's springs; the "bloom" cases take the default config (the
#: quasi-static solver and the shell)
STEPS = {"simulate.steps": 30_000, "simulate.frames": 31, "simulate.integrator": "semi-implicit",
         "simulate.model": "paper"}

CASES = [
    Case("buckling x^6", "severe buckling: growth 0.2 x^6", "petal",
         {"growth.curve": "0.2*x**6"}),
    Case("buckling 0.6 x^6", "stronger: growth 0.6 x^6", "petal", {"growth.curve": "0.6*x**6"}),
    Case("alpha 1.0", "very large growth: alpha = 1.0 x^2 (rims double)", "petal",
         {"growth.curve": "1.0*x**2"}),
    Case("uniform alpha 1.0", "the whole petal doubles: alpha = 1.0", "petal",
         {"growth.curve": "1.0"}),
    Case("skinny triangles", "240 triangles of aspect ~40 (no symmetrize; remesh repairs them "
         "to the 20 deg bound)", "skinny", {"remesh.symmetrize": False}),
    Case("skinny, remeshed", "the same mesh remeshed (remesh.petal_vertices = 320)",
         "skinny", {"remesh.symmetrize": False, "remesh.petal_vertices": 320}),
    Case("near-duplicates, slivers", "twins 1e-9 apart and a collinear face (welded and "
         "dropped by remesh)", "duplicates", {"remesh.symmetrize": False}),
    Case("folded near pi", "tip folded back 179 deg: hinges near the +-pi branch cut", "folded",
         {"remesh.symmetrize": False, "axis.base": "-y"}),
    Case("interpenetrating bud", "petals start through each other; collisions on", "crossing",
         {"effects.collisions.enabled": True}),
    Case("12-petal bud", "dense 12-petal bud, 2400 vertices; collisions on", "bud12",
         {"effects.collisions.enabled": True}, slow=True),
    Case("mass breaking", "connection springs 100x stiffer than plum_locked's, breaking at "
         "1% stretch", "bud6",
         {"effects.connections.enabled": True, "effects.connections.critical_stretch": 1.01,
          "effects.connections.stiffness": 0.01, "effects.connections.max_distance": 3.0,
          "effects.connections.min_s": 0.3}),
    Case("h 1.5", "time step 1.5, inside the explicit limit", "petal", {"simulate.h": 1.5}),
    Case("h 1.9", "time step 1.9, past the scheme's limit (1.49 / omega_max at eta 0.1): "
         "the integrator takes 2 substeps per step", "petal", {"simulate.h": 1.9}),
    Case("h 2.5", "time step 2.5, far past the limit: 2 substeps per step", "petal",
         {"simulate.h": 2.5}),
    # unseen-style buds, each with the default config: it must bloom
    Case("quad-grid petal", "a quad grid narrowing to a tip, random diagonals", "quad petal",
         expect="bloom"),
    Case("quad-grid bud", "6 such petals", "quad bud6", expect="bloom"),
    Case("jittered petal", "every vertex jittered by 0.3 of the spacing, in and out of plane",
         "jittered", expect="bloom"),
    Case("asymmetric bud", "6 petals, Delaunay of random points (no mirror pairs)",
         "asymmetric bud6", expect="bloom"),
    Case("dense 12 petals", "12 quad-grid petals, 2388 vertices, 3 whorls; collisions on",
         "quad bud12", {"effects.collisions.enabled": True}, expect="bloom"),
    Case("5000+ vertices", "5 petals of random Delaunay triangles, 5518 vertices", "bud5 5000",
         expect="bloom"),
    Case("3-vertex base", "a lone petal whose base is one short edge (3 boundary vertices)",
         "three-vertex base", expect="bloom"),
    Case("centimetres", "the quad-grid bud in centimetres (petals 4.5 long)", "centimetres",
         expect="bloom"),
]


def _toml(settings: dict) -> str:
    sections: dict[str, list[str]] = {}
    for dotted, value in settings.items():
        section, key = dotted.rsplit(".", 1)
        if isinstance(value, bool):
            text = "true" if value else "false"
        elif isinstance(value, str):
            text = f'"{value}"'
        else:
            text = repr(value)
        sections.setdefault(section, []).append(f"{key} = {text}")
    return "\n".join(f"[{s}]\n" + "\n".join(lines) for s, lines in sections.items()) + "\n"


@dataclass
class Result:
    case: Case
    outcome: str  #: finished, stopped, FAILED
    message: str = ""
    max_speed: float = float("nan")
    drift: float = float("nan")
    escape: float = float("nan")
    wall: float = 0.0
    ok: bool = False
    opening: float = float("nan")  #: mean opening angle of the last frame, degrees
    notes: str = ""  #: what the case's artifacts show it exercised


def run_case(case: Case, workdir: Path, steps: dict | None = None) -> Result:
    """Write the case's mesh and config, run remesh -> simulate as the commands do
    (:func:`pipeline.chain.run_scene`), judge. A clean stop is a one-line
    :class:`BloomError` with no output written for the stage that stopped."""
    workdir.mkdir(parents=True, exist_ok=True)
    v, f, p = MESHES[case.mesh]()
    mesh = workdir / "input.obj"
    procedural.write_obj(mesh, v, f, p, f"stability case: {case.name}")
    settings = ({} if case.expect == "bloom" else {**STEPS, **(steps or {})}) | case.settings
    cfg = workdir / "scene.toml"
    cfg.write_text('[scene]\nmesh = "input.obj"\n' + _toml(settings))
    paths = {k: workdir / f"{k}.h5" for k in ("remesh", "axis", "growth", "sim")}
    t0 = time.perf_counter()
    try:
        run_scene(cfg, workdir)
    except BloomError as exc:
        wall = time.perf_counter() - t0
        text = f"bloom: error: {exc}"
        written = [k for k in ("remesh", "axis", "growth", "sim") if paths[k].exists()]
        stopped_at = ("remesh", "axis", "growth", "sim")[len(written)] if len(written) < 4 else None
        clean = "\n" not in str(exc) and stopped_at is not None
        outcome = "stopped" if clean else "FAILED"
        return Result(case, outcome, text, wall=wall, ok=clean and case.expect in ("stop", "either"))
    except Exception as exc:  # anything else is not a clean stop
        return Result(case, "FAILED", f"{type(exc).__name__}: {exc}",
                      wall=time.perf_counter() - t0, ok=False)
    wall = time.perf_counter() - t0
    notes = []
    with h5py.File(paths["growth"]) as h5:
        folded = int(np.sum(np.abs(h5["growth/rest_angle"][()]) > np.radians(170)))
        if folded:
            notes.append(f"{folded} hinges folded past 170 deg")
    with h5py.File(paths["sim"]) as h5:
        pos = h5["frames/positions"][()]
        speed = h5["diagnostics/max_speed"][()]
        total = h5["diagnostics/total_energy"][()]
        growth = h5["diagnostics/growth"][()]
        opening = (float(h5["diagnostics/opening_angle"][-1])
                   if "diagnostics/opening_angle" in h5 else float("nan"))
        if "diagnostics/contacts" in h5:
            contacts = h5["diagnostics/contacts"][()]
            if h5.attrs["integrator"] == "quasi-static":  # (the barrier's pairs in band)
                notes.append(f"contacts in {int(np.count_nonzero(contacts))} of "
                             f"{len(contacts)} frames")
            else:
                notes.append(f"{int(contacts.sum())} contacts pushed back")
            crossed = int(sum(frame_intersections(pos, h5["mesh/faces"][()])))
            notes.append(f"{crossed} of {len(pos)} frames intersecting")
        if "diagnostics/connections_intact" in h5:
            intact = h5["diagnostics/connections_intact"][()]
            notes.append(f"connection springs {intact[0]} -> {intact[-1]} intact")
    finite = bool(np.all(np.isfinite(pos)) and np.all(np.isfinite(total)))
    reach0 = np.linalg.norm(pos[0], axis=1).max()
    escape = float(np.linalg.norm(pos, axis=2).max() / reach0)
    hold = np.flatnonzero(growth >= 1.0)
    drift = 0.0
    if len(hold) > 1:
        e0 = total[hold[0]]
        drift = float((total[hold].max() - e0) / max(abs(e0), 1e-12))
    ok = (finite and escape < MAX_ESCAPE and drift < MAX_DRIFT
          and (case.expect in ("finish", "either")
               or case.expect == "bloom" and opening >= MIN_OPENING))
    return Result(case, "finished" if finite else "FAILED", "", float(speed.max()), drift,
                  escape, wall, ok, opening, "; ".join(notes))


def table(results: list[Result]) -> str:
    rows = ["| case | what | outcome | opening | max speed | energy drift (hold) | escape | wall |",
            "|---|---|---|---|---|---|---|---|"]
    for r in results:
        outcome = r.outcome
        if r.message:  # the stage's one line, without the case's path and remedy
            outcome += ": " + r.message.split(": ", 3)[-1].split("; likely cause")[0]
        if r.notes:
            outcome += f" ({r.notes})"
        rows.append(f"| {r.case.name} | {r.case.what} | {outcome} | {r.opening:.1f} deg | "
                    f"{r.max_speed:.3g} | "
                    f"{r.drift:.2g} | {r.escape:.2f} | {r.wall:.1f} s |")
    return "\n".join(rows)


def main() -> int:
    """``make stability``: every case, the table, exit 1 if any case is not as expected."""

    results = []
    with tempfile.TemporaryDirectory(prefix="bloom-stability-") as tmp:
        for i, case in enumerate(CASES):
            r = run_case(case, Path(tmp) / f"case{i}")
            mark = "ok  " if r.ok else "BAD "
            print(f"{mark} {case.name}: {r.outcome} {r.message}", file=sys.stderr, flush=True)
            results.append(r)
    print(table(results))
    return 0 if all(r.ok for r in results) else 1


if __name__ == "__main__":
    raise SystemExit(main())
