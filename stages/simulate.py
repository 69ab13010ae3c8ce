"""bloom simulate: grow the petals and integrate (Eq. 6-8) -> sim.h5."""

from __future__ import annotations

import sys

import click
import numpy as np

from pipeline.errors import BloomError

from .common import config_options, input_hashes, load, log, output_options

#: effects the simulator composes; wrinkles act through growth.h5's alpha and stiffness
AVAILABLE_EFFECTS = ("wrinkles",)


@click.command("simulate")
@click.argument("growth_h5", type=click.Path(dir_okay=False))
@config_options
@output_options
@click.option("--progress/--no-progress", default=None,
              help="Progress bar [default: on when stderr is a terminal].")
def command(growth_h5: str, config_path, overrides, out, overwrite, progress) -> None:
    """Simulate the bloom of the petals in GROWTH_H5 and write the frames to sim.h5."""
    from pipeline import artifact
    from pipeline.measure import PetalFrames
    from pipeline.sim.integrators import make_integrator
    from pipeline.sim.model import Control, Model, State
    from pipeline.sim.run import run

    cfg = load(config_path, overrides)
    where = str(cfg.path) if cfg.path else "defaults"
    for name in cfg.effects_enabled():
        if name not in AVAILABLE_EFFECTS:
            raise BloomError(f"effects.{name}.enabled: the {name} effect is not available in "
                             "this version; set it to false", where=where)
    out = artifact.check_output(out, "simulate", overwrite)
    sim = cfg.section("simulate")
    steps, frames, h = sim["steps"], sim["frames"], sim["h"]
    with artifact.Artifact(growth_h5, needs="growth", reader="simulate") as src:
        v = src["mesh/vertices"]
        petal, base = src["mesh/petal"], src["axis/base"]
        try:
            model = Model.build(
                v, src["growth/edges"], src["growth/alpha"],
                sim["stretch_stiffness"] * src["growth/stiffness"], src["growth/hinges"],
                sim["bending_stiffness"], pinned=base, mass=sim["mass"])
        except ValueError as exc:
            raise BloomError(f"cannot build the model: {exc}", where=growth_h5) from None
        petals = PetalFrames.from_mesh(v, petal, base, src["axis/on_axis"], src["axis/tip"],
                                       src["axis/plane"])
        control = Control(cfg["growth.schedule"], cfg["growth.ramp"] * steps * h)
        integrator = make_integrator(sim["integrator"], sim["eta"], sim["damping"])
        state = State.at_rest(model, v, control)
        log.info("%d vertices (%d fixed), %d springs, %d hinges; %d steps of h = %g, %d frames",
                 model.vertex_count, int(model.pinned.sum()), model.edge_count,
                 model.hinge_count, steps, h, frames)
        show = sys.stderr.isatty() if progress is None else progress
        with click.progressbar(length=steps, label="simulate", file=sys.stderr,
                               show_eta=True, show_percent=True) if show else _Null() as bar:
            rec, wall = run(model, state, control, integrator, steps=steps, frames=frames, h=h,
                            petals=petals, progress=bar.update)
        diag = rec.arrays()
        positions = np.asarray(rec.positions)
        if not np.all(np.isfinite(positions)):
            raise BloomError("the simulation diverged (non-finite positions); try a smaller "
                             "simulate.h or a smaller simulate.eta", where=where)
        tail = max(1, (frames - 1) // 10)
        opening = diag.get("opening_angle", np.zeros(frames))
        log.info("%.2f s (%.3f ms/step); opening %.1f deg, change over the last 10%% %.3f deg; "
                 "final kinetic energy %.3g, max speed %.3g", wall, 1e3 * wall / steps,
                 opening[-1], opening[-1] - opening[-1 - tail], diag["kinetic_energy"][-1],
                 diag["max_speed"][-1])
        attrs = {"scale": src.attrs["scale"], "flower_axis": src.attrs["flower_axis"],
                 "steps": steps, "h": h,
                 "wall_seconds": wall, "ms_per_step": 1e3 * wall / steps,
                 "effects": ",".join(cfg.effects_enabled()),
                 "integrator": sim["integrator"]}
        with artifact.writing(out, stage="simulate", config_json=cfg.to_json(),
                              inputs=input_hashes(cfg, growth_h5), attrs=attrs) as h5:
            src.copy_to(h5, ("mesh/faces", "mesh/petal", "axis/base", "axis/x", "axis/tip"))
            artifact.put(h5, "frames/time", np.asarray(rec.time), "(T,) time of each frame")
            artifact.put(h5, "frames/positions", positions, "(T, V, 3) vertex positions")
            for name, values in diag.items():
                artifact.put(h5, f"diagnostics/{name}", values)
    log.info("wrote %s", out)


class _Null:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def update(self, n):
        pass
