"""The preview shows the user's flower: their own parts, the petals deformed through the
binding and the other parts in place, the flower upright along its own axis seen from
three-quarters above, both sides of a petal lit as a petal, the same pixels every time."""

from __future__ import annotations

import imageio.v2 as imageio
import numpy as np
import pytest
from click.testing import CliRunner

from pipeline.review import render
from stages.cli import cli
from tests.test_real_input import flower_parts, write_parts


def cup(n=24, turned=False):
    """A cupped square sheet opening toward +z (``turned``: the same sheet upside down,
    its back toward +z). Returns ``(points, faces)``."""
    u, v = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n))
    z = 0.35 * (u ** 2 + v ** 2)
    pts = np.c_[u.ravel(), v.ravel(), -z.ravel() if turned else z.ravel()]
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            faces += [[a, a + 1, a + n + 1], [a, a + n + 1, a + n]]
    return pts, np.array(faces)


def petal_pixels(img):
    rgb = img[..., :3].astype(int)
    return rgb[(rgb[..., 0] > rgb[..., 1] + 25) | (rgb.sum(axis=2) < 300)]


def test_the_camera_stands_the_flower_upright_and_frames_it():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(200, 3)) * [1.0, 3.0, 0.5] + [2.0, -1.0, 4.0]
    up = np.array([0.0, 1.0, 0.0])
    position, focal, view_up = (np.array(a) for a in render.flower_camera(pts, up, 4 / 3))
    toward = (position - focal) / np.linalg.norm(position - focal)
    assert np.degrees(np.arcsin(toward @ up)) == pytest.approx(render.ELEVATION)
    assert view_up @ up > 0.8  # the flower's axis is the picture's vertical
    right = np.cross(view_up, toward)
    rel = pts - position
    depth = -(rel @ toward)
    tan = np.tan(np.radians(render.VIEW_ANGLE / 2))
    x, y = rel @ right / (depth * tan * 4 / 3), rel @ view_up / (depth * tan)
    assert np.abs(x).max() <= 1.0 and np.abs(y).max() <= 1.0  # all in the picture
    assert max(np.abs(x).max(), np.abs(y).max()) > 0.75  # and filling it
    again = render.flower_camera(pts.copy(), up.copy(), 4 / 3)
    assert np.array_equal(np.array(again), np.array(render.flower_camera(pts, up, 4 / 3)))


def test_the_pictures_up_is_the_flowers_axis_turned_as_the_file_says():
    axis = np.r_[0.0, 0.0, 0.0, 0.1, -0.99, 0.0]
    assert render.flower_up(axis, np.array([0.0, 1.0, 0.0]))[1] > 0.9
    assert render.flower_up(axis, None, rise=np.array([0.0, 2.0, 0.0]))[1] > 0.9
    assert render.flower_up(axis, np.array([1.0, 0.0, 0.0]), rise=np.array([0, 1.0, 0]))[1] > 0.9
    lone = np.full(6, np.nan)
    np.testing.assert_array_equal(render.flower_up(lone, None), [0.0, 0.0, 1.0])
    np.testing.assert_array_equal(render.flower_up(lone, np.array([0.0, 1.0, 0.0])), [0, 1, 0])


def test_a_petal_turned_over_is_lit_as_a_petal(tmp_path):
    """Frame 0 shows the sheet's front, frame 1 its back: both as bright. (Before, the
    normals of the first frame stayed on the mesh: a petal that turned over went dark.)"""
    front, faces = cup()
    back, _ = cup(turned=True)
    layer = render.Layer(faces, np.stack([front, back]), color="#f4a6c1")
    render.render_frames([layer], tmp_path, width=160, height=120, fps=4, contact_frames=2)
    shots = [petal_pixels(imageio.imread(tmp_path / "frames" / f"{k:04d}.png")) for k in (0, 1)]
    assert min(len(s) for s in shots) > 1000
    bright = [s.sum(axis=1).mean() for s in shots]
    assert bright[1] > 0.85 * bright[0], bright
    assert np.mean(shots[1].sum(axis=1) < 240) < 0.01  # no near-black patch


def y_up(points):
    """+z -> +y, exactly."""
    p = np.asarray(points, dtype=np.float64)
    return np.c_[p[:, 0], p[:, 2], -p[:, 1]]


@pytest.fixture(scope="module")
def y_up_flower(tmp_path_factory):
    """A Y-up flower of named parts (five petals, stem, receptacle, stamens) taken to
    sim.h5 in a few steps."""
    d = tmp_path_factory.mktemp("yup")
    write_parts(d / "flower.obj", [(n, y_up(v), f) for n, v, f in flower_parts()])
    scene = d / "scene.toml"
    scene.write_text('[scene]\nmesh = "flower.obj"\nup = "+y"\n[render]\nwidth = 200\n'
                     'height = 150\nturntable_frames = 0\n')
    src = None
    for stage in ("remesh", "axis", "growth", "simulate"):
        args = [stage] + ([str(src)] if src else []) + ["--config", str(scene),
                                                        "--out", str(d / f"{stage}.h5")]
        if stage == "simulate":
            args += ["--set", "simulate.steps=600", "--set", "simulate.frames=3"]
        r = CliRunner().invoke(cli, args)
        assert r.exit_code == 0, r.output
        src = d / f"{stage}.h5"
    return src, scene


def test_render_shows_the_users_parts_upright_and_the_same_every_time(y_up_flower, tmp_path):
    sim, scene = y_up_flower
    shots = []
    for name in ("a", "b"):
        r = CliRunner().invoke(cli, ["render", str(sim), "--config", str(scene), "--out",
                                     str(tmp_path / name)])
        assert r.exit_code == 0, r.output
        shots.append([imageio.imread(tmp_path / name / "frames" / f"{k:04d}.png")
                      for k in range(3)])
        assert (tmp_path / name / "bloom.mp4").exists()
        assert (tmp_path / name / "contact_sheet.png").exists()
    assert all(np.array_equal(a, b) for a, b in zip(*shots, strict=True))  # the same pixels
    img = shots[0][-1][..., :3].astype(int)
    rows = np.arange(img.shape[0])[:, None] * np.ones(img.shape[1])
    pink = (img[..., 0] > img[..., 1] + 40) & (img[..., 0] > 150)
    green = (img[..., 1] > img[..., 0] + 15) & (img[..., 1] > img[..., 2])
    yellow = (img[..., 0] > 170) & (img[..., 1] > 130) & (img[..., 2] < 110)
    assert pink.sum() > 500 and green.sum() > 20 and yellow.sum() > 5, (
        pink.sum(), green.sum(), yellow.sum())  # petals, the stem, the stamens
    assert rows[green].mean() > rows[pink].mean()  # the stem below the petals: upright
    sheet = tmp_path / "sheet"
    r = CliRunner().invoke(cli, ["render", str(sim), "--config", str(scene), "--out", str(sheet),
                                 "--set", 'export.mesh="sheet"'])
    assert r.exit_code == 0, r.output
    only = imageio.imread(sheet / "frames" / "0002.png")[..., :3].astype(int)
    assert ((only[..., 1] > only[..., 0] + 15) & (only[..., 1] > only[..., 2])).sum() == 0


def test_a_petal_pieces_hub_keeps_the_petal_colour_and_a_leaf_is_a_leaf():
    """A petal part of two pieces, its points unwelded (as an STL's): a petal whose hub
    end stays (held with the hub) and a leaf that stays whole. The leaf is drawn as a
    leaf, apart and unframed; the petal, its held hub too, in the petal's colour."""
    from pipeline.io import binding, userasset

    quad = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    petal = np.vstack([quad, quad + [1.0, 0.0, 0.0]])  # two squares side by side
    leaf = quad + [5.0, 0.0, 0.0]
    tris = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7], [8, 9, 10], [8, 10, 11]])
    corners = np.vstack([petal, leaf])[tris.ravel()]  # (unwelded: each triangle its own)
    part = userasset.AssetPart("Flower", corners, np.full(len(tris), 3),
                               np.arange(3 * len(tris)))
    face = np.full(len(corners), 0, dtype=np.int64)
    face[:6] = -1  # (the petal's first square: its hub, held)
    face[12:] = -1  # (the leaf)
    b = binding.Binding(face, np.full((len(corners), 3), 1.0 / 3.0), corners.copy())
    sheet = np.array([[0, 1, 2]])
    frames = [np.stack([corners, corners + [0.0, 0.0, 0.1]])]
    asset = userasset.Asset([part], None, None)
    layers = render.asset_layers(frames, asset, {0: b}, sheet, np.zeros(3, dtype=np.int64),
                                 color="#ff99cc", palette="single")
    leaf_layer = [layer for layer in layers if layer.color == render.PART_COLOURS["leaf"]]
    assert len(leaf_layer) == 1 and not leaf_layer[0].framed
    assert sorted(np.unique(leaf_layer[0].faces // 3).tolist()) == [4, 5]  # the leaf only
    petal_layer = [layer for layer in layers if layer.color == "#ff99cc"]
    assert len(petal_layer) == 1 and len(petal_layer[0].faces) == 4  # the hub's two too
