"""The block LDL^T of the quasi-static solver (pipeline/sim/ldl.py) against dense
linear algebra: solves, inertia, directions of negative curvature, pattern reuse."""

import numpy as np
import pytest
import scipy.sparse as sp

from pipeline.sim.ldl import BlockLDL


def _random_spd_pattern(nv: int, seed: int, shift: float):
    """A symmetric matrix on a random vertex graph (3x3 blocks), upper triangle."""
    rng = np.random.default_rng(seed)
    edges = rng.integers(0, nv, size=(3 * nv, 2))
    edges = edges[edges[:, 0] != edges[:, 1]]
    rows, cols = [], []
    for a, b in np.vstack([edges, np.c_[np.arange(nv), np.arange(nv)]]):
        for i in range(3):
            for j in range(3):
                rows.append(3 * a + i)
                cols.append(3 * b + j)
    A = sp.coo_matrix((rng.standard_normal(len(rows)), (rows, cols)), shape=(3 * nv,) * 2)
    A = (A + A.T).toarray() + shift * np.eye(3 * nv)
    return sp.triu(sp.csc_matrix(A), format="csc"), A


@pytest.mark.parametrize("shift", [0.0, 8.0, 40.0])
def test_solve_and_inertia_match_dense_algebra(shift):
    upper, full = _random_spd_pattern(60, 3, shift)
    f = BlockLDL(upper)
    b = np.random.default_rng(0).standard_normal(full.shape[0])
    x = f.solve(b)
    assert np.linalg.norm(full @ x - b) <= 1e-10 * np.linalg.norm(full, 2) * np.linalg.norm(x)
    eig = np.linalg.eigvalsh(full)
    assert int((f.d < 0).sum()) == int((eig < 0).sum())  # Sylvester's law of inertia
    assert int((f.d > 0).sum()) == int((eig > 0).sum())


def test_curvature_direction_has_the_pivot_as_its_curvature():
    upper, full = _random_spd_pattern(50, 5, 2.0)
    f = BlockLDL(upper)
    assert (f.d < 0).any()
    k = int(np.argmin(f.d))
    z = f.curvature_direction(k)
    assert z @ full @ z == pytest.approx(f.d[k], rel=1e-9)
    assert z @ full @ z < 0.0


def test_update_refactors_on_the_same_pattern_as_a_new_analysis():
    upper, full = _random_spd_pattern(40, 7, 30.0)
    f = BlockLDL(upper)
    other = upper.copy()
    other.data = other.data * 1.5 + 0.25 * (other.indices == np.repeat(
        np.arange(upper.shape[0]), np.diff(upper.indptr)))
    f.update(other)
    g = BlockLDL(other)
    b = np.arange(upper.shape[0], dtype=float)
    assert np.array_equal(f.solve(b), g.solve(b))  # the same arithmetic, to the bit
    assert np.array_equal(f.d, g.d)


def test_zero_pivot_is_refused():
    upper, _ = _random_spd_pattern(10, 1, 30.0)
    upper = upper.tolil()
    upper[0, :] = 0.0
    with pytest.raises(ValueError, match="zero pivot"):
        BlockLDL(sp.csc_matrix(upper))


def test_fill_is_that_of_a_minimum_degree_ordering():
    """A 2D grid of vertices: the ordering keeps the factor's fill near n log n (the
    natural order's bandwidth would give n^1.5)."""
    side = 30
    idx = np.arange(side * side).reshape(side, side)
    pairs = np.vstack([np.c_[idx[:, :-1].ravel(), idx[:, 1:].ravel()],
                       np.c_[idx[:-1].ravel(), idx[1:].ravel()],
                       np.c_[idx.ravel(), idx.ravel()]])
    rows, cols = [], []
    for a, b in pairs:
        for i in range(3):
            for j in range(3):
                rows.append(3 * min(a, b) + i)
                cols.append(3 * max(a, b) + j)
    n = 3 * side * side
    A = sp.coo_matrix((np.full(len(rows), -1.0), (rows, cols)), shape=(n, n)).tocsc()
    A = sp.triu(A + A.T + 20.0 * sp.identity(n), format="csc")
    f = BlockLDL(A)
    banded = 9 * side * side * side  # (the natural order: a band of `side` vertices)
    assert f.nnz < 0.5 * banded
