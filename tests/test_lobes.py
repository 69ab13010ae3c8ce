"""Petals without a clean mid-surface: lobes of petals joined at a hub, and height-field
sheets of hemmed, coarse or solidified petals (the Blender lily's kind of petal part)."""

from __future__ import annotations

import gpytoolbox
import numpy as np
import pytest

from pipeline.mesh import procedural, topology
from pipeline.mesh.heightfield import height_sheet
from pipeline.mesh.lobes import angular_profile, lobes, profile_peaks
from tests.test_midsurface import _cup_petal, _solidify


def star(k=6, hub=0.25, length=1.0, rings=16, around=240, cup=0.3, phase=0.0, sharp=1.5):
    """A sheet of ``k`` petals joined at a round hub, in polar rings (a fan at the centre):
    radius hub + length |cos(k(t - phase)/2)|^sharp at angle t, cupped up by cup r^2."""
    t = np.linspace(0, 2 * np.pi, around, endpoint=False)
    r_out = hub + length * np.abs(np.cos(0.5 * k * (t - phase))) ** sharp
    s = np.arange(1, rings + 1) / rings
    r = s[:, None] * r_out[None, :]
    pts = np.stack([r * np.cos(t), r * np.sin(t), cup * r ** 2], axis=-1).reshape(-1, 3)
    v = np.vstack([[0.0, 0.0, 0.0], pts])
    idx = 1 + np.arange(rings * around).reshape(rings, around)
    nxt = np.roll(idx, -1, axis=1)
    fan = np.stack([np.zeros(around, dtype=np.int64), idx[0], nxt[0]], 1)
    a, b, c, d = idx[:-1], nxt[:-1], idx[1:], nxt[1:]
    quads = np.concatenate([np.stack([a, c, d], -1).reshape(-1, 3), np.stack([a, d, b], -1).reshape(-1, 3)])
    return v, np.vstack([fan, quads])


def hem(v, f, depth, width):
    """Fold an open sheet's edge under: a wall ``depth`` down its normals along the rim,
    then a flap ``width`` back in under the sheet (a hem, as a rim-only Solidify and a
    fold would make it). Returns the hemmed surface (one piece, still open)."""
    n = topology.vertex_normals(v, f)
    he, _ = topology.half_edges(f)
    _, he_edge, count = topology.unique_edges(f)
    rim = he[count[he_edge] == 1]  # directed as the faces wind: the sheet is to the left
    loop_next = dict(zip(rim[:, 0], rim[:, 1], strict=True))
    ids = np.unique(rim)
    prev = {b: a for a, b in loop_next.items()}
    along = np.array([v[loop_next[i]] - v[prev[i]] for i in ids])
    inward = np.cross(n[ids], along)
    inward /= np.linalg.norm(inward, axis=1)[:, None]
    nv = len(v)
    low = v[ids] - depth * n[ids]
    flap = low + width * inward
    at = {i: k for k, i in enumerate(ids)}
    verts = np.vstack([v, low, flap])
    faces = [f]
    for a, b in rim:
        la, lb = nv + at[a], nv + at[b]
        fa, fb = nv + len(ids) + at[a], nv + len(ids) + at[b]
        faces.append([[b, a, la], [b, la, lb], [lb, la, fa], [lb, fa, fb]])
    return verts, np.vstack(faces)


def _distance(points, v, f):
    d, _, _ = gpytoolbox.squared_distance(points, v, f, use_cpp=True)
    return np.sqrt(d)


def _gentle_petal():
    """A procedural petal of length 1, cupped gently (a height field over its plane)."""
    flat, faces = procedural.flat_petal(procedural.Outline(), 0.05, np.random.default_rng(0))
    x, y = flat[:, 0], flat[:, 1]
    return np.stack([x, y, 0.3 * x ** 2 + 0.1 * y ** 2], axis=1), faces


def _area(v, f):
    return 0.5 * float(np.linalg.norm(topology.face_normals(v, f), axis=1).sum())


# --- the angular profile and its peaks ---------------------------------------------------------

def test_angular_profile_keeps_the_weight_and_wraps_around():
    angle = np.array([359.5, 0.5, 90.0])
    prof = angular_profile(angle, np.array([1.0, 1.0, 2.0]))
    assert prof.shape == (360,)
    assert prof.sum() == pytest.approx(4.0)
    assert prof[0] == pytest.approx(prof[359])  # 359.5 and 0.5 smear across 0 alike
    assert int(np.argmax(prof)) == 90


def test_peaks_merge_across_shallow_valleys_only():
    x = np.arange(360)
    bumps = sum(np.exp(-0.5 * (((x - c + 180) % 360 - 180) / 12.0) ** 2) for c in (0, 120, 240))
    assert profile_peaks(bumps) == [0, 120, 240]
    ripple = bumps + 0.02 * np.sin(np.radians(x) * 36)  # small wiggles are not lobes
    assert len(profile_peaks(ripple)) == 3
    assert len(profile_peaks(np.ones(360) + 0.1 * np.cos(np.radians(x) * 5))) == 1


# --- lobes ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("k", [3, 5, 6])
def test_a_star_sheet_splits_into_its_petals(k):
    v, f = star(k=k, phase=0.3)
    split = lobes(v, f)
    assert split.count == k
    c = v[f].mean(axis=1)
    angle = np.arctan2(c[:, 1], c[:, 0])
    petal = np.round((angle - 0.3) * k / (2 * np.pi)).astype(int) % k  # the petal each face is in
    outer = split.radius > split.hub_radius
    # each lobe is one petal, and a petal is one lobe, beyond the hub
    for p in range(k):
        assert len(np.unique(split.label[outer & (petal == p)])) == 1
    assert len(np.unique(split.label[outer])) == k
    assert 0 < split.hub_radius < 0.25 + 0.5  # the hub (0.25) and the petals' root
    assert abs(abs(split.axis[2]) - 1) < 1e-6


def test_petals_that_overlap_in_angle_go_to_the_petal_they_are_part_of():
    """Two rings of three petals as separate pieces, the inner ones overlapping the outer
    ones in angle (a lily's six tepals): every face goes to its own piece's lobe."""
    v1, f1 = star(k=3, hub=0.1, length=1.0, cup=0.2, sharp=6)
    v2, f2 = star(k=3, hub=0.1, length=0.9, cup=0.5, phase=np.pi / 3, sharp=6)
    v2 = v2 + [0, 0, 0.05]
    v = np.vstack([v1, v2])
    f = np.vstack([f1, f2 + len(v1)])
    split = lobes(v, f)
    assert split.count == 6
    outer = split.radius > split.hub_radius
    piece = np.r_[np.zeros(len(f1), int), np.ones(len(f2), int)]
    for lobe in range(6):
        assert len(np.unique(piece[outer & (split.label == lobe)])) == 1


@pytest.mark.parametrize("sheet", ["petal", "two petals"])
def test_fewer_than_three_lobes_is_one(sheet):
    v, f = _cup_petal()
    if sheet == "two petals":
        v2 = v * [1, -1, 1]
        v, f = np.vstack([v, v2]), np.vstack([f, f[:, ::-1] + len(v)])
    split = lobes(v, f)
    assert split.count == 1 and not split.label.any() and split.hub_radius == 0.0


# --- height-field sheets ------------------------------------------------------------------------

def test_a_hemmed_petal_gives_its_top_sheet():
    v0, f0 = _gentle_petal()
    depth = 0.03
    v, f = hem(v0, f0, depth, 0.04)
    h = height_sheet(v, f)
    assert not h.two_sided
    d = _distance(h.vertices, v0, f0)
    assert d.max() < 0.1 * depth, d.max()  # on the top sheet, not dragged toward the flap
    assert _area(h.vertices, h.faces) > 0.8 * _area(v0, f0)  # measured 0.85: a rim of 1-2 cells
    assert topology.components(h.faces, len(h.vertices)).max() == 0
    _, _, count = topology.unique_edges(h.faces)
    assert count.max() == 2
    # the faces' winding agrees with the input sheet's
    assert np.dot(topology.face_normals(h.vertices, h.faces).sum(0), topology.face_normals(v0, f0).sum(0)) > 0
    assert np.median(h.thickness[h.thickness > 0]) == pytest.approx(depth, rel=0.35)


def test_a_solidified_petal_gives_the_sheet_halfway():
    t = 0.02
    v0, f0 = _cup_petal()
    v, f, top, bottom = _solidify(v0, f0, t)
    h = height_sheet(v, f)
    assert h.two_sided
    interior = ~topology.boundary_vertices(h.faces, len(h.vertices))
    d_top = _distance(h.vertices[interior], v, top)
    d_bottom = _distance(h.vertices[interior], v, bottom)
    # halfway along the plane's normal: equal distances, each t/2 times the cosine of the
    # petal's tilt from its plane (the cup here tilts up to ~30 degrees)
    assert np.abs(d_top - d_bottom).max() < 0.1 * t
    assert np.median(d_top) == pytest.approx(0.5 * t, rel=0.1)
    assert d_top.min() > 0.4 * t


def test_the_height_sheet_is_deterministic_and_moves_with_the_input():
    v, f = hem(*_gentle_petal(), 0.03, 0.04)
    a = height_sheet(v, f)
    b = height_sheet(v, f)
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
    rot = np.linalg.qr(np.random.default_rng(3).normal(size=(3, 3)))[0]
    rot *= np.sign(np.linalg.det(rot))
    c = height_sheet(7.0 * v @ rot.T + [1, 2, 3], f)
    back = (c.vertices - [1, 2, 3]) @ rot / 7.0
    assert np.abs(_distance(back, a.vertices, a.faces)).max() < 0.02
    assert _area(back, c.faces) == pytest.approx(_area(a.vertices, a.faces), rel=0.03)


def test_a_flat_star_with_hems_gives_one_sheet_per_petal_without_touching():
    from pipeline.flower.petals import _lobe_sheets

    v, f = hem(*star(k=5, cup=0.2), 0.05, 0.05)
    made = _lobe_sheets(v, f)
    assert len(made) == 5
    spacing = min(np.median(np.linalg.norm(sv[sf[:, 0]] - sv[sf[:, 1]], axis=1)) for sv, sf, _ in made)
    for i in range(5):
        for j in range(i + 1, 5):
            gap = _distance(made[i][0], made[j][0], made[j][1]).min()
            assert gap > 0.5 * spacing, (i, j, gap)
    assert all(len(t) == len(sv) for sv, _, t in made)


def test_asset_petal_is_unchanged_by_an_empty_hem():
    """A flat open petal, no hem: the height sheet lies on it."""
    flat, faces = procedural.flat_petal(procedural.Outline(), 0.05, np.random.default_rng(0))
    flat = np.c_[flat[:, :2], np.zeros(len(flat))]
    h = height_sheet(flat, faces)
    assert _distance(h.vertices, flat, faces).max() < 1e-9
    assert _area(h.vertices, h.faces) > 0.8 * _area(flat, faces)  # measured 0.84
