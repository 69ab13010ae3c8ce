"""Sparse LDL^T of the quasi-static solver's matrices, by 3x3 vertex blocks (numba).

The Newton matrices of a mesh have one 3x3 block per pair of vertices that share an
element, so the factorization is done by those blocks: ``P H P^T = L D L^T`` with
``P`` a permutation of the vertices (each vertex's three unknowns stay together, in
order), ``L`` unit lower triangular, block by block (the diagonal blocks unit lower
triangular 3x3), ``D`` diagonal. No pivoting: the pivots are the scalar ones of the
elimination, whose signs give the inertia (Sylvester's law), which the solver reads
to decide its shifts (:meth:`pipeline.sim.solver.system.System.factor`).

- Input: the Hessian's own 3x3 blocks (scipy's BSR layout, as
  :class:`pipeline.sim.blocks.Blocks` assembles them), a shift on the diagonal, and the coupling
  terms' scalar entries (contacts, connection springs) between vertex pairs the
  pattern was told of; the principal submatrix of a group of vertices (petals). No
  scalar matrix is built.
- Ordering: approximate minimum degree on the vertex graph, qdldl's (its AMD, run on
  a diagonally dominant matrix of the graph's pattern), once per pattern.
- Symbolic analysis: the elimination tree and the row patterns of L (Liu's
  algorithm, ``ereach``), once per pattern; ``factor`` refactors a matrix of the same
  pattern.
- Numeric: left-looking, one block column at a time; each update is a 3x3 times 3x3
  product that the compiler unrolls. The same sparse arithmetic as a scalar LDL^T
  (qdldl's), with a ninth of its index reads: 2.7 times as fast as qdldl on a petal of
  1 080 unknowns (0.74 ms against 2.0 ms with the inertia read; 7.5 GFMA/s; measured
  here), 2.8 times on the lily's 6 216 unknowns joined by contact (4.7 against 13 ms).
- Threads: a matrix of :data:`SPLIT` vertices or more, factored from the main thread,
  is split into two sets of whole subtrees of its elimination tree, of about equal
  work, factored at once, then the columns above them (AMD's separators): the lily's
  joined petals 5.1 -> 3.3 ms. A column reads only its descendants, so the split
  changes no bit.

The order of operations is fixed by the pattern, so a factorization is the same to the
bit on every run.

Why Bloom has its own (and not qdldl's scalar LDL^T, which it keeps for the ordering):
see docs/decisions.md. The module is long because the symbolic analysis, the numeric
kernels, the solves and the split into subtrees are one factorization over one data
layout; apart they would each need the others' internals.
"""

from __future__ import annotations

import os
import threading

import numpy as np
import scipy.sparse as sp
from numba import njit


@njit(cache=True, nogil=True)
def _symbolic(nv, up, ui):
    """Elimination tree of the block pattern (upper, by column: ``up``, ``ui``) and the
    pattern of L below the diagonal: by column (``lp``, ``li``, rows ascending) and by
    row (``rp``: for row J, ``rk`` the columns K < J and ``rq`` where (J, K) is in
    ``li``)."""
    parent = np.full(nv, -1, np.int64)
    ancestor = np.full(nv, -1, np.int64)
    for k in range(nv):
        for q in range(up[k], up[k + 1]):
            i = ui[q]
            while i != -1 and i < k:
                nxt = ancestor[i]
                ancestor[i] = k
                if nxt == -1:
                    parent[i] = k
                i = nxt
    flag = np.full(nv, -1, np.int64)
    count = np.zeros(nv, np.int64)
    rp = np.zeros(nv + 1, np.int64)
    for k in range(nv):  # (first pass: the counts)
        flag[k] = k
        rp[k + 1] = rp[k]
        for q in range(up[k], up[k + 1]):
            i = ui[q]
            while i < k and flag[i] != k:
                count[i] += 1
                rp[k + 1] += 1
                flag[i] = k
                i = parent[i]
    lp = np.zeros(nv + 1, np.int64)
    for k in range(nv):
        lp[k + 1] = lp[k] + count[k]
    li = np.empty(lp[nv], np.int64)
    rk = np.empty(rp[nv], np.int64)
    rq = np.empty(rp[nv], np.int64)
    fill = lp[:nv].copy()
    flag[:] = -1
    for k in range(nv):  # (row k's pattern: the tree paths from its entries up to k)
        flag[k] = k
        r = rp[k]
        for q in range(up[k], up[k + 1]):
            i = ui[q]
            while i < k and flag[i] != k:
                flag[i] = k
                li[fill[i]] = k
                rk[r] = i
                rq[r] = fill[i]
                fill[i] += 1
                r += 1
                i = parent[i]
    return lp, li, rp, rk, rq, parent


@njit(cache=True, nogil=True)
def _fill(data, source, diagonal, shift, xrow, xcol, xval, where, ap, ai, ax):
    """The matrix in the factor's lower blocks ``ax``: each block's from ``data`` (the
    Hessian's 3x3 blocks; ``source``: which, -1 for none), ``shift`` (per unknown, in
    the local order) on the diagonal (``diagonal``: each vertex's diagonal block), and
    the scalar entries ``xrow, xcol, xval`` (local unknowns, upper triangle: r <= c)
    added. Returns False if one of those falls outside the pattern."""
    for q in range(ax.shape[0]):
        k = source[q]
        for a in range(3):
            for b in range(3):
                ax[q, a, b] = data[k, a, b] if k >= 0 else 0.0
    for v in range(where.shape[0]):
        q = diagonal[where[v]]
        for a in range(3):
            ax[q, a, a] += shift[3 * v + a]
    for t in range(xval.shape[0]):
        r = xrow[t]
        c = xcol[t]
        i = where[r // 3]
        j = where[c // 3]
        lo = max(i, j)
        hi = min(i, j)
        q = ap[hi] + np.searchsorted(ai[ap[hi]:ap[hi + 1]], lo)
        if q >= ap[hi + 1] or ai[q] != lo:
            return False
        a = r % 3
        b = c % 3
        if i < j:  # (above the block diagonal: the block is stored turned)
            a, b = b, a
        ax[q, a, b] += xval[t]
        if i == j and a != b:
            ax[q, b, a] += xval[t]
    return True


@njit(cache=True, nogil=True)
def _numeric(columns, ap, ai, ax, lp, li, rp, rk, rq, lx, ldg, d, w, tiny):
    """Factor the lower blocks ``ax`` (by column: ``ap``, ``ai``), the block columns
    ``columns`` (each after its descendants in the elimination tree): ``lx`` the blocks
    of L below the diagonal, ``ldg`` the diagonal blocks' (l10, l20, l21), ``d`` the
    pivots. A column reads only its descendants' columns, so subtrees apart can be
    factored at once (each with its own work array ``w``), the same to the bit.
    Returns the index of the first pivot whose size is not above ``tiny`` (zero,
    rounding-sized, or not a number), or -1."""
    for j in columns:
        for q in range(ap[j], ap[j + 1]):
            i = ai[q]
            for a in range(3):
                for b in range(3):
                    w[i, a, b] = ax[q, a, b]
        for r in range(rp[j], rp[j + 1]):  # (each column K < j with L[j, K] != 0)
            k = rk[r]
            p = rq[r]
            d0 = d[3 * k]
            d1 = d[3 * k + 1]
            d2 = d[3 * k + 2]
            t00 = lx[p, 0, 0] * d0
            t01 = lx[p, 0, 1] * d1
            t02 = lx[p, 0, 2] * d2
            t10 = lx[p, 1, 0] * d0
            t11 = lx[p, 1, 1] * d1
            t12 = lx[p, 1, 2] * d2
            t20 = lx[p, 2, 0] * d0
            t21 = lx[p, 2, 1] * d1
            t22 = lx[p, 2, 2] * d2
            for q in range(p, lp[k + 1]):  # (W[I] -= L[I, K] D_K L[j, K]^T, I >= j)
                i = li[q]
                for a in range(3):
                    l0 = lx[q, a, 0]
                    l1 = lx[q, a, 1]
                    l2 = lx[q, a, 2]
                    w[i, a, 0] -= l0 * t00 + l1 * t01 + l2 * t02
                    w[i, a, 1] -= l0 * t10 + l1 * t11 + l2 * t12
                    w[i, a, 2] -= l0 * t20 + l1 * t21 + l2 * t22
        p0 = w[j, 0, 0]  # (the diagonal block: a scalar LDL^T of its lower triangle)
        if not abs(p0) > tiny:
            return 3 * j
        l10 = w[j, 1, 0] / p0
        l20 = w[j, 2, 0] / p0
        p1 = w[j, 1, 1] - l10 * l10 * p0
        if not abs(p1) > tiny:
            return 3 * j + 1
        l21 = (w[j, 2, 1] - l20 * l10 * p0) / p1
        p2 = w[j, 2, 2] - l20 * l20 * p0 - l21 * l21 * p1
        if not abs(p2) > tiny:
            return 3 * j + 2
        d[3 * j] = p0
        d[3 * j + 1] = p1
        d[3 * j + 2] = p2
        ldg[j, 0] = l10
        ldg[j, 1] = l20
        ldg[j, 2] = l21
        for a in range(3):
            for b in range(3):
                w[j, a, b] = 0.0
        for q in range(lp[j], lp[j + 1]):  # L[I, j] = W[I] L_jj^-T D_j^-1
            i = li[q]
            for a in range(3):
                x0 = w[i, a, 0]
                x1 = w[i, a, 1] - l10 * x0
                x2 = w[i, a, 2] - l20 * x0 - l21 * x1
                lx[q, a, 0] = x0 / p0
                lx[q, a, 1] = x1 / p1
                lx[q, a, 2] = x2 / p2
                w[i, a, 0] = 0.0
                w[i, a, 1] = 0.0
                w[i, a, 2] = 0.0
    return -1


@njit(cache=True, nogil=True)
def _diagonal_size(ap, ai, ax):
    """The largest absolute diagonal entry of the lower blocks ``ax`` (by column)."""
    size = 0.0
    for j in range(ap.shape[0] - 1):
        for q in range(ap[j], ap[j + 1]):
            if ai[q] == j:
                for a in range(3):
                    size = max(size, abs(ax[q, a, a]))
    return size


@njit(cache=True, nogil=True)
def _lower(nv, lp, li, lx, ldg, y):
    """y <- L^-1 y (in place; ``y`` (nv, 3) in the permuted order)."""
    for j in range(nv):
        y[j, 1] -= ldg[j, 0] * y[j, 0]
        y[j, 2] -= ldg[j, 1] * y[j, 0] + ldg[j, 2] * y[j, 1]
        y0 = y[j, 0]
        y1 = y[j, 1]
        y2 = y[j, 2]
        for q in range(lp[j], lp[j + 1]):
            i = li[q]
            for a in range(3):
                y[i, a] -= lx[q, a, 0] * y0 + lx[q, a, 1] * y1 + lx[q, a, 2] * y2


@njit(cache=True, nogil=True)
def _upper(nv, lp, li, lx, ldg, y):
    """y <- L^-T y (in place)."""
    for j in range(nv - 1, -1, -1):
        s0 = y[j, 0]
        s1 = y[j, 1]
        s2 = y[j, 2]
        for q in range(lp[j], lp[j + 1]):
            i = li[q]
            s0 -= lx[q, 0, 0] * y[i, 0] + lx[q, 1, 0] * y[i, 1] + lx[q, 2, 0] * y[i, 2]
            s1 -= lx[q, 0, 1] * y[i, 0] + lx[q, 1, 1] * y[i, 1] + lx[q, 2, 1] * y[i, 2]
            s2 -= lx[q, 0, 2] * y[i, 0] + lx[q, 1, 2] * y[i, 1] + lx[q, 2, 2] * y[i, 2]
        s1 -= ldg[j, 2] * s2
        s0 -= ldg[j, 0] * s1 + ldg[j, 1] * s2
        y[j, 0] = s0
        y[j, 1] = s1
        y[j, 2] = s2


@njit(cache=True, nogil=True)
def _solve(nv, lp, li, lx, ldg, d, y):
    _lower(nv, lp, li, lx, ldg, y)
    for j in range(nv):
        for a in range(3):
            y[j, a] /= d[3 * j + a]
    _upper(nv, lp, li, lx, ldg, y)


@njit(cache=True, nogil=True)
def _quadratic(ap, ai, ax, y):
    """``y^T A y`` of the matrix in the lower blocks ``ax`` (``y`` (nv, 3), permuted)."""
    total = 0.0
    for j in range(ap.shape[0] - 1):
        for q in range(ap[j], ap[j + 1]):
            i = ai[q]
            part = 0.0
            for a in range(3):
                for b in range(3):
                    part += y[i, a] * ax[q, a, b] * y[j, b]
            total += part if i == j else 2.0 * part
    return total


@njit(cache=True, nogil=True)
def _local(indptr, indices, vertices, extra):
    """The vertex pairs of the principal submatrix on ``vertices`` of a block pattern
    (``indptr``, ``indices``: a BSR pattern), in local numbering, with each vertex's
    diagonal and the local ``extra`` pairs: ``(rows, cols, sources)``, ``sources`` the
    BSR block of each pair (-1: none)."""
    n = indptr.shape[0] - 1
    local = np.full(n, -1, np.int64)
    for u in range(vertices.shape[0]):
        local[vertices[u]] = u
    count = vertices.shape[0] + extra.shape[0]
    for u in range(vertices.shape[0]):
        count += indptr[vertices[u] + 1] - indptr[vertices[u]]
    rows = np.empty(count, np.int64)
    cols = np.empty(count, np.int64)
    sources = np.full(count, -1, np.int64)
    t = 0
    for u in range(vertices.shape[0]):
        rows[t] = u
        cols[t] = u
        t += 1
        g = vertices[u]
        for q in range(indptr[g], indptr[g + 1]):
            h = local[indices[q]]
            if h >= 0:
                rows[t] = u
                cols[t] = h
                sources[t] = q
                t += 1
    for e in range(extra.shape[0]):
        rows[t] = extra[e, 0]
        cols[t] = extra[e, 1]
        t += 1
    return rows[:t], cols[:t], sources[:t]


@njit(cache=True, nogil=True)
def _pattern(nv, rows, cols, sources, where):
    """The lower block pattern, by column, of the vertex pairs ``rows, cols`` (either
    orientation, repeats allowed) with vertex v moved to ``where[v]``: ``(ap, ai)``
    (rows ascending) and its transpose ``(up, ui)``; ``source`` of each block: the BSR
    block of a pair that is its (row, column) in the local order, or -1; ``diagonal``:
    each column's diagonal block."""
    count = np.zeros(nv + 1, np.int64)
    m = rows.shape[0]
    lo = np.empty(m, np.int64)
    hi = np.empty(m, np.int64)
    for t in range(m):
        i = where[rows[t]]
        j = where[cols[t]]
        lo[t] = max(i, j)
        hi[t] = min(i, j)
        count[hi[t] + 1] += 1
    for k in range(nv):
        count[k + 1] += count[k]
    bucket = np.empty(m, np.int64)
    fill = count[:nv].copy()
    for t in range(m):
        bucket[fill[hi[t]]] = lo[t]
        fill[hi[t]] += 1
    ap = np.zeros(nv + 1, np.int64)
    ai = np.empty(m, np.int64)
    for k in range(nv):  # (each column's rows, sorted and once each)
        column = np.sort(bucket[count[k]:count[k + 1]])
        at = ap[k]
        for t in range(column.shape[0]):
            if t == 0 or column[t] != column[t - 1]:
                ai[at] = column[t]
                at += 1
        ap[k + 1] = at
    ai = ai[:ap[nv]].copy()
    source = np.full(ai.shape[0], -1, np.int64)
    for t in range(m):
        if sources[t] >= 0 and where[rows[t]] >= where[cols[t]]:  # (its orientation)
            k = hi[t]
            source[ap[k] + np.searchsorted(ai[ap[k]:ap[k + 1]], lo[t])] = sources[t]
    diagonal = ap[:nv].copy()  # (each column's first row is its diagonal)
    up = np.zeros(nv + 1, np.int64)
    for q in range(ai.shape[0]):
        up[ai[q] + 1] += 1
    for k in range(nv):
        up[k + 1] += up[k]
    ui = np.empty(ai.shape[0], np.int64)
    fill = up[:nv].copy()
    for k in range(nv):  # (columns ascending: each upper column's rows come ascending)
        for q in range(ap[k], ap[k + 1]):
            ui[fill[ai[q]]] = k
            fill[ai[q]] += 1
    return ap, ai, up, ui, source, diagonal


def _split(parent: np.ndarray, lp: np.ndarray, ways: int = 2) -> list[np.ndarray]:
    """The block columns in ``ways`` sets of whole subtrees of the elimination tree
    (``parent``) of about equal work, and the rest (the columns above them) last: each
    set can be factored at once with the others, then the rest. The work of a column is
    the square of its count."""
    nv = len(parent)
    parent = parent.tolist()  # (Python's own ints and floats: these loops are Python's)
    sub = ((np.diff(lp) + 1.0) ** 2).tolist()
    children = [[] for _ in range(nv)]
    for j in range(nv):  # (children come before their parents)
        if parent[j] >= 0:
            sub[parent[j]] += sub[j]
            children[parent[j]].append(j)
    frontier = [j for j in range(nv) if parent[j] < 0]
    total = sum(sub[j] for j in frontier)  # (the frontier's work)
    top = set()
    while True:  # (open the heaviest subtree while it outweighs the others)
        heaviest = max(frontier, key=lambda j: sub[j])
        if not children[heaviest] or sub[heaviest] <= total / ways:
            break
        frontier.remove(heaviest)
        top.add(heaviest)
        frontier.extend(children[heaviest])
        total += sum(sub[c] for c in children[heaviest]) - sub[heaviest]
    label = [-1] * nv
    load = [0.0] * ways
    for r in sorted(frontier, key=lambda j: (-sub[j], j)):
        k = min(range(ways), key=lambda w: load[w])
        label[r] = k
        load[k] += sub[r]
    for j in range(nv - 1, -1, -1):  # (parents first: a subtree takes its root's label)
        if label[j] < 0 and parent[j] >= 0 and parent[j] not in top:
            label[j] = label[parent[j]]
    label = np.asarray(label, dtype=np.int64)
    return [np.flatnonzero(label == k) for k in range(ways)] + [np.flatnonzero(label < 0)]


def _ordering(nv: int, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Approximate minimum degree ordering of the vertex graph (pairs ``rows, cols``):
    qdldl's AMD, run on a diagonally dominant matrix of that pattern (its diagonal
    each vertex's degree + 1, the rest -1)."""
    import qdldl

    none = np.full(len(rows), -1, np.int64)
    _, _, up, ui, _, _ = _pattern(nv, rows, cols, none, np.arange(nv, dtype=np.int64))
    columns = np.repeat(np.arange(nv), np.diff(up))
    off = ui != columns
    degree = np.bincount(ui[off], minlength=nv) + np.bincount(columns[off], minlength=nv)
    values = np.where(off, -1.0, degree[columns] + 1.0)
    graph = sp.csc_matrix((values, ui, up), shape=(nv, nv))
    return np.asarray(qdldl.Solver(graph, upper=True).factors()[2], dtype=np.int64)


#: vertices from which a factorization is split into subtrees factored in two threads
#: (the main thread's only: a matrix factored in a pool thread has others beside it)
SPLIT = 1000
_NO_COUPLING = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
_POOL = None


def _pool():
    global _POOL
    if _POOL is None:
        from concurrent.futures import ThreadPoolExecutor

        _POOL = ThreadPoolExecutor(max_workers=1)
    return _POOL


def _forgotten() -> None:
    """In a forked child: the parent's pool has no thread here (a factor submitted to
    it waited forever: a file's flowers bloomed in workers forked after a solve), so a
    new one is made at the next use."""
    global _POOL
    _POOL = None


os.register_at_fork(after_in_child=_forgotten)


#: a pivot no larger than this fraction of the matrix's largest diagonal entry is zero
#: to rounding: the matrix is taken as singular (an exact zero, or a cancellation that
#: leaves only rounding, would give a step of any size)
PIVOT = 1e-13


class BlockLDL:
    """``P A P^T = L D L^T`` of the principal submatrix on ``vertices`` of a symmetric
    block-sparse matrix (3x3 blocks in scipy's BSR layout, ``indptr``, ``indices``:
    both triangles), plus coupling entries between the vertex pairs ``extra`` (local
    numbering, ``(k, 2)``). ``d``: the pivots, in the permuted order (their signs: the
    inertia). Raises ``ValueError`` at a zero pivot (singular)."""

    def __init__(self, indptr: np.ndarray, indices: np.ndarray, vertices: np.ndarray,
                 extra: np.ndarray | None = None):
        vertices = np.ascontiguousarray(vertices, dtype=np.int64)
        extra = np.zeros((0, 2), np.int64) if extra is None else np.asarray(extra, np.int64)
        nv = len(vertices)
        rows, cols, sources = _local(np.asarray(indptr, np.int64), np.asarray(indices, np.int64),
                                     vertices, extra.reshape(-1, 2))
        perm = _ordering(nv, rows, cols)
        where = np.empty(nv, np.int64)
        where[perm] = np.arange(nv)
        self._ap, self._ai, up, ui, self._source, self._diagonal = _pattern(
            nv, rows, cols, sources, where)
        self._lp, self._li, self._rp, self._rk, self._rq, parent = _symbolic(nv, up, ui)
        self._sets = None  # (the columns in subtrees apart, for threads: :func:`_split`)
        if nv >= SPLIT and (os.cpu_count() or 1) > 1:
            self._sets = _split(parent, self._lp)
            self._w2 = np.zeros((nv, 3, 3))
        self.nv, self.perm, self._where = nv, perm, where
        self._all = np.arange(nv, dtype=np.int64)
        self._ax = np.zeros((len(self._ai), 3, 3))
        self._lx = np.zeros((len(self._li), 3, 3))
        self._ldg = np.zeros((nv, 3))
        self._w = np.zeros((nv, 3, 3))
        self.d = np.zeros(3 * nv)

    def factor(self, data: np.ndarray, shift: np.ndarray | None = None, coupling=None) -> bool:
        """Factor the matrix: the blocks ``data`` (the BSR matrix's), plus ``shift`` (3
        per vertex, local order) on the diagonal, plus ``coupling``: scalar entries
        ``(rows, cols, values)`` in local unknowns, upper triangle. Returns False (and
        factors nothing) if a coupling entry falls outside the pattern (new ``extra``
        pairs are needed)."""
        xr, xc, xv = coupling if coupling is not None else _NO_COUPLING
        if shift is None:
            shift = np.zeros(3 * self.nv)
        if not _fill(data, self._source, self._diagonal, shift, xr, xc, xv, self._where,
                     self._ap, self._ai, self._ax):
            return False
        tiny = PIVOT * _diagonal_size(self._ap, self._ai, self._ax)

        def run(columns, w):
            return _numeric(columns, self._ap, self._ai, self._ax, self._lp, self._li,
                            self._rp, self._rk, self._rq, self._lx, self._ldg, self.d, w, tiny)

        if self._sets is not None and threading.current_thread() is threading.main_thread():
            first, second, rest = self._sets
            other = _pool().submit(run, second, self._w2)
            zeros = [run(first, self._w), other.result()]
            zeros.append(run(rest, self._w) if max(zeros) < 0 else -1)
            zero = max(zeros)
        else:
            zero = run(self._all, self._w)
        if zero >= 0:  # (the column left half done: its work rows cleared for the next)
            self._w[...] = 0.0
            if self._sets is not None:
                self._w2[...] = 0.0
            raise ValueError(f"pivot {zero} is zero to rounding (under {PIVOT:g} of the largest "
                             "diagonal entry): the matrix is singular")
        return True

    def inertia(self) -> tuple[int, int]:
        """The numbers of positive and negative eigenvalues of the matrix last factored
        (the signs of its pivots, Sylvester's law of inertia; a singular one is refused
        by :meth:`factor`, so there are no zeros)."""
        positive = int(np.count_nonzero(self.d > 0.0))
        return positive, len(self.d) - positive

    def numeric(self) -> dict[str, np.ndarray]:
        """The factorization's numbers (the pattern comes from the constructor's
        arguments): what a checkpoint saves to restore it (:meth:`restore`) to the bit."""
        return {"ax": self._ax, "lx": self._lx, "ldg": self._ldg, "d": self.d}

    def restore(self, numbers: dict[str, np.ndarray]) -> None:
        """Put back a factorization's numbers (:meth:`numeric`) on the same pattern."""
        for name, target in (("ax", self._ax), ("lx", self._lx), ("ldg", self._ldg),
                             ("d", self.d)):
            if numbers[name].shape != target.shape:
                raise ValueError(f"{name}: shape {numbers[name].shape}, not {target.shape}")
            target[...] = numbers[name]

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        y = np.ascontiguousarray(rhs.reshape(-1, 3)[self.perm])
        _solve(self.nv, self._lp, self._li, self._lx, self._ldg, self.d, y)
        out = np.empty_like(y)
        out[self.perm] = y
        return out.reshape(-1)

    def curvature_direction(self, k: int) -> tuple[np.ndarray, float]:
        """``z = P^T L^-T e_k`` and ``z^T A z`` (= ``d[k]`` but for rounding; a direction
        of negative curvature where ``d[k] < 0``), of the matrix last factored."""
        y = np.zeros((self.nv, 3))
        y[k // 3, k % 3] = 1.0
        _upper(self.nv, self._lp, self._li, self._lx, self._ldg, y)
        curvature = _quadratic(self._ap, self._ai, self._ax, y)
        out = np.empty_like(y)
        out[self.perm] = y
        return out.reshape(-1), curvature
