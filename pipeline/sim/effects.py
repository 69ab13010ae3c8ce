"""The effects a scene may call for (docs/method.md, "Constraints and effects").

Each effect is a small unit built from the scene only when the scene enables it; its
per-step work is a compiled kernel that :func:`pipeline.sim.explicit.step.advance`
runs behind one branch. An effect that is off is never built (no grid, no pairs, no
arrays) and its loop never runs.

- ``curl``: rest dihedral angles decay, theta0(t) = (1 - B(t) beta) theta0(0) (Eq. 11),
  B = A;
- ``wrinkles``: boundary edges grow by alpha_add more and are softer (Eq. 12); it acts
  through the growth map (``bloom growth``) and needs nothing here;
- ``collisions``: vertex-triangle contacts between petals through a hashed uniform grid,
  rebuilt only when a vertex has moved more than a slack since the last build;
- ``connections``: springs from an outer petal's rim to the nearest inner petal that
  break for good past a critical stretch (the lily's lock);
- ``center_plane``: axis vertices keep their distance to their petal's center plane.
"""

from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass, field, fields, replace

import numpy as np

from pipeline.config import Config, load_config
from pipeline.sim.explicit.pushback import Collisions
from pipeline.sim.terms.center_plane import CenterPlane, project_out_normals
from pipeline.sim.terms.connections import Connections
from pipeline.sim.terms.growth import Curl

ORDER = ("curl", "wrinkles", "collisions", "connections", "center_plane")


@dataclass(frozen=True)
class CurlParams:
    beta: float  #: curl growth beta of Eq. 11, in [0, 1]


@dataclass(frozen=True)
class CollisionsParams:
    thickness: float  #: the gap the contact barrier keeps between petals (mesh units)
    offset: float  #: the push-back's offset (mesh units)


@dataclass(frozen=True)
class ConnectionsParams:
    stiffness: float  #: spring constant of a connection
    critical_stretch: float  #: breaks past this times its rest length
    max_distance: float  #: a rim vertex is tied to an inner petal within this (mesh units)
    min_s: float  #: only rim vertices past this s are tied


@dataclass(frozen=True)
class Params:
    """The parameters of the effects, typed: the ``effects`` section of a scene's config
    (:meth:`of`; every default from the config's schema, :meth:`defaults`)."""

    curl: CurlParams
    collisions: CollisionsParams
    connections: ConnectionsParams

    @classmethod
    def of(cls, cfg: Config) -> Params:
        def section(kind, name):
            return kind(**{f.name: cfg[f"effects.{name}.{f.name}"] for f in fields(kind)})

        return cls(section(CurlParams, "curl"), section(CollisionsParams, "collisions"),
                   section(ConnectionsParams, "connections"))

    @classmethod
    def defaults(cls) -> Params:
        return cls.of(load_config())

    def but(self, **sections) -> Params:
        """A copy with some sections' values changed: ``but(curl={"beta": 1.0})``."""
        return replace(self, **{name: replace(getattr(self, name), **values)
                                for name, values in sections.items()})


def petal_layers(vertices, petal, axis_point, axis_dir) -> np.ndarray:
    """``(P,)`` mean distance of each petal's vertices from the flower's axis, with a
    tiny tie-break by petal id: inner petals have lower values. ``axis_point`` and
    ``axis_dir`` ``(3,)``, or ``(P, 3)`` each petal's flower's."""
    petal = np.asarray(petal)
    point, direction = np.asarray(axis_point), np.asarray(axis_dir)
    if point.ndim == 2:  # (each petal's flower's)
        r = np.asarray(vertices) - point[petal]
        d = direction[petal]
        radial = np.linalg.norm(r - np.einsum("ij,ij->i", r, d)[:, None] * d, axis=1)
    else:
        r = np.asarray(vertices) - point
        radial = np.linalg.norm(r - np.outer(r @ direction, direction), axis=1)
    count = int(petal.max()) + 1
    return np.array([radial[petal == p].mean() + 1e-9 * p for p in range(count)])


def has_flower_axis(flower_axis) -> bool:
    """Whether ``flower_axis`` is a flower's axis (point and direction, six finite
    numbers; or ``(P, 6)``, each petal's flower's, of flowers that bloom as one problem);
    a lone petal's is NaN."""
    fa = np.asarray(flower_axis, dtype=np.float64)
    return fa.shape[-1:] == (6,) and fa.ndim <= 2 and fa.size > 0 and bool(np.all(np.isfinite(fa)))


def flower_axis_or_guess(vertices, flower_axis) -> tuple[np.ndarray, np.ndarray]:
    """The flower's axis as (point, unit direction), ``(3,)`` each, or ``(P, 3)`` each for
    a ``(P, 6)`` axis (each petal's flower's); a lone petal has none: the vertical line
    through its centroid stands in."""
    if has_flower_axis(flower_axis):
        fa = np.asarray(flower_axis, dtype=np.float64)
        return fa[..., :3], fa[..., 3:] / np.linalg.norm(fa[..., 3:], axis=-1, keepdims=True)
    return np.asarray(vertices).mean(axis=0), np.array([0.0, 0.0, 1.0])


#: What :func:`pipeline.sim.explicit.step.advance` takes of the effects, by name: each effect's on-flag,
#: parameters and work arrays (an effect that is off gives empty arrays). A namedtuple, so
#: that the compiled kernel reads fields by name and a checkpoint saves its arrays by name.
Bundle = namedtuple("Bundle", [
    "curl_on",
    "curl_theta0",
    "curl_beta",
    "curl_cos",
    "curl_sin",
    "plane_on",
    "plane_vertices",
    "plane_normals",
    "conn_on",
    "conn_pairs",
    "conn_rest",
    "conn_k",
    "conn_limit",
    "conn_alive",
    "conn_broken",
    "coll_on",
    "coll_faces",
    "coll_face_petal",
    "coll_vertex_petal",
    "coll_side",
    "coll_normals",
    "coll_params",
    "grid_start",
    "grid_count",
    "grid_items",
    "grid_reference",
    "counters",
    "pair_start",
    "pair_faces",
    "best_face",
    "best_dist",
    "coll_near",
    "plane_height",
])


_F8 = np.zeros(0)


_I8 = np.zeros(0, dtype=np.int64)


@dataclass
class Effects:
    """The effects a scene enabled, built, and the bundle the kernel takes."""

    names: tuple = ()
    curl: Curl | None = None
    collisions: Collisions | None = None
    connections: Connections | None = None
    center_plane: CenterPlane | None = None
    #: kernel counters: contacts since the last frame, grid builds, overflow, near pairs
    counters: np.ndarray = field(default_factory=lambda: np.zeros(4, dtype=np.int64))
    _bundle: Bundle | None = None

    def bundle(self) -> Bundle:
        if self._bundle is None:
            c, p, k, g = self.curl, self.center_plane, self.connections, self.collisions
            self._bundle = Bundle(
                c is not None, c.theta0 if c else _F8, c.beta if c else 0.0,
                c.cos_t if c else _F8, c.sin_t if c else _F8,
                p is not None, p.vertices if p else _I8, p.normals if p else np.zeros((0, 3)),
                k is not None, k.pairs if k else np.zeros((0, 2), dtype=np.int64),
                k.rest if k else _F8, k.stiffness if k else 0.0, k.limit if k else _F8,
                k.alive if k else np.zeros(0, dtype=bool), k.broken_step if k else _I8,
                g is not None, g.faces if g else np.zeros((0, 3), dtype=np.int64),
                g.face_petal if g else _I8, g.vertex_petal if g else _I8,
                g.side if g else np.zeros((0, 0)), g.normals if g else np.zeros((0, 3)),
                g.params if g else _F8, g.start if g else _I8, g.count if g else _I8,
                g.items if g else _I8, g.reference if g else np.zeros((0, 3)), self.counters,
                g.pair_start if g else _I8, g.pair_faces if g else _I8,
                g.best_face if g else _I8, g.best_dist if g else _F8,
                g.near if g else np.zeros((0, 0), dtype=np.int8), p.height if p else _F8)
        return self._bundle

    def constrain(self, forces: np.ndarray) -> None:
        """Apply the constraints to forces computed outside :func:`pipeline.sim.explicit.step.advance`."""
        if self.center_plane is not None:
            project_out_normals(forces, self.center_plane.vertices, self.center_plane.normals)

    def frame_diagnostics(self, positions=None, growth: float = 0.0) -> dict:
        """Per-frame figures of the effects that ran; resets the per-frame counters."""
        out = {}
        if self.curl is not None:
            out["curl_factor"] = growth * self.curl.beta
        if self.center_plane is not None and positions is not None:
            out["center_plane_drift"] = self.center_plane.drift(positions)
        if self.collisions is not None:
            out["contacts"] = int(self.counters[0])
            out["grid_builds"] = int(self.counters[1])
            out["near_pairs"] = int(self.counters[3])
            if self.counters[2]:
                raise RuntimeError("collision grid overflow: triangles grew far beyond their "
                                   "rest size or petals crowd together (diverging?)")
        if self.connections is not None:
            out["connections_intact"] = int(self.connections.alive.sum())
        self.counters[0] = 0
        return out


def build(names, *, vertices, faces, petal, pinned, on_axis, plane, s, rest_angle,
          flower_axis, max_edge: float, params: Params, left=None, flower=None,
          pushback: bool = True, contact_faces=None) -> Effects:
    """Build the enabled effects (``names``) from the mesh and their parameters.
    ``left`` (K, 2): petal pairs left through each other as modelled (no contact between
    the two of a pair), or None. ``flower`` (V,): each vertex's flower
    in a file of many (each flower blooms as a problem of its own, with contact among its
    own petals only); None: one flower. ``pushback``: the collisions' arrays for the
    push-back of the dynamic integrators (False: the quasi-static solver's contact only).
    ``contact_faces``: the triangles contact keeps apart and connection springs tie, on
    the first vertices (a mesh cut finer for the solve: the coarse mesh's), or None:
    ``faces``."""
    names = tuple(n for n in ORDER if n in set(names))
    petal = np.asarray(petal, dtype=np.int64)
    point, direction = flower_axis_or_guess(vertices, flower_axis)
    layer = petal_layers(vertices, petal, point, direction)
    fx = Effects(names=names)
    if "curl" in names:
        fx.curl = Curl.build(rest_angle, params.curl.beta)
    if "collisions" in names:
        c = params.collisions
        fx.collisions = Collisions.build(vertices, faces if contact_faces is None
                                         else contact_faces,
                                         petal, offset=c.offset,
                                         max_edge=max_edge, thickness=c.thickness,
                                         pushback=pushback, left=left)
        if contact_faces is not None:
            fx.collisions.in_contact = int(np.max(contact_faces)) + 1
        if flower is not None and len(flower) and int(np.max(flower)) > 0:
            fx.collisions.vertex_flower = np.asarray(flower, dtype=np.int64)
    if "connections" in names:
        c = params.connections
        fx.connections = Connections.build(  # (between the contact's vertices)
            vertices, faces if contact_faces is None else contact_faces, petal, pinned, s,
            layer, stiffness=c.stiffness,
            critical_stretch=c.critical_stretch, max_distance=c.max_distance, min_s=c.min_s)
    if "center_plane" in names:
        fx.center_plane = CenterPlane.build(vertices, on_axis, pinned, petal, plane)
    return fx


#: a scene with no effects
NO_EFFECTS = Effects()
