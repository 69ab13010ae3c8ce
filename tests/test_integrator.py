"""The semi-implicit scheme (Eq. 7-8): energy, damping, fixed base, rest, reproducibility."""

import numpy as np
import pytest

from pipeline.sim.explicit.semi_implicit import SemiImplicit
from pipeline.sim.model import Control, State
from pipeline.sim.run import run
from tests.conftest import build_model, prepared


def free_oscillation(eta, steps=6000, h=1.0, kb=0.0005, frames=61, d=1.0):
    """A petal at rest, kicked by random velocities, no growth: total energy per frame."""
    v, f, petal, axes, growth = prepared(1, 150, curve="0")
    model = build_model(v, growth, axes, kb=kb)
    control = Control("linear", 1.0)
    state = State.at_rest(model, v, control)
    rng = np.random.default_rng(1)
    state.velocities[:] = rng.normal(scale=0.01, size=state.velocities.shape)
    state.velocities[model.pinned] = 0.0
    rec, _ = run(model, state, control, SemiImplicit(eta, d), steps=steps, frames=frames, h=h)
    return np.asarray(rec.diagnostics["total_energy"]), model, state


def test_verlet_conserves_energy_over_a_free_oscillation():
    """eta = 1/2 is velocity Verlet: the energy error is bounded, O(h^2), without drift."""
    fine, _, _ = free_oscillation(0.5, steps=24000, h=0.25)
    coarse, _, _ = free_oscillation(0.5, steps=12000, h=0.5)
    err_fine = np.abs(fine / fine[0] - 1.0)
    err_coarse = np.abs(coarse / coarse[0] - 1.0)
    assert err_fine.max() < 5e-3  # measured 1.7e-3
    assert 3.0 < err_coarse.max() / err_fine.max() < 5.5  # second order: measured 4.1
    half = len(fine) // 2
    assert abs(fine[half:].mean() - fine[1:half].mean()) < 1e-3 * fine[0]  # no drift


@pytest.mark.parametrize("eta", [0.0, 0.25, 0.4])
def test_eta_below_half_dissipates(eta):
    energy, _, _ = free_oscillation(eta)
    assert np.all(np.diff(energy) <= 1e-12 * energy[0])  # never gains energy
    assert energy[-1] < 0.5 * energy[0]  # and loses much of it (measured below)


def test_smaller_eta_damps_more():
    final = [free_oscillation(eta)[0][-1] for eta in (0.0, 0.2, 0.4, 0.5)]
    assert final[0] < final[1] < final[2] < final[3]


def grow_petal(schedule, ramp, steps, frames, curve="0.2*x**2"):
    """A 150-vertex petal grown by ``curve`` with eta = 0.1: (initial vertices, model,
    recording with opening angles)."""
    from pipeline.flower.measure import PetalFrames

    v, f, petal, axes, growth = prepared(1, 150, curve=curve)
    model = build_model(v, growth, axes)
    petals = PetalFrames.from_mesh(v, petal, axes.base, axes.on_axis, axes.tip, axes.plane)
    control = Control(schedule, ramp)
    state = State.at_rest(model, v, control)
    rec, _ = run(model, state, control, SemiImplicit(0.1), steps=steps, frames=frames, h=1.0,
                 petals=petals)
    return v, model, rec


def test_base_vertices_stay_exactly_fixed():
    v, model, rec = grow_petal("smoothstep", 3000.0, steps=4000, frames=5)
    pos = np.asarray(rec.positions)
    base = model.pinned
    assert base.sum() >= 3
    assert np.array_equal(pos[:, base], np.broadcast_to(v[base], pos[:, base].shape))
    assert np.abs(pos[-1, ~base] - v[~base]).max() > 0.1  # the rest of the petal moved


def test_zero_growth_is_an_equilibrium():
    v, _, rec = grow_petal("smootherstep", 5000.0, steps=20000, frames=3, curve="0")
    assert np.abs(np.asarray(rec.positions) - v).max() < 1e-9


def test_growth_opens_the_petal_outward():
    _, _, rec = grow_petal("smootherstep", 20000.0, steps=30000, frames=4)
    angle = np.asarray(rec.diagnostics["opening_angle"])
    assert abs(angle[0]) < 1e-9
    assert angle[-1] > 20.0  # boundary-dominant growth bends the petal open (measured 57)


def test_same_inputs_give_bit_identical_frames():
    def once():
        return np.asarray(grow_petal("smootherstep", 1500.0, steps=2000, frames=3)[2].positions)

    assert np.array_equal(once(), once())


class _Pushes:
    """A stand-in integrator that moves every free vertex a little further each call,
    raising the energy while growth holds (``equilibria``: what it says of its frames)."""

    def __init__(self, equilibria: bool):
        self.equilibria = equilibria

    def advance(self, model, state, control, n, h, effects):
        state.positions[~model.pinned] *= 1.01
        state.potential_energy += 1.0 + abs(state.potential_energy)
        state.step += n

    def diagnostics(self):
        return {}


@pytest.mark.parametrize("equilibria", [False, True])
def test_the_hold_energy_guard_is_for_motion_not_for_equilibria(equilibria):
    """While growth holds, energy that rises is a time-stepper running away (Diverged);
    a solver whose every frame is an equilibrium (the quasi-static one, without inertia)
    is not guarded: a path played back from a model at rest (energy 0) meets contact in
    its hold (hallgeirl's: 1e-29 to 5e-6) and is no instability."""
    from pipeline.sim.explicit.semi_implicit import Diverged
    from pipeline.sim.solver.quasistatic import QuasiStatic

    assert QuasiStatic().equilibria and not QuasiStatic(inertia=True).equilibria
    v, f, petal, axes, growth = prepared(1, 150, curve="0")
    model = build_model(v, growth, axes)
    control = Control("linear", 1.0)  # (full growth from the first step on: a hold)
    state = State.at_rest(model, v, control)
    if equilibria:
        rec, _ = run(model, state, control, _Pushes(True), steps=10, frames=6, h=1.0)
        assert np.diff(rec.diagnostics["total_energy"]).min() > 0.0  # (it rose, unguarded)
    else:
        with pytest.raises(Diverged, match="while growth held"):
            run(model, state, control, _Pushes(False), steps=10, frames=6, h=1.0)
