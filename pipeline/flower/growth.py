"""Growth ratios per edge from the growth curve, and the hinges with their rest angles."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.expr import evaluate_curve
from pipeline.mesh import topology
from pipeline.mesh.hinge import dihedral_angles


@dataclass
class GrowthMap:
    edges: np.ndarray  #: (E, 2) int, i < j
    alpha: np.ndarray  #: (E,) growth ratio of each edge (Eq. 6, 12)
    stiffness: np.ndarray  #: (E,) factor on simulate.stretch_stiffness
    boundary_edge: np.ndarray  #: (E,) bool
    edge_x: np.ndarray  #: (E,) cross-section coordinate at the edge's midpoint
    hinges: np.ndarray  #: (H, 4) int, see :mod:`pipeline.mesh.hinge`
    hinge_edge: np.ndarray  #: (H,) index of each hinge's edge
    rest_angle: np.ndarray  #: (H,) signed dihedral angle of the initial mesh


def growth_rule(get) -> dict:
    """What :func:`assign_growth` is called with beside the mesh, from a scene's keys
    (``get(dotted key)``): the growth curve, and the wrinkles' extra rim growth and
    softer rim where the scene turns wrinkles on."""
    wrinkles = bool(get("effects.wrinkles.enabled"))
    return {"curve": get("growth.curve"),
            "alpha_add": get("effects.wrinkles.alpha_add") if wrinkles else 0.0,
            "boundary_stiffness": get("effects.wrinkles.boundary_stiffness") if wrinkles else 1.0}


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
