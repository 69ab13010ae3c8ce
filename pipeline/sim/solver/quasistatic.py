"""The quasi-static integrator: the bloom as a path of equilibria along the growth A(t).

A petal's bending modes are slow (a period of ~5e4 steps at h = 1), so an explicit
scheme needs ~1e5 steps or more to settle where growth puts it. This integrator does
not follow the dynamics: for each growth increment it finds the equilibrium
(grad U = 0) by Newton's method, starting from a prediction along the path (the secant
of the last two equilibria, or the tangent).

- Hessian: the analytic one of :mod:`pipeline.sim.terms`. A Newton step factors it as is (a sparse
  LDL^T by 3x3 vertex blocks, :mod:`ldl`, whose pivot signs give its inertia); a later
  step of the same solve may reuse that factorization (a chord step) if the step it
  gives is a tenth of the last one or less (the factorization is most of an iteration's
  cost). Where it is positive definite the step is Newton's, and near a stable
  equilibrium convergence is quadratic. Where it is not (the path passes a bifurcation
  or a snap, or the prediction is far off), the energy is first searched along a
  direction of negative curvature read from the factors, then the step solves ``(H + mu
  I) p = -g`` with ``mu`` raised until that is positive definite (see
  :meth:`pipeline.sim.solver.newton.Newton.solve`). (Projecting each element's Hessian to positive definite,
  the other classic remedy, was tried first: it converged linearly, 50-100 iterations
  per increment, and stalled at snaps.)
- Each connected piece (petal) is its own problem when petals do not interact. With
  collisions or connection springs they share one energy and one line search, but the
  linear algebra is split by group: petals that a contact within the barrier's band or
  an intact spring joins are one system, the others each their own (most petals,
  most of the time, are alone); each group is factored, and converges, apart, and a
  converged group stays put while the others iterate.
- Line search: backtracking on the energy (Armijo); a step within rounding of the
  energy is accepted.
- Increments: ``ceil(dA * stages)`` per call, so ``stages`` bounds the growth per
  increment; an increment that does not converge is halved (up to 6 times).
- Rescue: where an increment still does not converge (a snap, a buckle), the path
  steps through it (:mod:`pipeline.sim.solver.rescue`). A state whose forces have gone
  out of scale (a collapsed triangle) is no equilibrium, and is rescued or refused.
- Symmetry breaking: at the first increment every free vertex is moved by a tiny,
  seeded random amount (``perturbation`` mesh units), so that a perfectly symmetric
  petal can leave an unstable symmetric branch; Newton removes it where the branch is
  stable.
- Effects: curl (rest angles follow B = A), wrinkles (growth map), the fixed base and
  the center-plane constraint (a constrained vertex's Newton step has no component
  along its plane normal).
- Collisions: an IPC barrier between petals joins the energy (:class:`~pipeline.sim.terms.contact.Contact`);
  every step, the line search's and the negative-curvature search's, is first cut to
  what continuous collision detection allows, so no iterate crosses (or comes closer
  than ``effects.collisions.thickness``). A bud that starts intersecting is refused.
- Connection springs join the energy (:class:`~pipeline.sim.terms.connections.Springs`); when an increment
  converges with springs past their breaking length, those break (the step at which
  the growth reached that increment is recorded) and the increment is redone.

- Inertia (``inertia``, the key ``simulate.inertia``): each increment, at least one per
  frame and evenly spread in time, is an implicit Euler step in incremental-potential
  form, the minimum of ``U(x) + |x - x_pred|_M^2 / (2 dt^2)``, ``x_pred = x + dt v``, by
  the same Newton solver (:meth:`QuasiStatic._advance_dynamic`); then ``v = (x_new -
  x) / dt``. A motion such as the snap after springs break plays out over frames and
  comes to rest; the path of equilibria is its limit (``dt`` far past the slowest
  period).

``advance`` has the signature of the dynamic integrators, so :func:`run.run` records
one equilibrium (or, with inertia, one state of the motion) per frame; without inertia
velocities stay zero.

The module is long because the path following is one loop whose steps (prediction,
increments, halving, the rescue's smaller increments, implicit Euler motion and Newton
again, breaking springs, inertia) share the solver's state and its counters.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from pipeline.flower import axis
from pipeline.sim.effects import NO_EFFECTS, Effects
from pipeline.sim.model import Control, Model, State
from pipeline.sim.solver.newton import Counters, Failure, Newton, NotConverged
from pipeline.sim.solver.pieces import split
from pipeline.sim.solver.rescue import EXTRA_HALVINGS, RESCUES, Rescue, log_rescues, snap, step_through
from pipeline.sim.solver.system import System
from pipeline.sim.terms.connections import Springs
from pipeline.sim.terms.contact import Contact
from pipeline.sim.terms.inertia import Inertia
from pipeline.sim.terms.shell import contact_stiffness
from pipeline.sim.threads import dot, parallel_map

log = logging.getLogger("bloom")

#: an increment where Newton finds no equilibrium is halved up to this many times ...
HALVINGS = 6

@dataclass
class QuasiStatic:
    """Path-following Newton solver; see the module docstring."""

    @property
    def equilibria(self) -> bool:
        """Whether every frame it reaches is an equilibrium (without inertia)."""
        return not self.inertia

    stages: int = 20  #: growth increments over the whole ramp (at least)
    tolerance: float = 1e-6  #: converged when a Newton step moves no vertex further (mesh units)
    max_iterations: int = 200  #: Newton iterations per increment before it is halved (a snap takes ~50)
    perturbation: float = 1e-6  #: symmetry-breaking nudge at the start (mesh units)
    seed: int = 0
    #: (V, 3) a given symmetry-breaking offset instead of the random nudge (the shell's
    #: imperfection: smooth, the same at any resolution), or None
    nudge: np.ndarray | None = field(default=None, repr=False)
    #: with the inertia term: each increment is an implicit Euler step of the dynamics
    #: (:meth:`_advance_dynamic`); without it, the path of equilibria (its limit)
    inertia: bool = False
    counts: Counters = field(default_factory=Counters)  #: what it has done so far
    newton: Newton | None = field(default=None, repr=False)  #: its Newton solver
    _started: bool = field(default=False, repr=False)  #: settled at the start
    _parts: list | None = field(default=None, repr=False)  #: one solver per petal, or []
    #: (V, 3) where the petals were gathered into clusters that cannot meet (contact)
    _split_at: np.ndarray | None = field(default=None, repr=False)
    _perturbed: bool = field(default=False, repr=False)  #: the symmetry-breaking nudge is made
    #: the equilibrium before the last one on the path: (A, X), for the secant predictor
    _behind: tuple | None = field(default=None, repr=False)
    #: (V,) petal of each vertex, to name it in the log (None: named by vertex)
    petal: np.ndarray | None = field(default=None, repr=False)
    #: the rescues since the last :meth:`advance` logged them (:class:`Rescue`)
    rescued: list = field(default_factory=list, repr=False)

    def __post_init__(self):
        if self.newton is None:
            self.newton = Newton(self.tolerance, self.max_iterations, self.counts)

    @property
    def iterations(self) -> int:
        """Newton iterations so far (all increments)."""
        return self.counts.iterations

    @iterations.setter
    def iterations(self, value: int) -> None:
        self.counts.iterations = value

    @property
    def residuals(self) -> list:
        """The residual force at each iteration of the last Newton solve."""
        return self.newton.residuals

    def diagnostics(self) -> dict:
        # (the same names at every frame, the first included: coupling is built later)
        return {"newton_iterations": self.counts.iterations, "growth_increments": self.counts.increments,
                "shifted_factorizations": self.counts.shifted,
                "negative_curvature_steps": self.counts.descents, "ccd_cut_steps": self.counts.ccd_cuts,
                "redone_increments": self.counts.breaks, "rescues": self.counts.rescues,
                "rescue_halvings": self.counts.rescue_halvings,
                "rescue_inertia_steps": self.counts.rescue_inertia_steps}

    # --- one call: growth from A(t0) to A(t0 + n h) -----------------------------------
    def advance(self, model: Model, state: State, control: Control, n_steps: int, h: float,
                effects: Effects = NO_EFFECTS) -> None:
        if model.hinge_count and not np.all(model.hinge_stiffness > 0.0):
            raise ValueError("the quasi-static integrator needs bending stiffness > 0 (without "
                             "it a petal has no stiffness out of its plane)")
        if self._parts is None:
            self._couple(model, state.positions, effects)
        if not self._perturbed and (control.growth_at((state.step + n_steps) * h)
                                    != control.growth_at(state.step * h)):
            # at the first growth (not before: a keyed hold of the bud holds to the bit)
            self._perturbed = True
            self._perturb(model, state, effects)
        if self._parts is None:
            self._split(model, effects, state.positions)
        if not self._parts:
            try:
                self._advance(model, state, control, n_steps, h, effects)
            finally:
                log_rescues(self)
        for part in self._parts:  # independent petals: each follows its own path
            part.state.positions[:] = state.positions[part.vertices]
            part.state.velocities[:] = state.velocities[part.vertices]

        def follow(part):
            try:
                part.solver._advance(part.model, part.state, control, n_steps, h, part.effects)
            except NotConverged as exc:
                exc.vertex = int(part.vertices[exc.vertex])  # name it in the whole mesh
                raise
            finally:
                for r in part.solver.rescued:
                    r.vertex = int(part.vertices[r.vertex]) if r.vertex >= 0 else -1

        try:
            parallel_map(follow, self._parts)
        finally:  # (in the petals' order: the same log every run)
            for part in self._parts:
                self.rescued.extend(part.solver.rescued)
                part.solver.rescued.clear()
            log_rescues(self)
        for part in self._parts:
            state.positions[part.vertices] = part.state.positions
            state.velocities[part.vertices] = part.state.velocities
        if self._parts:
            state.step += n_steps
            for k in ("iterations", "increments", "shifted", "descents", "rescues",
                      "rescue_halvings", "rescue_inertia_steps"):
                setattr(self.counts, k, sum(getattr(p.solver.counts, k) for p in self._parts))
        if not self.inertia:
            state.velocities[:] = 0.0
        self.newton.at(model, effects, control.growth_at(state.step * h))
        state.potential_energy = self.newton.energy(state.positions, state.forces)
        effects.constrain(state.forces)
        if self.newton.contact is not None:  # the frame's contacts: pairs within the barrier's band
            effects.counters[0] = self.newton.contact.active_count(state.positions)
        elif self._parts and _apart(effects):  # (flowers apart: each flower's own)
            effects.counters[0] = sum(p.solver.newton.contact.active_count(p.state.positions)
                                      for p in self._parts if p.solver.newton.contact is not None)

    def _couple(self, model: Model, positions, effects: Effects, check: bool = True) -> None:
        """Build the terms that couple the petals, if the scene has them; refuse a bud
        that contact cannot start from
        (:meth:`~pipeline.sim.terms.contact.Contact.check_start`; not ``check``: a run
        resumed from a checkpoint, whose contact is restored)."""
        if effects.collisions is not None and not (self._parts is None and _apart(effects)):
            # (flowers apart: each flower's contact is its own, built with its cluster)
            c = effects.collisions
            stiffness = float(model.edge_stiffness.max())
            if getattr(model, "shell", None) is not None:  # (in petal units: contact_stiffness)
                stiffness = contact_stiffness(model.shell)
            self.newton.contact = Contact.build(positions, c.faces, c.petal,
                                                gap=c.thickness, stiffness=stiffness,
                                                left=c.left, count=c.in_contact)
            if getattr(model, "shell", None) is not None:  # (its gap in units of the petal)
                self.newton.contact.key = "effects.collisions.gap"
                self.newton.contact.unit = model.shell.size
            if check:
                self.newton.contact.check_start(positions)
        if effects.connections is not None:
            self.newton.springs = Springs(effects.connections)

    def _split(self, model: Model, effects: Effects, positions, check: bool = True) -> None:
        """The independent petals (with contact, clusters of petals that cannot meet),
        each with a solver of its own (or none: one problem)."""
        self._parts = split(model, effects, positions)
        self._split_at = None if positions is None else np.array(positions, dtype=np.float64)
        if not self._parts and _apart(effects) and self.newton.contact is None:
            self._couple(model, positions, effects, check=check)  # (one problem after all)
        for part in self._parts:
            part.solver = QuasiStatic(self.stages, self.tolerance, self.max_iterations,
                                      perturbation=0.0, inertia=self.inertia)
            if part.effects.collisions is not None:  # (a cluster: contact of its own)
                part.state.positions[:] = positions[part.vertices]
                part.solver._parts = []
                part.solver._couple(part.model, part.state.positions, part.effects,
                                    check=check and _apart(effects))

    # --- what a checkpoint saves ---------------------------------------------------------------
    def state(self) -> dict:
        """Everything this solver carries from one frame to the next, as plain numbers
        and arrays (a tree of dicts and lists): its counters, where the path is (the
        equilibrium behind, for the secant predictor), the sheet's force scale where the
        path started (what a collapsed triangle is measured against), its contact's gap
        and sweep, its groups' patterns and last factorizations, and the same of each
        independent petal's solver. A checkpoint saves it; :meth:`restore` puts it back, so a resumed
        run goes on to the bit as an uninterrupted one."""
        newton = self.newton
        behind = self._behind
        return {
            "counts": dict(vars(self.counts)),
            "started": self._started, "perturbed": self._perturbed,
            "behind_growth": None if behind is None else float(behind[0]),
            "behind_positions": None if behind is None else behind[1],
            "energy_rounding": newton.energy_rounding,
            "reference": newton.reference,
            "elastic": None if newton.terms is None else newton.terms.elastic.snapshot(),
            "contact": None if newton.contact is None else newton.contact.snapshot(),
            "system": None if newton.system is None else newton.system.snapshot(),
            "parts": None if self._parts is None else [p.solver.state() for p in self._parts],
            "split_at": self._split_at if self._parts else None,
        }

    def restore(self, model: Model, state: State, effects: Effects, saved: dict) -> None:
        """Put back a :meth:`state` taken from a run of the same model and effects (the
        effects' own arrays are restored by the checkpoint, beside this)."""
        for key, value in saved["counts"].items():
            setattr(self.counts, key, int(value))
        self._started, self._perturbed = bool(saved["started"]), bool(saved["perturbed"])
        self._behind = None if saved["behind_growth"] is None else (
            float(saved["behind_growth"]), np.array(saved["behind_positions"], dtype=np.float64))
        self.newton.energy_rounding = float(saved["energy_rounding"])
        self.newton.reference = float(saved["reference"])
        if self.newton.terms is None:  # (put back when they are built)
            self.newton.restored = saved.get("elastic")
        else:
            self.newton.terms.elastic.restore(saved.get("elastic"))
        if saved["parts"] is not None:  # (the solver of the whole, past its first advance)
            self._couple(model, state.positions, effects, check=False)
            if saved["contact"] is not None:
                self.newton.contact.restore(saved["contact"])
            if saved["parts"]:
                at = saved.get("split_at")
                self._split(model, effects, None if at is None else np.asarray(at), check=False)
            else:
                self._parts = []
            for part, part_state in zip(self._parts, saved["parts"], strict=True):
                part.state.step = state.step  # (each petal's path is at the whole's step)
                part.solver.restore(part.model, part.state, part.effects, part_state)
        if saved["system"] is not None:
            self.newton.system = System.build(model, effects)
            self.newton.system.restore(saved["system"])

    def _advance(self, model, state, control, n_steps: int, h: float, effects) -> None:
        """:meth:`advance` for one connected mesh."""
        if self.newton.system is None:
            self.newton.system = System.build(model, effects)
        if not self._started:  # settle at the start so that a tangent exists
            self._started = True
            a0 = control.growth_at(state.step * h)
            self.newton.at(model, effects, a0)
            self.newton.reference = self.newton.sheet_scale(state.positions)
            failure = self.newton.solve(model, state, effects, a0)
            if failure is not None:  # (no increment to halve: the motion from here)
                rescue = Rescue(a0, a0, failure)
                self.counts.rescues += 1
                failure = snap(self, model, state, effects, a0, rescue, lambda a: state.step)
                if failure is not None:
                    raise self._not_converged(model, state.positions, state.step, a0, failure,
                                              rescue)
        a0 = control.growth_at(state.step * h)
        a1 = control.growth_at((state.step + n_steps) * h)
        pieces = max(1, math.ceil(abs(a1 - a0) * self.stages - 1e-9))
        if self.inertia:
            self._advance_dynamic(model, state, control, n_steps, h, effects, pieces)
            return
        targets = a0 + (a1 - a0) * np.arange(1, pieces + 1) / pieces
        first, last = state.step, state.step + n_steps

        def step_of(a: float) -> int:
            """The first step of this call at which the growth reaches ``a`` (A rises)."""
            lo, hi = first, last
            while lo < hi:
                mid = (lo + hi) // 2
                if control.growth_at(mid * h) >= a:
                    hi = mid
                else:
                    lo = mid + 1
            return lo

        done = a0
        for target in targets:
            done = self._reach(model, state, effects, done, float(target), last, step_of)
        state.step += n_steps

    def _advance_dynamic(self, model, state, control, n_steps: int, h: float, effects,
                         pieces: int) -> None:
        """:meth:`_advance` with the inertia term: ``pieces`` equal time steps ``dt`` (at
        least one per call, more where the growth rises fast), each an implicit Euler
        step in incremental-potential form, the minimum of ``U(x) + 1/(2 dt^2) |x -
        x_pred|_M^2`` with ``x_pred = x + dt v``; then ``v = (x_new - x) / dt``. A step
        where Newton fails is halved (up to 6 times); one that ends with connection
        springs past their breaking length breaks them and is redone."""
        t_end = (state.step + n_steps) * h
        for k in range(1, pieces + 1):
            t_from = state.step * h + (k - 1) * n_steps * h / pieces
            t_to = t_end if k == pieces else state.step * h + k * n_steps * h / pieces
            t_now, size, halvings = t_from, t_to - t_from, 0
            rescue = None  #: past the usual halvings (:class:`Rescue`)
            while t_now != t_to:
                t_next = t_to if t_to - t_now <= size * (1 + 1e-9) else t_now + size
                dt = t_next - t_now
                a_now, a_next = control.growth_at(t_now), control.growth_at(t_next)
                start = state.positions.copy()
                weight = model.vertex_mass / (dt * dt)
                self.newton.dyn = Inertia(start + dt * state.velocities, weight)
                self.newton.system.inertia = self.newton.dyn.diagonal()
                try:
                    self._predict(model, state, effects, a_now, a_next,
                                  guess=self.newton.dyn.predicted - start)
                    failure = self.newton.solve(model, state, effects, a_next)
                finally:
                    self.newton.dyn, self.newton.system.inertia = None, None
                if failure is None:
                    over = self.newton.springs.over_limit(state.positions) if self.newton.springs else ()
                    if len(over):
                        c = self.newton.springs.connections
                        c.alive[over] = False
                        c.broken_step[over] = int(round(t_next / h))
                        self.counts.breaks += 1
                        state.positions[:] = start
                        continue
                    self.counts.increments += 1
                    state.velocities[:] = (state.positions - start) / dt
                    t_now = t_next
                    continue
                state.positions[:] = start
                halvings += 1
                if halvings > HALVINGS:  # (the rescue here: more, smaller time steps)
                    if rescue is None:
                        rescue = Rescue(a_now, a_next, failure, kind="time")
                        self.counts.rescues += 1
                    if rescue.halvings >= EXTRA_HALVINGS:
                        raise self._not_converged(model, state.positions,
                                                  int(round(t_next / h)), a_next, failure, rescue)
                    rescue.halvings += 1
                    self.counts.rescue_halvings += 1
                size *= 0.5
            if rescue is not None:
                rescue.smallest, rescue.done = size, True
                self.rescued.append(rescue)
        state.step += n_steps

    def _not_converged(self, model, X, step: int, growth: float,
                       failure: Failure, rescue: Rescue | None = None) -> NotConverged:
        """The failure, with the cause named: a piece held on a line (it can turn about
        it), a triangle collapsed (its forces out of scale), no stable equilibrium (a
        stall where the Hessian is not positive definite: it buckles or snaps), or a
        stall at a positive definite Hessian; and what the rescue tried (``rescue``)."""
        how = {"stalled": "found no descent along its step",
               "iterations": f"ran out of iterations ({self.max_iterations})",
               "shift": "found no shift that makes the Hessian positive definite",
               "degenerate": "found the sheet's forces out of scale"}[failure.how]
        pinned = model.pinned
        width = axis.base_width(X[pinned], X)
        if failure.how == "degenerate":
            cause = "degenerate"
            detail = (f"Newton {how}: the force scale at vertex {failure.vertex} is "
                      f"{failure.out_of_scale:.3g} times the sheet's where the path started, "
                      "so a triangle has collapsed to (nearly) no area and the petal folds "
                      "through itself there")
        elif width < axis.MIN_BASE_WIDTH:
            cause = "weak"
            detail = (f"its piece is held by {int(pinned.sum())} fixed vertices on a line (they "
                      f"stray {width:.2g} of its length from it) and can turn about it "
                      f"(Newton {how})")
        elif failure.inertia != "definite":
            cause = "unstable"
            detail = (f"Newton {how} where the Hessian is {failure.inertia}: "
                      + ("its rest state is no stable equilibrium" if growth == 0.0 else
                         "it has no stable equilibrium there (it buckles or snaps)"))
        else:
            cause = "stalled"
            detail = f"Newton {how} where the Hessian is positive definite"
        if rescue is not None:
            detail += f"; {rescue.tried()}"
        return NotConverged(step, growth, failure.residual, scale=failure.scale, cause=cause,
                            detail=detail, vertex=max(failure.vertex, 0))

    def _perturb(self, model: Model, state: State, effects: Effects) -> None:
        """The symmetry-breaking nudge (:attr:`nudge`, else a seeded random one of at most
        :attr:`perturbation`), never into the contact barrier: cut to half the part of it
        that continuous collision detection allows."""
        if self.nudge is not None:
            nudge = np.array(self.nudge, dtype=np.float64)
        elif self.perturbation > 0.0:
            rng = np.random.default_rng(self.seed)
            nudge = rng.uniform(-self.perturbation, self.perturbation, state.positions.shape)
        else:
            return
        nudge[model.pinned] = 0.0
        if effects.center_plane is not None:
            effects.constrain(nudge)
        contact = self.newton.contact if self.newton is not None else None
        if contact is not None and self.nudge is not None:
            allowed = contact.max_step(state.positions, state.positions + nudge)
            if allowed < 1.0:
                nudge *= 0.5 * allowed
        state.positions += nudge

    def _reach(self, model, state, effects, a_from: float, a_to: float, step: int,
               step_of=None) -> float:
        """Equilibrium at growth ``a_to``; an increment where Newton fails is halved
        (up to :data:`HALVINGS` times), then the path goes on to ``a_to``; where it still
        fails, the path is rescued (:func:`~pipeline.sim.solver.rescue.step_through`). An
        increment that ends with connection springs past their breaking length breaks them
        (at ``step_of(A)``) and is redone from where it started."""
        step_of = (lambda a: step) if step_of is None else step_of
        a_now, size, halvings = a_from, a_to - a_from, 0
        full = size
        rescue = None  #: the rescue under way (:class:`Rescue`), past the usual halvings
        while a_now != a_to:
            a_next = a_to if abs(a_to - a_now) <= abs(size) * (1 + 1e-9) else a_now + size
            start = state.positions.copy()
            self._predict(model, state, effects, a_now, a_next)
            failure = self.newton.solve(model, state, effects, a_next)
            if failure is None:
                if self._break_springs(state, start, step_of(a_next)):
                    self._behind = None  # (another path from here on)
                    continue
                self.counts.increments += 1
                self._behind = (a_now, start)
                a_now = a_next
                if rescue is not None:  # past the snag: the increments grow back
                    size = full if abs(2.0 * size) >= abs(full) else 2.0 * size
                continue
            state.positions[:] = start
            halvings += 1
            if halvings <= HALVINGS:
                size *= 0.5
                continue
            if rescue is None or rescue.done:
                if rescue is not None and rescue.count >= RESCUES:
                    raise self._not_converged(model, state.positions, step_of(a_next), a_next,
                                              failure, rescue)
                rescue = Rescue(a_now, a_next, failure, count=0 if rescue is None else rescue.count)
                rescue.count += 1
                self.counts.rescues += 1
            size = step_through(self, model, state, effects, rescue, a_now, a_next, size, failure,
                                step_of)
            if rescue.done:
                a_now = rescue.target
        return a_to

    def _break_springs(self, state, start, step: int) -> bool:
        """Connection springs past their breaking length at the converged positions
        break (recorded at ``step``): then the positions go back to ``start`` and the
        increment is redone (True)."""
        over = self.newton.springs.over_limit(state.positions) if self.newton.springs else ()
        if not len(over):
            return False
        c = self.newton.springs.connections
        c.alive[over] = False
        c.broken_step[over] = step
        self.counts.breaks += 1
        state.positions[:] = start
        return True

    def _predict(self, model, state, effects, a_now: float, a_next: float,
                 guess: np.ndarray | None = None) -> None:
        """Predictor, from the equilibrium X at ``a_now`` to a start for ``a_next``, with a
        line search on the new energy (CCD-limited with contact). Secant where the
        equilibrium before it is known (``_behind``): the path extrapolated along the
        chord of the last two equilibria, which is as accurate as the tangent (the
        error is second order in the increment) and needs no factorization at X.
        Otherwise tangent (Euler), if a positive definite factorization is at hand:
        the step ``H^-1 f(x, A_next)``. ``guess``: a step to try first (with inertia,
        where the velocity carries the vertices: ``dt v``)."""
        X = state.positions
        self.newton.at(model, effects, a_next)
        scratch = np.empty_like(X)
        energy, g = self.newton.gradient(X, scratch)
        step = None
        behind = self._behind
        if guess is not None:
            step = self.newton.constrained(guess)
            if not np.any(step) or dot(g, step) >= 0.0:
                step = None
        elif behind is not None and behind[0] != a_now and behind[1].shape == X.shape:
            secant = ((a_next - a_now) / (a_now - behind[0])) * (X - behind[1])
            step = self.newton.constrained(secant)
            if dot(g, step) >= 0.0:  # not downhill on the new energy: no use
                step = None
        if step is None:
            if not self.newton.system.tangent:
                return
            step = self.newton.system.solve(-g)
        self.counts.iterations += 1
        length = self.newton.line_search(X, scratch, energy, g, step)
        for gr in self.newton.system.groups:
            gr.moved = length * float(np.abs(step[gr.dofs]).max(initial=0.0))


def _apart(effects: Effects) -> bool:
    """Whether the scene's flowers bloom as problems apart (staggered flowers of a file of
    many: contact within each flower only; see :mod:`pipeline.flower.stagger`)."""
    c = effects.collisions
    return (c is not None and c.vertex_flower is not None and len(c.vertex_flower) > 0
            and int(c.vertex_flower.max()) != int(c.vertex_flower.min()))
