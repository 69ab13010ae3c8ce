"""axis.flower_axis and scene.up: the flower's axis given as a key (a Y-up or tilted model
keeps its bases and tips); no axis or growth output is ever NaN: a petal that would give
one is handled or refused in one line naming it. Numpy warnings are errors here."""

from __future__ import annotations

import dataclasses

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from pipeline.chain import axis as chain_axis
from pipeline.chain import growth as chain_growth
from pipeline.config import load_config
from pipeline.directions import parse_direction
from pipeline.errors import BloomError
from pipeline.flower import axis
from pipeline.flower.axis import BadPetal, PetalAxes, check_axes, find_axes
from pipeline.mesh import clean, procedural, symmetry
from stages.cli import cli

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")


def sound(axes: PetalAxes, petal: np.ndarray) -> PetalAxes:
    """What every find_axes output must be: finite, x in [-1, 1], s in [0, 1], a base of
    at least 3 vertices and a tip beyond it per petal."""
    for name in ("x", "s", "plane"):
        assert np.all(np.isfinite(getattr(axes, name))), name
    assert axes.x.min() >= -1.0 and axes.x.max() <= 1.0
    assert axes.s.min() >= 0.0 and axes.s.max() <= 1.0
    for p, tip in enumerate(axes.tip):
        assert axes.base[petal == p].sum() >= 3 and petal[tip] == p and not axes.base[tip]
    check_axes(axes, petal)
    return axes


def to_y_up(v):  # +z -> +y, exactly (a permutation and a sign)
    return np.stack([v[:, 0], v[:, 2], -v[:, 1]], axis=1)


def tilt(v, degrees=45.0):  # about x: +z -> (0, -sin, cos)
    a = np.radians(degrees)
    r = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]])
    return v @ r.T, r @ np.array([0.0, 0.0, 1.0])


@pytest.fixture(scope="module")
def bud():
    v, f, p = procedural.bud(6, 900, 0)
    return v / clean.mean_edge_length(v, f), f, p


@pytest.fixture(scope="module")
def lone():
    v, f, p = procedural.bud(1, 200, 0)
    return v / clean.mean_edge_length(v, f), f, p


def same(a: PetalAxes, b: PetalAxes) -> None:
    assert np.array_equal(a.base, b.base)
    assert np.array_equal(a.tip, b.tip)
    assert np.array_equal(a.on_axis, b.on_axis)
    assert np.allclose(a.s, b.s, atol=1e-9) and np.allclose(a.x, b.x, atol=1e-9)


def test_parse_direction():
    assert parse_direction("auto") is None
    assert np.array_equal(parse_direction("-y"), [0.0, -1.0, 0.0])
    assert np.allclose(parse_direction(" 0, -1, 1 "), np.array([0.0, -1.0, 1.0]) / np.sqrt(2))
    for bad in ("up", "1,2", "0,0,0", "nan,0,1", "1,inf,0", "1,2,3,4", "a,b,c", ""):
        with pytest.raises(ValueError, match="three finite numbers"):
            parse_direction(bad)


def test_a_y_up_bud_given_plus_y_keeps_its_bases_and_tips(bud):
    v, f, p = bud
    z_up = sound(find_axes(v, f, p), p)
    y_up = sound(find_axes(to_y_up(v), f, p, flower_axis="+y"), p)
    same(z_up, y_up)
    assert np.array_equal(y_up.flower_axis[3:], [0.0, 1.0, 0.0])
    assert np.linalg.norm(y_up.flower_axis[[0, 2]]) < 1e-6  # the bud's axis: through the origin
    # a found axis points from the receptacle to the tips, here +z
    assert z_up.flower_axis[5] > 0.999
    assert np.all(v[z_up.base, 2] < v[z_up.tip, 2].min())


def test_a_lone_petal_takes_its_base_at_the_end_lowest_along_the_given_axis(lone):
    v, f, p = lone
    z_up = sound(find_axes(v, f, p), p)  # the lone-petal rule: the narrow end
    up = sound(find_axes(to_y_up(v), f, p, flower_axis="+y"), p)
    down = sound(find_axes(to_y_up(v), f, p, flower_axis="-y"), p)
    same(z_up, up)
    assert np.isnan(z_up.flower_axis).all() and np.all(np.isfinite(up.flower_axis))
    # upside down, the base is the other end: the petal's top
    yy = to_y_up(v)[:, 1]
    assert yy[down.base].min() > yy[up.tip] - 0.2 * np.ptp(yy)
    assert yy[down.tip] < yy[up.base].max() + 0.2 * np.ptp(yy)
    assert not np.any(down.base & up.base)


def test_a_bud_tilted_45_degrees_with_its_axis_given(bud, lone):
    for v, f, p in (bud, lone):
        z_up = sound(find_axes(v, f, p), p)
        vt, axis_dir = tilt(v)
        given = sound(find_axes(vt, f, p, flower_axis=",".join(f"{c:.17g}" for c in axis_dir)), p)
        same(z_up, given)
        assert np.allclose(given.flower_axis[3:], axis_dir, atol=1e-12)
        point = given.flower_axis[:3]
        if p.max() == 0:  # a lone petal's axis passes through its base
            assert np.allclose(point, vt[given.base].mean(axis=0))
        else:  # the bud's: the tilted z axis through the origin
            assert np.linalg.norm(point - (point @ axis_dir) * axis_dir) < 1e-6 * np.ptp(v)
        upside = sound(find_axes(vt, f, p, flower_axis=-axis_dir), p)  # the other way up
        if p.max() == 0:  # a lone petal follows the axis: base at the other end
            assert not np.any(upside.base & z_up.base)
        else:  # petals around an axis: the ends nearest it, whichever way it points; x
            # positive counterclockwise seen from the tips, which the axis given says
            same(z_up, dataclasses.replace(upside, x=-upside.x))


def test_a_wrong_axis_still_gives_sound_axes(bud):
    v, f, p = bud
    for wrong in ("+x", "1,1,0", "0.3,-2,0.1"):
        sound(find_axes(v, f, p, flower_axis=wrong), p)


def radiating(count: int, height):
    """``count`` quad-grid petals (8 rows of 5, widening outward) radiating in the xy plane
    from radius 2, petal ``k`` lifted by ``height(k, xy)`` (xy: its own flat grid, x along
    it): ``(vertices, faces, petal)``."""
    rows, cols = 8, 5
    pts = np.array([[r + 2.0, (c - (cols - 1) / 2) * (0.4 + 0.1 * r)] for r in range(rows)
                    for c in range(cols)])
    quads = [(r * cols + c, r * cols + c + 1, (r + 1) * cols + c + 1, (r + 1) * cols + c)
             for r in range(rows - 1) for c in range(cols - 1)]
    tri = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    vs, fs, ps = [], [], []
    for k in range(count):
        a = 2 * np.pi * k / count
        rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        vs.append(np.c_[pts @ rot.T, height(k, pts)])
        fs.append(tri + k * len(pts))
        ps.append(np.full(len(pts), k))
    return np.vstack(vs), np.vstack(fs), np.concatenate(ps)


def test_a_flat_open_flower_is_oriented_by_scene_up():
    """Petals radiating in z = 0, a little cupped across (else z = 0 would be their mirror
    plane): tips and bases at one height, so the center planes' line has no orientation
    from the petals; up gives it."""
    v, f, p = radiating(5, lambda k, xy: 0.05 * xy[:, 1] ** 2)
    for up in ([0.0, 0.0, 1.0], [0.0, 0.0, -1.0]):
        axes = sound(find_axes(v, f, p, up=np.array(up)), p)
        assert np.allclose(axes.flower_axis[3:], up, atol=1e-9)
        assert np.linalg.norm(axes.flower_axis[:2]) < 1e-9
        assert np.linalg.norm(v[axes.base, :2], axis=1).max() < 3.5  # the inner ends (rows 1-2)


def test_every_petal_of_a_flower_has_x_positive_the_same_way_around_its_axis():
    """An open flower whose petals cup alternately up and down (a cup tells a lone
    petal's outward side; here it flips from petal to petal, as a shallow cup's few
    midrib vertices on an irregular mesh can): each petal's center plane still points
    the same way around the flower's axis (counterclockwise seen from the tips), so x
    is positive on the same side of every petal, and the imperfection that picks a side
    pushes them alike. The cup's rule flipped the plane of every second petal."""
    v, f, p = radiating(6, lambda k, xy: (0.05 if k % 2 == 0 else -0.05) * xy[:, 1] ** 2
                        + 0.02 * xy[:, 0] ** 2)
    axes = sound(find_axes(v, f, p), p)
    line = axes.flower_axis
    for k in range(6):
        around = np.cross(line[3:], v[p == k].mean(axis=0) - line[:3])
        assert axes.plane[k, :3] @ around > 0.9 * np.linalg.norm(around), k
        # x follows the plane: positive where the petal's vertices are on its normal's side
        side = v[p == k] @ axes.plane[k, :3] - axes.plane[k, 3]
        far = np.abs(side) > 0.1
        assert np.all(np.sign(axes.x[p == k][far]) == np.sign(side[far])), k


def lone_triangle(bud):
    v, f, p = bud
    tri = np.array([[30.0, 0.0, 0.0], [31.0, 0.0, 0.0], [30.5, 0.9, 0.0]])
    return (np.vstack([v, tri]), np.vstack([f, [[len(v), len(v) + 1, len(v) + 2]]]),
            np.r_[p, [6, 6, 6]])


def test_petals_that_gave_nan_are_refused_naming_the_petal(bud, lone):
    v, f, p = lone_triangle(bud)  # was: s = 0/0 on petal 6 (all its vertices are its base)
    with pytest.raises(BadPetal, match="petal 6: all its 3 vertices are base vertices") as exc:
        find_axes(v, f, p)
    assert exc.value.petal == 6 and exc.value.key == "remesh.petal_vertices"
    v, f, p = lone  # two copies in one petal: was inf distances, x and s NaN
    two = (np.vstack([v, v + [0.0, 0.0, 30.0]]), np.vstack([f, f + len(v)]), np.r_[p, p])
    with pytest.raises(BadPetal, match="petal 0: in 2 pieces"):
        find_axes(*two)
    with pytest.raises(BadPetal, match="petal 1: 2 vertices"):
        find_axes(v[:5], np.array([[0, 1, 2]]), np.array([0, 0, 0, 1, 1]))


def test_a_center_plane_of_no_normal_is_found_again(lone):
    v, f, p = lone
    ref = sound(find_axes(v, f, p), p)
    for plane in (np.zeros((1, 4)), np.full((1, 4), np.nan)):
        same(ref, sound(find_axes(v, f, p, planes=plane), p))


def test_a_center_plane_across_the_flowers_axis_is_put_through_it(bud):
    """A petal's plane found across its length (normal along the axis the others meet
    in; an irregular mesh of a cupped petal can look more symmetric there) is replaced
    by the plane through the axis and its centroid: the bud's axes are then those of
    its own planes (to rounding), and the other petals' planes are kept to the bit."""
    v, f, p = bud
    planes = np.array([symmetry.mirror_plane(v[p == k])[0] for k in range(6)])
    ref = sound(find_axes(v, f, p, planes=planes), p)
    wrong = planes.copy()
    c = v[p == 1].mean(axis=0)
    wrong[1] = [0.1, 0.13, 0.99, 0.0]
    wrong[1, :3] /= np.linalg.norm(wrong[1, :3])
    wrong[1, 3] = wrong[1, :3] @ c
    fixed = axis._planes_about_axis(v, p, wrong)
    assert np.array_equal(np.delete(fixed, 1, axis=0), np.delete(planes, 1, axis=0))
    assert abs(fixed[1, :3] @ planes[1, :3]) > 0.999
    got = sound(find_axes(v, f, p, planes=wrong), p)
    assert np.array_equal(got.tip, ref.tip) and np.array_equal(got.base, ref.base)
    assert np.abs(got.x - ref.x).max() < 0.05
    # a bud whose planes all meet the axis: untouched
    assert axis._planes_about_axis(v, p, planes) is planes


def test_check_axes_refuses_each_unsound_output(bud):
    v, f, p = bud
    good = sound(find_axes(v, f, p), p)
    mine = np.flatnonzero(p == 3)
    cases = [("x", mine[5], np.nan, "not finite"), ("s", mine[7], np.nan, "not finite"),
             ("x", mine[5], 1.5, "outside"), ("s", mine[7], -0.25, "outside")]
    for name, i, value, words in cases:
        bad = PetalAxes(**{k: getattr(good, k).copy() for k in ("base", "on_axis", "tip", "plane",
                                                                  "x", "s", "flower_axis")})
        getattr(bad, name)[i] = value
        with pytest.raises(BadPetal, match=f"petal 3: .*{words}"):
            check_axes(bad, p)
    bad = PetalAxes(**{k: getattr(good, k).copy() for k in ("base", "on_axis", "tip", "plane",
                                                              "x", "s", "flower_axis")})
    bad.base[mine] = False
    bad.base[mine[:2]] = True
    with pytest.raises(BadPetal, match="petal 3: 2 base vertices"):
        check_axes(bad, p)
    bad.base[mine] = good.base[mine]
    bad.tip[3] = np.flatnonzero(good.base & (p == 3))[0]
    with pytest.raises(BadPetal, match="petal 3: no tip"):
        check_axes(bad, p)


# --- the stages ---------------------------------------------------------------------


def write_remesh(path, v, f, p):
    """A remesh.h5 as `bloom remesh` writes it for an already clean mesh (scale 1, no
    planes recorded: axis finds them), so these tests do not hang on the remesher."""
    from pipeline import artifact

    with artifact.writing(path, stage="remesh", config_json="{}", inputs={},
                          attrs={"scale": 1.0}) as h5:
        artifact.put(h5, "mesh/vertices", np.asarray(v, dtype=np.float64))
        artifact.put(h5, "mesh/faces", np.asarray(f, dtype=np.int64))
        artifact.put(h5, "mesh/petal", np.asarray(p, dtype=np.int64))
    return path


@pytest.fixture(scope="module")
def remeshed(bud, tmp_path_factory):
    """remesh.h5 of the bud Z-up, and of the same bud Y-up."""
    v, f, p = bud
    root = tmp_path_factory.mktemp("flower_axis")
    return {name: write_remesh(root / f"remesh_{name}.h5", verts, f, p)
            for name, verts in (("z", v), ("y", to_y_up(v)))}


def run_axis(remesh, out, *settings):
    args = ["-q", "axis", str(remesh), "--out", str(out)]
    for s in settings:
        args += ["--set", s]
    return CliRunner().invoke(cli, args)


def read(path):
    with h5py.File(path) as h5:
        return {k: h5[k][()] for k in ("mesh/vertices", "axis/base", "axis/tip", "axis/x",
                                       "axis/s")} | {"up": h5.attrs["up"],
                                                     "flower_axis": h5.attrs["flower_axis"]}


def test_the_axis_stage_with_a_y_up_bud_and_flower_axis_plus_y(remeshed, tmp_path):
    assert run_axis(remeshed["z"], tmp_path / "z.h5").exit_code == 0
    r = run_axis(remeshed["y"], tmp_path / "y.h5", "axis.flower_axis=+y")
    assert r.exit_code == 0, r.output
    z, y = read(tmp_path / "z.h5"), read(tmp_path / "y.h5")
    back = np.stack([y["mesh/vertices"][:, 0], -y["mesh/vertices"][:, 2],
                     y["mesh/vertices"][:, 1]], axis=1)
    assert np.array_equal(back, z["mesh/vertices"])
    assert np.array_equal(z["axis/base"], y["axis/base"])
    assert np.array_equal(z["axis/tip"], y["axis/tip"])
    for name in ("axis/x", "axis/s"):
        assert np.all(np.isfinite(z[name])) and np.all(np.abs(z[name]) <= 1.0)
    assert np.array_equal(y["flower_axis"][3:], [0.0, 1.0, 0.0])


def test_scene_up_is_the_files_then_the_keys_and_is_carried_forward(remeshed, tmp_path):
    remesh = tmp_path / "remesh.h5"
    remesh.write_bytes(remeshed["z"].read_bytes())
    assert run_axis(remesh, tmp_path / "a.h5").exit_code == 0
    assert read(tmp_path / "a.h5")["up"] == "+z"  # no file_up: +z
    with h5py.File(remesh, "a") as h5:
        h5.attrs["file_up"] = ""  # a format with no convention (OBJ)
    assert run_axis(remesh, tmp_path / "a2.h5").exit_code == 0
    assert read(tmp_path / "a2.h5")["up"] == "+z"
    with h5py.File(remesh, "a") as h5:
        h5.attrs["file_up"] = "+y"  # what remesh will record for a glTF
    assert run_axis(remesh, tmp_path / "b.h5").exit_code == 0
    assert read(tmp_path / "b.h5")["up"] == "+y"
    assert run_axis(remesh, tmp_path / "c.h5", "scene.up=-x").exit_code == 0
    assert read(tmp_path / "c.h5")["up"] == "-x"
    r = CliRunner().invoke(cli, ["-q", "growth", str(tmp_path / "b.h5"), "--out",
                                 str(tmp_path / "g.h5")])
    assert r.exit_code == 0, r.output
    with h5py.File(tmp_path / "g.h5") as h5:
        assert h5.attrs["up"] == "+y"
    # the arrays do not depend on up: a bud's tips orient its axis
    assert all(np.array_equal(read(tmp_path / "a.h5")[k], read(tmp_path / "c.h5")[k])
               for k in ("axis/base", "axis/tip", "axis/x", "axis/s", "flower_axis"))


@pytest.mark.parametrize("value", ["1,2", "0,0,0", "nan,0,1", "sideways", "1;2;3"])
def test_a_wrong_flower_axis_is_one_line_naming_the_key(remeshed, tmp_path, value):
    out = tmp_path / "axis.h5"
    r = run_axis(remeshed["z"], out, f"axis.flower_axis={value}")
    line = r.output.strip()
    assert r.exit_code != 0 and len(line.splitlines()) == 1 and "Traceback" not in line, line
    assert "axis.flower_axis" in line and not out.exists()
    toml = tmp_path / "scene.toml"
    toml.write_text(f'[axis]\nflower_axis = "{value}"\n')
    with pytest.raises(BloomError, match="axis.flower_axis"):
        load_config(toml)


def test_a_wrong_scene_up_is_refused():
    with pytest.raises(BloomError, match="scene.up"):
        load_config(None, ["scene.up=0,1,0"])
    assert load_config(None, ["axis.flower_axis=0, 1, 0"])["axis.flower_axis"] == "0, 1, 0"


def test_the_axis_stage_refuses_a_lone_triangle_in_one_line(bud, tmp_path):
    remesh = write_remesh(tmp_path / "remesh.h5", *lone_triangle(bud))  # as remesh kept it
    out = tmp_path / "axis.h5"
    r = run_axis(remesh, out)
    line = r.output.strip()
    assert r.exit_code != 0 and len(line.splitlines()) == 1 and "Traceback" not in line, line
    assert "petal 6" in line and "remesh.petal_vertices" in line and not out.exists()


def test_the_stages_check_their_own_outputs(remeshed, tmp_path, monkeypatch):
    """Whatever the library hands them, axis and growth write no NaN."""
    real = axis.find_axes

    def nan_x(*args, **kwargs):
        axes = real(*args, **kwargs)
        axes.x[np.flatnonzero(args[2] == 2)[4]] = np.nan
        return axes

    monkeypatch.setattr(chain_axis, "find_axes", nan_x)
    out = tmp_path / "axis.h5"
    r = run_axis(remeshed["z"], out)
    line = r.output.strip()
    assert r.exit_code != 0 and len(line.splitlines()) == 1 and "petal 2" in line, line
    assert "not finite" in line and not out.exists()
    monkeypatch.undo()

    assert run_axis(remeshed["z"], out).exit_code == 0
    from pipeline.flower import growth

    real_growth = growth.assign_growth
    with h5py.File(out) as h5:
        petal = h5["mesh/petal"][()]
    hit = {}

    def nan_angle(*args, **kwargs):
        g = real_growth(*args, **kwargs)
        h = np.flatnonzero(petal[g.hinges[:, 0]] == 4)[10]
        g.rest_angle[h] = np.nan
        hit["petal"] = int(petal[g.hinges[h, 0]])
        return g

    monkeypatch.setattr(chain_growth, "assign_growth", nan_angle)
    gout = tmp_path / "growth.h5"
    r = CliRunner().invoke(cli, ["-q", "growth", str(out), "--out", str(gout)])
    line = r.output.strip()
    assert r.exit_code != 0 and len(line.splitlines()) == 1 and "petal 4" in line, line
    assert hit["petal"] == 4 and "rest angle is not finite" in line and not gout.exists()
