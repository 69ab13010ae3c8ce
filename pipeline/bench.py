"""Benchmarks: what each effect costs, as ratios to the bare simulation in one run, and
how the collision effect scales with the vertex count."""

from __future__ import annotations

import time

import numpy as np

from . import asset, topology
from .config import load_config
from .sim.build import Prepared
from .sim.integrators import SemiImplicit
from .sim.model import Control, State

#: the ``effects`` section of a scene at its defaults, connecting rims up to 3 edges away
PARAMS = load_config().nested()["effects"]
PARAMS["connections"]["max_distance"] = 3.0
VARIANTS = ((), ("curl",), ("wrinkles",), ("collisions",), ("connections",), ("center_plane",),
            ("curl", "wrinkles", "collisions", "connections", "center_plane"))


def _bud(petals: int, vertices: int):
    return asset.bud(petals, vertices, 0)


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
