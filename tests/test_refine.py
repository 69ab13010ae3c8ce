"""A coarse mesh solved cut finer (simulate.petal_vertices): the subdivision keeps the old
vertices and lifts the new onto the smooth surface, the finer problem carries the coarse
one's axes and base, and the bloom of a coarse bud comes back on the coarse vertices
nearer the fine bloom than the coarse mesh alone blooms."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from pipeline.chain.axis import axis_options
from pipeline.chain.problem import levels_for
from pipeline.config import load_config
from pipeline.mesh import procedural, topology
from pipeline.mesh.subdivide import subdivide
from pipeline.sim.build import Prepared


def _sphere_cap(n: int):
    """A cap of the unit sphere (polar angle up to 1 rad) as a regular grid in the
    angles, ``n`` rings."""
    import trimesh

    ico = trimesh.creation.icosphere(subdivisions=n)
    keep = ico.vertices[:, 2] > np.cos(1.0)
    faces = ico.faces[np.all(keep[ico.faces], axis=1)]
    used, remap = topology.used_vertices(faces, len(ico.vertices))
    return np.asarray(ico.vertices)[used], remap[faces]


def test_subdivision_keeps_the_old_vertices_and_lifts_the_new_onto_the_sphere():
    """Old vertices first with their indices; 4 children per face, oriented as their
    parent; the new vertices off the unit sphere by far less than the chords' midpoints
    (inside: under a fifth, 0.06-0.07 measured; on the rim, where a vertex's normal is
    one-sided, under 0.6, 0.47-0.52 measured), and less with each halving of the edge
    (inside 4.2-4.7 times)."""
    errors = []
    for n in (2, 3, 4):
        v, f = _sphere_cap(n)
        fine_v, fine_f, parent = subdivide(v, f)
        assert np.array_equal(fine_v[:len(v)], v) and len(fine_f) == 4 * len(f)
        assert len(parent) == len(fine_v) - len(v)
        up = np.einsum("ij,ij->i", topology.face_normals(fine_v, fine_f),
                       fine_v[fine_f].mean(axis=1))
        assert np.all(up > 0.0)  # (the sphere's faces face out, as the parent's do)
        rim = topology.boundary_vertices(f, len(v))
        inside = ~(rim[parent[:, 0]] | rim[parent[:, 1]])
        chord = np.abs(np.linalg.norm(0.5 * (v[parent[:, 0]] + v[parent[:, 1]]), axis=1) - 1)
        lifted = np.abs(np.linalg.norm(fine_v[len(v):], axis=1) - 1.0)
        assert lifted[inside].max() < 0.2 * chord[inside].max()
        assert lifted.max() < 0.6 * chord.max()
        errors.append(lifted[inside].max())
    assert errors[1] < errors[0] / 3.5 and errors[2] < errors[1] / 3.5


def test_the_outline_is_cut_along_its_curve_and_kept_at_its_corners():
    """A disc's rim (16 chords of the unit circle) is cut on the circle through it (the
    four-point rule: 5.5e-4 off it measured, against the chords' 0.019), so a coarse petal's
    outline does not stay a polygon; a square's corners stay corners and its straight
    sides straight (every new vertex of a flat grid at its edge's midpoint)."""
    n = 16
    angle = 2.0 * np.pi * np.arange(n) / n
    v = np.r_[[[0.0, 0.0, 0.0]], np.c_[np.cos(angle), np.sin(angle), np.zeros(n)]]
    f = np.array([[0, 1 + k, 1 + (k + 1) % n] for k in range(n)])
    fine_v, _, parent = subdivide(v, f)
    rim = (parent[:, 0] > 0) & (parent[:, 1] > 0)
    off = np.abs(np.linalg.norm(fine_v[len(v):][rim], axis=1) - 1.0)
    sagitta = 1.0 - np.cos(np.pi / n)
    assert off.max() < 0.05 * sagitta
    g = np.linspace(0.0, 1.0, 5)
    x, y = np.meshgrid(g, g)
    grid = np.c_[x.ravel(), y.ravel(), np.zeros(25)]
    quads = [(5 * i + j, 5 * i + j + 1, 5 * i + j + 6, 5 * i + j + 5)
             for i in range(4) for j in range(4)]
    faces = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    fine_v, _, parent = subdivide(grid, faces)
    assert np.allclose(fine_v[len(grid):], 0.5 * (grid[parent[:, 0]] + grid[parent[:, 1]]),
                       rtol=0.0, atol=1e-12)


def test_the_outline_curve_does_not_fold_a_thin_rim_triangle():
    """A hole's rim of 16 chords of the unit circle, each the edge of a sliver whose third
    corner lies between the chord and the circle (0.99 out at its middle): the curve
    through the rim would put the new vertex past that corner and fold the sliver's
    children (quality -0.07 measured); held to a quarter of the sliver's height into it,
    every child keeps its side and half its parent's quality."""
    n = 16
    turn = 2.0 * np.pi * np.arange(n) / n
    ring = lambda r, a: np.c_[r * np.cos(a), r * np.sin(a), np.zeros(n)]  # noqa: E731
    v = np.r_[ring(1.0, turn), ring(0.99, turn + np.pi / n), ring(1.5, turn)]
    f = []
    for k in range(n):
        k1 = (k + 1) % n
        f += [[k, n + k, k1], [k1, n + k, 2 * n + k1], [n + k, 2 * n + k, 2 * n + k1],
              [k, 2 * n + k, n + k]]
    f = np.array(f)

    def quality(v, f):  # twice the area (signed, +z up) over the longest edge squared
        a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        longest = np.max([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1),
                          np.linalg.norm(a - c, axis=1)], axis=0)
        return np.cross(b - a, c - a)[:, 2] / longest ** 2

    before = quality(v, f)
    assert np.all(before > 0.0)
    fine_v, fine_f, _ = subdivide(v, f)
    assert np.all(quality(fine_v, fine_f) >= 0.49 * np.tile(before, 4))


def _bud(vertices: int) -> Prepared:
    """A 3-petal bud through the shell's axis stage (the band, s and x on the surface)."""
    from pipeline.flower.axis import find_axes
    from pipeline.flower.growth import assign_growth
    from pipeline.mesh import clean

    v, f, p = procedural.bud(3, 900, 0)
    v = v / clean.mean_edge_length(v, f)
    axes = find_axes(v, f, p, **axis_options(load_config(None, ()).__getitem__))
    return Prepared.of(v, f, p, axes, assign_growth(v, f, axes.x, "0.2*x**2"))


def test_the_finer_problem_keeps_the_coarse_one_in_its_first_rows():
    """refined: the coarse vertices, petals and (for each petal) base are the first rows;
    s and x found again on the finer mesh stay in range and near the coarse ones at the
    old vertices; the growth map covers the finer edges, by the growth curve."""
    cfg = load_config(None, ())
    coarse = _bud(180)
    fine = coarse.refined(2, {"curve": "0.2*x**2"}, axes=axis_options(cfg.__getitem__))
    n = len(coarse.vertices)
    assert len(fine.vertices) > 12 * n
    assert np.array_equal(fine.vertices[:n], coarse.vertices)
    assert np.array_equal(fine.petal[:n], coarse.petal)
    assert np.all((fine.s >= 0) & (fine.s <= 1)) and np.all(np.abs(fine.x) <= 1)
    assert np.abs(fine.s[:n] - coarse.s).max() < 0.1
    assert np.abs(np.abs(fine.x[:n]) - np.abs(coarse.x)).mean() < 0.1
    # the band of the same extent in s (0.08), to the nearest of rows 4 times closer
    for p in range(3):
        mine = fine.petal == p
        assert 0.06 <= fine.s[mine & fine.base].max() <= 0.1
    edges = topology.unique_edges(fine.faces)[0]
    assert np.array_equal(fine.edges, edges)
    edge_x = 0.5 * (fine.x[edges[:, 0]] + fine.x[edges[:, 1]])
    assert np.allclose(fine.alpha, 0.2 * edge_x ** 2)


def test_a_held_base_stays_held_on_the_finer_mesh():
    """A base held further (simulate's second try for a bowl) is held as far."""
    import dataclasses

    coarse = _bud(180)
    held = dataclasses.replace(coarse, base=coarse.base | (coarse.s <= 0.35), held=0.35)
    fine = held.refined(1, {"curve": "0.2*x**2"})
    assert np.all(fine.base[fine.s <= 0.35])


@pytest.mark.parametrize("per_petal, total, want", [(50, 300, 2), (200, 1200, 1), (300, 1800, 0),
                                                    (50, 1200, 1), (50, 3000, 0), (300, 300, 1),
                                                    (600, 600, 0)])
def test_levels_until_the_petals_hold_enough_within_the_budget(per_petal, total, want):
    """Cut until the median petal holds simulate.petal_vertices (500), within
    simulate.max_vertices (6000) in all; the paper's springs never, nor the dynamic
    integrators (their push-back is on every vertex)."""
    petal = np.repeat(np.arange(total // per_petal), per_petal)
    prep = Prepared(np.zeros((len(petal), 3)), np.zeros((0, 3), dtype=np.int64), petal,
                    *([None] * 12))
    assert levels_for(prep, load_config(None, ())) == want
    for off in ("simulate.model=paper", "simulate.integrator=semi-implicit",
                "simulate.petal_vertices=0"):
        assert levels_for(prep, load_config(None, (off,))) == 0


def _bloom(tmp_path, name: str, per_petal: int, *sets: str):
    """A procedural 3-petal bud through every stage, remeshed to ``per_petal`` vertices
    a petal, with ``--set`` overrides on simulate: sim.h5 (open) and the rest
    vertices."""
    from click.testing import CliRunner

    from stages.cli import cli

    v, f, p = procedural.bud(3, 900, 0)
    mesh = tmp_path / f"{name}.obj"
    procedural.write_obj(mesh, v, f, p, "a bud")
    out = {k: tmp_path / f"{name}_{k}.h5" for k in ("r", "a", "g", "s")}
    extra = [a for s in sets for a in ("--set", s)]
    for stage, src, dst, more in (("remesh", mesh, "r", ["--set", f"remesh.petal_vertices={per_petal}"]),
                                  ("axis", out["r"], "a", []), ("growth", out["a"], "g", []),
                                  ("simulate", out["g"], "s", extra)):
        result = CliRunner().invoke(cli, [stage, str(src), "--out", str(out[dst]), *more])
        assert result.exit_code == 0, result.output
    with h5py.File(out["g"]) as g:
        rest = {"vertices": g["mesh/vertices"][:], "s": g["axis/s"][:], "x": g["axis/x"][:]}
    return h5py.File(out["s"]), rest


def test_a_coarse_bud_blooms_as_its_fine_mesh_does_when_solved_finer(tmp_path):
    """A bud of 3 petals remeshed to 50 vertices each, solved twice finer (the default
    simulate.petal_vertices = 500), ends within 2.5 deg of the same bud remeshed to 800
    a petal (measured 1.6), less than half as far as solved as it is (6.75 deg); the
    frames are the coarse mesh's own vertices, the first the bud as given."""
    fine, _ = _bloom(tmp_path, "fine", 800)
    coarse, rest = _bloom(tmp_path, "coarse", 50)
    plain, _ = _bloom(tmp_path, "plain", 50, "simulate.petal_vertices=0")
    with fine, coarse, plain:
        assert "solved_on_vertices" not in fine.attrs and "solved_on_vertices" not in plain.attrs
        n = len(rest["vertices"])
        assert coarse.attrs["solved_on_vertices"] > 12 * n
        assert coarse["frames/positions"].shape[1] == n
        assert np.array_equal(coarse["frames/positions"][0], rest["vertices"])
        # the s and x the solve found on the finer mesh, at the coarse vertices: near the
        # axis stage's, not the same (s 0.011 apart at most, x 0.026 on average: measured),
        # x on the same side of each plane (a petal's flipped would be 1 apart on average)
        s, x = coarse["axis/s"][:], coarse["axis/x"][:]
        assert not np.array_equal(s, rest["s"]) and np.abs(s - rest["s"]).max() < 0.05
        assert np.abs(x - rest["x"]).mean() < 0.1
        assert np.array_equal(plain["axis/s"][:], rest["s"])
        want = fine["diagnostics/opening_angle"][-1]
        off = abs(coarse["diagnostics/opening_angle"][-1] - want)
        assert off < 2.5 and off < 0.5 * abs(plain["diagnostics/opening_angle"][-1] - want)


def test_a_bloom_that_stops_cut_finer_is_solved_again_as_it_is(tmp_path, monkeypatch):
    """Where the solve cut finer finds no equilibrium part way (contact pushes on the
    user's own vertices only, and the fine triangles around one can collapse: a bud
    remeshed to 200 vertices a petal stopped at A = 0.35 so), the bloom is solved again
    on the mesh as it is: the same frames as a run asked for that (simulate.petal_vertices
    = 0), and no record of a finer solve."""
    import dataclasses

    from pipeline.chain import problem as chain_problem

    real = chain_problem._problem
    asked = []

    def stops_when_fine(prep, job, ckpt, label=""):
        run = real(prep, job, ckpt, label)
        asked.append(len(prep.vertices))
        return dataclasses.replace(run, stopped=(0.35, 0)) if prep.contact_faces is not None \
            else run

    plain, _ = _bloom(tmp_path, "plain", 50, "simulate.petal_vertices=0")
    monkeypatch.setattr(chain_problem, "_problem", stops_when_fine)
    again, rest = _bloom(tmp_path, "again", 50)
    with plain, again:
        n = len(rest["vertices"])
        assert asked == [asked[0], n] and asked[0] > 12 * n  # cut finer, then as it is
        assert "solved_on_vertices" not in again.attrs
        assert np.array_equal(again["frames/positions"][:], plain["frames/positions"][:])


def _cupped_petal():
    """A coarse cupped petal (37 vertices, z = 0.3 x^2) whose base edge, bowed a little,
    ends at two corners turning just over OUTLINE_CORNER: ``(vertices, faces, the two
    corners)``."""
    from scipy.spatial import Delaunay

    a = np.radians(38.0)
    right = np.array([(0.15, 0.02), (0.15 + 0.2 * np.cos(a), 0.02 + 0.2 * np.sin(a)),
                      (0.42, 0.33), (0.47, 0.5), (0.45, 0.7), (0.38, 0.88), (0.25, 1.02)])
    outline = np.vstack([(0.0, 0.0), right, (0.0, 1.1), right[::-1] * [-1, 1]])
    gx, gy = np.meshgrid(np.linspace(-0.3, 0.3, 4), np.linspace(0.25, 0.9, 5))
    pts = np.vstack([outline, np.c_[gx.ravel(), gy.ravel()]])
    return np.c_[pts, 0.3 * pts[:, 0] ** 2], Delaunay(pts).simplices, [1, len(outline) - 1]


def test_a_coarse_outline_cut_finer_twice_keeps_its_base_corners():
    """Cut finer twice, the curve through a coarse rim rounds a base corner under
    OUTLINE_CORNER, and the base edge found by the turn on the finer mesh shrank to one
    vertex (a Poisson-disc bud's petals were clamped and measured from a point: 6.5 deg
    less open); with the coarse mesh's corners kept (outline_corners) it still runs
    between them."""
    from pipeline.flower.coords import base_edge
    from pipeline.mesh.remesh import OUTLINE_CORNER, corner_vertices, outline_corners

    v, f, ends = _cupped_petal()
    corners = outline_corners(v, f)
    assert corners[ends].all()
    for _ in range(2):
        v, f, parent = subdivide(v, f, corners)
        corners = np.concatenate([corners, np.zeros(len(parent), dtype=bool)])
    assert not corner_vertices(v, f, OUTLINE_CORNER)[ends].any()  # (rounded off)
    rim = topology.boundary_vertices(f, len(v))
    reach = 0.08 * np.ptp(v[:, 1])
    assert base_edge(v, f, rim, v[:, 1], reach).sum() == 1
    kept = base_edge(v, f, rim, v[:, 1], reach, corners)
    assert kept[ends].all() and kept.sum() > 4


def test_the_flowers_of_a_file_share_its_budget_of_vertices():
    """A file's flowers that are not copies share simulate.file_vertices (60,000) for
    their solves cut finer, each also within simulate.max_vertices: a branch of a thousand
    blossoms of 50 vertices is solved as meshed (each cut three times had 3,200, and the
    thousand took hours); ten flowers keep max_vertices' 6,000 each; 0 is no limit."""
    from pipeline.chain.flowers import _shared_budget
    from pipeline.chain.problem import Job

    petal = np.repeat(np.arange(5), 10)  # (a blossom of five 10-vertex petals)
    prep = Prepared(np.zeros((len(petal), 3)), np.zeros((0, 3), dtype=np.int64), petal,
                    *([None] * 12))

    def levels(problems: int, *sets: str) -> int:
        job = Job(load_config(None, sets), None, [], {}, False, False, "branch.glb")
        return levels_for(prep, job.cfg, _shared_budget(job, problems).max_vertices)

    assert levels(1) == 3  # alone: cut three times (3,200 vertices, 640 a petal)
    assert levels(10) == 3  # ten share 6,000 each: as alone
    assert levels(100) == 1  # 600 each: cut once (200; twice is 800)
    assert levels(1000) == 0  # 60 each: as meshed
    assert levels(1000, "simulate.file_vertices=0") == 3
    assert levels(1000, "simulate.file_vertices=6000000") == 3  # (6,000 each)
