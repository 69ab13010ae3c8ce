"""growth.start = "open": from a model of the open flower, its bud, and the bloom back to it."""

from __future__ import annotations

import dataclasses

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from pipeline.flower.axis import find_axes
from pipeline.flower.growth import assign_growth
from pipeline.mesh import clean, procedural
from pipeline.mesh.hinge import edge_lengths
from pipeline.sim import reverse
from pipeline.sim.effects import Effects
from pipeline.sim.model import Control, State
from pipeline.sim.solver.quasistatic import QuasiStatic
from pipeline.sim.terms.elastic import internal_forces
from stages.cli import cli
from tests.conftest import build_model


def open_petal(vertices: int = 150):
    """One tepal of the procedural open lily, at mean edge 1, with its axes and growth."""
    v, f, petal = procedural.open_flower(1, vertices, 0)
    v = v / clean.mean_edge_length(v, f)
    axes = find_axes(v, f, petal)
    return v, f, petal, axes, assign_growth(v, f, axes.x, "0.2*x**2")


def residual(model, X, growth: float) -> float:
    """Largest free-vertex force over the largest spring force scale (k times a rest length)."""
    F = np.zeros_like(X)
    internal_forces(X, model.edge_indices, model.edge_rest_length, model.edge_growth,
                            model.edge_stiffness, model.hinge_indices, model.hinge_rest_cos,
                            model.hinge_rest_sin, model.hinge_stiffness, growth, F)
    F[model.pinned] = 0.0
    scale = float(np.max(model.edge_stiffness * model.edge_rest_length))
    return float(np.abs(F).max() / scale)


def test_the_open_model_is_the_rest_state_at_full_growth():
    v, f, petal, axes, growth = open_petal()
    model = reverse.open_model(build_model(v, growth, axes), 1.0)
    rest = model.edge_rest_length * (1.0 + model.edge_growth)
    length = np.empty(model.edge_count)
    edge_lengths(v, model.edge_indices, length)
    np.testing.assert_allclose(rest, length, rtol=1e-14)
    assert residual(model, v, 1.0) < 1e-12
    assert residual(model, v, 0.0) > 1e-4  # shorter rest lengths at the bud: not at rest there
    half = reverse.open_model(build_model(v, growth, axes), 0.5)
    np.testing.assert_allclose(half.edge_growth, 0.5 * model.edge_growth)
    with pytest.raises(ValueError, match="growth.close"):
        reverse.open_model(build_model(v, growth, axes), -1e3)
    with pytest.raises(ValueError, match="curl"):
        reverse.open_rest_angle(np.ones(3), 1.0)


def test_backward_then_forward_returns_to_the_model_and_the_bud_is_an_equilibrium():
    """One tepal: the bud is found backward (A 1 -> 0), is an equilibrium at A = 0 (to
    rounding), is closed (its tip nearer the axis), and growing it forward again ends on
    the model to the solver's tolerance."""
    v, f, petal, axes, growth = open_petal()
    model = reverse.open_model(build_model(v, growth, axes), 1.0)
    bud, solver = reverse.find_bud(model, v, Effects(), stages=20, tolerance=1e-6)
    assert solver.counts.increments >= 20
    assert residual(model, bud, 0.0) < 1e-9
    moved = reverse.distance_to_model(bud, v, petal, axes.base)
    assert moved > 0.05  # it closed by a twentieth of its length or more
    tip = int(axes.tip[0])
    assert np.hypot(*bud[tip, :2]) < np.hypot(*v[tip, :2])  # the tip came in toward the axis
    control = Control("linear", 10.0)
    state = State.at_rest(model, bud, control)
    QuasiStatic().advance(model, state, control, 10, 1.0)
    assert reverse.distance_to_model(state.positions, v, petal, axes.base) < 1e-6


@pytest.mark.slow
def test_the_open_lily_scene_blooms_back_to_itself(tmp_path):
    """The default scene lily_open, end to end: the last frame is the model, the first is
    at least 20 deg less open."""
    from tests.conftest import ROOT

    out = tmp_path / "s"
    runner = CliRunner()
    config = str(ROOT / "configs" / "lily_open.toml")
    for stage, src in (("remesh", None), ("axis", "remesh"), ("growth", "axis"), ("simulate", "growth")):
        args = [stage] + ([str(out / f"{src}.h5")] if src else []) + [
            "--config", config, "--out", str(out / f"{stage}.h5")]
        result = runner.invoke(cli, args)
        assert result.exit_code == 0, result.output
    with h5py.File(out / "simulate.h5") as h:
        assert h.attrs["distance_to_model"] < 1e-3
        opening = h["diagnostics/opening_angle"][()]
        assert opening[-1] - opening[0] >= 20.0
        np.testing.assert_array_equal(h["open/bud"][()], h["frames/positions"][0])


def test_the_lift_chooses_the_branch_a_flat_petal_closes_on():
    """A flat, horizontal petal closes up or down (the path forks): lifted toward +z it
    closes up, toward -z down, and either way the bud is the model's own equilibrium."""
    v, f, petal = procedural.open_flower(1, 150, 0, procedural.OpenShape(lean=90.0, recurve=90.0,
                                                                trough=1e3))
    v = v / clean.mean_edge_length(v, f)
    assert np.ptp(v[:, 2]) < 1e-3 * np.ptp(v[:, 0])  # flat
    axes = find_axes(v, f, petal)
    growth = assign_growth(v, f, axes.x, "0.2*x**2")
    model = reverse.open_model(build_model(v, growth, axes), 1.0)
    size = 0.05 * reverse.petal_lengths(v, petal, axes.base).mean()
    tips = []
    for sign in (1.0, -1.0):
        lift = reverse.closing_lift(v, axes.s, axes.x, axes.base, [0.0, 0.0, sign], size)
        bud, _ = reverse.find_bud(model, v, Effects(), stages=20, tolerance=1e-6, lift=lift)
        assert residual(model, bud, 0.0) < 1e-9
        tips.append(bud[int(axes.tip[0]), 2] - v[axes.base, 2].mean())
    length = reverse.petal_lengths(v, petal, axes.base)[0]
    assert tips[0] > 0.05 * length and tips[1] < -0.05 * length, tips


def test_a_bud_search_that_finds_no_equilibrium_closes_half_as_far(tmp_path, monkeypatch):
    """Where the path to the bud crumples a petal (a rose's rolled rim), the bud is found
    closing half as far (logged, recorded as bud_close), not refused; after
    CLOSE_TRIES halvings it is refused in one line naming growth.close."""
    from pipeline.sim.solver.newton import NotConverged

    v, f, p = procedural.open_flower(3, 600, 0)
    mesh = tmp_path / "open.obj"
    procedural.write_obj(mesh, v, f, p, "an open flower")
    real = reverse.find_bud
    closes = []

    def crumples_at_full_close(model, *args, **kwargs):
        closes.append(float(np.max(np.abs(model.edge_growth))))
        if len(closes) == 1 or fail_always:
            raise NotConverged(0, 0.5, 1.0, scale=1.0, vertex=0)
        return real(model, *args, **kwargs)

    monkeypatch.setattr(reverse, "find_bud", crumples_at_full_close)
    # (five frames: with the bud's cup, a bloom in five steps lands 1.4% off the model and
    # the search is made again along the model's own path, at growth.close 1; the halving
    # is what is tested here, so the bud keeps the model's curvature)
    short = ["--set", "growth.start=open", "--set", "simulate.frames=5",
             "--set", "growth.cup=0", "--set", "growth.recurve=false"]
    out = {k: tmp_path / f"{k}.h5" for k in ("r", "a", "g", "s")}
    for stage, src, dst in (("remesh", mesh, "r"), ("axis", out["r"], "a"), ("growth", out["a"], "g")):
        assert CliRunner().invoke(cli, [stage, str(src), "--out", str(out[dst])]).exit_code == 0
    fail_always = False
    r = CliRunner().invoke(cli, ["simulate", str(out["g"]), "--out", str(out["s"]), *short])
    assert r.exit_code == 0, r.output
    assert closes[1] == pytest.approx(0.5 * closes[0])  # (the growth ratios, halved)
    assert "closing half as far" in r.output
    with h5py.File(out["s"]) as h:
        assert h.attrs["bud_close"] == 0.5
    fail_always = True
    r = CliRunner().invoke(cli, ["simulate", str(out["g"]), "--out", str(tmp_path / "t.h5"), *short])
    assert r.exit_code != 0 and "growth.close" in r.output and "0.25" in r.output
    assert not (tmp_path / "t.h5").exists()


def _open_flower_stages(tmp_path) -> dict:
    """A procedural open 3-petal flower through remesh, axis and growth: the artifacts'
    paths (``r``, ``a``, ``g``; ``s`` for simulate's)."""
    v, f, p = procedural.open_flower(3, 600, 0)
    mesh = tmp_path / "open.obj"
    procedural.write_obj(mesh, v, f, p, "an open flower")
    out = {k: tmp_path / f"{k}.h5" for k in ("r", "a", "g", "s")}
    for stage, src, dst in (("remesh", mesh, "r"), ("axis", out["r"], "a"), ("growth", out["a"], "g")):
        assert CliRunner().invoke(cli, [stage, str(src), "--out", str(out[dst])]).exit_code == 0
    return out


def _folds_at(real, growth: float):
    """``real`` (the chain's integrate) cut to its first frame, then a NotConverged at
    ``growth`` naming the last vertex: a bloom forward that folds off its branch."""
    from pipeline.sim.solver.newton import NotConverged

    def folds(model, state, control, integrator, **kwargs):
        real(model, state, control, integrator, **{**kwargs, "frames": 2, "steps": 1})
        raise NotConverged(0, growth, 1.0, scale=1.0, vertex=len(state.positions) - 1)

    return folds


def test_a_bloom_that_leaves_its_branch_is_the_path_back_played_forward(tmp_path, monkeypatch):
    """Where the forward run from the bud finds no equilibrium (the path forward folds off
    the branch the bud was found on), the bloom of an open model is the model's own path
    to its bud, played forward: logged, recorded as bloom_path, the last frame the model
    itself, the first the bud (more closed), growth and the solver's counts rising."""
    from pipeline.chain import problem as chain

    out = _open_flower_stages(tmp_path)
    monkeypatch.setattr(chain, "integrate", _folds_at(chain.integrate, 0.3))
    r = CliRunner().invoke(cli, ["simulate", str(out["g"]), "--out", str(out["s"]), "--set",
                                 "growth.start=open", "--set", "simulate.frames=9"])
    assert r.exit_code == 0, r.output
    assert "played forward" in r.output and "A = 0.3 (petal 2)" in r.output
    with h5py.File(out["s"]) as h:
        assert h.attrs["bloom_path"] == "retraced" and h.attrs["bud_path"] == "own"
        X = h["frames/positions"][()]
        assert len(X) == 9 and h.attrs["distance_to_model"] < 1e-12
        np.testing.assert_array_equal(h["open/bud"][()], X[0])
        d = h["diagnostics"]
        growth, opening = d["growth"][()], d["opening_angle"][()]
        assert growth[0] == 0.0 and growth[-1] == 1.0 and np.all(np.diff(growth) >= 0.0)
        assert np.all(np.diff(d["newton_iterations"][()]) >= 0) and d["newton_iterations"][-1] > 0
        assert opening[-1] - opening[0] > 10.0 and not d["intersecting"][()].any()
        assert h.attrs["summary"].startswith("sound")


def _closes_first(real, dip: float):
    """``real`` (the chain's integrate), its frames' openings lowered by a bump of
    ``dip`` deg over the first half: a bloom forward that closes before it opens."""
    def closes(model, state, control, integrator, **kwargs):
        rec, wall = real(model, state, control, integrator, **kwargs)
        frames = len(rec.time)
        bump = dip * np.sin(np.pi * np.clip(np.arange(frames) / (frames // 2), 0.0, 1.0))
        per = rec.diagnostics["opening_angle_per_petal"]
        rec.diagnostics["opening_angle_per_petal"] = [a - b for a, b in zip(per, bump, strict=True)]
        rec.diagnostics["opening_angle"] = [float(np.mean(a)) for a in
                                            rec.diagnostics["opening_angle_per_petal"]]
        return rec, wall

    return closes


@pytest.mark.parametrize("bud_hangs_open", [False, True])
def test_a_bloom_that_closes_first_is_the_path_back_played_forward(tmp_path, monkeypatch,
                                                                   bud_hangs_open):
    """An open start whose bloom from its bud closes first (its mean opening more than
    report.CLOSES_FIRST below the start: hallgeirl's flower closed 48 deg at once) is the
    model's own path back to its bud, played forward, where that closes less first and
    its bud is more closed than the model: logged, recorded, sound. A path back whose bud
    hangs open the other way is no bloom: the bloom from the bud is kept, and starts from
    its most closed frame (its first frames hold it)."""
    from pipeline.chain import problem as chain
    from pipeline.review import report
    from pipeline.sim.build import Prepared

    out = _open_flower_stages(tmp_path)
    monkeypatch.setattr(chain, "integrate", _closes_first(chain.integrate, 30.0))
    if bud_hangs_open:
        monkeypatch.setattr(Prepared, "bud_closed", lambda self, bud, model: -4.0)
    r = CliRunner().invoke(cli, ["simulate", str(out["g"]), "--out", str(out["s"]), "--set",
                                 "growth.start=open", "--set", "simulate.frames=9",
                                 "--set", "simulate.petal_vertices=0"])  # (as it is: quicker)
    assert r.exit_code == 0, r.output
    assert "deg (mean over its petals) before it opens (over 5)" in r.output
    with h5py.File(out["s"]) as h:
        opening = h["diagnostics/opening_angle_per_petal"][()]
        if bud_hangs_open:  # (its bloom then starts from its most closed frame)
            assert "the bloom from the bud kept" in r.output
            assert "it starts from its most closed frame (frame " in r.output
            assert "bloom_path" not in h.attrs  # (not the path back)
            X, growth = h["frames/positions"][()], h["diagnostics/growth"][()]
            first = int(np.argmax(growth > growth[0])) - 1  # (the most closed frame)
            assert first >= 1 and 0.0 < h.attrs["bud_growth"] == growth[0] < growth[-1]
            for k in range(first):
                np.testing.assert_array_equal(X[k], X[first])
            np.testing.assert_array_equal(h["open/bud"][()], X[0])
            assert report.closing_dip(opening) <= report.CLOSES_FIRST
        else:
            assert "the path back kept: it closes 0.0 deg first" in r.output
            assert h.attrs["bloom_path"] == "retraced" and h.attrs["bud_path"] == "own"
            # (no dip: the first frame's angles are the bud's own, 0 to rounding)
            assert report.closing_dip(opening) <= 1e-9 * opening[-1].max()
            assert opening[-1].min() > 10.0
            assert h.attrs["distance_to_model"] < 1e-12
            assert h.attrs["summary"].startswith("sound")


@pytest.mark.parametrize("bud_hangs_open", [False, True])
def test_a_bloom_that_closes_first_is_stopped_there_and_goes_on_only_if_needed(
        tmp_path, monkeypatch, bud_hangs_open):
    """An open start's bloom from its bud is stopped at the frame at which it has closed
    first (over report.CLOSES_FIRST) and the path back tried then: kept, the rest of the
    bloom is never run; not kept (its bud hangs open the other way), the bloom goes on
    from the frame it stopped at, and ends the same bits as one that was never stopped.
    (The dip is a stand-in: 30 deg on the frames of a bloom not yet at its end.)"""
    from pipeline.review import report
    from pipeline.sim.build import Prepared

    out = _open_flower_stages(tmp_path)
    args = ["simulate", str(out["g"]), "--set", "growth.start=open", "--set",
            "simulate.frames=9", "--set", "simulate.petal_vertices=0", "--out"]
    whole = CliRunner().invoke(cli, args + [str(tmp_path / "whole.h5")])
    assert whole.exit_code == 0 and "before it opens" not in whole.output, whole.output
    real = report.closing_dip
    monkeypatch.setattr(report, "closing_dip",
                        lambda opening: 30.0 if 1 < len(opening) < 9 else real(opening))
    if bud_hangs_open:
        monkeypatch.setattr(Prepared, "bud_closed", lambda self, bud, model: -4.0)
    r = CliRunner().invoke(cli, args + [str(out["s"])])
    assert r.exit_code == 0, r.output
    assert "closes 30.0 deg (mean over its petals) by frame 1 before it opens" in r.output
    with h5py.File(out["s"]) as h, h5py.File(tmp_path / "whole.h5") as w:
        if bud_hangs_open:
            assert "the rest of the bloom from the bud, from frame 1" in r.output
            assert "bloom_path" not in h.attrs
            np.testing.assert_array_equal(h["frames/positions"][()], w["frames/positions"][()])
        else:
            assert "the rest of the bloom" not in r.output
            assert h.attrs["bloom_path"] == "retraced"


def test_the_lifted_and_the_own_path_share_one_path_back(tmp_path, monkeypatch):
    """The path back depends on the bud's model only, the same for the lifted and the own
    path at one growth.close: where both blooms close first (and every path back is
    refused: its bud hangs open the other way), it is run once for the two (the faded
    path's is its own), and the own path's bloom decides on it as the lifted's did."""
    from pipeline.chain import problem as chain
    from pipeline.review import report
    from pipeline.sim.build import Prepared

    out = _open_flower_stages(tmp_path)
    monkeypatch.setattr(chain, "integrate", _closes_first(chain.integrate, 30.0))
    monkeypatch.setattr(Prepared, "bud_closed", lambda self, bud, model: -4.0)
    monkeypatch.setattr(report, "OFF_MODEL", -1.0)  # (every bloom is searched again)
    real, made = chain.retrace, []

    def counted(model, *args, **kwargs):
        made.append(model)
        return real(model, *args, **kwargs)

    monkeypatch.setattr(chain, "retrace", counted)
    r = CliRunner().invoke(cli, ["simulate", str(out["g"]), "--out", str(out["s"]), "--set",
                                 "growth.start=open", "--set", "simulate.frames=9", "--set",
                                 "simulate.petal_vertices=0"])
    assert r.exit_code == 0, r.output
    refused = [line for line in r.output.splitlines() if "the path back closes" in line]
    assert len(refused) == 3 and refused[0] == refused[1], refused  # (lifted, own; faded)
    assert "searching again along the model's own" in r.output
    assert r.output.count("not run again") == 1 and len(made) == 2


@pytest.mark.parametrize("hangs_open", [False, True])
def test_an_unlifted_open_start_is_its_own_path_followed_once(tmp_path, monkeypatch,
                                                               hangs_open):
    """Where contact cuts the closing lift to nothing (petals that start within the gap of
    each other: hallgeirl's, four more of the external models), the lifted path is the
    model's own: it is followed once, as the path back, and is the bloom, with no bud
    search and no bloom from a bud (the same frames a closing-first bloom's path back
    gives). Where that path is no bloom (its bud hangs open the other way) the bud is
    searched for and bloomed from, as before."""
    from pipeline.sim.build import Prepared

    out = _open_flower_stages(tmp_path)
    monkeypatch.setattr(reverse, "contact_free", lambda lift, *args: np.zeros_like(lift))
    searched, real = [], reverse.find_bud
    monkeypatch.setattr(reverse, "find_bud", lambda *a, **k: searched.append(1) or real(*a, **k))
    if hangs_open:
        monkeypatch.setattr(Prepared, "bud_closed", lambda self, bud, model: -4.0)
    r = CliRunner().invoke(cli, ["simulate", str(out["g"]), "--out", str(out["s"]), "--set",
                                 "growth.start=open", "--set", "simulate.frames=9", "--set",
                                 "simulate.petal_vertices=0"])
    assert r.exit_code == 0, r.output
    assert "with the lift cut to nothing the path to the bud is the model's own" in r.output
    with h5py.File(out["s"]) as h:
        if hangs_open:
            assert "its bud hangs open the other way (-4.0 deg); the bud searched" in r.output
            assert searched and "bloom_path" not in h.attrs
            assert h.attrs["bud_seconds"] > 0.0
        else:
            assert not searched and "the model's own path kept as the bloom" in r.output
            assert h.attrs["bloom_path"] == "retraced" and h.attrs["bud_seconds"] == 0.0
            X = h["frames/positions"][()]
            np.testing.assert_array_equal(h["open/bud"][()], X[0])
            assert h.attrs["distance_to_model"] < 1e-12
            assert h["diagnostics/opening_angle"][-1] - h["diagnostics/opening_angle"][0] > 10.0
            assert h.attrs["summary"].startswith("sound")


def test_closing_dip_is_the_mean_openings_fall_below_its_start():
    from pipeline.review.report import closing_dip

    assert closing_dip(np.array([[0.0, 0.0], [-4.0, -8.0], [10.0, 20.0]])) == 6.0
    assert closing_dip(np.array([[0.0, 0.0], [1.0, -0.5], [10.0, 20.0]])) == 0.0
    assert closing_dip(np.zeros((0, 3))) == 0.0


def test_a_path_back_that_stops_short_of_the_bud_blooms_from_where_it_stopped(
        tmp_path, monkeypatch):
    """Where the bloom forward leaves its branch and the model's own path back then finds
    no equilibrium before A = 0 (a triangle that collapses near the bud), the bloom is
    that path as far as it went, played forward: its first frames hold the last
    equilibrium reached, logged and recorded (``bud_growth``), the last frame the model."""
    from pipeline.chain import problem as chain
    from pipeline.sim.run import Recording, frame_steps
    from pipeline.sim.solver.newton import NotConverged

    out = _open_flower_stages(tmp_path)
    back = reverse.integrate

    def stops(model, state, control, integrator, **kwargs):
        rec, _ = back(model, state, control, integrator, **kwargs)
        exc = NotConverged(0, 0.05, 1.0, scale=1.0, vertex=len(state.positions) - 1)
        exc.recording = Recording(rec.time[:6], rec.positions[:6],
                                  {k: list(x[:6]) for k, x in rec.diagnostics.items()})
        exc.frame_steps = frame_steps(kwargs["steps"], kwargs["frames"])
        raise exc

    monkeypatch.setattr(chain, "integrate", _folds_at(chain.integrate, 0.3))
    monkeypatch.setattr(reverse, "integrate", stops)
    r = CliRunner().invoke(cli, ["simulate", str(out["g"]), "--out", str(out["s"]), "--set",
                                 "growth.start=open", "--set", "simulate.frames=9"])
    assert r.exit_code == 0, r.output
    assert "the path back found no equilibrium below A = " in r.output
    with h5py.File(out["s"]) as h:
        X = h["frames/positions"][()]
        growth = h["diagnostics/growth"][()]
        reached = float(h.attrs["bud_growth"])
        assert h.attrs["bloom_path"] == "retraced" and len(X) == 9
        assert 0.0 < reached < 1.0 and growth[0] == reached and growth[-1] == 1.0
        assert np.all(np.diff(growth) >= 0.0)
        for k in range(1, 4):  # (the frames below the growth reached hold the bud)
            np.testing.assert_array_equal(X[k], X[0])
        assert not np.array_equal(X[4], X[0])
        np.testing.assert_array_equal(h["open/bud"][()], X[0])
        assert h.attrs["distance_to_model"] < 1e-12


def test_an_open_shell_is_its_own_rest_state_and_blooms_back_to_itself():
    """The shell (``simulate.model = shell``) from an open model: at A = 1 the mesh is at
    rest, curvature included (with and without curl), and not at A = 0; the bud found
    backward grows forward onto the model to the solver's tolerance."""
    from pipeline.sim.build import Prepared
    from pipeline.sim.effects import Curl
    from pipeline.sim.terms.shell import ShellTerm

    v, f, petal, axes, growth = open_petal()
    opened = Prepared.of(v, f, petal, axes, growth).shell_model(27.3, 0.013, 1 / 3)

    def force(model, X, A, curl=None):
        g = ShellTerm(model, curl).at(A).gradient(X)
        g[model.pinned] = 0.0
        return np.abs(g).max()

    for beta in (0.0, 0.4):
        model = reverse.open_model(opened, 1.0, v, beta)
        curl = Curl.build(np.zeros(model.hinge_count), beta=beta) if beta else None
        at_bud = force(model, v, 0.0, curl)  # the bud's rest state is not the mesh
        assert at_bud > 0.0
        assert force(model, v, 1.0, curl) <= 1e-9 * at_bud
    with pytest.raises(ValueError, match="positions"):
        reverse.open_model(opened, 1.0)
    model = reverse.open_model(opened, 1.0, v)
    bud, _ = reverse.find_bud(model, v, Effects(), stages=20, tolerance=1e-6)
    assert reverse.distance_to_model(bud, v, petal, axes.base) > 0.05
    control = Control("linear", 10.0)
    state = State.at_rest(model, bud, control)
    QuasiStatic(perturbation=0.0).advance(model, state, control, 10, 1.0)
    assert reverse.distance_to_model(state.positions, v, petal, axes.base) < 1e-6


def test_a_sliver_whose_edges_grow_unevenly_keeps_an_area_at_the_bud(caplog):
    """A shell triangle whose edges' growth ratios would leave it no triangle at the bud
    (a rose's remeshed sliver, 17/18/145 deg, its long edge growing least: the rose bed's
    run stopped on "2 faces have no rest area") has its ratios evened out toward their
    mean, logged; every other triangle keeps its ratios, bit for bit."""
    from pipeline.sim.build import Prepared
    from pipeline.sim.terms.shell_kernels import rest_dets

    sliver = np.array([[0, 1, 2]])
    full = np.array([0.32864504, 0.165094, 0.17986026])  # (the rose's, opposite q0, q1, q2)
    growth, changed = reverse.even_growth(sliver, full, np.array([0.05, 0.2, 0.05]))
    det0, det1 = np.empty(1), np.empty(1)
    rest_dets(sliver, full / (1.0 + growth), growth, det0)
    rest_dets(sliver, full, np.zeros(3), det1)
    assert changed == [0]
    assert det0[0] * (1.0 + growth.mean()) ** 4 >= reverse.EVEN * det1[0]
    assert growth.mean() == pytest.approx(0.1, rel=1e-12)  # (evened toward, not cut)

    v, f, petal, axes, growth = open_petal()
    opened = Prepared.of(v, f, petal, axes, growth).shell_model(27.3, 0.013, 1 / 3)
    fe = opened.shell.face_edges
    steep = np.array(opened.edge_growth)
    steep[fe[40, 1:]] = 3.0  # (two edges of a triangle grow by 4x, its third not at all)
    with caplog.at_level("INFO", logger="bloom"):
        model = reverse.open_model(dataclasses.replace(opened, edge_growth=steep), 1.0, v,
                                   petal=petal)
    assert "sliver triangle(s) of petal(s) 0" in caplog.text
    det0 = np.empty(len(fe))
    rest_dets(fe, model.edge_rest_length, model.edge_growth, det0)
    assert np.all(det0 > 0.0)
    # (only the triangle and the ones around it: the edges changed are all within them)
    ring = np.unique(f[np.any(np.isin(f, opened.shell.face_indices[40]), axis=1)])
    changed = np.flatnonzero(model.edge_growth != steep)
    assert 0 < len(changed) <= 12
    assert np.all(np.isin(model.edge_indices[changed], ring))


def test_closing_twice_as_far_keeps_the_first_bud_unless_the_second_is_more_closed(monkeypatch):
    """With growth.close left unset, a bud under CLOSED deg more closed is searched again
    closing twice as far; the second is kept only if it is more closed (hallgeirl's at
    2 hung open the other way, -6.6 deg, and bloomed worse than the one at 1)."""
    from types import SimpleNamespace

    X = np.zeros((4, 3))
    X[:, 0] = np.arange(4.0)
    petal, base = np.zeros(4, dtype=np.int64), np.array([True, False, False, False])

    def found_at(cfg, close, *args, **kwargs):
        bud = X + np.array([0.0, 0.0, close])  # (the bud says which close found it)
        return bud, SimpleNamespace(iterations=1), "model", "angles", "params"

    monkeypatch.setattr(reverse, "_find_bud_closing", found_at)
    cfg = type("Cfg", (), {"given": set(), "__getitem__": lambda self, key: 1.0})()
    for closed, kept in (({1.0: 10.0, 2.0: -6.6}, 1.0), ({1.0: 10.0, 2.0: 30.0}, 2.0),
                         ({1.0: 10.0, 2.0: 15.0, 4.0: 12.0}, 2.0)):
        out = reverse.open_start(cfg, None, X, None, None, None, petal, base, None, None,
                                 None, "here", closed_by=lambda bud, c=closed: c[bud[0, 2]])
        assert out[-1]["bud_close"] == kept


def test_the_recurve_is_the_curvature_away_from_the_inside_and_the_cup_curves_toward_it():
    """``recurve_form`` keeps, per face, the principal curvatures of the sign that curves
    away from the inside (the flower's), and ``bloom_form`` takes the bud's cup off it;
    exact on quadratic sheets: a cylinder rolled either way, a saddle."""
    from pipeline.sim.budshape import BudShape, bloom_form, face_metrics, recurve_form
    from pipeline.sim.terms.shell_kernels import second_form
    from pipeline.sim.terms.shell_stencil import face_stencil, ghost_rows

    g = np.linspace(-1.0, 1.0, 9)
    xy = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    tri = []
    for i in range(8):
        for j in range(8):
            a, b, c, d = 9 * i + j, 9 * (i + 1) + j, 9 * (i + 1) + j + 1, 9 * i + j + 1
            tri += [(a, b, c), (a, c, d)]
    faces = np.array(tri, dtype=np.int64)

    def curvatures(z, inside):
        """The inside-relative principal curvatures of (form, recurve, bud) per face."""
        X = np.c_[xy, z(xy[:, 0], xy[:, 1])]
        opp = face_stencil(X, faces)
        crease = np.zeros((len(faces), 3, 2))
        ghost = np.ascontiguousarray(ghost_rows(X, faces, opp))
        form = np.empty((len(faces), 3))
        second_form(X, faces, opp, ghost, crease, form)
        side = np.full(len(faces), float(inside))
        out = recurve_form(X, faces, form, side)
        bud = form - bloom_form(X, faces, form, BudShape(side, cup=0.5, recurve=True), 2.0)
        metric = face_metrics(X, faces)

        def principal(b):
            a = np.stack([metric[:, [0, 1]], metric[:, [1, 2]]], 1)
            m = np.stack([b[:, [0, 1]], b[:, [1, 2]]], 1)
            return np.sort(np.linalg.eigvals(np.linalg.solve(a, inside * m)).real, axis=1)
        interior = np.all(np.abs(X[faces][:, :, :2]).max(axis=2) < 0.76, axis=1)
        return [principal(b)[interior] for b in (form, out, bud)]

    # (the face normals e1 x e2 point +z: z = +k x^2 / 2 curves toward +z)
    for inside, k in ((1.0, 0.6), (-1.0, 0.6), (1.0, -0.6), (1.0, 0.0)):
        form, out, bud = curvatures(lambda x, y, k=k: 0.5 * k * x ** 2 - 0.2 * y ** 2, inside)
        assert np.any(form < -0.1)  # (some curvature away from the inside)
        np.testing.assert_allclose(out, np.minimum(form, 0.0), atol=1e-9)
        # the bud: never curved away; cupped toward the inside by 0.5 / size (size 2)
        np.testing.assert_allclose(bud, np.maximum(form, 0.0) + 0.25, atol=1e-9)
    form, out, bud = curvatures(lambda x, y: 0.3 * x * x + 0.2 * y * y, 1.0)
    assert np.all(form > 0.1)  # a bowl toward the inside: no recurve
    np.testing.assert_allclose(out, 0.0, atol=1e-9)
    np.testing.assert_allclose(bud, form + 0.25, atol=1e-9)


def test_an_open_shell_with_its_bud_shape_is_at_rest_on_the_model_and_its_bud_is_not():
    """With the bud's cup and the recurve left out of the bud (growth.cup, growth.recurve),
    the model is still its own rest state at A = 1; at A = 0 the rest curvature is the
    bud's (the model's less :func:`bloom_form`); and the lifted path keeps the bud shape."""
    from pipeline.sim.budshape import BudShape, bloom_form, inner_sides
    from pipeline.sim.build import Prepared
    from pipeline.sim.terms.shell import ShellTerm

    v, f, petal, axes, growth = open_petal()
    opened = Prepared.of(v, f, petal, axes, growth).shell_model(27.3, 0.013, 1 / 3)
    inside = inner_sides(v, opened.shell.face_indices, petal, axes.s,
                                 np.full(6, np.nan))
    shape = BudShape(inside, cup=1.5, recurve=True)
    model = reverse.open_model(opened, 1.0, v, 0.0, petal, shape)
    plain = reverse.open_model(opened, 1.0, v)
    g = ShellTerm(model).at(1.0).gradient(v)
    g[model.pinned] = 0.0
    at_bud = ShellTerm(plain).at(0.0).gradient(v)
    at_bud[model.pinned] = 0.0
    assert np.abs(g).max() <= 1e-9 * np.abs(at_bud).max()
    form = model.shell.form_at(v)
    added = bloom_form(np.asarray(v, float), model.shell.face_indices, form, shape,
                       model.shell.size)
    scale = model.shell.face_rest_form / form  # the growth's per-face factor, both alike
    ok = np.abs(form) > 1e-6 * np.abs(form).max()
    np.testing.assert_allclose(model.shell.face_bloom_form[ok], (added * scale)[ok],
                               rtol=1e-9, atol=1e-12 * np.abs(added).max())
    assert np.abs(model.shell.face_bloom_form).max() > 0.0
    lifted = reverse.rest_at(model, v + 0.01)
    assert lifted.shell.bud is shape and np.abs(lifted.shell.face_bloom_form).max() > 0.0


def test_the_lift_faded_into_the_rest_state_picks_the_branch_and_keeps_the_model_at_rest():
    """The closing lift grown into the open shell's rest state at the bud, fading out over
    the bloom (reverse.lift_faded): at A = 1 the mesh is still at rest; at A = 0 the rest
    lengths are the lifted mesh's, undone by the growth; and the model's own path from the
    flat petal (which forks: up or down) closes toward the lift's side, either way."""
    from pipeline.sim.build import Prepared
    from pipeline.sim.terms.shell import ShellTerm

    v, f, petal = procedural.open_flower(1, 150, 0, procedural.OpenShape(lean=90.0, recurve=90.0,
                                                                trough=1e3))
    v = v / clean.mean_edge_length(v, f)
    axes = find_axes(v, f, petal)
    growth = assign_growth(v, f, axes.x, "0.2*x**2")
    opened = Prepared.of(v, f, petal, axes, growth).shell_model(27.3, 0.013, 1 / 3)
    model = reverse.open_model(opened, 1.0, v)
    size = 0.05 * reverse.petal_lengths(v, petal, axes.base).mean()
    length = reverse.petal_lengths(v, petal, axes.base)[0]
    for sign in (1.0, -1.0):
        lift = reverse.closing_lift(v, axes.s, axes.x, axes.base, [0.0, 0.0, sign], size)
        faded = reverse.lift_faded(model, v, lift)
        g = ShellTerm(faded).at(1.0).gradient(v)
        g[faded.pinned] = 0.0
        at_bud = ShellTerm(faded).at(0.0).gradient(v)
        at_bud[faded.pinned] = 0.0
        assert np.abs(g).max() <= 1e-9 * np.abs(at_bud).max()
        up = np.empty(model.edge_count)
        edge_lengths(np.ascontiguousarray(v + lift), model.edge_indices, up)
        np.testing.assert_allclose(faded.edge_rest_length, up / (1.0 + model.edge_growth),
                                   rtol=1e-12)
        bud, _ = reverse.find_bud(faded, v, Effects(), stages=20, tolerance=1e-6)
        tip = bud[int(axes.tip[0]), 2] - v[axes.base, 2].mean()
        assert sign * tip > 0.05 * length, (sign, tip)


def test_a_bloom_off_the_model_along_both_paths_is_searched_with_the_lift_faded():
    """The faded path's bloom is kept where it ends nearer the model from a bud more closed
    than the model; not where its bud hangs open the other way or it ends farther, nor
    where it finds no bud (the bloom before kept, each logged)."""
    from types import SimpleNamespace

    from pipeline.chain.problem import _faded
    from pipeline.errors import BloomError

    before = SimpleNamespace(distance=0.033, bud="lifted bud")

    def bloom_ending(distance):
        def bloom(path):
            assert path == "faded"
            if distance is None:
                raise BloomError("no equilibrium")
            return SimpleNamespace(distance=distance, bud="faded bud")
        return bloom

    for distance, closed, kept in ((0.0, 8.1, "faded bud"), (0.0, None, "faded bud"),
                                   (0.0, -30.0, "lifted bud"), (0.05, 8.1, "lifted bud"),
                                   (None, 8.1, "lifted bud")):
        run = _faded(before, bloom_ending(distance), lambda bud, c=closed: c)
        assert run.bud == kept, (distance, closed)
