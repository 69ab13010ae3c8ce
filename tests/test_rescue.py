"""Where Newton finds no equilibrium on the path (a snap, a buckle, a stage that will not
converge) the solver steps through it on its own: more, smaller increments, then the snap
as a motion (implicit Euler steps with the inertia term) to rest, then Newton's
equilibrium there; each rescue counted and logged. A state whose forces have gone out of
scale (a collapsed triangle) is no equilibrium."""

import logging

import numpy as np
import pytest

from pipeline.sim.model import Control, State
from pipeline.sim.reverse import triangle_quality, unfolded_lift
from pipeline.sim.solver import quasistatic as qsmod
from pipeline.sim.solver.newton import Failure, Newton
from pipeline.sim.solver.quasistatic import QuasiStatic
from pipeline.studies import accuracy

SNAG = 0.5  #: the growth no quasi-static increment can cross in the snagged solver


@pytest.fixture(scope="module")
def petal():
    return accuracy.Scene.bud(1, 200)


def _run(scene, snag: bool, monkeypatch=None, motion_too: bool = False):
    """The petal grown to A = 1 in 10 increments; with ``snag``, Newton fails on every
    increment of the path that crosses A = SNAG (as at a snap no increment gets over),
    but not on the motion's implicit Euler steps (unless ``motion_too``)."""
    if snag:
        solve = Newton.solve
        reached = {"A": 0.0}

        def snagged(self, model, state, effects, A):
            if (self.dyn is None or motion_too) and reached["A"] < SNAG <= A:
                return Failure(1.0, 1.0, "iterations", "definite", vertex=0)
            failure = solve(self, model, state, effects, A)
            if failure is None:
                reached["A"] = max(reached["A"], A)
            return failure

        monkeypatch.setattr(Newton, "solve", snagged)
    control = Control("linear", 100.0)
    state = State.at_rest(scene.model, scene.vertices, control)
    qs = QuasiStatic(stages=10)
    qs.advance(scene.model, state, control, 100, 1.0)
    return state.positions, qs


def test_a_snag_newton_cannot_cross_is_stepped_through_and_logged(petal, monkeypatch, caplog):
    reference, _ = _run(petal, False)
    with caplog.at_level(logging.INFO, logger="bloom"):
        X, qs = _run(petal, True, monkeypatch)
    d = qs.diagnostics()
    assert d["rescues"] == 1
    assert d["rescue_halvings"] == qsmod.EXTRA_HALVINGS  # smaller increments first
    assert d["rescue_inertia_steps"] >= 2  # then the snap as a motion, to rest
    lines = [r.getMessage() for r in caplog.records if "rescued the path" in r.getMessage()]
    assert len(lines) == 1 and "A = 0.4" in lines[0], lines
    # a lone petal has one equilibrium at A = 1: the rescued path ends on it
    length = np.ptp(reference, axis=0).max()
    assert np.sqrt(np.mean(np.sum((X - reference) ** 2, axis=1))) < 1e-6 * length


def test_a_snag_nothing_gets_through_names_what_the_rescue_tried(petal, monkeypatch):
    with pytest.raises(qsmod.NotConverged) as info:
        _run(petal, True, monkeypatch, motion_too=True)
    text = str(info.value)
    assert "no equilibrium" in text and "halv" in text, text


def test_a_lift_that_would_fold_a_triangle_is_mended(petal):
    """The open start's closing lift grows as s^2 + x^2; where x runs from -1 to 1 within
    an edge (a narrow tip) that folds a triangle: the mended lift follows the distance
    from the petal's center plane and folds none."""
    X = petal.vertices
    faces = petal.faces
    n = len(X)
    petal_id = np.zeros(n, dtype=np.int64)
    centre = X.mean(axis=0)
    # a plane through the petal's long axis (its largest extent), as the axis stage's
    extent = X - centre
    _, _, vt = np.linalg.svd(extent, full_matrices=False)
    normal = vt[1]
    plane = np.append(normal, -normal @ centre)[None, :]
    s = (extent @ vt[0] - (extent @ vt[0]).min()) / np.ptp(extent @ vt[0])
    # the worst x: from 0 on the midrib to 1 within an edge (as near a narrow tip)
    edge = np.median(np.linalg.norm(X[faces[:, 0]] - X[faces[:, 1]], axis=1))
    x = (np.abs(extent @ normal) > 0.5 * edge).astype(float)
    pinned = s < 0.05
    up = vt[2]
    size = 0.6 * np.ptp(extent @ vt[0])
    lift, folded = unfolded_lift(X, faces, petal_id, plane, s, x, pinned, up, size)
    assert folded == [0]
    before = triangle_quality(X, faces)
    assert (triangle_quality(X + lift, faces) >= 0.25 * before).all()
