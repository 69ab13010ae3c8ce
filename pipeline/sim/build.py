"""One builder: the arrays the stages make (a mesh, its axes, its growth map) to what the
simulator runs (:class:`~pipeline.sim.model.Model`, the scene's
:class:`~pipeline.sim.effects.Effects`, the petal frames the opening is measured in).

The simulate stage builds it from growth.h5 (:meth:`Prepared.from_artifact`); the
accuracy study, the bench and the tests from a mesh (:meth:`Prepared.from_mesh`, the
library's axis and growth stages on it). Either way the same calls make the Model and
the Effects, so a scene simulated by the pipeline and by a study are the same problem.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from dataclasses import dataclass

import numpy as np

from pipeline.config import dotted_keys
from pipeline.flower.axis import BadPetal, WeakBase, find_axes
from pipeline.flower.growth import GrowthMap, assign_growth
from pipeline.flower.measure import PetalFrames, leans
from pipeline.mesh import clean
from pipeline.mesh.hinge import edge_lengths
from pipeline.sim import effects as fx
from pipeline.sim.model import Model
from pipeline.sim.terms.elastic import internal_forces
from pipeline.sim.terms.shell import POISSON, ShellData, petal_size

log = logging.getLogger("bloom")


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
    #: (6,) point and direction (nan for a lone petal); (P, 6) each petal's flower's, in
    #: a part of several flowers that bloom as one problem (:meth:`flowers_part`)
    flower_axis: np.ndarray
    edges: np.ndarray  #: (E, 2)
    alpha: np.ndarray  #: (E,) growth ratios
    stiffness: np.ndarray  #: (E,) factors on simulate.stretch_stiffness
    hinges: np.ndarray  #: (H, 4)
    rest_angle: np.ndarray  #: (H,) dihedral angles of the rest state
    #: (V,) a thick petal's mid-surface thickness (mesh units; 0 for sheets), or None
    thickness: np.ndarray | None = None
    #: (K, 2) petal pairs left through each other as modelled (remesh could not move them
    #: apart): no contact between the two of a pair; None: none
    left: np.ndarray | None = None
    #: (V,) each vertex's flower in a file of many (remesh's ``flower/petal_flower``), or
    #: None: one flower
    flower: np.ndarray | None = None
    #: (K, 6) each flower's axis, point and direction (``flower/axis``), or None: one
    #: flower, :attr:`flower_axis`
    flower_axes: np.ndarray | None = None
    #: flowers that bloom together (:meth:`flowers_part`): the bud search keeps contact
    #: within each (:attr:`flower` apart), the bloom has contact between them too
    together: bool = False
    #: with :attr:`together`, the bud search has contact between the flowers too: their
    #: buds searched within each can pass through each other (a branch's blossoms a few
    #: tenths of a petal apart), and the bloom cannot start from them
    searched_together: bool = False
    #: each petal held further than its base, up to this ``s`` (every vertex within it
    #: fixed; simulate's second try for a bowl), or None
    held: float | None = None
    #: the triangles contact keeps apart where the solve is on a mesh cut finer (the
    #: coarse mesh's, on its vertices, which come first: :meth:`refined`), or None: faces
    contact_faces: np.ndarray | None = None
    #: the keys the stages that made these arrays ran with, dotted (growth.h5's record;
    #: empty where unknown): what a solve cut finer finds the axes and growth again by
    recorded: dict = dataclasses.field(default_factory=dict)

    @classmethod
    def from_artifact(cls, src) -> Prepared:
        """From growth.h5 (or any later artifact that carries its datasets)."""
        return cls(src["mesh/vertices"], src["mesh/faces"], src["mesh/petal"], src["axis/base"],
                   src["axis/on_axis"], src["axis/s"], src["axis/x"], src["axis/tip"],
                   src["axis/plane"], np.asarray(src.attrs["flower_axis"]), src["growth/edges"],
                   src["growth/alpha"], src["growth/stiffness"], src["growth/hinges"],
                   src["growth/rest_angle"],
                   src["mesh/thickness"] if "mesh/thickness" in src else None,
                   np.asarray(src["mesh/left"]) if "mesh/left" in src else None,
                   np.asarray(src["flower/petal_flower"])[np.asarray(src["mesh/petal"])]
                   if "flower/petal_flower" in src else None,
                   np.asarray(src["flower/axis"]) if "flower/axis" in src else None,
                   recorded=dotted_keys(json.loads(src.attrs["config"]))
                   if "config" in src.attrs else {})

    @classmethod
    def of(cls, vertices, faces, petal, axes, growth) -> Prepared:
        """From the library's own results (:func:`pipeline.flower.axis.find_axes`,
        :func:`pipeline.flower.growth.assign_growth`)."""
        return cls(vertices, faces, petal, axes.base, axes.on_axis, axes.s, axes.x, axes.tip,
                   axes.plane, np.asarray(axes.flower_axis), growth.edges, growth.alpha,
                   growth.stiffness, growth.hinges, growth.rest_angle)

    @classmethod
    def from_mesh(cls, vertices, faces, petal, curve: str = "0.2*x**2", *,
                  alpha_add: float = 0.0, boundary_stiffness: float = 1.0) -> Prepared:
        """A bud mesh scaled to mean edge 1 (as `bloom remesh` leaves it), its axes and its
        growth map (``alpha_add``, ``boundary_stiffness``: the wrinkles of Eq. 12)."""
        v = np.asarray(vertices, dtype=np.float64)
        v = v / clean.mean_edge_length(v, faces)
        axes = find_axes(v, faces, petal)
        growth = assign_growth(v, faces, axes.x, curve, alpha_add=alpha_add,
                               boundary_stiffness=boundary_stiffness)
        return cls.of(v, faces, petal, axes, growth)

    def flower_part(self, k: int) -> tuple[Prepared, np.ndarray]:
        """Flower ``k`` of a file of many (:attr:`flower`) as a problem of its own: its
        vertices, faces, petals (numbered from 0 in their order), edges and hinges
        renumbered, its axis the flower's; and ``(n,)`` its vertices' indices here."""
        return self.flowers_part([k])

    def flowers_part(self, ks) -> tuple[Prepared, np.ndarray]:
        """Flowers ``ks`` of a file of many as one problem (:meth:`flower_part` of one):
        contact between them too, and each petal's flower's axis (``flower_axis``
        ``(P, 6)``) where there are several."""
        ks = sorted(int(k) for k in ks)
        idx = np.flatnonzero(np.isin(np.asarray(self.flower), ks))
        new = np.full(len(self.vertices), -1, dtype=np.int64)
        new[idx] = np.arange(len(idx))
        petal = np.asarray(self.petal)
        petals = np.unique(petal[idx])
        renumber = np.full(len(self.tip), -1, dtype=np.int64)
        renumber[petals] = np.arange(len(petals))

        def inside(cells):
            cells = np.asarray(cells, dtype=np.int64)
            keep = np.all(new[cells] >= 0, axis=1) if len(cells) else np.zeros(0, dtype=bool)
            return new[cells[keep]], keep

        faces, _ = inside(self.faces)
        edges, on_edge = inside(self.edges)
        hinges, on_hinge = inside(self.hinges)

        def part(a):
            return None if a is None else np.asarray(a)[idx]

        axis = np.asarray(self.flower_axis)
        if self.flower_axes is not None:
            axes = np.asarray(self.flower_axes, dtype=np.float64)
            axis = axes[ks[0]]
            if len(ks) > 1:  # (each petal's flower's)
                of = np.zeros(len(petals), dtype=np.int64)
                of[renumber[petal[idx]]] = np.asarray(self.flower)[idx]
                axis = axes[of]

        together = {}
        if len(ks) > 1:  # (each flower's bud its own; the bloom one)
            together = {"flower": np.searchsorted(ks, np.asarray(self.flower)[idx]),
                        "flower_axes": None if self.flower_axes is None
                        else np.asarray(self.flower_axes, dtype=np.float64)[ks],
                        "together": True}
        return Prepared(
            np.asarray(self.vertices)[idx], faces, renumber[petal[idx]],
            np.asarray(self.base)[idx], np.asarray(self.on_axis)[idx], np.asarray(self.s)[idx],
            np.asarray(self.x)[idx], new[np.asarray(self.tip)[petals]],
            np.asarray(self.plane)[petals], axis, edges, np.asarray(self.alpha)[on_edge],
            np.asarray(self.stiffness)[on_edge], hinges, np.asarray(self.rest_angle)[on_hinge],
            part(self.thickness), self._left_among(renumber), **together), idx

    def scaled(self, factor: float) -> Prepared:
        """The same problem ``factor`` times the size: its vertices, center planes'
        offsets, flowers' axis points and thicknesses scaled; everything else (``s``,
        ``x``, growth ratios, stiffness factors, angles) has no unit."""
        def points(axes):  # ((6,) or (K, 6): point, direction)
            if axes is None:
                return None
            axes = np.array(axes, dtype=np.float64)
            axes[..., :3] *= factor
            return axes

        plane = np.array(self.plane, dtype=np.float64)
        plane[:, 3] *= factor
        return dataclasses.replace(
            self, vertices=factor * np.asarray(self.vertices, dtype=np.float64), plane=plane,
            flower_axis=points(self.flower_axis), flower_axes=points(self.flower_axes),
            thickness=None if self.thickness is None
            else factor * np.asarray(self.thickness, dtype=np.float64))

    def _left_among(self, renumber) -> np.ndarray | None:
        """:attr:`left`'s pairs of petals both kept, in their new numbers (``renumber``
        (P,): each petal's, -1 where it is not kept)."""
        if self.left is None:
            return None
        pairs = renumber[np.asarray(self.left, dtype=np.int64).reshape(-1, 2)]
        return pairs[np.all(pairs >= 0, axis=1)]

    def refined(self, levels: int, rule: dict, *, axes: dict | None = None) -> Prepared:
        """The same petals cut ``levels`` times finer (:func:`pipeline.mesh.subdivide.
        subdivide`), the old vertices first, with their indices (so a frame of the fine
        problem holds this one's in its first rows), each new vertex on the smooth surface
        through the old.

        ``axes``: the axis stage's options (:func:`pipeline.chain.axis.axis_options`):
        each petal's base, axis, tip, ``s`` and ``x`` found again on the finer mesh (the
        same center planes and outline corners), as the axis stage would have found them
        there, unless a petal's base would then lie elsewhere (its old base vertices past
        :data:`REFINED_BASE` of its length: then, and without ``axes``, every new vertex
        has its edge's mean ``s``, ``x`` and thickness, and is fixed and on the axis where
        both ends are). A base held further (:attr:`held`) is held as far on the finer
        mesh. The growth map is made again on the finer edges by the growth stage's own
        rule (``rule``: :func:`pipeline.flower.growth.growth_rule`). Contact stays on this
        mesh's triangles (:attr:`contact_faces`), whose vertices come first."""
        from pipeline.mesh.remesh import outline_corners
        from pipeline.mesh.subdivide import subdivide

        v, f = np.asarray(self.vertices, dtype=np.float64), np.asarray(self.faces)
        corners = outline_corners(v, f)  # (kept at every level: see outline_corners)
        fields = {"petal": self.petal, "base": self.base, "on_axis": self.on_axis, "s": self.s,
                  "x": self.x, "thickness": self.thickness,
                  "flower": self.flower}
        fields = {k: None if a is None else np.asarray(a) for k, a in fields.items()}
        for _ in range(levels):
            v, f, parent = subdivide(v, f, corners)
            corners = np.concatenate([corners, np.zeros(len(parent), dtype=bool)])
            i, j = parent[:, 0], parent[:, 1]
            for k, a in fields.items():
                if a is None:
                    continue
                if a.dtype == bool:  # (fixed, on the axis: where both ends are)
                    new = a[i] & a[j]
                elif k in ("s", "x", "thickness"):
                    new = 0.5 * (a[i] + a[j])
                else:  # (petal, flower: an edge's ends share them)
                    new = a[i]
                fields[k] = np.concatenate([a, new])
        tip, plane = np.asarray(self.tip), np.asarray(self.plane)
        if axes is not None and levels > 0:
            found = self._axes_again(v, f, fields, axes, corners)
            if found is not None:
                fields.update(base=found.base, on_axis=found.on_axis, s=found.s, x=found.x)
                tip, plane = found.tip, found.plane
        if self.held is not None:
            fields["base"] = fields["base"] | (fields["s"] <= self.held)
        g = assign_growth(v, f, fields["x"], **rule)
        return dataclasses.replace(self, vertices=v, faces=f, tip=tip, plane=plane, edges=g.edges,
                                   alpha=g.alpha, stiffness=g.stiffness, hinges=g.hinges,
                                   rest_angle=g.rest_angle, contact_faces=self.faces
                                   if self.contact_faces is None else self.contact_faces,
                                   **fields)

    def _axes_again(self, v, f, fields: dict, axes: dict, corners=None):
        """The axes found on the finer mesh ``v, f`` (:meth:`refined`), or None where they
        cannot be found or a petal's base would move (logged)."""
        petal = fields["petal"]
        flower = None
        if fields["flower"] is not None:  # (each petal's flower)
            flower = np.zeros(len(self.tip), dtype=np.int64)
            flower[petal] = fields["flower"]
        try:
            found = find_axes(v, f, petal, **axes, planes=np.asarray(self.plane), flower=flower,
                              corners=corners)
        except (BadPetal, WeakBase, ValueError) as exc:
            log.info("the axes on the finer mesh: %s; the old ones carried over", exc)
            return None
        old = np.flatnonzero(np.asarray(self.base))  # (the old vertices keep their indices)
        reach = np.zeros(len(self.tip))
        np.maximum.at(reach, petal[old], found.s[old])
        if np.any(reach > REFINED_BASE):
            log.info("the axes on the finer mesh put petal %d's base elsewhere (its old base "
                     "up to s = %.2f); the old ones carried over", int(np.argmax(reach)),
                     float(reach.max()))
            return None
        return found

    def model(self, stretch: float, bending: float, mass: float = 1.0, pinned=None) -> Model:
        """The springs (``stretch`` times each edge's stiffness factor) and hinges
        (``bending``), rest state measured on :attr:`vertices`, the base fixed."""
        return Model.build(self.vertices, self.edges, self.alpha, stretch * np.asarray(self.stiffness),
                           self.hinges, bending, self.base if pinned is None else pinned, mass=mass)

    def imperfection(self, amount: float) -> np.ndarray:
        """A small, smooth, mesh-independent imperfection of the bud ``(V, 3)``: each
        petal's vertices moved along its center plane's normal by ``amount`` times the
        petal size times ``s^2`` (0 at the base, ``amount`` at the tip). A perfectly
        symmetric petal can reach a fork in its path (a sideways lean, a twist) where
        it must choose a side; this chooses it the same way at any resolution and on any
        triangulation (a random nudge per vertex, or rounding, chooses per mesh)."""
        v = np.asarray(self.vertices, dtype=np.float64)
        if amount == 0.0:
            return np.zeros_like(v)
        petal = np.asarray(self.petal)
        normal = np.asarray(self.plane, dtype=np.float64)[petal, :3]
        size = petal_size(v, self.faces, petal)
        s = np.asarray(self.s, dtype=np.float64)
        return (amount * size * s * s)[:, None] * normal

    def shell_model(self, stretch_modulus: float, thickness: float, poisson: float,
                    mass: float = 1.0, pinned=None) -> Model:
        """The shell (:mod:`pipeline.sim.terms.shell`): the model's edges keep the rest lengths
        and growth ratios (the rest metric of each face is made of them), and carry the
        paper's equivalent stiffnesses for what is still counted in springs (contact,
        the solver's scales). ``stretch_modulus`` and ``thickness`` are in units of the
        petal size (see :func:`pipeline.sim.terms.shell.moduli`). A fixed boundary edge (the
        base) is clamped (:func:`pipeline.sim.terms.shell.clamped_anchors`). The growth
        map's stiffness factors per edge (wrinkles' softer rim) scale the stretch modulus
        of the faces they border (their mean over a face's three edges)."""
        model = self.model(1.0, 1.0, mass=mass, pinned=pinned)
        data = ShellData.build(self.vertices, self.faces, model, stretch_modulus=stretch_modulus,
                               thickness=thickness, poisson=poisson, petal=self.petal,
                               vertex_thickness=self.thickness)
        # the edges' stiffness factors (wrinkles' softer rim, Eq. 12: 1 elsewhere) soften
        # the membrane of the faces they border, by their mean over the face's edges
        data.face_stretch = data.face_stretch * model.edge_stiffness[data.face_edges].mean(axis=1)
        ks, kb = data.equivalent()
        model.edge_stiffness = np.full(model.edge_count, ks)
        model.hinge_stiffness = np.full(model.hinge_count, kb)
        model.shell = data
        return model

    def effects(self, names, params: fx.Params, *, positions=None, rest_angle=None,
                max_edge: float | None = None, pushback: bool = True,
                apart: bool = True) -> fx.Effects:
        """The effects ``names`` (those the scene enabled), built at ``positions`` (default
        the rest state) with the parameters ``params``. ``max_edge``: the
        longest edge the collision grid must hold (default: the longest fully grown edge).
        ``pushback``: with the dynamic integrators' push-back arrays (False: the
        quasi-static solver's contact, which does not read them). ``apart``: flowers
        (:attr:`flower`) each with contact among its own petals (False: between flowers
        too)."""
        positions = self.vertices if positions is None else positions
        if max_edge is None:
            max_edge = self.max_grown_edge()
        return fx.build(names, vertices=positions, faces=self.faces, petal=self.petal,
                        left=self.left, flower=self.flower if apart else None,
                        pinned=self.base, on_axis=self.on_axis, plane=self.plane, s=self.s,
                        rest_angle=self.rest_angle if rest_angle is None else rest_angle,
                        flower_axis=self.flower_axis, max_edge=max_edge, params=params,
                        pushback=pushback, contact_faces=self.contact_faces)

    def contact_gap(self, cfg) -> float:
        """The gap contact keeps, in mesh units: the shell's ``effects.collisions.gap``
        in units of the petal size (:func:`~pipeline.sim.terms.shell.petal_size`, the
        shell's own unit: mesh units shrink as the mesh is refined), the paper's springs'
        ``effects.collisions.thickness`` as it is."""
        if cfg["simulate.model"] == "shell":
            return cfg["effects.collisions.gap"] * petal_size(self.vertices, self.faces,
                                                              self.petal)
        return cfg["effects.collisions.thickness"]

    def max_grown_edge(self) -> float:
        """The longest edge at full growth (``L (1 + max(alpha, 0))``, measured as the
        model measures its rest lengths): what the collision grid's cells must hold."""
        edges = np.ascontiguousarray(self.edges, dtype=np.int64).reshape(-1, 2)
        if len(edges) == 0:
            return clean.mean_edge_length(self.vertices, self.faces)
        length = np.empty(len(edges))
        edge_lengths(np.ascontiguousarray(self.vertices, dtype=np.float64), edges, length)
        return float((length * (1.0 + np.maximum(np.asarray(self.alpha), 0.0))).max())

    def petal_axes(self) -> np.ndarray:
        """``(P, 6)`` each petal's flower's axis (nan for a lone petal)."""
        count = len(self.tip)
        if self.flower is not None and self.flower_axes is not None:
            of = np.zeros(count, dtype=np.int64)
            of[np.asarray(self.petal)] = np.asarray(self.flower)
            return np.asarray(self.flower_axes, dtype=np.float64)[of]
        return np.broadcast_to(np.asarray(self.flower_axis, dtype=np.float64), (count, 6))

    def bud_closed(self, bud, model) -> float | None:
        """How much less the petals of ``bud`` lean from their flower's axis than those
        of ``model`` (deg, the lower median over petals; not positive: half of them or
        more lean further, the bud hangs open the other way). None without a flower's
        axis (a lone petal). The median, not the mean: a bud of which half the petals hang
        down under the others' (a daisy's own path: eight of sixteen at 162-176 deg, the
        others curled in over the disc) is no bud, whatever the curled ones add to the
        mean; the lower one, so that half is not a tie."""
        axes = self.petal_axes()
        if not np.all(np.isfinite(axes)):
            return None
        return float(np.percentile(leans(model, self.petal, self.base, self.tip, axes)
                                   - leans(bud, self.petal, self.base, self.tip, axes), 50,
                                   method="lower"))

    def recurve(self) -> float | None:
        """How much of the model's curvature curves away from its flower's inside: the
        share of its squared curvature (:func:`pipeline.sim.budshape.recurve_share`, the
        shell's second fundamental forms; the sides by
        :func:`~pipeline.sim.budshape.inner_sides`). A bud's petals cup over its centre
        (the default buds: 0.3-0.4%); an open rose's are rolled back (83%). None where
        the sheet has a face of no area (no form to measure)."""
        from pipeline.sim.budshape import inner_sides, recurve_share

        try:  # (the moduli do not matter: the form is the geometry's)
            sh = self.shell_model(1.0, 0.025, POISSON).shell
        except ValueError:
            return None
        inside = inner_sides(self.vertices, self.faces, self.petal, self.s, self.petal_axes())
        return recurve_share(self.vertices, sh.face_indices, sh.form_at(self.vertices), inside)

    def frames(self, positions=None):
        """The petal frames the opening angle is measured in, at ``positions`` (default
        the rest state)."""
        return PetalFrames.from_mesh(self.vertices if positions is None else positions,
                                     self.petal, self.base, self.on_axis, self.tip, self.plane,
                                     flower_axis=self.flower_axis)


#: a petal's old base vertices further than this along it (s) on the finer mesh: the
#: axes found there put its base elsewhere (:meth:`Prepared.refined`)
REFINED_BASE = 0.25


#: rest-state check: every vertex is nudged by this many mean edges (far above rounding,
#: far below any motion that matters) ...
REST_NUDGE = 1e-9


#: ... and the force that comes back may be at most this many times (K_s + K_b) per unit
#: of nudge. A sound mesh measures 5-8 times K_s (the stiffest vertex's springs); a
#: triangle collapsed to a sliver makes its hinge ~ K_b / height^2 stiff: 1e15 measured.
REST_STIFFNESS = 1000.0


def rest_stiffness(vertices: np.ndarray, growth: GrowthMap, petal: np.ndarray, pinned: np.ndarray,
                   stretch_stiffness: float, bending_stiffness: float, seed: int = 0) -> np.ndarray:
    """``(P,)`` how stiff each petal's rest state is, in units of ``K_s + K_b``: the
    largest force on a free vertex after every vertex is nudged at random by
    ``REST_NUDGE`` (mesh units, mean edge 1), over the nudge.

    At growth 0 the rest state is an equilibrium by construction (rest lengths and
    angles are measured on it), so the force there is zero; what can be wrong is that
    it is not a *sound* one: rounding, or the first step, moves a degenerate triangle's
    normal by a lot, and its hinge pushes back with a force no time step can integrate.
    The nudge measures that; more than ``REST_STIFFNESS`` is a broken rest state.
    """
    model = Model.build(vertices, growth.edges, growth.alpha, stretch_stiffness * growth.stiffness,
                        growth.hinges, bending_stiffness, pinned)
    rng = np.random.default_rng(seed)
    X = vertices + rng.uniform(-REST_NUDGE, REST_NUDGE, vertices.shape)
    F = np.zeros_like(X)
    internal_forces(X, model.edge_indices, model.edge_rest_length, 0.0 * model.edge_growth,
                            model.edge_stiffness, model.hinge_indices, model.hinge_rest_cos,
                            model.hinge_rest_sin, model.hinge_stiffness, 0.0, F)
    force = np.linalg.norm(F, axis=1)
    force[model.pinned] = 0.0
    force[~np.isfinite(force)] = np.inf
    out = np.zeros(int(petal.max()) + 1 if len(petal) else 0)
    np.maximum.at(out, petal, force)
    return out / (REST_NUDGE * (stretch_stiffness + bending_stiffness))
