"""The physical terms of a scene, each a unit with one interface.

A term is a piece of the potential energy. Every one answers, at positions ``X (V, 3)``
and the growth it was last set to (:meth:`Term.at`):

- ``forces(X, F) -> energy``: adds ``-dE/dX`` to ``F (V, 3)`` and returns ``E``: what a
  dynamic integrator needs, and what the Newton solver sums (its gradient is minus it);
- ``energy(X)``, ``gradient(X)``: the same, on their own;
- ``hessian(X, project=False)``: ``d2E/dX2`` as a ``(3V, 3V)`` scipy matrix (``None``
  when the term has nothing there); ``project=True`` gives the positive semi-definite
  form the Newton solver factors where the term defines one (contact), else the exact.

The terms (METHOD.md, "Constraints and effects"), each built only when the scene has it
(:func:`build`):

- :class:`Stretch` (Eq. 2) and :class:`Bending` (Eq. 3, with the curl of Eq. 11 moving
  its rest angles when the scene curls); :class:`Elastic` is the two in one pass, the
  form the solvers run (``kernels.advance`` fuses the same arithmetic into its step);
- :class:`Inertia`: ``1/2 |x - x_pred|_M^2 / dt^2``, the implicit Euler step in
  incremental-potential form (``simulate.inertia``);
- :class:`~pipeline.sim.contact.Contact`: the IPC barrier between petals
  (``effects.collisions``);
- :class:`~pipeline.sim.contact.Springs`: the connection springs
  (``effects.connections``);
- wrinkles act through the growth map (``bloom growth``) and are in :class:`Stretch`'s
  rest lengths and stiffnesses.

The fixed base and the center plane are not energies but constraints: they take away
directions (:class:`FixedBase`, :class:`CenterPlane`, ``project``). The Newton solver
projects its gradient and Hessian with them; the dynamic integrators zero the fixed
vertices' inverse mass and project the plane vertices' forces.

The paper's push-back (``pipeline/sim/pushback.py``) is a response after the step, not
an energy, and stays inside the explicit kernel.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from . import hessian as hs
from .constraints import curl_rest_angles
from .elastic import _W_SIZE, _add_forces, bending_forces, stretch_forces


class Term:
    """One piece of the energy; subclasses define :meth:`forces` and :meth:`hessian`."""

    name = "term"

    def at(self, growth: float) -> Term:
        """Set the growth A(t) the term is evaluated at (terms that do not grow ignore
        it); returns the term."""
        return self

    def forces(self, X, F) -> float:
        raise NotImplementedError

    def hessian(self, X, project: bool = False):
        raise NotImplementedError

    def energy(self, X) -> float:
        return self.forces(X, np.zeros_like(X, dtype=np.float64))

    def gradient(self, X) -> np.ndarray:
        F = np.zeros_like(X, dtype=np.float64)
        self.forces(X, F)
        return -F


def _blocks_matrix(vertex_count, edges, hinges, fill) -> sp.csr_matrix:
    """A (3V, 3V) matrix from 3x3 blocks that ``fill(data, edge_slots, hinge_slots)``
    adds into (the Hessian kernels' layout)."""
    indptr, indices, eslots, hslots = hs.block_pattern(vertex_count, edges, hinges)
    data = np.zeros((len(indices), 3, 3))
    fill(data, eslots, hslots)
    n = 3 * vertex_count
    return sp.bsr_matrix((data, indices, indptr), shape=(n, n)).tocsr()


class Stretch(Term):
    """Springs on the edges (Eq. 2): ``1/2 k (l - L)^2``, ``L = L0 (1 + A alpha)`` (Eq. 6)."""

    name = "stretch"

    def __init__(self, edges, rest0, growth, stiffness, vertex_count: int):
        self.edges, self.rest0, self.growth, self.stiffness = edges, rest0, growth, stiffness
        self.vertex_count, self.A = vertex_count, 0.0

    @classmethod
    def of(cls, model) -> Stretch:
        return cls(model.edge_indices, model.edge_rest_length, model.edge_growth,
                   model.edge_stiffness, model.vertex_count)

    def at(self, growth: float) -> Stretch:
        self.A = float(growth)
        return self

    def forces(self, X, F) -> float:
        return stretch_forces(X, self.edges, self.rest0, self.growth, self.stiffness, self.A, F)

    def hessian(self, X, project: bool = False) -> sp.csr_matrix:
        return _blocks_matrix(
            self.vertex_count, self.edges, np.zeros((0, 4), dtype=np.int64),
            lambda data, es, hs_: hs.stretch_terms(X, self.edges, self.rest0, self.growth,
                                                   self.stiffness, self.A, data, es))


class Bending(Term):
    """Angular springs across interior edges (Eq. 3): ``K_b (1 - cos(theta - theta0))``.
    With curl, the rest angles decay with the growth, ``theta0 (1 - A beta)`` (Eq. 11)."""

    name = "bending"

    def __init__(self, hinges, rest_cos, rest_sin, stiffness, vertex_count: int, curl=None):
        self.hinges, self.stiffness, self.curl = hinges, stiffness, curl
        self.vertex_count = vertex_count
        self.cos0, self.sin0 = rest_cos, rest_sin
        self._rest = (rest_cos, rest_sin)

    @classmethod
    def of(cls, model, curl=None) -> Bending:
        """``curl``: the scene's :class:`~pipeline.sim.effects.Curl`, or None."""
        return cls(model.hinge_indices, model.hinge_rest_cos, model.hinge_rest_sin,
                   model.hinge_stiffness, model.vertex_count, curl)

    def at(self, growth: float) -> Bending:
        if self.curl is None:
            self.cos0, self.sin0 = self._rest
        else:
            c = self.curl
            curl_rest_angles(c.theta0, growth * c.beta, c.cos_t, c.sin_t)
            self.cos0, self.sin0 = c.cos_t, c.sin_t
        return self

    def forces(self, X, F) -> float:
        return bending_forces(X, self.hinges, self.cos0, self.sin0, self.stiffness, F)

    def hessian(self, X, project: bool = False) -> sp.csr_matrix:
        work = np.zeros((7, 4, 3, 3))
        return _blocks_matrix(
            self.vertex_count, np.zeros((0, 2), dtype=np.int64), self.hinges,
            lambda data, es, hs_: hs.bending_terms(X, self.hinges, self.cos0, self.sin0,
                                                   self.stiffness, data, hs_, work))


class Elastic(Term):
    """:class:`Stretch` and :class:`Bending` in one pass (each edge's spring rides with
    its hinge): the form the solvers run. Its Hessian is assembled into the solver's
    fixed block pattern (:class:`~pipeline.sim.hessian.Blocks`, :meth:`assemble`)."""

    name = "elastic"

    def __init__(self, stretch: Stretch, bending: Bending):
        self.stretch, self.bending = stretch, bending
        self._work = np.empty(_W_SIZE)
        self._blocks = None

    @classmethod
    def of(cls, model, curl=None) -> Elastic:
        return cls(Stretch.of(model), Bending.of(model, curl))

    @property
    def A(self) -> float:
        return self.stretch.A

    def at(self, growth: float) -> Elastic:
        self.stretch.at(growth)
        self.bending.at(growth)
        return self

    def forces(self, X, F) -> float:
        s, b = self.stretch, self.bending
        return _add_forces(X, s.edges, s.rest0, s.growth, s.stiffness, b.hinges, b.cos0, b.sin0,
                           b.stiffness, s.A, F, self._work)

    def assemble(self, X, blocks: hs.Blocks, part: hs.Part | None = None) -> None:
        """The Hessian at X into ``blocks`` (zeroed first): the solver's layout.
        ``part``: a part of the mesh that no other element touches (a petal): only its
        blocks are zeroed and assembled (the same sums, in the same order), with the
        part's own scratch; the others are left as they are."""
        s, b = self.stretch, self.bending
        if part is None:
            hs.hessian(X, s.edges, s.rest0, s.growth, s.stiffness, b.hinges, b.cos0, b.sin0,
                       b.stiffness, s.A, blocks.data, blocks.edge_slots, blocks.hinge_slots,
                       blocks.work)
            return
        e, h = part.edges, part.hinges
        if part.static is None:
            part.static = (s.edges[e], s.rest0[e], s.growth[e], s.stiffness[e],
                           blocks.edge_slots[e], b.hinges[h], b.stiffness[h],
                           blocks.hinge_slots[h])
        edges, rest0, growth, stiffness, edge_slots, hinges, hinge_k, hinge_slots = part.static
        blocks.data[part.blocks] = 0.0
        if len(e):
            hs.stretch_terms(X, edges, rest0, growth, stiffness, s.A, blocks.data, edge_slots)
        if len(h):
            hs.bending_terms(X, hinges, b.cos0[h], b.sin0[h], hinge_k, blocks.data,
                             hinge_slots, part.work)

    def hessian(self, X, project: bool = False) -> sp.csr_matrix:
        s, b = self.stretch, self.bending
        if self._blocks is None:
            indptr, indices, es, hs_ = hs.block_pattern(s.vertex_count, s.edges, b.hinges)
            self._blocks = hs.Blocks(indptr, indices, es, hs_, np.zeros((len(indices), 3, 3)),
                                     np.zeros((7, 4, 3, 3)))
        self.assemble(X, self._blocks)
        return self._blocks.matrix().tocsr()

    def rounding(self, X, per_vertex) -> float:
        """What the force kernel adds and subtracts, per vertex into ``per_vertex``; the
        energy's rounding scale (see :func:`~pipeline.sim.hessian.rounding_scale`)."""
        s, b = self.stretch, self.bending
        return hs.rounding_scale(X, s.edges, s.rest0, s.growth, s.stiffness, b.hinges, b.cos0,
                                 b.sin0, b.stiffness, s.A, per_vertex)


class Inertia(Term):
    """``1/2 sum_v w_v |x_v - x_pred_v|^2``, ``w = m / dt^2``, ``x_pred = x + dt v``:
    with it, a minimum of the energy is an implicit Euler step (incremental-potential
    form)."""

    name = "inertia"

    def __init__(self, predicted, weight):
        self.predicted = np.asarray(predicted, dtype=np.float64)
        self.weight = np.asarray(weight, dtype=np.float64)

    def forces(self, X, F) -> float:
        d = X - self.predicted
        F -= self.weight[:, None] * d
        return 0.5 * float(np.sum(self.weight[:, None] * d * d))

    def diagonal(self) -> np.ndarray:
        """The Hessian's diagonal, per unknown (3V,)."""
        return np.repeat(self.weight, 3)

    def hessian(self, X, project: bool = False) -> sp.csr_matrix:
        return sp.diags(self.diagonal()).tocsr()


class FixedBase:
    """The fixed petal base (Eq. 10): its vertices never move."""

    name = "fixed_base"

    def __init__(self, pinned):
        self.pinned = np.asarray(pinned, dtype=bool)

    def project(self, vec) -> None:
        """Remove from ``vec (V, 3)``, in place, what the constraint forbids."""
        vec[self.pinned] = 0.0


class CenterPlane:
    """Axis vertices keep their distance to their petal's center plane: no motion along
    its normal."""

    name = "center_plane"

    def __init__(self, vertices, normals):
        self.vertices = np.asarray(vertices, dtype=np.int64)
        self.normals = np.asarray(normals, dtype=np.float64)

    def project(self, vec) -> None:
        if len(self.vertices):
            v, n = self.vertices, self.normals
            vec[v] -= np.einsum("ij,ij->i", vec[v], n)[:, None] * n


class Terms:
    """What a scene's energy is made of: the elastic unit, the coupling terms (contact,
    connection springs) the scene has, and its constraints. Built by :func:`build`."""

    def __init__(self, elastic: Elastic, coupling: list, constraints: list, model=None):
        self.elastic, self.coupling, self.constraints = elastic, coupling, constraints
        self.model = model  #: the model they were built of

    def __iter__(self):
        """The energy terms (the constraints are not)."""
        return iter([self.elastic.stretch, self.elastic.bending, *self.coupling])

    def names(self) -> list[str]:
        return [t.name for t in self] + [c.name for c in self.constraints]


def build(model, effects, *, contact=None, springs=None) -> Terms:
    """The terms of a scene: stretch and bending always (curl if the scene curls), the
    coupling terms given (``contact``: a :class:`~pipeline.sim.contact.Contact`;
    ``springs``: :class:`~pipeline.sim.contact.Springs`), the fixed base, and the center
    plane if the scene has it."""
    constraints = [FixedBase(model.pinned)]
    if effects.center_plane is not None:
        constraints.append(CenterPlane(effects.center_plane.vertices,
                                       effects.center_plane.normals))
    coupling = [t for t in (contact, springs) if t is not None]
    return Terms(Elastic.of(model, effects.curl), coupling, constraints, model)
