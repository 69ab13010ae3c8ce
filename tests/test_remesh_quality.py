"""The remesh stage's quality bound: after remesh and symmetrize every petal has no
degenerate and no inverted triangle and no angle under remesh.MIN_ANGLE away from sharp
rim corners, is mirror-symmetric (or reported unsymmetrized), and is never refused."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.flower.petals import prepare_parts
from pipeline.io.meshfile import read_mesh, read_parts
from pipeline.mesh import procedural, remesh, symmetry
from pipeline.studies import stability
from tests.conftest import SHARED, prepare

EXTERNAL = SHARED / "external-meshes"
needs_shared = pytest.mark.skipif(not EXTERNAL.exists(), reason="../shared/external-meshes absent")


def hexagon(center=(0.0, 0.0)):
    """Six triangles around a centre vertex: equilateral when the centre is at the origin."""
    ring = [(np.cos(a), np.sin(a), 0.0) for a in np.radians(np.arange(0, 360, 60))]
    v = np.vstack([[*center, 0.0], ring])
    f = np.array([(0, 1 + k, 1 + (k + 1) % 6) for k in range(6)])
    return v, f


# --- the measure, by hand ----------------------------------------------------------------

def test_one_equilateral_triangle_measures_60_degrees():
    v = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, np.sqrt(3.0) / 2.0, 0.0]])
    assert remesh.quality(v, np.array([[0, 1, 2]])) == pytest.approx(60.0)
    assert remesh.quality(*hexagon()) == pytest.approx(60.0)


def test_a_sliver_is_detected():
    v, f = hexagon(center=(0.0, -0.84))  # the centre almost on the rim edge below it
    assert remesh.quality(v, f) < 5.0 < remesh.MIN_ANGLE
    v[0, 1] = -np.sqrt(3.0) / 2.0  # exactly on it: two faces of zero area
    assert remesh.quality(v, f) == 0.0


def test_a_flipped_and_a_folded_triangle_are_detected():
    v, f = hexagon()
    flipped = f.copy()
    flipped[2] = flipped[2, [0, 2, 1]]
    assert remesh.inverted_faces(v, flipped).tolist() == [False, True, True, True, False, False]
    assert remesh.quality(v, flipped) == 0.0
    folded = v.copy()
    folded[0] = [0.0, -1.2, 0.0]  # the centre pushed out past a rim edge: its face turns over
    assert remesh.inverted_faces(folded, f).any() and remesh.quality(folded, f) == 0.0


def test_a_sharp_rim_corner_is_excepted_and_only_there():
    # a thin isosceles triangle between two fat ones: its 10 deg tip is a corner of the rim
    tip = np.radians(10.0)
    v = np.array([[0, 0, 0], [np.cos(tip / 2), np.sin(tip / 2), 0], [np.cos(tip / 2), -np.sin(tip / 2), 0],
                  [1.2, 0.0, 0.0]], dtype=float)
    f = np.array([[0, 2, 1], [1, 2, 3]])
    assert remesh.corner_angles(v, f)[0].tolist() == [True, False, False]
    assert remesh.quality(v, f) == pytest.approx(
        min(remesh.triangle_angles(v, f)[0, 1:].min(), remesh.triangle_angles(v, f)[1].min()))
    assert remesh.triangle_angles(v, f).min() < 11.0 < remesh.quality(v, f)


def test_the_edge_ratio_is_the_shortest_over_the_mean_edge():
    v, f = hexagon()  # 12 edges of length 1
    assert remesh.edge_ratio(v, f) == pytest.approx(1.0)
    v[1] = 0.1 * v[1]  # one spoke 0.1 long; two ring edges stretch
    e = np.linalg.norm(v[[1, 1, 2, 3, 4, 5, 6]] - v[[0, 2, 3, 4, 5, 6, 1]], axis=1)
    mean = (e.sum() + 5.0) / 12.0
    assert remesh.edge_ratio(v, f) == pytest.approx(0.1 / mean)
    assert not remesh.meets_bound(v, f) and remesh.meets_bound(*hexagon())


def ear_strip(step):
    """A 6 x 1 strip whose right end has rim vertex 7 ``step`` above corner 6."""
    x = np.arange(7.0)
    v = np.array([(k, 0.0, 0.0) for k in x] + [(6.0, step, 0.0)]
                 + [(k, 1.0, 0.0) for k in x[::-1]])  # bottom 0-6, 7, top 8 (x=6) - 14 (x=0)
    f = [(k, k + 1, 13 - k) for k in range(5)] + [(k, 13 - k, 14 - k) for k in range(5)]
    return v, np.array(f + [(5, 6, 7), (5, 7, 8), (5, 8, 9)])


def test_a_short_rim_edge_at_a_corner_is_collapsed():
    """A corner (it never moves) whose next rim vertex is 0.07 h away, the short edge's
    triangle an ear (its third vertex is the corner's other rim neighbour): the short
    edge goes and the corner stays. Before, an ear was never collapsed, and a petal tip
    kept triangles 13x smaller than the rest, which flattened in the simulation."""
    v, f = ear_strip(0.07)
    assert remesh.corner_vertices(v, f)[6] and remesh.edge_ratio(v, f) < 0.1
    out_v, out_f, _ = remesh.resample_boundary(v, f, 1.0)
    assert remesh.edge_ratio(out_v, out_f) > 0.5
    assert np.any(np.all(out_v == v[6], axis=1)) and remesh.quality(out_v, out_f) > 40.0


def test_a_notch_between_two_corners_below_the_resolution_is_collapsed():
    """Two rim corners 0.06 h apart (a torn rim: hallgeirl's mid-surfaces kept one, and a
    3.5 deg triangle with it) merge at the middle of their edge; corners MIN_EDGE h apart
    or more are a feature of the outline and stay; an end the caller pinned (a mirror
    seam's end) keeps its place; two pinned ends both stay."""
    v, f = ear_strip(0.06)
    both = np.zeros(len(v), dtype=bool)
    both[[6, 7]] = True  # both corners
    none = np.zeros(len(v), dtype=bool)
    out_v, out_f, _, _, n = remesh._collapse_short(v, f, both.copy(), 1.0, none)
    assert n >= 1 and remesh.edge_ratio(out_v, out_f) > 0.5
    assert np.any(np.all(out_v == [6.0, 0.03, 0.0], axis=1))
    seam = none.copy()
    seam[7] = True
    out_v, _, _, _, _ = remesh._collapse_short(v, f, both.copy(), 1.0, seam)
    assert np.any(np.all(out_v == v[7], axis=1)) and not np.any(np.all(out_v == v[6], axis=1))
    kept = remesh._collapse_short(v, f, both.copy(), 1.0, both.copy())[0]
    assert np.any(np.all(kept == v[6], axis=1)) and np.any(np.all(kept == v[7], axis=1))
    v, f = ear_strip(0.3)  # 0.3 h: a feature
    kept = remesh._collapse_short(v, f, both.copy(), 1.0, none)[0]
    assert np.any(np.all(kept == v[6], axis=1)) and np.any(np.all(kept == v[7], axis=1))


def test_a_flat_needle_on_the_rim_is_clipped():
    """A 4 x 2 grid with one more face on its rim: an ear whose tip lies almost on the
    rim's line, 4 edges out (a needle that a thick petal's mid-surface left: 173.8 deg
    at its base on pchinyun's petal, which then flattened in the simulation). No move,
    collapse or split mends it: improve drops it, tip and all, and the grid is left as
    it was, its faces meeting the bound."""
    x, y = np.meshgrid(np.arange(5.0), np.arange(3.0), indexing="ij")
    v = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    idx = np.arange(15).reshape(5, 3)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    grid = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    p, q = idx[3, 0], idx[4, 0]  # a rim edge along y = 0
    v = np.vstack([v, [8.0, -0.2, 0.0]])
    f = np.vstack([grid, [[q, p, 15]]])
    assert remesh.quality(v, f) < 5.0
    out_v, out_f, _, _ = remesh.improve(v, f)
    assert len(out_v) == 15 and not np.any(np.all(out_v == [8.0, -0.2, 0.0], axis=1))
    assert remesh.quality(out_v, out_f) >= remesh.MIN_ANGLE


def test_the_measure_does_not_depend_on_the_units():
    v, f, _ = stability.MESHES["asymmetric bud6"]()
    assert remesh.quality(v, f) == pytest.approx(remesh.quality(4.5e-3 * v, f), abs=1e-9)


# --- every generator and real mesh -------------------------------------------------------

def check(result):
    """The bound, per petal; returns the smallest angle."""
    worst = []
    for p in range(int(result.petal.max()) + 1):
        idx = np.flatnonzero(result.petal == p)
        faces = np.searchsorted(idx, result.faces[np.isin(result.faces[:, 0], idx)])
        v = result.vertices[idx]
        assert not remesh.inverted_faces(v, faces).any(), p
        worst.append(remesh.quality(v, faces))
        assert worst[-1] >= remesh.MIN_ANGLE, (p, worst[-1], result.notes)
        assert remesh.edge_ratio(v, faces) >= remesh.MIN_EDGE, (p, result.notes)
        if p not in result.unsymmetrized:  # mean edge is 1: relative to it
            assert result.asymmetry_after[p] < 1e-9, (p, result.asymmetry_after[p])
    np.testing.assert_allclose(result.min_angle, worst, rtol=0, atol=1e-9)  # before the last rescale
    return min(worst)


GENERATORS = ["petal", "bud6", "quad petal", "quad bud6", "jittered", "asymmetric bud6", "quad bud12",
              "bud5 5000", "three-vertex base", "centimetres", "skinny", "duplicates"]


@pytest.mark.parametrize("name", GENERATORS)
def test_every_generator_meets_the_bound_symmetric_and_unrefused(name):
    v, f, _ = stability.MESHES[name]()
    check(prepare(v, f, where=name))


@needs_shared
@pytest.mark.parametrize("name", ["chianti_petal1", "chianti_flower5", "souki202_petal"])
def test_real_meshes_meet_the_bound(name):
    v, f = read_mesh(EXTERNAL / f"{name}.obj")
    check(prepare(v, f, where=name))


@needs_shared
def test_thick_petals_with_torn_mid_surfaces_meet_the_bound():
    """hallgeirl's 14 tube petals: 11 of their mid-surfaces have a slit (zipped) and notches
    0.07 edge long (collapsed); two petals whose mirrored remesh kept an angle of 18 deg
    are remeshed unsymmetrized instead. Before, 9 of 14 missed the bound (down to 1.2 deg
    and 0.01 of the mean edge) and the simulation gained energy."""
    result = prepare_parts(read_parts(EXTERNAL / "hallgeirl_petals.obj"), where="hallgeirl")
    assert result.petal.max() + 1 == 14
    check(result)
    assert sum("closed a slit" in n for n in result.notes) == 11


@needs_shared
def test_a_thick_petal_whose_remesh_left_needles_on_its_rim_meets_the_bound():
    """pchinyun's solidified petal: its mid-surface, remeshed, kept needles on the rim
    (single faces down to 4.2 deg away from their tips, bases 0.09 of the mean edge);
    improve clips them and a second remesh collapses their bases. Before, the petal left
    remesh below the bound and the default simulation failed at growth 0.045."""
    result = prepare_parts(read_parts(EXTERNAL / "pchinyun_petal.obj"), where="pchinyun")
    assert result.petal.max() + 1 == 1
    check(result)


def test_quad_petals_are_cut_remeshed_and_mirrored_and_say_so():
    v, f, _ = stability.MESHES["quad petal"]()
    result = prepare(v, f, where="quad.obj")
    assert len(result.notes) == 1 and "triangles below 20 deg (min 10.8 deg)" in result.notes[0]
    assert "cut along its center plane, remeshed at edge" in result.notes[0], result.notes
    assert result.edge_target[0] > 0


def test_a_passing_mirror_paired_petal_is_left_as_it_is():
    v, f, _ = procedural.bud(1, 320, 0)
    assert remesh.quality(v, f) >= remesh.MIN_ANGLE
    result = prepare(v, f, where="petal.obj")
    assert result.notes == [] and result.edge_target[0] == 0
    np.testing.assert_array_equal(result.faces, f)
    plane = result.plane[0]
    partner = symmetry.mirror_pairs(v * result.scale, plane, f)
    expect = symmetry.symmetrize(v * result.scale, plane, partner)
    np.testing.assert_allclose(result.vertices, expect, rtol=0, atol=1e-12)


def test_a_petal_that_cannot_be_mirrored_is_kept_fixed_and_listed(monkeypatch):
    def refuse(*args, **kwargs):
        raise ValueError("the petal lies on one side of its center plane")

    monkeypatch.setattr(symmetry, "mirrored_mesh", refuse)
    v, f, _ = stability.MESHES["quad bud6"]()
    result = prepare(v, f, where="quad.obj")
    assert result.unsymmetrized == list(range(6))
    assert sum("warning: cannot be mirrored" in n for n in result.notes) == 6
    check(result)


def test_remesh_is_reproducible_and_unit_free():
    v, f, _ = stability.MESHES["asymmetric bud6"]()
    a = prepare(v, f, where="m")
    b = prepare(v.copy(), f.copy(), where="m")
    assert a.vertices.tobytes() == b.vertices.tobytes() and a.faces.tobytes() == b.faces.tobytes()
    cm = prepare(100.0 * v, f, where="cm")
    np.testing.assert_array_equal(cm.faces, a.faces)
    np.testing.assert_allclose(cm.vertices, a.vertices, rtol=0, atol=1e-9)
    assert cm.scale == pytest.approx(a.scale / 100.0)


def test_ends_of_a_mirror_cut_closer_than_a_quarter_edge_are_one_end():
    """The half of a petal cut at its center plane (first coordinate 0 along the cut) whose
    cut has three held ends within 0.01 h of one another at the tip (a rim that zigzags
    across the plane there: the lotus's petal 7, whose mirrored tip kept edges 0.01 of
    the mean and was refused at growth as a degenerate rest state): the remesh holds the
    first of them only, so the tip's edges are of the mesh's size."""
    from scipy.spatial import Delaunay

    from pipeline.flower.petals import _remesh_half

    u, y = np.meshgrid(np.linspace(0.0, 1.0, 5), np.linspace(0.0, 3.0, 13), indexing="ij")
    flat = np.column_stack([u.ravel(), y.ravel()])
    flat = np.vstack([[[0.0, 3.0], [0.0, 0.0], [0.0, 2.99], [0.0, 2.995]],
                      flat[~((flat[:, 0] == 0.0) & np.isin(flat[:, 1], [0.0, 3.0]))]])
    v = np.column_stack([flat, np.zeros(len(flat))])
    f = Delaunay(flat).simplices.astype(np.int64)
    turned = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])[:, 2] < 0
    f[turned] = f[turned][:, [0, 2, 1]]
    held = np.zeros(len(v), dtype=bool)
    held[:4] = True
    assert remesh.edge_ratio(v, f) < 0.05
    out_v, out_f, out_held = _remesh_half(0.25)(v, f, held)
    assert remesh.edge_ratio(out_v, out_f) >= remesh.MIN_EDGE
    assert np.any(np.all(out_v == [0.0, 3.0, 0.0], axis=1))  # the first end is held
    assert np.all(out_v[:, 0] >= 0.0)


def test_a_fold_on_the_rim_is_dropped_with_the_faces_around_it():
    """A rim vertex pushed along the rim past its neighbour folds a face over the others (a
    mirrored tip that crumpled): those faces and the ones sharing a vertex with them go,
    and no vertex is left without a face; a sheet with no fold comes back as it was."""
    from tests.test_separate import sheet

    pts, tri = sheet(0, 6, 0, 6)
    v = np.c_[pts, np.zeros(len(pts))]
    assert remesh.drop_rim_folds(v, tri)[2] == 0
    rim = int(np.argmin(np.abs(v[:, 0] - 3.0) + v[:, 1]))  # (3, 0): the bottom rim's middle
    v[rim, :2] = [1.5, 0.2]  # past its rim neighbour at (2, 0): its face there turns over
    assert remesh.inverted_faces(v, tri).any()
    out, faces, dropped = remesh.drop_rim_folds(v, tri)
    # (the fold and the faces around it; with the faces that pass through the sheet: 16)
    assert 0 < dropped <= 18 and len(faces) == len(tri) - dropped
    assert not remesh.inverted_faces(out, faces).any()
    assert np.array_equal(np.unique(faces), np.arange(len(out)))


def test_a_flap_that_hangs_on_the_sheet_by_a_vertex_is_dropped():
    """Two faces joined to a sheet at one corner vertex and no edge (what dropping a rim
    fold left on the lotus's petal 11, 0.002 edges from its neighbour): the sheet's edge-
    joined pieces are two, and the flap goes with its own vertices; the sheet itself and a
    piece too large to be a flap are left."""
    from pipeline.mesh import topology
    from tests.test_separate import sheet

    pts, tri = sheet(0, 6, 0, 6)
    v = np.c_[pts, np.zeros(len(pts))]
    assert remesh.drop_flaps(v, tri)[2] == 0
    corner = int(np.argmin(np.linalg.norm(v - [6.0, 6.0, 0.0], axis=1)))
    flap = np.array([[6.2, 6.1, 0.0], [6.3, 6.4, 0.0], [6.0, 6.3, 0.0]])
    n = len(v)
    f = np.r_[tri, [[corner, n, n + 1], [corner, n + 1, n + 2]]]
    w = np.r_[v, flap]
    piece = topology.face_components(f)
    assert piece.max() == 1 and np.sum(piece == 1) == 2
    out, faces, dropped = remesh.drop_flaps(w, f)
    assert dropped == 2 and len(faces) == len(tri) and len(out) == len(v)
    assert np.array_equal(out, v)
    # a second sheet as large as the first, joined at the same corner: not a flap
    big = np.r_[tri, tri + len(v)]
    twice = np.r_[v, v + [6.0, 6.0, 0.0]]
    twice_faces = np.where(big == len(v) + int(np.argmin(np.linalg.norm(v, axis=1))), corner, big)
    assert topology.face_components(twice_faces).max() == 1
    assert remesh.drop_flaps(twice, twice_faces)[2] == 0


def test_a_rim_tucked_through_the_sheet_is_dropped_though_no_face_turns_over():
    """A rim strip folded back over the sheet, a little past flat at one end and short of
    it at the other, so it passes through the sheet between (what the mid-surface of a
    fused solid, an OpenSCAD union of petals, gave one petal): no face is inverted against
    its neighbours (the strip's faces neighbour each other), but the sheet passes through
    itself; the faces that cross, and those around them, are dropped and the sheet no
    longer crosses itself."""
    from tests.test_separate import sheet

    pts, tri = sheet(0, 6, 0, 6)
    v = np.c_[pts, np.zeros(len(pts))]
    hinge = np.unique(np.round(v[:, 1], 9))[1]
    rim = v[:, 1] < 1e-9
    turn = np.radians(170.0 + 20.0 * v[rim, 0] / 6.0)
    depth = hinge - v[rim, 1]
    v[rim, 1] = hinge - depth * np.cos(turn)
    v[rim, 2] = -depth * np.sin(turn)
    assert not remesh.inverted_faces(v, tri).any()
    assert remesh.self_crossed_faces(v, tri).any()
    out, faces, dropped = remesh.drop_rim_folds(v, tri)
    assert 0 < dropped <= 16 and len(faces) == len(tri) - dropped
    assert not remesh.self_crossed_faces(out, faces).any()
    assert not remesh.self_crossed_faces(np.c_[pts, np.zeros(len(pts))], tri).any()
