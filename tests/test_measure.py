"""The opening angle: each petal's, turned outward by a known angle, reads that angle."""

import numpy as np
import pytest
from conftest import prepared

from pipeline.flower.measure import PetalFrames


def _turned(v, petal, axes, degrees: float, side: str = "base") -> np.ndarray:
    """Every petal turned rigidly by ``degrees`` about the line through its base's centre
    along the flower's tangent there (positive: its tip away from the flower's axis, on
    the ``side`` of its base's centre, or of its centroid)."""
    point, a = axes.flower_axis[:3], axes.flower_axis[3:] / np.linalg.norm(axes.flower_axis[3:])
    out = v.copy()
    t = np.radians(degrees)
    for p in range(int(petal.max()) + 1):
        mine = petal == p
        center = v[mine & axes.base].mean(axis=0)
        r = (center if side == "base" else v[mine].mean(axis=0)) - point
        r -= a * (r @ a)
        k = np.cross(a, r / np.linalg.norm(r))  # the tip (along a) turns toward r
        x = v[mine] - center
        out[mine] = center + (x * np.cos(t) + np.cross(k, x) * np.sin(t)
                              + np.outer(x @ k, k) * (1 - np.cos(t)))
    return out


@pytest.mark.parametrize("petals, vertices, seed", [(6, 900, 0), (12, 1500, 7), (14, 2800, 5)])
def test_every_petal_turned_outward_opens_by_that_angle(petals, vertices, seed):
    """In dense buds some petals' cups do not tell which way is out (nearly flat, or
    cupped the other way): those read -20 deg for 20 deg outward until the flower's axis
    decided it, and a 14-petal bud that opened to 62 deg reported 5.5."""
    v, f, petal, axes, _ = prepared(petals, vertices, seed)
    frames = PetalFrames.from_mesh(v, petal, axes.base, axes.on_axis, axes.tip, axes.plane,
                                   flower_axis=axes.flower_axis)
    assert np.all(np.abs(frames.opening_angles(v)) < 1e-9)
    for degrees in (20.0, -10.0):
        angles = frames.opening_angles(_turned(v, petal, axes, degrees))
        assert np.all(np.abs(angles - degrees) < 0.1 * abs(degrees)), angles


def test_a_lone_petal_is_measured_by_its_cup():
    """No flower axis (nan): the cup alone sets outward, as before."""
    v, f, petal, axes, _ = prepared(1, 150)
    assert not np.all(np.isfinite(axes.flower_axis))
    args = (v, petal, axes.base, axes.on_axis, axes.tip, axes.plane)
    a, b = PetalFrames.from_mesh(*args), PetalFrames.from_mesh(*args, flower_axis=axes.flower_axis)
    assert np.array_equal(a.outward_dirs, b.outward_dirs)


def test_a_petal_leaning_over_the_axis_opens_outward():
    """A bud's petal may lean over the flower's axis, its centroid across it (the open
    lily's bud, found backward, has one): outward is still away from its own base."""
    v, f, petal, axes, _ = prepared(6, 900)
    leaned = _turned(v, petal, axes, -40.0)  # every petal over the axis
    point, a = axes.flower_axis[:3], axes.flower_axis[3:]
    r = leaned[petal == 0].mean(axis=0) - point
    base = v[(petal == 0) & axes.base].mean(axis=0) - point
    assert (r - a * (r @ a)) @ (base - a * (base @ a)) < 0.0  # (its centroid: across)
    frames = PetalFrames.from_mesh(leaned, petal, axes.base, axes.on_axis, axes.tip,
                                   axes.plane, flower_axis=axes.flower_axis)
    angles = frames.opening_angles(_turned(leaned, petal, axes, 20.0))
    assert np.all(np.abs(angles - 20.0) < 2.0), angles


def test_petals_whose_bases_meet_on_the_axis_open_outward():
    """Sheets joined at the flower's centre (an open flower of five sheets, souki202's,
    has one base on its axis): where the base does not tell, the petal's centroid does."""
    v, f, petal, axes, _ = prepared(14, 2800, 5)
    point, a = axes.flower_axis[:3], axes.flower_axis[3:]
    met = v.copy()
    for p in range(14):  # each petal moved across, its base's centre onto the axis
        mine = petal == p
        r = v[mine & axes.base].mean(axis=0) - point
        met[mine] -= r - a * (r @ a)
    frames = PetalFrames.from_mesh(met, petal, axes.base, axes.on_axis, axes.tip, axes.plane,
                                   flower_axis=axes.flower_axis)
    angles = frames.opening_angles(_turned(met, petal, axes, 20.0, side="centroid"))
    assert np.all(np.abs(angles - 20.0) < 2.0), angles


def test_an_open_start_measures_opening_toward_the_model():
    """A bud found backward may curl past where its chord and cup tell which way is out:
    the model (open by definition) decides, so the bloom from the bud to it opens."""
    from pipeline.flower.measure import PetalFrames

    frames = PetalFrames(np.zeros((2, 3)), np.array([1, 3]), np.array([[0.0, 0, 1], [0, 0, 1]]),
                         np.array([[1.0, 0, 0], [1, 0, 0]]))
    model = np.array([[0.0, 0, 0], [-1, 0, 1], [0, 0, 0], [1, 0, 1]])
    assert np.allclose(frames.opening_angles(model), [-45.0, 45.0])
    toward = frames.opening_toward(model)
    assert np.allclose(toward.opening_angles(model), [45.0, 45.0])
    assert np.array_equal(toward.chord_dirs, frames.chord_dirs)
