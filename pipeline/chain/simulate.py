"""The simulate stage: grow the petals and integrate (Eq. 6-8) -> sim.h5.

:func:`run` builds the model and the scene's effects from growth.h5
(:class:`pipeline.sim.build.Prepared`), finds the bud first for an open start
(:func:`pipeline.sim.reverse.open_start`), integrates frame by frame
(:func:`pipeline.sim.run.run`, checkpointing as it goes so that ``--resume`` continues
an interrupted run), and writes the frames and diagnostics. One problem's bloom (the
whole file, or each flower of a staggered file of many) is
:func:`pipeline.chain.problem.problem`; what the solver cannot do becomes one line
naming the key to change (:func:`pipeline.chain.problem.refusal`). What is decided for
the whole file (the flowers, the start, the effects) is decided here.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np

from pipeline import artifact
from pipeline.chain import carried_attrs, flowers, problem
from pipeline.config import Config
from pipeline.errors import BloomError
from pipeline.flower import stagger
from pipeline.flower.measure import Start, bloom_start, petals_within_reach
from pipeline.forks import workers
from pipeline.mesh.intersect import frame_intersections
from pipeline.review import report
from pipeline.sim import checkpoint
from pipeline.sim.build import Prepared
from pipeline.sim.reverse import petal_lengths
from pipeline.sim.terms.contact import own_spots

log = logging.getLogger("bloom")

#: a bud blooming forward of which a petal does not open (under report.NOT_OPEN) or lags
#: the others (report.lagging) is bloomed again with each petal held up to this s (every
#: vertex within it fixed), where the scene leaves the base to the defaults, and the bloom
#: where fewer petals lag is kept (the lotus: 2 of 16 lag, none held): the
#: closed tulip's bowl-shaped petals turn inward from the bowl's bottom under the rims'
#: growth (-3.3 deg on average, the least -9.7); held up to 0.35 every petal opens, the
#: least 14.5 deg (docs/performance.md). No measure of the model was found that tells
#: such a bowl from the default buds' (which open 60 deg on the default band), so it is a
#: second try, not a first choice
HOLD_BOWL = 0.35
#: the keys that, set by the scene, say how a petal is held (no second try then)
HOLD_KEYS = ("axis.base", "axis.base_fraction", "axis.base_region", "axis.base_band")

#: what the later stages need of growth.h5, carried forward
CARRIED = ("mesh/faces", "mesh/petal", "mesh/left", "mesh/part_names", "mesh/part", "axis/base",
           "axis/on_axis", "axis/x", "axis/s", "axis/tip", "axis/plane", "growth/hinges",
           "input/asset", "bind", "flower/petal_flower")


def run(growth_h5: str | Path, out: str | Path, cfg: Config, *, overwrite: bool = False,
        resume: bool = False, progress: bool | None = None) -> None:
    """Simulate the bloom of the petals in ``growth_h5`` and write the frames to ``out``.

    ``resume``: continue from the checkpoint an interrupted run of the same inputs and
    config left next to ``out``. ``progress``: a bar (default: when stderr is a
    terminal). A file of many flowers staggered in time blooms flower by flower, each a
    problem of its own (:func:`pipeline.chain.flowers.flowers_apart`): a flower that
    cannot bloom is kept as modelled, named in a warning and in the report, and the
    others bloom."""
    where = str(cfg.path) if cfg.path else "defaults"
    out = artifact.check_output(out, "simulate", overwrite)
    sim = cfg.section("simulate")
    steps, frames = sim["steps"], sim["frames"]
    with artifact.Artifact(growth_h5, needs="growth", reader="simulate") as src:
        prep = Prepared.from_artifact(src)
        v, petal = prep.vertices, prep.petal
        starts = decide_flowers(cfg, prep, stagger.flower_count(src), frames)
        start = decide_start(cfg, prep)
        names = decide_effects(cfg, prep)
        inputs = artifact.input_hashes(cfg, growth_h5)
        ckpt = checkpoint.path_for(out)
        model_positions = np.asarray(v) if start.start == "open" else None
        job = problem.Job(cfg, start, names, inputs, resume, progress, where)
        result = (problem.Result.of(problem.problem(prep, job, ckpt)) if prep.flower is None
                  else flowers.flowers_apart(prep, job, ckpt, starts))
        held = None
        if start.start == "bud" and prep.flower is None:
            prep, result, held = hold_bowls(cfg, prep, job, ckpt, result)
        v, positions, diag = result.bud, np.asarray(result.positions), result.diag
        bud_info, resumed, resumed_step, wall = (result.bud_info, result.resumed,
                                                 result.resumed_step, result.wall)
        if not np.all(np.isfinite(positions)):
            problem.unlink_checkpoints(ckpt)
            raise BloomError("the simulation diverged (non-finite positions); try a smaller "
                             "simulate.h or a smaller simulate.eta", where=where)
        tail = max(1, (frames - 1) // 10)
        opening = diag.get("opening_angle", np.zeros(frames))
        stepped = max(steps - resumed_step, 1)  # the steps this run took (after a resume)
        log.info("%.2f s (%.3f ms/step); opening %.1f deg, change over the last 10%% %.3f deg; "
                 "final kinetic energy %.3g, max speed %.3g", wall, 1e3 * wall / stepped,
                 opening[-1], opening[-1] - opening[-1 - tail], diag["kinetic_energy"][-1],
                 diag["max_speed"][-1])
        attrs = {**carried_attrs(src), "steps": steps, "h": sim["h"],
                 "wall_seconds": wall, "ms_per_step": 1e3 * wall / stepped,
                 "effects": ",".join(result.names),
                 "integrator": sim["integrator"], "fps": cfg["render.fps"]}
        if resumed is not None:  # then wall_seconds covers this run's steps only
            attrs["resumed_from_step"] = resumed_step
        attrs["growth_start"], attrs["growth_start_rule"] = start.start, start.reason
        if held is not None:
            attrs["base_held_to"] = held
        if result.solved_on is not None:  # (simulate.petal_vertices: the mesh cut finer)
            attrs["solved_on_vertices"] = result.solved_on
        if result.held:
            attrs["flowers_kept_as_modelled"] = np.asarray(result.held, dtype=np.int64)
        if result.stopped:  # a bloom held where no equilibrium was found past it
            attrs["bloom_stopped_at"] = min(a for a, _ in result.stopped)
            attrs["bloom_stopped_petals"] = np.asarray([p for _, p in result.stopped],
                                                       dtype=np.int64)
        if model_positions is not None:
            attrs["distance_to_model"] = result.distance
            attrs.update(bud_info)
            less = prep.bud_closed(v, model_positions)
            if less is not None:
                attrs["bud_closed"] = less
                log.info("the bud's petals lean %.1f deg less from the flower's axis than the "
                         "model's (median over petals)", less)
            log.info("last frame %.3g petal lengths (RMS) from the model",
                     attrs["distance_to_model"])
        names = report.petal_names(petal, src["mesh/part_names"], src["mesh/part"]) \
            if "mesh/part_names" in src and "mesh/part" in src else None
        if result.together is not None:  # (flowers that bloom together start together)
            starts = stagger.together(starts, result.together)
        seen = positions if starts is None else stagger.staggered(positions, prep.flower, starts)
        sound = report.soundness(positions, prep.faces,
                                 diag.get("opening_angle_per_petal", np.zeros((len(positions), 0))),
                                 distance_to_model=attrs.get("distance_to_model"),
                                 bud_closed=attrs.get("bud_closed"),
                                 petal_names=names, petal=petal, left=prep.left,
                                 intersecting=frame_intersections(
                                     seen, prep.faces, petal, prep.left,
                                     workers=workers(cfg["simulate.workers"])),
                                 held_flowers=result.held,
                                 stopped=attrs.get("bloom_stopped_at"),
                                 flower=src["flower/petal_flower"][:]
                                 if "flower/petal_flower" in src else None)
        diag["intersecting"] = np.asarray(sound["intersecting"], dtype=bool)
        attrs["summary"] = report.summary_line(sound)
        report.warn_not_opened(sound["not_opened"], lambda m: log.warning("%s", m))
        report.warn_lagging(sound, lambda m: log.warning("%s", m))
        (log.info if attrs["summary"].startswith("sound") else log.warning)("%s", attrs["summary"])
        with artifact.writing(out, stage="simulate", config_json=cfg.to_json(),
                              inputs=inputs, attrs=attrs, previous=src) as h5:
            solved = () if result.axes is None else ("axis/s", "axis/x")
            src.copy_to(h5, tuple(n for n in CARRIED if n not in solved
                                  and (held is None or n != "axis/base")))
            if result.axes is not None:  # (the mesh cut finer: its axes found there)
                artifact.put(h5, "axis/s", result.axes[0],
                             "(V,) distance from the base over the petal's length, as the "
                             "solve found it on the mesh cut finer (solved_on_vertices)")
                artifact.put(h5, "axis/x", result.axes[1],
                             "(V,) cross-section coordinate in [-1, 1], as the solve found "
                             "it on the mesh cut finer (solved_on_vertices)")
            if held is not None:
                artifact.put(h5, "axis/base", np.asarray(prep.base, dtype=bool),
                             f"(V,) fixed base vertices: every vertex within s = {held:g} "
                             "(a bud's petals held further, as the bloom was run)")
            artifact.put(h5, "frames/time", result.time, "(T,) time of each frame")
            artifact.put(h5, "frames/frame", np.arange(len(result.time), dtype=np.int64),
                         "(T,) frame number of each frame (growth.keys' frames; USD time codes)")
            artifact.put(h5, "frames/positions", positions, "(T, V, 3) vertex positions")
            if model_positions is not None:
                artifact.put(h5, "open/model", model_positions,
                             "(V, 3) the open model (the input mesh) the bloom ends on")
                artifact.put(h5, "open/bud", v, "(V, 3) the bud found from it (frame 0)")
            for name, values in diag.items():
                artifact.put(h5, f"diagnostics/{name}", values)
            if result.together is not None:
                artifact.put(h5, "flower/together", result.together,
                             "(K,) each flower's cluster (the first flower in it): flowers "
                             "that would pass through each other blooming apart, staggered, "
                             "start together, and bloom as one problem where that crosses "
                             "less")
            if result.connections is not None:
                c = result.connections
                artifact.put(h5, "effects/connections/pairs", c.pairs,
                             "(C, 2) connected vertices, the first on the outer petal's rim")
                artifact.put(h5, "effects/connections/broken_step", c.broken_step,
                             "(C,) step at which each spring broke, -1 if intact")
    problem.unlink_checkpoints(ckpt)
    log.info("wrote %s", out)


def hold_bowls(cfg: Config, prep: Prepared, job, ckpt: Path, result):
    """A bud's bloom of which some petals did not open or lag the others
    (:func:`~pipeline.review.report.lagging`), tried again with each petal held up to
    :data:`HOLD_BOWL` of its length (unless the scene sets how petals are held,
    :data:`HOLD_KEYS`): ``(prep, result, held)``, the second bloom's (``held`` the s it
    holds to) where fewer of its petals lag and no more frames have an intersection, else
    the first's (``held`` None), its wall seconds those of both. Logged."""
    opening = result.diag.get("opening_angle_per_petal")
    if opening is None or any(key in cfg.given for key in HOLD_KEYS):
        return prep, result, None
    def behind(opening) -> int:  # petals shut or lagging at the last frame
        return int(np.sum(report.lagging(np.asarray(opening)[-1])))

    shut = behind(opening)
    if shut == 0:
        return prep, result, None
    wider = _spots_whole(cfg, prep, job.names, prep.base | (np.asarray(prep.s) <= HOLD_BOWL))
    if np.array_equal(wider, prep.base):
        return prep, result, None
    final = np.asarray(opening)[-1]
    log.info("%d of %d petals did not open or lag the others (under %g deg, or under %g of "
             "the median %.1f deg; the least %.1f): blooming again with each held up to "
             "s = %g (the bottom of a bowl-shaped petal can turn inward under the rims' "
             "growth, a petal be caught under its neighbour; axis.base_band sets it)", shut,
             len(final), report.NOT_OPEN, report.LAGS, float(np.median(final)),
             float(final.min()), HOLD_BOWL)
    held = dataclasses.replace(prep, base=wider, held=HOLD_BOWL)
    again_job = dataclasses.replace(job, inputs={**job.inputs, "base held to": HOLD_BOWL})
    try:
        again = problem.Result.of(problem.problem(held, again_job,
                                                  ckpt.with_name(ckpt.name + "-held")))
    except BloomError as exc:  # (the first bloom stands)
        log.info("held up to s = %g: no bloom (%s): the first bloom kept", HOLD_BOWL, exc)
        return prep, result, None
    opened = again.diag.get("opening_angle_per_petal")
    still = behind(opened) if opened is not None else shut
    both = result.wall + again.wall  # (the seconds the stage spent: both blooms)

    def crossed(bloom) -> int:  # frames with an intersection (report.soundness's test)
        return int(sum(frame_intersections(bloom.positions, prep.faces, prep.petal,
                                           prep.left)))

    worse = crossed(again) if still < shut else 0
    if worse and worse > crossed(result):  # (an intersection is worse than a lagging petal)
        log.info("held up to s = %g: %d of them lag (%d before), but %d frame(s) with an "
                 "intersection: the first bloom kept", HOLD_BOWL, still, shut, worse)
        return prep, dataclasses.replace(result, wall=both), None
    if still < shut:
        log.info("held up to s = %g: %d of them lag (%d before): that bloom kept",
                 HOLD_BOWL, still, shut)
        return held, dataclasses.replace(again, wall=both), HOLD_BOWL
    log.info("held up to s = %g: %d lag (%d before): the first bloom kept",
             HOLD_BOWL, still, shut)
    return prep, dataclasses.replace(result, wall=both), None


def _spots_whole(cfg: Config, prep: Prepared, names, held: np.ndarray) -> np.ndarray:
    """``held`` (``(V,)`` bool, the vertices a second try holds) with every spot the
    contact leaves to itself (a petal's own triangles that start within the barrier's
    reach of each other: :func:`~pipeline.sim.terms.contact.own_spots`) that it holds in
    part held whole: held in part, the free side of such a spot folds through the held
    side with nothing to stop it (the lotus's petal 2, a rim hairpin across s = 0.35,
    in one frame). Logged where it holds more."""
    if "collisions" not in names or cfg["simulate.integrator"] != "quasi-static":
        return held
    faces = prep.faces if prep.contact_faces is None else prep.contact_faces
    count = int(np.max(faces)) + 1
    spot = np.full(len(held), -1, dtype=np.int64)
    spot[:count] = own_spots(np.asarray(prep.vertices)[:count], faces,
                             np.asarray(prep.petal)[:count], prep.contact_gap(cfg), prep.left)
    inside = spot >= 0
    cut = np.intersect1d(spot[inside & held], spot[inside & ~held])
    if not len(cut):
        return held
    whole = held | np.isin(spot, cut)
    log.info("held up to s = %g: %d vertices more, of %d spot(s) the contact leaves to "
             "themselves (a rim's hairpin) that the hold would cut: each held whole",
             HOLD_BOWL, int(whole.sum() - held.sum()), len(cut))
    return whole


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
                            prep.x, prep.on_axis, prep.flower_axis, recurve=prep.recurve)
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
        if prep.left is not None:  # (petals left through each other as modelled: no contact)
            left = {(min(a, b), max(a, b)) for a, b in np.asarray(prep.left).tolist()}
            pairs = [pair for pair in pairs if (min(pair), max(pair)) not in left]
        if pairs:
            names.append("collisions")
            log.info("effects.collisions.enabled = auto: on (%d pair(s) of %d petals can meet)",
                     len(pairs), count)
        else:
            log.info("effects.collisions.enabled = auto: off (%s)",
                     "a lone petal" if count == 1 else f"none of the {count} petals can meet")
    return sorted(names)
