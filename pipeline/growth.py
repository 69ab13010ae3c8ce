"""Growth ratios per edge from the growth curve, and the hinges with their rest angles."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import topology
from .expr import evaluate_curve
from .sim.elastic import dihedral_angles


@dataclass
class GrowthMap:
    edges: np.ndarray  #: (E, 2) int, i < j
    alpha: np.ndarray  #: (E,) growth ratio of each edge (Eq. 6, 12)
    stiffness: np.ndarray  #: (E,) factor on simulate.stretch_stiffness
    boundary_edge: np.ndarray  #: (E,) bool
    edge_x: np.ndarray  #: (E,) cross-section coordinate at the edge's midpoint
    hinges: np.ndarray  #: (H, 4) int, see kernels
    hinge_edge: np.ndarray  #: (H,) index of each hinge's edge
    rest_angle: np.ndarray  #: (H,) signed dihedral angle of the initial mesh


def assign_growth(vertices: np.ndarray, faces: np.ndarray, x: np.ndarray, curve: str, *,
                  alpha_add: float = 0.0, boundary_stiffness: float = 1.0) -> GrowthMap:
    """alpha_e = curve(x_e), x_e the mean of the edge's end coordinates; boundary edges
    get ``alpha_add`` more and their stiffness scaled (the wrinkles of Eq. 12).

    Raises ``ValueError`` if the curve is invalid or makes a rest length non-positive.
    """
    edges, _, count = topology.unique_edges(faces)
    edge_x = 0.5 * (x[edges[:, 0]] + x[edges[:, 1]])
    alpha = evaluate_curve(curve, edge_x)
    boundary = count == 1
    alpha = alpha + alpha_add * boundary
    if np.any(alpha <= -1.0):
        worst = float(alpha.min())
        raise ValueError(f"gives alpha = {worst:.3g} <= -1 on some edge, which would make "
                         "its rest length zero or negative")
    stiffness = np.where(boundary, boundary_stiffness, 1.0)
    hinges, hinge_edge = topology.hinges(faces)
    rest = dihedral_angles(vertices, hinges)
    return GrowthMap(edges, alpha, stiffness, boundary, edge_x, hinges, hinge_edge, rest)


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
    from .sim import kernels
    from .sim.model import Model

    model = Model.build(vertices, growth.edges, growth.alpha, stretch_stiffness * growth.stiffness,
                        growth.hinges, bending_stiffness, pinned)
    rng = np.random.default_rng(seed)
    X = vertices + rng.uniform(-REST_NUDGE, REST_NUDGE, vertices.shape)
    F = np.zeros_like(X)
    kernels.internal_forces(X, model.edge_indices, model.edge_rest_length, 0.0 * model.edge_growth,
                            model.edge_stiffness, model.hinge_indices, model.hinge_rest_cos,
                            model.hinge_rest_sin, model.hinge_stiffness, 0.0, F)
    force = np.linalg.norm(F, axis=1)
    force[model.pinned] = 0.0
    force[~np.isfinite(force)] = np.inf
    out = np.zeros(int(petal.max()) + 1 if len(petal) else 0)
    np.maximum.at(out, petal, force)
    return out / (REST_NUDGE * (stretch_stiffness + bending_stiffness))
