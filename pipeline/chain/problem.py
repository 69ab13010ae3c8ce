"""One bloom problem of the simulate stage (:mod:`pipeline.chain.simulate`): a whole
file, or one flower of a file of many (:func:`problem`; a file's flowers are put together
in :mod:`pipeline.chain.flowers`); the solver's failures as one line naming the key
(:func:`refusal`); the checkpoints a run writes as it goes (:class:`Saver`).

The module is long because one problem's bloom is one sequence of fallbacks (the run
from the bud; the model's own path back where that fails or closes first; its most
closed frame; the search without the lift where the bloom ends off the model), which
share the closures that build the run's effects, integrator and petal frames."""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.chain.axis import axis_options
from pipeline.config import KEYS, Config
from pipeline.errors import BloomError
from pipeline.flower.growth import growth_rule
from pipeline.flower.measure import Start
from pipeline.progress import Progress, doing
from pipeline.review import report
from pipeline.sim import checkpoint, reverse
from pipeline.sim.build import Prepared
from pipeline.sim.effects import Params
from pipeline.sim.explicit.semi_implicit import Diverged
from pipeline.sim.integrators import make_integrator
from pipeline.sim.model import Control, State
from pipeline.sim.reverse import distance_to_model, open_start, retrace
from pipeline.sim.run import Recording, hold_first, hold_last
from pipeline.sim.run import run as integrate
from pipeline.sim.solver.newton import NotConverged

log = logging.getLogger("bloom")


@dataclass
class Job:
    """What every problem of a run shares: the config, the start and effects decided for
    the whole file, the inputs' hashes (the checkpoints' key), whether to resume and show
    a bar, and the config's name for messages."""

    cfg: Config
    start: Start
    names: list
    inputs: dict
    resume: bool
    progress: bool | None
    where: str
    #: the most vertices a solve cut finer may have (None: ``simulate.max_vertices``; a
    #: file of many flowers: their share of ``simulate.file_vertices``, or fewer)
    max_vertices: int | None = None


@dataclass
class Result:
    """A run's bloom, whole or put together from its flowers: the bud (frame 0's start),
    the bud search's figures, the effects' names and connection springs, the frames'
    times, positions and diagnostics, wall seconds, the checkpoint it resumed from, the
    last frame's distance to the model (an open start) and the flowers kept as
    modelled."""

    bud: np.ndarray
    bud_info: dict
    names: list
    connections: object
    time: np.ndarray
    positions: np.ndarray
    diag: dict
    wall: float
    resumed: object
    resumed_step: int
    distance: float | None
    held: list = field(default_factory=list)
    stopped: list = field(default_factory=list)  #: (growth reached, petal) per bloom held
    #: a file of many flowers: ``(K,)`` each flower's problem, the first flower in it
    #: (flowers that bloom together start together), or None: each its own
    together: np.ndarray | None = None
    #: the vertices of the mesh it was solved on, where that was cut finer (else None)
    solved_on: int | None = None
    #: where it was cut finer: ``(s, x)`` of the mesh's own vertices as the solve found
    #: them on the finer mesh (else None: the axis stage's)
    axes: tuple | None = None

    @classmethod
    def of(cls, run: Bloom) -> Result:
        """The bloom of a whole file, one problem."""
        return cls(run.bud, run.bud_info, run.effects.names, run.effects.connections,
                   np.asarray(run.rec.time), np.asarray(run.rec.positions), run.rec.arrays(),
                   run.wall, run.resumed, run.resumed_step, run.distance,
                   stopped=[run.stopped] if run.stopped else [], solved_on=run.solved_on,
                   axes=run.axes)


def unlink_checkpoints(ckpt: Path) -> None:
    """The run's checkpoints: the whole run's, the search without the lift's, each
    flower's."""
    for path in [ckpt, *ckpt.parent.glob(ckpt.name + "-*")]:
        path.unlink(missing_ok=True)


#: an open start's checkpoint for each path to the bud (:data:`~pipeline.sim.reverse.PATHS`):
#: its name's suffix, and what its fingerprint adds to the inputs
CHECKPOINTS = {"lifted": "", "own": "-unlifted", "faded": "-faded"}
SEARCHES = {"lifted": {}, "own": {"bud search": "own path"},
            "faded": {"bud search": "own path, the lift faded"}}

#: the most times a mesh is cut finer for the solve (each time four times the faces)
MAX_LEVELS = 3


def levels_for(prep: Prepared, cfg: Config, most: int | None = None) -> int:
    """How many times the shell's solve cuts ``prep`` finer (:meth:`Prepared.refined`):
    until its median petal holds ``simulate.petal_vertices`` (each cut about four times
    the vertices), at most :data:`MAX_LEVELS` and ``most`` (default
    ``simulate.max_vertices``) in all; 0 for
    the paper's springs (their energy is the triangles': a finer mesh is another
    material) and the dynamic integrators (their push-back is on every vertex: the
    coarse mesh's contact, :attr:`Prepared.contact_faces`, is the quasi-static
    solver's)."""
    want = cfg["simulate.petal_vertices"]
    most = cfg["simulate.max_vertices"] if most is None else most
    if (cfg["simulate.model"] != "shell" or cfg["simulate.integrator"] != "quasi-static"
            or want <= 0 or len(prep.vertices) == 0):
        return 0
    n = float(np.median(np.bincount(np.asarray(prep.petal))[np.unique(prep.petal)]))
    total = float(len(prep.vertices))
    levels = 0
    while n < want and levels < MAX_LEVELS and 4.0 * total <= most:
        n, total, levels = 4.0 * n, 4.0 * total, levels + 1
    return levels


def problem(prep: Prepared, job: Job, ckpt: Path, label: str = "") -> Bloom:
    """One problem's bloom (a whole file, or one flower of many), solved on ``prep`` cut
    finer where its petals are coarser than ``simulate.petal_vertices`` (:func:`levels_for`;
    the bloom's frames then those of ``prep``'s own vertices)."""
    levels = levels_for(prep, job.cfg, job.max_vertices)
    if levels == 0:
        return _problem(prep, job, ckpt, label)
    cfg = job.cfg

    def made(key: str):  # (the axes and growth as their stages made them: their keys as
        # growth.h5 records them, where it does)
        return prep.recorded[key] if key in prep.recorded else cfg[key]

    fine = prep.refined(levels, growth_rule(made), axes=axis_options(made))
    log.info("simulate.petal_vertices = %d: %s solved on a mesh cut %d time(s) finer (%d "
             "vertices for %d), its frames those of its own vertices",
             cfg["simulate.petal_vertices"], label or "the bloom", levels, len(fine.vertices),
             len(prep.vertices))
    try:
        run = _problem(fine, job, ckpt, label)
    except BloomError as exc:
        run, fault = None, f"was refused ({exc.args[0] if exc.args else exc})"
    else:
        if run.stopped is None:
            return run.coarse(prep, fine)
        fault = f"stops at A = {run.stopped[0]:.4g} (petal {run.stopped[1]})"
    # Contact keeps the user's own triangles apart, and on the finer mesh it pushes on
    # their vertices only: where petals press hard, a few fine triangles around such a
    # vertex take the whole push and collapse (a bud remeshed to 200 vertices a petal
    # stopped at A = 0.35 so, where its own mesh blooms to the end)
    log.warning("%s cut finer %s: solved again on the mesh as it is", label or "the bloom",
                fault)
    again = _problem(prep, job, ckpt.with_name(ckpt.name + "-as-is"), label)
    if run is None or again.stopped is None or again.stopped[0] >= run.stopped[0]:
        return again
    log.warning("%s as it is stops earlier (A = %.4g): the bloom cut finer is kept",
                label or "the bloom", again.stopped[0])
    return run.coarse(prep, fine)


def _problem(prep: Prepared, job: Job, ckpt: Path, label: str = "") -> Bloom:
    """One problem's bloom on ``prep`` as it is: the model and effects built, the bud
    found for an open start (and searched again along the model's own path where the
    bloom ends off the model: without the lift, then with it faded, :data:`~pipeline.sim.
    reverse.PATHS`), integrated; the solver's failures as one line naming the key
    (:class:`BloomError`)."""
    cfg, start, where, progress = job.cfg, job.start, job.where, job.progress
    sim = cfg.section("simulate")
    steps, frames, h = sim["steps"], sim["frames"], sim["h"]
    v, petal, base = prep.vertices, prep.petal, prep.base
    shell = sim["model"] == "shell"
    try:
        if shell:
            modulus, thickness = shell_moduli(cfg)
            model = prep.shell_model(modulus, thickness, sim["poisson"], sim["mass"])
        else:
            model = prep.model(sim["stretch_stiffness"], sim["bending_stiffness"],
                               sim["mass"])
    except ValueError as exc:
        raise BloomError(f"cannot build the model{' of ' + label if label else ''}: {exc}",
                         where=where) from None
    params = Params.of(cfg)
    if shell:  # the contact gap in units of the petal
        params = params.but(collisions={"thickness": prep.contact_gap(cfg)})
    rest_angle = prep.rest_angle
    max_edge = prep.max_grown_edge()  # once: the bud search changes the model's rest lengths

    def build_effects(positions, apart: bool = True):
        return prep.effects(job.names, params, positions=positions, rest_angle=rest_angle,
                            max_edge=max_edge,
                            pushback=sim["integrator"] != "quasi-static", apart=apart)

    # flowers that bloom together: the bud search with contact within each (or between
    # them too, where so asked), the bloom with contact between them too
    apart = not prep.together
    searched_apart = not prep.searched_together

    def bud_effects(positions):
        return build_effects(positions, searched_apart)

    inputs = job.inputs
    model_positions = np.asarray(v) if start.start == "open" else None
    bud_model, bud_angle, bud_params = model, rest_angle, params

    def closed_by(bud) -> float:
        """How much more closed ``bud`` is than the model: the mean over petals of
        the opening angle's change (deg)."""
        frames_ = prep.frames(bud).opening_toward(model_positions)
        return float(np.mean(np.abs(frames_.opening_angles(model_positions))))

    def bloom(path: str, unlifted: bool = False) -> Bloom:
        """The run from the bud (an open start: found along ``path``, :func:`~pipeline.
        sim.reverse.open_start`), resumed from its checkpoint if asked (each path its
        own). ``unlifted``: where contact cuts the lift to nothing, the model's own path
        is followed once, as the path back, and is the bloom where it is one
        (:func:`_own_path_bloom`); else the bud is searched for."""
        v0, model, rest_angle, params, bud_info = v, bud_model, bud_angle, bud_params, {}
        if model_positions is not None:
            doing(f"simulate {label}: finding the bud ({path})" if label else "finding the bud")
            v0, model, rest_angle, params, bud_info = open_start(
                cfg, model, model_positions, rest_angle, params, bud_effects, petal,
                base, prep.s, prep.x, prep.flower_axis, where, faces=prep.faces,
                plane=prep.plane, path=path, closed_by=closed_by, unlifted=unlifted)
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

        what = f"simulate {label}" if label else "simulate"

        def describe(effects_) -> None:  # (the run's size and effects, logged)
            log.info("%d vertices (%d fixed), %d springs, %d hinges; %d steps of h = %g, %d "
                     "frames; effects: %s", model.vertex_count, int(model.pinned.sum()),
                     model.edge_count, model.hinge_count, steps, h, frames,
                     ", ".join(effects_.names) or "none")
            if effects_.connections is not None:
                log.info("%d connection springs between petals",
                         len(effects_.connections.pairs))

        def path_back():
            """The model's own path back to a bud, played forward: ``(recording, wall,
            stopped, effects)`` (:func:`~pipeline.sim.reverse.retrace`)."""
            fx = build_effects(model_positions, apart)
            with Progress(steps, f"{what} (the path back)", progress) as bar:
                made = retrace(
                    model, model_positions, control, fresh_integrator(), fx, steps=steps,
                    frames=frames, h=h, progress=bar.update,
                    petals_at=lambda bud: prep.frames(bud).opening_toward(model_positions))
            return (*made, fx)

        # the path back depends on the bud's model only, the same for the lifted and the
        # own path at the same growth.close (not the faded's: its rest state differs): run
        # once for both (each of the daisy bush's daisies ran it twice, 10-12 s each)
        shared = paths_back.setdefault((bud_info.get("bud_close"), path == "faded"),
                                       _Shared(path_back))

        def retraced():
            """The model's own path back to a bud, played forward (every frame an
            equilibrium at its growth): ``(recording, wall, bud, bud_info, effects)``;
            ``wall`` 0 where another path's bloom ran it."""
            rec_, wall_, back, fx = shared()
            bud = np.asarray(rec_.positions[0])
            info = {**bud_info, "bud_path": "faded" if path == "faded" else "own",
                    "bloom_path": "retraced",
                    "bud_distance": distance_to_model(bud, model_positions, petal, base)}
            if back is not None:  # (the bud is the path's last equilibrium, short of A = 0)
                info["bud_growth"] = back[0]
                log.warning("the path back found no equilibrium below A = %.4g (petal %d), "
                            "even with the rescue: the bloom starts there, from the last "
                            "equilibrium the path reached (its first frames hold it)",
                            back[0], int(petal[back[1]]))
            return rec_, wall_, bud, info, fx

        if model_positions is not None and v0 is None:  # (the lift cut to nothing)
            direct = _own_path_bloom(retraced, closed_by,
                                     lambda bud: prep.bud_closed(bud, model_positions),
                                     "growth.close" not in cfg.given)
            if direct is None:
                return bloom(path)
            rec, wall, v0, bud_info, effects = direct
            describe(effects)
            return Bloom(v0, bud_info, effects, rec, wall, None, 0, distance_to_model(
                np.asarray(rec.positions[-1]), model_positions, petal, base))
        petals = prep.frames(v0)
        if model_positions is not None:  # the model is the open flower: it says which way is out
            petals = petals.opening_toward(model_positions)
        integrator = fresh_integrator()
        if shell and model_positions is not None:  # (the found bud breaks the symmetry)
            integrator.perturbation = 0.0
        elif shell and hasattr(integrator, "nudge") and sim["imperfection"] > 0.0:
            # a bud that is not perfectly symmetric, the same at any resolution, from the
            # first growth on (a random nudge per vertex picks a branch per mesh)
            integrator.nudge = prep.imperfection(sim["imperfection"])
        effects = build_effects(v0, apart)
        state = State.at_rest(model, v0, control)
        effects.constrain(state.forces)
        saved = ckpt.with_name(ckpt.name + CHECKPOINTS[path])
        key = checkpoint.fingerprint(cfg.to_json(), {**inputs, **SEARCHES[path]})
        resumed = (checkpoint.load(saved, key, state, effects, integrator, model) if job.resume
                   else None)
        resumed_step = state.step
        if resumed is not None:
            log.info("resuming from step %d (%s)", state.step, saved)
        saver = Saver(saved, key, effects, integrator, sim["checkpoint_seconds"])
        describe(effects)
        # an open start's bloom that closes first is stopped there: the path back is tried
        # before the rest of it (hallgeirl's flower spent 190 s on a bloom it threw away)
        watch = model_positions is not None and sim["integrator"] == "quasi-static"

        def forward(resume, watched: bool):
            """The bloom from the bud, from ``resume`` (frames so far, or None): ``(rec,
            wall, failed, stopped, closing)``, ``closing`` where it was stopped at the
            frame at which it had closed over CLOSES_FIRST (``watched``; ``rec`` then the
            frames so far, ``state`` and the integrator at that frame, to go on)."""
            seen = {"rec": resume}

            def saving(rec_, state_):
                saver(rec_, state_)
                seen["rec"] = rec_
                if watched and report.closing_dip(rec_.diagnostics.get(
                        "opening_angle_per_petal", ())) > report.CLOSES_FIRST:
                    raise ClosesFirst

            failed_ = stopped_ = None
            clock = time.perf_counter()
            with Progress(steps, what, progress) as bar:
                try:
                    rec_, wall_ = integrate(model, state, control, integrator, steps=steps,
                                            frames=frames, h=h, petals=petals, effects=effects,
                                            progress=bar.update, resume=resume,
                                            checkpoint=saving)
                except ClosesFirst:
                    return seen["rec"], time.perf_counter() - clock, None, None, True
                except (Diverged, NotConverged, ValueError, RuntimeError) as exc:
                    saved.unlink(missing_ok=True)  # a failed run's checkpoint would fail again
                    quasi = (isinstance(exc, NotConverged)
                             and sim["integrator"] == "quasi-static")
                    if quasi and model_positions is None and len(exc.recording.time) > 1:
                        rec_, stopped_ = _stopped(exc, petal, h)
                        wall_ = time.perf_counter() - clock
                    elif not (quasi and model_positions is not None):
                        raise refusal(exc, sim, steps, petal, where) from None
                    else:
                        rec_, wall_, failed_ = None, time.perf_counter() - clock, exc
            return rec_, wall_, failed_, stopped_, False

        rec, wall, failed, stopped, closing = forward(resumed, watch)

        back = _once(retraced)

        def failed_forward(failed_):  # an open model: its own path, from the model to a bud
            log.warning("the bloom from the bud found no equilibrium at A = %.4g (petal "
                        "%d): the path forward leaves the branch the bud is on; the bloom "
                        "is the model's own path to its bud, played forward (every frame "
                        "an equilibrium at its growth)", failed_.growth,
                        int(petal[failed_.vertex]))
            try:
                return back()
            except (Diverged, NotConverged, ValueError, RuntimeError) as exc:
                raise refusal(exc, sim, steps, petal, where) from None

        def finish():
            """The whole bloom from the bud (the rest of it, where it was stopped as it
            closed first): ``(recording, wall, bud, bud_info, effects)``."""
            if not closing:
                return rec, wall, v0, bud_info, effects
            log.info("the rest of the bloom from the bud, from frame %d", len(rec.time) - 1)
            rest, more, failed_, _, _ = forward(rec, False)
            if failed_ is not None:
                found = failed_forward(failed_)
                return (found[0], wall + more + found[1]) + found[2:]
            return rest, wall + more, v0, bud_info, effects

        if failed is not None:
            rec, wall, v0, bud_info, effects = failed_forward(failed)
        elif (model_positions is not None and sim["integrator"] == "quasi-static"
              and "opening_angle_per_petal" in rec.diagnostics):
            dip = report.closing_dip(rec.diagnostics["opening_angle_per_petal"])
            if dip > report.CLOSES_FIRST:
                rec, wall, v0, bud_info, effects = _closes_first(
                    dip, len(rec.time) - 1 if closing else None, wall, finish, back,
                    lambda bud: prep.bud_closed(bud, model_positions))
        if (model_positions is not None and getattr(integrator, "equilibria", False)
                and "opening_angle_per_petal" in rec.diagnostics):  # (frames at rest)
            rec, v0, bud_info = _from_most_closed(
                rec, bud_info, lambda bud: prep.frames(bud).opening_toward(model_positions))
        distance = (None if model_positions is None else
                    distance_to_model(np.asarray(rec.positions[-1]), model_positions,
                                      petal, base))
        return Bloom(v0, bud_info, effects, rec, wall, resumed, resumed_step, distance, stopped)

    paths_back: dict = {}  #: the path back of each bud model (:class:`_Shared`)
    run_ = bloom("lifted", unlifted=sim["integrator"] == "quasi-static")
    if (run_.distance is not None and run_.distance > report.OFF_MODEL
            and sim["integrator"] == "quasi-static" and run_.bud_info["bud_path"] == "lifted"):
        # the forward path from the bud the lift picked lands on another equilibrium:
        # the model's own path back (no lift) may lead to a bud that returns to it
        log.warning("the bloom ends %.3g petal lengths (RMS) from the model (over %g): "
                    "its bud is on another branch; searching again along the model's own "
                    "path (no closing lift)", run_.distance, report.OFF_MODEL)
        try:
            other = bloom("own")
        except BloomError as exc:
            log.warning("no bud without the lift: %s", exc)
        else:
            lifted_closed = prep.bud_closed(run_.bud, model_positions)
            own_closed = prep.bud_closed(other.bud, model_positions)
            if (lifted_closed is not None and own_closed is not None
                    and lifted_closed > 0.0 >= own_closed):
                # a bud that hangs open the other way makes a "bloom" that closes the
                # flower: a bloom forward that ends off the model is nearer what was asked
                log.warning("without the lift the bud hangs open the other way (its petals "
                            "lean %.1f deg further from the axis than the model's, the "
                            "bloom would close the flower): the lifted bloom kept, %.3g "
                            "petal lengths from the model", -own_closed, run_.distance)
            else:
                better = other.distance < run_.distance
                log.info("without the lift the bloom ends %.3g petal lengths from the "
                         "model: %s", other.distance,
                         "kept" if better else "the first one kept")
                if better:
                    run_ = other
        if run_.distance > report.OFF_MODEL and shell:
            run_ = _faded(run_, bloom, lambda bud: prep.bud_closed(bud, model_positions))
    return run_


def _faded(run: Bloom, bloom, bud_closed) -> Bloom:
    """An open start whose bloom ends off the model from the lifted bud and from the
    model's own path's: searched again along the model's own path with the closing lift
    grown into its rest state (``bloom("faded")``, :func:`~pipeline.sim.reverse.
    lift_faded`), kept where it ends nearer the model from a bud more closed than the
    model (``bud_closed(bud)`` > 0, or None). The daisy bush's sixteen rays, lifted, jam
    edge on as they close and slip past each other as they open; along their own path
    they hang open the other way. Logged."""
    log.warning("the bloom ends %.3g petal lengths (RMS) from the model (over %g): "
                "searching again along the model's own path with the closing lift grown "
                "into its rest state at the bud (fading out over the bloom)", run.distance,
                report.OFF_MODEL)
    try:
        other = bloom("faded")
    except BloomError as exc:
        log.warning("no bud with the lift faded: %s", exc)
        return run
    closed = bud_closed(other.bud)
    if other.distance < run.distance and (closed is None or closed > 0.0):
        log.info("with the lift faded the bloom ends %.3g petal lengths from the model%s: "
                 "kept", other.distance, "" if closed is None else
                 f", from a bud {closed:.1f} deg more closed than the model")
        return other
    log.warning("with the lift faded the bloom ends %.3g petal lengths from the model%s: "
                "the one %.3g from it kept", other.distance, "" if closed is None else
                f", from a bud {closed:.1f} deg more closed than the model", run.distance)
    return run


def _own_path_bloom(retraced, closed_by, bud_closed, doubling: bool):
    """An open start whose closing lift contact cuts to nothing (petals that start within
    the gap of each other: the lifted path is the model's own): that path is followed
    once, as the path back (``retraced()``), and is the bloom where it is one: it closes
    no more than :data:`~pipeline.review.report.CLOSES_FIRST` first, its bud does not
    hang open the other way (``bud_closed(bud)`` > 0, or None) and, with ``doubling``
    (growth.close at its default), it is :data:`~pipeline.sim.reverse.CLOSED` deg more
    closed than the model (``closed_by(bud)``) or more. Returns ``(recording, wall, bud,
    bud_info, effects)``, or None: the bud is then searched for (and the path back,
    shared, is there if the bloom from it closes first). hallgeirl's flower ran the
    search, a bloom from its bud that closed first, then this path: 42 s of simulate."""
    try:
        back = retraced()
    except (Diverged, NotConverged, ValueError, RuntimeError) as exc:
        log.warning("the model's own path found no bud (%s): searching for it",
                    str(exc).split(";")[0])
        return None
    bud = back[2]
    dip = report.closing_dip(back[0].diagnostics["opening_angle_per_petal"])
    closed, turned = bud_closed(bud), closed_by(bud)
    why = (f"it closes {dip:.1f} deg first" if dip > report.CLOSES_FIRST else
           f"its bud hangs open the other way ({closed:.1f} deg)"
           if closed is not None and closed <= 0.0 else
           f"its bud is only {turned:.1f} deg more closed than the model"
           if doubling and turned < reverse.CLOSED else None)
    if why is not None:
        log.info("the model's own path: %s; the bud searched for", why)
        return None
    log.info("the model's own path kept as the bloom: it closes %.1f deg first, its bud "
             "%.1f deg more closed than the model%s", dip, turned if closed is None else closed,
             "" if closed is None else " (its petals' lean from the axis)")
    return back


class ClosesFirst(Exception):
    """An open start's bloom from its bud stopped at the frame at which it has closed
    over :data:`~pipeline.review.report.CLOSES_FIRST` (its path back is tried first)."""


class _Shared:
    """``make()``'s result (or its exception), made at the first call only; at a later
    call, a copy of the recording (the first item) whose lists are its own, and 0 wall
    seconds (the second item): the work was done once."""

    def __init__(self, make):
        self.once, self.calls = _once(make), 0

    def __call__(self) -> tuple:
        rec, wall, *rest = self.once()
        self.calls += 1
        if self.calls == 1:
            return (rec, wall, *rest)
        log.info("the path back: the same as the first bud search's (its bud's model is "
                 "the same), not run again")
        return (Recording(time=list(rec.time), positions=list(rec.positions),
                          diagnostics={k: list(v) for k, v in rec.diagnostics.items()}),
                0.0, *rest)


def _once(make):
    """``make()``'s result (or its exception), made at the first call only."""
    made = {}

    def once():
        if "value" not in made:
            try:
                made["value"] = (make(), None)
            except Exception as exc:  # (kept, raised again at every call)
                made["value"] = (None, exc)
        value, exc = made["value"]
        if exc is not None:
            raise exc
        return value
    return once


def _closes_first(dip: float, frame: int | None, wall: float, finish, retraced,
                  bud_closed) -> tuple:
    """An open start's bloom from its bud that closes ``dip`` deg first (over
    :data:`~pipeline.review.report.CLOSES_FIRST`: its path left the bud's branch at once,
    hallgeirl's flower 38.7 deg): the model's own path back to a bud, played forward
    (``retraced()``), where it closes less first and its bud is more closed than the model
    (``bud_closed(bud)`` > 0 or None; a bud that hangs open the other way makes no bloom).
    ``frame``: the frame the bloom was stopped at, as it had closed ``dip`` (None: it ran
    to the end); ``wall`` its seconds so far; ``finish()`` the whole bloom from the bud (it
    goes on from ``frame``), only where the path back is not kept by ``dip`` (then it is
    weighed again against the whole bloom's dip: the same choice as when the bloom ran to
    the end first). The result: ``(recording, wall, bud, bud_info, effects)``, the wall
    time of every run made. Logged."""
    log.warning("the bloom from the bud closes %.1f deg (mean over its petals) %sbefore it "
                "opens (over %g): its path leaves the branch the bud is on; trying the "
                "model's own path to its bud, played forward", dip,
                "" if frame is None else f"by frame {frame} ", report.CLOSES_FIRST)
    try:
        back = retraced()
    except (Diverged, NotConverged, ValueError, RuntimeError) as exc:
        log.warning("the path back found no bud (%s): the bloom from the bud kept",
                    str(exc).split(";")[0])
        return finish()
    dip_back = report.closing_dip(back[0].diagnostics["opening_angle_per_petal"])
    closed = bud_closed(back[2])
    if closed is None or closed > 0.0:
        if dip_back >= dip and frame is not None:  # (weighed against the whole bloom)
            whole = finish()
            wall, dip = whole[1], report.closing_dip(
                whole[0].diagnostics["opening_angle_per_petal"])
            if dip_back >= dip:
                log.warning("the path back closes %.1f deg first: the bloom from the bud "
                            "kept", dip_back)
                return whole
        if dip_back < dip:
            log.info("the path back kept: it closes %.1f deg first%s", dip_back,
                     "" if closed is None else f", its bud {closed:.1f} deg more closed "
                     "than the model (its petals' lean from the axis)")
            return (back[0], wall + back[1]) + back[2:]
    log.warning("the path back closes %.1f deg first%s: the bloom from the bud kept",
                dip_back, "" if closed is None or closed > 0.0 else
                f" and its bud hangs open the other way ({closed:.1f} deg)")
    return finish()


def _from_most_closed(rec, bud_info: dict, petals_at) -> tuple:
    """An open start's bloom that still closes first (over
    :data:`~pipeline.review.report.CLOSES_FIRST`): it starts from its most closed frame
    (an equilibrium at its growth, the bud; the frames before hold it, as a path back
    that stops short of A = 0 does: ``bud_growth``), its openings measured from there in
    ``petals_at(bud)``. Returns ``(recording, bud, bud_info)``; logged."""
    dip = report.closing_dip(rec.diagnostics["opening_angle_per_petal"])
    if dip <= report.CLOSES_FIRST:
        return rec, np.asarray(rec.positions[0]), bud_info
    first = int(np.argmin(rec.diagnostics["opening_angle"]))
    growth = float(rec.diagnostics["growth"][first])
    log.warning("the bloom still closes %.1f deg before it opens: it starts from its most "
                "closed frame (frame %d, A = %.4g), which its first frames hold", dip, first,
                growth)
    rec = hold_first(rec, first, petals_at(np.asarray(rec.positions[first])))
    return rec, np.asarray(rec.positions[0]), {**bud_info, "bud_growth": growth}


def _stopped(exc: NotConverged, petal, h: float):
    """A bloom from a bud that got going and then found no equilibrium: kept as far as it
    went, its last frame held (a refusal after minutes of work gives the user nothing).
    Returns the frames and ``(growth reached, petal)``; logged."""
    stopped = (float(exc.recording.diagnostics["growth"][-1]), int(petal[exc.vertex]))
    rec = hold_last(exc.recording, exc.frame_steps, h)
    log.warning("the bloom stops at A = %.4g: the quasi-static solver found no equilibrium "
                "at A = %.4g (petal %d, %s), even with the rescue; its last %d frame(s) hold "
                "the frame at A = %.4g", stopped[0], exc.growth, stopped[1], exc.cause,
                len(rec.time) - len(exc.recording.time), stopped[0])
    return rec, stopped


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


def refusal(exc: Exception, sim: dict, steps: int, petal, where: str) -> BloomError:
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
class Bloom:
    """One run of :func:`run`'s: its bud, the bud search's figures, the effects, the
    frames, wall seconds, the checkpoint it resumed from and the last frame's distance
    to the model (an open start; else None); ``stopped``: where a bloom from a bud found
    no equilibrium, ``(growth reached, petal)``, its last frame held from there."""

    bud: np.ndarray
    bud_info: dict
    effects: object
    rec: object
    wall: float
    resumed: object
    resumed_step: int
    distance: float | None
    stopped: tuple | None = None
    #: the vertices of the mesh it was solved on, where that was cut finer (else None)
    solved_on: int | None = None
    #: where it was cut finer: ``(s, x)`` of the coarse mesh's vertices as found on the
    #: finer one (:meth:`coarse`)
    axes: tuple | None = None

    def coarse(self, prep: Prepared, fine: Prepared) -> Bloom:
        """This bloom of ``fine`` (``prep`` cut finer, :meth:`Prepared.refined`) seen on
        ``prep``'s own vertices, its first rows (its connection springs tie them only):
        its bud and frames those rows, and the s and x the solve found at them (each
        petal's x the sign of ``prep``'s: the same side of its center plane)."""
        count = len(prep.vertices)
        rec = dataclasses.replace(self.rec, positions=[np.asarray(p)[:count]
                                                       for p in self.rec.positions])
        s, x, was = (np.asarray(fine.s)[:count], np.asarray(fine.x)[:count].copy(),
                     np.asarray(prep.x))
        petal = np.asarray(prep.petal)
        flip = np.bincount(petal, weights=x * was) < 0.0
        x[flip[petal]] *= -1.0
        return dataclasses.replace(self, bud=np.asarray(self.bud)[:count], rec=rec,
                                   solved_on=len(self.bud), axes=(s, x))


class Saver:
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
