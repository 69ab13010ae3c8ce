"""The growth stage: each edge's growth ratio alpha = growth.curve(x), the hinges and
their rest angles (:func:`pipeline.flower.growth.assign_growth`) -> growth.h5."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from pipeline import artifact
from pipeline.chain import carried_attrs
from pipeline.config import Config
from pipeline.errors import BloomError
from pipeline.flower.growth import assign_growth, growth_rule
from pipeline.sim.build import REST_STIFFNESS, rest_stiffness

log = logging.getLogger("bloom")

#: what the later stages need of axis.h5, carried forward
CARRIED = ("mesh/vertices", "mesh/faces", "mesh/petal", "mesh/left", "mesh/part_names",
           "mesh/part", "mesh/thickness",
           "mesh/flower", "flower/petal_flower", "flower/centre", "flower/axis", "axis/base", "axis/on_axis",
           "axis/tip", "axis/plane", "axis/x", "axis/s", "input/asset", "bind")


def run(axis_h5: str | Path, out: str | Path, cfg: Config, *, overwrite: bool = False) -> None:
    """Assign each edge its growth ratio alpha = growth.curve(x) and list the hinges."""
    where = str(cfg.path) if cfg.path else "defaults"
    out = artifact.check_output(out, "growth", overwrite)
    with artifact.Artifact(axis_h5, needs="axis", reader="growth") as src:
        v, f, x = src["mesh/vertices"], src["mesh/faces"], src["axis/x"]
        try:
            g = assign_growth(v, f, x, **growth_rule(cfg.__getitem__))
        except ValueError as exc:
            raise BloomError(f"growth.curve: {exc}", where=where) from None
        # no NaN leaves this stage: alpha and the rest angles finite, or refused naming the petal
        petal = src["mesh/petal"]
        bad = np.flatnonzero(~np.isfinite(g.alpha))
        if len(bad):
            e = int(bad[0])
            why = (f"growth.curve is not finite at x = {g.edge_x[e]:.6g}" if np.isfinite(g.edge_x[e])
                   else "its x is not finite (rerun bloom axis)")
            raise BloomError(f"petal {int(petal[g.edges[e, 0]])}: alpha is not finite on {len(bad)} "
                             f"edge(s): {why}; nothing written", where=axis_h5)
        bad = np.flatnonzero(~np.isfinite(g.rest_angle))
        if len(bad):
            raise BloomError(f"petal {int(petal[g.hinges[bad[0], 0]])}: the rest angle is not finite "
                             f"at {len(bad)} hinge(s): degenerate triangles; rerun bloom remesh; "
                             "nothing written", where=axis_h5)
        stiff = rest_stiffness(v, g, src["mesh/petal"], src["axis/base"],
                               cfg["simulate.stretch_stiffness"], cfg["simulate.bending_stiffness"])
        bad = np.flatnonzero(~(stiff <= REST_STIFFNESS))
        if len(bad):
            worst = int(bad[np.argmax(stiff[bad])])
            raise BloomError(
                f"remesh: petal {worst} is not a sound rest state ({len(bad)} petal(s) in all): a "
                f"1e-9 nudge brings back a force {stiff[worst]:.3g} times K_s + K_b per unit of "
                f"nudge (a sound mesh: 5-10; refused above {REST_STIFFNESS:g}), so its triangles "
                f"are degenerate; rerun bloom remesh (and "
                f"check remesh.petal_vertices) rather than simulate this", where=axis_h5)
        log.info("%d edges (%d on the boundary), %d hinges; alpha in [%.4g, %.4g]",
                 len(g.edges), int(g.boundary_edge.sum()), len(g.hinges),
                 g.alpha.min(), g.alpha.max())
        attrs = {"up": "+z", **carried_attrs(src)}
        with artifact.writing(out, stage="growth", config_json=cfg.to_json(),
                              inputs=artifact.input_hashes(cfg, axis_h5), attrs=attrs, previous=src) as h5:
            src.copy_to(h5, CARRIED)
            artifact.put(h5, "growth/edges", g.edges, "(E, 2) vertex pairs, i < j")
            artifact.put(h5, "growth/alpha", g.alpha, "(E,) growth ratio (Eq. 6, 12)")
            artifact.put(h5, "growth/stiffness", g.stiffness,
                         "(E,) factor on simulate.stretch_stiffness")
            artifact.put(h5, "growth/boundary", g.boundary_edge, "(E,) boundary edge")
            artifact.put(h5, "growth/edge_x", g.edge_x, "(E,) cross-section coordinate of the edge")
            artifact.put(h5, "growth/hinges", g.hinges,
                         "(H, 4) edge i, j, vertex opposite in face i->j, in face j->i")
            artifact.put(h5, "growth/hinge_edge", g.hinge_edge, "(H,) edge index of each hinge")
            artifact.put(h5, "growth/rest_angle", g.rest_angle, "(H,) signed dihedral angle, radians")
            artifact.put(h5, "growth/connections", np.zeros((0, 2), dtype=np.int64),
                         "(C, 2) connection springs between petals")
    log.info("wrote %s", out)
