"""Benchmarks: what each effect costs, as ratios to the bare simulation in one run, how
the collision effect scales with the vertex count, and what the remesh stage costs on a
studio-sized model."""

from __future__ import annotations

import dataclasses
import resource
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

from pipeline.chain import run_scene
from pipeline.errors import BloomError
from pipeline.flower.petals import prepare_parts
from pipeline.forks import workers
from pipeline.io.meshfile import MeshFile, Part
from pipeline.mesh import procedural, topology
from pipeline.mesh.intersect import frame_intersections
from pipeline.sim.build import Prepared
from pipeline.sim.effects import Params
from pipeline.sim.explicit.semi_implicit import SemiImplicit
from pipeline.sim.model import Control, State
from pipeline.studies import models

#: the ``effects`` section of a scene at its defaults, connecting rims up to 3 edges away
PARAMS = Params.defaults().but(connections={"max_distance": 3.0})
VARIANTS = ((), ("curl",), ("wrinkles",), ("collisions",), ("connections",), ("center_plane",),
            ("curl", "wrinkles", "collisions", "connections", "center_plane"))


def _bud(petals: int, vertices: int):
    return procedural.bud(petals, vertices, 0)


def _ms_per_step(bud, names, steps: int, ramp: float) -> float:
    wrinkles = "wrinkles" in names
    prep = Prepared.from_mesh(*bud, "0.2*x**2", alpha_add=0.1 if wrinkles else 0.0,
                              boundary_stiffness=0.5 if wrinkles else 1.0)
    model = prep.model(0.1, 0.0005)
    effects = prep.effects(names, PARAMS, max_edge=1.5)
    control = Control("linear", ramp)
    state = State.at_rest(model, prep.vertices, control)
    integrator = SemiImplicit(0.1)
    integrator.advance(model, state, control, 2, 1.0, effects)  # compile, if not cached
    t0 = time.perf_counter()
    integrator.advance(model, state, control, steps, 1.0, effects)
    return 1e3 * (time.perf_counter() - t0) / steps


def effect_costs(vertices: int = 2000, steps: int = 3000, repeats: int = 3) -> list[dict]:
    """ms per step of a 6-petal bud with no effect, each effect alone, and all of them;
    the best of ``repeats`` runs, interleaved so machine noise hits every variant alike."""
    bud = _bud(6, vertices)
    best = {names: np.inf for names in VARIANTS}
    for _ in range(repeats):
        for names in VARIANTS:
            best[names] = min(best[names], _ms_per_step(bud, names, steps, ramp=steps))
    bare = best[()]
    return [{"effects": "+".join(names) or "none", "ms_per_step": best[names],
             "ratio": best[names] / bare} for names in VARIANTS]


def collision_scaling(sizes=(2000, 8000, 32000), steps: int = 300) -> list[dict]:
    """ms per step with and without collisions on buds of ``sizes`` vertices."""
    rows = []
    for n in sizes:
        bud = _bud(6, n)
        bare = _ms_per_step(bud, (), steps, ramp=steps)
        coll = _ms_per_step(bud, ("collisions",), steps, ramp=steps)
        edges = len(topology.unique_edges(bud[1])[0])
        rows.append({"vertices": len(bud[0]), "edges": edges, "bare_ms": bare,
                     "bare_ns_per_edge": 1e6 * bare / edges, "collisions_ms": coll,
                     "collisions_ns_per_vertex": 1e6 * (coll - bare) / len(bud[0])})
    return rows


#: the default scenes with contact (``configs/<name>.toml``), for :func:`contact_scenes`
CONTACT_SCENES = ("lily", "magnolia", "bud6", "plum", "lily_wrinkles", "plum_locked")


def contact_scenes(names=("lily",), workdir=None, overrides=()) -> list[dict]:
    """Each default scene ``configs/<name>.toml`` through remesh, axis, growth and
    simulate with its own config (Newton with contact), as ``make`` runs it: simulate's
    wall seconds (``wall_seconds`` of sim.h5, the stepping alone), its Newton iterations,
    and the frames where two triangles intersect (ipctk's exact test)."""
    root = Path(__file__).resolve().parents[2]
    rows = []
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        tmp = Path(tmp)
        for name in names:
            try:
                run_scene(root / "configs" / f"{name}.toml", tmp, overrides=overrides)
            except BloomError as exc:
                raise RuntimeError(f"{name}: {exc}") from None
            with h5py.File(tmp / "sim.h5") as f:
                X = f["frames/positions"][()]
                d = f["diagnostics"]
                rows.append({
                    "scene": name, "vertices": int(X.shape[1]),
                    "integrator": str(f.attrs["integrator"]),
                    "simulate_seconds": float(f.attrs["wall_seconds"]),
                    "newton_iterations": int(d["newton_iterations"][-1])
                    if "newton_iterations" in d else 0,
                    "intersecting_frames": int(sum(frame_intersections(X, f["mesh/faces"][()]))),
                    "frames": int(X.shape[0]),
                    "opening_deg": float(d["opening_angle"][-1]),
                    "final_kinetic_energy": float(d["kinetic_energy"][-1])})
    return rows


def solidified(vertices: np.ndarray, faces: np.ndarray, thickness: float):
    """A sheet made a closed shell as Blender's Solidify makes it: two sides at
    +-thickness/2 along the vertex normals, joined along the rim by a strip of quads."""
    n = topology.vertex_normals(vertices, faces)
    nv = len(vertices)
    v = np.concatenate([vertices + 0.5 * thickness * n, vertices - 0.5 * thickness * n])
    he, _ = topology.half_edges(faces)
    _, he_edge, count = topology.unique_edges(faces)
    a, b = he[count[he_edge] == 1].T
    strip = np.concatenate([np.stack([b, a, a + nv], 1), np.stack([b, a + nv, b + nv], 1)])
    return v, np.concatenate([faces, faces[:, [0, 2, 1]] + nv, strip])


def studio_flower(faces: int = 100_000, petals: int = 12, seed: int = 0):
    """A flower as a studio exports it, for timing the remesh stage: one mesh of about
    ``faces`` triangles holding ``petals`` solidified (closed, thin) petals of an open
    lily in two whorls and a closed receptacle they are pushed into (as the lotus and
    the water lily are). Returns ``(vertices, faces)``; the same seed gives the same mesh."""
    import trimesh

    receptacle = trimesh.creation.icosphere(subdivisions=4, radius=0.12)
    per_petal = (faces - len(receptacle.faces)) // petals
    # a solidified sheet of n vertices has about 4.4 n faces (two sides and the rim strip)
    v, f, label = procedural.open_flower(petals, vertices=int(petals * per_petal / 4.4), seed=seed)
    verts, tris, offset = [], [], 0
    rng = np.random.default_rng(seed)
    for p in range(petals):
        idx = np.flatnonzero(label == p)
        keep = np.isin(f[:, 0], idx)
        pv = v[idx]
        # twisted a little about its own length, each its own way, as real petals are: no
        # petal is mirror-symmetric, so each goes through the remesh (not the shortcut
        # for a mesh whose vertices pair up across its plane)
        c = pv.mean(axis=0)
        _, _, axes = np.linalg.svd(pv - c, full_matrices=False)
        along, across = (pv - c) @ axes[0], (pv - c) @ axes[1]
        pv = pv + np.outer(rng.uniform(0.2, 0.4) * along * across, axes[2])
        sv, sf = solidified(pv, np.searchsorted(idx, f[keep]), 0.01)
        verts.append(sv)
        tris.append(sf + offset)
        offset += len(sv)
    verts.append(np.asarray(receptacle.vertices) + [0.0, 0.0, -0.05])
    tris.append(np.asarray(receptacle.faces) + offset)
    return np.concatenate(verts), np.concatenate(tris)


def remesh_cost(faces: int = 100_000, seed: int = 0) -> dict:
    """The remesh stage's library work (:func:`pipeline.flower.petals.prepare_parts`, default
    config, petals in :func:`pipeline.forks.workers` processes) on
    :func:`studio_flower`: wall and CPU seconds (CPU: this process's and its finished
    workers', which other jobs on the machine do not inflate), the peak resident memory
    of this process and of its largest worker, and what came out."""
    v, f = studio_flower(faces, seed=seed)
    mesh_file = MeshFile([Part("flower", v, f)], None, None)
    t0, c0 = time.perf_counter(), _cpu()
    result = prepare_parts(mesh_file, where="studio_flower", workers=workers(0))
    wall, cpu = time.perf_counter() - t0, _cpu() - c0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux
    worker_peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    return {"faces_in": len(f), "vertices_in": len(v), "petals": len(result.plane),
            "flowers": len(result.flower_centre), "vertices_out": len(result.vertices),
            "wall_seconds": wall, "cpu_seconds": cpu, "peak_rss_mb": peak,
            "worker_peak_rss_mb": worker_peak}


def _cpu() -> float:
    """CPU seconds of this process and of its children that have ended."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def real_models(meshes, workdir=None) -> list[dict]:
    """Each real flower model through the simulation stages with a scene of ``scene.mesh``
    only (:func:`pipeline.studies.models.run_model`): its row of the models study, whose
    ``seconds`` is simulate's with an open model's bud search included."""
    rows = []
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        for mesh in meshes:
            row = models.run_model(Path(mesh), Path(tmp) / Path(mesh).stem, timeout=3600.0)
            rows.append(dataclasses.asdict(row))
    return rows
