"""Time integrators. Each has one verb: ``advance(model, state, control, n_steps, h, effects)``."""

from __future__ import annotations

from dataclasses import dataclass

from . import kernels
from .effects import Effects
from .model import Control, Model, State

NO_EFFECTS = Effects()


@dataclass
class SemiImplicit:
    """The paper's scheme (Eq. 7-8) with damping factor eta; with ``eta = 1/2`` and a
    velocity factor ``d < 1`` it is the explicit damping of Eq. 9."""

    eta: float
    d: float = 1.0

    def advance(self, model: Model, state: State, control: Control, n_steps: int, h: float,
                effects: Effects = NO_EFFECTS) -> None:
        if n_steps <= 0:
            return
        state.potential_energy = kernels.advance(
            state.positions, state.velocities, state.forces, state.scratch,
            model.vertex_inv_mass, model.edge_indices, model.edge_rest_length,
            model.edge_growth, model.edge_stiffness, model.hinge_indices,
            model.hinge_rest_cos, model.hinge_rest_sin, model.hinge_stiffness,
            control.schedule_code, control.ramp_time, state.step, n_steps, h, self.eta, self.d,
            effects.bundle())
        state.step += n_steps


def make_integrator(name: str, eta: float, damping: float):
    """The integrator a scene asks for by ``simulate.integrator``."""
    if name == "semi-implicit":
        return SemiImplicit(eta=eta)
    if name == "explicit-damping":
        return SemiImplicit(eta=0.5, d=damping)
    raise ValueError(f"unknown integrator {name!r}")
