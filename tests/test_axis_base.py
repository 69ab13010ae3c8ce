"""The axis stage never hands a petal held on a line downstream: such a base is widened
to MIN_BASE_WIDTH (a petal on a line of fixed vertices can spin about it), or refused
in one line; the project's own buds keep their bases."""

import numpy as np
import pytest
from click.testing import CliRunner

from pipeline.flower import axis
from pipeline.flower.axis import MIN_BASE_WIDTH, WeakBase, base_width, find_axes
from pipeline.mesh import clean, procedural
from pipeline.studies import stability


def cupped_petal(rows: int = 14, cols: int = 8, cup: float = 0.6):
    """A quad-grid petal cupped across (z = cup u^2 s) whose base row (s = 0) lies
    exactly on the x axis: fixing it holds the petal on a line. Mean edge 1."""
    pts, f = stability.quad_petal(rows, cols, seed=0)
    u, s = pts[:, 0], pts[:, 1]
    v = np.stack([u, s, cup * u ** 2 * s], axis=1)
    return v / clean.mean_edge_length(v, f), f


def test_base_width_is_scale_free_and_zero_on_a_line():
    v, _ = cupped_petal()
    row = v[:9]  # the base row, on the x axis
    assert base_width(row, v) == 0.0
    tri = v[[0, 8, 9 + 4]]  # the row's ends and a vertex of the next row
    w = base_width(tri, v)
    assert w > 0.01
    assert base_width(1e-3 * tri, 1e-3 * v) == pytest.approx(w, rel=1e-12)
    assert base_width(1e3 * tri + 5.0, 1e3 * v + 5.0) == pytest.approx(w, rel=1e-9)


def test_a_base_on_a_line_is_widened_near_the_base_end():
    v, f = cupped_petal()
    p = np.zeros(len(v), dtype=np.int64)
    axes = find_axes(v, f, p)
    base = np.flatnonzero(axes.base)
    assert base_width(v[:9], v) == 0.0  # what the old rule fixed: the straight row alone
    assert set(range(9)) <= set(base)  # the row is still fixed ...
    assert base_width(v[base], v) >= MIN_BASE_WIDTH  # ... with enough off it to hold it
    # widened by the nearest vertices only: all within the first rows, few added
    assert v[base, 1].max() <= 2.5 / 14 * np.ptp(v[:, 1])
    assert len(base) <= 9 + 4
    assert axes.widened == (0,)


def test_a_base_that_cannot_be_widened_is_refused_in_one_line(tmp_path, monkeypatch):
    from stages.cli import cli

    v, f = cupped_petal()
    p = np.zeros(len(v), dtype=np.int64)
    monkeypatch.setattr(axis, "BASE_REACH", 0.0)  # only base_fraction's reach (< one row)
    with pytest.raises(WeakBase, match="petal 0's base is a line"):
        find_axes(v, f, p, base_fraction=0.04)
    mesh = tmp_path / "flatbase.obj"
    procedural.write_obj(mesh, v, f, p, "a petal whose base row is straight")
    runner = CliRunner()
    remesh = tmp_path / "remesh.h5"
    r = runner.invoke(cli, ["-q", "remesh", str(mesh), "--out", str(remesh), "--set",
                            "remesh.symmetrize=false"])
    assert r.exit_code == 0, r.output
    out = tmp_path / "axis.h5"
    r = runner.invoke(cli, ["axis", str(remesh), "--out", str(out), "--set",
                            "axis.base_fraction=0.01", "--set", "axis.base_region=rim"])
    line = r.output.strip()
    assert r.exit_code != 0 and len(line.splitlines()) == 1 and "Traceback" not in line, line
    for words in ("axis.base_fraction", "petal 0", "base is a line", "spin about"):
        assert words in line, line
    assert not out.exists()


@pytest.mark.parametrize("petals,vertices", [(1, 320), (6, 1200), (5, 2000)])
def test_the_project_buds_keep_their_bases(petals, vertices, monkeypatch):
    """The widening never triggers on procedural.bud: the same base as without it."""
    v, f, p = procedural.bud(petals, vertices, 0)
    v = v / clean.mean_edge_length(v, f)
    now = find_axes(v, f, p)
    monkeypatch.setattr(axis, "MIN_BASE_WIDTH", 0.0)  # the rule before widening
    before = find_axes(v, f, p)
    assert np.array_equal(now.base, before.base) and now.widened == ()
    for k in range(petals):
        assert base_width(v[now.base & (p == k)], v[p == k]) >= 2 * MIN_BASE_WIDTH


def test_in_a_file_of_many_flowers_a_base_on_a_line_is_held_not_refused(monkeypatch):
    """One blossom of a thousand whose base cannot be widened does not stop the file: with
    ``hold_bad`` (a file of many flowers) it is held as modelled and named, the other
    flower's axes are what they are alone; without it, it is refused as before."""
    v, f = cupped_petal()
    monkeypatch.setattr(axis, "BASE_REACH", 0.0)
    good = procedural.bud(1, 200, 0)
    shift = np.array([0.0, 0.0, 60.0])
    both_v = np.vstack([good[0], v + shift])
    both_f = np.vstack([good[1], f + len(good[0])])
    petal = np.r_[np.zeros(len(good[0]), dtype=np.int64), np.ones(len(v), dtype=np.int64)]
    flower = np.array([0, 1])
    with pytest.raises(WeakBase, match="petal 1's base is a line"):
        find_axes(both_v, both_f, petal, flower=flower, base_fraction=0.04)
    axes = find_axes(both_v, both_f, petal, flower=flower, base_fraction=0.04, hold_bad=True)
    assert [p for p, _ in axes.held] == [1] and "base is a line" in axes.held[0][1]
    mine = petal == 1
    assert axes.base[mine].all() and np.all(axes.s[mine] == 0.0)
    alone = find_axes(*good, base_fraction=0.04)
    for name in ("base", "on_axis", "s", "x"):
        assert np.array_equal(getattr(axes, name)[~mine], getattr(alone, name)), name
