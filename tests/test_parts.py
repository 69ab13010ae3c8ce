"""Named parts of a mesh file (read_parts) and which of them are petals (classify, select)."""

import json
import struct
from pathlib import Path

import numpy as np
import pytest
import trimesh

from pipeline.config import load_config
from pipeline.errors import BloomError
from pipeline.flower.classify import KINDS, classify, select
from pipeline.io.meshfile import MeshFile, Part, read_parts
from pipeline.mesh import procedural, symmetry, topology

EXTERNAL = Path(__file__).resolve().parents[2] / "shared" / "external-meshes"


# --- reading ----------------------------------------------------------------------------

def test_obj_objects_are_parts_in_file_order_with_local_triangulated_faces(tmp_path):
    path = tmp_path / "two.obj"
    path.write_text("# Blender 4.2\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nv 6 5 5\nv 6 6 5\nv 5 6 5\n"
                    "o Zeta\nf 4 5 6 7\no alpha\nf 1 2 3\n")
    mesh_file = read_parts(path)
    assert [p.name for p in mesh_file.parts] == ["Zeta", "alpha"]
    zeta, alpha = mesh_file.parts
    assert zeta.faces.shape == (2, 3) and len(zeta.vertices) == 4
    assert alpha.faces.shape == (1, 3) and len(alpha.vertices) == 3
    assert zeta.faces.dtype == np.int64 and zeta.vertices.dtype == np.float64
    assert np.allclose(zeta.vertices.min(axis=0), [5, 5, 5])  # its own vertices only
    assert mesh_file.up is None and mesh_file.meters_per_unit is None


def test_maya_groups_are_parts_and_the_centimetre_header_is_read(tmp_path):
    path = tmp_path / "maya.obj"
    lines = ["# This file uses centimeters as units for non-parametric coordinates.", "",
             "g default"]
    for k in range(3):
        lines += [f"v {k} 0 0", f"v {k} 1 0", f"v {k} 0 1"]
    for k, name in enumerate(["pCube14", "pCube2", "pCube14"]):
        lines += ["g default", f"g {name}", f"f {3 * k + 1} {3 * k + 2} {3 * k + 3}"]
    path.write_text("\n".join(lines) + "\n")
    mesh_file = read_parts(path)
    assert [p.name for p in mesh_file.parts] == ["pCube14", "pCube2"]  # the faces of one name join
    assert [len(p.faces) for p in mesh_file.parts] == [2, 1]
    assert mesh_file.meters_per_unit == 0.01


def test_obj_groups_within_objects_are_named_object_slash_group(tmp_path):
    path = tmp_path / "og.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n"
                    "o Flower\ng petals\nf 1 2 3\ng stem\nf 2 4 3\no Leaf\nf 1 2 4\n")
    assert [p.name for p in read_parts(path).parts] == ["Flower/petals", "Flower/stem", "Leaf"]


def test_glb_nodes_are_parts_in_node_order_placed_by_their_transforms(tmp_path):
    box = trimesh.creation.box()
    scene = trimesh.Scene()
    placed = {}
    for k, name in enumerate(["petal_b", "Circle.001", "stem"]):
        T = trimesh.transformations.rotation_matrix(0.7 * k, [0, 1, 0])
        T[:3, 3] = [k, 10.0 * k, 0]
        scene.add_geometry(box.copy(), geom_name=f"mesh{k}", node_name=name, transform=T)
        placed[name] = trimesh.transformations.transform_points(box.vertices, T)
    path = tmp_path / "flower.glb"
    path.write_bytes(scene.export(file_type="glb"))
    mesh_file = read_parts(path)
    assert [p.name for p in mesh_file.parts] == ["petal_b", "Circle.001", "stem"]
    for part in mesh_file.parts:
        assert len(part.vertices) == 8 and len(part.faces) == 12
        assert np.allclose(np.sort(part.vertices, axis=0), np.sort(placed[part.name], axis=0), atol=1e-6)
    assert mesh_file.up == "+y" and mesh_file.meters_per_unit == 1.0


def _edit_glb(data: bytes, edit) -> bytes:
    """Apply ``edit`` to a GLB's JSON chunk; the binary chunk is kept as it is."""
    n = struct.unpack("<I", data[12:16])[0]
    header = json.loads(data[20:20 + n])
    edit(header)
    text = json.dumps(header).encode()
    text += b" " * (-len(text) % 4)
    rest = data[20 + n:]
    return b"glTF" + struct.pack("<II", 2, 20 + len(text) + len(rest)) + \
        struct.pack("<I", len(text)) + b"JSON" + text + rest


def test_glb_names_fall_back_to_the_mesh_and_primitives_and_children_join_their_node(tmp_path):
    box = trimesh.creation.box()
    scene = trimesh.Scene()
    scene.add_geometry(box.copy(), geom_name="body", node_name="parent",
                       transform=trimesh.transformations.translation_matrix([0, 5, 0]))
    scene.add_geometry(box.copy(), geom_name="second", node_name="child", parent_node_name="parent",
                       transform=trimesh.transformations.translation_matrix([3, 0, 0]))
    scene.add_geometry(box.copy(), geom_name="Leaf mesh", node_name="nameless")

    def edit(h):
        names = [n.get("name") for n in h["nodes"]]
        parent, child = h["nodes"][names.index("parent")], h["nodes"][names.index("child")]
        del h["nodes"][names.index("nameless")]["name"]
        # the child's mesh becomes a second primitive of the parent's mesh
        h["meshes"][parent["mesh"]]["primitives"] += h["meshes"][child["mesh"]]["primitives"]
        del child["mesh"]

    path = tmp_path / "edited.glb"
    path.write_bytes(_edit_glb(scene.export(file_type="glb"), edit))
    parts = {p.name: p for p in read_parts(path).parts}
    assert sorted(parts) == ["Leaf mesh", "parent"]
    assert len(parts["parent"].faces) == 24  # two primitives, one part
    assert np.allclose(parts["parent"].vertices.mean(axis=0), [0, 5, 0])
    assert np.allclose(parts["Leaf mesh"].vertices.mean(axis=0), 0)


def test_glb_child_nodes_are_placed_by_their_parents(tmp_path):
    box = trimesh.creation.box()
    scene = trimesh.Scene()
    scene.add_geometry(box.copy(), geom_name="a", node_name="parent",
                       transform=trimesh.transformations.rotation_matrix(np.pi / 2, [0, 0, 1]))
    scene.add_geometry(box.copy(), geom_name="b", node_name="child", parent_node_name="parent",
                       transform=trimesh.transformations.translation_matrix([3, 0, 0]))
    path = tmp_path / "nested.glb"
    path.write_bytes(scene.export(file_type="glb"))
    parts = {p.name: p for p in read_parts(path).parts}
    assert np.allclose(parts["child"].vertices.mean(axis=0), [0, 3, 0])


def test_stl_is_one_nameless_part(tmp_path):
    path = tmp_path / "petal.stl"
    trimesh.creation.icosphere(1).export(path)
    mesh_file = read_parts(path)
    assert [p.name for p in mesh_file.parts] == ["part_0"]
    assert len(mesh_file.parts[0].faces) == 80 and mesh_file.up is None


@pytest.mark.parametrize("text, message", [(None, "not found"), ("v 0 0 0\n", "no triangles"),
                                           ("v 0 0 0\nv 1 0 0\nv nan 1 0\no a\nf 1 2 3\n",
                                            "non-finite")])
def test_bad_files_are_one_line_errors_naming_the_file(tmp_path, text, message):
    path = tmp_path / "bad.obj"
    if text is not None:
        path.write_text(text)
    with pytest.raises(BloomError, match=message) as err:
        read_parts(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


# --- a procedural flower ------------------------------------------------------------------

def _solidify(v, f, t):
    """Offset a sheet by +-t/2 along its vertex normals and join the rims: a closed shell."""
    n = topology.vertex_normals(v, f)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    he = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = {tuple(e) for e in he.tolist()}
    rim = np.array([e for e in he.tolist() if (e[1], e[0]) not in key])
    m = len(v)
    a, b = rim[:, 0], rim[:, 1]
    side = np.concatenate([np.stack([b, a, a + m], 1), np.stack([b, a + m, b + m], 1)])
    return np.vstack([v + 0.5 * t * n, v - 0.5 * t * n]), np.vstack([f, f[:, ::-1] + m, side])


def _mesh(m):
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def _at(m, z0, z1=None, xy=(0.0, 0.0)):
    m = m.copy()
    m.apply_translation([xy[0], xy[1], z0 if z1 is None else 0.5 * (z0 + z1)])
    return m


def flower(thick=False):
    """A bud of 6 petals with a stem, a receptacle, two leaves, 5 stamens and a pistil,
    every part with a generic name. Returns ``(parts, expected kinds)``. +z up."""
    v, f, petal = procedural.bud(6, 900, 0)
    parts, kinds = [], []
    for p in range(6):
        idx = np.flatnonzero(petal == p)
        pv, pf = v[idx], np.searchsorted(idx, f[np.isin(f[:, 0], idx)])
        if thick:
            pv, pf = _solidify(pv, pf, 0.02)
        parts.append(Part(f"Circle.{p + 1:03d}", pv, pf))
        kinds.append("thick petal" if thick else "petal")
    cyl = trimesh.creation.cylinder
    parts.append(Part("Cylinder", *_mesh(_at(cyl(0.03, 1.5, sections=16), -1.55, -0.05))))
    kinds.append("stem")
    parts.append(Part("Sphere", *_mesh(_at(trimesh.creation.icosphere(2, 0.09), -0.03))))
    kinds.append("receptacle")
    leaf, leaf_f = procedural.flat_petal(procedural.Outline(0.05, 0.3, 0.5), 0.05, np.random.default_rng(1))
    for k, azimuth in enumerate([0.3, 0.3 + np.pi]):
        out = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
        across = np.array([-np.sin(azimuth), np.cos(azimuth), 0.0])
        up = (out + np.array([0, 0, 0.6])) / np.linalg.norm(out + [0, 0, 0.6])
        lv = 0.03 * out + 0.8 * leaf[:, 1:2] * up + 0.8 * leaf[:, :1] * across + [0, 0, -1.0 + 0.2 * k]
        parts.append(Part(f"Plane.{k:03d}", lv, leaf_f))
        kinds.append("leaf")
    for k in range(5):
        a = 2 * np.pi * (k + 0.5) / 5
        xy = (0.13 * np.cos(a), 0.13 * np.sin(a))
        stamen = trimesh.util.concatenate([_at(cyl(0.006, 0.45, sections=8), 0.02, 0.47, xy),
                                           _at(trimesh.creation.icosphere(1, 0.025), 0.49, None, xy)])
        parts.append(Part(f"Cylinder.{k + 1:03d}", *_mesh(stamen)))
        kinds.append("stamen")
    pistil = trimesh.util.concatenate([_at(cyl(0.015, 0.55, sections=12), 0.0, 0.55),
                                       _at(trimesh.creation.icosphere(1, 0.03), 0.57)])
    parts.append(Part("Cylinder.006", *_mesh(pistil)))
    kinds.append("pistil")
    return parts, kinds


@pytest.fixture(scope="module")
def thin_flower():
    parts, kinds = flower()
    return parts, kinds, classify(parts)


def _kinds(verdicts):
    return [v.kind for v in verdicts]


def _wrong(parts, verdicts, kinds):
    return [(p.name, k, v) for p, v, k in zip(parts, verdicts, kinds, strict=True) if v.kind != k]


def test_every_part_of_a_generic_flower_gets_its_kind(thin_flower):
    parts, kinds, verdicts = thin_flower
    assert _kinds(verdicts) == kinds, _wrong(parts, verdicts, kinds)
    assert all(v.kind in KINDS and v.reason for v in verdicts)
    assert "one of 6 alike ringed around" in verdicts[0].reason


def test_thick_petals_are_told_from_thin_ones():
    parts, kinds = flower(thick=True)
    verdicts = classify(parts)
    assert _kinds(verdicts) == kinds, _wrong(parts, verdicts, kinds)


def test_verdicts_do_not_depend_on_units_position_or_part_order(thin_flower):
    parts, kinds, _ = thin_flower
    rotation = trimesh.transformations.rotation_matrix(1.0, [1, 2, 3])[:3, :3]
    moved = [Part(p.name, 100.0 * p.vertices @ rotation.T + [5, -7, 300], p.faces) for p in parts]
    order = np.random.default_rng(0).permutation(len(parts))
    verdicts = classify([moved[i] for i in order])
    assert _kinds(verdicts) == [kinds[i] for i in order]


def test_names_decide_where_they_are_unambiguous(thin_flower):
    parts, kinds, _ = thin_flower
    renamed = list(parts)
    renamed[0] = Part("Petal_outer", parts[0].vertices, parts[0].faces)  # shape agrees
    renamed[6] = Part("main stem", parts[6].vertices, parts[6].faces)
    renamed[8] = Part("LeafLeft", parts[-1].vertices, parts[-1].faces)  # the pistil's shape
    renamed[9] = Part("petal_or_stem", parts[9].vertices, parts[9].faces)  # ambiguous: shape
    verdicts = classify(renamed)
    assert _kinds(verdicts)[0] == "petal" and "named 'Petal_outer'" in verdicts[0].reason
    assert verdicts[6].kind == "stem" and verdicts[8].kind == "leaf" and verdicts[9].kind == "leaf"


def test_globs_override_the_verdict_both_ways(thin_flower):
    parts, kinds, verdicts = thin_flower
    names = [p.name for p in parts]
    chosen = select(names, verdicts)
    assert chosen == [k == "petal" for k in kinds]
    chosen = select(names, verdicts, petals_globs=["Plane.*"], exclude_globs=["Circle.00[12]"])
    assert [n for n, c in zip(names, chosen, strict=True) if c] == [
        "Circle.003", "Circle.004", "Circle.005", "Circle.006", "Plane.000", "Plane.001"]
    # exclude wins over petals
    assert not any(select(names, verdicts, petals_globs=["*"], exclude_globs=["*"]))


def test_a_lone_sheet_is_a_petal_and_a_lone_ball_is_not():
    v, f = procedural.flat_petal(procedural.Outline(), 0.05, np.random.default_rng(0))
    sheet = Part("part_0", np.c_[v, 0.05 * v[:, 0] ** 2], f)
    ball = Part("part_0", *_mesh(trimesh.creation.icosphere(2)))
    assert classify([sheet])[0].kind == "petal"
    assert classify([ball])[0].kind == "other"


# --- config -------------------------------------------------------------------------------

def test_scene_petals_and_exclude_are_lists_of_globs(tmp_path):
    cfg = load_config()
    assert cfg["scene.petals"] == [] and cfg["scene.exclude"] == []
    path = tmp_path / "scene.toml"
    path.write_text('[scene]\npetals = ["Circle.0*", "petal_?"]\nexclude = []\n')
    assert load_config(path)["scene.petals"] == ["Circle.0*", "petal_?"]
    assert load_config(None, ['scene.exclude=["Sphere*"]'])["scene.exclude"] == ["Sphere*"]
    for bad, what in [('petals = "Circle*"', "expected a list of strings"),
                      ("petals = [1, 2]", "expected a list of strings, got 1 in it")]:
        path.write_text(f"[scene]\n{bad}\n")
        with pytest.raises(BloomError, match=f"scene.petals: {what}"):
            load_config(path)


# --- real models by other people ----------------------------------------------------------

def _external(name):
    path = EXTERNAL / name
    if not path.exists():
        pytest.skip(f"{path} not present")
    parts = read_parts(path).parts
    return {p.name: v for p, v in zip(parts, classify(parts), strict=True)}


def test_lily_petals_are_thick_petals_and_its_stamens_are_not_petals():
    verdicts = _external("bulat66_lily.glb")
    assert len(verdicts) == 18
    # Circle.003 holds the six solidified petals; Circle.004-010 are the filaments that
    # carry the Sphere anthers; Circle is the stem, Circle.002 the pistil, Circle.001 the
    # spiky cup at the base (seen in renders of the file)
    assert verdicts["Circle.003"].kind == "thick petal"
    assert [n for n, v in verdicts.items() if v.is_petal] == ["Circle.003"]
    assert all(verdicts[f"Circle.{k:03d}"].kind == "stamen" for k in range(4, 11))
    assert all(v.kind == "stamen" for n, v in verdicts.items() if n.startswith("Sphere"))
    assert verdicts["Circle"].kind == "stem" and verdicts["Circle.002"].kind == "pistil"
    assert verdicts["Circle.001"].kind == "sepal"


@pytest.mark.parametrize("name, count", [("hallgeirl_petals.obj", 14), ("ssajeev_daisy.obj", 11)])
def test_closed_tube_and_box_petals_are_thick_petals(name, count):
    verdicts = _external(name)
    assert len(verdicts) == count
    assert {v.kind for v in verdicts.values()} == {"thick petal"}
    assert all(f"one of {count} alike ringed" in v.reason for v in verdicts.values())


def test_five_open_petals_in_one_group_are_petals():
    verdicts = _external("chianti_flower5.obj")
    assert list(verdicts) == ["pPlane18"]
    assert verdicts["pPlane18"].kind == "petal"
    assert "5 pieces" in verdicts["pPlane18"].reason and "one of 5 alike" in verdicts["pPlane18"].reason


def _low_poly_blossom(size: float = 0.005, seed: int = 3, axis=(0.3, -0.2, 1.0),
                      centre=(0.1, 0.2, 0.3)):
    """A blossom as a branch's low-poly asset writes it: five kite petals of 4 vertices
    (2 triangles) leaning out of a flat hexagon disc whose rim they pass through, all in
    one mesh, in metres."""
    rng = np.random.default_rng(seed)
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    u = np.cross(axis, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(axis, u)
    centre = np.asarray(centre, dtype=np.float64)
    verts = [centre] + [centre + 0.25 * size * (np.cos(a) * u + np.sin(a) * w) + 0.02 * size * axis
                        for a in np.arange(6) * np.pi / 3]
    faces = [[0, 1 + k, 1 + (k + 1) % 6] for k in range(6)]
    lean = np.radians(60.0)
    for p in range(5):
        az = 2 * np.pi * p / 5 + rng.normal(0, 0.05)
        radial = np.cos(az) * u + np.sin(az) * w
        side = np.cross(axis, radial)
        out = np.sin(lean) * radial + np.cos(lean) * axis
        base = centre + 0.2 * size * radial
        mid = base + 0.5 * size * out
        k = len(verts)
        verts += [base, mid + 0.22 * size * side, base + size * out, mid - 0.22 * size * side]
        faces += [[k, k + 1, k + 2], [k, k + 2, k + 3]]
    return np.array(verts, dtype=np.float32).astype(np.float64), np.array(faces)  # (a glb's)


def test_a_low_poly_blossom_gives_its_five_kites_and_keeps_its_disc():
    """Its disc is the blossom's centre (a flat round sheet facing along the axis), not a
    petal nor a sepal, and is kept; each kite is a petal (its surface's principal axes,
    not its two face centres', give its length), cut along its center plane and mirrored
    (the side corners, its widest points, are not snapped onto the plane: that left a
    line and the petal was lost), along its length though a rhombus is symmetric across
    it too (float32 rounding chose either)."""
    from pipeline.flower.petals import prepare_parts

    for seed in range(12):
        v, f = _low_poly_blossom(seed=seed)
        for k in range(7, 27, 4):
            plane, _ = symmetry.mirror_plane(v[k:k + 4])
            along = v[k + 2] - v[k]  # base to tip
            assert abs(plane[:3] @ along) < 1e-3 * np.linalg.norm(along), (seed, k)

    v, f = _low_poly_blossom()
    verdict = classify([Part("Blossom", v, f)])[0]
    assert verdict.kind == "petal" and verdict.faces is not None
    assert "5 petals" in verdict.reason and "1 receptacle" in verdict.reason, verdict.reason
    assert int(verdict.faces.sum()) == 10  # the kites' two triangles each
    result = prepare_parts(MeshFile([Part("Blossom", v, f)], None, None), where="blossom")
    assert int(result.petal.max()) + 1 == 5
    assert not any("left out" in n for n in result.notes), result.notes
    assert result.unsymmetrized == []
    assert np.all(np.bincount(result.petal) > 30)  # remeshed up from 4 vertices
    # each rhombus is mirror-symmetric both ways: its center plane is along its length
    # (through the disc's centre, the normal across the petal), not across it
    for k in range(5):
        mine = result.vertices[result.petal == k]
        centre = mine.mean(axis=0)
        along = mine[np.argmax(np.linalg.norm(mine - centre, axis=1))] - centre
        assert abs(result.plane[k][:3] @ along) < 0.2 * np.linalg.norm(along), k


def _turned(v, axis, centre, degrees):
    """``v`` turned about the line through ``centre`` along ``axis``."""
    from scipy.spatial.transform import Rotation

    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    turn = Rotation.from_rotvec(np.radians(degrees) * axis)
    return turn.apply(v - np.asarray(centre)) + np.asarray(centre)


def test_blossoms_a_few_tenths_of_a_petal_apart_stay_a_flower_each():
    """A branch's blossoms, each one mesh of kites and a disc, whose bases lie closer than
    the flowers' link (0.4 petal lengths): each part whose own pieces ring an axis is a
    flower of its own, its disc a receptacle; grouped by their bases alone, two blossoms
    made one ring of ten and their discs were taken for petals. Two parts that ring one
    axis (a flower's whorls in two meshes) stay one flower."""
    from pipeline.flower.petals import prepare_parts

    size = 0.005
    axes = [(0.3, -0.2, 1.0), (-0.4, 0.3, 1.0), (0.1, 0.5, 1.0)]
    parts = [Part(f"Blossom.{k:03d}",
                  *_low_poly_blossom(size, seed=k, axis=axes[k],
                                     centre=(0.1 + 0.4 * size * k, 0.2, 0.3)))
             for k in range(3)]
    verdicts = classify(parts)
    for p, verdict in zip(parts, verdicts, strict=True):
        assert verdict.kind == "petal" and verdict.faces is not None, (p.name, verdict.reason)
        assert "5 petals" in verdict.reason and "1 receptacle" in verdict.reason, verdict.reason
    assert sorted(v.whole for v in verdicts) == [0, 1, 2]
    result = prepare_parts(MeshFile(parts, None, None), where="branch")
    assert int(result.petal.max()) + 1 == 15
    assert np.array_equal(np.bincount(result.petal_flower), [5, 5, 5])

    # an outer whorl and an inner one, each its own mesh, around one axis: one flower
    v, f = _low_poly_blossom(size, seed=1)
    inner = _turned(v, (0.3, -0.2, 1.0), (0.1, 0.2, 0.3), 36.0)
    whorls = [Part("Outer", v, f), Part("Inner", inner[7:], f[6:] - 7)]
    verdicts = classify(whorls)
    assert [v.kind for v in verdicts] == ["petal", "petal"], [v.reason for v in verdicts]
    assert verdicts[0].whole == verdicts[1].whole == 0
    result = prepare_parts(MeshFile(whorls, None, None), where="whorls")
    assert int(result.petal.max()) + 1 == 10
    assert np.array_equal(result.petal_flower, np.zeros(10, dtype=np.int64))
