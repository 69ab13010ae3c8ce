"""The quasi-static integrator: the bloom as a path of equilibria along the growth A(t).

A petal's bending modes are slow (a period of ~5e4 steps at h = 1), so an explicit
scheme needs ~1e5 steps or more to settle where growth puts it. This integrator does
not follow the dynamics: for each growth increment it finds the equilibrium
(grad U = 0) by Newton's method, starting from a prediction along the path (the secant
of the last two equilibria, or the tangent).

- Hessian: the analytic one of :mod:`hessian`. A Newton step factors it as is (a sparse
  LDL^T by 3x3 vertex blocks, :mod:`ldl`, whose pivot signs give its inertia); a later
  step of the same solve may reuse that factorization (a chord step) if the step it
  gives is a tenth of the last one or less (the factorization is most of an iteration's
  cost). Where it is positive definite the step is Newton's, and near a stable
  equilibrium convergence is quadratic. Where it is not (the path passes a bifurcation
  or a snap, or the prediction is far off), the energy is first searched along a
  direction of negative curvature read from the factors, then the step solves ``(H + mu
  I) p = -g`` with ``mu`` raised until that is positive definite (see
  :meth:`QuasiStatic._newton`). (Projecting each element's Hessian to positive definite,
  the other classic remedy, was tried first: it converged linearly, 50-100 iterations
  per increment, and stalled at snaps.)
- Each connected piece (petal) is its own problem when petals do not interact. With
  collisions or connection springs they share one energy and one line search, but the
  linear algebra is split by group: petals that a contact within the barrier's band or
  an intact spring joins are one system, the others each their own (most petals,
  most of the time, are alone); each group is factored, and converges, apart, and a
  converged group stays put while the others iterate.
- Line search: backtracking on the energy (Armijo); a step within rounding of the
  energy is accepted.
- Increments: ``ceil(dA * stages)`` per call, so ``stages`` bounds the growth per
  increment; an increment that does not converge is halved (up to 6 times).
- Symmetry breaking: at the first increment every free vertex is moved by a tiny,
  seeded random amount (``perturbation`` mesh units), so that a perfectly symmetric
  petal can leave an unstable symmetric branch; Newton removes it where the branch is
  stable.
- Effects: curl (rest angles follow B = A), wrinkles (growth map), the fixed base and
  the center-plane constraint (a constrained vertex's Newton step has no component
  along its plane normal).
- Collisions: an IPC barrier between petals joins the energy (:class:`~pipeline.sim.terms.contact.Contact`);
  every step, the line search's and the negative-curvature search's, is first cut to
  what continuous collision detection allows, so no iterate crosses (or comes closer
  than ``effects.collisions.thickness``). A bud that starts intersecting is refused.
- Connection springs join the energy (:class:`~pipeline.sim.terms.connections.Springs`); when an increment
  converges with springs past their breaking length, those break (the step at which
  the growth reached that increment is recorded) and the increment is redone.

- Inertia (``inertia``, the key ``simulate.inertia``): each increment, at least one per
  frame and evenly spread in time, is an implicit Euler step in incremental-potential
  form, the minimum of ``U(x) + |x - x_pred|_M^2 / (2 dt^2)``, ``x_pred = x + dt v``, by
  the same Newton solver (:meth:`QuasiStatic._advance_dynamic`); then ``v = (x_new -
  x) / dt``. A motion such as the snap after springs break plays out over frames and
  comes to rest; the path of equilibria is its limit (``dt`` far past the slowest
  period).

``advance`` has the signature of the dynamic integrators, so :func:`run.run` records
one equilibrium (or, with inertia, one state of the motion) per frame; without inertia
velocities stay zero.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from pipeline.sim import energy
from pipeline.sim.blocks import Blocks, Part, constrain
from pipeline.sim.effects import NO_EFFECTS, Effects
from pipeline.sim.model import Control, Model, State
from pipeline.sim.solver.ldl import BlockLDL
from pipeline.sim.terms.center_plane import CenterPlane
from pipeline.sim.terms.connections import Springs
from pipeline.sim.terms.contact import Contact
from pipeline.sim.terms.growth import Curl
from pipeline.sim.terms.inertia import Inertia

_POOL = None


#: how far (mesh units) a search along a direction of negative curvature may go
DESCENT = 2.0


def _map(fn, items: list) -> list:
    """``[fn(x) for x in items]``, the calls overlapping in threads. For work apart
    whose heavy parts, the numba kernels (the factorization's too), release the GIL:
    the solves of petals that do not interact, the factorizations and shift searches of
    the groups of one coupled Newton step, the pieces' Hessians. Each call's arithmetic is its own, so the
    results are the same to the bit with any number of threads, and they come back in
    order (an exception: the first item's that raised). A call made from a pool thread
    has one item (a petal's solver has one group), so it runs inline."""
    global _POOL
    if len(items) < 2:
        return [fn(x) for x in items]
    if _POOL is None:
        from concurrent.futures import ThreadPoolExecutor

        _POOL = ThreadPoolExecutor(max_workers=max(1, min(4, os.cpu_count() or 1)))
    return list(_POOL.map(fn, items))


@dataclass
class _Part:
    """One connected piece (a petal): its vertices in the whole, and its own problem."""

    vertices: np.ndarray
    model: Model
    effects: Effects
    state: State
    solver: QuasiStatic | None = None


def _split(model: Model, effects: Effects) -> list[_Part]:
    """The mesh's connected pieces, each as a problem of its own; [] if it is one piece
    or if the pieces interact (collisions, connection springs: then they are one problem).
    Without those, petals do not interact: each is solved on its own, so a petal that
    snaps costs iterations of its own factorization only, and the line search of one does
    not hold back another. Pieces without springs are left where they are."""
    from scipy.sparse.csgraph import connected_components

    n = model.vertex_count
    e = model.edge_indices
    graph = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    count, label = connected_components(graph, directed=False)
    pinned_pieces = np.unique(label[model.pinned])
    for c in range(count):
        if c not in pinned_pieces and np.any(label[e[:, 0]] == c):
            raise ValueError(f"a piece of the mesh ({int(np.sum(label == c))} vertices) has no "
                             "fixed base vertex: with nothing holding it, it has no "
                             "equilibrium; check axis.base")
    if count <= 1 or effects.collisions is not None or effects.connections is not None:
        return []
    parts = []
    for c in range(count):
        idx = np.flatnonzero(label == c)
        local = np.full(n, -1, dtype=np.int64)
        local[idx] = np.arange(len(idx))
        emask = label[e[:, 0]] == c
        if not emask.any():
            continue
        hmask = label[model.hinge_indices[:, 0]] == c
        sub = Model(
            vertex_count=len(idx), vertex_mass=model.vertex_mass[idx],
            vertex_inv_mass=model.vertex_inv_mass[idx], edge_indices=local[e[emask]],
            edge_rest_length=model.edge_rest_length[emask], edge_growth=model.edge_growth[emask],
            edge_stiffness=model.edge_stiffness[emask],
            hinge_indices=local[model.hinge_indices[hmask]],
            hinge_rest_cos=model.hinge_rest_cos[hmask], hinge_rest_sin=model.hinge_rest_sin[hmask],
            hinge_stiffness=model.hinge_stiffness[hmask])
        fx = Effects(names=effects.names)
        if effects.curl is not None:
            k = effects.curl
            fx.curl = Curl(k.theta0[hmask].copy(), k.beta, k.cos_t[hmask].copy(),
                           k.sin_t[hmask].copy())
        if effects.center_plane is not None:
            cp = effects.center_plane
            mine = label[cp.vertices] == c
            fx.center_plane = CenterPlane(local[cp.vertices[mine]], cp.normals[mine],
                                          cp.height[mine])
        zeros = np.zeros((len(idx), 3))
        state = State(zeros.copy(), zeros.copy(), zeros.copy(), 0, 0.0, zeros.copy())
        parts.append(_Part(idx, sub, fx, state))
    return parts


#: a gradient component below this many times ``eps`` times the force scale (the size of
#: what the force kernel adds and subtracts at that vertex,
#: :func:`~pipeline.sim.terms.elastic.rounding_scale`)
#: is rounding: Newton's own steps end at 0.1-0.2 of it on the project's buds
#: with contact, a residual force under this fraction of the force scale is converged
#: (see :meth:`QuasiStatic._newton`)
PRESSED = 1e-6
ROUNDING_FACTOR = 2.0
#: a group's factorization is reused for a step at most this fraction of its last one
CHORD = 0.1
EPS = float(np.finfo(np.float64).eps)
@dataclass
class _Failure:
    """Why Newton stopped without an equilibrium."""

    residual: float  #: largest gradient component left (force units)
    scale: float  #: the force scale there (eps * scale * ROUNDING_FACTOR: the rounding level)
    how: str  #: stalled (no descent along the step), iterations, or shift (no shift helped)
    inertia: str  #: the Hessian's last factorization: definite, indefinite or singular

    @property
    def rounding(self) -> float:
        return ROUNDING_FACTOR * EPS * self.scale


class NotConverged(RuntimeError):
    """Newton did not reach an equilibrium, even with halved growth increments.

    ``cause``: ``weak`` (the piece is held by fixed vertices on a line and can turn about
    it), ``unstable`` (Newton stalled with a real residual where the Hessian is
    indefinite or singular: no stable equilibrium there, the petal buckles or snaps) or
    ``stalled`` (a real residual at a positive definite Hessian, or out of iterations).
    ``vertex``: a vertex of the piece that failed (for naming its petal)."""

    def __init__(self, step: int, growth: float, residual: float, *, scale: float = float("nan"),
                 cause: str = "stalled", detail: str = "", vertex: int = 0):
        self.step, self.growth, self.residual = step, growth, residual
        self.scale, self.cause, self.vertex = scale, cause, vertex
        rounding = ROUNDING_FACTOR * EPS * scale
        text = (f"no equilibrium at step {step} (growth A = {growth:.4g}): residual force "
                f"{residual:.3g}, {residual / rounding:.3g} times its rounding level "
                f"{rounding:.2g} (force scale {scale:.3g})")
        super().__init__(f"{text}; {detail}" if detail else text)


@dataclass
class _Group:
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
    #: direction of negative curvature found shows it: :meth:`_System.factor`)
    need: float = 0.0


@dataclass
class _System:
    """The block-sparse pattern and work arrays, built once per model, and the groups
    of pieces that are solved as one system each (:meth:`regroup`)."""

    blocks: Blocks  #: the Hessian, assembled and constrained in place
    pinned: np.ndarray
    plane_row: np.ndarray
    normals: np.ndarray
    piece: np.ndarray  #: (V,) connected piece (petal) of each vertex
    edge_piece: np.ndarray  #: (E,) piece of each edge
    hinge_piece: np.ndarray  #: (H,) piece of each hinge
    #: (3V, 3V) the constraints as a projection: 0 for a fixed vertex, I - n n^T for a
    #: center-plane vertex, I for the others (applied to the coupling terms' Hessian)
    project: sp.csr_matrix | None = None
    #: upper triangle of the coupling terms' constrained Hessian (contact, connection
    #: springs), added to the elastic one at factorization; None: none
    extra: sp.coo_matrix | None = None
    #: (3V,) the inertia term's Hessian (m / dt^2 per unknown), added to the diagonal;
    #: None: none (the quasi-static path)
    inertia: np.ndarray | None = None
    groups: list = field(default_factory=list)  #: the current groups (:class:`_Group`)
    _known: dict = field(default_factory=dict)  #: every group met so far, by key
    _joined: np.ndarray | None = None  #: the piece pairs the groups were made of
    _parts: dict = field(default_factory=dict)  #: each piece's part, by piece (:meth:`_part`)

    @classmethod
    def build(cls, model: Model, effects: Effects) -> _System:
        from scipy.sparse.csgraph import connected_components

        n = model.vertex_count
        blocks = Blocks.build(model)
        plane_row = np.full(n, -1, dtype=np.int64)
        normals = np.zeros((0, 3))
        if effects.center_plane is not None:
            plane_row[effects.center_plane.vertices] = np.arange(len(effects.center_plane.vertices))
            normals = np.ascontiguousarray(effects.center_plane.normals)
        e = model.edge_indices
        graph = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
        piece = connected_components(graph, directed=False)[1].astype(np.int64)
        system = cls(blocks, model.pinned.copy(), plane_row, normals, piece, piece[e[:, 0]],
                     piece[model.hinge_indices[:, 0]])
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
        from scipy.sparse.csgraph import connected_components

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
                np.concatenate([np.arange(indptr[v], indptr[v + 1]) for v in vertices]))
        return part

    def _group(self, key: tuple) -> _Group:
        group = self._known.get(key)
        if group is None:
            vertices = np.flatnonzero(np.isin(self.piece, key))
            dofs = (3 * vertices[:, None] + np.arange(3)).ravel()
            local = np.full(3 * len(self.piece), -1, dtype=np.int64)
            local[dofs] = np.arange(len(dofs))
            group = self._known[key] = _Group(key, vertices, dofs, local,
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
    def factor(self, group: _Group, mu: float = 0.0, direction: bool = True):
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
                pairs = np.concatenate([group.pairs, np.c_[coupling[0] // 3, coupling[1] // 3]])
                group.pairs = np.unique(np.sort(pairs, axis=1), axis=0)
                group.solver = None
        except ValueError:  # a zero pivot: singular
            group.solver, group.positive = None, False
            return False, None
        D = group.solver.d
        group.positive = bool(np.all(D > 0.0))
        if group.positive or not direction:
            return group.positive, None
        d, curvature = group.solver.curvature_direction(int(np.argmin(D)))
        size = d @ d
        if size > 0.0:
            group.need = max(group.need, mu - curvature / size)
        if not curvature < mu * size:
            return False, None
        out = np.zeros(3 * len(self.piece))
        out[group.dofs] = d
        return False, out

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


@dataclass
class QuasiStatic:
    """Path-following Newton solver; see the module docstring."""

    stages: int = 20  #: growth increments over the whole ramp (at least)
    tolerance: float = 1e-6  #: converged when a Newton step moves no vertex further (mesh units)
    max_iterations: int = 200  #: Newton iterations per increment before it is halved (a snap takes ~50)
    perturbation: float = 1e-6  #: symmetry-breaking nudge at the start (mesh units)
    seed: int = 0
    #: with the inertia term: each increment is an implicit Euler step of the dynamics
    #: (:meth:`_advance_dynamic`); without it, the path of equilibria (its limit)
    inertia: bool = False
    iterations: int = 0  #: Newton iterations so far (all increments)
    increments: int = 0  #: growth increments solved so far
    shifted: int = 0  #: factorizations retried with a larger shift mu
    descents: int = 0  #: searches along a direction of negative curvature
    ccd_cuts: int = 0  #: steps cut short by continuous collision detection
    breaks: int = 0  #: connection springs broken (each break redoes its increment)
    residuals: list = field(default_factory=list, repr=False)  #: per iteration of the last solve
    _system: _System | None = field(default=None, repr=False)
    _started: bool = field(default=False, repr=False)
    _parts: list | None = field(default=None, repr=False)  #: one solver per petal, or []
    _energy_rounding: float = field(default=0.0, repr=False)  #: of the last Newton iterate
    _scale_work: np.ndarray | None = field(default=None, repr=False)
    _perturbed: bool = field(default=False, repr=False)  #: the symmetry-breaking nudge is made
    _contact: Contact | None = field(default=None, repr=False)  #: the barrier, if collisions
    _springs: Springs | None = field(default=None, repr=False)  #: if connection springs
    _coupling: np.ndarray | None = field(default=None, repr=False)  #: their last forces
    _limited: bool = field(default=False, repr=False)  #: the last line search was cut by CCD
    #: the energy at the step the last line search took, whose forces it left in its
    #: scratch (None: not since); the next Newton iteration starts from them
    _accepted: float | None = field(default=None, repr=False)
    #: the equilibrium before the last one on the path: (A, X), for the secant predictor
    _behind: tuple | None = field(default=None, repr=False)
    #: the inertia term of the increment being solved (None: the quasi-static path)
    _dyn: Inertia | None = field(default=None, repr=False)
    #: the scene's terms (:func:`~pipeline.sim.energy.build`), at the growth last set (:meth:`_at`)
    _terms: energy.Terms | None = field(default=None, repr=False)

    def diagnostics(self) -> dict:
        # (the same names at every frame, the first included: coupling is built later)
        return {"newton_iterations": self.iterations, "growth_increments": self.increments,
                "shifted_factorizations": self.shifted,
                "negative_curvature_steps": self.descents, "ccd_cut_steps": self.ccd_cuts,
                "redone_increments": self.breaks}

    # --- one call: growth from A(t0) to A(t0 + n h) -----------------------------------
    def advance(self, model: Model, state: State, control: Control, n_steps: int, h: float,
                effects: Effects = NO_EFFECTS) -> None:
        if model.hinge_count and not np.all(model.hinge_stiffness > 0.0):
            raise ValueError("the quasi-static integrator needs bending stiffness > 0 (without "
                             "it a petal has no stiffness out of its plane)")
        if self._parts is None:
            self._couple(model, state, effects)
        if not self._perturbed and (control.growth_at((state.step + n_steps) * h)
                                    != control.growth_at(state.step * h)):
            # at the first growth (not before: a keyed hold of the bud holds to the bit)
            self._perturbed = True
            self._perturb(model, state, effects)
        if self._parts is None:
            self._parts = _split(model, effects)
            for part in self._parts:
                part.solver = QuasiStatic(self.stages, self.tolerance, self.max_iterations,
                                          perturbation=0.0, inertia=self.inertia)
        if not self._parts:
            self._advance(model, state, control, n_steps, h, effects)
        for part in self._parts:  # independent petals: each follows its own path
            part.state.positions[:] = state.positions[part.vertices]
            part.state.velocities[:] = state.velocities[part.vertices]

        def follow(part):
            try:
                part.solver._advance(part.model, part.state, control, n_steps, h, part.effects)
            except NotConverged as exc:
                exc.vertex = int(part.vertices[exc.vertex])  # name it in the whole mesh
                raise

        _map(follow, self._parts)
        for part in self._parts:
            state.positions[part.vertices] = part.state.positions
            state.velocities[part.vertices] = part.state.velocities
        if self._parts:
            state.step += n_steps
            self.iterations, self.increments, self.shifted, self.descents = (
                sum(getattr(p.solver, k) for p in self._parts)
                for k in ("iterations", "increments", "shifted", "descents"))
        if not self.inertia:
            state.velocities[:] = 0.0
        self._at(model, effects, control.growth_at(state.step * h))
        state.potential_energy = self._energy(state.positions, state.forces)
        effects.constrain(state.forces)
        if self._contact is not None:  # the frame's contacts: pairs within the barrier's band
            effects.counters[0] = self._contact.active_count(state.positions)

    def _couple(self, model: Model, state: State, effects: Effects) -> None:
        """Build the terms that couple the petals, if the scene has them; refuse a bud
        that contact cannot start from (:meth:`~pipeline.sim.terms.contact.Contact.check_start`)."""
        if effects.collisions is not None:
            c = effects.collisions
            self._contact = Contact.build(state.positions, c.faces, c.vertex_petal,
                                          gap=c.thickness,
                                          stiffness=float(model.edge_stiffness.max()))
            self._contact.check_start(state.positions)
        if effects.connections is not None:
            self._springs = Springs(effects.connections)

    def _advance(self, model, state, control, n_steps: int, h: float, effects) -> None:
        """:meth:`advance` for one connected mesh."""
        if self._system is None:
            self._system = _System.build(model, effects)
        if not self._started:  # settle at the start so that a tangent exists
            self._started = True
            a0 = control.growth_at(state.step * h)
            failure = self._newton(model, state, effects, a0)
            if failure is not None:
                raise self._not_converged(model, state.positions, state.step, a0, failure)
        a0 = control.growth_at(state.step * h)
        a1 = control.growth_at((state.step + n_steps) * h)
        pieces = max(1, math.ceil(abs(a1 - a0) * self.stages - 1e-9))
        if self.inertia:
            self._advance_dynamic(model, state, control, n_steps, h, effects, pieces)
            return
        targets = a0 + (a1 - a0) * np.arange(1, pieces + 1) / pieces
        first, last = state.step, state.step + n_steps

        def step_of(a: float) -> int:
            """The first step of this call at which the growth reaches ``a`` (A rises)."""
            lo, hi = first, last
            while lo < hi:
                mid = (lo + hi) // 2
                if control.growth_at(mid * h) >= a:
                    hi = mid
                else:
                    lo = mid + 1
            return lo

        done = a0
        for target in targets:
            done = self._reach(model, state, effects, done, float(target), last, step_of)
        state.step += n_steps

    def _advance_dynamic(self, model, state, control, n_steps: int, h: float, effects,
                         pieces: int) -> None:
        """:meth:`_advance` with the inertia term: ``pieces`` equal time steps ``dt`` (at
        least one per call, more where the growth rises fast), each an implicit Euler
        step in incremental-potential form, the minimum of ``U(x) + 1/(2 dt^2) |x -
        x_pred|_M^2`` with ``x_pred = x + dt v``; then ``v = (x_new - x) / dt``. A step
        where Newton fails is halved (up to 6 times); one that ends with connection
        springs past their breaking length breaks them and is redone."""
        t_end = (state.step + n_steps) * h
        for k in range(1, pieces + 1):
            t_from = state.step * h + (k - 1) * n_steps * h / pieces
            t_to = t_end if k == pieces else state.step * h + k * n_steps * h / pieces
            t_now, size, halvings = t_from, t_to - t_from, 0
            while t_now != t_to:
                t_next = t_to if t_to - t_now <= size * (1 + 1e-9) else t_now + size
                dt = t_next - t_now
                a_now, a_next = control.growth_at(t_now), control.growth_at(t_next)
                start = state.positions.copy()
                weight = model.vertex_mass / (dt * dt)
                self._dyn = Inertia(start + dt * state.velocities, weight)
                self._system.inertia = self._dyn.diagonal()
                try:
                    self._predict(model, state, effects, a_now, a_next,
                                  guess=self._dyn.predicted - start)
                    failure = self._newton(model, state, effects, a_next)
                finally:
                    self._dyn, self._system.inertia = None, None
                if failure is None:
                    over = self._springs.over_limit(state.positions) if self._springs else ()
                    if len(over):
                        c = self._springs.connections
                        c.alive[over] = False
                        c.broken_step[over] = int(round(t_next / h))
                        self.breaks += 1
                        state.positions[:] = start
                        continue
                    self.increments += 1
                    state.velocities[:] = (state.positions - start) / dt
                    t_now = t_next
                    continue
                state.positions[:] = start
                halvings += 1
                if halvings > 6:
                    raise self._not_converged(model, state.positions, int(round(t_next / h)),
                                              a_next, failure)
                size *= 0.5
        state.step += n_steps

    def _not_converged(self, model, X, step: int, growth: float,
                       failure: _Failure) -> NotConverged:
        """The failure, with the cause named: a piece held on a line (it can turn about
        it), no stable equilibrium (a stall where the Hessian is not positive definite:
        it buckles or snaps), or a stall at a positive definite Hessian."""
        from pipeline.flower.axis import MIN_BASE_WIDTH, base_width

        how = {"stalled": "found no descent along its step",
               "iterations": f"ran out of iterations ({self.max_iterations})",
               "shift": "found no shift that makes the Hessian positive definite"}[failure.how]
        pinned = model.pinned
        width = base_width(X[pinned], X)
        if width < MIN_BASE_WIDTH:
            cause = "weak"
            detail = (f"its piece is held by {int(pinned.sum())} fixed vertices on a line (they "
                      f"stray {width:.2g} of its length from it) and can turn about it "
                      f"(Newton {how})")
        elif failure.inertia != "definite":
            cause = "unstable"
            detail = (f"Newton {how} where the Hessian is {failure.inertia}: "
                      + ("its rest state is no stable equilibrium" if growth == 0.0 else
                         "it has no stable equilibrium there (it buckles or snaps)"))
        else:
            cause = "stalled"
            detail = f"Newton {how} where the Hessian is positive definite"
        return NotConverged(step, growth, failure.residual, scale=failure.scale, cause=cause,
                            detail=detail)

    def _perturb(self, model: Model, state: State, effects: Effects) -> None:
        if self.perturbation <= 0.0:
            return
        rng = np.random.default_rng(self.seed)
        nudge = rng.uniform(-self.perturbation, self.perturbation, state.positions.shape)
        nudge[model.pinned] = 0.0
        if effects.center_plane is not None:
            effects.constrain(nudge)
        state.positions += nudge

    def _reach(self, model, state, effects, a_from: float, a_to: float, step: int,
               step_of=None) -> float:
        """Equilibrium at growth ``a_to``; an increment where Newton fails is halved
        (up to 6 times), then the path goes on to ``a_to``. An increment that ends with
        connection springs past their breaking length breaks them (at ``step_of(A)``) and
        is redone from where it started."""
        a_now, size, halvings = a_from, a_to - a_from, 0
        while a_now != a_to:
            a_next = a_to if abs(a_to - a_now) <= abs(size) * (1 + 1e-9) else a_now + size
            start = state.positions.copy()
            self._predict(model, state, effects, a_now, a_next)
            failure = self._newton(model, state, effects, a_next)
            if failure is None:
                over = self._springs.over_limit(state.positions) if self._springs else ()
                if len(over):
                    c = self._springs.connections
                    c.alive[over] = False
                    c.broken_step[over] = step if step_of is None else step_of(a_next)
                    self.breaks += 1
                    state.positions[:] = start
                    self._behind = None  # (another path from here on)
                    continue
                self.increments += 1
                self._behind = (a_now, start)
                a_now = a_next
                continue
            state.positions[:] = start
            halvings += 1
            if halvings > 6:
                raise self._not_converged(model, state.positions, step, a_next, failure)
            size *= 0.5
        return a_to

    def _predict(self, model, state, effects, a_now: float, a_next: float,
                 guess: np.ndarray | None = None) -> None:
        """Predictor, from the equilibrium X at ``a_now`` to a start for ``a_next``, with a
        line search on the new energy (CCD-limited with contact). Secant where the
        equilibrium before it is known (``_behind``): the path extrapolated along the
        chord of the last two equilibria, which is as accurate as the tangent (the
        error is second order in the increment) and needs no factorization at X.
        Otherwise tangent (Euler), if a positive definite factorization is at hand:
        the step ``H^-1 f(x, A_next)``. ``guess``: a step to try first (with inertia,
        where the velocity carries the vertices: ``dt v``)."""
        X = state.positions
        self._at(model, effects, a_next)
        scratch = np.empty_like(X)
        energy, g = self._gradient(X, scratch)
        step = None
        behind = self._behind
        if guess is not None:
            step = self._constrained(guess)
            if not np.any(step) or float(g @ step) >= 0.0:
                step = None
        elif behind is not None and behind[0] != a_now and behind[1].shape == X.shape:
            secant = ((a_next - a_now) / (a_now - behind[0])) * (X - behind[1])
            step = self._constrained(secant)
            if float(g @ step) >= 0.0:  # not downhill on the new energy: no use
                step = None
        if step is None:
            if not self._system.tangent:
                return
            step = self._system.solve(-g)
        self.iterations += 1
        length = self._line_search(X, scratch, energy, g, step)
        for gr in self._system.groups:
            gr.moved = length * float(np.abs(step[gr.dofs]).max(initial=0.0))

    def _at(self, model: Model, effects: Effects, A: float) -> None:
        """Set the scene's terms (built once per model, :func:`~pipeline.sim.energy.build`) to growth A:
        every evaluation below (energy, gradient, Hessian, rounding) is of the growth
        last set here."""
        if self._terms is None or self._terms.model is not model:
            self._terms = energy.build(model, effects, contact=self._contact,
                                      springs=self._springs)
        self._terms.elastic.at(A)

    def _assemble(self, X, groups=None) -> None:
        """The constrained Hessian at X into the system's blocks; its elastic part only
        in the blocks of ``groups`` if given (the others' are not read until they are
        assembled again)."""
        s = self._system
        H = s.blocks
        elastic = self._terms.elastic
        parts = [p for gr in (s.groups if groups is None else groups) for p in gr.parts]
        if len(parts) > 1:  # (pieces touch blocks apart: they are assembled in threads)
            _map(lambda p: elastic.assemble(X, H, p), parts)
        elif parts:
            elastic.assemble(X, H, parts[0])
        constrain(H.indptr, H.indices, H.data, s.pinned, s.plane_row, s.normals)
        if s.project is not None:
            s.couple([t.hessian(X, project=True) for t in self._terms.coupling])

    def _links(self, X) -> np.ndarray:
        """(k, 2) vertex pairs the coupling terms join at X: the contacts within the
        barrier's band and the intact connection springs."""
        links = [np.zeros((0, 2), dtype=np.int64)]
        if self._contact is not None:
            links.append(self._contact.linked(X))
        if self._springs is not None:
            c = self._springs.connections
            links.append(np.asarray(c.pairs, dtype=np.int64)[np.asarray(c.alive, dtype=bool)])
        return np.concatenate(links)

    def _energy(self, X, scratch) -> float:
        """The energy at X; the forces into ``scratch``. With coupling terms, their
        forces are also kept (``_coupling``) for :meth:`_rounding`."""
        scratch[:] = 0.0
        energy = self._terms.elastic.forces(X, scratch)
        if self._dyn is not None:
            energy += self._dyn.forces(X, scratch)
        coupled = self._terms.coupling
        if not coupled:
            return energy
        coupling = self._coupling
        if coupling is None or coupling.shape != X.shape:
            coupling = self._coupling = np.empty_like(X)
        coupling[:] = 0.0
        for term in coupled:
            energy += term.forces(X, coupling)
        scratch += coupling
        return energy

    def _newton(self, model, state, effects, A: float) -> _Failure | None:
        """Newton iterations at growth A; None when converged, else why not.

        The pieces (petals) are grouped: those a contact or a connection spring joins
        are one linear system, the others each their own (:meth:`_System.regroup`), and
        each group is factored, and converges, apart. A group is converged when its
        residual force is at the rounding level of the forces (:meth:`_rounding`),
        whatever its Hessian's inertia (a piece free to turn, or at a bifurcation, has a
        singular Hessian at its equilibrium: that is no reason to go on); or below
        ``tolerance`` times the softest stiffness that matters with its Hessian
        positive definite (then the tangent predictor can use it); or when a Newton
        step moved it less than ``tolerance``. A converged group stays put while the
        others iterate (unless a new contact joins it to one of them).

        Where a group's H is positive definite the step is Newton's. Each group is
        factored afresh at its first iteration of the solve, then its factorization is
        reused for as long as each step cuts its residual at least ``1/CHORD`` times
        (a chord step: the Hessian has barely changed; a factorization is most of an
        iteration's cost). Where H is not positive definite (the path is at a
        bifurcation or a snap, or the prediction is far off), the energy is first
        searched along a direction of negative curvature read from the factorization
        (so a saddle is left in one step rather than by slow amplification of the
        perturbation); then the step solves ``(H + mu I) p = -g`` with ``mu`` grown
        tenfold until the factorization is positive definite (an implicit Euler step of
        the gradient flow, time step ``1/sqrt(mu)``).
        """
        X = state.positions
        self._at(model, effects, A)
        scratch = np.empty_like(X)
        residual = np.inf
        floor = 1e-3 * float(model.hinge_stiffness.max(initial=0.0) or model.edge_stiffness.max())
        top = 1e6 * float(model.edge_stiffness.max())  #: a shift past this: none helps
        system = self._system
        self.residuals = []
        scale = 0.0
        done: set = set()  #: groups converged by their step
        stale: set = set()  #: groups whose factorization a chord step failed with
        fresh: set = set()  #: groups factored in this solve
        chord: dict = {}  #: whether a group's step reuses its factorization
        self._accepted = None
        for _ in range(self.max_iterations):
            if self._accepted is not None:  # (the line search left X's forces in scratch)
                energy, g = self._accepted, self._constrained(-scratch)
                self._accepted = None
            else:
                energy, g = self._gradient(X, scratch)
            residual = float(np.abs(g).max())
            self.residuals.append(residual)
            scale, self._energy_rounding = self._rounding(X)
            rounding = ROUNDING_FACTOR * EPS * scale
            if residual <= rounding:
                return None  # at rounding: no step can do better
            # a mode as soft as floor moves less than tolerance
            if residual <= self.tolerance * floor and system.tangent:
                return None
            if system.project is not None and system.regroup(self._links(X)):
                done &= {gr.key for gr in system.groups}
                fresh &= {gr.key for gr in system.groups}
            moving = []
            solved = {}  #: the chord steps found, by group
            for gr in system.groups:
                r = float(np.abs(g[gr.dofs]).max()) if len(gr.dofs) else 0.0
                if (gr.key in done or r <= rounding
                        or (r <= self.tolerance * floor and gr.positive and gr.shift == 0.0
                            and gr.solver is not None)):
                    continue
                moving.append(gr)
                # a chord step (the factorization made at an earlier iteration of this
                # solve, unshifted and positive) if it is a tenth of the group's last step
                # or less: then the Hessian has barely changed where it matters
                chord[gr.key] = False
                if (gr.key in fresh and gr.positive and gr.shift == 0.0
                        and gr.key not in stale):
                    trial = gr.solver.solve(-g[gr.dofs])
                    chord[gr.key] = float(np.abs(trial).max()) <= CHORD * gr.moved
                    if chord[gr.key]:
                        solved[gr.key] = trial  # (the step, unless g changes below)
            if not moving:
                return None
            self.iterations += 1
            lost = []  # groups whose Hessian is not positive definite
            factored = [gr for gr in moving if not chord[gr.key]]
            if factored:
                self._assemble(X, factored)
            downs = []  # (the groups' directions of negative curvature)
            for gr, (positive, down) in zip(factored, _map(system.factor, factored), strict=True):
                fresh.add(gr.key)
                stale.discard(gr.key)
                if not positive:
                    lost.append(gr)
                    if down is not None:
                        downs.append(self._downhill(self._constrained(down), g))
            if self._contact is not None and len(downs) > 1:
                # (one sweep for all the groups' searches: each moves its group alone)
                self._contact.cover(X, X + DESCENT * sum(downs))
            for d in downs:
                self.descents += 1
                energy = self._descend(X, scratch, energy, d)
            if lost:
                energy, g = self._gradient(X, scratch)

                def shift(gr):
                    """The group's shift search: (mu, shifts rejected); mu None if none."""
                    mu, rejected = floor, 0
                    # (a shift that a direction of negative curvature rules out is
                    # rejected unfactored)
                    while (mu * (1.0 + 1e-6) < gr.need
                           or not system.factor(gr, mu, direction=False)[0]):
                        rejected += 1
                        mu *= 10.0
                        if mu > top:  # no shift makes it positive: not finite?
                            return None, rejected
                    return mu, rejected

                for _gr, (mu, rejected) in zip(lost, _map(shift, lost), strict=True):
                    self.shifted += rejected
                    if mu is None:
                        return _Failure(residual, scale, "shift", self._inertia())
            step = system.solve(-g, moving, None if lost else solved)
            length = self._line_search(X, scratch, energy, g, step)
            if length == 0.0:
                reused = [gr.key for gr in moving if chord[gr.key]]
                if reused:  # an old factorization is no excuse: factor afresh
                    stale.update(reused)
                    continue
                return _Failure(residual, scale, "stalled", self._inertia(lost))
            # (a step cut by CCD is no sign of convergence: the whole step was not small)
            for gr in moving:
                gr.moved = length * float(np.abs(step[gr.dofs]).max())
                if gr.shift == 0.0 and not self._limited and gr.moved < self.tolerance:
                    done.add(gr.key)
            # petals pressed together: the barrier's projected Hessian over-stiffens the
            # contact and Newton converges linearly there (0.3% a step on lily_open's
            # bud); a force a millionth of the force scale is converged
            if self._contact is not None and residual <= PRESSED * scale:
                done.update(gr.key for gr in moving if gr.shift == 0.0)
            if all(gr.key in done for gr in moving):  # (the others had converged)
                return None  # (the factorization is that of the equilibrium, to rounding)
        return _Failure(residual, scale, "iterations", self._inertia())

    def _inertia(self, lost=None) -> str:
        """The last factorizations' inertia, as a failure names it."""
        groups = self._system.groups if lost is None else lost
        if any(g.solver is None for g in groups):
            return "singular"
        return "definite" if all(g.positive for g in groups) else "indefinite"

    def _rounding(self, X) -> tuple[float, float]:
        """The force scale (the largest, over the vertices, of what the force kernel adds
        and subtracts there: :func:`~pipeline.sim.terms.elastic.rounding_scale`) and the rounding level of
        the energy. ``eps`` times the force scale bounds the gradient that rounding
        alone leaves (of coordinates, lengths, angles and sums), on any machine: a
        residual below it is no reason to iterate. Both scale with the stiffnesses and
        with the mesh's size, as the forces do."""
        per_vertex = self._scale_work
        if per_vertex is None or len(per_vertex) != len(X):
            per_vertex = self._scale_work = np.empty(len(X))
        energy = self._terms.elastic.rounding(X, per_vertex)
        if self._dyn is not None:  # the inertia term's force w (x - x_pred)
            x_pred, weight = self._dyn.predicted, self._dyn.weight
            size = np.abs(X).max(axis=1) + np.abs(x_pred).max(axis=1)
            per_vertex += weight * size
            energy += float(np.sum(weight * size * size))
        if self._coupling is not None:  # the contacts' and springs' forces at X (just taken)
            per_vertex += np.abs(self._coupling).max(axis=1)
            if self._springs is not None:
                self._springs.scale(X, per_vertex)
        free = ~self._system.pinned
        force = float(per_vertex[free].max()) if free.any() else 0.0
        return force, EPS * energy

    def _gradient(self, X, scratch) -> tuple[float, np.ndarray]:
        """Energy and gradient (flattened) with the constraints applied, from the force
        kernel."""
        energy = self._energy(X, scratch)
        return energy, self._constrained(-scratch)

    def _constrained(self, vec: np.ndarray) -> np.ndarray:
        """``vec`` (per vertex) without what the constraints forbid: nothing for a fixed
        vertex, no normal part for a center-plane vertex. Flattened copy."""
        out = np.array(vec, dtype=np.float64).reshape(-1, 3)
        for constraint in self._terms.constraints:
            constraint.project(out)
        return out.ravel()

    def _line_search(self, X, scratch, energy, g, step) -> float:
        """Backtracking (Armijo) along ``step``, from the longest step that continuous
        collision detection allows (1 without contact); moves X and returns the step
        length taken (0: none found). A change within rounding of the energy is accepted
        (as :meth:`_rounding` measures it, or 1e-14 of the energy)."""
        slope = float(g @ step)
        length = 1.0
        base = X.copy()
        self._limited = False
        if self._contact is not None:
            cap = self._contact.max_step(base, base + step.reshape(-1, 3))
            if cap < 1.0:
                length, self._limited = cap, True
                self.ccd_cuts += 1
        # two energies each within their rounding differ by up to twice it: a step whose
        # predicted change is below that cannot be judged by the energy (near an
        # equilibrium, where only the gradient still tells), so it is taken as Newton's
        blind = 2.0 * self._energy_rounding
        while length >= 1e-6:
            X[:] = base + length * step.reshape(-1, 3)
            trial = self._energy(X, scratch)
            change = abs(trial - energy)
            if (trial <= energy + 1e-4 * length * slope or change <= 1e-14 * abs(energy)
                    or (change <= blind and length * abs(slope) <= blind)):
                self._accepted = trial
                return length
            length *= 0.5
        X[:] = base
        return 0.0

    @staticmethod
    def _downhill(down, g) -> np.ndarray:
        """The direction ``down`` (flattened) as :meth:`_descend` searches it: per vertex,
        its largest component 1, its sign downhill on the energy of gradient ``g``."""
        d = down.reshape(-1, 3) / np.abs(down).max()
        return -d if float(g @ down) > 0.0 else d

    def _descend(self, X, scratch, energy, d) -> float:
        """Move X along the downhill negative-curvature direction ``d``
        (:meth:`_downhill`), by the length (doubling from 1e-3, at most
        :data:`DESCENT` mesh units) that lowers the energy most; returns the energy
        there."""
        base = X.copy()
        best, best_length, length = energy, 0.0, 1e-3
        top = DESCENT  # (no further than contact allows)
        if self._contact is not None:
            top *= self._contact.max_step(base, base + top * d)
        while length <= top:
            X[:] = base + length * d
            trial = self._energy(X, scratch)
            if trial >= best:
                break
            best, best_length = trial, length
            length *= 2.0
        X[:] = base + best_length * d
        return best

