"""Real-world input: file formats, remeshing, symmetrizing non-symmetric topology,
refusing what is not a petal sheet, and the external meshes in ../shared."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner
from scipy.spatial import Delaunay

from pipeline.flower.axis import find_axes
from pipeline.io.meshfile import read_mesh
from pipeline.mesh import clean, procedural, remesh, symmetry, topology
from stages.cli import cli
from tests.conftest import SHARED, prepare

EXTERNAL = SHARED / "external-meshes"
needs_shared = pytest.mark.skipif(not EXTERNAL.exists(), reason="../shared/external-meshes absent")


def petal(vertices=300, seed=0):
    v, f, _ = procedural.bud(1, vertices, seed)
    return v / clean.mean_edge_length(v, f), f


def irregular_petal(seed=3):
    """A petal whose triangulation is not mirror-symmetric and whose shape is a little off."""
    v, f = petal(300, seed)
    v, f, _ = remesh.isotropic(v, f, 0.8)  # new topology, no longer paired across the plane
    rng = np.random.default_rng(seed)
    return v + 0.05 * rng.normal(size=v.shape) + 0.15 * np.outer(v[:, 0] > 0, [0, 0, 1]), f


def min_angles(v, f):
    p = v[f]
    out = []
    for k in range(3):
        a, b = p[:, (k + 1) % 3] - p[:, k], p[:, (k + 2) % 3] - p[:, k]
        cos = np.einsum("ij,ij->i", a, b) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
        out.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    return np.min(out, axis=0)


def area(v, f):
    return 0.5 * np.linalg.norm(topology.face_normals(v, f), axis=1).sum()


def perimeter(v, f):
    edges, _, count = topology.unique_edges(f)
    b = edges[count == 1]
    return np.linalg.norm(v[b[:, 0]] - v[b[:, 1]], axis=1).sum()


# --- remeshing --------------------------------------------------------------------------

@pytest.mark.parametrize("h", [0.6, 1.5])
def test_isotropic_remesh_hits_the_target_inside_and_on_the_boundary(h):
    v, f = petal(300)
    u, g, _ = remesh.isotropic(v, f, h)
    edges, _, count = topology.unique_edges(g)
    length = np.linalg.norm(u[edges[:, 0]] - u[edges[:, 1]], axis=1)
    assert abs(length.mean() / h - 1) < 0.1, length.mean()
    rim = length[count == 1]
    assert remesh.COLLAPSE * h * 0.75 < rim.min(), rim.min()
    assert rim.max() < remesh.SPLIT * h * 1.01, rim.max()
    assert np.percentile(min_angles(u, g), 5) > 25
    assert count.max() == 2 and topology.components(g, len(u)).max() == 0
    assert abs(area(u, g) / area(v, f) - 1) < 0.03
    assert abs(perimeter(u, g) / perimeter(v, f) - 1) < 0.03


def test_boundary_resampling_splits_long_and_collapses_short_edges():
    # a coarse square whose boundary edges are 5x too long on one side, 2.5x too short on another
    xs, ys = np.meshgrid(np.linspace(0, 10, 3), np.linspace(0, 10, 26))
    v = np.c_[xs.ravel(), ys.ravel(), np.zeros(xs.size)]
    f = Delaunay(v[:, :2]).simplices
    u, g, fixed = remesh.resample_boundary(v, f, 1.0)
    edges, _, count = topology.unique_edges(g)
    rim = np.linalg.norm(u[edges[count == 1, 0]] - u[edges[count == 1, 1]], axis=1)
    assert rim.max() < remesh.SPLIT and rim.min() > 0.5, (rim.min(), rim.max())
    assert fixed.sum() == 4  # the square's corners
    np.testing.assert_allclose(np.sort(u[fixed][:, :2], axis=0), [[0, 0], [0, 0], [10, 10], [10, 10]])


# --- symmetry ---------------------------------------------------------------------------

@pytest.mark.parametrize("h", [0.0, 1.0])
def test_cut_and_mirror_makes_any_petal_symmetric_to_1e9(h):
    v, f = irregular_petal()
    plane, before = symmetry.mirror_plane(v)
    assert symmetry.mirror_pairs(v, plane, f) is None  # the old way cannot do this one
    redo = (lambda a, b, fixed: remesh.isotropic(a, b, h, fixed=fixed)) if h else None
    u, g, partner = symmetry.mirrored_mesh(v, f, plane, snap=0.2, remesh=redo)
    assert symmetry.asymmetry(u, plane) < 1e-9 < before
    np.testing.assert_array_equal(partner[partner], np.arange(len(u)))
    np.testing.assert_allclose(symmetry.reflect(u, plane)[partner], u, atol=1e-9)
    faces = {tuple(sorted(t)) for t in g.tolist()}
    assert all(tuple(sorted(partner[t])) in faces for t in g.tolist())
    on_plane = partner == np.arange(len(u))
    np.testing.assert_allclose(u[on_plane] @ plane[:3] - plane[3], 0, atol=1e-9)
    _, _, count = topology.unique_edges(g)
    assert count.max() == 2 and topology.components(g, len(u)).max() == 0
    assert abs(area(u, g) / area(v, f) - 1) < 0.05


def test_symmetrized_petal_has_its_axis_on_the_plane_and_x_is_antisymmetric():
    v, f = irregular_petal()
    result = prepare(v, f, where="test", target_edge=1.0)
    assert min_angles(result.vertices, result.faces).min() > 15.0  # measured 24.5 deg
    axes = find_axes(result.vertices, result.faces, result.petal, planes=result.plane)
    plane = result.plane[0]
    u = result.vertices
    np.testing.assert_allclose(u[axes.on_axis] @ plane[:3] - plane[3], 0, atol=1e-9)
    np.testing.assert_allclose(u[axes.tip] @ plane[:3] - plane[3], 0, atol=1e-9)
    partner = symmetry.mirror_pairs(u, plane)
    np.testing.assert_allclose(axes.x[partner], -axes.x, atol=1e-9)
    np.testing.assert_allclose(axes.s[partner], axes.s, atol=1e-9)


def test_mirror_plane_of_a_nearly_symmetric_petal_is_refined_past_the_principal_axes():
    v, f = petal(300)
    true_plane, _ = symmetry.mirror_plane(v)
    across = int(np.argmax(np.abs(true_plane[:3])))
    w = v.copy()
    w[w[:, across] > true_plane[3]] *= [1.1, 1.0, 1.0]  # one half widened: the principal axes tilt
    rough, rough_err = symmetry.mirror_plane(w, refine=False)
    fine, fine_err = symmetry.mirror_plane(w)
    assert fine_err < 0.95 * rough_err
    assert abs(fine[:3] @ true_plane[:3]) > abs(rough[:3] @ true_plane[:3])


# --- reading ----------------------------------------------------------------------------

@pytest.mark.parametrize("ext", ["obj", "ply", "stl", "off", "glb"])
def test_every_format_reads_to_the_same_petal(tmp_path, ext):
    v, f = petal(200)
    path = tmp_path / f"petal.{ext}"
    trimesh.Trimesh(v, f, process=False).export(path)
    w, g = read_mesh(path)
    result = prepare(w, g, where=str(path), symmetrize=False)
    assert len(result.vertices) == len(v)  # STL stores each triangle alone: welding rejoins them
    assert len(result.faces) == len(f)
    assert topology.components(result.faces, len(result.vertices)).max() == 0


def test_quads_and_polygons_are_triangulated(tmp_path):
    path = tmp_path / "quads.obj"
    grid = [(i, j) for j in range(4) for i in range(4)]
    lines = [f"v {i} {j} {0.1 * i * i}" for i, j in grid]
    lines += [f"f {a} {a + 1} {a + 5} {a + 4}" for a in (1, 2, 3, 5, 6, 7, 9, 10, 11)]
    path.write_text("\n".join(lines) + "\n")
    v, f = read_mesh(path)
    assert f.shape == (18, 3) and len(v) == 16


def test_a_flower_in_a_glb_scene_keeps_its_petals_and_their_placement(tmp_path):
    v, f = petal(150)
    scene = trimesh.Scene()
    for k in range(3):
        T = trimesh.transformations.rotation_matrix(2 * np.pi * k / 3, [0, 0, 1])
        T[:3, 3] = [0, 0, k]
        scene.add_geometry(trimesh.Trimesh(v, f, process=False), node_name=f"p{k}", transform=T)
    path = tmp_path / "flower.glb"
    scene.export(path)
    w, g = read_mesh(path)
    result = prepare(w, g, where=str(path), symmetrize=False)
    assert result.petal.max() == 2
    heights = [np.round(w[result.petal == p][:, 2].mean() - v[:, 2].mean(), 6) for p in range(3)]
    assert sorted(heights) == [0, 1, 2]


# --- refusals ---------------------------------------------------------------------------

def slab(slit=True):
    """A flat two-layer slab (a thick petal) opened along one side, as Cinema 4D exports."""
    n = 12
    xs, ys = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float))
    top = np.c_[xs.ravel(), ys.ravel(), np.zeros(n * n)]
    idx = np.arange(n * n).reshape(n, n)
    quads = [(idx[j, i], idx[j, i + 1], idx[j + 1, i + 1], idx[j + 1, i])
             for j in range(n - 1) for i in range(n - 1)]
    ft = [(a, b, c) for a, b, c, d in quads] + [(a, c, d) for a, b, c, d in quads]
    v = np.vstack([top, top - [0, 0, 0.4]])
    f = np.vstack([ft, np.asarray(ft)[:, ::-1] + n * n])
    # join the layers along three sides (the fourth is the slit)
    rim = list(idx[0, :]) + list(idx[1:, -1]) + list(idx[-1, -2::-1])
    side = []
    for a, b in zip(rim[:-1], rim[1:], strict=True):
        side += [(b, a, a + n * n), (b, a + n * n, b + n * n)]
    return v, np.vstack([f, side])


def test_a_slab_is_two_layers_and_a_folded_sheet_is_not():
    v, f = slab()
    assert clean.layered_fraction(v, f)[0] > 0.5
    w, g = petal(300)
    assert clean.layered_fraction(w, g)[0] < 0.05


# --- the external meshes ----------------------------------------------------------------

def run(*args):
    r = CliRunner().invoke(cli, [str(a) for a in args])
    return r.exit_code, r.output


@needs_shared
@pytest.mark.parametrize("name, petals",
                         [("chianti_petal1", 1), ("chianti_flower5", 5), ("souki202_petal", 5)])
def test_real_meshes_go_through_the_geometry_stages_and_simulate(tmp_path, name, petals):
    import h5py

    mesh = EXTERNAL / f"{name}.obj"
    code, out = run("remesh", mesh, "--out", tmp_path / "remesh.h5", "--set", "remesh.petal_vertices=250")
    assert code == 0, out
    assert run("axis", tmp_path / "remesh.h5", "--out", tmp_path / "axis.h5")[0] == 0
    assert run("growth", tmp_path / "axis.h5", "--out", tmp_path / "growth.h5")[0] == 0
    code, out = run("simulate", tmp_path / "growth.h5", "--out", tmp_path / "sim.h5",
                    "--set", "simulate.steps=300", "--set", "simulate.frames=3")
    assert code == 0, out
    with h5py.File(tmp_path / "growth.h5") as h:
        v, f, petal_id, x = (h[k][()] for k in ("mesh/vertices", "mesh/faces", "mesh/petal", "axis/x"))
        scale = h.attrs["scale"]
    assert petal_id.max() + 1 == petals
    # mean edge 1, up to the separation of crossing petals (after scaling: moves < 10%)
    assert abs(clean.mean_edge_length(v, f) - 1) < 0.02
    for p in range(petals):
        assert x[petal_id == p].min() == -1.0 and x[petal_id == p].max() == 1.0
        count = int((petal_id == p).sum())
        assert 200 < count < 320, count  # about remesh.petal_vertices
    extent_in = np.ptp(read_mesh(mesh)[0], axis=0).max()
    assert abs(np.ptp(v, axis=0).max() / scale / extent_in - 1) < 0.05  # scale returns to the user's units
    with h5py.File(tmp_path / "sim.h5") as h:
        assert np.isfinite(h["frames/positions"][()]).all()
    # remeshed and symmetrized without needle triangles: measured min angle 5.6 deg
    # (souki202's needle tips) to 13, 5th percentile 21 to 37
    angles = min_angles(v, f)
    assert angles.min() > 4.0 and np.percentile(angles, 5) > 18.0, (angles.min(), np.percentile(angles, 5))


def test_remeshing_is_reproducible_bit_for_bit():
    v, f = irregular_petal()
    a = prepare(v, f, where="test", petal_vertices=200)
    b = prepare(v.copy(), f.copy(), where="test", petal_vertices=200)
    assert a.vertices.tobytes() == b.vertices.tobytes() and a.faces.tobytes() == b.faces.tobytes()


@needs_shared
def test_a_solidified_petal_blooms_with_the_default_config(tmp_path):
    """pchinyun's Blender-solidified petal, every stage at its defaults: its mid-surface
    is remeshed to the quality bound (needles clipped off its rim) and Newton follows it
    to the end. Before, a needle on the rim flattened at growth 0.045 and simulate
    stopped with "no equilibrium". Measured: final opening 81.8 deg, from a bud cupped and
    not rolled back (growth.cup, growth.recurve; 36.7 deg from a bud that kept the model's
    curvature, 18.1 deg while the axis of this unsymmetrized petal was a band two vertices
    wide, both ends of every edge crossing its center plane held at x = 0)."""
    import h5py

    steps = (("remesh", EXTERNAL / "pchinyun_petal.obj", "remesh.h5"),
             ("axis", tmp_path / "remesh.h5", "axis.h5"),
             ("growth", tmp_path / "axis.h5", "growth.h5"),
             ("simulate", tmp_path / "growth.h5", "sim.h5"))
    for stage, src, dst in steps:
        code, out = run(stage, src, "--out", tmp_path / dst)
        assert code == 0, (stage, out)
    with h5py.File(tmp_path / "sim.h5") as h:
        X = h["frames/positions"][()]
        opening = h["diagnostics/opening_angle"][()]
    assert np.isfinite(X).all() and len(X) == 121
    assert 10.0 < opening[-1] < 120.0
