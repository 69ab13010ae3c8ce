"""The remesh stage on real input: named parts, classification, thick petals, repairs."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from pipeline.io import binding
from pipeline.mesh import procedural, topology
from pipeline.review import report
from stages.cli import cli
from tests.conftest import SHARED

EXTERNAL = SHARED / "external-meshes"
needs_shared = pytest.mark.skipif(not EXTERNAL.exists(), reason="../shared/external-meshes absent")


def run(*args):
    r = CliRunner().invoke(cli, [str(a) for a in args])
    return r.exit_code, r.output


def run_stages(tmp_path, scene):
    """remesh, axis, growth and simulate of the scene file ``scene`` into ``tmp_path``
    (r.h5, a.h5, g.h5, s.h5), each asserted to exit 0 without a traceback; returns
    simulate's output."""
    src = None
    for stage, dst in (("remesh", "r.h5"), ("axis", "a.h5"), ("growth", "g.h5"),
                       ("simulate", "s.h5")):
        args = [stage] + ([] if src is None else [src]) + ["--config", scene, "--out",
                                                           tmp_path / dst]
        code, out = run(*args)
        assert code == 0 and "Traceback" not in out, out
        src = tmp_path / dst
    return out


def write_parts(path, parts, header=""):
    """An OBJ with one ``o`` group per ``(name, vertices, faces)``."""
    lines = [f"# {line}" for line in header.splitlines()]
    offset = 0
    for name, v, f in parts:
        lines.append(f"o {name}")
        lines += [f"v {x:.9f} {y:.9f} {z:.9f}" for x, y, z in v]
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in np.asarray(f) + offset]
        offset += len(v)
    path.write_text("\n".join(lines) + "\n")
    return path


def bud_petals(count=5):
    """The procedural bud's petals, each ``(vertices, faces)``."""
    v, f, petal = procedural.bud(count, 600, 0)
    out = []
    for p in range(count):
        idx = np.flatnonzero(petal == p)
        keep = np.isin(f[:, 0], idx)
        out.append((v[idx], np.searchsorted(idx, f[keep])))
    return out


def flower_parts():
    """Five named petals, a stem below the base, a receptacle and five stamens."""
    petals = bud_petals()
    allv = np.vstack([v for v, _ in petals])
    length = float(np.ptp(allv[:, 2]))
    parts = [(f"Circle.00{k}", v, f) for k, (v, f) in enumerate(petals)]
    stem = trimesh.creation.cylinder(radius=0.03 * length, height=length, sections=16)
    parts.append(("Cylinder", stem.vertices + [0, 0, allv[:, 2].min() - 0.5 * length], stem.faces))
    ball = trimesh.creation.icosphere(2, radius=0.08 * length)
    parts.append(("Sphere", ball.vertices + [0, 0, allv[:, 2].min()], ball.faces))
    ring = float(np.median(np.linalg.norm(allv[:, :2], axis=1)))
    for k in range(5):
        a = 2 * np.pi * (k + 0.5) / 5
        stamen = trimesh.creation.cylinder(radius=0.008 * length, height=0.4 * length, sections=8)
        centre = [0.3 * ring * np.cos(a), 0.3 * ring * np.sin(a), allv[:, 2].min() + 0.25 * length]
        parts.append((f"Cylinder.{k + 1:03d}", stamen.vertices + centre, stamen.faces))
    return parts


def test_named_parts_are_classified_and_only_petals_simulated(tmp_path):
    parts = flower_parts()
    mesh = write_parts(tmp_path / "flower.obj", parts)
    out = tmp_path / "remesh.h5"
    code, text = run("remesh", mesh, "--out", out)  # the log is on stderr, in the output
    assert code == 0, text
    with h5py.File(out) as h:
        names = [n.decode() if isinstance(n, bytes) else n for n in h["mesh/part_names"][()]]
        assert names == [name for name, _, _ in parts]
        info = json.loads(h.attrs["parts"])
        petal, part = h["mesh/petal"][()], h["mesh/part"][()]
        assert petal.max() + 1 == 5
        assert sorted(set(part.tolist())) == [0, 1, 2, 3, 4]
        assert np.all(h["mesh/thickness"][()] == 0)
        assert h.attrs["file_up"] == ""
        kinds = {d["name"]: d["kind"] for d in info}
        roles = {d["name"]: d["role"] for d in info}
        for k in range(5):
            assert kinds[f"Circle.00{k}"] == "petal" and roles[f"Circle.00{k}"] == "petal"
        assert kinds["Cylinder"] == "stem", info
        assert kinds["Sphere"] == "receptacle", info
        assert all(kinds[f"Cylinder.{k:03d}"] == "stamen" for k in range(1, 6)), info
        for i, (name, v, f) in enumerate(parts):
            if i < 5:
                assert f"input/parts/{i}" not in h
                continue
            assert roles[name] == "kept"
            assert np.array_equal(h[f"input/parts/{i}/faces"][()], f)
            assert np.allclose(h[f"input/parts/{i}/vertices"][()], v, atol=1e-8)  # input units
    logged = text
    for name, _, _ in parts:
        assert f"part {name!r}: " in logged
    assert "'Sphere': receptacle" in logged and "kept as it is" in logged
    # carried forward through axis and growth
    assert run("axis", out, "--out", tmp_path / "axis.h5")[0] == 0
    assert run("growth", tmp_path / "axis.h5", "--out", tmp_path / "growth.h5")[0] == 0
    with h5py.File(tmp_path / "growth.h5") as h:
        assert len(h["mesh/part_names"]) == len(parts)
        assert np.array_equal(h["mesh/part"][()], part)
        assert "mesh/thickness" in h


def test_exclude_leaves_a_petal_out(tmp_path):
    mesh = write_parts(tmp_path / "flower.obj", flower_parts())
    code, text = run("remesh", mesh, "--out", tmp_path / "r.h5", "--set", 'scene.exclude=["Circle.004"]')
    assert code == 0, text
    with h5py.File(tmp_path / "r.h5") as h:
        assert h["mesh/petal"][()].max() + 1 == 4
        roles = {d["name"]: d["role"] for d in json.loads(h.attrs["parts"])}
        assert roles["Circle.004"] == "excluded" and "input/parts/4/vertices" in h


def solidify(v, f, t):
    """A closed shell: the sheet offset by +-t/2 along its vertex normals, rims joined.
    Returns ``(vertices, faces, top, bottom)`` (the two layers as trimesh meshes)."""
    n = trimesh.Trimesh(v, f, process=False).vertex_normals
    top, bottom = v + 0.5 * t * n, v - 0.5 * t * n
    nv = len(v)
    faces = [f, f[:, ::-1] + nv]
    he = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    _, he_edge, count = topology.unique_edges(f)
    rim = he[count[he_edge] == 1]
    a, b = rim[:, 0], rim[:, 1]
    faces.append(np.stack([b, a, a + nv], axis=1))
    faces.append(np.stack([b, a + nv, b + nv], axis=1))
    return (np.vstack([top, bottom]), np.vstack(faces),
            trimesh.Trimesh(top, f, process=False), trimesh.Trimesh(bottom, f, process=False))


def test_solidified_petals_become_their_mid_surfaces(tmp_path):
    import gpytoolbox

    petals = bud_petals()
    length = float(np.ptp(petals[0][0], axis=0).max())
    t = 0.03 * length
    parts, layers = [], []
    for k, (v, f) in enumerate(petals):
        sv, sf, top, bottom = solidify(v, f, t)
        parts.append((f"Cylinder{k:02d}", sv, sf))
        layers.append((top, bottom))
    mesh = write_parts(tmp_path / "thick.obj", parts)
    code, text = run("remesh", mesh, "--out", tmp_path / "r.h5")
    assert code == 0, text
    with h5py.File(tmp_path / "r.h5") as h:
        v, petal, part = h["mesh/vertices"][()], h["mesh/petal"][()], h["mesh/part"][()]
        thick, scale = h["mesh/thickness"][()], h.attrs["scale"]
        kinds = [d["kind"] for d in json.loads(h.attrs["parts"])]
        assert json.loads(h.attrs["clean"])["midsurfaces"] == 5
    assert kinds == ["thick petal"] * 5
    assert petal.max() + 1 == 5
    assert np.all(np.abs(thick / scale - t) < 0.1 * t), (thick.min() / scale / t, thick.max() / scale / t)
    for p in range(5):
        pts = v[petal == p] / scale
        top, bottom = layers[int(part[petal == p][0])]
        for layer in (top, bottom):
            d = np.sqrt(gpytoolbox.squared_distance(pts, layer.vertices, layer.faces, use_cpp=True)[0])
            assert np.all(np.abs(d - 0.5 * t) < 0.1 * t), (p, d.min() / t, d.max() / t)


def test_stacked_flipped_duplicate_faces_are_dropped_and_counted(tmp_path):
    petals = bud_petals()
    v, f = petals[2]
    parts = [(f"Circle.00{k}", pv, pf) for k, (pv, pf) in enumerate(petals)]
    parts[2] = ("Circle.002", v, np.vstack([f, f[:, ::-1]]))
    mesh = write_parts(tmp_path / "stacked.obj", parts)
    code, text = run("remesh", mesh, "--out", tmp_path / "r.h5")
    assert code == 0, text
    with h5py.File(tmp_path / "r.h5") as h:
        report = json.loads(h.attrs["clean"])
        assert h["mesh/petal"][()].max() + 1 == 5
    assert report["duplicate_faces"] == len(f) and report["opposite_duplicate_faces"] == len(f)


def fin(v, f):
    """A sheet with one non-manifold edge: a third face on an interior edge."""
    _, he_edge, count = topology.unique_edges(f)
    he = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    a, b = he[np.flatnonzero(count[he_edge] == 2)[0]]
    tip = 0.5 * (v[a] + v[b]) + 0.01 * np.cross(v[b] - v[a], [0, 0, 1.0])
    return np.vstack([v, tip]), np.vstack([f, [[a, b, len(v)]]])


def test_fins_and_touching_petals_are_repaired_and_counted(tmp_path):
    """A third face on an edge (a fin) is dropped; five petals welded into one part at a
    shared centre vertex come apart there (one copy of the vertex per petal)."""
    petals = bud_petals()
    parts = [(f"petal_{k}", pv, pf) for k, (pv, pf) in enumerate(petals)]
    parts[1] = ("petal_1", *fin(*petals[1]))
    parts[3] = ("petal_3", *fin(*petals[3]))
    # all five in one more part, their base vertices nearest the centre welded to one
    offsets = np.cumsum([0] + [len(pv) for pv, _ in petals])
    allv = np.vstack([pv for pv, _ in petals])
    allf = np.vstack([pf + o for (_, pf), o in zip(petals, offsets, strict=False)])
    centre = allv.mean(axis=0) * [1, 1, 0] + [0, 0, allv[:, 2].min()]
    lowest = [o + int(np.argmin(np.linalg.norm(pv - centre, axis=1)))
              for (pv, _), o in zip(petals, offsets, strict=False)]
    allv[lowest] = allv[lowest[0]]
    mesh = write_parts(tmp_path / "fins.obj", parts[:4] + [("fused", allv, allf)])
    # (five overlapping petals in one part look like a layered shell: named petals here)
    code, out = run("remesh", mesh, "--out", tmp_path / "r.h5", "--set", 'scene.petals=["*"]')
    assert code == 0, out
    with h5py.File(tmp_path / "r.h5") as h:
        record = json.loads(h.attrs["clean"])
        assert record["nonmanifold_edges"] == 2 and record["nonmanifold_faces"] == 2
        assert record["split_vertices"] == 4  # the welded centre: one copy per petal
        names = list(h["mesh/part_names"].asstr()[()])
        part = h["mesh/part"][()]
        petal = h["mesh/petal"][()]
        assert len(np.unique(petal[part == names.index("fused")])) == 5
        assert len(np.unique(petal)) == 9
    assert "petal_1: 1 non-manifold edges: kept the two faces" in out, out


def test_two_bad_petal_parts_are_named_in_one_line(tmp_path):
    """Two parts named petals that are solid blocks: both named, one line, no output."""
    petals = bud_petals()
    parts = [(f"petal_{k}", pv, pf) for k, (pv, pf) in enumerate(petals)]
    for k in (1, 3):
        block = trimesh.creation.box(extents=np.ptp(petals[k][0], axis=0) + 0.5)
        parts[k] = (f"petal_{k}", block.vertices + petals[k][0].mean(axis=0), block.faces)
    mesh = write_parts(tmp_path / "bad.obj", parts)
    code, out = run("remesh", mesh, "--out", tmp_path / "r.h5", "--set", 'scene.petals=["petal_*"]')
    assert code == 1
    assert out.startswith(f"bloom remesh: error: {mesh}: "), out
    assert out.strip().count("\n") == 0 and "Traceback" not in out
    assert "petal_1: cannot become a sheet" in out and "petal_3: cannot become a sheet" in out, out
    assert 'scene.exclude = ["petal_1", "petal_3"]' in out, out
    assert not (tmp_path / "r.h5").exists()


def test_no_petals_lists_every_part(tmp_path):
    parts = [p for p in flower_parts() if not p[0].startswith("Circle")]
    mesh = write_parts(tmp_path / "stem.obj", parts)
    code, out = run("remesh", mesh, "--out", tmp_path / "r.h5")
    assert code == 1 and out.strip().count("\n") == 0, out
    assert "no petals: " in out and all(f"{name}: " in out for name, _, _ in parts), out


def test_uv_seam_duplicates_are_welded_at_centimetre_scale(tmp_path):
    parts = []
    seams = 0
    for k, (v, f) in enumerate(bud_petals()):
        v = v * 0.01  # small coordinates: the weld tolerance must follow the part's size
        # a seam across the petal: faces above it use their own copies of its vertices
        c = v[f].mean(axis=1)[:, 2]
        cut = np.median(c)
        upper = c > cut
        shared = np.intersect1d(np.unique(f[upper]), np.unique(f[~upper]))
        copy = np.arange(len(v))
        copy[shared] = len(v) + np.arange(len(shared))
        f = np.where(upper[:, None], copy[f], f)
        parts.append((f"Plane.{k:03d}", np.vstack([v, v[shared]]), f))
        seams += len(shared)
    mesh = write_parts(tmp_path / "seam.obj", parts,
                       header="This file uses centimeters as units for non-parametric coordinates.")
    code, text = run("remesh", mesh, "--out", tmp_path / "r.h5")
    assert code == 0, text
    with h5py.File(tmp_path / "r.h5") as h:
        assert h["mesh/petal"][()].max() + 1 == 5
        assert json.loads(h.attrs["clean"])["welded"] == seams
        assert h.attrs["meters_per_unit"] == 0.01


@needs_shared
@pytest.mark.parametrize("name, petals", [
    ("hallgeirl_petals", 14), ("ssajeev_daisy", 11), ("ericrius1_petal", 1),
    ("dimontel_petal", 1), ("chianti_flower5", 5), ("pchinyun_petal", 1), ("clach_flower", 5)])
def test_external_meshes(tmp_path, name, petals):
    code, out = run("remesh", EXTERNAL / f"{name}.obj", "--out", tmp_path / "r.h5")
    assert code == 0, out
    with h5py.File(tmp_path / "r.h5") as h:
        assert h["mesh/petal"][()].max() + 1 == petals
        names = list(h["mesh/part_names"].asstr()[()])
        info = json.loads(h.attrs["parts"])
        assert [d["name"] for d in info] == names
        assert h["mesh/part"].shape == h["mesh/petal"].shape


@needs_shared
def test_the_blender_lily_reaches_growth_with_six_tepals_based_at_its_centre(tmp_path):
    """bulat66_lily.glb's petal part (Circle.003) is six tepals and a hub in one coarse
    surface, each tepal a single sheet whose edges fold under (a hem), with a groove
    along its midrib: no mid-surface covers it. Its 37 non-manifold edges are repaired,
    it is split into its six lobes and each is sampled as a height field; the stamens,
    stem, pistil and sepal stay as they are. Each tepal's base is at the flower's centre
    and its tip is the point farthest out."""
    code, out = run("remesh", EXTERNAL / "bulat66_lily.glb", "--out", tmp_path / "r.h5",
                    "--set", "remesh.petal_vertices=300")
    assert code == 0, out
    assert "Circle.003: no mid-surface" in out and "simulated as 6 sheet(s) sampled over its lobes" in out
    with h5py.File(tmp_path / "r.h5") as h:
        assert h["mesh/petal"][()].max() + 1 == 6
        names = list(h["mesh/part_names"].asstr()[()])
        assert set(names[i] for i in h["mesh/part"][()]) == {"Circle.003"}
        clean = json.loads(h.attrs["clean"])
        assert clean["height_sheets"] == 6 and clean["nonmanifold_edges"] == 37
        kinds = {d["name"]: d["kind"] for d in json.loads(h.attrs["parts"])}
        assert kinds["Circle.004"] == "stamen" and kinds["Sphere"] == "stamen"
    for stage, src, dst in (("axis", "r.h5", "a.h5"), ("growth", "a.h5", "g.h5")):
        code, out = run(stage, tmp_path / src, "--out", tmp_path / dst)
        assert code == 0, out
        if stage == "axis":  # (the hub the tepals are joined at stays with it)
            assert "part 'Circle.003':" in out and "held with the hub" in out, out
    with h5py.File(tmp_path / "a.h5") as h:
        b = binding.read_bindings(h)
        part = list(h["input/asset/names"].asstr()[()]).index("Circle.003")
        points = h["input/asset/points"][()][h["input/asset/points_offsets"][part]:
                                               h["input/asset/points_offsets"][part + 1]]
        line = h["flower/axis"][0]
        q = points * h.attrs["scale"] - line[:3]
        r = np.linalg.norm(q - np.outer(q @ line[3:], line[3:]), axis=1)
        held = b[part].face < 0
        assert 0 < held.sum() < 0.5 * len(held)  # the hub, not the tepals
        assert np.median(r[held]) < 0.5 * np.median(r[~held])
    with h5py.File(tmp_path / "g.h5") as h:
        v, petal = h["mesh/vertices"][()], h["mesh/petal"][()]
        base, tip, s = h["axis/base"][()], h["axis/tip"][()], h["axis/s"][()]
        alpha = h["growth/alpha"][()]
        assert np.isfinite(alpha).all() and alpha.max() > 0 and np.isfinite(h["growth/rest_angle"][()]).all()
    centre = v.mean(axis=0)
    normal = np.linalg.svd(v - centre)[2][2]
    def radial(p):
        d = p - centre
        return np.linalg.norm(d - np.outer(d @ normal, normal), axis=1)
    for k in range(6):
        mine = petal == k
        r = radial(v[mine])
        assert radial(v[tip[k]][None])[0] > np.percentile(r, 95)  # the tip is the far end
        assert radial(v[base & mine]).mean() < np.percentile(r, 15)  # the base is the near end
        assert s[mine].min() == 0 and s[mine].max() == 1


# --- petals joined in one surface, and what is not a set of petals ----------------------------

def test_a_star_of_petals_in_one_sheet_becomes_its_petals(tmp_path):
    """A low-poly flower modelled as one sheet (five petals joined at a hub, a stem beside
    it): five petals that share no point, the hub left out, said in the log and counted."""
    from tests.test_lobes import star

    v, f = star(k=5, hub=0.2, cup=0.3, rings=12, around=150)
    stem = trimesh.creation.cylinder(radius=0.03, height=1.0, sections=10)
    stem.apply_translation([0, 0, -0.5])
    mesh = write_parts(tmp_path / "star.obj", [("Flower", v, f), ("Stem", stem.vertices, stem.faces)])
    code, out = run("remesh", mesh, "--out", tmp_path / "r.h5")
    assert code == 0, out
    assert "Flower: one sheet of 5 petals joined at a hub: split into its petals" in out
    with h5py.File(tmp_path / "r.h5") as h:
        petal, verts = h["mesh/petal"][()], h["mesh/vertices"][()]
        assert petal.max() + 1 == 5
        assert json.loads(h.attrs["clean"])["ring_splits"] == 1
        kinds = {d["name"]: (d["kind"], d["role"]) for d in json.loads(h.attrs["parts"])}
    assert kinds["Flower"][1] == "petal" and kinds["Stem"] == ("stem", "kept")
    from scipy.spatial import cKDTree

    for p in range(5):
        others = cKDTree(verts[petal != p])
        assert others.query(verts[petal == p])[0].min() > 0.2  # mean edges apart: no shared point


@pytest.mark.parametrize("kind", ["cloud", "splat", "voxels"])
def test_what_is_not_a_set_of_petals_is_named_in_one_line(tmp_path, kind):
    rng = np.random.default_rng(0)
    path = tmp_path / f"{kind}.ply"
    if kind == "voxels":  # MagicaVoxel-style: a ring of five petals of unit cubes
        cells = {tuple(np.round([i * np.cos(a) - j * np.sin(a), i * np.sin(a) + j * np.cos(a), 0]))
                 for a in 2 * np.pi * np.arange(5) / 5 for i in range(1, 7) for j in (-1, 0, 1)}
        trimesh.util.concatenate([trimesh.creation.box(extents=(1, 1, 1)).apply_translation(c)
                                  for c in sorted(cells)]).export(path)
        expected = "part_0: other (not a petal: voxel cubes (up to"
    else:
        props = ["x", "y", "z"] + (["f_dc_0", "opacity", "scale_0", "rot_0"] if kind == "splat" else [])
        header = ("ply\nformat binary_little_endian 1.0\nelement vertex 400\n"
                  + "".join(f"property float {p}\n" for p in props) + "end_header\n")
        path.write_bytes(header.encode() + rng.normal(size=(400, len(props))).astype("<f4").tobytes())
        expected = {"cloud": "a point cloud (400 points, no faces)",
                    "splat": "a Gaussian splat (400 splats with opacity, scale and rotation"}[kind]
    code, out = run("remesh", path, "--out", tmp_path / "r.h5")
    assert code == 1 and out.strip().count("\n") == 0, out
    assert out.startswith(f"bloom remesh: error: {path}: ") and expected in out, out
    assert not (tmp_path / "r.h5").exists()


@pytest.mark.slow
@pytest.mark.studio
@needs_shared
def test_hallgeirls_flat_flower_blooms_from_a_closed_bud(tmp_path):
    """hallgeirl's flat flower (14 petals in a pinwheel, tips curled 131 deg down), default
    config, about two minutes (``make test-studio``). With the model's curvature kept in
    the bud, undoing the rims' growth rolled its petals further down and under: a bud
    63.5 deg more open than the model, the "bloom" closing it. With the recurve left out
    of the bud and the bud cupped toward the inside (growth.recurve, growth.cup): a bud
    34.3 deg more closed than the model, every petal opening over 100 deg. That bloom then
    closed 38.7 deg before it opened (its upright petals, pressed together, fell in across
    the axis at once): it is now the model's own path played forward, from its most
    closed frame, and sound."""
    scene = tmp_path / "scene.toml"
    scene.write_text(f'[scene]\nmesh = "{EXTERNAL / "hallgeirl_petals.obj"}"\n')
    run_stages(tmp_path, scene)
    with h5py.File(tmp_path / "s.h5") as h:
        assert h.attrs["growth_start"] == "open"
        assert h.attrs["bud_closed"] > 20.0
        assert h.attrs["recurve_share"] > 0.3
        assert h.attrs["summary"].startswith("sound"), h.attrs["summary"]
        assert h.attrs["bloom_path"] == "retraced"
        opening = h["diagnostics/opening_angle_per_petal"][()]
        assert opening[-1].min() > 20.0
        assert report.closing_dip(opening) <= report.CLOSES_FIRST
