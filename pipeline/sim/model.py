"""Model (static), State (changing) and Control (prescribed in time), after newton's split."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import PchipInterpolator

from pipeline.mesh.hinge import edge_lengths, hinge_cos_sin
from pipeline.mesh.topology import components
from pipeline.sim.terms.elastic import internal_forces
from pipeline.sim.terms.growth import SCHEDULE_CODES, growth_value
from pipeline.sim.terms.shell import ShellTerm


def _c(a, dtype) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=dtype)


def hinge_order(edges: np.ndarray, hinges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The edges in the order the force kernel reads fastest: edge h is hinge h's edge,
    as ``(i, j)`` of the hinge, wherever hinge h's edge is among ``edges`` (and not
    already taken by an earlier hinge); the other edges fill the remaining places in
    their given order. Then :func:`internal_forces` does edge h and hinge h in
    one pass. Hinges keep their order (effects index them).

    Returns ``(order, reordered)``: ``edges[order]``, with the hinge's orientation where
    it is a hinge's edge, is ``reordered``."""
    ne, nh = len(edges), len(hinges)
    order = np.arange(ne)
    if ne == 0 or nh == 0:
        return order, edges
    n = int(max(edges.max(), hinges[:, :2].max())) + 1
    ekey = np.minimum(edges[:, 0], edges[:, 1]) * n + np.maximum(edges[:, 0], edges[:, 1])
    hkey = np.minimum(hinges[:, 0], hinges[:, 1]) * n + np.maximum(hinges[:, 0], hinges[:, 1])
    by_key = np.argsort(ekey, kind="stable")
    pos = np.minimum(np.searchsorted(ekey[by_key], hkey), ne - 1)
    edge_of = np.where(ekey[by_key][pos] == hkey, by_key[pos], -1)  # (H,) first edge with the key
    edge_of[ne:] = -1  # only the first E hinges have a place
    first = np.zeros(nh, dtype=bool)  # the first hinge on each edge takes it
    _, at = np.unique(edge_of, return_index=True)
    first[at] = True
    slot = np.flatnonzero(first & (edge_of >= 0))
    order = np.full(ne, -1)
    order[slot] = edge_of[slot]
    used = np.zeros(ne, dtype=bool)
    used[edge_of[slot]] = True
    order[order < 0] = np.flatnonzero(~used)
    reordered = edges[order]
    reordered[slot] = hinges[slot, :2]
    return order, reordered


@dataclass
class Model:
    """What does not change while simulating. Built once by :meth:`build`, which checks it."""

    vertex_count: int
    vertex_mass: np.ndarray  #: (V,) mass of each vertex
    vertex_inv_mass: np.ndarray  #: (V,) 1/mass; 0 for pinned (base) vertices
    #: (E, 2) int64 vertex pairs; every edge carries a stretch spring. Not the order given
    #: to :meth:`build`: edge h is hinge h's edge i-j where it can be (see :func:`hinge_order`)
    edge_indices: np.ndarray
    edge_rest_length: np.ndarray  #: (E,) rest length at t = 0 (the input mesh's lengths)
    edge_growth: np.ndarray  #: (E,) growth ratio alpha (Eq. 6)
    edge_stiffness: np.ndarray  #: (E,) K_s of each spring
    hinge_indices: np.ndarray  #: (H, 4) int64, see :mod:`pipeline.mesh.hinge`
    hinge_rest_cos: np.ndarray  #: (H,) cos of the rest dihedral angle at t = 0
    hinge_rest_sin: np.ndarray  #: (H,) sin of the rest dihedral angle at t = 0
    hinge_stiffness: np.ndarray  #: (H,) K_b of each hinge
    #: the surface's elasticity (:class:`pipeline.sim.terms.shell.ShellData`) when the model is a
    #: shell (``simulate.model = "shell"``); then the springs and hinges above carry only
    #: the rest lengths and growth (the rest metric is made of them) and the paper's
    #: equivalent stiffnesses (the solver's scales, the contact barrier's stiffness)
    shell: object = None

    @property
    def edge_count(self) -> int:
        return len(self.edge_indices)

    @property
    def hinge_count(self) -> int:
        return len(self.hinge_indices)

    @property
    def pinned(self) -> np.ndarray:
        return self.vertex_inv_mass == 0.0

    @property
    def pieces(self) -> np.ndarray:
        """``(V,)`` each vertex's piece (a petal: the vertices its edges join), numbered
        by first vertex: no spring, hinge or face of one piece reaches another."""
        return components(self.edge_indices, self.vertex_count)

    @classmethod
    def build(cls, vertices, edges, edge_growth, edge_stiffness, hinges, hinge_stiffness,
              pinned, mass: float = 1.0) -> Model:
        """Rest lengths and rest angles are measured on ``vertices`` (the initial mesh)."""
        X = _c(vertices, np.float64)
        edges = _c(edges, np.int64).reshape(-1, 2)
        hinges = _c(hinges, np.int64).reshape(-1, 4)
        n = len(X)
        for name, idx in (("edges", edges), ("hinges", hinges)):
            if idx.size and (idx.min() < 0 or idx.max() >= n):
                raise ValueError(f"{name} index a vertex outside 0..{n - 1}")
        order, edges = hinge_order(edges, hinges)
        rest = np.empty(len(edges))
        edge_lengths(X, edges, rest)
        if np.any(rest <= 0.0):
            raise ValueError(f"{int(np.sum(rest <= 0))} edges have zero length")
        cos0 = np.empty(len(hinges))
        sin0 = np.empty(len(hinges))
        hinge_cos_sin(X, hinges, cos0, sin0)
        vmass = np.full(n, float(mass))
        inv = 1.0 / vmass
        inv[_c(pinned, bool)] = 0.0
        edge_growth = _c(np.broadcast_to(edge_growth, (len(edges),))[order], np.float64)
        if np.any(1.0 + edge_growth <= 0.0):
            raise ValueError("a growth ratio <= -1 would make a rest length zero or negative")
        return cls(
            vertex_count=n, vertex_mass=vmass, vertex_inv_mass=inv,
            edge_indices=edges, edge_rest_length=rest, edge_growth=edge_growth,
            edge_stiffness=_c(np.broadcast_to(edge_stiffness, (len(edges),))[order], np.float64),
            hinge_indices=hinges, hinge_rest_cos=cos0, hinge_rest_sin=sin0,
            hinge_stiffness=_c(np.broadcast_to(hinge_stiffness, (len(hinges),)), np.float64),
        )


@dataclass
class State:
    """Positions, velocities and the forces at those positions (and that state's time)."""

    positions: np.ndarray  #: (V, 3)
    velocities: np.ndarray  #: (V, 3)
    forces: np.ndarray  #: (V, 3) f(positions) at time ``step * h``
    step: int = 0  #: index of the time step this state is at
    potential_energy: float = 0.0
    scratch: np.ndarray = field(default=None, repr=False)  #: (V, 3) the integrator's f(X[n+1])

    @classmethod
    def at_rest(cls, model: Model, positions, control: Control) -> State:
        X = _c(positions, np.float64).copy()
        state = cls(X, np.zeros_like(X), np.zeros_like(X), 0, 0.0, np.zeros_like(X))
        if model.shell is not None:
            state.potential_energy = ShellTerm(model).at(control.growth_at(0.0)).forces(
                X, state.forces)
            return state
        state.potential_energy = internal_forces(
            X, model.edge_indices, model.edge_rest_length, model.edge_growth,
            model.edge_stiffness, model.hinge_indices, model.hinge_rest_cos,
            model.hinge_rest_sin, model.hinge_stiffness, control.growth_at(0.0), state.forces)
        return state

    def kinetic_energy(self, model: Model) -> float:
        return float(0.5 * np.sum(model.vertex_mass[:, None] * self.velocities ** 2))

    def max_speed(self) -> float:
        return float(np.sqrt(np.max(np.sum(self.velocities ** 2, axis=1)))) if len(self.velocities) else 0.0


@dataclass
class Control:
    """Growth prescribed over time: A(t) rises from 0 to 1 over ``ramp_time`` (Eq. 6), or,
    keyed (:meth:`keyed`), A read from ``table``."""

    schedule: str  #: linear, smoothstep, smootherstep, or table
    ramp_time: float  #: time at which A reaches 1 (table: the time the table spans)
    #: (N + 1,) A at N + 1 evenly spaced times from 0 to ``ramp_time`` (schedule "table"
    #: only; linear in between)
    table: np.ndarray = field(default_factory=lambda: np.zeros(1))

    @property
    def schedule_code(self) -> int:
        return SCHEDULE_CODES[self.schedule]

    def growth_at(self, t: float) -> float:
        return float(growth_value(self.schedule_code, float(t), float(self.ramp_time),
                                          self.table))

    @classmethod
    def keyed(cls, keys, frames: int, steps: int, h: float) -> Control:
        """A keyed in frames (``keys``: ``[[frame, A], ...]``, frames increasing, A not
        decreasing), as a table of A at every step. Frame ``f`` is at step ``f * steps /
        (frames - 1)`` (frame 0 the first stored frame, ``frames - 1`` the last). Between
        keys A follows a monotone cubic (PCHIP, Fritsch-Carlson): smooth (C1), never
        past its keys, flat where two keys hold the same value; before the first key and
        after the last it holds."""

        keys = np.asarray(keys, dtype=np.float64).reshape(-1, 2)
        frame = np.arange(steps + 1) * ((frames - 1) / steps)
        if len(keys) == 1:
            table = np.full(steps + 1, keys[0, 1])
        else:
            table = PchipInterpolator(keys[:, 0], keys[:, 1], extrapolate=False)(frame)
            table = np.where(frame <= keys[0, 0], keys[0, 1],
                             np.where(frame >= keys[-1, 0], keys[-1, 1], table))
        return cls("table", steps * h, np.ascontiguousarray(table, dtype=np.float64))
