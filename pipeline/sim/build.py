"""One builder: the arrays the stages make (a mesh, its axes, its growth map) to what the
simulator runs (:class:`~pipeline.sim.model.Model`, the scene's
:class:`~pipeline.sim.effects.Effects`, the petal frames the opening is measured in).

The simulate stage builds it from growth.h5 (:meth:`Prepared.from_artifact`); the
accuracy study, the bench and the tests from a mesh (:meth:`Prepared.from_mesh`, the
library's axis and growth stages on it). Either way the same calls make the Model and
the Effects, so a scene simulated by the pipeline and by a study are the same problem.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import effects as fx
from .model import Model


@dataclass
class Prepared:
    """A mesh taken through the remesh, axis and growth stages, as arrays."""

    vertices: np.ndarray  #: (V, 3) the rest state (mean edge 1)
    faces: np.ndarray  #: (F, 3)
    petal: np.ndarray  #: (V,) petal of each vertex
    base: np.ndarray  #: (V,) bool, the fixed base
    on_axis: np.ndarray  #: (V,) bool
    s: np.ndarray  #: (V,) along the axis, 0 at the base, 1 at the tip
    x: np.ndarray  #: (V,) across, -1 .. 1
    tip: np.ndarray  #: (P,) tip vertex of each petal
    plane: np.ndarray  #: (P, 4) each petal's center plane
    flower_axis: np.ndarray  #: (6,) point and direction (nan for a lone petal)
    edges: np.ndarray  #: (E, 2)
    alpha: np.ndarray  #: (E,) growth ratios
    stiffness: np.ndarray  #: (E,) factors on simulate.stretch_stiffness
    hinges: np.ndarray  #: (H, 4)
    rest_angle: np.ndarray  #: (H,) dihedral angles of the rest state

    @classmethod
    def from_artifact(cls, src) -> Prepared:
        """From growth.h5 (or any later artifact that carries its datasets)."""
        return cls(src["mesh/vertices"], src["mesh/faces"], src["mesh/petal"], src["axis/base"],
                   src["axis/on_axis"], src["axis/s"], src["axis/x"], src["axis/tip"],
                   src["axis/plane"], np.asarray(src.attrs["flower_axis"]), src["growth/edges"],
                   src["growth/alpha"], src["growth/stiffness"], src["growth/hinges"],
                   src["growth/rest_angle"])

    @classmethod
    def of(cls, vertices, faces, petal, axes, growth) -> Prepared:
        """From the library's own results (:func:`pipeline.axis.find_axes`,
        :func:`pipeline.growth.assign_growth`)."""
        return cls(vertices, faces, petal, axes.base, axes.on_axis, axes.s, axes.x, axes.tip,
                   axes.plane, np.asarray(axes.flower_axis), growth.edges, growth.alpha,
                   growth.stiffness, growth.hinges, growth.rest_angle)

    @classmethod
    def from_mesh(cls, vertices, faces, petal, curve: str = "0.2*x**2", *,
                  alpha_add: float = 0.0, boundary_stiffness: float = 1.0) -> Prepared:
        """A bud mesh scaled to mean edge 1 (as `bloom remesh` leaves it), its axes and its
        growth map (``alpha_add``, ``boundary_stiffness``: the wrinkles of Eq. 12)."""
        from .. import clean
        from ..axis import find_axes
        from ..growth import assign_growth

        v = np.asarray(vertices, dtype=np.float64)
        v = v / clean.mean_edge_length(v, faces)
        axes = find_axes(v, faces, petal)
        growth = assign_growth(v, faces, axes.x, curve, alpha_add=alpha_add,
                               boundary_stiffness=boundary_stiffness)
        return cls.of(v, faces, petal, axes, growth)

    def model(self, stretch: float, bending: float, mass: float = 1.0, pinned=None) -> Model:
        """The springs (``stretch`` times each edge's stiffness factor) and hinges
        (``bending``), rest state measured on :attr:`vertices`, the base fixed."""
        return Model.build(self.vertices, self.edges, self.alpha, stretch * np.asarray(self.stiffness),
                           self.hinges, bending, self.base if pinned is None else pinned, mass=mass)

    def effects(self, names, params: dict, *, positions=None, rest_angle=None,
                max_edge: float | None = None) -> fx.Effects:
        """The effects ``names`` (those the scene enabled), built at ``positions`` (default
        the rest state) from the ``effects`` config section ``params``. ``max_edge``: the
        longest edge the collision grid must hold (default: the longest fully grown edge)."""
        positions = self.vertices if positions is None else positions
        if max_edge is None:
            max_edge = self.max_grown_edge()
        return fx.build(names, vertices=positions, faces=self.faces, petal=self.petal,
                        pinned=self.base, on_axis=self.on_axis, plane=self.plane, s=self.s,
                        rest_angle=self.rest_angle if rest_angle is None else rest_angle,
                        flower_axis=self.flower_axis, max_edge=max_edge, params=params)

    def max_grown_edge(self) -> float:
        """The longest edge at full growth (``L (1 + max(alpha, 0))``, measured as the
        model measures its rest lengths): what the collision grid's cells must hold."""
        from .. import clean
        from .elastic import edge_lengths

        edges = np.ascontiguousarray(self.edges, dtype=np.int64).reshape(-1, 2)
        if len(edges) == 0:
            return clean.mean_edge_length(self.vertices, self.faces)
        length = np.empty(len(edges))
        edge_lengths(np.ascontiguousarray(self.vertices, dtype=np.float64), edges, length)
        return float((length * (1.0 + np.maximum(np.asarray(self.alpha), 0.0))).max())

    def frames(self, positions=None):
        """The petal frames the opening angle is measured in, at ``positions`` (default
        the rest state)."""
        from ..measure import PetalFrames

        return PetalFrames.from_mesh(self.vertices if positions is None else positions,
                                     self.petal, self.base, self.on_axis, self.tip, self.plane,
                                     flower_axis=self.flower_axis)
