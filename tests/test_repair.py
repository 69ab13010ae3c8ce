"""pipeline.mesh.repair, function by function, on small meshes made by hand."""

from __future__ import annotations

import numpy as np

from pipeline.mesh import repair, topology


def bowtie():
    """Two triangles that share only vertex 0."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0.0]])
    return v, np.array([[0, 1, 2], [0, 3, 4]])


def square():
    """A unit square of two triangles in z = 0, diagonal (0, 2)."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]])
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def test_corner_fans_tell_a_bowtie_from_a_sheet():
    v, f = bowtie()
    fan = repair.corner_fans(f)
    assert fan[0] != fan[1]  # vertex 0 of face 0 and of face 1: two fans
    _, f = square()
    fan = repair.corner_fans(f)
    assert fan[0] == fan[1]  # vertex 0 of both faces: linked through edge (0, 2)


def test_split_fans_gives_each_fan_its_own_vertex():
    v, f = bowtie()
    out_v, out_f, copies = repair.split_fans(v, f)
    assert copies == 1 and len(out_v) == 6
    np.testing.assert_array_equal(out_f[0], f[0])  # the first fan keeps the index
    assert out_f[1, 0] == 5 and np.all(out_v[5] == v[0])
    assert topology.components(out_f, len(out_v)).max() == 1  # two pieces now
    v, f = square()
    assert repair.split_fans(v, f)[2] == 0


def test_a_fin_is_dropped_and_the_sheet_kept():
    v, f = square()
    # a fin standing on the diagonal, and one more flap folded back over face 0
    v = np.vstack([v, [0.5, 0.5, 1.0], [0.9, 0.1, 0.05]])
    f = np.vstack([f, [[0, 2, 4]], [[2, 0, 5]]])
    out, dropped = repair.resolve_nonmanifold_edges(v, f)
    assert dropped == 2
    np.testing.assert_array_equal(out, f[:2])  # the flat pair goes on straight


def test_a_manifold_sheet_is_left_alone():
    v, f = square()
    out, dropped = repair.resolve_nonmanifold_edges(v, f)
    assert dropped == 0 and np.array_equal(out, f)


def slit_grid(gap):
    """A 4 x 4 grid of unit squares cut along x = 2 from y = 0 up to y = 2: the cut's
    lips are two columns of vertices ``gap`` apart (the right one moved), meeting at the
    slit's end (2, 2)."""
    n = 5
    v = [(x, y, 0.0) for y in range(n) for x in range(n)]
    idx = {(x, y): y * n + x for y in range(n) for x in range(n)}
    lip = {}
    for y in range(2):  # a copy of (2, y) for the right-hand squares
        lip[(2, y)] = len(v)
        v.append((2.0 + gap, float(y), 0.0))
    f = []
    for y in range(n - 1):
        for x in range(n - 1):
            corner = [(x, y), (x + 1, y), (x + 1, y + 1), (x, y + 1)]
            k = [lip[c] if x == 2 and c in lip else idx[c] for c in corner]
            f += [(k[0], k[1], k[2]), (k[0], k[2], k[3])]
    return np.array(v), np.array(f)


def test_zip_slits_closes_a_slit_and_leaves_a_sheet_alone():
    v, f = slit_grid(0.002)
    # the rim's 16, the lips' two copies, and (2, 1) and the slit's end (2, 2)
    assert topology.boundary_vertices(f, len(v)).sum() == 16 + 2 + 2
    out_v, out_f, merged = repair.zip_slits(v, f)
    assert merged == 2 and len(out_v) == 25
    assert topology.boundary_vertices(out_f, len(out_v)).sum() == 16  # the slit's end is inside
    _, _, count = topology.unique_edges(out_f)
    assert count.max() == 2 and len(out_f) == len(f)
    v, f = slit_grid(0.2)  # lips 0.2 edges apart: a gap in the outline, not a slit
    assert repair.zip_slits(v, f)[2] == 0
