"""Defaults decided from the model: which way to bloom (growth.start = auto), whether
petals can meet (effects.collisions.enabled = auto), and a bud whose petals do not open
held further (simulate's second try)."""

from __future__ import annotations

import dataclasses
import types

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from pipeline.config import load_config
from pipeline.errors import BloomError
from pipeline.flower.measure import OPEN_CHORD, OPEN_CUP, OPEN_RECURVE, bloom_start, petals_within_reach
from pipeline.mesh import procedural, topology
from pipeline.sim.build import Prepared
from pipeline.sim.reverse import petal_lengths
from stages.cli import cli


def _start(v, f, p):
    prep = Prepared.from_mesh(v, f, p)
    return bloom_start(prep.vertices, prep.faces, prep.petal, prep.base, prep.tip, prep.s,
                       prep.x, prep.on_axis, prep.flower_axis)


def test_a_closed_bud_blooms_forward_and_an_open_flower_back_onto_itself():
    bud = _start(*procedural.bud(5, 1000, 1))
    assert bud.start == "bud" and bud.figure < OPEN_CHORD / 2
    lily = _start(*procedural.open_flower(6, 1800, 0))
    assert lily.start == "open" and lily.figure > 1.5 * OPEN_CHORD
    assert "from the flower's axis" in lily.reason and f"{lily.figure:.1f}" in lily.reason


def test_a_flower_whose_petals_rise_but_roll_back_is_open():
    """A flower's petals that stand along its axis (a bud's lean) but curve away from its
    inside (an open rose's inner whorls) make an open flower: rims' growth would close
    them. The bud's own petals, each mirrored across the plane through its centre and
    the flower's axis, lean as before but roll back."""
    v, f, p = procedural.bud(5, 1000, 1)
    prep = Prepared.from_mesh(v, f, p)
    point, up = prep.flower_axis[:3], prep.flower_axis[3:] / np.linalg.norm(prep.flower_axis[3:])
    rolled = v.copy()
    for q in range(5):
        mine = p == q
        centre = v[mine].mean(axis=0)
        out = centre - point - ((centre - point) @ up) * up
        out /= np.linalg.norm(out)
        rolled[mine] = v[mine] - 2.0 * np.outer((v[mine] - centre) @ out, out)
    back = Prepared.from_mesh(rolled, f, p)
    assert prep.recurve() < 0.01 and back.recurve() > 0.99  # measured 0.3%, 99.98%
    bud, open_ = (bloom_start(q.vertices, q.faces, q.petal, q.base, q.tip, q.s, q.x, q.on_axis,
                              q.flower_axis, recurve=q.recurve) for q in (prep, back))
    assert bud.start == "bud" and open_.start == "open"
    assert open_.figure < OPEN_CHORD / 2  # (not by its lean: 9.1 deg)
    assert f"over {100 * OPEN_RECURVE:g}%" in open_.reason and "100% of its squared" in open_.reason


def test_a_cupped_petal_is_a_bud_and_a_flat_one_is_open():
    v, f, p = procedural.bud(1, 320, 0)
    cupped = _start(v, f, p)
    assert cupped.start == "bud" and cupped.figure > 1.5 * OPEN_CUP
    flat, faces = procedural.flat_petal(procedural.Outline(), 0.05, np.random.default_rng(0))
    flat = np.c_[flat, np.zeros(len(flat))]
    lone = _start(flat, faces, np.zeros(len(flat), dtype=np.int64))
    assert lone.start == "open" and lone.figure < OPEN_CUP / 4


def test_petals_of_a_flower_can_meet_and_a_lone_petal_or_far_flowers_cannot():
    v, f, p = procedural.bud(3, 600, 0)
    lengths = petal_lengths(v, p, np.zeros(len(v), bool))
    assert petals_within_reach(v, p, lengths) == [(0, 1), (0, 2), (1, 2)]
    assert petals_within_reach(v, np.zeros(len(v), dtype=np.int64), lengths[:1]) == []
    # the same three petals pulled far apart along x, as flowers of a bush: none meets
    far = v + np.outer(p, [10.0 * lengths.max(), 0.0, 0.0])
    assert petals_within_reach(far, p, lengths) == []


def test_auto_is_a_value_of_the_keys_that_take_it_and_nothing_else():
    cfg = load_config()
    assert cfg["growth.start"] == "auto" and cfg["effects.collisions.enabled"] == "auto"
    assert "collisions" not in cfg.effects_enabled() and cfg.effects_auto() == ["collisions"]
    on = load_config(None, ["effects.collisions.enabled=true"])
    assert on.effects_enabled() == ["collisions"] and on.effects_auto() == []
    with pytest.raises(BloomError, match="effects.curl.enabled"):
        load_config(None, ["effects.curl.enabled=auto"])
    with pytest.raises(BloomError, match="effects.collisions.enabled"):
        load_config(None, ["effects.collisions.enabled=maybe"])
    with pytest.raises(BloomError, match="growth.start"):
        load_config(None, ["growth.start=closed"])


@pytest.mark.parametrize("kind, petals, start, collisions",
                         [("petal", 1, "bud", False), ("bud", 3, "bud", True)])
def test_simulate_records_what_it_decided(tmp_path, kind, petals, start, collisions):
    """With the defaults: sim.h5 records growth_start and its rule, and collisions in
    ``effects`` where petals can meet; the log says each in one line."""
    runner = CliRunner()
    mesh = tmp_path / "m.obj"
    assert runner.invoke(cli, ["asset", kind, "--petals", str(petals), "--vertices",
                               str(200 * petals), "--out", str(mesh)]).exit_code == 0
    paths = [mesh] + [tmp_path / f"{k}.h5" for k in ("r", "a", "g", "s")]
    steps = ["--set", "simulate.steps=2000", "--set", "simulate.frames=5"]
    for stage, src, out in zip(("remesh", "axis", "growth", "simulate"), paths[:-1], paths[1:],
                               strict=True):
        r = runner.invoke(cli, [stage, str(src), "--out", str(out)]
                          + (steps if stage == "simulate" else []))
        assert r.exit_code == 0, r.output
    assert f"growth.start = auto: {start}" in r.output
    assert f"effects.collisions.enabled = auto: {'on' if collisions else 'off'}" in r.output
    with h5py.File(paths[-1]) as h5:
        assert h5.attrs["growth_start"] == start and "deg" in h5.attrs["growth_start_rule"]
        assert ("collisions" in h5.attrs["effects"].split(",")) == collisions
        assert h5.attrs["summary"].startswith(("sound", "unsound"))
        assert h5["diagnostics/intersecting"].shape == (5,)


def test_a_bud_whose_petals_lean_out_but_curl_their_tips_in_is_a_bud():
    """The lotus's kind: petals leaving the receptacle far from the axis (chords leaning
    over OPEN_CHORD) but turning their tips back in over the centre. A lean alone would
    call it open; its tips say it is closed."""
    shape = procedural.OpenShape(lean=75.0, recurve=-25.0, inner_lean=75.0, inner_recurve=-25.0)
    lotus = _start(*procedural.open_flower(6, 1200, 0, shape))
    assert lotus.figure > OPEN_CHORD and lotus.start == "bud", lotus.reason
    assert "their tips turn -" in lotus.reason


def test_an_open_flower_whose_inner_whorls_stand_is_open():
    """The water lily's kind: five petals standing up the axis as in a bud, and an outer
    whorl of three lying open and turned out. The median lean says bud (and the water
    lily, so taken, bloomed on past flat into an umbrella and stopped where a petal
    folded); its outer petals (OPEN_OUTER) say open."""
    from pipeline.flower.measure import OPEN_OUTER

    vi, fi, pi = procedural.bud(5, 1000, 1)
    vo, fo, po = procedural.open_flower(3, 900, 0, procedural.OpenShape(
        lean=80.0, recurve=100.0, receptacle_radius=0.4))
    v, f, which = topology.stack([(vi, fi), (vo, fo)])
    p = np.where(which == 0, pi[np.minimum(np.arange(len(v)), len(vi) - 1)],
                 5 + po[np.clip(np.arange(len(v)) - len(vi), 0, len(vo) - 1)])
    whorls = _start(v, f, p)
    assert whorls.figure < OPEN_CHORD and whorls.start == "open", whorls.reason
    assert "outer petals lean" in whorls.reason and f"over {OPEN_OUTER:g}" in whorls.reason
    assert _start(vi, fi, pi).start == "bud"


def test_a_bud_whose_petals_do_not_open_blooms_again_held_further(monkeypatch, tmp_path):
    """A bud's bloom with a petal under 5 deg, or under half the others' median opening,
    is run again with each petal held up to s = HOLD_BOWL, and that bloom is kept where
    fewer petals lag; not when every petal opened with the others, not when the scene
    sets how petals are held, and the first bloom is kept where holding opens no more.
    (The runs are stand-ins: which petals open is read from the base each was given.)"""
    from pipeline.chain import problem
    from pipeline.chain import simulate as chain
    from pipeline.flower.measure import Start

    prep = Prepared.from_mesh(*procedural.bud(3, 300, 0))
    held_base = prep.base | (np.asarray(prep.s) <= chain.HOLD_BOWL)
    runs = []

    def bloom(opening_held):
        def run(p, job, ckpt, label=""):
            runs.append((p, job, ckpt))
            last = opening_held if np.array_equal(p.base, held_base) else [20.0, 1.0, 2.0]
            return problem.Result(None, {}, [], None, None, None, {
                "opening_angle_per_petal": np.array([[0.0, 0.0, 0.0], last])}, 2.0, None, 0,
                None)
        return run

    monkeypatch.setattr(problem.Result, "of", staticmethod(lambda run: run))
    monkeypatch.setattr(chain, "frame_intersections",  # (a stand-in's frames say it)
                        lambda frames, *a: [frames == "through itself"])
    first = bloom(None)(prep, None, None)
    runs.clear()
    cfg = load_config()
    job = problem.Job(cfg, Start("bud", 0.0, ""), [], {"growth.h5": "x"}, False, False, "t")
    ckpt = tmp_path / "sim.h5.ckpt"

    monkeypatch.setattr(problem, "problem", bloom([20.0, 14.0, 15.0]))
    kept, result, held = chain.hold_bowls(cfg, prep, job, ckpt, first)
    assert held == chain.HOLD_BOWL and np.array_equal(kept.base, held_base)
    assert result.diag["opening_angle_per_petal"][-1].min() == 14.0
    assert result.wall == 4.0  # (the stage's seconds: both blooms)
    (p, again_job, again_ckpt), = runs
    assert again_job.inputs["base held to"] == chain.HOLD_BOWL  # (its own checkpoint key)
    assert again_ckpt.name == "sim.h5.ckpt-held"

    runs.clear()  # holding opens no more petals: the first bloom is kept
    monkeypatch.setattr(problem, "problem", bloom([20.0, 1.0, 3.0]))
    kept, result, held = chain.hold_bowls(cfg, prep, job, ckpt, first)
    assert held is None and kept is prep and len(runs) == 1
    assert result.diag is first.diag and result.wall == 4.0

    def fails(p, job, ckpt, label=""):
        raise BloomError("no equilibrium", where="t")

    monkeypatch.setattr(problem, "problem", fails)  # a second try that fails: the first
    kept, result, held = chain.hold_bowls(cfg, prep, job, ckpt, first)
    assert held is None and kept is prep and result is first

    runs.clear()  # the scene says how petals are held: no second try
    said = load_config(None, ["axis.base_band=0.1"])
    assert chain.hold_bowls(said, prep, job, ckpt, first)[2] is None and not runs
    opened = types.SimpleNamespace(diag={"opening_angle_per_petal": np.array([[0.0] * 3,
                                                                              [20.0] * 3])})
    assert chain.hold_bowls(cfg, prep, job, ckpt, opened)[1] is opened and not runs

    # a petal that opens, but under half as far as the others, lags: tried again too
    lags = dataclasses.replace(first, diag={"opening_angle_per_petal": np.array(
        [[0.0] * 3, [58.0, 60.0, 19.0]])})
    monkeypatch.setattr(problem, "problem", bloom([50.0, 52.0, 48.0]))
    kept, result, held = chain.hold_bowls(cfg, prep, job, ckpt, lags)
    assert held == chain.HOLD_BOWL and len(runs) == 1
    runs.clear()  # a held bloom with a frame through itself: the first one stands
    monkeypatch.setattr(problem, "problem", lambda *a, **k: dataclasses.replace(
        bloom([50.0, 52.0, 48.0])(*a, **k), positions="through itself"))
    kept, result, held = chain.hold_bowls(cfg, prep, job, ckpt, lags)
    assert held is None and kept is prep and result.diag is lags.diag
    runs.clear()  # (one that opens under half the median but keeps within it: none)
    even = types.SimpleNamespace(diag={"opening_angle_per_petal": np.array(
        [[0.0] * 3, [58.0, 60.0, 31.0]])})
    assert chain.hold_bowls(cfg, prep, job, ckpt, even)[1] is even and not runs


def test_a_bud_that_closes_is_tried_again_held_and_kept_as_it_was(tmp_path):
    """A real run: a bud whose rims shrink (growth -0.2 x^2) closes every petal; simulate
    blooms it again held up to HOLD_BOWL, which closes them too, so the first bloom is
    kept: no base_held_to, the growth stage's base, no checkpoint left behind."""
    runner = CliRunner()
    mesh = tmp_path / "m.obj"
    assert runner.invoke(cli, ["asset", "bud", "--petals", "3", "--vertices", "600",
                               "--out", str(mesh)]).exit_code == 0
    paths = [mesh] + [tmp_path / f"{k}.h5" for k in ("r", "a", "g", "s")]
    extra = {"growth": ["--set", "growth.curve=-0.2*x**2"],
             "simulate": ["--set", "simulate.frames=5"]}
    for stage, src, out in zip(("remesh", "axis", "growth", "simulate"), paths[:-1], paths[1:],
                               strict=True):
        r = runner.invoke(cli, [stage, str(src), "--out", str(out), *extra.get(stage, [])])
        assert r.exit_code == 0, r.output
    assert "3 of 3 petals did not open" in r.output and "blooming again" in r.output
    assert "the first bloom kept" in r.output
    with h5py.File(paths[-2]) as g, h5py.File(paths[-1]) as s:
        assert "base_held_to" not in s.attrs
        assert np.array_equal(s["axis/base"][:], g["axis/base"][:])
        assert np.all(s["diagnostics/opening_angle_per_petal"][-1] < 0.0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.h5", "g.h5", "m.obj", "r.h5", "s.h5"]
