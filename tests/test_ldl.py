"""The block LDL^T of the quasi-static solver (pipeline/sim/solver/ldl.py) against dense
linear algebra: solves, inertia, directions of negative curvature, coupling entries,
principal submatrices, pattern reuse."""

import numpy as np
import pytest
import scipy.sparse as sp

from pipeline.sim.solver.ldl import BlockLDL


def _random_blocks(nv: int, seed: int, shift: float):
    """A symmetric matrix on a random vertex graph (3x3 blocks): ``(bsr, dense)``."""
    rng = np.random.default_rng(seed)
    edges = rng.integers(0, nv, size=(3 * nv, 2))
    edges = edges[edges[:, 0] != edges[:, 1]]
    A = np.zeros((3 * nv, 3 * nv))
    for a, b in np.vstack([edges, np.c_[np.arange(nv), np.arange(nv)]]):
        A[3 * a:3 * a + 3, 3 * b:3 * b + 3] += rng.standard_normal((3, 3))
    A = A + A.T + shift * np.eye(3 * nv)
    bsr = sp.bsr_matrix(A, blocksize=(3, 3))
    bsr.sort_indices()
    return bsr, A


def _factor(bsr, vertices=None, **kw):
    nv = bsr.shape[0] // 3
    f = BlockLDL(bsr.indptr, bsr.indices, np.arange(nv) if vertices is None else vertices,
                 kw.pop("extra", None))
    assert f.factor(bsr.data, **kw)
    return f


def _residual(A, x, b):
    return np.linalg.norm(A @ x - b) / (np.linalg.norm(A, 2) * np.linalg.norm(x))


@pytest.mark.parametrize("shift", [0.0, 8.0, 40.0])
def test_solve_and_inertia_match_dense_algebra(shift):
    bsr, A = _random_blocks(60, 3, shift)
    f = _factor(bsr)
    b = np.random.default_rng(0).standard_normal(A.shape[0])
    assert _residual(A, f.solve(b), b) < 1e-12
    eig = np.linalg.eigvalsh(A)
    assert int((f.d < 0).sum()) == int((eig < 0).sum())  # Sylvester's law of inertia
    assert int((f.d > 0).sum()) == int((eig > 0).sum())


def test_a_diagonal_shift_is_the_shifted_matrix():
    bsr, A = _random_blocks(30, 4, 0.0)
    mu = np.linspace(5.0, 9.0, A.shape[0])
    f = _factor(bsr, shift=mu)
    b = np.ones(A.shape[0])
    assert _residual(A + np.diag(mu), f.solve(b), b) < 1e-12


def test_curvature_direction_has_the_pivot_as_its_curvature():
    bsr, A = _random_blocks(50, 5, 2.0)
    f = _factor(bsr)
    assert (f.d < 0).any()
    k = int(np.argmin(f.d))
    z, curvature = f.curvature_direction(k)
    assert z @ A @ z == pytest.approx(f.d[k], rel=1e-9)
    assert curvature == pytest.approx(z @ A @ z, rel=1e-12)
    assert curvature < 0.0


def test_coupling_entries_join_vertices_the_blocks_do_not():
    """Entries between vertices with no block (contacts between petals) are added where
    the pattern has their pair, and refused (False) where it has not."""
    bsr, A = _random_blocks(40, 6, 30.0)
    nv = 40
    pairs = [(u, v) for u in range(nv) for v in range(u + 1, nv)
             if not np.any(A[3 * u:3 * u + 3, 3 * v:3 * v + 3])][:5]
    rows, cols, vals = [], [], []
    C = np.zeros_like(A)
    for t, (u, v) in enumerate(pairs):
        for a in range(3):
            for b in range(3):
                rows.append(3 * u + a)
                cols.append(3 * v + b)
                vals.append(0.5 + t + a - b)
                C[3 * u + a, 3 * v + b] = C[3 * v + b, 3 * u + a] = vals[-1]
    coupling = (np.array(rows), np.array(cols), np.array(vals))
    lacking = BlockLDL(bsr.indptr, bsr.indices, np.arange(nv))
    assert not lacking.factor(bsr.data, coupling=coupling)
    f = _factor(bsr, extra=np.array(pairs), coupling=coupling)
    b = np.arange(A.shape[0], dtype=float)
    assert _residual(A + C, f.solve(b), b) < 1e-12


def test_a_principal_submatrix_on_some_vertices():
    bsr, A = _random_blocks(40, 8, 30.0)
    vertices = np.arange(3, 40, 2)
    f = _factor(bsr, vertices)
    dofs = (3 * vertices[:, None] + np.arange(3)).ravel()
    sub = A[np.ix_(dofs, dofs)]
    b = np.cos(np.arange(len(dofs)))
    assert _residual(sub, f.solve(b), b) < 1e-12


def test_refactoring_on_the_same_pattern_is_a_new_analysis_to_the_bit():
    bsr, _ = _random_blocks(40, 7, 30.0)
    f = _factor(bsr)
    other = bsr.copy()
    other.data = other.data * 1.5 + 0.25
    assert f.factor(other.data)
    g = _factor(other)
    b = np.arange(bsr.shape[0], dtype=float)
    assert np.array_equal(f.solve(b), g.solve(b))
    assert np.array_equal(f.d, g.d)


def test_zero_pivot_is_refused():
    bsr, _ = _random_blocks(10, 1, 30.0)
    data = bsr.data.copy()
    first = np.flatnonzero(bsr.indices[:bsr.indptr[1]] == 0)[0]
    data[first, 0, 0] = 0.0
    data[:bsr.indptr[1], 0, :] = 0.0  # (vertex 0's first row: zero)
    f = BlockLDL(bsr.indptr, bsr.indices, np.arange(10))
    with pytest.raises(ValueError, match="singular"):
        f.factor(data)


def test_a_pivot_zero_to_rounding_is_refused_as_singular():
    """A matrix of rank 5 in 6 unknowns (B B^T, B random 6 x 5): its last pivot is not an
    exact zero but rounding (under 1e-13 of the largest diagonal entry): refused; the
    same matrix made regular by a shift of 1e-6 of its scale is factored."""
    rng = np.random.default_rng(4)
    B = rng.standard_normal((6, 5))
    A = B @ B.T
    bsr = sp.bsr_matrix(A, blocksize=(3, 3))
    bsr.sort_indices()
    f = BlockLDL(bsr.indptr, bsr.indices, np.arange(2))
    with pytest.raises(ValueError, match="singular"):
        f.factor(bsr.data)
    assert f.factor(bsr.data, shift=np.full(6, 1e-6 * np.abs(A).max()))
    assert f.inertia() == (6, 0)


def test_fill_is_that_of_a_minimum_degree_ordering():
    """A 2D grid of vertices: the ordering keeps the factor's fill near n log n (the
    natural order's bandwidth would give n^1.5)."""
    side = 30
    n = side * side
    idx = np.arange(n).reshape(side, side)
    pairs = np.vstack([np.c_[idx[:, :-1].ravel(), idx[:, 1:].ravel()],
                       np.c_[idx[:-1].ravel(), idx[1:].ravel()]])
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    graph = (graph + graph.T + sp.identity(n)).tocsr()
    graph.sort_indices()
    f = BlockLDL(graph.indptr, graph.indices, np.arange(n))
    on_diagonal = graph.indices == np.repeat(np.arange(n), np.diff(graph.indptr))
    assert f.factor(np.where(on_diagonal, 20.0, -1.0)[:, None, None] * np.eye(3))
    banded = 9 * n * side  # (the natural order: a band of `side` vertices)
    assert 9 * len(f._li) + 3 * f.nv < 0.5 * banded  # L's entries below its diagonal


def test_subtrees_factored_in_two_threads_are_the_serial_factorization(monkeypatch):
    """A large matrix is factored as two sets of subtrees of its elimination tree at
    once, then the columns above them: the same arithmetic, to the bit."""
    from pipeline.sim.solver import ldl

    side = 20
    n = side * side
    idx = np.arange(n).reshape(side, side)
    pairs = np.vstack([np.c_[idx[:, :-1].ravel(), idx[:, 1:].ravel()],
                       np.c_[idx[:-1].ravel(), idx[1:].ravel()],
                       np.c_[idx[:-1, :-1].ravel(), idx[1:, 1:].ravel()]])
    rng = np.random.default_rng(2)
    A = np.zeros((3 * n, 3 * n))
    for a, b in pairs:
        A[3 * a:3 * a + 3, 3 * b:3 * b + 3] = rng.standard_normal((3, 3))
    A = A + A.T + 40.0 * np.eye(3 * n)
    bsr = sp.bsr_matrix(A, blocksize=(3, 3))
    bsr.sort_indices()
    graph, data = bsr, bsr.data
    monkeypatch.setattr(ldl, "SPLIT", 10)
    split = BlockLDL(graph.indptr, graph.indices, np.arange(n))
    first, second, rest = split._sets
    assert len(first) > n // 10 and len(second) > n // 10 and len(rest) < n // 4
    monkeypatch.setattr(ldl, "SPLIT", 10 ** 9)
    serial = BlockLDL(graph.indptr, graph.indices, np.arange(n))
    assert serial._sets is None
    assert split.factor(data) and serial.factor(data)
    b = np.sin(np.arange(3 * n))
    assert np.array_equal(split.d, serial.d) and np.array_equal(split.solve(b), serial.solve(b))
    assert _residual(A, split.solve(b), b) < 1e-12


def test_a_forked_child_makes_its_own_thread_pools():
    """A pool made before a fork has no thread in the child: a factorization submitted to
    it waited forever (a test run hung in a file's flowers bloomed in forked workers after
    an earlier solve in the same process). Each pool is forgotten at a fork."""
    import multiprocessing

    from pipeline.sim import threads
    from pipeline.sim.solver import ldl

    assert ldl._pool().submit(lambda: 1).result() == 1
    assert threads.parallel_map(lambda x: x + 1, [1, 2]) == [2, 3]

    def child():
        assert ldl._POOL is None and threads._POOL is None
        assert ldl._pool().submit(lambda: 2).result(timeout=20) == 2
        assert threads.parallel_map(lambda x: x * 2, [1, 2]) == [2, 4]

    proc = multiprocessing.get_context("fork").Process(target=child)
    proc.start()
    proc.join(60)
    alive = proc.is_alive()
    if alive:
        proc.kill()
    assert not alive and proc.exitcode == 0
