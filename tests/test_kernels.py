"""Forces are minus the gradient of the energies; rest states feel no force."""

import numpy as np
import pytest

from pipeline.mesh.hinge import dihedral_angles
from pipeline.sim.terms.bending import bending_forces
from pipeline.sim.terms.elastic import internal_forces
from pipeline.sim.terms.growth import SCHEDULE_CODES, schedule_value


def energy_and_forces(X, edges, rest0, growth, ks, hinges, cos0, sin0, kb, A=0.0):
    F = np.zeros_like(X)
    E = internal_forces(X, edges, rest0, growth, ks, hinges, cos0, sin0, kb, A, F)
    return E, F


def central_difference(fun, X, eps=1e-6):
    G = np.zeros_like(X)
    for v in range(X.shape[0]):
        for c in range(3):
            Xp = X.copy()
            Xm = X.copy()
            Xp[v, c] += eps
            Xm[v, c] -= eps
            G[v, c] = (fun(Xp) - fun(Xm)) / (2 * eps)
    return G


def hinge_config(theta, rng, jitter=0.3):
    """Four points forming a hinge of dihedral angle ``theta`` (with random shape)."""
    i = np.zeros(3)
    j = np.array([1.0, 0.0, 0.0]) + rng.normal(scale=0.1, size=3)
    k = np.array([0.4 + rng.uniform(-jitter, jitter), 1.0, 0.0])
    # l: rotate the mirror of k about the x axis so that the angle is theta
    r = 0.9 + rng.uniform(0, jitter)
    l = np.array([0.5 + rng.uniform(-jitter, jitter), -r * np.cos(theta), -r * np.sin(theta)])
    return np.array([i, j, k, l])


@pytest.mark.parametrize("seed", range(6))
def test_stretch_forces_are_minus_gradient(seed):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(5, 3))
    edges = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [0, 4], [1, 3]])
    rest0 = rng.uniform(0.5, 1.5, len(edges))
    growth = rng.uniform(-0.2, 0.5, len(edges))
    ks = rng.uniform(0.05, 0.2, len(edges))
    none = np.zeros((0, 4), dtype=np.int64)
    args = (edges, rest0, growth, ks, none, np.zeros(0), np.zeros(0), np.zeros(0))
    E, F = energy_and_forces(X, *args, A=0.7)
    G = central_difference(lambda Y: energy_and_forces(Y, *args, A=0.7)[0], X)
    assert E > 0
    np.testing.assert_allclose(F, -G, atol=1e-8)


@pytest.mark.parametrize("theta", [0.0, 1e-7, -1e-7, 0.3, -1.2, 2.0, 3.1, -3.1, np.pi - 1e-4])
@pytest.mark.parametrize("theta0", [0.0, 0.4, -2.9])
def test_bending_forces_are_minus_gradient(theta, theta0):
    """Near-flat, moderately and strongly folded hinges (up to the branch cut at pi)."""
    rng = np.random.default_rng(int(1000 * abs(theta)) + 7)
    X = hinge_config(theta, rng)
    hinges = np.array([[0, 1, 2, 3]])
    measured = dihedral_angles(X, hinges)[0]
    assert abs(np.angle(np.exp(1j * (measured - theta)))) < 0.6  # the config has about theta
    kb = np.array([0.7])
    no_edges = np.zeros((0, 2), dtype=np.int64)
    args = (no_edges, np.zeros(0), np.zeros(0), np.zeros(0), hinges,
            np.cos([theta0]), np.sin([theta0]), kb)
    E, F = energy_and_forces(X, *args)
    G = central_difference(lambda Y: energy_and_forces(Y, *args)[0], X)
    np.testing.assert_allclose(E, 0.7 * (1 - np.cos(measured - theta0)), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(F, -G, atol=2e-8)


def test_bending_forces_balance_and_have_no_torque():
    rng = np.random.default_rng(3)
    X = rng.normal(size=(4, 3))
    hinges = np.array([[0, 1, 2, 3]])
    F = np.zeros_like(X)
    bending_forces(X, hinges, np.array([0.3]), np.array([0.95]), np.array([1.0]), F)
    assert np.abs(F).max() > 1e-3
    np.testing.assert_allclose(F.sum(axis=0), 0.0, atol=1e-13)
    np.testing.assert_allclose(np.cross(X, F).sum(axis=0), 0.0, atol=1e-13)


def test_signed_angle_is_continuous_across_pi():
    """Energy and forces do not jump when a hinge folds through +-pi."""
    hinges = np.array([[0, 1, 2, 3]])
    fold = np.pi - 1e-6
    a = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -np.cos(fold), -np.sin(fold)]])
    b = a.copy()
    b[3] = [a[3, 0], a[3, 1], -a[3, 2]]  # mirror l through the plane: angle -> -(pi - 1e-6)
    ta, tb = dihedral_angles(a, hinges)[0], dihedral_angles(b, hinges)[0]
    assert ta > 3.14 and tb < -3.14
    no_edges = np.zeros((0, 2), dtype=np.int64)
    args = (no_edges, np.zeros(0), np.zeros(0), np.zeros(0), hinges,
            np.array([1.0]), np.array([0.0]), np.array([1.0]))
    Ea, Fa = energy_and_forces(a, *args)
    Eb, Fb = energy_and_forces(b, *args)
    assert abs(Ea - Eb) < 1e-9
    assert np.abs(Fa - Fb).max() < 1e-5


def test_rest_state_feels_exactly_zero_force(small_petal):
    from pipeline.sim.model import Control, State
    from tests.conftest import build_model

    v, f, petal, axes, growth = small_petal
    model = build_model(v, growth, axes)
    state = State.at_rest(model, v, Control("linear", 100.0))
    assert np.all(state.forces == 0.0)
    assert abs(state.potential_energy) < 1e-15  # 1 - (cos^2 + sin^2) rounds, forces do not


def test_schedules_rise_from_zero_to_one_smoothly():
    t = np.linspace(-10, 110, 1201)
    for name, code in SCHEDULE_CODES.items():
        a = np.array([schedule_value(code, x, 100.0) for x in t])
        assert a[0] == 0.0 and a[-1] == 1.0
        assert np.all(np.diff(a) >= 0), name
        assert np.max(np.abs(np.diff(a))) <= 0.1 * (120 / 1200) * 2 + 1e-12  # no jump
        if name != "linear":  # C1: zero rate at both ends of the ramp
            assert abs(a[101] - a[100]) < 1e-4 and abs(a[1100] - a[1099]) < 1e-4
