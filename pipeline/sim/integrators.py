"""Time integrators. Each has one verb: ``advance(model, state, control, n_steps, h, effects)``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import kernels
from .effects import Effects
from .model import Control, Model, State

NO_EFFECTS = Effects()


class Diverged(RuntimeError):
    """The divergence guard stopped a run: non-finite energy or runaway speed."""

    def __init__(self, step: int, energy: float, speed: float, why: str = ""):
        self.step, self.energy, self.speed = step, energy, speed
        super().__init__(f"diverged at step {step}: "
                         + (why or f"potential energy {energy:.3g}, max speed {speed:.3g}"))


@dataclass
class SemiImplicit:
    """The paper's scheme (Eq. 7-8) with damping factor eta; with ``eta = 1/2`` and a
    velocity factor ``d < 1`` it is the explicit damping of Eq. 9."""

    eta: float
    d: float = 1.0
    speed_limit: float = 1.0  #: a vertex faster than this (mesh units per unit time) has diverged

    def diagnostics(self) -> dict:
        return {}

    def advance(self, model: Model, state: State, control: Control, n_steps: int, h: float,
                effects: Effects = NO_EFFECTS) -> None:
        """Advance ``n_steps`` steps; raises :class:`Diverged` (with ``state`` at the step
        that failed) when the divergence guard trips."""
        if n_steps <= 0:
            return
        energy, taken = kernels.advance(
            state.positions, state.velocities, state.forces, state.scratch,
            model.vertex_inv_mass, model.edge_indices, model.edge_rest_length,
            model.edge_growth, model.edge_stiffness, model.hinge_indices,
            model.hinge_rest_cos, model.hinge_rest_sin, model.hinge_stiffness,
            control.schedule_code, control.ramp_time, state.step, n_steps, h, self.eta, self.d,
            effects.bundle(), self.speed_limit)
        state.potential_energy = energy
        state.step += taken
        if taken < n_steps or not np.isfinite(energy):
            raise Diverged(state.step, energy, state.max_speed())


def make_integrator(name: str, eta: float, damping: float, speed_limit: float = 1.0,
                    stages: int = 20, tolerance: float = 1e-6):
    """The integrator a scene asks for by ``simulate.integrator``."""
    if name == "quasi-static":
        from .quasistatic import QuasiStatic

        return QuasiStatic(stages=stages, tolerance=tolerance)
    if name == "semi-implicit":
        return SemiImplicit(eta=eta, speed_limit=speed_limit)
    if name == "explicit-damping":
        return SemiImplicit(eta=0.5, d=damping, speed_limit=speed_limit)
    raise ValueError(f"unknown integrator {name!r}")
