"""Many flowers in one file: petals grouped into flowers by where their bases gather
(pipeline.mesh.flowers), a whole flower in one mesh split into its petals, each
flower's own axis (pipeline.flower.axis.find_axes), and scene.flower."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from pipeline.flower.axis import find_axes
from pipeline.flower.classify import classify
from pipeline.flower.petals import prepare_parts
from pipeline.io.meshfile import MeshFile, Part
from pipeline.mesh import clean, procedural
from pipeline.mesh.flowers import flowers
from stages.cli import cli
from tests.test_real_input import write_parts


def _rotation(axis: np.ndarray) -> np.ndarray:
    """A rotation taking +z to ``axis``."""
    z = np.array([0.0, 0.0, 1.0])
    a = axis / np.linalg.norm(axis)
    v, c = np.cross(z, a), float(z @ a)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k / (1.0 + c)


#: three open lilies: where each stands and which way it faces
BUSH = ((np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])),
        (np.array([2.6, 0.4, 0.3]), np.array([0.3, 0.1, 1.0])),
        (np.array([1.1, 2.4, -0.2]), np.array([-0.2, 0.4, 1.0])))


def bush(petals: int = 6, vertices: int = 900):
    """Three open lilies (petals ~1 long) a little over two petal lengths apart, each
    tilted its own way: ``(vertices, faces, petal, flower of each petal)``."""
    vs, fs, ps, fl, offset = [], [], [], [], 0
    for k, (where, up) in enumerate(BUSH):
        v, f, p = procedural.open_flower(petals, vertices, seed=k)
        vs.append(v @ _rotation(up).T + where)
        fs.append(f + offset)
        ps.append(p + k * petals)
        fl += [k] * petals
        offset += len(v)
    return np.vstack(vs), np.vstack(fs), np.concatenate(ps), np.array(fl)


def test_petals_are_grouped_by_their_flower():
    v, _, petal, truth = bush()
    got = flowers(v, petal)
    assert got.count == 3
    assert np.array_equal(got.flower, truth)  # numbered by first petal: same as built
    for k, (where, _) in enumerate(BUSH):
        assert np.linalg.norm(got.centre[k] - where) < 0.3  # bases gather at the receptacle
    # each petal's base end is the one at its flower's centre, not its tip
    assert np.all(np.linalg.norm(got.base - got.centre[got.flower], axis=1)
                  < np.linalg.norm(got.tip - got.centre[got.flower], axis=1))


def test_flowers_do_not_depend_on_order_or_scale():
    v, _, petal, truth = bush()
    rng = np.random.default_rng(3)
    order = rng.permutation(len(v))  # points shuffled, petals renumbered backwards
    count = petal.max() + 1
    got = flowers(1000.0 * v[order] - 7.0, count - 1 - petal[order])
    assert got.count == 3
    mapped = got.flower[count - 1 - np.arange(count)]  # back to the original numbering
    for k in range(3):
        assert len(set(mapped[truth == k].tolist())) == 1
    assert len(set(mapped.tolist())) == 3


def test_flowers_whose_tips_touch_stay_apart():
    """Two lilies whose petal tips overlap: grouped by their bases, not by touching."""
    a, fa, pa = procedural.open_flower(6, 900, seed=0)
    b, fb, pb = procedural.open_flower(6, 900, seed=1)
    reach = np.linalg.norm(a[:, :2], axis=1).max()
    b = b + [1.7 * reach, 0.0, 0.0]  # tips of the two reach into each other
    got = flowers(np.vstack([a, b]), np.concatenate([pa, pb + 6]))
    assert got.count == 2
    assert np.array_equal(got.flower, [0] * 6 + [1] * 6)


def test_no_petals_no_flowers():
    got = flowers(np.zeros((0, 3)), np.zeros(0, dtype=np.int64))
    assert got.count == 0 and got.flower.shape == (0,)


def test_each_flower_gets_its_own_axis():
    v, f, petal, truth = bush()
    v = v / clean.mean_edge_length(v, f)
    axes = find_axes(v, f, petal, flower=truth)
    assert axes.flower_axes.shape == (3, 6)
    for k, (_, up) in enumerate(BUSH):
        d = axes.flower_axes[k, 3:]
        assert d @ (up / np.linalg.norm(up)) > np.cos(np.radians(5.0)), (k, d)
    # every base is at its own flower's axis, its tip away from it
    for p in range(len(axes.tip)):
        line = axes.flower_axes[truth[p]]
        r = v[(petal == p)] - line[:3]
        dist = np.linalg.norm(r - np.outer(r @ line[3:], line[3:]), axis=1)
        base = axes.base[petal == p]
        assert dist[base].mean() < dist.mean() < dist[axes.tip[p] - np.flatnonzero(petal == p)[0]]
    # one flower for all (the axis stage before flowers): one line fits none of them
    one = find_axes(v, f, petal)
    assert one.flower_axes.shape == (1, 6)


def _whole_flower(petals=5):
    """One mesh holding a bud's petals, a closed receptacle and a stem below (a whole
    flower exported as one object)."""
    v, f, petal = procedural.bud(petals, 600, 0)
    length = float(np.ptp(v[:, 2]))
    ball = trimesh.creation.icosphere(2, radius=0.08 * length)
    stem = trimesh.creation.cylinder(radius=0.03 * length, height=length, sections=16)
    parts = [(v, f), (ball.vertices + [0, 0, v[:, 2].min()], ball.faces),
             (stem.vertices + [0, 0, v[:, 2].min() - 0.5 * length], stem.faces)]
    verts, faces, offset = [], [], 0
    for pv, pf in parts:
        verts.append(pv)
        faces.append(np.asarray(pf) + offset)
        offset += len(pv)
    return np.vstack(verts), np.vstack(faces), len(f)


def test_a_whole_flower_in_one_mesh_is_split_into_its_petals():
    v, f, petal_faces = _whole_flower()
    (verdict,) = classify([Part("flower", v, f)])
    assert verdict.is_petal and verdict.faces is not None
    assert np.array_equal(verdict.faces, np.arange(len(f)) < petal_faces)  # petals only
    assert "a whole flower in one mesh" in verdict.reason
    result = prepare_parts(MeshFile([Part("flower", v, f)], None, None), where="flower.obj")
    assert len(result.plane) == 5
    assert result.found["flower"]["petals"] == 5 and result.found["flower"]["area_kept"] > 0.9
    kept_v, kept_f = result.kept_parts[0]  # the receptacle and stem are kept, not simulated
    assert len(kept_f) == len(f) - petal_faces


def _bush_obj(tmp_path):
    v, f, petal, _ = bush(petals=5, vertices=600)
    parts = []
    for k in range(3):  # a part per flower, as a bush exported per object
        idx = np.flatnonzero((petal >= 5 * k) & (petal < 5 * k + 5))
        keep = np.isin(f[:, 0], idx)
        parts.append((f"Flower.{k:03d}", v[idx], np.searchsorted(idx, f[keep])))
    return write_parts(tmp_path / "bush.obj", parts)


def test_remesh_records_the_flowers_and_axis_finds_each_axis(tmp_path):
    mesh = _bush_obj(tmp_path)
    r = CliRunner().invoke(cli, ["remesh", str(mesh), "--out", str(tmp_path / "r.h5")])
    assert r.exit_code == 0, r.output
    assert "3 flower(s)" in r.output and "15 petal(s) found" in r.output
    with h5py.File(tmp_path / "r.h5") as h:
        flower, petal = h["mesh/flower"][()], h["mesh/petal"][()]
        per_petal = h["flower/petal_flower"][()]
        assert np.array_equal(per_petal, np.repeat([0, 1, 2], 5))
        assert np.array_equal(flower, per_petal[petal])
        assert h["flower/centre"].shape == (3, 3) and h.attrs["flower_count"] == 3
        assert h.attrs["flower_picked"] == -1
    r = CliRunner().invoke(cli, ["axis", str(tmp_path / "r.h5"), "--out", str(tmp_path / "a.h5")])
    assert r.exit_code == 0, r.output
    with h5py.File(tmp_path / "a.h5") as h:
        axis = h["flower/axis"][()]
        assert axis.shape == (3, 6) and np.all(np.isfinite(axis))
        for k, (_, up) in enumerate(BUSH):
            assert axis[k, 3:] @ (up / np.linalg.norm(up)) > np.cos(np.radians(5.0))
        assert np.array_equal(h["mesh/flower"][()], flower)  # carried forward
    r = CliRunner().invoke(cli, ["growth", str(tmp_path / "a.h5"), "--out", str(tmp_path / "g.h5")])
    assert r.exit_code == 0, r.output
    with h5py.File(tmp_path / "g.h5") as h:
        assert h["flower/axis"].shape == (3, 6) and "flower/petal_flower" in h


@pytest.mark.parametrize("pick, flower", [("1", 1), ("Flower.002", 2), ("Flower.00[0]", 0)])
def test_scene_flower_picks_one_flower(tmp_path, pick, flower):
    mesh = _bush_obj(tmp_path)
    r = CliRunner().invoke(cli, ["remesh", str(mesh), "--out", str(tmp_path / "r.h5"),
                                 "--set", f"scene.flower={pick}"])
    assert r.exit_code == 0, r.output
    with h5py.File(tmp_path / "r.h5") as h:
        assert h.attrs["petal_count"] == 5 and h.attrs["flower_picked"] == flower
        assert np.all(h["mesh/flower"][()] == 0)
        names = [n.decode() if isinstance(n, bytes) else n for n in h["mesh/part_names"][()]]
        assert {names[i] for i in np.unique(h["mesh/part"][()])} == {f"Flower.{flower:03d}"}


def test_a_flower_picked_from_a_part_of_several_binds_only_its_own_points(tmp_path):
    """The three lilies in one part (as a rose bed's one petal mesh), flower 1 picked: the
    user's points of that flower are bound to its sheets, the other flowers' stay where
    they are (bound to the picked flower's petals, the rose bed's other roses swung
    across the picture with them as it bloomed)."""
    from pipeline.io.binding import read_bindings

    v, f, petal, _ = bush(petals=5, vertices=600)
    mesh = write_parts(tmp_path / "bed.obj", [("Petals", v, f)])
    r = CliRunner().invoke(cli, ["remesh", str(mesh), "--out", str(tmp_path / "r.h5"),
                                 "--set", "scene.flower=1"])
    assert r.exit_code == 0, r.output
    with h5py.File(tmp_path / "r.h5") as h:
        assert h.attrs["petal_count"] == 5 and h.attrs["flower_picked"] == 1
        b = read_bindings(h)[0]
    mine = (petal >= 5) & (petal < 10)  # (flower 1's points, in the file's order)
    assert len(b.face) == len(v)
    assert np.all(b.face[mine] >= 0) and np.all(b.face[~mine] < 0)


@pytest.mark.parametrize("pick, words", [("3", "0 to 2"), ("Nothing*", "no petal part"),
                                         ("Flower.*", "3 flowers")])
def test_a_bad_scene_flower_is_one_line_naming_the_key(tmp_path, pick, words):
    mesh = _bush_obj(tmp_path)
    out = tmp_path / "r.h5"
    r = CliRunner().invoke(cli, ["remesh", str(mesh), "--out", str(out), "--set",
                                 f"scene.flower={pick}"])
    assert r.exit_code != 0 and not out.exists()
    line = r.output.strip().splitlines()[-1]
    assert "scene.flower" in line and words in line and "Traceback" not in r.output


def test_copied_petals_are_remeshed_once_and_moved():
    """A petal that is a moved, turned and scaled copy of another is remeshed once; the
    copy's sheet is the original's moved the same way. A mirror image is not a copy."""
    from pipeline.flower.petals import _copies

    v, f, petal = procedural.open_flower(5, 700, seed=2)
    idx = np.flatnonzero(petal == 0)
    pts, lf = v[idx], np.searchsorted(idx, f[np.isin(f[:, 0], idx)])
    rot = _rotation(np.array([0.3, -0.5, 1.0]))
    copy = 1.7 * pts @ rot.T + [3.0, 1.0, -2.0]
    mirror = pts * [-1.0, 1.0, 1.0]
    found = _copies([pts, copy, mirror, pts + 1e-3], [lf, lf, lf, lf], scaled=True)
    assert found[0] is None and found[2] is None  # the first, and a mirror image
    k, s, r, t = found[1]
    assert k == 0 and s == pytest.approx(1.7) and np.allclose(r, rot)
    assert found[3][0] == 0 and found[3][1] == pytest.approx(1.0)  # moved only
    assert _copies([pts, copy], [lf, lf], scaled=False)[1] is None  # an absolute target edge
    # end to end: three copies of one lily, turned and scaled, as three parts
    parts = []
    for k, (where, up) in enumerate(BUSH):
        parts.append(Part(f"Lily.{k}", (1.0 + 0.2 * k) * v @ _rotation(up).T + where, f))
    result = prepare_parts(MeshFile(parts, None, None), where="bush", target_edge=0.0,
                           petal_vertices=150)
    assert len(result.plane) == 15 and len(result.flower_centre) == 3
    assert any("10 of 15 petals are copies" in n for n in result.notes)
    first = result.vertices[result.petal == 0]
    for k in (1, 2):
        other = result.vertices[result.petal == 5 * k]
        assert len(other) == len(first)
        size = np.linalg.norm(np.ptp(other, axis=0))
        # the same sheet, moved: pairwise distances scale by one factor
        d0 = np.linalg.norm(first[1:] - first[0], axis=1)
        dk = np.linalg.norm(other[1:] - other[0], axis=1)
        assert np.allclose(dk / d0, (1.0 + 0.2 * k), rtol=1e-6, atol=1e-9 * size)


def test_copies_are_found_among_many_shapes_of_one_mesh():
    """Forty petals of one mesh structure but as many shapes (a branch whose blossoms vary,
    1% apart): each is its own, and a copy of the last is still found (an earlier cap
    compared only the first 8), as is one written out to 6 decimals of a metre."""
    from pipeline.flower.petals import _copies

    v, f, petal = procedural.open_flower(5, 700, seed=2)
    idx = np.flatnonzero(petal == 0)
    pts, lf = v[idx], np.searchsorted(idx, f[np.isin(f[:, 0], idx)])
    rng = np.random.default_rng(1)
    shapes = [pts * [1.0, 1.0 + 0.02 * k, 1.0 - 0.01 * k] for k in range(40)]
    rot = _rotation(np.array([0.2, 0.7, 1.0]))
    copies = [2.0 * shapes[k] @ rot.T + rng.normal(size=3) for k in (39, 0, 25)]
    # as Blender's OBJ exporter writes a 1 cm petal a metre out: 6 decimals of a metre
    copies.append(np.round(0.01 * shapes[7] @ rot.T + [1.5, 0.3, 2.0], 6))
    found = _copies(shapes + copies, [lf] * 44, scaled=True)
    assert all(found[k] is None for k in range(40))
    assert [found[40 + i][0] for i in range(4)] == [39, 0, 25, 7]
    assert [found[40 + i][1] for i in range(4)] == pytest.approx([2.0, 2.0, 2.0, 0.01], rel=1e-4)


def test_a_copied_petal_takes_its_originals_axis_moved():
    """A petal that is another turned, moved and scaled (an instanced blossom's, to rounding)
    gets that petal's base, axis, tip, s and x, bit for bit, and its center plane moved:
    a tie decided at rounding is decided alike, so copied blossoms bloom once. A petal
    a little off a copy finds its own."""
    v, f, petal = procedural.open_flower(5, 500, seed=1)
    v = v / clean.mean_edge_length(v, f)
    rot = _rotation(np.array([0.4, -0.3, 1.0]))
    t = np.array([40.0, -7.0, 3.0])
    rng = np.random.default_rng(0)
    copy = 1.3 * v @ rot.T + t + rng.normal(scale=1e-9, size=v.shape)  # scaled; rounding
    near = v @ rot.T - t + rng.normal(scale=1e-3, size=v.shape)  # not a copy
    n, count = len(v), petal.max() + 1
    allv = np.vstack([v, copy, near])
    allf = np.vstack([f, f + n, f + 2 * n])
    allp = np.concatenate([petal, petal + count, petal + 2 * count])
    flower = np.repeat(np.arange(3), count)
    axes = find_axes(allv, allf, allp, surface=True, base_region="band", base_fraction=0.08,
                     flower=flower)
    first, second, third = slice(0, n), slice(n, 2 * n), slice(2 * n, 3 * n)
    for name in ("base", "on_axis", "s", "x"):
        got = getattr(axes, name)
        assert np.array_equal(got[first], got[second]), name
    assert not np.array_equal(axes.s[first], axes.s[third])  # found on its own
    assert np.allclose(axes.s[first], axes.s[third], atol=0.05)  # ... and much the same
    assert np.array_equal(axes.tip[count:2 * count], axes.tip[:count] + n)
    normal = axes.plane[:count, :3] @ rot.T
    assert np.allclose(axes.plane[count:2 * count, :3], normal, atol=1e-6)
    # the moved plane passes through the moved petal
    side = np.einsum("ij,ij->i", copy, axes.plane[allp[second], :3]) - axes.plane[allp[second], 3]
    assert np.abs(side[axes.on_axis[second]]).max() < 0.5


def test_scene_flower_takes_an_index_as_a_number_in_the_file(tmp_path):
    from pipeline.config import load_config

    scene = tmp_path / "bush.toml"
    scene.write_text('[scene]\nmesh = "bush.obj"\nflower = 2\n')
    assert load_config(scene)["scene.flower"] == "2"
    scene.write_text('[scene]\nmesh = "bush.obj"\nflower = 2.5\n')
    with pytest.raises(Exception, match="scene.flower"):
        load_config(scene)


def test_start_frames_are_seeded_and_the_first_starts_at_once():
    from pipeline.flower.stagger import start_frames

    a = start_frames(10, 30, seed=3)
    assert np.array_equal(a, start_frames(10, 30, seed=3))
    assert a.min() == 0 and a.max() <= 30 and len(set(a.tolist())) > 1
    assert not np.array_equal(a, start_frames(10, 30, seed=4))
    assert not start_frames(1, 30, 0).any() and not start_frames(5, 0, 0).any()


def test_a_staggered_flower_is_the_run_shifted_holding_its_bud_and_its_end():
    from pipeline.flower.stagger import staggered

    run = np.arange(4, dtype=float)[:, None, None] * np.ones((4, 3, 3))  # frame t: all t
    out = staggered(run, np.array([0, 1, 1]), np.array([0, 2]))
    assert out.shape == (6, 3, 3)
    assert out[:, 0, 0].tolist() == [0, 1, 2, 3, 3, 3]  # on time, then holds its end
    assert out[:, 1, 0].tolist() == [0, 0, 0, 1, 2, 3]  # holds its bud 2 frames


def staggered_bush_usd(tmp_path):
    """Three flowers of five petals through every stage (short) and exported staggered
    (scene.stagger 6, seed 1) to one USD of the sheets: ``(usd, sim.h5, start frames)``."""
    mesh = _bush_obj(tmp_path)
    short = ["--set", "simulate.steps=400", "--set", "simulate.frames=5",
             "--set", "growth.start=bud", "--set", "effects.collisions.enabled=false"]
    paths = {k: tmp_path / f"{k}.h5" for k in ("r", "a", "g", "s")}
    for stage, src, out, extra in (("remesh", mesh, "r", []), ("axis", paths["r"], "a", []),
                                   ("growth", paths["a"], "g", []),
                                   ("simulate", paths["g"], "s", short)):
        r = CliRunner().invoke(cli, ["-q", stage, str(src), "--out", str(paths[out]), *extra])
        assert r.exit_code == 0, r.output
    usd = tmp_path / "bloom.usda"
    r = CliRunner().invoke(cli, ["export", str(paths["s"]), "--out", str(usd), "--set",
                                 "scene.stagger=6", "--set", "scene.stagger_seed=1",
                                 "--set", "export.mesh=sheet"])
    assert r.exit_code == 0, r.output
    from pipeline.flower.stagger import start_frames

    return usd, paths["s"], start_frames(3, 6, 1)


def staggered_bush_frames(sim, starts):
    """What the staggered bush's USD holds: each frame's points in the USD's order (a
    mesh per petal, in order), at the input's scale."""
    from pipeline.flower.stagger import staggered

    with h5py.File(sim) as h:
        run, petal = h["frames/positions"][()], h["mesh/petal"][()]
        scale = h.attrs["scale"]
    order = np.argsort(petal, kind="stable")
    return staggered(run / scale, petal // 5, starts)[:, order]


def test_many_flowers_come_back_staggered_in_one_usd(tmp_path):
    from pxr import Usd

    from pipeline.io.export import read_usd_points

    usd, sim, starts = staggered_bush_usd(tmp_path)
    stage = Usd.Stage.Open(str(usd))
    assert stage.GetEndTimeCode() == 4 + starts.max()  # the run's 5 frames, then the latest
    want = staggered_bush_frames(sim, starts)
    for t in (0, int(starts.max()), 4 + int(starts.max())):
        got = read_usd_points(usd, float(t))
        np.testing.assert_allclose(got, want[t], rtol=1e-6, atol=1e-6 * np.abs(want).max())
    with h5py.File(sim) as h:
        bud, petal = h["frames/positions"][0] / h.attrs["scale"], h["mesh/petal"][()]
    flower = (petal // 5)[np.argsort(petal, kind="stable")]
    late = int(np.argmax(starts))  # at its start frame the latest flower still holds its bud
    np.testing.assert_array_equal(want[starts[late]][flower == late],
                                  bud[np.argsort(petal, kind="stable")][flower == late])


def test_the_flowers_of_a_file_are_problems_apart_however_near():
    """With contact, petals that can meet are one problem; but the flowers of a file are
    each a problem of their own (each from its own bud, staggered by the scene), even
    where their boxes overlap: contact is kept within each flower."""
    from pipeline.sim.build import Prepared
    from pipeline.sim.effects import Params
    from pipeline.sim.solver.pieces import split

    v, f, p = procedural.bud(3, 300, 0)
    near = 0.3 * np.ptp(v, axis=0).max()  # (a second bud, within the first's reach)
    v, f, p = np.vstack([v, v + [near, 0.0, 0.0]]), np.vstack([f, f + len(v)]), np.r_[p, p + 3]
    prep = Prepared.from_mesh(v, f, p)
    model = prep.model(0.1, 0.0005)
    params = Params.defaults()
    assert split(model, prep.effects(("collisions",), params), prep.vertices) == []  # one problem
    prep.flower = (prep.petal >= 3).astype(np.int64)
    parts = split(model, prep.effects(("collisions",), params), prep.vertices)
    assert [np.unique(prep.flower[pt.vertices]).tolist() for pt in parts] == [[0], [1]]
    assert all(pt.effects.collisions is not None for pt in parts)
    assert sorted(np.unique(prep.petal[parts[1].vertices]).tolist()) == [3, 4, 5]
    from pipeline.sim.model import Control, State
    from pipeline.sim.solver.quasistatic import QuasiStatic

    control = Control("linear", 1.0)
    state = State.at_rest(model, prep.vertices, control)
    qs = QuasiStatic(stages=2)
    qs.advance(model, state, control, 1, 0.1, prep.effects(("collisions",), params))
    assert qs.newton.contact is None  # (no contact between the flowers ...)
    assert len(qs._parts) == 2 and all(pt.solver.newton.contact is not None for pt in qs._parts)


def _bush_growth(tmp_path):
    """The three-flower bush through remesh, axis and growth: growth.h5."""
    mesh = _bush_obj(tmp_path)
    paths = {k: tmp_path / f"{k}.h5" for k in ("r", "a", "g")}
    for stage, src, out in (("remesh", mesh, "r"), ("axis", paths["r"], "a"),
                            ("growth", paths["a"], "g")):
        r = CliRunner().invoke(cli, ["-q", stage, str(src), "--out", str(paths[out])])
        assert r.exit_code == 0, r.output
    return paths["g"]


SHORT = ["--set", "simulate.steps=400", "--set", "simulate.frames=5", "--set",
         "growth.start=bud", "--set", "effects.collisions.enabled=false", "--set",
         "scene.stagger=2"]


def test_each_flower_of_a_file_blooms_as_it_would_alone(tmp_path):
    """A file of staggered flowers is simulated flower by flower: each flower's frames
    in sim.h5 are, to the bit, those of its own problem run alone (at its own size,
    :func:`pipeline.chain.flowers.solve`); the openings per petal are each flower's, in
    the file's petal order, and their mean is the mean."""
    from pipeline.chain import problem
    from pipeline.chain.flowers import solve
    from pipeline.config import load_config
    from pipeline.flower.measure import Start
    from pipeline.sim.build import Prepared

    growth = _bush_growth(tmp_path)
    r = CliRunner().invoke(cli, ["simulate", str(growth), "--out", str(tmp_path / "s.h5"),
                                 *SHORT])
    assert r.exit_code == 0, r.output
    assert "flower 2 of 3: 5 petal(s)" in r.output
    with h5py.File(tmp_path / "s.h5") as h:
        X, opening = h["frames/positions"][()], h["diagnostics/opening_angle_per_petal"][()]
        mean = h["diagnostics/opening_angle"][()]
        assert "flowers_kept_as_modelled" not in h.attrs
    cfg = load_config(None, [s for s in SHORT if s != "--set"])
    job = problem.Job(cfg, Start("bud", float("nan"), "test"), [], {}, False, False, "test")
    with h5py.File(growth) as src:
        prep = Prepared.from_artifact(src)
        part, idx = prep.flower_part(1)
        alone = solve(part, job, tmp_path / "alone.ckpt", "alone")
        mine = np.unique(np.asarray(prep.petal)[idx])
    np.testing.assert_array_equal(X[:, idx], np.asarray(alone.rec.positions))
    np.testing.assert_array_equal(opening[:, mine], alone.rec.arrays()["opening_angle_per_petal"])
    np.testing.assert_allclose(mean, opening.mean(axis=1), rtol=1e-12)
    assert opening[-1].min() > 1.0  # (every petal opened some)


def test_a_flower_of_a_file_blooms_the_same_at_any_size(tmp_path):
    """A flower of a file is solved at its own size (pipeline.chain.flowers.solve): the
    same flower three times the size blooms three times the size, to 1e-9 of it, with
    contact on. Solved at the size it is given, the two differed by 1.2% of the flower's
    size (measured; which of the solve's mesh-unit settings makes it, not)."""
    from pipeline.chain import problem
    from pipeline.chain.flowers import solve
    from pipeline.config import load_config
    from pipeline.flower.measure import Start
    from pipeline.sim.build import Prepared

    growth = _bush_growth(tmp_path)
    sets = ["simulate.steps=400", "simulate.frames=5", "effects.collisions.enabled=true"]
    job = problem.Job(load_config(None, sets), Start("bud", float("nan"), "test"),
                      ["collisions"], {}, False, False, "test")
    with h5py.File(growth) as src:
        part, _ = Prepared.from_artifact(src).flower_part(0)
        one = np.asarray(solve(part, job, tmp_path / "one.ckpt", "one").rec.positions)
        three = np.asarray(solve(part.scaled(3.0), job, tmp_path / "three.ckpt",
                                 "three").rec.positions)
    size = float(np.ptp(one[0], axis=0).max())
    assert np.abs(three / 3.0 - one).max() < 1e-9 * size
    assert np.abs(one[-1] - one[0]).max() > 0.2 * size  # (it bloomed)


def test_flowers_bloom_side_by_side_to_the_same_bits(tmp_path):
    """simulate.workers: the flowers of a file bloomed in one process and in two forked
    ones give the same sim.h5 arrays bit for bit, and the same log, flower after flower
    (a worker's log is written by the parent as its flower comes back)."""
    growth = _bush_growth(tmp_path)
    out, logs = {}, {}
    for n in (1, 2):
        path = tmp_path / f"s{n}.h5"
        r = CliRunner().invoke(cli, ["simulate", str(growth), "--out", str(path), *SHORT,
                                     "--set", f"simulate.workers={n}"])
        assert r.exit_code == 0, r.output
        logs[n] = [line for line in r.output.splitlines()
                   if line.startswith(("flower ", "growth.start")) or "vertices (" in line]
        with h5py.File(path) as h:
            out[n] = {k: h[k][()] for k in ("frames/positions", "frames/time",
                                             "diagnostics/opening_angle_per_petal")}
    assert "3 of 3 flowers to bloom, 2 side by side" in r.output
    for key, value in out[1].items():
        np.testing.assert_array_equal(out[2][key], value, err_msg=key)
    assert logs[2] == logs[1]
    assert [line.split(":")[0] for line in logs[2] if line.startswith("flower ")] == [
        "flower 0 of 3", "flower 1 of 3", "flower 2 of 3"]


def test_a_flower_that_cannot_bloom_is_kept_as_modelled_and_named(tmp_path, monkeypatch):
    """One flower of three whose bloom is refused: the others bloom, it stays as
    modelled in every frame, the log says why in a warning naming it, sim.h5 and the
    report name it and the summary is unsound. Every flower refused: the run is."""
    from pipeline.chain import problem
    from pipeline.errors import BloomError

    growth = _bush_growth(tmp_path)
    original = problem.problem

    def refusing(prep, job, ckpt, label=""):
        if label in refused:
            raise BloomError("simulate.stages: the quasi-static solver found no equilibrium "
                             "(petal 2)", where=job.where)
        return original(prep, job, ckpt, label)

    monkeypatch.setattr(problem, "problem", refusing)
    refused = {"flower 1"}
    r = CliRunner().invoke(cli, ["simulate", str(growth), "--out", str(tmp_path / "s.h5"),
                                 *SHORT])
    assert r.exit_code == 0, r.output
    assert ("flower 1 could not bloom; it is kept as modelled: simulate.stages: the "
            "quasi-static solver found no equilibrium") in r.output
    with h5py.File(tmp_path / "s.h5") as h:
        X, petal = h["frames/positions"][()], h["mesh/petal"][()]
        opening = h["diagnostics/opening_angle_per_petal"][()]
        assert h.attrs["flowers_kept_as_modelled"].tolist() == [1]
        assert h.attrs["summary"].startswith("unsound")
        assert "1 flower(s) kept as modelled, no bloom found: flower 1" in h.attrs["summary"]
    with h5py.File(growth) as g:
        model = g["mesh/vertices"][()]
    held = (petal // 5) == 1
    assert np.all(X[:, held] == model[held])  # as modelled, every frame
    assert np.abs(X[-1, ~held] - model[~held]).max() > 0.1  # the others bloomed
    assert np.all(opening[-1, 5:10] == 0.0) and opening[-1, :5].min() > 1.0
    r = CliRunner().invoke(cli, ["report", str(tmp_path / "s.h5"), "--out",
                                 str(tmp_path / "report.json")])
    assert r.exit_code == 0, r.output
    import json

    data = json.loads((tmp_path / "report.json").read_text())
    assert data["flowers_kept_as_modelled"] == [1] and data["summary"].startswith("unsound")

    refused.update({"flower 0", "flower 2"})
    r = CliRunner().invoke(cli, ["simulate", str(growth), "--out", str(tmp_path / "t.h5"),
                                 *SHORT])
    assert r.exit_code != 0 and "simulate.stages" in r.output.splitlines()[-1]
    assert not (tmp_path / "t.h5").exists()


def _copied_bush(tmp_path, scale: float = 1.0):
    """Three open lilies, the third the first scaled by ``scale``, turned and moved: its
    growth.h5 (remesh, axis and growth run), and ``(vertices, faces, petal, turn, move)``."""
    v, f, petal, _ = bush(petals=5, vertices=600)
    first = np.flatnonzero(petal < 5)
    second = np.flatnonzero((petal >= 5) & (petal < 10))
    turn = _rotation(np.array([0.3, -0.5, 1.0]))
    move = np.array([0.5, 4.0, 0.2])

    def faces_of(idx):
        return np.searchsorted(idx, f[np.isin(f[:, 0], idx)])

    parts = [("Flower.000", v[first], faces_of(first)), ("Flower.001", v[second], faces_of(second)),
             ("Flower.002", scale * v[first] @ turn.T + move, faces_of(first))]
    mesh = write_parts(tmp_path / "copies.obj", parts)
    paths = {k: tmp_path / f"{k}.h5" for k in ("r", "a", "g", "s")}
    for stage, src, out in (("remesh", mesh, "r"), ("axis", paths["r"], "a"),
                            ("growth", paths["a"], "g")):
        r = CliRunner().invoke(cli, ["-q", stage, str(src), "--out", str(paths[out])])
        assert r.exit_code == 0, r.output
    return paths, (v, f, petal, turn, move)


@pytest.mark.parametrize("scale", [1.0, 1.25])
def test_a_flower_that_is_a_copy_of_another_blooms_as_it_does_moved(tmp_path, scale):
    """Instanced blossoms: the third flower is the first one turned and moved, and
    scaled 1.25 (its petals remeshed alike, as remesh does a copy). It is not simulated
    again: its frames are the first flower's turned, moved and scaled, to rounding, and
    its own problem, solved alone (at its own size, as every flower of a file is), blooms
    the same to a millionth of the petal length. (Solved at the file's scale, a copy
    scaled 1.25 opened 55-58 deg where its original opened 62-89.)"""
    from pipeline.chain import problem
    from pipeline.chain.flowers import solve
    from pipeline.config import load_config
    from pipeline.flower.measure import Start
    from pipeline.mesh.similar import similarity
    from pipeline.sim.build import Prepared

    paths, (v, f, petal, turn, move) = _copied_bush(tmp_path, scale)
    r = CliRunner().invoke(cli, ["simulate", str(paths["g"]), "--out", str(paths["s"]), *SHORT])
    assert r.exit_code == 0, r.output
    assert "1 of 3 flowers are copies of others" in r.output
    assert "flower 2 of 3" not in r.output  # (not simulated again)
    with h5py.File(paths["s"]) as h:
        X = h["frames/positions"][()]
    cfg = load_config(None, [s for s in SHORT if s != "--set"])
    job = problem.Job(cfg, Start("bud", float("nan"), "test"), [], {}, False, False, "test")
    with h5py.File(paths["g"]) as src:
        prep = Prepared.from_artifact(src)
        _, idx0 = prep.flower_part(0)
        part2, idx2 = prep.flower_part(2)
        alone = np.asarray(solve(part2, job, tmp_path / "alone.ckpt", "alone").rec.positions)
    size = float(np.ptp(X[0, idx2], axis=0).max())
    grown, rot, shift = similarity(X[0, idx0], X[0, idx2])  # (mesh units)
    assert np.allclose(rot, turn, atol=1e-9) and abs(grown - scale) < 1e-9
    moved = grown * X[:, idx0] @ rot.T + shift
    assert np.abs(X[:, idx2] - moved).max() < 1e-9 * size
    assert np.abs(alone - X[:, idx2]).max() < 1e-6 * size
    assert np.abs(X[-1, idx2] - X[0, idx2]).max() > 0.05 * size  # (it bloomed)


def test_a_copy_that_would_pass_through_a_neighbour_blooms_on_its_own(tmp_path, monkeypatch):
    """A copy's original has other neighbours than the copy: when the original's bloom,
    moved, passes through a neighbour of the copy, the copy blooms on its own and keeps
    the bloom that crosses less. Here the moved bloom is pushed into the second flower
    (as rounding can send a copy's path another way); the copy's own bloom is clear of
    it, so it is kept: flower 2's frames are its own problem's, and no frame the user
    sees (staggered) has a crossing."""
    from pipeline.chain import copies, problem
    from pipeline.chain.flowers import solve
    from pipeline.config import load_config
    from pipeline.flower.measure import Start
    from pipeline.sim.build import Prepared

    paths, (v, f, petal, turn, move) = _copied_bush(tmp_path)
    with h5py.File(paths["g"]) as src:
        prep = Prepared.from_artifact(src)
        _, idx1 = prep.flower_part(1)
        part2, idx2 = prep.flower_part(2)
        into = 0.8 * (np.asarray(prep.vertices)[idx1].mean(axis=0)
                      - np.asarray(prep.vertices)[idx2].mean(axis=0))
    original = copies.moved
    monkeypatch.setattr(copies, "moved",
                        lambda run, rot, t, scale: original(run, rot, t + into, scale))
    r = CliRunner().invoke(cli, ["simulate", str(paths["g"]), "--out", str(paths["s"]), *SHORT])
    assert r.exit_code == 0, r.output
    assert "1 copied flower(s) pass through a neighbour when moved (flower 2 in" in r.output
    assert "flower 2 blooms on its own: it crosses a neighbour in 0 frame(s)" in r.output
    with h5py.File(paths["s"]) as h:
        X = h["frames/positions"][()]
        assert not h["diagnostics/intersecting"][()].any()
        assert h.attrs["summary"].startswith("sound"), h.attrs["summary"]
    cfg = load_config(None, [s for s in SHORT if s != "--set"])
    job = problem.Job(cfg, Start("bud", float("nan"), "test"), [], {}, False, False, "test")
    alone = np.asarray(solve(part2, job, tmp_path / "alone.ckpt", "alone").rec.positions)
    size = float(np.ptp(X[0, idx2], axis=0).max())
    assert np.abs(alone - X[:, idx2]).max() < 1e-9 * size


#: SHORT with contact, the three flowers starting at frames 2, 1, 0 apart
SHORT_TOGETHER = [s.replace("collisions.enabled=false", "collisions.enabled=true")
                  .replace("scene.stagger=2", "scene.stagger=4") for s in SHORT]


def _pushed_into(original, into):
    """``original`` (:func:`pipeline.chain.problem.problem`) with flower 1's bloom apart
    pushed by ``into`` (in the flower's own units, ~1) in every frame but its first and
    last, as a path swinging wide would be."""
    import dataclasses

    from pipeline.sim.run import Recording

    def pushed(part, job, ckpt, label=""):
        run = original(part, job, ckpt, label)
        if label != "flower 1":
            return run
        frames = [np.asarray(X) + (into if 0 < i < len(run.rec.positions) - 1 else 0.0)
                  for i, X in enumerate(run.rec.positions)]
        return dataclasses.replace(run, rec=Recording(list(run.rec.time), frames,
                                                      run.rec.diagnostics))

    return pushed


def test_flowers_that_cross_blooming_apart_bloom_together(tmp_path, monkeypatch):
    """Staggered flowers bloom apart, each at its own stage of growth: where two pass
    through each other in a frame the user sees, they bloom together, as one problem
    with contact between them, each petal opening about its own flower's axis, and
    start together. Here flower 1's bloom apart is pushed into flower 0 mid-bloom (as
    a path swinging wide would); together they are clear of each other. Their frames are
    those of their problem together, to the bit; sim.h5 names the problem of each
    flower, and the export staggers the two as one."""

    from pipeline.chain import problem
    from pipeline.chain.flowers import solve
    from pipeline.config import load_config
    from pipeline.flower import stagger
    from pipeline.flower.measure import Start
    from pipeline.sim.build import Prepared

    growth = _bush_growth(tmp_path)
    with h5py.File(growth) as src:
        prep = Prepared.from_artifact(src)
        both, idx = prep.flowers_part([0, 1])
        v = np.asarray(prep.vertices)
        flower = np.asarray(prep.flower)
        into = 0.6 * (v[flower == 0].mean(axis=0) - v[flower == 1].mean(axis=0))
        axes = np.asarray(src["flower/axis"])
    # each petal's flower's axis: the two lilies lean their own ways
    np.testing.assert_array_equal(both.flower_axis, axes[[0] * 5 + [1] * 5])
    assert np.degrees(np.arccos(np.clip(axes[0, 3:] @ axes[1, 3:], -1, 1))) > 5.0
    monkeypatch.setattr(problem, "problem", _pushed_into(problem.problem, into))
    short = SHORT_TOGETHER  # (starts 2, 1, 0)
    out = tmp_path / "s.h5"
    r = CliRunner().invoke(cli, ["simulate", str(growth), "--out", str(out), *short])
    assert r.exit_code == 0, r.output
    assert "flowers 0, 1 pass through each other in" in r.output
    assert "flowers 0, 1 bloom together: they and their neighbours cross in 0 frame(s)" in r.output
    with h5py.File(out) as h:
        X = h["frames/positions"][()]
        assert h["flower/together"][()].tolist() == [0, 0, 2]
        assert not h["diagnostics/intersecting"][()].any()
        assert h.attrs["summary"].startswith("sound"), h.attrs["summary"]
        cfg = load_config(None, [s for s in short if s != "--set"])
        starts = stagger.of_run(h, cfg)
    assert starts.tolist() == [1, 1, 0]  # (2, 1, 0 apart)
    job = problem.Job(cfg, Start("bud", float("nan"), "test"), ["collisions"], {}, False,
                      False, "test")
    together = np.asarray(solve(both, job, tmp_path / "both.ckpt", "both").rec.positions)
    np.testing.assert_array_equal(X[:, idx], together)


def test_each_petals_axis_is_the_flowers_axis_where_all_are_one():
    """A part of several flowers carries each petal's flower's axis ``(P, 6)``: where
    every row is the one flower's axis, the opening frames, the inner sides, the
    closing lift and the petals' layers are those of the flower's axis ``(6,)``."""
    from pipeline.flower.measure import PetalFrames
    from pipeline.sim.budshape import inner_sides
    from pipeline.sim.effects import flower_axis_or_guess, petal_layers
    from pipeline.sim.reverse import closing_lift

    v, f, petal, _ = bush(petals=5, vertices=600)
    first = petal < 5
    v, petal = v[first], petal[first]
    f = f[np.all(first[f], axis=1)]
    axes = find_axes(v, f, petal)
    one = np.asarray(axes.flower_axis)
    each = np.tile(one, (5, 1))
    a = PetalFrames.from_mesh(v, petal, axes.base, axes.on_axis, axes.tip, axes.plane, one)
    b = PetalFrames.from_mesh(v, petal, axes.base, axes.on_axis, axes.tip, axes.plane, each)
    np.testing.assert_array_equal(a.outward_dirs, b.outward_dirs)
    np.testing.assert_array_equal(inner_sides(v, f, petal, axes.s, one),
                                  inner_sides(v, f, petal, axes.s, each))
    (p1, up1), (p5, up5) = flower_axis_or_guess(v, one), flower_axis_or_guess(v, each)
    np.testing.assert_allclose(closing_lift(v, axes.s, axes.x, axes.base, up1, 0.3),
                               closing_lift(v, axes.s, axes.x, axes.base, up5[petal], 0.3),
                               rtol=1e-15, atol=0)
    np.testing.assert_allclose(petal_layers(v, petal, p1, up1), petal_layers(v, petal, p5, up5),
                               rtol=1e-12)


def test_one_sheet_of_petals_around_a_wide_hub_is_one_flower(tmp_path):
    """A flower modelled as one sheet (an OpenSCAD union, a low-poly star) whose hub is
    wider than its petals are long: the sheet is split into its petals at the hub, and
    they are one flower, though their bases are further apart than the flowers' rule
    links (each its own flower before)."""
    from tests.test_lobes import star

    v, f = star(k=6, hub=1.5, length=1.0, rings=12, around=180, cup=0.1)
    base = flowers(*_star_petals(v, f, 6))
    assert base.count == 6  # by their bases alone: six flowers
    mesh = write_parts(tmp_path / "star.obj", [("Star", v, f)])
    r = CliRunner().invoke(cli, ["remesh", str(mesh), "--out", str(tmp_path / "r.h5")])
    assert r.exit_code == 0, r.output
    assert "joined at a hub" in r.output and "1 flower(s)" in r.output, r.output
    with h5py.File(tmp_path / "r.h5") as h:
        assert h.attrs["petal_count"] == 6 and h.attrs["flower_count"] == 1
        assert np.all(h["mesh/flower"][()] == 0)


def _star_petals(v, f, k):
    """The star's vertices outside its hub, labelled by the petal (angle) each is in."""
    r = np.linalg.norm(v[:, :2], axis=1)
    out = r > 1.6
    petal = np.round(np.arctan2(v[out, 1], v[out, 0]) * k / (2 * np.pi)).astype(int) % k
    return v[out], petal


def test_a_blossoms_petals_whose_bases_lie_apart_find_their_base_by_their_neighbours():
    """Two blossoms far apart, each of five strip petals radiating from 0.3 of a petal
    length off its centre (the bases 0.35 of a length apart: past NEAR, so neither end
    of a petal has another petal near). The base is the end nearer another petal; by
    the mean of the file's petals (the old rule) the petal of each blossom that points
    at the other took its tip for its base and came apart from its blossom."""
    from pipeline.mesh.flowers import flowers

    points, label = [], []
    for centre in (np.zeros(3), np.array([100.0, 0.0, 0.0])):
        for k in range(5):
            a = 2 * np.pi * k / 5
            radial, side = np.array([np.cos(a), np.sin(a), 0.0]), np.array([-np.sin(a), np.cos(a), 0.0])
            s, w = np.meshgrid(np.linspace(0.3, 1.3, 11), np.linspace(-0.15, 0.15, 3))
            strip = centre + s.reshape(-1, 1) * radial + w.reshape(-1, 1) * side
            strip[:, 2] += 0.3 * (s.reshape(-1) - 0.3)  # (leaning up)
            points.append(strip)
            label.append(np.full(len(strip), len(label)))
    found = flowers(np.vstack(points), np.concatenate(label))
    assert found.count == 2
    assert np.array_equal(found.flower, np.repeat([0, 1], 5))
    radial_base = np.linalg.norm(found.base[:, :2] - np.repeat([[0.0, 0.0], [100.0, 0.0]], 5, axis=0),
                                 axis=1)
    assert np.all(radial_base < 0.5)  # every base at the blossom's centre end


def test_flowers_whose_buds_found_apart_cross_are_searched_together(tmp_path, monkeypatch):
    """Flowers that cross blooming apart bloom together from buds searched within each
    flower; where those buds pass through each other (a branch's blossoms a few tenths
    of a petal apart), the bloom together cannot start, and the buds are searched again
    with contact between the flowers too: that bloom is kept, its frames those of the
    problem searched together, to the bit. (The crossing buds are a stand-in: the first
    search together is refused as contact refuses such a bud.)"""
    import dataclasses

    from pipeline.chain import problem
    from pipeline.chain.flowers import solve
    from pipeline.config import load_config
    from pipeline.errors import BloomError
    from pipeline.flower.measure import Start
    from pipeline.sim.build import Prepared

    growth = _bush_growth(tmp_path)
    with h5py.File(growth) as src:
        prep = Prepared.from_artifact(src)
        both, idx = prep.flowers_part([0, 1])
        v = np.asarray(prep.vertices)
        flower = np.asarray(prep.flower)
        into = 0.6 * (v[flower == 0].mean(axis=0) - v[flower == 1].mean(axis=0))
    original = problem.problem
    push = _pushed_into(original, into)
    seen = []

    def pushed(part, job, ckpt, label=""):
        if part.together:
            seen.append(part.searched_together)
            if not part.searched_together:
                raise BloomError("effects.collisions: petals 2-7 pass through each other in "
                                 "the bud: contact cannot start from an intersecting bud",
                                 where=job.where)
        return push(part, job, ckpt, label)

    monkeypatch.setattr(problem, "problem", pushed)
    short = SHORT_TOGETHER
    out = tmp_path / "s.h5"
    r = CliRunner().invoke(cli, ["simulate", str(growth), "--out", str(out), *short])
    assert r.exit_code == 0, r.output
    assert seen == [False, True]
    assert "their buds are searched together, with contact between them" in r.output
    assert "flowers 0, 1 bloom together: they and their neighbours cross in 0 frame(s)" in r.output
    with h5py.File(out) as h:
        X = h["frames/positions"][()]
        assert h["flower/together"][()].tolist() == [0, 0, 2]
        assert not h["diagnostics/intersecting"][()].any()
    cfg = load_config(None, [s for s in short if s != "--set"])
    job = problem.Job(cfg, Start("bud", float("nan"), "test"), ["collisions"], {}, False,
                      False, "test")
    searched = dataclasses.replace(both, searched_together=True)
    together = np.asarray(solve(searched, job, tmp_path / "both.ckpt", "both").rec.positions)
    np.testing.assert_array_equal(X[:, idx], together)

    # the bud search's contact: within each flower, or between them too where so asked
    asked = []
    monkeypatch.setattr(Prepared, "effects", lambda self, names, params, **kw:
                        asked.append(kw["apart"]) or (_ for _ in ()).throw(BloomError("stop")))
    open_job = dataclasses.replace(job, start=Start("open", float("nan"), "test"))
    for part, apart in ((both, True), (searched, False)):
        asked.clear()
        with pytest.raises(BloomError, match="stop"):
            original(part, open_job, tmp_path / "bud.ckpt", "both")
        assert asked and set(asked) == {apart}
