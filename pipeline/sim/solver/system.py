"""The linear algebra of a Newton step: the Hessian's block pattern, the groups of
petals solved as one system each, and their factorizations.

Petals that a contact within the barrier's band or an intact connection spring joins
are one system (:meth:`System.regroup`); the others are each their own. Each group is
factored (:class:`~pipeline.sim.solver.ldl.BlockLDL`, whose pivot signs give the
inertia), shifted where it is not positive definite, and solved apart."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from pipeline.sim.blocks import Blocks, Part
from pipeline.sim.effects import Effects
from pipeline.sim.model import Model
from pipeline.sim.solver.ldl import BlockLDL
from pipeline.sim.terms.shell import ShellBlocks
from pipeline.sim.threads import dot


@dataclass
class Group:
    """Pieces (petals) that are one linear system: a piece alone, or pieces joined by
    contacts or connection springs. Its unknowns, its factorization and how that was
    made."""

    key: tuple  #: its pieces, ascending
    vertices: np.ndarray  #: (n,) its vertices, ascending
    dofs: np.ndarray  #: (3n,) its unknowns in the whole (3 per vertex), ascending
    local: np.ndarray  #: (3V,) index in dofs of each unknown of the whole, -1 outside
    parts: list  #: its pieces' :class:`~pipeline.sim.blocks.Part`: what assembling its Hessian touches
    #: its factorization (:class:`ldl.BlockLDL`), on the pattern of its last matrix
    #: (None: none yet, or singular)
    solver: object = None
    #: (k, 2) vertex pairs (local) the coupling terms have joined in its matrices: the
    #: pattern is the elastic one and these, so that the ordering and symbolic analysis
    #: are redone only when a new pair appears
    pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))
    positive: bool = False  #: the last factorization is positive definite
    shift: float = 0.0  #: the mu of the last factorization
    moved: float = 0.0  #: how far its last step (Newton's, or the predictor's) moved it
    #: a shift mu of the H last assembled that cannot make it positive definite (a
    #: direction of negative curvature found shows it: :meth:`System.factor`)
    need: float = 0.0
    #: the lattice index of its last shift (:meth:`System.shifted`: where the next search
    #: starts; it decides the work only, not the shift found)
    guess: int = 0


@dataclass
class System:
    """The block-sparse pattern and work arrays, built once per model, and the groups
    of pieces that are solved as one system each (:meth:`regroup`)."""

    blocks: Blocks | ShellBlocks  #: the Hessian, assembled and constrained in place
    pinned: np.ndarray
    plane_row: np.ndarray
    normals: np.ndarray
    piece: np.ndarray  #: (V,) connected piece (petal) of each vertex
    edge_piece: np.ndarray  #: (E,) piece of each edge
    hinge_piece: np.ndarray  #: (H,) piece of each hinge
    face_piece: np.ndarray  #: (F,) piece of each face of a shell (empty for the springs)
    #: (3V, 3V) the constraints as a projection: 0 for a fixed vertex, I - n n^T for a
    #: center-plane vertex, I for the others (applied to the coupling terms' Hessian)
    project: sp.csr_matrix | None = None
    #: upper triangle of the coupling terms' constrained Hessian (contact, connection
    #: springs), added to the elastic one at factorization; None: none
    extra: sp.coo_matrix | None = None
    #: (3V,) the inertia term's Hessian (m / dt^2 per unknown), added to the diagonal;
    #: None: none (the quasi-static path)
    inertia: np.ndarray | None = None
    groups: list = field(default_factory=list)  #: the current groups (:class:`Group`)
    _known: dict = field(default_factory=dict)  #: every group met so far, by key
    _joined: np.ndarray | None = None  #: the piece pairs the groups were made of
    _parts: dict = field(default_factory=dict)  #: each piece's part, by piece (:meth:`_part`)

    @classmethod
    def build(cls, model: Model, effects: Effects) -> System:
        n = model.vertex_count
        blocks = ShellBlocks.build(model) if model.shell is not None else Blocks.build(model)
        plane_row = np.full(n, -1, dtype=np.int64)
        normals = np.zeros((0, 3))
        if effects.center_plane is not None:
            plane_row[effects.center_plane.vertices] = np.arange(len(effects.center_plane.vertices))
            normals = np.ascontiguousarray(effects.center_plane.normals)
        e = model.edge_indices
        piece = model.pieces
        faces = model.shell.face_indices if model.shell is not None else np.zeros((0, 3), int)
        system = cls(blocks, model.pinned.copy(), plane_row, normals, piece, piece[e[:, 0]],
                     piece[model.hinge_indices[:, 0]], piece[faces[:, 0]])
        if effects.collisions is not None or effects.connections is not None:
            P = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
            P[model.pinned] = 0.0
            if len(normals):
                idx = effects.center_plane.vertices
                P[idx] -= normals[:, :, None] * normals[:, None, :]
            system.project = sp.bsr_matrix((P, np.arange(n), np.arange(n + 1)),
                                           shape=(3 * n, 3 * n)).tocsr()
        system.regroup(np.zeros((0, 2), dtype=np.int64))
        return system

    # --- groups ---------------------------------------------------------------------------
    def regroup(self, links: np.ndarray) -> bool:
        """Group the pieces: pieces joined by a link (``(k, 2)`` vertex pairs: the
        contacts and springs that couple them) are one system. Returns whether the
        groups changed."""
        count = int(self.piece.max()) + 1 if len(self.piece) else 0
        a, b = self.piece[links[:, 0]], self.piece[links[:, 1]]
        joined = np.unique(np.minimum(a, b) * count + np.maximum(a, b))
        if self._joined is not None and np.array_equal(joined, self._joined):
            return False  # (the same pieces joined: the same groups)
        self._joined = joined
        graph = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(count, count))
        label = connected_components(graph, directed=False)[1]
        keys = [tuple(np.flatnonzero(label == c).tolist()) for c in range(label.max() + 1)]
        keys.sort()
        before = [g.key for g in self.groups]
        self.groups = [self._group(k) for k in keys]
        return keys != before

    def _part(self, piece: int) -> Part:
        """What assembling piece ``piece``'s Hessian touches (no element joins two)."""
        part = self._parts.get(piece)
        if part is None:
            indptr = self.blocks.indptr
            vertices = np.flatnonzero(self.piece == piece)
            part = self._parts[piece] = Part(
                np.flatnonzero(self.edge_piece == piece),
                np.flatnonzero(self.hinge_piece == piece),
                np.concatenate([np.arange(indptr[v], indptr[v + 1]) for v in vertices]),
                faces=np.flatnonzero(self.face_piece == piece))
        return part

    def _group(self, key: tuple) -> Group:
        group = self._known.get(key)
        if group is None:
            vertices = np.flatnonzero(np.isin(self.piece, key))
            dofs = (3 * vertices[:, None] + np.arange(3)).ravel()
            local = np.full(3 * len(self.piece), -1, dtype=np.int64)
            local[dofs] = np.arange(len(dofs))
            group = self._known[key] = Group(key, vertices, dofs, local,
                                              [self._part(p) for p in key])
        return group

    @property
    def tangent(self) -> bool:
        """Every group's last factorization is Newton's (unshifted) and positive definite."""
        return all(g.solver is not None and g.positive and g.shift == 0.0 for g in self.groups)

    # --- the coupling terms -----------------------------------------------------------------
    def couple(self, hessians: list) -> None:
        """Set the coupling terms' Hessians (3V x 3V sparse, or None) for the next
        factorizations, restricted to the free directions."""
        hessians = [t for t in hessians if t is not None]
        if not hessians:
            self.extra = None
            return
        P = self.project
        total = hessians[0] if len(hessians) == 1 else sum(hessians[1:], hessians[0])
        extra = sp.triu(P @ total @ P, format="coo")
        keep = extra.data != 0.0
        self.extra = sp.coo_matrix((extra.data[keep], (extra.row[keep], extra.col[keep])),
                                   shape=extra.shape)

    # --- factorization --------------------------------------------------------------------
    def factor(self, group: Group, mu: float = 0.0, direction: bool = True):
        """LDL^T of the group's ``H + mu I`` (H as last assembled). Returns
        ``(positive, down)``: whether it is positive definite and, if not (and
        ``direction``), a direction of negative curvature ``d^T H d < 0`` (3V, zero
        outside the group; None if none was found). A direction found also bounds the
        shift that can make H positive definite: ``mu <= -d^T H d / d^T d`` cannot
        (``group.need``, the largest such bound for the H last assembled).

        ``P (H + mu I) P^T = L D L^T``: the signs of D are those of the eigenvalues
        (Sylvester's law of inertia); for ``D_k < 0``, ``z = L^-T e_k`` has
        ``z^T L D L^T z = D_k``. A group whose matrix has the pattern of its last one
        (a petal alone always has) reuses its ordering and symbolic analysis.
        """
        shift = np.full(len(group.dofs), mu)
        if self.inertia is not None:
            shift += self.inertia[group.dofs]
        coupling = None
        if self.extra is not None:
            x = self.extra
            r, c = group.local[x.row], group.local[x.col]
            inside = r >= 0
            if inside.any():
                coupling = (r[inside], c[inside], x.data[inside])
        group.shift = mu
        if mu == 0.0:  # (a new H: what is known of its shifts is of the last one)
            group.need = 0.0
        try:
            while True:
                if group.solver is None:
                    group.solver = BlockLDL(self.blocks.indptr, self.blocks.indices,
                                            group.vertices, group.pairs)
                if group.solver.factor(self.blocks.data, shift, coupling):
                    break
                # (a coupling entry outside the pattern: the pattern grows by its pairs)
                group.pairs = _union(group.pairs, coupling[0] // 3, coupling[1] // 3,
                                     len(group.vertices))
                group.solver = None
        except ValueError:  # a zero pivot: singular
            group.solver, group.positive = None, False
            return False, None
        D = group.solver.d
        group.positive = bool(np.all(D > 0.0))
        if group.positive or not direction:
            return group.positive, None
        d, curvature = group.solver.curvature_direction(int(np.argmin(D)))
        size = dot(d, d)
        if size > 0.0:
            group.need = max(group.need, mu - curvature / size)
        if not curvature < mu * size:
            return False, None
        out = np.zeros(3 * len(self.piece))
        out[group.dofs] = d
        return False, out

    def shifted(self, group: Group, floor: float, top: float) -> tuple[float | None, int]:
        """The smallest shift ``mu`` of the lattice ``floor 10^k`` (up to ``top``), not
        below ``group.need``, for which the group's ``H + mu I`` (H as last assembled) is
        positive definite; its factorization is left in the group. Returns ``(mu,
        rejected)``: ``rejected`` the lattice points below it; ``(None, all of them)`` if
        none up to ``top`` is (no shift helps: H is not finite?).

        Positive definiteness is monotone in mu, so the smallest such point is the same
        whatever order the points are tried in: the search starts next to the group's
        last shift (``group.guess``) and walks down or up from it. Upward from ``floor``
        finds the same mu, but the shift a group needs changes little from one iteration
        to the next, far from floor (the lily's settle after its bud search, 4e1 to 4e4
        times it): that tried 4 to 7 factorizations per search, this 2 or 3."""
        mus = [floor]
        while mus[-1] * 10.0 <= top:
            mus.append(mus[-1] * 10.0)
        first = 0  # (points a direction of negative curvature rules out: not factored)
        while first < len(mus) and mus[first] * (1.0 + 1e-6) < group.need:
            first += 1
        if first == len(mus):
            return None, len(mus)

        def positive(k: int) -> bool:
            return self.factor(group, mus[k], direction=False)[0]

        k = min(max(group.guess, first), len(mus) - 1)
        if k > first and positive(k - 1):  # (below the guess first: where that fails
            k -= 1  # and the guess holds, the guess's factorization is the last one made)
            while k > first:
                kept = group.solver, {n: a.copy() for n, a in group.solver.numeric().items()}
                if not positive(k - 1):  # (the one above it is the shift: put back)
                    group.solver = kept[0]
                    group.solver.restore(kept[1])
                    group.shift, group.positive = mus[k], True
                    break
                k -= 1
        else:
            while not positive(k):
                k += 1
                if k == len(mus):
                    return None, len(mus)
        group.guess = k
        return mus[k], k

    def solve(self, rhs: np.ndarray, groups=None, known=None) -> np.ndarray:
        """The step of each group's last factorization for ``rhs`` (3V); zero in the
        groups not given (default: all) and in a group with no factorization. ``known``:
        steps already solved for this ``rhs``, by group key."""
        out = np.zeros_like(rhs)
        for g in self.groups if groups is None else groups:
            if known is not None and g.key in known:
                out[g.dofs] = known[g.key]
            elif g.solver is not None:
                out[g.dofs] = g.solver.solve(rhs[g.dofs])
        return out

    # --- what a checkpoint saves -----------------------------------------------------------
    def snapshot(self) -> dict:
        """What the groups carry from one Newton solve to the next (their patterns, the
        last factorizations and how they were made), for a checkpoint: :meth:`restore`
        puts it back to the bit."""
        known = []
        for key, g in sorted(self._known.items()):
            known.append({"key": np.asarray(key, dtype=np.int64), "pairs": g.pairs,
                          "positive": g.positive, "shift": g.shift, "moved": g.moved,
                          "need": g.need,
                          "factors": None if g.solver is None else g.solver.numeric()})
        return {"known": known, "current": [np.asarray(g.key, dtype=np.int64) for g in self.groups],
                "joined": self._joined}

    def restore(self, saved: dict) -> None:
        """Put back a :meth:`snapshot` (on a system built from the same model)."""
        for item in saved["known"]:
            g = self._group(tuple(int(k) for k in item["key"]))
            g.pairs = np.asarray(item["pairs"], dtype=np.int64).reshape(-1, 2)
            g.positive, g.shift = bool(item["positive"]), float(item["shift"])
            g.moved, g.need = float(item["moved"]), float(item["need"])
            g.solver = None
            if item["factors"] is not None:
                g.solver = BlockLDL(self.blocks.indptr, self.blocks.indices, g.vertices, g.pairs)
                g.solver.restore(item["factors"])
        self.groups = [self._group(tuple(int(k) for k in key)) for key in saved["current"]]
        self._joined = None if saved["joined"] is None else np.asarray(saved["joined"])


def _union(pairs: np.ndarray, a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """``(k, 2)`` the vertex pairs ``pairs`` and ``(a, b)`` (local vertices under ``n``),
    each once, its smaller vertex first, in ascending order (as ``np.unique(..., axis=0)``
    would give them, by a key per pair)."""
    lo = np.concatenate([pairs[:, 0], np.minimum(a, b)])
    hi = np.concatenate([pairs[:, 1], np.maximum(a, b)])
    key = np.unique(lo * n + hi)
    return np.c_[key // n, key % n]
