"""bloom simulate: grow the petals and integrate (Eq. 6-8) -> sim.h5."""

from __future__ import annotations

import click
import numpy as np

from pipeline.errors import BloomError

from .common import config_options, input_hashes, load, log, output_options, progress_bar


@click.command("simulate")
@click.argument("growth_h5", type=click.Path(dir_okay=False))
@config_options
@output_options
@click.option("--progress/--no-progress", default=None,
              help="Progress bar [default: on when stderr is a terminal].")
@click.option("--resume", is_flag=True,
              help="Continue from the checkpoint an interrupted run of the same inputs and "
                   "config left next to --out (same result as an uninterrupted run).")
def command(growth_h5: str, config_path, overrides, out, overwrite, progress, resume) -> None:
    """Simulate the bloom of the petals in GROWTH_H5 and write the frames to sim.h5."""
    from pipeline import artifact, clean
    from pipeline.measure import PetalFrames
    from pipeline.sim import checkpoint
    from pipeline.sim import effects as fx
    from pipeline.sim.integrators import Diverged, make_integrator
    from pipeline.sim.model import Control, Model, State
    from pipeline.sim.quasistatic import NotConverged
    from pipeline.sim.run import run

    cfg = load(config_path, overrides)
    where = str(cfg.path) if cfg.path else "defaults"
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
        integrator = make_integrator(sim["integrator"], sim["eta"], sim["damping"],
                                     sim["speed_limit"], sim["stages"], sim["tolerance"],
                                     sim["substeps"], sim["inertia"])
        grown = model.edge_rest_length * (1.0 + np.maximum(model.edge_growth, 0.0))
        effects = fx.build(
            cfg.effects_enabled(), vertices=v, faces=src["mesh/faces"], petal=petal,
            pinned=base, on_axis=src["axis/on_axis"], plane=src["axis/plane"], s=src["axis/s"],
            rest_angle=src["growth/rest_angle"], flower_axis=src.attrs["flower_axis"],
            max_edge=float(grown.max()) if len(grown) else clean.mean_edge_length(v, src["mesh/faces"]),
            params=cfg.nested().get("effects", {}))
        state = State.at_rest(model, v, control)
        effects.constrain(state.forces)
        inputs = input_hashes(cfg, growth_h5)
        ckpt = checkpoint.path_for(out)
        key = checkpoint.fingerprint(cfg.to_json(), inputs)
        dynamic = sim["integrator"] != "quasi-static"  # its solver state is not checkpointed
        resumed = checkpoint.load(ckpt, key, state, effects) if resume and dynamic else None
        resumed_step = state.step
        if resumed is not None:
            log.info("resuming from step %d (%s)", state.step, ckpt)
        saver = _Saver(ckpt, key, effects, sim["checkpoint_seconds"] if dynamic else 0.0)
        log.info("%d vertices (%d fixed), %d springs, %d hinges; %d steps of h = %g, %d frames; "
                 "effects: %s", model.vertex_count, int(model.pinned.sum()), model.edge_count,
                 model.hinge_count, steps, h, frames, ", ".join(effects.names) or "none")
        if effects.connections is not None:
            log.info("%d connection springs between petals", len(effects.connections.pairs))
        with progress_bar(steps, "simulate", progress) as bar:
            try:
                try:
                    rec, wall = run(model, state, control, integrator, steps=steps,
                                    frames=frames, h=h, petals=petals, effects=effects,
                                    progress=bar.update, resume=resumed, checkpoint=saver)
                except (Diverged, NotConverged, ValueError, RuntimeError):
                    ckpt.unlink(missing_ok=True)  # a failed run's checkpoint would fail again
                    raise
            except Diverged as exc:
                if sim["substeps"]:  # a fixed substep: the step may simply be too large
                    raise BloomError(
                        f"simulate.h: the simulation {exc} (of {steps}, {sim['substeps']} "
                        "substep(s) each); likely cause: the time step is too large for the "
                        "stiffness; remedy: simulate.substeps = 0 (chosen from the stable "
                        "step), a smaller simulate.h, or simulate.integrator = quasi-static",
                        where=where) from None
                raise BloomError(
                    f"simulate.steps: the simulation {exc} (of {steps}); the substep was "
                    "already chosen from the stable step and halved after each divergence, "
                    "so the motion itself runs away; likely cause: growth too fast for the "
                    "steps, or vertices faster than simulate.speed_limit; remedy: more "
                    "simulate.steps, or simulate.integrator = quasi-static",
                    where=where) from None
            except NotConverged as exc:  # the cause, as the solver names it, picks the key
                name = f"petal {int(petal[exc.vertex])}" if len(petal) else "the mesh"
                if exc.cause == "weak":
                    raise BloomError(
                        f"axis.base_fraction: the quasi-static solver found {exc}; {name}'s base "
                        "is a line and it would spin about it; remedy: rerun bloom axis (it "
                        "widens such a base) or a larger axis.base_fraction", where=where) from None
                remedy = ("more simulate.stages, a larger simulate.tolerance, or a dynamic "
                          "integrator (it follows a snap)")
                if exc.growth == 0.0:  # growth has not started: not the growth curve's doing
                    remedy = "check the mesh (bloom inspect), or a dynamic integrator"
                raise BloomError(f"simulate.stages: the quasi-static solver found {exc} ({name}); "
                                 f"remedy: {remedy}", where=where) from None
            except ValueError as exc:  # what the integrator cannot do with this scene
                raise BloomError(f"simulate.integrator: {exc}", where=where) from None
            except RuntimeError as exc:
                key = getattr(exc, "key", None) or (  # (contact.ContactError names its key)
                    "effects.collisions" if "collision" in str(exc) else "simulate")
                raise BloomError(f"{key}: {exc}", where=where) from None
        diag = rec.arrays()
        positions = np.asarray(rec.positions)
        if not np.all(np.isfinite(positions)):
            ckpt.unlink(missing_ok=True)
            raise BloomError("the simulation diverged (non-finite positions); try a smaller "
                             "simulate.h or a smaller simulate.eta", where=where)
        tail = max(1, (frames - 1) // 10)
        opening = diag.get("opening_angle", np.zeros(frames))
        stepped = max(steps - resumed_step, 1)  # the steps this run took (after a resume)
        log.info("%.2f s (%.3f ms/step); opening %.1f deg, change over the last 10%% %.3f deg; "
                 "final kinetic energy %.3g, max speed %.3g", wall, 1e3 * wall / stepped,
                 opening[-1], opening[-1] - opening[-1 - tail], diag["kinetic_energy"][-1],
                 diag["max_speed"][-1])
        attrs = {"scale": src.attrs["scale"], "flower_axis": src.attrs["flower_axis"],
                 "steps": steps, "h": h,
                 "wall_seconds": wall, "ms_per_step": 1e3 * wall / stepped,
                 "effects": ",".join(effects.names),
                 "integrator": sim["integrator"]}
        if resumed is not None:  # then wall_seconds covers this run's steps only
            attrs["resumed_from_step"] = resumed_step
        with artifact.writing(out, stage="simulate", config_json=cfg.to_json(),
                              inputs=inputs, attrs=attrs, previous=src) as h5:
            src.copy_to(h5, ("mesh/faces", "mesh/petal", "axis/base", "axis/on_axis", "axis/x",
                             "axis/s", "axis/tip", "axis/plane", "growth/hinges"))
            artifact.put(h5, "frames/time", np.asarray(rec.time), "(T,) time of each frame")
            artifact.put(h5, "frames/positions", positions, "(T, V, 3) vertex positions")
            for name, values in diag.items():
                artifact.put(h5, f"diagnostics/{name}", values)
            if effects.connections is not None:
                c = effects.connections
                artifact.put(h5, "effects/connections/pairs", c.pairs,
                             "(C, 2) connected vertices, the first on the outer petal's rim")
                artifact.put(h5, "effects/connections/broken_step", c.broken_step,
                             "(C,) step at which each spring broke, -1 if intact")
    ckpt.unlink(missing_ok=True)
    log.info("wrote %s", out)


class _Saver:
    """Writes a checkpoint after a frame when ``every`` wall seconds have passed."""

    def __init__(self, path, key, effects, every: float):
        import time

        self.path, self.key, self.effects, self.every = path, key, effects, every
        self.clock = time.monotonic
        self.last = self.clock()

    def __call__(self, rec, state) -> None:
        if self.every > 0 and self.clock() - self.last >= self.every:
            from pipeline.sim import checkpoint

            checkpoint.save(self.path, self.key, state, self.effects, rec)
            self.last = self.clock()
