"""The dynamic integrator chooses its own substep (pipeline/sim/explicit/stable_step.py and
SemiImplicit's substeps): the scheme's limit, the estimate of omega_max against the true
eigenvalue, a user's h past the limit now finishing, rollback by halving, the user's units
kept (steps, break steps), and bit-identical reruns."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.flower.axis import find_axes
from pipeline.flower.growth import assign_growth
from pipeline.mesh import clean, procedural
from pipeline.sim import effects as fx
from pipeline.sim.effects import Params
from pipeline.sim.explicit.semi_implicit import Diverged, SemiImplicit
from pipeline.sim.explicit.stable_step import StableStep, amplification, scheme_limit
from pipeline.sim.model import Control, State
from pipeline.sim.run import run
from pipeline.sim.terms.connections import connection_blocks
from tests.conftest import build_model, prepared

PARAMS = Params.defaults()


@pytest.fixture(scope="module")
def bud():
    return prepared(3, 450, seed=1)


@pytest.mark.parametrize("eta, d, expected", [(0.5, 1.0, 2.0), (0.25, 1.0, 1.633),
                                               (0.1, 1.0, 1.491), (0.0, 1.0, 1.414),
                                               (0.4, 1.0, 1.826), (0.5, 0.99, 1.414)])
def test_scheme_limit_is_where_the_amplification_matrix_reaches_one(eta, d, expected):
    z = scheme_limit(eta, d)
    assert z == pytest.approx(expected, abs=1e-3)

    def rho(x):
        return max(abs(np.linalg.eigvals(amplification(x, eta, d))))

    assert all(rho(x) <= 1.0 + 1e-9 for x in np.linspace(0.0, 0.999 * z, 200))
    assert rho(1.002 * z) > 1.0 + 1e-6


def dense_top_eigenvalue(est: StableStep, n: int, conn=None, X=None) -> float:
    """The largest eigenvalue of D H D over the free vertices, dense (H as last assembled
    by ``est``; connection springs added)."""
    H = est.blocks.matrix().toarray()
    if conn is not None:
        blocks = np.zeros((len(conn.pairs), 3, 3))
        connection_blocks(X, conn.pairs, conn.rest, conn.stiffness, conn.alive, blocks)
        for (i, j), K in zip(conn.pairs, blocks, strict=True):
            for a, b, s in ((i, i, 1), (j, j, 1), (i, j, -1), (j, i, -1)):
                H[3 * a:3 * a + 3, 3 * b:3 * b + 3] += s * K
    D = np.repeat(est.scale, 3)
    S = (D[:, None] * H * D[None, :])[np.ix_(D > 0, D > 0)]
    return float(np.linalg.eigvalsh(S)[-1])


@pytest.mark.parametrize("vertices, ks, A", [(150, 0.1, 0.0), (150, 0.1, 0.7), (320, 1.0, 0.3)])
def test_estimate_bounds_the_top_eigenvalue_from_above_within_2_percent(vertices, ks, A):
    v, f, petal, axes, growth = prepared(1, vertices)
    model = build_model(v, growth, axes, ks=ks)
    X = v + np.random.default_rng(2).normal(scale=0.05, size=v.shape)  # off its rest state
    est = StableStep.build(model)
    e = est.estimate(model, X, A, model.hinge_rest_cos, model.hinge_rest_sin)
    true = dense_top_eigenvalue(est, model.vertex_count)
    assert true <= e.gershgorin <= 2.5 * true  # the bound (measured 1.8-1.95 x)
    assert true <= e.omega2 <= 1.02 * true  # tightened by Lanczos (measured 1.0004-1.002)
    assert e.omega2 == e.lanczos


def test_estimate_counts_intact_connection_springs(bud):
    v, f, petal, axes, growth = bud
    model = build_model(v, growth, axes)
    p = PARAMS.but(connections={"stiffness": 1.0, "max_distance": 3.0})
    effects = fx.build(("connections",), vertices=v, faces=f, petal=petal, pinned=model.pinned,
                       on_axis=axes.on_axis, plane=axes.plane, s=axes.s,
                       rest_angle=growth.rest_angle, flower_axis=axes.flower_axis,
                       max_edge=1.5, params=p)
    conn = effects.connections
    assert len(conn.pairs) > 5
    X = v + np.random.default_rng(3).normal(scale=0.05, size=v.shape)
    est = StableStep.build(model)
    cos0, sin0 = model.hinge_rest_cos, model.hinge_rest_sin
    bare = est.estimate(model, X, 0.0, cos0, sin0)
    e = est.estimate(model, X, 0.0, cos0, sin0, conn)
    true = dense_top_eigenvalue(est, model.vertex_count, conn, X)
    assert e.omega2 > 1.5 * bare.omega2  # stiff springs between petals raise omega_max
    assert true <= e.gershgorin and true <= e.omega2 <= 1.02 * true
    conn.alive[:] = False  # broken springs count no more
    assert est.estimate(model, X, 0.0, cos0, sin0, conn).omega2 == pytest.approx(bare.omega2)


def grow(h, steps=1200, frames=5, integrator=None, vertices=150, effects=None, mesh=None):
    """A petal grown with 0.2 x^2 at step ``h``: (recording, state, integrator)."""
    v, f, petal, axes, growth = mesh or prepared(1, vertices)
    model = build_model(v, growth, axes)
    control = Control("smootherstep", 0.6 * steps * h)
    state = State.at_rest(model, v, control)
    integrator = integrator or SemiImplicit(0.1)
    fxs = effects(model, mesh) if effects else fx.Effects()
    fxs.constrain(state.forces)
    rec, _ = run(model, state, control, integrator, steps=steps, frames=frames, h=h,
                 effects=fxs)
    return rec, state, integrator, fxs


def test_a_step_past_the_limit_diverges_without_substeps_and_finishes_with_them():
    with pytest.raises(Diverged):
        grow(2.5, integrator=SemiImplicit(0.1, substeps=1))
    rec, state, _, _ = grow(2.5)
    assert state.step == 1200 and np.all(np.isfinite(rec.positions))
    sub = np.asarray(rec.diagnostics["substeps"])
    assert sub[0] == 0 and np.all(sub[1:] == 2)  # omega_max ~ 0.79: 2.5 / 2 * 0.79 < 1.34
    assert np.all(np.asarray(rec.diagnostics["rollbacks"]) == 0)
    h_max = np.asarray(rec.diagnostics["stable_step"])
    assert h_max[0] == 0.0 and np.all((1.25 <= h_max[1:]) & (h_max[1:] < 2.5))
    assert max(rec.diagnostics["max_speed"]) < 0.1
    assert np.allclose(rec.time, [0, 750, 1500, 2250, 3000])  # in the user's steps
    moved = np.abs(np.asarray(rec.positions[-1]) - rec.positions[0]).max()
    assert 0.1 < moved < 10.0  # it grew, and stayed bounded


def test_where_h_is_stable_it_is_one_substep_and_bit_identical_to_no_substeps():
    rec, _, _, _ = grow(1.0)
    assert list(rec.diagnostics["substeps"]) == [0, 1, 1, 1, 1]
    plain, _, _, _ = grow(1.0, integrator=SemiImplicit(0.1, substeps=1))
    assert np.array_equal(rec.positions, plain.positions)
    assert rec.diagnostics["total_energy"] == plain.diagnostics["total_energy"]


def test_substeps_are_bit_identical_on_rerun():
    a, _, _, _ = grow(2.5, steps=600, frames=3)
    b, _, _, _ = grow(2.5, steps=600, frames=3)
    assert a.diagnostics["substeps"][-1] == 2
    assert np.array_equal(a.positions, b.positions)


class Optimistic(SemiImplicit):
    """An estimate far too optimistic: one substep whatever h."""

    def stable_step(self, model, state, control, h, effects=None):
        return 1, 100.0


def test_a_diverging_call_rolls_back_and_halves_the_substep():
    rec, state, _, _ = grow(2.5, integrator=Optimistic(0.1))
    rollbacks = np.asarray(rec.diagnostics["rollbacks"])
    assert np.all(rollbacks[1:] >= 1) and state.step == 1200
    assert np.all(np.asarray(rec.diagnostics["substeps"])[1:] >= 2)
    # rolled back exactly: from the same state, k = 2 is what the estimate chooses
    honest, _, _, _ = grow(2.5)
    assert list(honest.diagnostics["substeps"]) == list(rec.diagnostics["substeps"])
    assert np.array_equal(rec.positions, honest.positions)


def test_rollback_gives_up_after_the_halvings():
    with pytest.raises(Diverged, match="after 0 halvings"):
        grow(2.5, integrator=Optimistic(0.1, max_halvings=0))
    with pytest.raises(Diverged, match="64 substeps per step after 6 halvings"):
        grow(1e4, steps=20, frames=2, integrator=Optimistic(0.1))
    with pytest.raises(Diverged, match="8 substeps per step after 3 halvings"):
        grow(1e4, steps=20, frames=2, integrator=Optimistic(0.1, max_substeps=8))


def test_substeps_are_capped():
    """An estimate past the cap is clamped to it (h = 1e4 needs ~10^4 substeps)."""
    integ = SemiImplicit(0.1, max_substeps=16, max_halvings=0)
    with pytest.raises(Diverged, match="16 substeps per step after 0 halvings"):
        grow(1e4, steps=20, frames=2, integrator=integ)


def bud_effects(names, stiffness=1e-5):
    def make(model, mesh):
        v, f, petal, axes, growth = mesh
        p = PARAMS.but(connections={"max_distance": 3.0, "stiffness": stiffness,
                                    "critical_stretch": 1.05})
        return fx.build(names, vertices=v, faces=f, petal=petal, pinned=model.pinned,
                        on_axis=axes.on_axis, plane=axes.plane, s=axes.s,
                        rest_angle=growth.rest_angle, flower_axis=axes.flower_axis,
                        max_edge=1.5, params=p)
    return make


def test_rollback_restores_the_effects_and_break_steps_stay_in_user_steps():
    """A 4-petal bud whose layers start through each other, with collisions, connection
    springs, curl and the center plane on, at h = 2.5: an optimistic estimate diverges
    and is rolled back each frame; the run is the one the honest estimate gives, bit for
    bit (so every array the kernel changes was restored), and springs break at user
    steps."""
    v, f, petal = procedural.bud(4, 480, 1, procedural.BudShape(layer_gap=-0.04), crossing=True)
    v = v / clean.mean_edge_length(v, f)
    axes = find_axes(v, f, petal)
    mesh = v, f, petal, axes, assign_growth(v, f, axes.x, "0.2*x**2")
    names = ("curl", "collisions", "connections", "center_plane")
    kw = dict(steps=1500, frames=4, mesh=mesh, effects=bud_effects(names))
    honest, _, _, fxa = grow(2.5, **kw)
    forced, state, _, fxb = grow(2.5, integrator=Optimistic(0.1), **kw)
    assert np.all(np.asarray(forced.diagnostics["rollbacks"])[1:] >= 1)
    assert np.all(np.asarray(honest.diagnostics["substeps"])[1:] >= 2)
    assert np.array_equal(forced.positions, honest.positions)
    assert np.array_equal(fxa.connections.broken_step, fxb.connections.broken_step)
    assert np.array_equal(fxa.collisions.side, fxb.collisions.side)
    assert forced.diagnostics["contacts"] == honest.diagnostics["contacts"]
    assert sum(honest.diagnostics["contacts"]) > 1000  # measured 5084
    c = fxa.connections
    broken = c.broken_step[~c.alive]
    assert len(broken) > 0 and np.all((broken >= 1) & (broken <= 1500))
    assert np.all(c.broken_step[c.alive] == -1)


def test_connection_springs_break_at_the_user_step_their_substep_falls_in(bud, monkeypatch):
    """k = 3 substeps: a spring that breaks at substep s is recorded at step ceil(s / 3);
    the same run at k = 1 breaks them at nearby steps (within a few percent of the run)."""

    class Three(SemiImplicit):
        def stable_step(self, model, state, control, h, effects=None):
            return 3, 1.0

    names = ("connections",)
    kw = dict(steps=3000, frames=4, mesh=bud, effects=bud_effects(names))
    _, _, _, one = grow(1.0, **kw)
    _, _, _, three = grow(1.0, integrator=Three(0.1), **kw)
    a, b = one.connections, three.connections
    assert (~a.alive).sum() > 5
    both = ~a.alive & ~b.alive
    assert both.sum() >= 0.8 * (~a.alive).sum()
    assert np.all((b.broken_step[~b.alive] >= 1) & (b.broken_step[~b.alive] <= 3000))
    assert np.abs(a.broken_step[both] - b.broken_step[both]).max() < 150
