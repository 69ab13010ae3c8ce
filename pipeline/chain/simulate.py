"""The simulate stage: grow the petals and integrate (Eq. 6-8) -> sim.h5.

:func:`run` builds the model and the scene's effects from growth.h5
(:class:`pipeline.sim.build.Prepared`), finds the bud first for an open start
(:func:`pipeline.sim.reverse.open_start`), integrates frame by frame
(:func:`pipeline.sim.run.run`, checkpointing as it goes so that ``--resume`` continues
an interrupted run), and writes the frames and diagnostics. What the solver cannot do
becomes one line naming the key to change (:func:`_refusal`).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline import artifact
from pipeline.chain import carried_attrs
from pipeline.config import KEYS, Config
from pipeline.errors import BloomError
from pipeline.flower import stagger
from pipeline.flower.measure import Start, bloom_start, leans, petals_within_reach
from pipeline.mesh.separate import patch_groups
from pipeline.progress import Progress
from pipeline.review import report
from pipeline.sim import checkpoint
from pipeline.sim.build import Prepared
from pipeline.sim.effects import Params
from pipeline.sim.explicit.semi_implicit import Diverged
from pipeline.sim.integrators import make_integrator
from pipeline.sim.model import Control, State
from pipeline.sim.reverse import distance_to_model, open_start, petal_lengths, retrace
from pipeline.sim.run import run as integrate
from pipeline.sim.solver.newton import NotConverged
from pipeline.sim.terms.contact import frame_intersections

log = logging.getLogger("bloom")

#: what the later stages need of growth.h5, carried forward
CARRIED = ("mesh/faces", "mesh/petal", "mesh/patch", "mesh/part_names", "mesh/part", "axis/base",
           "axis/on_axis", "axis/x", "axis/s", "axis/tip", "axis/plane", "growth/hinges",
           "input/asset", "bind", "flower/petal_flower")


def run(growth_h5: str | Path, out: str | Path, cfg: Config, *, overwrite: bool = False,
        resume: bool = False, progress: bool | None = None) -> None:
    """Simulate the bloom of the petals in ``growth_h5`` and write the frames to ``out``.

    ``resume``: continue from the checkpoint an interrupted run of the same inputs and
    config left next to ``out``. ``progress``: a bar (default: when stderr is a
    terminal)."""
    where = str(cfg.path) if cfg.path else "defaults"
    out = artifact.check_output(out, "simulate", overwrite)
    sim = cfg.section("simulate")
    steps, frames, h = sim["steps"], sim["frames"], sim["h"]
    with artifact.Artifact(growth_h5, needs="growth", reader="simulate") as src:
        prep = Prepared.from_artifact(src)
        v, petal, base = prep.vertices, prep.petal, prep.base
        shell = sim["model"] == "shell"
        starts = decide_flowers(cfg, prep, stagger.flower_count(src), frames)
        start = decide_start(cfg, prep)
        try:
            if shell:
                modulus, thickness = shell_moduli(cfg)
                model = prep.shell_model(modulus, thickness, sim["poisson"], sim["mass"])
            else:
                model = prep.model(sim["stretch_stiffness"], sim["bending_stiffness"],
                                   sim["mass"])
        except ValueError as exc:
            raise BloomError(f"cannot build the model: {exc}", where=growth_h5) from None
        params = Params.of(cfg)
        if shell:  # the contact gap in units of the petal (mesh units shrink as the mesh is
            # refined)
            params = params.but(collisions={
                "thickness": cfg["effects.collisions.gap"] * model.shell.size})
        rest_angle = prep.rest_angle
        max_edge = prep.max_grown_edge()  # once: the bud search changes the model's rest lengths
        names = decide_effects(cfg, prep)

        def build_effects(positions):
            return prep.effects(names, params, positions=positions, rest_angle=rest_angle,
                                max_edge=max_edge,
                                pushback=sim["integrator"] != "quasi-static")

        inputs = artifact.input_hashes(cfg, growth_h5)
        ckpt = checkpoint.path_for(out)
        model_positions = np.asarray(v) if start.start == "open" else None
        bud_model, bud_angle, bud_params = model, rest_angle, params

        axes = prep.petal_axes()

        def closed_by(bud) -> float:
            """How much more closed ``bud`` is than the model: the mean over petals of
            the opening angle's change (deg)."""
            frames_ = prep.frames(bud).opening_toward(model_positions)
            return float(np.mean(np.abs(frames_.opening_angles(model_positions))))

        def leans_less(bud) -> float | None:
            """In a flower, how much less ``bud``'s petals lean from their flower's axis
            than the model's (deg, the mean over petals; negative: they lean further,
            hanging open the other way, and the bloom closes them); None for a lone petal."""
            if not np.all(np.isfinite(axes)):
                return None
            return float(np.mean(leans(model_positions, petal, base, prep.tip, axes)
                                 - leans(bud, petal, base, prep.tip, axes)))

        def bloom(lifted: bool) -> _Bloom:
            """The run from the bud (an open start: found with the closing lift or
            without, :func:`~pipeline.sim.reverse.open_start`), resumed from its checkpoint
            if asked (each search its own)."""
            v0, model, rest_angle, params, bud_info = v, bud_model, bud_angle, bud_params, {}
            if model_positions is not None:
                v0, model, rest_angle, params, bud_info = open_start(
                    cfg, model, model_positions, rest_angle, params, build_effects, petal,
                    base, prep.s, prep.x, prep.flower_axis, where, faces=prep.faces,
                    plane=prep.plane, lifted=lifted, closed_by=closed_by)
            petals = prep.frames(v0)
            if model_positions is not None:  # the model is the open flower: it says which way is out
                petals = petals.opening_toward(model_positions)
            if cfg["growth.keys"]:
                control = Control.keyed(cfg["growth.keys"], frames, steps, h)
            else:
                control = Control(cfg["growth.schedule"], cfg["growth.ramp"] * steps * h)
            def fresh_integrator():
                made = make_integrator(sim["integrator"], sim["eta"], sim["damping"],
                                       sim["speed_limit"], sim["stages"], sim["tolerance"],
                                       sim["substeps"], sim["inertia"])
                if hasattr(made, "petal"):  # (it names the petal of each rescue in the log)
                    made.petal = np.asarray(petal)
                return made

            integrator = fresh_integrator()
            if shell and model_positions is not None:  # (the found bud breaks the symmetry)
                integrator.perturbation = 0.0
            elif shell and hasattr(integrator, "nudge") and sim["imperfection"] > 0.0:
                # a bud that is not perfectly symmetric, the same at any resolution, from the
                # first growth on (a random nudge per vertex picks a branch per mesh)
                integrator.nudge = prep.imperfection(sim["imperfection"])
            effects = build_effects(v0)
            state = State.at_rest(model, v0, control)
            effects.constrain(state.forces)
            path = ckpt if lifted else ckpt.with_name(ckpt.name + "-unlifted")
            key = checkpoint.fingerprint(cfg.to_json(),
                                         inputs if lifted else {**inputs, "bud search": "own path"})
            resumed = (checkpoint.load(path, key, state, effects, integrator, model) if resume
                       else None)
            resumed_step = state.step
            if resumed is not None:
                log.info("resuming from step %d (%s)", state.step, path)
            saver = _Saver(path, key, effects, integrator, sim["checkpoint_seconds"])
            log.info("%d vertices (%d fixed), %d springs, %d hinges; %d steps of h = %g, %d "
                     "frames; effects: %s", model.vertex_count, int(model.pinned.sum()),
                     model.edge_count, model.hinge_count, steps, h, frames,
                     ", ".join(effects.names) or "none")
            if effects.connections is not None:
                log.info("%d connection springs between petals", len(effects.connections.pairs))
            failed = None
            with Progress(steps, "simulate", progress) as bar:
                try:
                    rec, wall = integrate(model, state, control, integrator, steps=steps,
                                          frames=frames, h=h, petals=petals, effects=effects,
                                          progress=bar.update, resume=resumed,
                                          checkpoint=saver)
                except (Diverged, NotConverged, ValueError, RuntimeError) as exc:
                    path.unlink(missing_ok=True)  # a failed run's checkpoint would fail again
                    if not (isinstance(exc, NotConverged) and model_positions is not None
                            and sim["integrator"] == "quasi-static"):
                        raise _refusal(exc, sim, steps, petal, where) from None
                    failed = exc
            if failed is not None:  # an open model: its own path, from the model to a bud
                log.warning("the bloom from the bud found no equilibrium at A = %.4g (petal "
                            "%d): the path forward leaves the branch the bud is on; the bloom "
                            "is the model's own path to its bud, played forward (every frame "
                            "an equilibrium at its growth)", failed.growth,
                            int(petal[failed.vertex]))
                integrator = fresh_integrator()  # (its nudge at the start, as the search's)
                effects = build_effects(model_positions)
                with Progress(steps, "simulate (the path back)", progress) as bar:
                    try:
                        rec, wall = retrace(
                            model, model_positions, control, integrator, effects, steps=steps,
                            frames=frames, h=h, progress=bar.update,
                            petals_at=lambda bud: prep.frames(bud).opening_toward(model_positions))
                    except (Diverged, NotConverged, ValueError, RuntimeError) as exc:
                        raise _refusal(exc, sim, steps, petal, where) from None
                v0 = np.asarray(rec.positions[0])
                bud_info = {**bud_info, "bud_path": "own", "bloom_path": "retraced",
                            "bud_distance": distance_to_model(v0, model_positions, petal,
                                                              base)}
            distance = (None if model_positions is None else
                        distance_to_model(np.asarray(rec.positions[-1]), model_positions,
                                          petal, base))
            return _Bloom(v0, bud_info, effects, rec, wall, resumed, resumed_step, distance)

        run_ = bloom(lifted=True)
        if (run_.distance is not None and run_.distance > report.OFF_MODEL
                and sim["integrator"] == "quasi-static" and run_.bud_info["bud_path"] == "lifted"):
            # the forward path from the bud the lift picked lands on another equilibrium:
            # the model's own path back (no lift) may lead to a bud that returns to it
            log.warning("the bloom ends %.3g petal lengths (RMS) from the model (over %g): "
                        "its bud is on another branch; searching again along the model's own "
                        "path (no closing lift)", run_.distance, report.OFF_MODEL)
            try:
                other = bloom(lifted=False)
            except BloomError as exc:
                log.warning("no bud without the lift: %s", exc)
            else:
                better = other.distance < run_.distance
                log.info("without the lift the bloom ends %.3g petal lengths from the model: "
                         "%s", other.distance, "kept" if better else "the first one kept")
                if better:
                    run_ = other
        v, bud_info, effects, rec, wall = run_.bud, run_.bud_info, run_.effects, run_.rec, run_.wall
        resumed, resumed_step = run_.resumed, run_.resumed_step
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
        attrs = {**carried_attrs(src), "steps": steps, "h": h,
                 "wall_seconds": wall, "ms_per_step": 1e3 * wall / stepped,
                 "effects": ",".join(effects.names),
                 "integrator": sim["integrator"], "fps": cfg["render.fps"]}
        if resumed is not None:  # then wall_seconds covers this run's steps only
            attrs["resumed_from_step"] = resumed_step
        attrs["growth_start"], attrs["growth_start_rule"] = start.start, start.reason
        if model_positions is not None:
            attrs["distance_to_model"] = run_.distance
            attrs.update(bud_info)
            less = leans_less(v)
            if less is not None:
                attrs["bud_closed"] = less
                log.info("the bud's petals lean %.1f deg less from the flower's axis than the "
                         "model's (mean over petals)", less)
            log.info("last frame %.3g petal lengths (RMS) from the model",
                     attrs["distance_to_model"])
        names = report.petal_names(petal, src["mesh/part_names"], src["mesh/part"]) \
            if "mesh/part_names" in src and "mesh/part" in src else None
        seen = positions if starts is None else stagger.staggered(positions, prep.flower, starts)
        sound = report.soundness(positions, prep.faces,
                                 diag.get("opening_angle_per_petal", np.zeros((len(positions), 0))),
                                 distance_to_model=attrs.get("distance_to_model"),
                                 bud_closed=attrs.get("bud_closed"),
                                 petal_names=names, petal=petal, patch=prep.patch,
                                 intersecting=frame_intersections(seen, prep.faces, petal,
                                                                  prep.patch))
        diag["intersecting"] = np.asarray(sound["intersecting"], dtype=bool)
        attrs["summary"] = report.summary_line(sound)
        for p in sound["not_opened"]:
            log.warning("%s did not open: %+.1f deg at the end (under %g deg)", p["name"],
                        p["opening"], report.NOT_OPEN)
        (log.info if attrs["summary"].startswith("sound") else log.warning)("%s", attrs["summary"])
        with artifact.writing(out, stage="simulate", config_json=cfg.to_json(),
                              inputs=inputs, attrs=attrs, previous=src) as h5:
            src.copy_to(h5, CARRIED)
            artifact.put(h5, "frames/time", np.asarray(rec.time), "(T,) time of each frame")
            artifact.put(h5, "frames/frame", np.arange(len(rec.time), dtype=np.int64),
                         "(T,) frame number of each frame (growth.keys' frames; USD time codes)")
            artifact.put(h5, "frames/positions", positions, "(T, V, 3) vertex positions")
            if model_positions is not None:
                artifact.put(h5, "open/model", model_positions,
                             "(V, 3) the open model (the input mesh) the bloom ends on")
                artifact.put(h5, "open/bud", v, "(V, 3) the bud found from it (frame 0)")
            for name, values in diag.items():
                artifact.put(h5, f"diagnostics/{name}", values)
            if effects.connections is not None:
                c = effects.connections
                artifact.put(h5, "effects/connections/pairs", c.pairs,
                             "(C, 2) connected vertices, the first on the outer petal's rim")
                artifact.put(h5, "effects/connections/broken_step", c.broken_step,
                             "(C,) step at which each spring broke, -1 if intact")
    ckpt.unlink(missing_ok=True)
    ckpt.with_name(ckpt.name + "-unlifted").unlink(missing_ok=True)
    log.info("wrote %s", out)


def shell_moduli(cfg: Config) -> tuple[float, float]:
    """The shell's ``(stretch_modulus, thickness)``: the scene's, or, where it sets the
    paper's ``K_s``/``K_b`` (``simulate.stretch_stiffness``, ``bending_stiffness``) and not
    these, the shell's defaults scaled as those springs are from their defaults: ``K_s``
    times ``c`` stretches ``c`` times as hard, ``K_b`` times ``c`` bends ``c`` times as hard
    (bending ~ ``Y t^2``: the thickness times ``sqrt(c / c_s)``). A scene made for the
    springs keeps its meaning (the plum's stiffer ``K_b`` is a thicker shell). Logged."""
    sim = cfg.section("simulate")
    paper = [k for k in ("stretch_stiffness", "bending_stiffness")
             if f"simulate.{k}" in cfg.given]
    if not paper or any(f"simulate.{k}" in cfg.given for k in ("stretch_modulus", "thickness")):
        return sim["stretch_modulus"], sim["thickness"]
    stretch = sim["stretch_stiffness"] / KEYS["simulate.stretch_stiffness"].default
    bend = sim["bending_stiffness"] / KEYS["simulate.bending_stiffness"].default
    modulus = sim["stretch_modulus"] * stretch
    thickness = sim["thickness"] * float(np.sqrt(bend / stretch))
    log.info("simulate.model = shell: %s scale the shell's defaults: stretch_modulus %.4g, "
             "thickness %.4g", ", ".join(f"simulate.{k} = {sim[k]:g}" for k in paper),
             modulus, thickness)
    return modulus, thickness


def decide_flowers(cfg: Config, prep: Prepared, flowers: int, frames: int):
    """A file of many flowers: staggered (``scene.stagger``), they bloom as problems
    apart (``prep.flower`` kept: each flower's contact among its own petals); all
    together, as one problem (``prep.flower`` None). Returns the start frames the frames'
    check staggers the run by, or None; logged in one line."""
    spread = stagger.spread(cfg, flowers, frames)
    if flowers <= 1 or spread <= 0:
        if flowers > 1:
            log.info("scene.stagger = 0: the %d flowers bloom together, as one problem "
                     "(contact between flowers too)", flowers)
        prep.flower = None
        return None
    starts = stagger.start_frames(flowers, spread, cfg["scene.stagger_seed"])
    log.info("scene.stagger = %s: the %d flowers start over %d frames (the render and the "
             "export stagger them); each blooms as a problem of its own, with contact among "
             "its own petals", cfg["scene.stagger"], flowers, spread)
    return starts


def decide_start(cfg: Config, prep: Prepared) -> Start:
    """``growth.start``: as the scene says, or (``auto``) decided from the model
    (:func:`pipeline.flower.measure.bloom_start`), logged in one line. A scene with
    connection springs is a bud (its lock holds a bud)."""
    said = cfg["growth.start"]
    if said != "auto":
        return Start(said, float("nan"), "set by growth.start")
    if cfg["effects.connections.enabled"] is True:
        start = Start("bud", float("nan"), "connection springs hold a bud")
    else:
        start = bloom_start(prep.vertices, prep.faces, prep.petal, prep.base, prep.tip, prep.s,
                            prep.x, prep.on_axis, prep.flower_axis)
    what = ("Bloom finds the bud it grew from and blooms back to the model"
            if start.start == "open" else "it blooms forward from the model")
    log.info("growth.start = auto: %s (%s): %s", start.start, start.reason, what)
    return start


def decide_effects(cfg: Config, prep: Prepared) -> list[str]:
    """The effects that run: those the scene turns on, and those it leaves to ``auto``
    decided from the model (collisions: on where two petals can meet,
    :func:`pipeline.flower.measure.petals_within_reach`), logged."""
    names = list(cfg.effects_enabled())
    if "collisions" in cfg.effects_auto():
        pairs = petals_within_reach(prep.vertices, prep.petal,
                                    petal_lengths(prep.vertices, prep.petal, prep.base))
        count = int(prep.petal.max()) + 1
        if prep.flower is not None:  # (flowers apart: contact within each flower only)
            of = np.zeros(count, dtype=np.int64)
            of[prep.petal] = prep.flower
            pairs = [(a, b) for a, b in pairs if of[a] == of[b]]
        if prep.patch is not None:  # (petals left through each other as modelled: no contact)
            together = {(a, b) for g in patch_groups(prep.petal, prep.patch)
                        for i, a in enumerate(g) for b in g[i + 1:]}
            pairs = [pair for pair in pairs if pair not in together]
        if pairs:
            names.append("collisions")
            log.info("effects.collisions.enabled = auto: on (%d pair(s) of %d petals can meet)",
                     len(pairs), count)
        else:
            log.info("effects.collisions.enabled = auto: off (%s)",
                     "a lone petal" if count == 1 else f"none of the {count} petals can meet")
    return sorted(names)


def _refusal(exc: Exception, sim: dict, steps: int, petal, where: str) -> BloomError:
    """What the integrator could not do, as one line naming the key to change."""
    if isinstance(exc, Diverged):
        if sim["substeps"]:  # a fixed substep: the step may simply be too large
            return BloomError(
                f"simulate.h: the simulation {exc} (of {steps}, {sim['substeps']} "
                "substep(s) each); likely cause: the time step is too large for the "
                "stiffness; remedy: simulate.substeps = 0 (chosen from the stable "
                "step), a smaller simulate.h, or simulate.integrator = quasi-static",
                where=where)
        return BloomError(
            f"simulate.steps: the simulation {exc} (of {steps}); the substep was "
            "already chosen from the stable step and halved after each divergence, "
            "so the motion itself runs away; likely cause: growth too fast for the "
            "steps, or vertices faster than simulate.speed_limit; remedy: more "
            "simulate.steps, or simulate.integrator = quasi-static", where=where)
    if isinstance(exc, NotConverged):  # the cause, as the solver names it, picks the key
        name = f"petal {int(petal[exc.vertex])}" if len(petal) else "the mesh"
        if exc.cause == "weak":
            return BloomError(
                f"axis.base_fraction: the quasi-static solver found {exc}; {name}'s base "
                "is a line and it would spin about it; remedy: rerun bloom axis (it "
                "widens such a base) or a larger axis.base_fraction", where=where)
        remedy = ("more simulate.stages, a larger simulate.tolerance, or a dynamic "
                  "integrator (it follows a snap)")
        if exc.growth == 0.0:  # growth has not started: not the growth curve's doing
            remedy = "check the mesh (bloom inspect), or a dynamic integrator"
        return BloomError(f"simulate.stages: the quasi-static solver found {exc} ({name}); "
                          f"remedy: {remedy}", where=where)
    if isinstance(exc, ValueError):  # what the integrator cannot do with this scene
        return BloomError(f"simulate.integrator: {exc}", where=where)
    key = getattr(exc, "key", None) or (  # (contact.ContactError names its key)
        "effects.collisions" if "collision" in str(exc) else "simulate")
    return BloomError(f"{key}: {exc}", where=where)


@dataclass
class _Bloom:
    """One run of :func:`run`'s: its bud, the bud search's figures, the effects, the
    frames, wall seconds, the checkpoint it resumed from and the last frame's distance
    to the model (an open start; else None)."""

    bud: np.ndarray
    bud_info: dict
    effects: object
    rec: object
    wall: float
    resumed: object
    resumed_step: int
    distance: float | None


class _Saver:
    """Writes a checkpoint after a frame when ``every`` wall seconds have passed: the
    state, the effects' arrays, the frames so far and the integrator's own state (the
    quasi-static solver's path and factorizations)."""

    def __init__(self, path, key, effects, integrator, every: float):
        self.path, self.key, self.effects, self.every = path, key, effects, every
        self.integrator = integrator
        self.clock = time.monotonic
        self.last = self.clock()

    def __call__(self, rec, state) -> None:
        if self.every > 0 and self.clock() - self.last >= self.every:
            checkpoint.save(self.path, self.key, state, self.effects, rec, self.integrator)
            self.last = self.clock()
