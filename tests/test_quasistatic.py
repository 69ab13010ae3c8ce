"""The quasi-static integrator: its Hessian, Newton's convergence, and agreement with a
slow explicit run."""

import numpy as np
import pytest

from pipeline import study
from pipeline.sim import effects as fx
from pipeline.sim import hessian, kernels
from pipeline.sim.model import Control, Model, State
from pipeline.sim.quasistatic import QuasiStatic, _System


@pytest.fixture(scope="module")
def petal():
    return study.Scene.bud(1, 200)


def _grown_state(scene, A):
    """An equilibrium of the petal at growth A (quasi-static path)."""
    control = Control("linear", 100.0)
    state = State.at_rest(scene.model, scene.vertices, control)
    qs = QuasiStatic(stages=10)
    qs.advance(scene.model, state, control, int(round(100 * A)), 1.0)
    return state, qs


def _gradient(model, X, A):
    """Minus the simulator's own forces (kernels.internal_forces)."""
    F = np.empty_like(X)
    kernels.internal_forces(X, model.edge_indices, model.edge_rest_length, model.edge_growth,
                            model.edge_stiffness, model.hinge_indices, model.hinge_rest_cos,
                            model.hinge_rest_sin, model.hinge_stiffness, A, F)
    return -F


def test_hessian_matches_finite_differences_of_the_gradient(petal):
    """Away from equilibrium (growth 0.5, positions jittered), so that every term of the
    spring and hinge Hessians counts: each column against central differences of the
    gradient the solver uses (minus the kernels' forces)."""
    import scipy.sparse as sp

    m = petal.model
    free = Model.build(petal.vertices, m.edge_indices, m.edge_growth, m.edge_stiffness,
                       m.hinge_indices, m.hinge_stiffness, np.zeros(m.vertex_count, bool))
    system = _System.build(free, fx.Effects())
    rng = np.random.default_rng(3)
    X = petal.vertices + rng.normal(scale=0.1, size=petal.vertices.shape)
    A = 0.5
    hessian.hessian(X, free.edge_indices, free.edge_rest_length, free.edge_growth,
                    free.edge_stiffness, free.hinge_indices, free.hinge_rest_cos,
                    free.hinge_rest_sin, free.hinge_stiffness, A, system.data,
                    system.edge_slots, system.hinge_slots, system.work)
    n = 3 * free.vertex_count
    H = sp.bsr_matrix((system.data.copy(), system.indices, system.indptr), shape=(n, n)).toarray()
    assert np.abs(H - H.T).max() < 1e-14
    eps = 1e-6
    cols = rng.choice(n, 60, replace=False)
    for c in cols:
        Xp = X.copy()
        Xp.ravel()[c] += eps
        Xm = X.copy()
        Xm.ravel()[c] -= eps
        fd = (_gradient(free, Xp, A) - _gradient(free, Xm, A)).ravel() / (2 * eps)
        assert np.abs(H[:, c] - fd).max() < 1e-7 * max(1.0, np.abs(H[:, c]).max()), c


def test_newton_converges_quadratically_near_a_solution(petal):
    """From an equilibrium nudged by 1e-4 and by 1e-5, one Newton step leaves a residual
    force that scales with the square of the first (10x closer: 100x smaller), and the
    solve ends below 1e-12."""
    after_one = []
    for scale in (1e-4, 1e-5):
        state, qs = _grown_state(petal, 0.4)
        rng = np.random.default_rng(0)
        nudge = rng.normal(scale=scale, size=state.positions.shape)
        nudge[petal.model.pinned] = 0.0
        state.positions += nudge
        qs.tolerance = 1e-10
        assert qs._newton(petal.model, state, fx.Effects(), 0.4) is None
        r = qs.residuals
        assert r[-1] < 1e-12 and len(r) <= 5, r
        assert 1e-2 < r[1] / r[0] ** 2 < 1e2, r  # r1 = C r0^2
        after_one.append((r[0], r[1]))
    (a0, a1), (b0, b1) = after_one
    assert 8 < a0 / b0 < 12  # the nudges differ 10x ...
    assert a1 / b1 > 50  # ... and the residuals after one step ~100x: quadratic


def test_quasi_static_path_agrees_with_a_very_slow_explicit_run(petal):
    ref = study.simulate(petal, "quasi-static", ramp=1, stages=20, tolerance=1e-8)
    slow = study.simulate(petal, "semi-implicit", ramp=80_000, hold=40_000, eta=0.1)
    fast = study.simulate(petal, "semi-implicit", ramp=20_000, hold=10_000, eta=0.1)
    err_slow, angle_slow = study.shape_error(petal, slow.positions, ref.positions)
    err_fast, _ = study.shape_error(petal, fast.positions, ref.positions)
    opening = petal.petals.opening_angles(ref.positions).mean()
    assert opening > 30.0  # it did open
    assert err_slow < 2e-3 and abs(angle_slow) < 0.2, (err_slow, angle_slow)
    assert err_fast > 10 * err_slow  # the explicit scheme converges to it as growth slows


def test_equilibria_are_independent_of_the_increments(petal):
    """Stage counts 10 and 40 land on the same bloom (the path is followed, not jumped)."""
    a = study.simulate(petal, "quasi-static", ramp=1, stages=10, tolerance=1e-8)
    b = study.simulate(petal, "quasi-static", ramp=1, stages=40, tolerance=1e-8)
    assert study.shape_error(petal, a.positions, b.positions)[0] < 1e-6


def test_quasi_static_keeps_the_center_plane_and_curls():
    """A 3-petal bud grown hard (1.0 x^2): the petals buckle, so the solver leaves
    saddles along negative curvature and shifts its Hessian; the center-plane vertices
    must stay on their planes through all of it; curl changes the bloom."""
    from pipeline import asset, clean
    from pipeline.axis import find_axes
    from pipeline.growth import assign_growth

    scene = study.Scene.bud(3, 600, curve="1.0*x**2")
    m = scene.model
    v, f, p = asset.bud(3, 600, 0)
    v = v / clean.mean_edge_length(v, f)
    axes = find_axes(v, f, p)
    g = assign_growth(v, f, axes.x, "1.0*x**2")
    blooms = {}
    for names in (("center_plane",), ("curl", "center_plane")):
        effects = fx.build(names, vertices=v, faces=f, petal=p, pinned=m.pinned,
                           on_axis=axes.on_axis, plane=axes.plane, s=axes.s,
                           rest_angle=g.rest_angle, flower_axis=axes.flower_axis, max_edge=1.5,
                           params={"curl": {"beta": 1.0}})
        control = Control("linear", 100.0)
        state = State.at_rest(m, v, control)
        qs = QuasiStatic(stages=10)
        qs.advance(m, state, control, 100, 1.0, effects)
        assert len(effects.center_plane.vertices) > 20
        assert effects.center_plane.drift(state.positions) < 1e-9, names
        blooms[names] = state.positions.copy()
    assert qs.descents > 0  # the negative-curvature search did run
    # curl with beta = 1 flattens the cross-sections: a different bloom
    diff = study.shape_error(scene, blooms[("curl", "center_plane")], blooms[("center_plane",)])
    assert diff[0] > 1e-3


def test_time_to_converge_reports_each_integrator(petal):
    """`bloom bench`'s converged-bloom figures on a lone petal: every integrator gets
    within 1% (the dynamic ones with long enough growth), each row says what it cost,
    and the paper's 44 s is beside it."""
    ref = study.simulate(petal, "quasi-static", ramp=1, stages=40, tolerance=1e-8)
    rows = study.time_to_converge(petal, ref.positions)
    by = {r["integrator"]: r for r in rows}
    assert set(by) == {"quasi-static", "semi-implicit eta=0.1", "Verlet (eta=0.5)",
                       "explicit-damping d=0.999"}
    for row in rows:
        assert row["converged"] and row["error"] < 0.01 and row["paper_seconds"] == 44.0
        assert row["wall_seconds"] > 0
    assert by["semi-implicit eta=0.1"]["steps"] >= 15_000  # slow growth is what converges


def test_bench_json_reports_step_cost_per_edge():
    import json

    from click.testing import CliRunner

    from stages.cli import cli

    r = CliRunner().invoke(cli, ["bench", "--json", "--vertices", "300", "--steps", "20",
                                 "--sizes", "300,1200", "--no-converge"])
    assert r.exit_code == 0, r.output
    data = json.loads(r.output)
    sizes = [row["vertices"] for row in data["step_cost"]]
    assert len(sizes) == 2 and sizes[1] > 3 * sizes[0]
    for row in data["step_cost"]:
        assert row["edges"] > row["vertices"] and 0 < row["ns_per_edge"] < 1e4
        assert row["ms_per_step"] == pytest.approx(row["ns_per_edge"] * row["edges"] / 1e6)
    assert data["effects"][0]["effects"] == "none" and data["effects"][0]["ratio"] == 1.0
    assert data["converged_bloom"] is None
