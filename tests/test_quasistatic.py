"""The quasi-static integrator: its Hessian, Newton's convergence, and agreement with a
slow explicit run."""

import json

import h5py
import numpy as np
import pytest

from pipeline.sim import effects as fx
from pipeline.sim.model import Control, Model, State
from pipeline.sim.solver.quasistatic import QuasiStatic
from pipeline.sim.solver.system import System
from pipeline.sim.terms.elastic import hessian, internal_forces, rounding_scale
from pipeline.studies import accuracy


@pytest.fixture(scope="module")
def petal():
    return accuracy.Scene.bud(1, 200)


def _grown_state(scene, A):
    """An equilibrium of the petal at growth A (quasi-static path)."""
    control = Control("linear", 100.0)
    state = State.at_rest(scene.model, scene.vertices, control)
    qs = QuasiStatic(stages=10)
    qs.advance(scene.model, state, control, int(round(100 * A)), 1.0)
    return state, qs


def _gradient(model, X, A):
    """Minus the simulator's own forces (internal_forces)."""
    F = np.empty_like(X)
    internal_forces(X, model.edge_indices, model.edge_rest_length, model.edge_growth,
                            model.edge_stiffness, model.hinge_indices, model.hinge_rest_cos,
                            model.hinge_rest_sin, model.hinge_stiffness, A, F)
    return -F


def _assemble(blocks, model, X, A):
    """The elastic Hessian of ``model`` at X, growth A and its rest angles, into ``blocks``."""
    hessian(X, model.edge_indices, model.edge_rest_length, model.edge_growth,
            model.edge_stiffness, model.hinge_indices, model.hinge_rest_cos, model.hinge_rest_sin,
            model.hinge_stiffness, A, blocks.data, blocks.edge_slots, blocks.hinge_slots,
            blocks.work)


def test_hessian_matches_finite_differences_of_the_gradient(petal):
    """Away from equilibrium (growth 0.5, positions jittered), so that every term of the
    spring and hinge Hessians counts: each column against central differences of the
    gradient the solver uses (minus the kernels' forces)."""

    m = petal.model
    free = Model.build(petal.vertices, m.edge_indices, m.edge_growth, m.edge_stiffness,
                       m.hinge_indices, m.hinge_stiffness, np.zeros(m.vertex_count, bool))
    system = System.build(free, fx.Effects())
    rng = np.random.default_rng(3)
    X = petal.vertices + rng.normal(scale=0.1, size=petal.vertices.shape)
    A = 0.5
    _assemble(system.blocks, free, X, A)
    n = 3 * free.vertex_count
    H = system.blocks.matrix().toarray()
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
        qs.newton.tolerance = 1e-10
        assert qs.newton.solve(petal.model, state, fx.Effects(), 0.4) is None
        r = qs.residuals
        assert r[-1] < 1e-12 and len(r) <= 5, r
        assert 1e-2 < r[1] / r[0] ** 2 < 1e2, r  # r1 = C r0^2
        after_one.append((r[0], r[1]))
    (a0, a1), (b0, b1) = after_one
    assert 8 < a0 / b0 < 12  # the nudges differ 10x ...
    assert a1 / b1 > 50  # ... and the residuals after one step ~100x: quadratic


def test_quasi_static_path_agrees_with_a_very_slow_explicit_run(petal):
    ref = accuracy.simulate(petal, "quasi-static", ramp=1, stages=20, tolerance=1e-8)
    slow = accuracy.simulate(petal, "semi-implicit", ramp=80_000, hold=40_000, eta=0.1)
    fast = accuracy.simulate(petal, "semi-implicit", ramp=20_000, hold=10_000, eta=0.1)
    err_slow, angle_slow = accuracy.shape_error(petal, slow.positions, ref.positions)
    err_fast, _ = accuracy.shape_error(petal, fast.positions, ref.positions)
    opening = petal.petals.opening_angles(ref.positions).mean()
    assert opening > 30.0  # it did open
    assert err_slow < 2e-3 and abs(angle_slow) < 0.2, (err_slow, angle_slow)
    assert err_fast > 10 * err_slow  # the explicit scheme converges to it as growth slows


def test_equilibria_are_independent_of_the_increments(petal):
    """Stage counts 10 and 40 land on the same bloom (the path is followed, not jumped)."""
    a = accuracy.simulate(petal, "quasi-static", ramp=1, stages=10, tolerance=1e-8)
    b = accuracy.simulate(petal, "quasi-static", ramp=1, stages=40, tolerance=1e-8)
    assert accuracy.shape_error(petal, a.positions, b.positions)[0] < 1e-6


def test_quasi_static_keeps_the_center_plane_and_curls():
    """A 3-petal bud grown hard (1.0 x^2): the petals buckle, so the solver leaves
    saddles along negative curvature and shifts its Hessian; the center-plane vertices
    must stay on their planes through all of it; curl changes the bloom."""
    from pipeline.flower.axis import find_axes
    from pipeline.flower.growth import assign_growth
    from pipeline.mesh import clean, procedural

    scene = accuracy.Scene.bud(3, 600, curve="1.0*x**2")
    m = scene.model
    v, f, p = procedural.bud(3, 600, 0)
    v = v / clean.mean_edge_length(v, f)
    axes = find_axes(v, f, p)
    g = assign_growth(v, f, axes.x, "1.0*x**2")
    blooms = {}
    for names in (("center_plane",), ("curl", "center_plane")):
        effects = fx.build(names, vertices=v, faces=f, petal=p, pinned=m.pinned,
                           on_axis=axes.on_axis, plane=axes.plane, s=axes.s,
                           rest_angle=g.rest_angle, flower_axis=axes.flower_axis, max_edge=1.5,
                           params=fx.Params.defaults().but(curl={"beta": 1.0}))
        control = Control("linear", 100.0)
        state = State.at_rest(m, v, control)
        qs = QuasiStatic(stages=10)
        qs.advance(m, state, control, 100, 1.0, effects)
        assert len(effects.center_plane.vertices) > 20
        assert effects.center_plane.drift(state.positions) < 1e-9, names
        blooms[names] = state.positions.copy()
    assert qs.counts.descents > 0  # the negative-curvature search did run
    # curl with beta = 1 flattens the cross-sections: a different bloom
    diff = accuracy.shape_error(scene, blooms[("curl", "center_plane")], blooms[("center_plane",)])
    assert diff[0] > 1e-3


def test_time_to_converge_reports_each_integrator(petal):
    """`bloom bench`'s converged-bloom figures on a lone petal: every integrator gets
    within 1% (the dynamic ones with long enough growth), each row says what it cost,
    and the paper's 44 s is beside it."""
    ref = accuracy.simulate(petal, "quasi-static", ramp=1, stages=40, tolerance=1e-8)
    rows = accuracy.time_to_converge(petal, ref.positions)
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
                                 "--sizes", "300,1200", "--no-converge", "--remesh-faces", "0"])
    assert r.exit_code == 0, r.output
    data = json.loads(r.output)
    sizes = [row["vertices"] for row in data["step_cost"]]
    assert len(sizes) == 2 and sizes[1] > 3 * sizes[0]
    for row in data["step_cost"]:
        assert row["edges"] > row["vertices"] and 0 < row["ns_per_edge"] < 1e4
        assert row["ms_per_step"] == pytest.approx(row["ns_per_edge"] * row["edges"] / 1e6)
    assert data["effects"][0]["effects"] == "none" and data["effects"][0]["ratio"] == 1.0
    assert data["converged_bloom"] is None and data["remesh"] is None


def _rounding_bound(model, X, A=0.0):
    """The solver's rounding level of the forces at X: ROUNDING_FACTOR eps times the
    largest free vertex's force scale (rounding_scale)."""
    from pipeline.sim.solver.newton import EPS, ROUNDING_FACTOR

    scale = np.empty(len(X))
    rounding_scale(X, model.edge_indices, model.edge_rest_length, model.edge_growth,
                           model.edge_stiffness, model.hinge_indices, model.hinge_rest_cos,
                           model.hinge_rest_sin, model.hinge_stiffness, A, scale)
    return ROUNDING_FACTOR * EPS * scale[~model.pinned].max()


def _residual(model, X, A=0.0):
    g = _gradient(model, X, A)
    g[model.pinned] = 0.0
    return float(np.abs(g).max())


def test_a_rest_state_converges_at_the_rounding_level_of_its_forces():
    """A 6-petal bud at A = 0 with a tight tolerance (1e-9: tolerance times the soft
    stiffness is 5e-16, below what rounding leaves of forces on vertices 20 mesh units
    from the origin). It used to end in 'no equilibrium found at step 0 (growth A = 0,
    residual force 2.11e-13)': the energy could no longer see Newton's decrease, and
    1e-14 was an absolute floor. Now Newton goes on to the rounding level and stops."""
    scene = accuracy.Scene.bud(6, 600)
    m = scene.model
    control = Control("smootherstep", 1.0)
    state = State.at_rest(m, scene.vertices, control)
    qs = QuasiStatic(stages=80, tolerance=1e-9)
    qs.advance(m, state, control, 0, 1.0)  # the settle at A = 0 only
    bound = _rounding_bound(m, state.positions)
    assert 1e-15 < bound < 1e-13  # eps x (K_s x ~20 mesh units x a few springs)
    assert _residual(m, state.positions) <= bound


def test_stiffness_scale_does_not_change_convergence(petal):
    """The same petal with K_s and K_b scaled by 1e-3 and 1e3: the same Newton
    iterations and the same equilibria (to rounding), and each residual below its own
    rounding bound. (With the old absolute 1e-14 floor: 55, 63 and 73 iterations, and
    shapes 5e-10 apart.)"""
    m = petal.model
    runs = {}
    for k in (1e-3, 1.0, 1e3):
        model = Model.build(petal.vertices, m.edge_indices, m.edge_growth, k * m.edge_stiffness,
                            m.hinge_indices, k * m.hinge_stiffness, m.pinned)
        control = Control("linear", 100.0)
        state = State.at_rest(model, petal.vertices, control)
        qs = QuasiStatic(stages=10, tolerance=1e-10)
        qs.advance(model, state, control, 100, 1.0)
        runs[k] = qs.iterations, state.positions.copy()
        X = state.positions
        assert _residual(model, X, 1.0) <= _rounding_bound(model, X, 1.0), k
    assert runs[1e-3][0] == runs[1.0][0] == runs[1e3][0], {k: r[0] for k, r in runs.items()}
    for k in (1e-3, 1e3):
        assert np.abs(runs[k][1] - runs[1.0][1]).max() < 1e-12 * petal.length, k


def test_a_petal_held_on_a_line_converges_where_its_hessian_is_singular():
    """A cupped petal fixed by 3 vertices of its straight base row: it can turn about
    that line (a null mode, so the Hessian is singular at every equilibrium). Stiffness
    x1e3 and tolerance 1e-10: the residual can only reach rounding, where the old solver
    said 'no equilibrium found at step 100 (growth A = 0.2047, residual force 2.92e-13)'.
    Now a residual at rounding is converged, whatever the inertia."""
    from test_axis_base import cupped_petal

    from pipeline.flower.axis import find_axes
    from pipeline.flower.growth import assign_growth

    v, f = cupped_petal()
    axes = find_axes(v, f, np.zeros(len(v), dtype=np.int64))
    g = assign_growth(v, f, axes.x, "0.2*x**2")
    pinned = np.zeros(len(v), dtype=bool)
    pinned[[3, 4, 5]] = True  # on the x axis: (u, 0, 0)
    model = Model.build(v, g.edges, g.alpha, 100.0 * g.stiffness, g.hinges, 0.5, pinned)
    control = Control("linear", 100.0)
    state = State.at_rest(model, v, control)
    qs = QuasiStatic(stages=10, tolerance=1e-10)
    qs.advance(model, state, control, 100, 1.0)
    X = state.positions
    assert _residual(model, X, 1.0) <= _rounding_bound(model, X, 1.0)
    # the turn about the base line (the x axis) costs nothing: H r = 0 to rounding on
    # the free vertices (E(R X) = E(X) gives H r = w x g, and g = 0 where free)
    system = System.build(model, fx.Effects())
    _assemble(system.blocks, model, X, 1.0)
    H = system.blocks.matrix()
    turn = np.cross([1.0, 0.0, 0.0], X).ravel()
    assert np.abs(turn.reshape(-1, 3)[pinned]).max() == 0.0  # the fixed ones stay put
    free = np.repeat(~pinned, 3)
    assert np.abs((H @ turn)[free]).max() < 1e-12 * np.abs(H).max() * np.abs(turn).max()
    # and the petal did open (the growth acted; it did not just spin)
    assert np.linalg.norm(X - v, axis=1).max() > 1.0


def test_failures_name_their_cause():
    """A piece fixed on a line is 'weak'; a stall where the Hessian is indefinite is
    'unstable' (no stable equilibrium: it buckles or snaps); both say the residual over
    its rounding level and the force scale; the message has no doubled 'found'."""
    from test_axis_base import cupped_petal

    from pipeline.sim.solver.newton import Failure

    v, f = cupped_petal()
    edges = np.array(sorted({tuple(sorted(e)) for t in f for e in ((t[0], t[1]), (t[1], t[2]),
                                                                   (t[0], t[2]))}))
    qs = QuasiStatic()
    for row, cause in (([3, 4, 5], "weak"), ([0, 8, 13], "unstable")):
        pinned = np.zeros(len(v), dtype=bool)
        pinned[row] = True
        model = Model.build(v, edges, 0.0, 0.1, np.zeros((0, 4), dtype=np.int64), 0.0, pinned)
        exc = qs._not_converged(model, v, 7, 0.5, Failure(3e-9, 0.25, "stalled", "indefinite"))
        assert exc.cause == cause, str(exc)
        text = str(exc)
        assert text.startswith("no equilibrium at step 7 (growth A = 0.5): residual force 3e-09")
        assert "times its rounding level" in text and "force scale 0.25" in text
        assert ("on a line" in text) == (cause == "weak")
        assert ("no stable equilibrium there (it buckles" in text) == (cause == "unstable")


def test_simulate_names_the_cause_in_one_line(tmp_path, monkeypatch):
    """The stage's message for each cause: a stall at the rest state does not blame the
    growth curve; a piece held on a line points at axis.base_fraction; one line, the
    typo 'found no equilibrium found' gone, no output file."""
    from click.testing import CliRunner

    from pipeline.flower import axis
    from pipeline.sim.solver.newton import Failure, Newton
    from stages.cli import cli

    runner = CliRunner()
    mesh, paths = tmp_path / "petal.obj", {k: tmp_path / f"{k}.h5" for k in ("r", "a", "g")}
    assert runner.invoke(cli, ["asset", "petal", "--vertices", "200", "--out", str(mesh)]).exit_code == 0
    for stage, src, out in (("remesh", mesh, "r"), ("axis", paths["r"], "a"),
                            ("growth", paths["a"], "g")):
        r = runner.invoke(cli, ["-q", stage, str(src), "--out", str(paths[out])])
        assert r.exit_code == 0, r.output

    def stall(self, model, state, effects, A):
        return Failure(3e-9, 0.25, "stalled", "indefinite")

    monkeypatch.setattr(Newton, "solve", stall)
    lines = {}
    for case in ("rest", "weak"):
        if case == "weak":  # every base now counts as a line
            monkeypatch.setattr(axis, "MIN_BASE_WIDTH", 1.0)
        out = tmp_path / f"sim-{case}.h5"
        r = runner.invoke(cli, ["-q", "simulate", str(paths["g"]), "--out", str(out), "--set",
                                "simulate.integrator=quasi-static"])
        line = r.output.strip()
        assert r.exit_code != 0 and len(line.splitlines()) == 1 and not out.exists(), line
        assert "found no equilibrium at step 0 (growth A = 0)" in line, line
        assert "found no equilibrium found" not in line
        assert "times its rounding level" in line, line
        lines[case] = line
    assert "simulate.stages" in lines["rest"] and "rest state is no stable" in lines["rest"]
    assert "growth curve" not in lines["rest"]
    assert "axis.base_fraction" in lines["weak"] and "base is a line" in lines["weak"]
    assert "spin about it" in lines["weak"] and "petal 0" in lines["weak"]


def test_inertia_plays_a_jump_in_growth_out_over_frames_and_comes_to_rest(petal):
    """The inertia term (implicit Euler, incremental-potential form): growth jumps to
    A = 1 in one time unit; the petal takes many frames to get to the equilibrium there
    (it moves, with kinetic energy), then comes to rest on it. With a time step far
    longer than the petal's slowest period the first frame is already the equilibrium:
    the quasi-static path is the limit."""
    m = petal.model
    control = Control("linear", 1.0)
    eq = State.at_rest(m, petal.vertices, control)
    QuasiStatic(stages=10, tolerance=1e-9).advance(m, eq, control, 1, 1.0)
    length = petal.length

    def error(X):
        return accuracy.shape_error(petal, X, eq.positions)[0]

    start = error(petal.vertices)
    assert start > 0.05  # the jump moves the petal a lot
    state = State.at_rest(m, petal.vertices, control)
    qs = QuasiStatic(stages=10, tolerance=1e-9, inertia=True)
    errors, energies = [], []
    for _ in range(60):
        qs.advance(m, state, control, 2000, 1.0)
        errors.append(error(state.positions))
        energies.append(state.kinetic_energy(m))
    assert errors[0] > 0.2 * start  # one frame is not enough: inertia holds it back
    assert max(energies) > 1e-9 * m.vertex_count * length ** 2  # it moved
    assert energies[-1] < 1e-6 * max(energies)  # and came to rest ...
    assert errors[-1] < 1e-4  # ... on the equilibrium
    assert np.array_equal(state.velocities[m.pinned], np.zeros_like(state.velocities[m.pinned]))

    limit = State.at_rest(m, petal.vertices, control)
    QuasiStatic(stages=10, tolerance=1e-9, inertia=True).advance(m, limit, control, 10**12, 1.0)
    assert error(limit.positions) < 1e-5


@pytest.mark.parametrize("effects", [(), ("collisions",)])
def test_threads_give_the_same_arrays_as_one(monkeypatch, effects):
    """Petals that do not interact solve in threads, and with contact the groups of a
    Newton step factor in threads: the bloom is the same to the bit with one thread as
    with three, and the threads are used."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    from pipeline.sim import threads as qs_module

    scene = accuracy.Scene.bud(6, 300)
    threads = set()
    factor = System.factor

    def watched(self, *args, **kwargs):
        threads.add(threading.get_ident())
        return factor(self, *args, **kwargs)

    monkeypatch.setattr(System, "factor", watched)
    runs = []
    for workers in (1, 3):
        pool = ThreadPoolExecutor(workers)
        monkeypatch.setattr(qs_module, "_POOL", pool)
        threads.clear()
        runs.append(accuracy.simulate(scene, "quasi-static", ramp=1, stages=5, effects=effects))
        used = len(threads - {threading.get_ident()})
        pool.shutdown()
        assert used >= 2 if workers > 1 else used == 1
    assert runs[0].iterations == runs[1].iterations > 0
    assert np.array_equal(runs[0].positions, runs[1].positions)


@pytest.mark.parametrize("names, inertia, flowers", [((), False, 1), (("collisions",), False, 1),
                                                      (("connections",), True, 1),
                                                      (("collisions",), False, 2)],
                         ids=["independent-petals", "contact", "springs-inertia",
                              "contact-two-flowers"])
def test_the_solver_state_restored_mid_path_goes_on_to_the_same_bits(names, inertia, flowers):
    """The quasi-static solver's state (:meth:`QuasiStatic.state`) taken after 6 frames
    and restored into a fresh solver (as ``simulate --resume`` does from a checkpoint)
    gives the frames after it to the bit, and the same Newton counts. Two buds far apart
    with contact are two problems, each with its own contact."""
    import copy

    from pipeline.mesh import procedural
    from pipeline.sim.build import Prepared
    from pipeline.sim.effects import Params
    from pipeline.sim.run import frame_steps

    v, f, p = procedural.bud(3, 600, 0)
    if flowers == 2:  # (a second bud, far off: two problems)
        far = 10.0 * np.ptp(v, axis=0).max()
        v, f, p = np.vstack([v, v + [far, 0.0, 0.0]]), np.vstack([f, f + len(v)]), np.r_[p, p + 3]
    prep = Prepared.from_mesh(v, f, p)
    model = prep.model(0.1, 0.0005)
    params = Params.defaults().but(connections={"max_distance": 3.0})
    steps, frames = 20000, 13
    control = Control("smootherstep", 0.6 * steps)
    targets = frame_steps(steps, frames)

    def fresh():
        return (QuasiStatic(stages=20, inertia=inertia), State.at_rest(model, prep.vertices, control),
                prep.effects(names, params))

    def go(qs, state, fx, upto):
        out = []
        for t in targets[1:upto]:
            qs.advance(model, state, control, int(t - state.step), 1.0, fx)
            out.append((state.positions.copy(), qs.counts.iterations))
        return out

    whole = go(*fresh(), len(targets))
    qs, state, fx = fresh()
    if flowers == 2:
        go(qs, state, fx, 2)
        assert len(qs._parts) == 2 and all(pt.solver.newton.contact is not None
                                           for pt in qs._parts)
        qs, state, fx = fresh()
    go(qs, state, fx, 7)
    saved = copy.deepcopy(qs.state())
    arrays = {k: a.copy() for k, a in fx.bundle()._asdict().items() if isinstance(a, np.ndarray)}
    qs2, state2, fx2 = fresh()
    state2.positions[:], state2.velocities[:], state2.step = (state.positions, state.velocities,
                                                             state.step)
    for k, a in fx2.bundle()._asdict().items():
        if isinstance(a, np.ndarray):
            a[...] = arrays[k]
    qs2.restore(model, state2, fx2, saved)
    rest = []
    for t in targets[7:]:
        qs2.advance(model, state2, control, int(t - state2.step), 1.0, fx2)
        rest.append((state2.positions.copy(), qs2.counts.iterations))
    assert len(rest) == len(whole) - 6
    for (a, ia), (b, ib) in zip(whole[6:], rest, strict=True):
        assert np.array_equal(a, b) and ia == ib
    assert not np.array_equal(whole[6][0], whole[-1][0])  # (it did move after the restore)


def test_an_energy_taken_again_at_the_same_point_is_not_evaluated_again(monkeypatch):
    """The solver asks for the energy at the same X and growth more than once (a
    predictor's accepted step is the next solve's first iterate; a converged solve's X
    is the frame's, and a held frame's is the one before): the second time it is the
    first's result, the same bits. A bud with contact blooms over 12 frames to the same
    arrays with and without that, in fewer evaluations (measured: 163 against 201);
    with connection springs (they break as their forces are taken) or the inertia term
    nothing is kept."""
    from pipeline.sim.solver.newton import Newton

    scene = accuracy.Scene.bud(6, 300)
    evaluate, key = Newton._evaluate, Newton._memo_key
    count = [0]

    def counted(self, X, scratch):
        count[0] += 1
        return evaluate(self, X, scratch)

    def bloom():
        control = Control("smootherstep", 100.0)
        state = State.at_rest(scene.model, scene.vertices, control)
        qs = QuasiStatic(stages=20)
        effects = scene.effects(("collisions",))
        for _ in range(12):  # 10 frames of growth, 2 held
            qs.advance(scene.model, state, control, 10, 1.0, effects)
        return state.positions.copy(), state.potential_energy, qs.iterations

    monkeypatch.setattr(Newton, "_evaluate", counted)
    runs, counts = [], []
    for kept in (key, lambda self: None):
        monkeypatch.setattr(Newton, "_memo_key", kept)
        count[0] = 0
        runs.append(bloom())
        counts.append(count[0])
    assert np.array_equal(runs[0][0], runs[1][0]) and runs[0][1:] == runs[1][1:]
    assert counts[0] < 0.9 * counts[1], counts
    assert key(Newton(1e-6, 10, None, springs=object())) is None


def test_a_bloom_that_finds_no_equilibrium_past_half_growth_is_held_there(tmp_path, monkeypatch):
    """A bloom from a bud whose solver finds no equilibrium past A = 0.5 (the water lily's
    petal 35 folded through itself at A = 0.969, after 7 minutes of a run that was then
    refused): the frames it reached are kept, the last one held for the rest, the
    summary unsound and naming where it stopped; sim.h5 and report.json say so. A failure
    at the very start (no frame past the bud) is still refused (above)."""
    from click.testing import CliRunner

    from pipeline.sim.solver.newton import Failure, Newton
    from stages.cli import cli

    runner = CliRunner()
    mesh, paths = tmp_path / "petal.obj", {k: tmp_path / f"{k}.h5" for k in ("r", "a", "g")}
    assert runner.invoke(cli, ["asset", "petal", "--vertices", "200", "--out", str(mesh)]).exit_code == 0
    for stage, src, out in (("remesh", mesh, "r"), ("axis", paths["r"], "a"),
                            ("growth", paths["a"], "g")):
        assert runner.invoke(cli, ["-q", stage, str(src), "--out", str(paths[out])]).exit_code == 0
    real = Newton.solve

    def past_half(self, model, state, effects, A):
        return Failure(3e-3, 1.0, "stalled", "indefinite") if A > 0.5 else real(
            self, model, state, effects, A)

    monkeypatch.setattr(Newton, "solve", past_half)
    out = tmp_path / "s.h5"
    r = runner.invoke(cli, ["simulate", str(paths["g"]), "--out", str(out), "--set",
                            "simulate.frames=11", "--set", "growth.start=bud"])
    assert r.exit_code == 0, r.output
    assert "the bloom stops at A = 0.5" in r.output, r.output
    with h5py.File(out) as h:
        assert abs(h.attrs["bloom_stopped_at"] - 0.5) < 1e-9
        assert list(h.attrs["bloom_stopped_petals"]) == [0]
        assert "unsound" in h.attrs["summary"] and "the bloom stops at A = 0.5" in h.attrs["summary"]
        X, growth = h["frames/positions"][()], h["diagnostics/growth"][()]
        t = h["frames/time"][()]
    assert len(X) == 11 and np.all(np.diff(t) > 0)
    reached = int(np.flatnonzero(growth == growth[-1])[0])  # the frame held
    assert 0 < reached < 10 and np.all(growth[reached:] == growth[reached])
    assert np.all(X[reached + 1:] == X[reached]) and not np.array_equal(X[reached], X[0])
    r = runner.invoke(cli, ["report", str(out), "--out", str(tmp_path / "report.json")])
    assert r.exit_code == 0, r.output
    assert abs(json.loads((tmp_path / "report.json").read_text())["bloom_stopped_at"] - 0.5) < 1e-9
