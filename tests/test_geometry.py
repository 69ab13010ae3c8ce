"""Geometry stages on procedural meshes: invariances under mirroring, permutation,
rotation and scaling; symmetry; the cross-section coordinate."""

import numpy as np
import pytest

from pipeline.flower.axis import find_axes
from pipeline.mesh import clean, procedural, symmetry, topology
from tests.conftest import prepared


def rotation(seed):
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def test_hinges_of_two_triangles_by_hand():
    faces = np.array([[0, 1, 2], [1, 0, 3]])
    h, e = topology.hinges(faces)
    assert h.tolist() == [[0, 1, 2, 3]]
    edges, _, count = topology.unique_edges(faces)
    assert edges[e[0]].tolist() == [0, 1] and count.tolist() == [2, 1, 1, 1, 1]
    with pytest.raises(ValueError, match="orientation"):
        topology.hinges(np.array([[0, 1, 2], [0, 1, 3]]))
    with pytest.raises(ValueError, match="non-manifold"):
        topology.hinges(np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]]))


def test_orientation_is_made_consistent():
    v, f, _ = procedural.bud(1, 120, 0)
    flipped = f.copy()
    flipped[::3] = flipped[::3][:, [0, 2, 1]]
    _, fixed, report = clean.clean_mesh(v, flipped)
    assert report.flipped_faces > 0
    topology.hinges(fixed)  # raises if any edge still runs the same way twice


def test_welding_merges_duplicates_and_drops_degenerate_faces():
    v, f, _ = procedural.bud(1, 120, 0)
    dup = np.concatenate([v, v[:5] + 1e-9])
    f2 = f.copy()
    f2[f2 < 5] += len(v)  # use the duplicates in some faces
    f2 = np.concatenate([f2[: len(f) // 2], f[len(f) // 2:], [[0, 0, 1]]])
    v3, f3, report = clean.clean_mesh(dup, f2)
    assert report.welded == 5 and report.degenerate_faces == 1
    assert len(v3) == len(v) and len(f3) == len(f)


def test_procedural_petals_are_mirror_symmetric():
    v, f, petal = procedural.bud(5, 1000, 2)
    for p in range(5):
        idx = np.flatnonzero(petal == p)
        plane, err = symmetry.mirror_plane(v[idx])
        assert err < 1e-9
        local = np.searchsorted(idx, f[np.isin(f[:, 0], idx)])
        assert symmetry.mirror_pairs(v[idx], plane, local) is not None


def test_symmetrize_makes_a_perturbed_petal_symmetric_to_1e9():
    v, f, _ = procedural.bud(1, 200, 0)
    v = v / clean.mean_edge_length(v, f)
    noisy = v + np.random.default_rng(0).normal(scale=0.01, size=v.shape)
    plane, before = symmetry.mirror_plane(noisy)
    partner = symmetry.mirror_pairs(noisy, plane, f)
    assert partner is not None and before > 1e-3
    sym = symmetry.symmetrize(noisy, plane, partner)
    np.testing.assert_allclose(symmetry.reflect(sym, plane)[partner], sym, atol=1e-9)
    assert symmetry.asymmetry(sym, plane) < 1e-9


def test_mirrored_input_mirrors_the_plane():
    v, f, petal, axes, _ = prepared(1, 200)
    m = v * [-1.0, 1.0, 1.0]
    mirrored = find_axes(m, f[:, [0, 2, 1]], petal)
    n0, n1 = axes.plane[0, :3], mirrored.plane[0, :3]
    assert abs(abs(n1 @ (n0 * [-1, 1, 1])) - 1.0) < 1e-9
    np.testing.assert_allclose(np.abs(mirrored.x), np.abs(axes.x), atol=1e-9)
    np.testing.assert_allclose(mirrored.s, axes.s, atol=1e-9)


def test_permuted_vertices_give_permuted_results():
    v, f, petal, axes, _ = prepared(1, 200)
    perm = np.random.default_rng(5).permutation(len(v))
    inverse = np.argsort(perm)
    moved = find_axes(v[perm], inverse[f], petal[perm])
    np.testing.assert_allclose(moved.s, axes.s[perm], atol=1e-12)
    np.testing.assert_allclose(np.abs(moved.x), np.abs(axes.x[perm]), atol=1e-12)
    assert np.array_equal(moved.base, axes.base[perm])
    assert inverse[axes.tip[0]] == moved.tip[0]


@pytest.mark.parametrize("petals", [1, 6])
def test_rotated_and_scaled_input_gives_the_same_x_and_s(petals):
    v, f, petal, axes, _ = prepared(petals, 300 * petals)
    R = rotation(petals)
    moved = find_axes(3.7 * v @ R.T + [10.0, -4.0, 2.0], f, petal)
    np.testing.assert_allclose(moved.s, axes.s, atol=1e-9)
    np.testing.assert_allclose(np.abs(moved.x), np.abs(axes.x), atol=1e-9)
    assert np.array_equal(moved.base, axes.base) and np.array_equal(moved.tip, axes.tip)


def test_cross_section_coordinate():
    v, f, petal, axes, _ = prepared(6, 1800)
    boundary = topology.boundary_vertices(f, len(v))
    rim = boundary & ~axes.base & ~axes.on_axis
    assert np.all(np.abs(axes.x[rim]) == 1.0)
    assert np.all(axes.x[axes.on_axis] == 0.0)
    assert np.all(np.abs(axes.x) <= 1.0)
    for p in range(6):
        mine = petal == p
        assert axes.x[mine].min() == -1.0 and axes.x[mine].max() == 1.0
        # mirror partners have opposite x
        idx = np.flatnonzero(mine)
        partner = symmetry.mirror_pairs(v[idx], axes.plane[p], None)
        np.testing.assert_allclose(axes.x[idx][partner], -axes.x[idx], atol=1e-9)
        # x grows from the axis toward the rim along a cross-section
        from scipy.stats import spearmanr

        dist = np.abs(v[mine] @ axes.plane[p, :3] - axes.plane[p, 3])
        s_bin = np.floor(axes.s[mine] * 8)
        for b in range(1, 7):  # within one cross-section, |x| orders like the distance
            here = s_bin == b
            assert spearmanr(np.abs(axes.x[mine][here]), dist[here]).statistic > 0.95


def test_bud_bases_are_found_next_to_the_flower_axis():
    v, f, petal, axes, _ = prepared(6, 1800)
    assert np.all(np.isfinite(axes.flower_axis))
    direction = axes.flower_axis[3:]
    assert abs(abs(direction[2]) - 1.0) < 1e-6  # the generator's axis is z
    radius = np.linalg.norm(v[:, :2], axis=1)
    assert radius[axes.base].max() < 0.15 * radius.max() + 3.0
    assert np.all(v[axes.base, 2] < v[axes.tip, 2].min())


def _with_sliver(interior: bool):
    """A 3x3-vertex grid sheet plus a sliver (height ~1e-8 of its edge): on the rim, a
    face hanging on a boundary edge; inside, a cap: the diagonal 0-4 bent through a point
    m next to its middle, the cap (0, m, 4) filling the gap (a valid manifold sheet)."""
    v = np.array([[x, y, 0.0] for y in range(3) for x in range(3)], dtype=float)
    f = []
    for y in range(2):
        for x in range(2):
            a = 3 * y + x
            f += [[a, a + 1, a + 4], [a, a + 4, a + 3]]
    m = len(v)
    if interior:
        v = np.vstack([v, [0.5 + 1e-8, 0.5 - 1e-8, 0.0]])
        f = [t for t in f if t != [0, 1, 4]] + [[0, 1, m], [m, 1, 4], [0, m, 4]]
        return v, np.array(f)
    v = np.vstack([v, [0.5, -1e-8, 0.0]])  # under the bottom boundary edge 0-1
    return v, np.array(f + [[0, m, 1]])


def test_rim_sliver_is_dropped_and_an_inner_one_kept_whole():
    from pipeline.mesh import clean, topology
    from pipeline.mesh.remesh import boundary_loops

    v, f = _with_sliver(interior=False)
    v2, f2, rep = clean.clean_mesh(v, f)
    assert rep.degenerate_faces == 1 and len(f2) == 8 and len(v2) == 9
    assert len(boundary_loops(f2)) == 1
    v, f = _with_sliver(interior=True)
    _, _, count = topology.unique_edges(f)
    assert count.max() == 2 and len(boundary_loops(f)) == 1
    v3, f3, rep = clean.clean_mesh(v, f)
    assert rep.degenerate_faces == 0 and len(f3) == len(f)  # the cap is kept ...
    assert len(boundary_loops(f3)) == 1  # ... so no slit is cut into the sheet


def test_sharp_ears_on_the_rim_are_dropped_in_mirror_pairs():
    """A needle and a flat cap hung on the rim of a sheet (each a face whose tip is in no
    other face) are dropped after a remesh, on both sides of the center plane alike; a
    sound ear and the rest of the sheet are kept."""
    from pipeline.mesh.remesh import drop_ears, triangle_angles

    xs = np.linspace(-1.0, 1.0, 5)
    v = np.array([(x, y, 0.0) for y in xs for x in xs])
    f = []
    for j in range(4):
        for i in range(4):
            a = 5 * j + i
            f += [(a, a + 1, a + 6), (a, a + 6, a + 5)]
    sheet = len(f)
    v = np.vstack([v, [(-0.75, -5.0, 0.0), (0.75, -5.0, 0.0),  # needles, a mirror pair
                       (-1.02, -0.25, 0.0), (1.02, -0.25, 0.0),  # flat caps, a pair
                       (0.25, 1.4, 0.0)]])  # a sound ear
    f = np.array(f + [(1, 0, 25), (4, 3, 26), (5, 10, 27), (14, 9, 28), (22, 23, 29)])
    angles = triangle_angles(v, f).min(axis=1)
    assert np.all(angles[sheet:sheet + 4] < 10.0) and angles[sheet + 4] > 10.0
    v2, f2, dropped = drop_ears(v, f)
    assert dropped == 4 and len(f2) == sheet + 1 and len(v2) == 26
    assert np.all(triangle_angles(v2, f2).min(axis=1) > 10.0)
    assert np.array_equal(v2, np.vstack([v[:25], v[29:]]))  # (both of each pair gone)


def test_compiled_edges_and_components_are_numpys_and_scipys():
    """The compiled edge list and component labels are, array for array, what
    np.unique of the edges' codes and scipy's connected components (relabelled by
    first vertex) give, on meshes with non-manifold edges, stray vertices and edges as
    cells."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    def by_numpy(f):
        key = np.sort(topology.half_edges(f)[0], axis=1)
        n = int(key.max()) + 1
        u, inverse, count = np.unique(key[:, 0] * n + key[:, 1], return_inverse=True,
                                      return_counts=True)
        return np.stack([u // n, u % n], axis=1), inverse.reshape(-1), count

    def by_scipy(cells, vertex_count):
        m = cells.shape[1]
        rows = np.concatenate([cells[:, k] for k in range(m)])
        cols = np.concatenate([cells[:, (k + 1) % m] for k in range(m)])
        graph = sp.coo_matrix((np.ones(rows.size), (rows, cols)),
                              shape=(vertex_count, vertex_count))
        _, labels = connected_components(graph, directed=False)
        _, first = np.unique(labels, return_index=True)
        rank = np.empty_like(first)
        rank[np.argsort(first)] = np.arange(first.size)
        return rank[labels]

    rng = np.random.default_rng(5)
    for _ in range(100):
        n = int(rng.integers(3, 60))
        f = rng.integers(0, n, (int(rng.integers(1, 90)), 3))
        for got, want in zip(topology.unique_edges(f), by_numpy(f), strict=True):
            np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(topology.components(f, n + 3), by_scipy(f, n + 3))
        e = f[:, :2]
        np.testing.assert_array_equal(topology.components(e, n), by_scipy(e, n))


def test_by_label_gives_each_values_indices_as_a_mask_would():
    """topology.by_label: one sort, the same indices (ascending) as ``flatnonzero(label ==
    k)`` for every value, empty for a value absent."""
    label = np.random.default_rng(3).integers(0, 6, 200)
    label[label == 4] = 5  # (4 absent)
    groups = topology.by_label(label, 7)
    assert len(groups) == 7
    for k, idx in enumerate(groups):
        assert np.array_equal(idx, np.flatnonzero(label == k))
    assert len(groups[4]) == 0 and len(groups[6]) == 0
