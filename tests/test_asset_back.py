"""The user's asset back (issue 15): the input's own parts, bound to the simulated sheet,
deformed by its frames and exported with their names, polygons, UVs, normals and
materials; the growth schedule keyed in frames."""

from pathlib import Path

import h5py
import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from pipeline.io import binding, export, userasset
from pipeline.sim.model import Control
from stages.cli import cli

SHARED = Path(__file__).resolve().parents[2] / "shared" / "external-meshes"
KEYS = "growth.keys=[[0, 0], [2, 0], [6, 1]]"  # hold the bud 2 frames, open over 4, hold
SHORT = ["--set", "simulate.steps=2000", "--set", "simulate.frames=9", "--set", KEYS,
         "--set", "growth.start=bud"]  # (frame 0 is the input: a bud that opens)


def invoke(*args):
    r = CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    return r


def run_chain(mesh: Path, d: Path, *extra) -> Path:
    prev = None
    for stage in ("remesh", "axis", "growth", "simulate"):
        out = d / f"{stage}.h5"
        args = [stage, mesh] if prev is None else [stage, prev]
        invoke(*args, "--out", out, *SHORT, *extra)
        prev = out
    return prev


def solid_petal(n_u=16, n_v=9, length=0.04, width=0.016, thickness=0.0015):
    """A cupped petal solidified (two sides and a rim strip: closed), with UVs: each
    side's grid in its own half of the UV square."""
    u, v = np.meshgrid(np.linspace(0, 1, n_u), np.linspace(-1, 1, n_v), indexing="ij")
    half = 0.5 * width * (0.25 + 0.75 * np.sin(np.pi * np.clip(u, 0, 0.85)))
    mid = np.stack([v * half, u * length, (v * half) ** 2 / width + 0.1 * length * u ** 2],
                   -1).reshape(-1, 3)
    quads = np.array([(i * n_v + j, (i + 1) * n_v + j, (i + 1) * n_v + j + 1, i * n_v + j + 1)
                      for i in range(n_u - 1) for j in range(n_v - 1)])
    tri = np.vstack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    n = trimesh.Trimesh(mid, tri, process=False).vertex_normals
    nv = len(mid)
    loop = ([i * n_v for i in range(n_u)] + [(n_u - 1) * n_v + j for j in range(1, n_v)]
            + [i * n_v + n_v - 1 for i in range(n_u - 2, -1, -1)] + list(range(n_v - 2, 0, -1)))
    rim = [f for a, b in zip(loop, loop[1:] + loop[:1], strict=True)
           for f in ((a, b + nv, b), (a, a + nv, b + nv))]
    vertices = np.vstack([mid + 0.5 * thickness * n, mid - 0.5 * thickness * n])
    faces = np.vstack([tri, tri[:, ::-1] + nv, rim])
    grid = np.c_[(v.ravel() + 1) / 4, u.ravel()]
    return vertices, faces, np.vstack([grid, grid + [0.5, 0.0]])


@pytest.fixture(scope="module")
def gltf_chain(tmp_path_factory):
    """A glTF flower (Y-up, metres): a solidified petal with UVs and a material, and a
    stem, taken through the chain with a keyed schedule and exported to USD."""
    d = tmp_path_factory.mktemp("gltf")
    v, f, uv = solid_petal()
    petal = trimesh.Trimesh(v, f, process=False, visual=trimesh.visual.TextureVisuals(
        uv=uv, material=trimesh.visual.material.PBRMaterial(name="Petal.Mat")))
    stem = trimesh.creation.cylinder(radius=0.002, height=0.03, sections=12)
    stem.apply_translation([0, -0.015, 0])
    stem.visual = trimesh.visual.TextureVisuals(
        uv=np.c_[np.linspace(0, 1, len(stem.vertices)), np.zeros(len(stem.vertices))],
        material=trimesh.visual.material.PBRMaterial(name="StemMat"))
    scene = trimesh.Scene()
    scene.add_geometry(petal, node_name="Petal.001", geom_name="PetalMesh")
    scene.add_geometry(stem, node_name="Stem", geom_name="StemMesh")
    mesh = d / "flower.glb"
    mesh.write_bytes(scene.export(file_type="glb"))
    sim = run_chain(mesh, d)
    usd = d / "bloom.usda"
    invoke("export", sim, "--out", usd)
    return {"mesh": mesh, "sim": sim, "usd": usd, "dir": d}


def test_the_gltf_comes_back_as_its_own_parts(gltf_chain):
    """Names (valid prim names), vertex and face counts and order, UVs per vertex (as
    glTF has them), materials as GeomSubsets, metres and Y up, frame numbers as time
    codes; frame 0 is the input, the petal moves, the stem stays."""
    from pxr import Usd, UsdGeom, UsdShade

    asset = userasset.read_asset(gltf_chain["mesh"])
    stage = Usd.Stage.Open(str(gltf_chain["usd"]))
    assert UsdGeom.GetStageUpAxis(stage) == "Y" and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, 8)
    meshes = [p for p in stage.GetPrimAtPath("/Bloom").GetChildren() if p.IsA(UsdGeom.Mesh)]
    assert [p.GetName() for p in meshes] == ["Petal_001", "Stem"]
    assert [p.GetDisplayName() for p in meshes] == ["Petal.001", "Stem"]
    for prim, part in zip(meshes, asset.parts, strict=True):
        mesh = UsdGeom.Mesh(prim)
        assert np.array_equal(mesh.GetFaceVertexIndicesAttr().Get(), part.face_indices)
        assert np.array_equal(mesh.GetFaceVertexCountsAttr().Get(), part.face_counts)
        st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
        assert st.GetInterpolation() == "vertex"
        np.testing.assert_allclose(np.asarray(st.Get()), part.uv, atol=1e-7)
        np.testing.assert_allclose(np.asarray(mesh.GetPointsAttr().Get(0)), part.points,
                                   atol=1e-6 * np.abs(part.points).max())
        (subset,) = UsdGeom.Subset.GetAllGeomSubsets(mesh)
        assert len(subset.GetIndicesAttr().Get()) == len(part.face_counts)
        bound, _ = UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()
        assert bound.GetPrim().GetDisplayName() == part.materials[0]
    petal, stem = (UsdGeom.Mesh(p).GetPointsAttr() for p in meshes)
    assert not np.allclose(np.asarray(petal.Get(8)), np.asarray(petal.Get(0)), atol=1e-4)
    assert stem.GetNumTimeSamples() == 0  # in place, static
    normals = np.asarray(UsdGeom.Mesh(meshes[0]).GetNormalsAttr().Get(8))
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)


def test_export_shows_how_far_it_has_got_part_by_part(gltf_chain, monkeypatch, tmp_path):
    """Under make (no terminal) `bloom export` logs how far it has got, naming the part
    (a branch of a thousand blossoms took minutes, silent): binding, turning and writing
    each part is a third of its share; the USD is the same to the bit."""
    from pipeline import progress

    monkeypatch.setattr(progress, "EVERY", 0.0)  # (a line at every tenth, however quick)
    usd = tmp_path / "again.usda"
    r = invoke("export", gltf_chain["sim"], "--out", usd)
    lines = [line for line in r.output.splitlines() if line.startswith("export: ")]
    assert lines and lines[-1].startswith("export: 100% done"), r.output
    assert all("(part '" in line for line in lines)
    assert {"Petal.001", "Stem"} <= {line.split("(part '")[1].rstrip("')") for line in lines}
    assert usd.read_text() == gltf_chain["usd"].read_text()


def test_a_thick_petal_keeps_its_thickness_and_does_not_pop(gltf_chain):
    """Through every frame, the solidified petal's thickness (each point's distance to
    the other side) stays within 5% of the input's, and no bound point moves further
    between two frames than the sheet's fastest vertex does (plus a tenth)."""
    with h5py.File(gltf_chain["sim"]) as f:
        asset, bindings = userasset.read(f), binding.read_bindings(f)
        sheet, faces, scale = f["frames/positions"][()], f["mesh/faces"][()], f.attrs["scale"]
    assert list(bindings) == [0]  # the petal; the stem is not bound
    frames = export.asset_frames(sheet, faces, asset, bindings, scale)
    part, b = asset.parts[0], bindings[0]
    assert frames[0].shape == (len(sheet), len(part.points), 3)
    np.testing.assert_allclose(frames[0][0], part.points, rtol=0, atol=1e-12)
    which = binding.two_sided(part.points, part.triangles(), b, sheet[0] / scale, faces, scale)
    rest = binding.thickness(part.points, part.triangles(), b.offset[:, 2], which)
    assert len(rest) > 50 and np.allclose(np.median(rest), 0.0015, rtol=0.05)
    worst = max(np.abs(binding.thickness(P, part.triangles(), b.offset[:, 2], which) / rest - 1).max()
                for P in frames[0])
    assert worst < 0.05, worst
    jump = np.linalg.norm(np.diff(frames[0], axis=0), axis=2).max()
    sheet_jump = np.linalg.norm(np.diff(sheet / scale, axis=0), axis=2).max()
    assert sheet_jump > 1e-3 and jump <= 1.1 * sheet_jump, (jump, sheet_jump)


def test_the_keyed_schedule_holds_opens_and_holds_to_the_frame(gltf_chain):
    with h5py.File(gltf_chain["sim"]) as f:
        growth, frame = f["diagnostics/growth"][()], f["frames/frame"][()]
        positions = f["frames/positions"][()]
    assert np.array_equal(frame, np.arange(9))
    assert np.all(growth[:3] == 0.0) and np.all(growth[6:] == 1.0)
    assert np.all(np.diff(growth[2:7]) > 0)
    np.testing.assert_array_equal(positions[1], positions[0])  # the bud holds, to the bit
    assert np.abs(positions[3] - positions[2]).max() > 0  # and opens after frame 2


def test_control_keyed_is_smooth_monotone_and_exact_at_the_keys():
    keys = [[0, 0.0], [24, 0.0], [72, 1.0], [120, 1.0]]  # hold, open over 48 frames, hold
    c = Control.keyed(keys, frames=121, steps=1200, h=0.5)
    at = [c.growth_at(f * 5.0) for f in range(121)]  # frame f is step 10 f, time 5 f
    assert at[:25] == [0.0] * 25 and at[72:] == [1.0] * 49
    assert np.all(np.diff(c.table) >= 0) and np.all(np.diff(at[24:73]) > 0)
    assert at[48] == pytest.approx(0.5)
    # smooth: no step of the table jumps by more than the keyed slope allows (C1, no kick)
    assert np.abs(np.diff(c.table, 2)).max() < 1e-4
    assert c.growth_at(52.5) == pytest.approx(0.5 * (c.table[105] + c.table[106]))


def test_growth_keys_are_checked(tmp_path):
    from pipeline.config import load_config
    from pipeline.errors import BloomError

    for bad, words in (("[[0, 0], [10, 1], [5, 1]]", "must increase"),
                       ("[[0, 0.5], [10, 0.2]]", "falls"), ("[[0, 2]]", "outside [0, 1]"),
                       ("[[0]]", "[frame, A]"), ("[[0, 0], [500, 1]]", "past the last frame"),
                       ('["a"]', "[frame, A] pairs")):
        with pytest.raises(BloomError, match="growth.keys") as exc:
            load_config(None, [f"growth.keys={bad}"])
        assert words in str(exc.value)


def maya_obj(path: Path) -> None:
    """A Maya-style OBJ (centimetres, g names, usemtl, UV seams): a cupped quad petal
    in two materials, and a stem."""
    n_u, n_v = 9, 7
    u, v = np.meshgrid(np.linspace(0, 1, n_u), np.linspace(-1, 1, n_v), indexing="ij")
    half = 0.9 * (0.3 + 0.7 * np.sin(np.pi * np.clip(u, 0, 0.8)))
    pts = np.stack([v * half, 0.3 * (v * half) ** 2 + 0.5 * u ** 2, 4.0 * u], -1).reshape(-1, 3)
    lines = ["# This file uses centimeters as units for non-parametric coordinates.",
             "mtllib flower.mtl", "g default"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in pts]
    # UVs: a seam down the middle (the two halves have their own vt rows)
    uv = [(j / (n_v - 1), i / (n_u - 1)) for i in range(n_u) for j in range(n_v)]
    lines += [f"vt {a:.6f} {b:.6f}" for a, b in uv] + [f"vt {a + 1:.6f} {b:.6f}" for a, b in uv]
    lines.append("g petal")
    for half_k, mat in ((0, "petalPink"), (1, "petalWhite")):
        lines.append(f"usemtl {mat}")
        for i in range(n_u - 1):
            for j in range(half_k * 3, half_k * 3 + 3):
                q = [i * n_v + j, (i + 1) * n_v + j, (i + 1) * n_v + j + 1, i * n_v + j + 1]
                lines.append("f " + " ".join(f"{k + 1}/{k + 1 + half_k * len(uv)}" for k in q))
    base = len(pts)
    ring = [(np.cos(a) * 0.1, np.sin(a) * 0.1) for a in np.linspace(0, 2 * np.pi, 6, endpoint=False)]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for z in (-2.0, 0.0) for x, y in ring]
    lines += ["g stem", "usemtl stemGreen"]
    for k in range(6):
        a, b = base + k + 1, base + (k + 1) % 6 + 1
        lines.append(f"f {a} {b} {b + 6} {a + 6}")
    path.write_text("\n".join(lines) + "\n")


def test_a_maya_obj_comes_back_with_its_quads_uv_seams_materials_and_units(tmp_path):
    from pxr import Usd, UsdGeom, UsdShade

    mesh = tmp_path / "flower.obj"
    maya_obj(mesh)
    sim = run_chain(mesh, tmp_path, "--set", 'scene.petals=["petal"]')
    usd = tmp_path / "bloom.usdc"
    invoke("export", sim, "--out", usd)
    asset = userasset.read_asset(mesh)
    assert asset.names == ["petal", "stem"] and asset.meters_per_unit == 0.01
    stage = Usd.Stage.Open(str(usd))
    assert UsdGeom.GetStageMetersPerUnit(stage) == 0.01
    petal = UsdGeom.Mesh(stage.GetPrimAtPath("/Bloom/petal"))
    part = asset.parts[0]
    assert list(petal.GetFaceVertexCountsAttr().Get()) == [4] * 48  # quads kept
    assert len(petal.GetPointsAttr().Get(0)) == 63
    st = UsdGeom.PrimvarsAPI(petal).GetPrimvar("st")
    assert st.GetInterpolation() == "faceVarying"
    np.testing.assert_array_equal(np.asarray(st.GetIndices()), part.uv_indices)
    np.testing.assert_allclose(np.asarray(st.ComputeFlattened()), part.uv[part.uv_indices], atol=1e-6)
    subsets = {s.GetPrim().GetName(): len(s.GetIndicesAttr().Get())
               for s in UsdGeom.Subset.GetAllGeomSubsets(petal)}
    assert subsets == {"petalPink": 24, "petalWhite": 24}
    assert UsdShade.MaterialBindingAPI(petal).GetMaterialBindSubsetsFamilyType() == "partition"
    # the OBJ sequence keeps names, UVs and polygons: read back like the input
    seq = tmp_path / "obj"
    invoke("export", sim, "--format", "obj", "--out", seq)
    files = sorted(seq.glob("bloom_*.obj"))
    assert [f.name for f in files[:2]] == ["bloom_0000.obj", "bloom_0001.obj"] and len(files) == 9
    back = userasset.read_asset(files[-1])
    assert back.names == asset.names
    for got, want in zip(back.parts, asset.parts, strict=True):
        assert np.array_equal(got.face_counts, want.face_counts)
        assert np.array_equal(got.face_indices, want.face_indices)
        assert (got.uv is None) == (want.uv is None)
        if want.uv is not None:
            np.testing.assert_allclose(got.uv[got.uv_indices], want.uv[want.uv_indices], atol=1e-6)
        assert got.materials == want.materials
    last = np.asarray(petal.GetPointsAttr().Get(8))
    np.testing.assert_allclose(back.parts[0].points, last, atol=1e-5)
    np.testing.assert_allclose(back.parts[1].points, asset.parts[1].points, atol=1e-6)


# --- the binding, on cases worked out by hand ---------------------------------------------------

def test_binding_a_point_above_a_triangle_and_past_its_edge():
    V = np.array([[0.0, 0, 0], [2, 0, 0], [0, 2, 0]])
    F = np.array([[0, 1, 2]])
    P = np.array([[0.5, 0.5, 0.3], [1.5, -1.0, -0.2]])
    b = binding.bind(P, V, F)
    np.testing.assert_allclose(b.bary[0], [0.5, 0.25, 0.25])
    np.testing.assert_allclose(b.offset[0], [0, 0, 0.3], atol=1e-15)
    np.testing.assert_allclose(b.bary[1], [0.25, 0.75, 0.0])  # clamped to edge 0-1
    np.testing.assert_allclose(b.offset[1], [0, -1.0, -0.2], atol=1e-15)  # t2 = n x t1 = +y
    np.testing.assert_allclose(binding.deform(V, F, b), P, atol=1e-15)


def test_a_rigid_motion_of_the_sheet_moves_the_bound_points_rigidly():
    rng = np.random.default_rng(1)
    x, y = np.meshgrid(np.linspace(0, 3, 7), np.linspace(0, 2, 5))
    V = np.c_[x.ravel(), y.ravel(), 0.1 * x.ravel() ** 2]
    F = np.array([(i * 7 + j, i * 7 + j + 1, (i + 1) * 7 + j + 1) for i in range(4) for j in range(6)]
                 + [(i * 7 + j, (i + 1) * 7 + j + 1, (i + 1) * 7 + j) for i in range(4) for j in range(6)])
    P = rng.uniform([-0.5, -0.5, -0.3], [3.5, 2.5, 1.2], (200, 3))
    b = binding.bind(P, V, F)
    angle = 0.7
    R = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    t = np.array([0.3, -2.0, 5.0])
    np.testing.assert_allclose(binding.deform(V @ R.T + t, F, b), P @ R.T + t, atol=1e-12)
    # the same points bound to the same sheet with its faces in another order land the same
    order = rng.permutation(len(F))
    b2 = binding.bind(P, V, F[order])
    np.testing.assert_allclose(binding.deform(V @ R.T + t, F[order], b2), P @ R.T + t, atol=1e-12)


def _grid(nx, ny, z=0.0, x0=0.0):
    x, y = np.meshgrid(x0 + np.arange(nx, dtype=float), np.arange(ny, dtype=float), indexing="ij")
    V = np.c_[x.ravel(), y.ravel(), np.full(x.size, z)]
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return V, np.concatenate([np.c_[a, b, c], np.c_[a, c, d]])


def _part(points, triangles):
    return userasset.AssetPart("p", np.asarray(points, float), np.full(len(triangles), 3),
                               np.asarray(triangles).ravel())


def test_a_petal_stays_bound_to_its_own_sheet_where_petals_overlap():
    """Two petals of one input part overlap 0.4 apart; petal 0 has a bump 0.3 high, its
    points closer to petal 1's sheet than to its own. Each input piece is bound to the
    sheet petal most of it lies on: petal 1's rising does not take the bump with it."""
    va, fa = _grid(6, 4)
    vb, fb = _grid(4, 4, 0.4, x0=3.0)
    sheet = np.concatenate([va, vb])
    sheet_faces = np.concatenate([fa, fb + len(va)])
    points = np.concatenate([va, vb])
    bump = np.flatnonzero((va[:, 0] == 4.0) & (va[:, 1] >= 1.0) & (va[:, 1] <= 2.0))
    points[bump, 2] = 0.3
    asset = userasset.Asset([_part(points, sheet_faces)], None, None)
    b = binding.bind_parts(asset, 1.0, sheet, sheet_faces, np.zeros(len(sheet), dtype=int))[0]
    assert np.all(b.face[bump] < len(fa))  # petal 0's triangles (a plain bind takes petal 1's)
    assert np.all(binding.bind(points, sheet, sheet_faces).face[bump] >= len(fa))
    raised = sheet.copy()
    raised[len(va):, 2] += 5.0  # petal 1 moves away
    np.testing.assert_allclose(binding.deform(raised, sheet_faces, b)[bump], points[bump],
                               atol=1e-12)


def test_the_hub_of_a_flower_modelled_in_one_piece_stays_with_the_hub():
    """Two petal sheets (a grid each, their bases the rows nearest the centre) and points
    of one input part: on a sheet, past a tip, just past a base, and a hub point at the
    centre, behind a base and far off the sheet's rim. Only the hub point stays
    (hold_hub); turning the sheets about their bases moves every other one with them."""
    a, fa = _grid(9, 5)  # petal 0: x in [2, 6], y in [-1, 1], edges of 0.5, base at x = 2
    a = a * 0.5 + np.array([2.0, -1.0, 0.0])
    b = a * np.array([-1.0, 1.0, 1.0])  # petal 1: its mirror image, base at x = -2
    V = np.vstack([a, b])
    F = np.vstack([fa, fa[:, ::-1] + len(a)])  # (petal 1 mirrored: wound back)
    petal = np.repeat([0, 1], len(a))
    base = np.isclose(np.abs(V[:, 0]), 2.0)
    P = np.array([[3.5, 0.2, 0.1],   # on petal 0
                  [6.4, 0.0, 0.0],   # past petal 0's tip
                  [1.7, 0.0, 0.0],   # just past its base (0.3: under two edges)
                  [0.1, 0.0, 0.0],   # the hub, 1.9 off petal 0's base rim
                  [-3.0, 0.5, -0.1]])  # on petal 1
    bindings = {0: binding.bind(P, V, F)}
    held = binding.hold_hub(bindings, V, F, petal, base)
    assert held == {0: 1}
    bnd = bindings[0]
    assert bnd.face.tolist()[3] == -1 and np.all(np.delete(bnd.face, 3) >= 0)
    rest = binding.deform(V, F, bnd)
    np.testing.assert_allclose(rest, P, atol=1e-12)  # exact at rest
    X = V.copy()  # each petal turned 30 deg up about its base
    for side in (1.0, -1.0):
        mine = np.sign(V[:, 0]) == side
        r = np.abs(V[mine, 0]) - 2.0
        X[mine, 0] = side * (2.0 + r * np.cos(np.radians(30)))
        X[mine, 2] = r * np.sin(np.radians(30))
    moved = binding.deform(X, F, bnd)
    np.testing.assert_array_equal(moved[3], rest[3])  # the hub stays
    assert np.all(np.linalg.norm(moved[[0, 1, 4]] - P[[0, 1, 4]], axis=1) > 0.1)
    # a petal with no fixed base has none behind it; thick petals are measured in their
    # thickness: 1.9 off is under two thicknesses of 1
    loose = {0: binding.bind(P, V, F)}
    assert binding.hold_hub(loose, V, F, petal, np.zeros(len(V), dtype=bool)) == {}
    thick = {0: binding.bind(P, V, F)}
    assert binding.hold_hub(thick, V, F, petal, base, np.ones(len(V))) == {}


def test_a_leaf_modelled_in_the_petals_part_stays_where_it_is():
    """One input part holds a petal and, beside it, a leaf (a tulip's leaves and stem are
    in its petals' mesh). Remesh keeps the leaf as a piece that is no petal; bound to the
    nearest petal it followed the petal through the bloom (the tulip's leaves crumpled in
    its render). Its points stay (face -1), exactly, in every frame; the petal's follow
    the sheet; the render draws the leaf as a leaf, not framed; the report's vote of the
    part's petal counts the petal's points only."""
    from pipeline.review import render
    from pipeline.review.report import petal_names

    va, fa = _grid(6, 4)
    leaf, leaf_f = _grid(3, 3, 0.5, x0=7.0)
    points = np.concatenate([va, leaf])
    asset = userasset.Asset([_part(points, np.concatenate([fa, leaf_f + len(va)]))], None, None)
    kept = {0: (points.copy(), leaf_f + len(va))}  # (remesh keeps the part's vertex array)
    b = binding.bind_parts(asset, 2.0, 2.0 * va, fa, np.zeros(len(va), dtype=int), kept)[0]
    stays = b.face < 0
    assert np.array_equal(stays, np.r_[np.zeros(len(va), bool), np.ones(len(leaf), bool)])
    bent = 2.0 * va.copy()
    bent[:, 2] += 0.3 * bent[:, 0] ** 2  # the petal bends up
    moved = binding.deform(bent, fa, b) / 2.0
    assert np.array_equal(moved[stays], points[stays])
    np.testing.assert_allclose(moved[~stays], bent / 2.0, atol=1e-12)
    frames = binding.local_frames(bent, fa, b.face, b.bary)
    assert np.array_equal(frames[stays], np.broadcast_to(np.eye(3), (len(leaf), 3, 3)))
    # (without kept the leaf is bound to the petal and rises with it)
    plain = binding.bind_parts(asset, 2.0, 2.0 * va, fa, np.zeros(len(va), dtype=int))[0]
    assert np.all(plain.face >= 0)
    assert np.abs(binding.deform(bent, fa, plain)[stays] / 2.0 - points[stays]).max() > 1.0
    layers = render.asset_layers([np.stack([points, moved])], asset, {0: b}, fa,
                                 np.zeros(len(va), dtype=int), color="#ffc0cb", palette="petals")
    assert [len(layer.faces) for layer in layers] == [len(leaf_f), len(fa)]
    assert not layers[0].framed and layers[1].framed
    assert petal_names(np.zeros(len(va), dtype=int), bindings={0: b}, faces=fa,
                       asset_names=["flower"]) == ["petal 0 (flower)"]


def test_only_a_part_with_two_sides_has_a_thickness_to_measure():
    """A one-sided sheet whose points stray off it by up to a tenth of an edge (a
    remeshed surface) has no thickness; the same sheet solidified (two sides 0.2 apart)
    is measured at the points inside it, each 0.2."""
    rng = np.random.default_rng(0)
    sheet, faces = _grid(8, 8)
    wavy = sheet + np.c_[np.zeros((len(sheet), 2)), rng.uniform(-0.1, 0.1, len(sheet))]
    b = binding.bind(wavy, sheet, faces)
    assert len(binding.two_sided(wavy, faces, b, sheet, faces, 1.0)) == 0
    shift = np.array([0.3, 0.2, 0.0])  # (so that its points lie inside sheet triangles)
    top, bottom = sheet + shift + [0, 0, 0.1], sheet + shift - [0, 0, 0.1]
    solid = np.concatenate([top, bottom])
    solid_faces = np.concatenate([faces, faces[:, ::-1] + len(sheet)])
    b = binding.bind(solid, sheet, faces)
    which = binding.two_sided(solid, solid_faces, b, sheet, faces, 1.0)
    assert len(which) == 49 and np.all(which < len(sheet))  # the top's 7 x 7 over the sheet
    np.testing.assert_allclose(binding.thickness(solid, solid_faces, b.offset[:, 2], which), 0.2)


def _bent(sheet, angle):
    """The flat sheet (along x from 0) rolled about the y axis through ``angle`` over its
    length."""
    if angle == 0.0:
        return sheet.copy()
    R = sheet[:, 0].max() / angle
    return np.c_[R * np.sin(sheet[:, 0] / R), sheet[:, 1], R * (1 - np.cos(sheet[:, 0] / R))]


def test_a_coarse_thick_petal_bent_keeps_its_thickness():
    """A slab 0.2 thick whose two sides were modelled apart (faces 0.9 long, 4.5x the
    thickness, one side's vertices over the middle of the other's faces), bound to a fine
    sheet that rolls through 2 rad. Through the binding alone each side's flat faces cut
    chords across the bend: the other side's points come over 20% closer to them. With
    keep_thickness every measured point is within 5% of its rest distance at every
    angle (the sides' flat faces cannot all be exactly 0.2 apart: the rest is a
    least-squares compromise), no point jumps between two angles more than 1.5x the
    binding alone, and the rest pose is given back."""
    sheet, faces = _grid(41, 9)
    sheet *= 0.1
    top, top_tris = _grid(5, 3)
    bottom, bottom_tris = _grid(4, 3)
    points = np.concatenate([top * [0.9, 0.3, 0.0] + [0.23, 0.16, 0.1],  # (inside sheet
                             bottom * [0.9, 0.3, 0.0] + [0.68, 0.16, -0.1]])  # triangles)
    triangles = np.concatenate([top_tris, bottom_tris[:, ::-1] + len(top)])
    b = binding.bind(points, sheet, faces)
    s = binding.sides(points, triangles, b, sheet, faces, 1.0)
    which = binding.two_sided(points, triangles, b, sheet, faces, 1.0)
    # the top's 3 x 3 inner points (its end columns lie past the bottom), all the bottom's
    assert len(which) == 9 and len(s.point) == 21 and np.sum(~s.positive) == 12
    rest = binding.thickness(points, triangles, b.offset[:, 2], which)
    np.testing.assert_allclose(rest, 0.2, rtol=1e-12)
    np.testing.assert_allclose(binding.keep_thickness(binding.deform(sheet, faces, b), triangles, s),
                               points, rtol=0, atol=1e-12)
    plain, kept = [], []
    for angle in np.linspace(0.0, 2.0, 31):
        P = binding.deform(_bent(sheet, angle), faces, b)
        plain.append(P)
        kept.append(binding.keep_thickness(P, triangles, s))
    change = [[np.abs(binding.thickness(P, triangles, b.offset[:, 2], which) / rest - 1).max()
               for P in frames] for frames in (plain, kept)]
    assert change[0][-1] > 0.2 and max(change[1]) < 0.05, (change[0][-1], max(change[1]))
    jumps = [np.linalg.norm(np.diff(np.stack(F), axis=0), axis=2).max() for F in (plain, kept)]
    assert jumps[1] <= 1.5 * jumps[0], jumps


# --- a real flower -------------------------------------------------------------------------------

def test_the_blender_lily_comes_back_as_18_meshes(tmp_path):
    """The done-when of issue 15: bulat66's lily (18 meshes with UVs) comes back as 18 USD
    meshes with its names, vertex counts and UVs; petals deformed, stamens and leaf in
    place. Runs the real chain once `bloom remesh` accepts the lily."""
    from pxr import Usd, UsdGeom

    lily = SHARED / "bulat66_lily.glb"
    if not lily.exists():
        pytest.skip("../shared/external-meshes is not here")
    r = CliRunner().invoke(cli, ["remesh", str(lily), "--out", str(tmp_path / "remesh.h5")])
    if r.exit_code != 0:
        pytest.skip(f"bloom remesh does not take the lily yet: {r.output.strip()[:300]}")
    sim = run_chain(lily, tmp_path, "--set", "remesh.petal_vertices=300")  # coarse: test time
    usd = tmp_path / "bloom.usdc"
    invoke("export", sim, "--out", usd)
    asset = userasset.read_asset(lily)
    stage = Usd.Stage.Open(str(usd))
    meshes = [p for p in stage.GetPrimAtPath("/Bloom").GetChildren() if p.IsA(UsdGeom.Mesh)]
    assert len(meshes) == 18 == len(asset.parts)
    assert [p.GetDisplayName() for p in meshes] == asset.names
    assert [p.GetName() for p in meshes] == export.prim_names(asset.names)
    with h5py.File(sim) as f:
        bound = set(binding.read_bindings(f))
    assert bound
    for i, (prim, part) in enumerate(zip(meshes, asset.parts, strict=True)):
        mesh = UsdGeom.Mesh(prim)
        first = np.asarray(mesh.GetPointsAttr().Get(0))
        last = np.asarray(mesh.GetPointsAttr().Get(8))
        assert len(first) == len(part.points)
        np.testing.assert_allclose(np.asarray(UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st").Get()),
                                   part.uv, atol=1e-6)
        if i in bound:
            assert not np.allclose(first, last)
        else:
            np.testing.assert_allclose(last, part.points, atol=1e-5)


def test_the_asset_is_stored_packed_and_read_back_part_for_part(tmp_path):
    """The user's parts, with and without UVs, normals and materials, are stored as one
    array per field (not a group per part: a branch of 5,000 parts wrote 25,000 datasets)
    and read back as they were; an artifact of the earlier layout (a group per part)
    still reads."""
    rng = np.random.default_rng(2)
    parts = [
        userasset.AssetPart("Petal.000", rng.normal(size=(5, 3)), np.array([3, 4]),
                            np.array([0, 1, 2, 1, 2, 3, 4]), uv=rng.random((7, 2)),
                            uv_indices=np.arange(7), materials=["pink", "white"],
                            face_material=np.array([1, 0])),
        userasset.AssetPart("Stem", rng.normal(size=(4, 3)), np.array([3, 3]),
                            np.array([0, 1, 2, 0, 2, 3]), normals=rng.normal(size=(4, 3))),
        userasset.AssetPart("Empty", np.zeros((0, 3)), np.zeros(0, dtype=np.int64),
                            np.zeros(0, dtype=np.int64)),
    ]
    asset = userasset.Asset(parts, "+y", 0.01)

    def same(got):
        assert (got.up, got.meters_per_unit) == ("+y", 0.01)
        assert [p.name for p in got.parts] == [p.name for p in parts]
        for g, p in zip(got.parts, parts, strict=True):
            for name in ("points", "face_counts", "face_indices", "uv", "uv_indices",
                         "normals", "normal_indices"):
                want = getattr(p, name)
                if want is None:
                    assert getattr(g, name) is None, name
                else:
                    np.testing.assert_array_equal(getattr(g, name), want, err_msg=name)
            assert g.materials == p.materials
            np.testing.assert_array_equal(
                g.face_material, p.face_material if p.face_material is not None
                else np.full(len(p.face_counts), -1))

    with h5py.File(tmp_path / "packed.h5", "w") as h:
        userasset.write(h, asset)
        stored = h[userasset.GROUP]  # (one dataset per field, no group per part)
        assert all(isinstance(x, h5py.Dataset) for x in stored.values())
        assert len(stored["points"]) == 9 and stored["points_offsets"][()].tolist() == [0, 5, 9, 9]
    with h5py.File(tmp_path / "packed.h5") as h:
        same(userasset.read(h))
    with h5py.File(tmp_path / "old.h5", "w") as h:  # a group per part, as written before
        for i, p in enumerate(parts):
            g = h.create_group(f"{userasset.GROUP}/{i}")
            g.attrs["name"] = p.name
            for name in ("points", "face_counts", "face_indices", "uv", "uv_indices",
                         "normals", "normal_indices"):
                if getattr(p, name) is not None:
                    g[name] = getattr(p, name)
            g["face_material"] = (p.face_material if p.face_material is not None
                                  else np.full(len(p.face_counts), -1))
            g.create_dataset("materials", data=np.array(p.materials, dtype=object),
                             dtype=h5py.string_dtype("utf-8"))
        h[userasset.GROUP].attrs.update({"up": "+y", "meters_per_unit": 0.01})
    with h5py.File(tmp_path / "old.h5") as h:
        same(userasset.read(h))


def test_bindings_are_stored_packed_and_read_back_by_part(tmp_path):
    """The parts' bindings are stored as one array per field with the parts bound and
    where each starts, and read back part for part (parts 0 and 3 bound, 3 with no
    points); the earlier layout, a group per part, still reads."""
    rng = np.random.default_rng(4)
    bindings = {3: binding.Binding(np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros((0, 3))),
                0: binding.Binding(rng.integers(-1, 9, 6), rng.random((6, 3)), rng.normal(size=(6, 3)))}
    with h5py.File(tmp_path / "b.h5", "w") as h:
        binding.write_bindings(h, bindings)
        assert len(h[binding.BIND_GROUP]) == 5
    with h5py.File(tmp_path / "old.h5", "w") as h:
        for i, b in bindings.items():
            for name in ("face", "bary", "offset"):
                h[f"{binding.BIND_GROUP}/{i}/{name}"] = getattr(b, name)
    for name in ("b.h5", "old.h5"):
        with h5py.File(tmp_path / name) as h:
            got = binding.read_bindings(h)
        assert sorted(got) == [0, 3]
        for i, b in bindings.items():
            for field in ("face", "bary", "offset"):
                np.testing.assert_array_equal(getattr(got[i], field), getattr(b, field))
