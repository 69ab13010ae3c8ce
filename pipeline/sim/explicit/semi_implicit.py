"""The paper's time integrator (Eq. 7-8) and the explicit damping of Eq. 9, with substeps
chosen from the model's stable time step. One verb:
``advance(model, state, control, n_steps, h, effects)``."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pipeline.sim.effects import NO_EFFECTS, Effects
from pipeline.sim.explicit.stable_step import StableStep, rest_angles, scheme_limit
from pipeline.sim.explicit.step import advance
from pipeline.sim.model import Control, Model, State
from pipeline.sim.terms.shell import kernel_shell


class Diverged(RuntimeError):
    """The divergence guard stopped a run: non-finite energy or runaway speed."""

    def __init__(self, step: int, energy: float, speed: float, why: str = ""):
        self.step, self.energy, self.speed = step, energy, speed
        super().__init__(f"diverged at step {step}: "
                         + (why or f"potential energy {energy:.3g}, max speed {speed:.3g}"))


#: the substep keeps ``h_sub omega_max`` under this fraction of the scheme's limit
SAFETY = 0.9


#: a substep that still diverges is halved at most this many times, then Diverged
MAX_HALVINGS = 6


#: never more substeps per step than this (a mesh that needs more, e.g. a collapsing
#: triangle, would otherwise run for ever): the estimate is clamped to it, and a
#: divergence at it is final
MAX_SUBSTEPS = 256


#: the substep is re-chosen at least every this many steps: a frame of a large, slow
#: mesh spans thousands of steps, and a triangle that flattens within it stiffens its
#: hinges (omega_max rises) long before the frame ends. The default scenes' frames are
#: shorter, so they still choose once per frame.
CHUNK = 256


@dataclass
class SemiImplicit:
    """The paper's scheme (Eq. 7-8) with damping factor eta; with ``eta = 1/2`` and a
    velocity factor ``d < 1`` it is the explicit damping of Eq. 9.

    Substeps: the user's ``h`` is the step of the step counter, of the recorded times, of
    A(t) and of the connection springs' break steps; the kernel integrates with
    ``h / k``, ``k >= 1`` the smallest integer that puts ``h / k * omega_max`` under
    :data:`SAFETY` times the scheme's limit
    (:func:`pipeline.sim.stable_step.scheme_limit`), with ``omega_max`` estimated from the
    model at the start of each :meth:`advance` call (one per recorded frame;
    :mod:`pipeline.sim.stable_step`) and again every :data:`CHUNK` steps within it.
    Where ``h`` is stable, ``k = 1`` and the kernel runs exactly as without substeps.
    A chunk that still diverges is rolled back to its start (state and the effects'
    arrays) and retried with the substep halved, up to :data:`MAX_HALVINGS` times (and
    :data:`MAX_SUBSTEPS` substeps). Each choice depends only on the state at the start
    of its chunk, and chunks start at frames (where a checkpoint resumes), so a resumed
    run chooses as an uninterrupted one does. ``substeps = N > 0`` takes exactly ``N``
    kernel steps per
    step, with no estimate and no rollback (``N = 1`` is the paper's scheme as printed).

    Effects under substeps: collisions work in distances (the push-back offset, the
    margin, the grid's slack), not in steps, and each substep resolves its contacts (the
    ``contacts`` diagnostic counts kernel steps' contacts, so ``k`` times as many for a
    contact that persists); connection springs are tested every substep and a break at
    substep ``s`` is recorded at the user's step ``ceil(s / k)``."""

    eta: float
    d: float = 1.0
    speed_limit: float = 1.0  #: a vertex faster than this (mesh units per unit time) has diverged
    substeps: int = 0  #: 0: chosen per frame from the stable-step estimate; N > 0: fixed
    safety: float = SAFETY
    max_halvings: int = MAX_HALVINGS
    max_substeps: int = MAX_SUBSTEPS
    chunk: int = CHUNK
    _estimator: object = field(default=None, repr=False, compare=False)
    _frame: dict = field(default_factory=dict, repr=False, compare=False)
    _shell: tuple = field(default=None, repr=False, compare=False)  #: (model, curl, its KernelShell)

    def diagnostics(self) -> dict:
        """Per frame (the :meth:`advance` call that ended at it): ``substeps`` (kernel
        steps per user step, the most any chunk of the frame took; 0 before the first
        call), ``stable_step`` (the largest step the estimate allows, safety included,
        the smallest of the frame's chunks; from the Gershgorin bound alone when that
        already allows ``h``, so then a lower bound; 0 before the first call),
        ``rollbacks`` (halvings after a divergence)."""
        if self.substeps:
            return {}
        return {"substeps": self._frame.get("substeps", 0),
                "stable_step": self._frame.get("stable_step", 0.0),
                "rollbacks": self._frame.get("rollbacks", 0)}

    def limit(self) -> float:
        """The largest ``h_sub * omega_max`` allowed: the scheme's limit times the safety."""
        return self.safety * scheme_limit(self.eta, self.d)

    def stable_step(self, model: Model, state: State, control: Control, h: float,
                    effects: Effects = NO_EFFECTS) -> tuple[int, float]:
        """``(k, h_max)``: the substeps per step of ``h`` and the largest stable step
        estimated at ``state`` (rest lengths and angles of its time, intact connection
        springs). Lanczos tightens the Gershgorin bound only when that bound alone does
        not allow ``h`` (it costs twice the bound)."""
        if self._estimator is None or self._estimator[0] is not model:
            self._estimator = (model, StableStep.build(model))
        t = state.step * h
        cos0, sin0 = rest_angles(model, control, effects, t)
        args = (model, state.positions, control.growth_at(t), cos0, sin0, effects.connections,
                effects.curl)
        limit = self.limit()
        estimator = self._estimator[1]
        est = estimator.estimate(*args, tighten=False)
        if h * est.omega > limit:
            est = estimator.estimate(*args)
        omega = est.omega
        if not math.isfinite(omega):
            return 1, math.nan
        if omega == 0.0:
            return 1, math.inf
        h_max = limit / omega
        return min(self.max_substeps, max(1, math.ceil(h / h_max * (1.0 - 1e-12)))), h_max

    def advance(self, model: Model, state: State, control: Control, n_steps: int, h: float,
                effects: Effects = NO_EFFECTS) -> None:
        """Advance ``n_steps`` steps of ``h``; raises :class:`Diverged` (with ``state`` at
        the step that failed) when the divergence guard trips at every substep tried."""
        if n_steps <= 0:
            return
        if self.substeps:
            k = self.substeps
            energy, taken = self._kernel(model, state, control, n_steps * k, h / k, k, effects)
            state.potential_energy = energy
            state.step += -(-taken // k)
            if taken < n_steps * k or not np.isfinite(energy):
                raise Diverged(state.step, energy, state.max_speed())
            return
        self._frame = {"substeps": 0, "stable_step": math.inf, "rollbacks": 0}
        done = 0
        while done < n_steps:
            n = min(self.chunk, n_steps - done)
            self._advance_chunk(model, state, control, n, h, effects)
            done += n

    def _advance_chunk(self, model, state, control, n_steps, h, effects) -> None:
        """Up to :attr:`chunk` steps on a substep chosen at their start, rolled back and
        halved while they diverge."""
        k, h_max = self.stable_step(model, state, control, h, effects)
        frame = self._frame
        frame["stable_step"] = min(frame["stable_step"], h_max)
        saved = _Snapshot.take(state, effects)
        for attempt in range(self.max_halvings + 1):
            energy, taken = self._kernel(model, state, control, n_steps * k, h / k, k, effects)
            if taken == n_steps * k and np.isfinite(energy):
                state.potential_energy = energy
                state.step += n_steps
                frame["substeps"] = max(frame["substeps"], k)
                return
            if attempt == self.max_halvings or 2 * k > self.max_substeps:
                break
            saved.restore(state, effects)
            k *= 2
            frame["rollbacks"] += 1
        state.potential_energy = energy
        state.step += -(-taken // k)
        frame["substeps"] = max(frame["substeps"], k)
        why = (f"potential energy {energy:.3g}, max speed {state.max_speed():.3g}, with "
               f"{k} substeps per step after {frame['rollbacks']} halvings")
        raise Diverged(state.step, energy, state.max_speed(), why)

    def _kernel(self, model, state, control, n, h_sub, k, effects) -> tuple[float, int]:
        """``n`` kernel steps of ``h_sub = h / k`` from the user's step ``state.step``;
        connection springs that break get their step in the user's units."""
        conn = effects.connections
        intact = conn.alive.copy() if conn is not None and k > 1 else None
        if self._shell is None or self._shell[0] is not model or self._shell[1] is not effects.curl:
            self._shell = (model, effects.curl, kernel_shell(model, effects.curl))
        energy, taken = advance(
            state.positions, state.velocities, state.forces, state.scratch,
            model.vertex_inv_mass, model.edge_indices, model.edge_rest_length,
            model.edge_growth, model.edge_stiffness, model.hinge_indices,
            model.hinge_rest_cos, model.hinge_rest_sin, model.hinge_stiffness,
            control.schedule_code, control.ramp_time, control.table, state.step * k, n, h_sub,
            self.eta,
            self.d, effects.bundle(), self.speed_limit, self._shell[2])
        if intact is not None:
            broke = intact & ~conn.alive
            conn.broken_step[broke] = -(-conn.broken_step[broke] // k)  # substep -> step
        return energy, taken


@dataclass
class _Snapshot:
    """What one :meth:`SemiImplicit.advance` call changes: the state and every array of
    the effects' bundle (as a checkpoint saves them), to roll a diverged call back."""

    positions: np.ndarray
    velocities: np.ndarray
    forces: np.ndarray
    step: int
    potential_energy: float
    arrays: list

    @classmethod
    def take(cls, state: State, effects: Effects) -> _Snapshot:
        return cls(state.positions.copy(), state.velocities.copy(), state.forces.copy(),
                   state.step, state.potential_energy,
                   [(a, a.copy()) for a in effects.bundle()
                    if isinstance(a, np.ndarray) and a.size and a.flags.writeable])

    def restore(self, state: State, effects: Effects) -> None:
        state.positions[...] = self.positions
        state.velocities[...] = self.velocities
        state.forces[...] = self.forces
        state.step, state.potential_energy = self.step, self.potential_energy
        for a, saved in self.arrays:
            a[...] = saved
