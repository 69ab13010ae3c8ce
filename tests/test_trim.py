"""Petals whose bases are buried in other petals (a lotus modelled with its bases stuck into
the centre): the parts beyond a crossing toward the centre are cut away
(pipeline.mesh.trim), where moving the petals apart cannot part them."""

from __future__ import annotations

import numpy as np

from pipeline.mesh.ipc import ipctk
from pipeline.mesh.separate import crossings
from pipeline.mesh.trim import buried
from tests.test_separate import sheet


def _crossings_of(v, petal):
    def found(faces):
        E = np.asarray(ipctk().edges(np.asfortranarray(faces, dtype=np.int32)), dtype=np.int64)
        c = crossings(v, faces, E, petal)
        return np.column_stack([E[c[:, 0]], c[:, 1]])
    return found


def _area(v, f):
    return 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]),
                                axis=1).sum()


def stuck(base=-2.0):
    """Petal 0 lies flat (z = 0.1 x), from its buried base at y = ``base`` out to y = 10;
    petal 1 stands across it at y = 1 (x in [-5, 5], z in [-2, 6]). The flower's centre is
    the origin: petal 0's part under y = 1 is buried in petal 1, toward the centre."""
    pa, ta = sheet(-3, 3, base, 10, 0.5)
    pb, tb = sheet(-5, 5, -2, 6, 0.5)
    v = np.vstack([np.c_[pa, 0.1 * pa[:, 0]], np.c_[pb[:, 0], 1.0 + 0.02 * pb[:, 1], pb[:, 1]]])
    f = np.vstack([ta, tb + len(pa)])
    return v, f, np.repeat([0, 1], [len(pa), len(pb)])


def test_a_base_buried_in_another_petal_is_cut_away_at_the_crossing():
    v, f, p = stuck()
    centre = np.zeros((2, 3))
    assert len(_crossings_of(v, p)(f))
    out = buried(v, f, p, centre, _crossings_of(v, p))
    assert out.rounds == 1 and not len(_crossings_of(v, p)(f[out.keep]))
    # petal 0 loses its part under y = 1 (a quarter of it) and the row of faces the
    # crossing runs through, no more; petal 1, crossed in its middle, keeps every face
    assert 3.0 / 12.0 < out.lost[0] < 3.0 / 12.0 + 0.1 and out.lost[1] == 0.0
    kept = f[out.keep & (p[f[:, 0]] == 0)]
    assert v[kept][:, :, 1].min() > 0.9 and v[kept][:, :, 1].max() == v[p == 0, 1].max()
    assert np.isclose(_area(v, f[out.keep & (p[f[:, 0]] == 1)]), _area(v, f[p[f[:, 0]] == 1]))
    # the same faces every run
    assert np.array_equal(buried(v, f, p, centre, _crossings_of(v, p)).keep, out.keep)


def test_a_part_on_the_far_side_of_the_crossing_or_too_large_is_kept():
    """The same petals with the centre beyond the tip: what lies past the crossing is the
    far side, in view; and a base buried over half the petal is more than a trim."""
    v, f, p = stuck()
    far = buried(v, f, p, np.tile([0.0, 20.0, 0.0], (2, 1)), _crossings_of(v, p))
    assert not far.lost.any() and far.keep.all()
    v, f, p = stuck(base=-14.0)
    deep = buried(v, f, p, np.zeros((2, 3)), _crossings_of(v, p))
    assert not deep.lost.any()


def test_a_cut_petal_is_held_where_it_leaves_the_centre():
    """The rim the cut makes is the base `bloom axis` holds (remesh.h5's mesh/cut_rim):
    the band along it, whatever else says where the base lies (here axis.base = +y, the
    far end, which it is without the cut rim)."""
    from pipeline.flower.axis import find_axes
    from pipeline.mesh.topology import boundary_vertices

    v, f, p = stuck()
    out = buried(v, f, p, np.zeros((2, 3)), _crossings_of(v, p))
    mine = out.keep & (p[f[:, 0]] == 0)  # petal 0, cut at y = 1
    used = np.unique(f[mine])
    new = np.full(len(v), -1)
    new[used] = np.arange(len(used))
    faces = new[f[mine]]
    rim = boundary_vertices(f[p[f[:, 0]] == 0], len(v))[used]
    cut = boundary_vertices(faces, len(used)) & ~rim
    assert cut.sum() >= 3
    petal = np.zeros(len(used), dtype=np.int64)
    options = dict(base_region="band", base_fraction=0.08, surface=True, base_mode="+y")
    held = find_axes(v[used], faces, petal, held_rim=cut, **options)
    y = v[used][:, 1]
    assert held.base[cut].all() and y[held.base].max() < y.min() + 0.15 * np.ptp(y)
    assert y[held.tip[0]] > y.max() - 0.5  # the tip at the far end
    # (told that the base lies toward +y, with no cut rim the base is the far end)
    told = find_axes(v[used], faces, petal, **options)
    assert y[told.base].min() > y.max() - 0.15 * np.ptp(y)
