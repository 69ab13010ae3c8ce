"""What accuracy costs in time: runs of one scene with each integrator, measured against
a reference bloom (``bloom study accuracy``, ``make accuracy``).

- Scene: a procedural bud (``procedural.bud``) at growth ``0.2 x^2``, K_s 0.1, K_b 0.0005,
  a smootherstep ramp and, for the dynamic integrators, a hold of half the ramp after
  it. First without collisions; then (a bud of several petals) with them: Newton with
  the contact barrier against the semi-implicit scheme with the paper's push-back,
  each against a contact reference, with whether the bloom ends with two triangles
  through each other (ipctk's exact test).
- Reference: the quasi-static path with many growth increments and a tight tolerance;
  :func:`reference` also measures how much halving the increments and tightening the
  tolerance again changes it (it must be < 0.1% of the petal length).
- Error of a run: RMS distance of its final vertices to the reference's, over the mean
  petal length (base to tip), and the difference of the mean opening angle. A petal
  is symmetric and so is its growth: where it buckles to one side, its mirror image is
  an equilibrium as good as the reference's, and runs pick either side. So each petal
  is compared with the reference and with the reference's mirror image across the
  petal's center plane, and the nearer counts.
"""

from __future__ import annotations

import csv
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.artifact import atomic_path
from pipeline.flower.measure import PetalFrames
from pipeline.mesh import procedural, topology
from pipeline.mesh.intersect import frame_intersections
from pipeline.mesh.remesh import isotropic, target_for_vertices
from pipeline.mesh.symmetry import closest_points, mirror_pairs, reflect
from pipeline.sim.build import Prepared
from pipeline.sim.effects import Params
from pipeline.sim.integrators import make_integrator
from pipeline.sim.model import Control, Model, State

#: the ``effects`` section of a scene at its defaults
DEFAULT_EFFECTS = Params.defaults()


@dataclass
class Scene:
    vertices: np.ndarray
    faces: np.ndarray
    model: Model
    petals: PetalFrames
    length: float  #: mean petal length, base to tip, at rest
    petal: np.ndarray  #: (V,) petal of each vertex
    planes: np.ndarray  #: (P, 4) each petal's center plane at rest
    partner: np.ndarray | None  #: (V,) each vertex's mirror partner, if the petals pair up
    prep: Prepared | None = None  #: the arrays the effects are built from

    def effects(self, names=()):
        """The effects ``names`` (none: an empty set) at the defaults of the config."""
        return self.prep.effects(names, DEFAULT_EFFECTS)

    @classmethod
    def bud(cls, petals: int = 6, vertices: int = 2133, curve: str = "0.2*x**2",
            bending: float = 0.0005, stretch: float = 0.1, seed: int = 0) -> Scene:
        v, f, petal = procedural.bud(petals, vertices, seed)
        return cls.from_mesh(v, f, petal, curve, bending, stretch)

    @classmethod
    def remeshed(cls, source: tuple, vertices: int, curve: str = "0.2*x**2",
                 bending: float = 0.0005, stretch: float = 0.1) -> Scene:
        """The bud ``source = (v, f, petal)`` remeshed to about ``vertices`` vertices:
        the same surface, other triangles (a mesh-resolution study)."""

        v0, f0, petal0 = source
        count = int(petal0.max()) + 1
        meshes = []
        for p in range(count):
            idx = np.flatnonzero(petal0 == p)
            local = np.full(len(v0), -1)
            local[idx] = np.arange(len(idx))
            fp = local[f0[petal0[f0[:, 0]] == p]]
            h = target_for_vertices(v0[idx], fp, vertices // count)
            meshes.append(isotropic(v0[idx], fp, h)[:2])
        return cls.from_mesh(*topology.stack(meshes), curve, bending, stretch)

    @classmethod
    def from_mesh(cls, v, f, petal, curve: str = "0.2*x**2", bending: float = 0.0005,
                  stretch: float = 0.1) -> Scene:
        """A scene from a bud mesh (scaled to mean edge 1, as `bloom remesh` does)."""
        petals = int(petal.max()) + 1
        prep = Prepared.from_mesh(v, f, petal, curve)
        v, axes_plane = prep.vertices, prep.plane
        model = prep.model(stretch, bending)
        frames = prep.frames()
        length = float(np.linalg.norm(v[frames.tips] - frames.base_centers, axis=1).mean())
        partner = np.arange(len(v))
        for p in range(petals):
            idx = np.flatnonzero(petal == p)
            pairs = mirror_pairs(v[idx], axes_plane[p])
            if pairs is None:
                partner = None
                break
            partner[idx] = idx[pairs]
        return cls(v, f, model, frames, length, petal, np.asarray(axes_plane), partner, prep)

    def mirrored(self, X) -> np.ndarray:
        """Each petal's shape reflected across its center plane (vertex by vertex)."""
        out = np.empty_like(X)
        for p, plane in enumerate(self.planes):
            idx = np.flatnonzero(self.petal == p)
            out[idx] = reflect(X[self.partner[idx]], plane)
        return out


@dataclass
class Run:
    integrator: str
    params: str
    steps: int
    wall: float
    positions: np.ndarray
    iterations: int = 0
    crossed: bool = False  #: two triangles intersect at the end (ipctk's exact test)


def simulate(scene: Scene, integrator: str, *, ramp: int, hold: int = 0, h: float = 1.0,
             eta: float = 0.1, damping: float = 0.9999, stages: int = 20,
             tolerance: float = 1e-6, schedule: str = "smootherstep", effects=()) -> Run:
    """One run: growth over ``ramp`` steps, then ``hold`` steps at full growth, with the
    ``effects`` named."""

    model = scene.model
    steps = ramp + hold
    control = Control(schedule, ramp * h)
    state = State.at_rest(model, scene.vertices, control)
    stepper = make_integrator(integrator, eta, damping, speed_limit=10.0, stages=stages,
                              tolerance=tolerance)
    built = scene.effects(effects)
    t0 = time.perf_counter()
    stepper.advance(model, state, control, steps, h, built)
    wall = time.perf_counter() - t0
    if integrator == "quasi-static":
        params = f"stages={stages} tol={tolerance:g}"
    elif integrator == "explicit-damping":
        params = f"d={damping:g} h={h:g} ramp={ramp}"
    else:
        params = f"eta={eta:g} h={h:g} ramp={ramp}"
    if "collisions" in effects:
        params += " contact" if integrator == "quasi-static" else " push-back"
    return Run(integrator, params, steps, wall, state.positions.copy(),
               stepper.diagnostics().get("newton_iterations", 0),
               frame_intersections([state.positions], scene.faces)[0])


def shape_error(scene: Scene, X, reference) -> tuple[float, float]:
    """(RMS vertex distance / petal length, opening angle difference in degrees); each
    petal against the reference or its mirror image, whichever is nearer."""
    X = np.asarray(X)
    sq = np.sum((X - reference) ** 2, axis=1)
    if scene.partner is not None:
        sq_mirror = np.sum((X - scene.mirrored(reference)) ** 2, axis=1)
        for p in range(len(scene.planes)):
            idx = scene.petal == p
            if sq_mirror[idx].sum() < sq[idx].sum():
                sq[idx] = sq_mirror[idx]
    rms = float(np.sqrt(np.mean(sq)))
    angle = float(scene.petals.opening_angles(X).mean()
                  - scene.petals.opening_angles(reference).mean())
    return rms / scene.length, angle


def surface_error(scene: Scene, X, ref_scene: Scene, reference) -> tuple[float, float]:
    """:func:`shape_error` for a run on another mesh of the same bud: RMS distance of its
    vertices to the reference's surface (each petal to the same petal, or to its mirror
    image, whichever is nearer), over the reference's petal length. Meshes are scaled
    to a mean edge of 1, so the run is first scaled to the reference's petal length."""

    X = np.asarray(X) * (ref_scene.length / scene.length)
    faces = ref_scene.faces
    shapes = [reference] + ([ref_scene.mirrored(reference)] if ref_scene.partner is not None
                            else [])
    total = 0.0
    for p in range(len(ref_scene.planes)):
        pts = X[scene.petal == p]
        idx = np.flatnonzero(ref_scene.petal == p)
        local = np.full(len(ref_scene.petal), -1)
        local[idx] = np.arange(len(idx))
        mine = local[faces[ref_scene.petal[faces[:, 0]] == p]]
        total += min(float(np.sum((closest_points(R[idx], mine, pts) - pts) ** 2))
                     for R in shapes)
    angle = float(scene.petals.opening_angles(X).mean()
                  - ref_scene.petals.opening_angles(reference).mean())
    return float(np.sqrt(total / len(X))) / ref_scene.length, angle


def reference(scene: Scene, stages: int = 40, tolerance: float = 1e-8, effects=()):
    """The reference bloom and the change that refining it once more makes (fraction of
    the petal length): ``2 stages`` and ``tolerance / 10``."""
    ref = simulate(scene, "quasi-static", ramp=1, stages=stages, tolerance=tolerance,
                   effects=effects)
    finer = simulate(scene, "quasi-static", ramp=1, stages=2 * stages, tolerance=tolerance / 10,
                     effects=effects)
    change, _ = shape_error(scene, finer.positions, ref.positions)
    return ref, change


def plan(quick: bool = False) -> list[dict]:
    """The runs of the study: each integrator over a range of cost. Dynamic runs hold
    for half their ramp after it; ``h = 1.5`` runs cover the same growth time in fewer
    steps; ``vertices`` runs are the same bud surface remeshed coarser or finer."""
    ramps = (2_000, 8_000, 32_000) if quick else (5_000, 20_000, 80_000, 160_000)
    runs = [dict(integrator="quasi-static", stages=s, tolerance=t)
            for s, t in ((1, 1e-2), (2, 1e-3), (5, 1e-4), (10, 1e-6), (20, 1e-8))]
    runs += [dict(integrator="quasi-static", stages=10, tolerance=1e-6, vertices=v)
             for v in ((300, 700) if quick else (700, 1200, 2133, 4000))]
    for ramp in ramps:
        for eta in (0.1, 0.3, 0.5):
            runs.append(dict(integrator="semi-implicit", eta=eta, ramp=ramp, hold=ramp // 2))
        runs.append(dict(integrator="explicit-damping", damping=0.999, ramp=ramp,
                         hold=ramp // 2))
        short = int(ramp / 1.5)
        runs.append(dict(integrator="semi-implicit", eta=0.1, h=1.5, ramp=short,
                         hold=short // 2))
    return runs


def contact_plan(quick: bool = False) -> list[dict]:
    """The runs with collisions: Newton with the contact barrier over a range of
    increments, and the semi-implicit scheme with the paper's push-back over a range of
    growth durations."""
    ramps = (4_000, 16_000) if quick else (20_000, 80_000, 160_000)
    runs = [dict(integrator="quasi-static", stages=s, tolerance=t)
            for s, t in ((5, 1e-4), (10, 1e-6), (20, 1e-8))]
    runs += [dict(integrator="semi-implicit", eta=0.1, ramp=r, hold=r // 2) for r in ramps]
    return [dict(r, effects=("collisions",)) for r in runs]


FLOOR = 1e-6  #: errors below this are drawn at it (the reference's own rounding is ~1e-12)


def label(run: Run) -> str:
    if run.integrator == "semi-implicit":
        eta, h = run.params.split()[:2]
        name = "Verlet (eta=0.5)" if eta == "eta=0.5" else f"semi-implicit {eta}"
        name = name if h == "h=1" else f"{name} {h}"
        return f"{name}, push-back" if "push-back" in run.params else name
    return f"{run.integrator}, contact" if "contact" in run.params else run.integrator


def warm_up(scene: Scene, runs: list[dict]) -> None:
    """Run each integrator and time step of ``runs`` for a few steps first, so that no
    row's wall time includes compiling a kernel it is the first to use."""
    seen = set()
    for spec in runs:
        key = (spec["integrator"], spec.get("h", 1.0), spec.get("effects", ()))
        if key not in seen:
            seen.add(key)
            extra = {k: spec[k] for k in ("eta", "damping", "h", "effects") if k in spec}
            simulate(scene, spec["integrator"], ramp=4, hold=2, **extra)


def accuracy(out_dir, *, petals: int = 6, vertices: int = 2133, quick: bool = False,
             resolution: dict | None = None, echo=print) -> list[dict]:
    """Run the study; write ``accuracy.csv`` and ``accuracy.png`` into ``out_dir``.
    ``resolution``: the arguments of a resolution study
    (:func:`pipeline.studies.resolution.resolution`: ``config``, ``counts``, ``models``)
    run into ``out_dir/resolution`` and drawn beside the cost curves (None: none)."""

    source = procedural.bud(petals, vertices, 0)
    scene = Scene.from_mesh(*source)
    sections = [((), plan(quick))]
    if petals > 1:  # contact is between petals
        sections.append((("collisions",), contact_plan(quick)))
    rows = []
    for effects, runs in sections:
        ref, change = reference(scene, effects=effects)
        what = " with contact" if effects else ""
        echo(f"reference{what}: quasi-static, 40 increments, tolerance 1e-8: {ref.wall:.2f} s; "
             f"refining it changes it by {100 * change:.4f}% of the petal length"
             + ("; it ends with petals through each other" if ref.crossed else ""))
        if change > 1e-3:
            echo("WARNING: the reference is not converged to 0.1% of the petal length")
        warm_up(scene, runs)
        for spec in runs:
            rows.append(_row(scene, source, dict(spec), ref))
            r = rows[-1]
            echo(f"{r['integrator']:34s} {r['params']:36s} {r['wall_seconds']:8.2f} s  error "
                 f"{100 * r['error']:8.3f}%  opening {r['opening_difference_deg']:+7.2f} deg"
                 + ("  INTERSECTING" if r["intersecting_at_end"] else ""))
    with atomic_path(out_dir / "accuracy.csv") as tmp, open(tmp, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    meshes = None
    if resolution is not None:
        from pipeline.studies import resolution as study

        echo(f"resolution: {Path(resolution['config']).stem} at "
             f"{', '.join(map(str, resolution['counts']))} vertices per petal, "
             f"{', '.join(resolution['models'])}")
        meshes = study.resolution(out_dir / "resolution", echo=echo, **resolution)
    plot(rows, out_dir / "accuracy.png",
         f"What accuracy costs: {petals}-petal bud, {scene.model.vertex_count} vertices, "
         "the paper's springs", resolution=meshes,
         scene=None if resolution is None else Path(resolution["config"]).stem)
    return rows


def _row(scene: Scene, source, spec: dict, ref: Run) -> dict:
    """One run of a plan, measured against the reference ``ref``."""
    name = spec.pop("integrator")
    size = spec.pop("vertices", None)
    ramp = 1 if name == "quasi-static" else spec.pop("ramp")
    if size is None:
        run = simulate(scene, name, ramp=ramp, **spec)
        err, dangle = shape_error(scene, run.positions, ref.positions)
        name = label(run)
    else:  # the same bud remeshed: distances to the reference's surface
        other = Scene.remeshed(source, size)
        run = simulate(other, name, ramp=ramp, **spec)
        err, dangle = surface_error(other, run.positions, scene, ref.positions)
        run.params += f" V={other.model.vertex_count}"
        name = f"{label(run)}, mesh resolution"
    return {"integrator": name, "params": run.params, "steps": run.steps,
            "newton_iterations": run.iterations, "wall_seconds": run.wall, "error": err,
            "opening_difference_deg": dangle,
            "effects": "+".join(spec.get("effects", ())) or "none",
            "intersecting_at_end": int(run.crossed)}


PAPER_LILY_SECONDS = 44.0  #: the paper's time for its Fig. 12 lily (2133 vertices)


def time_to_converge(scene: Scene, reference_positions, target: float = 0.01,
                     echo=None, quick: bool = False) -> list[dict]:
    """Wall seconds each integrator needs for a bloom within ``target`` (fraction of the
    petal length) of the reference: the dynamic ones with growth ramps doubling from
    10k steps (plus a hold of half) until one is within; the quasi-static one with 5,
    10, 20 and 40 increments at tolerance 1e-6 and 20 and 40 at 1e-3 (Newton stops at a
    step of a thousandth of a mesh unit), the fastest within (fewer increments are not
    cheaper: each needs more Newton iterations). ``quick``: ramps from 5k steps, at most 20k."""
    ramps = (5_000, 10_000, 20_000) if quick else (10_000, 20_000, 40_000, 80_000, 160_000)
    tries = {
        "quasi-static": [dict(ramp=1, stages=s, tolerance=t)
                         for s, t in ((5, 1e-6), (10, 1e-6), (20, 1e-6), (40, 1e-6),
                                      (20, 1e-3), (40, 1e-3))],
        "semi-implicit eta=0.1": [dict(ramp=r, hold=r // 2, eta=0.1)
                                  for r in ramps],
        "Verlet (eta=0.5)": [dict(ramp=r, hold=r // 2, eta=0.5)
                             for r in ramps],
        "explicit-damping d=0.999": [dict(ramp=r, hold=r // 2, damping=0.999)
                                     for r in ramps],
    }
    rows = []
    for name, specs in tries.items():
        integrator = name.split()[0] if name != "Verlet (eta=0.5)" else "semi-implicit"
        row = {"integrator": name, "converged": False}
        for spec in specs:
            run = simulate(scene, integrator, **spec)
            err, dangle = shape_error(scene, run.positions, reference_positions)
            this = dict(params=run.params, steps=run.steps, wall_seconds=run.wall, error=err,
                        opening_difference_deg=dangle, converged=err < target)
            if echo:
                echo(f"  {name:26s} {run.params:28s} {run.wall:7.2f} s  error {100 * err:.3f}%")
            better = not row["converged"] or (this["converged"]
                                              and this["wall_seconds"] < row["wall_seconds"])
            if better:
                row.update(this)
            if err < target and integrator != "quasi-static":
                break
        row["paper_seconds"] = PAPER_LILY_SECONDS
        rows.append(row)
    return rows


def plot(rows: list[dict], path, title: str, resolution: list[dict] | None = None,
         scene: str | None = None) -> None:
    """Error against wall seconds, log-log, one curve per integrator; with
    ``resolution`` (a resolution study's rows, of the scene named ``scene``), its two
    panels beside it: each elastic model's difference from its finest mesh against the
    vertices."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if resolution:
        from pipeline.studies.resolution import draw

        fig, axes = plt.subplots(1, 3, figsize=(18, 5), dpi=110,
                                 gridspec_kw={"width_ratios": (1.4, 1, 1)})
        ax = axes[0]
        draw(axes[1:], resolution)
        axes[1].set_title(f"mesh resolution: {scene or 'one'} scene, "
                          "the same surface at other densities", fontsize=9)
        axes[2].set_title("against each model's finest regular mesh (dotted: 1 deg, 2%)",
                          fontsize=9)
    else:
        fig, ax = plt.subplots(figsize=(7, 5), dpi=110)
    for name in dict.fromkeys(r["integrator"] for r in rows):
        pts = sorted((r["wall_seconds"], max(r["error"], FLOOR)) for r in rows
                     if r["integrator"] == name)
        ax.loglog(*zip(*pts, strict=True), "o-", label=name)
    ax.axhline(0.01, color="grey", lw=0.8, ls="--")
    ax.text(ax.get_xlim()[0], 0.0105, " 1% of petal length", color="grey", fontsize=8)
    ax.set_xlabel("wall seconds (simulate)")
    ax.set_ylabel(f"shape error (RMS distance / petal length; below {FLOOR:g}: at {FLOOR:g})")
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
