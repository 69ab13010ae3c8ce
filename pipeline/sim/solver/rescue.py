"""The quasi-static path's rescue: where Newton finds no equilibrium after the usual
halvings of an increment (a snap, a buckle, a stage that will not converge), the path
steps through on its own (:func:`step_through`): more, smaller increments where they
converge, then the snap as a motion (:func:`snap`: implicit Euler steps with the inertia
term at the growth past the snag, until the sheet comes to rest) and Newton's equilibrium
from there; then the path goes on. Each rescue is a :class:`Rescue`, counted in the
solver's diagnostics and logged in one line (:func:`log_rescues`). The functions take the
:class:`~pipeline.sim.solver.quasistatic.QuasiStatic` whose path they rescue."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from pipeline.sim.solver.newton import Failure
from pipeline.sim.terms.inertia import Inertia

log = logging.getLogger("bloom")

#: ... then the path is rescued (:func:`step_through`): up to this many more
#: halvings (more, smaller increments, where they converge) ...
EXTRA_HALVINGS = 4
#: ... then the snap as a motion: implicit Euler steps (at most this many) ...
RESCUE_STEPS = 200
#: ... each halved at most this many times where Newton fails on it ...
RESCUE_DT_HALVINGS = 10
#: ... until the motion has come to rest: a step moves the sheet this fraction of the
#: largest step so far or less (then Newton seeks the equilibrium from there)
REST = 1e-2
#: an implicit Euler step that converges in this many Newton iterations or fewer doubles
#: the next one's time step
EASY = 8
#: a growth increment is rescued at most this many times
RESCUES = 8


@dataclass
class Rescue:
    """What one rescue did (:func:`step_through`): where the path snagged, why,
    and how it got through."""

    growth: float  #: the growth A the path had reached (converged)
    target: float  #: the growth past the snag it reached (or tried to)
    failure: Failure  #: Newton's failure that started it (after the usual halvings)
    kind: str = "growth"  #: growth (increments of A) or time (the inertia variant's steps)
    count: int = 0  #: rescues of this increment so far (this one included)
    halvings: int = 0  #: halvings past the usual limit
    smallest: float = 0.0  #: the smallest increment tried (of A, or of time)
    inertia: int = 0  #: implicit Euler steps of the snap
    dt: list = field(default_factory=list)  #: the snap's first and last time steps
    moved: float = 0.0  #: how far the snap moved the sheet (largest vertex distance)
    done: bool = False  #: got through: the path goes on from ``target``

    @property
    def vertex(self) -> int:
        return self.failure.vertex

    @vertex.setter
    def vertex(self, value: int) -> None:
        self.failure.vertex = value

    @property
    def why(self) -> str:
        return {"stalled": "found no descent along its step",
                "iterations": "ran out of iterations",
                "shift": "found no shift that makes the Hessian positive definite",
                "degenerate": "found the sheet's forces out of scale (a triangle collapsed)",
                }[self.failure.how] + f" (Hessian {self.failure.inertia})"

    def tried(self) -> str:
        """What it did, in words."""
        unit = "dA" if self.kind == "growth" else "dt"
        parts = []
        if self.halvings:
            parts.append(f"{self.halvings} more halving(s) (increments down to {unit} = "
                         f"{abs(self.smallest):.3g})")
        if self.inertia or self.dt:
            parts.append(f"{self.inertia} implicit Euler step(s) with the inertia term (dt "
                         f"{self.dt[0]:.3g} to {self.dt[1]:.3g}) at A = {self.target:.6g}"
                         + (f", coming to rest {self.moved:.3g} mesh units away" if self.done
                            else ""))
        done = "; the path goes on" if self.done else "; no equilibrium found"
        return (", then ".join(parts) or "nothing more") + done


def step_through(qs, model, state, effects, rescue: Rescue, a_now: float, a_next: float,
            size: float, failure: Failure, step_of) -> float:
    """One move of a rescue where the increment from ``a_now`` to ``a_next`` failed
    after the usual halvings: a further halving (more, smaller increments, up to
    :data:`EXTRA_HALVINGS`), or, past those, the snap as a motion (:meth:`_snap`) to
    the growth ``a_next`` of the smallest increment tried, then Newton's equilibrium
    there; the path goes on from it (``rescue.done``). Returns the next increment's
    size. Raises :class:`NotConverged` (naming what was tried) if the motion finds no
    equilibrium."""
    if rescue.halvings < EXTRA_HALVINGS:
        rescue.halvings += 1
        qs.counts.rescue_halvings += 1
        rescue.smallest = min(abs(rescue.smallest) or math.inf, abs(0.5 * size))
        return 0.5 * size
    rescue.target = a_next
    snagged = snap(qs, model, state, effects, a_next, rescue, step_of)
    if snagged is not None:
        raise qs._not_converged(model, state.positions, step_of(a_next), a_next, snagged,
                                  rescue)
    qs.counts.increments += 1
    qs._behind = None  # (a jump: the secant of the path behind is no guide)
    rescue.done = True
    qs.rescued.append(rescue)
    return size



def snap(qs, model, state, effects, growth: float, rescue: Rescue,
          step_of) -> Failure | None:
    """The snap as a motion: from rest, implicit Euler steps with the inertia term at
    ``growth`` (each the minimum of ``U(x) + |x - x_pred|_M^2 / (2 dt^2)``, as
    :meth:`_advance_dynamic`'s), until the sheet comes to rest (a step moves it
    :data:`REST` of its largest step or less); then Newton's equilibrium from there.
    The time step starts at the sheet's fastest spring period (``sqrt(m / K_s)``),
    doubles after a step Newton solves easily and halves where it fails. None when
    the equilibrium is found (the positions at it); else the last failure (the
    positions as they were). Bounded: :data:`RESCUE_STEPS` steps."""
    X = state.positions
    origin = X.copy()
    velocity = np.zeros_like(X)
    dt = math.sqrt(float(model.vertex_mass.min()) / float(model.edge_stiffness.max()))
    rescue.dt = [dt, dt]
    largest, halvings, failure = 0.0, 0, rescue.failure
    newton = qs.newton
    for _ in range(RESCUE_STEPS):
        start = X.copy()
        newton.dyn = Inertia(start + dt * velocity, model.vertex_mass / (dt * dt))
        newton.system.inertia = newton.dyn.diagonal()
        try:
            qs._predict(model, state, effects, growth, growth,
                          guess=newton.dyn.predicted - start)
            failure = newton.solve(model, state, effects, growth)
        finally:
            newton.dyn, newton.system.inertia = None, None
        if failure is not None:
            X[:] = start
            halvings += 1
            if halvings > RESCUE_DT_HALVINGS:
                break
            dt *= 0.5
            continue
        if qs._break_springs(state, start, step_of(growth)):
            continue
        easy = len(newton.residuals) <= EASY + 1
        qs.counts.rescue_inertia_steps += 1
        rescue.inertia += 1
        moved = float(np.abs(X - start).max())
        largest = max(largest, moved)
        velocity[:] = (X - start) / dt
        rescue.dt[1] = dt
        if rescue.inertia >= 2 and moved <= REST * largest:
            # at rest: the equilibrium from here (else on, until it slows again)
            at_rest = X.copy()
            failure = newton.solve(model, state, effects, growth)
            if failure is None:
                rescue.moved = float(np.linalg.norm(X - origin, axis=1).max())
                return None
            X[:] = at_rest
            largest = moved
        if easy:
            dt *= 2.0
    X[:] = origin
    return failure if failure is not None else rescue.failure  # (never came to rest)



def log_rescues(qs) -> None:
    """One log line per rescue since the last call."""
    for r in qs.rescued:
        where = "" if r.vertex < 0 else (
            f" (petal {int(qs.petal[r.vertex])})" if qs.petal is not None
            else f" (vertex {r.vertex})")
        log.info("rescued the path at growth A = %.6g%s, where Newton %s: %s", r.growth,
                 where, r.why, r.tried())
    qs.rescued.clear()
