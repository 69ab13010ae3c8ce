"""The integrators a scene may choose (``simulate.integrator``), by name."""

from __future__ import annotations

from pipeline.sim.explicit.semi_implicit import SemiImplicit
from pipeline.sim.solver.quasistatic import QuasiStatic


def make_integrator(name: str, eta: float, damping: float, speed_limit: float = 1.0,
                    stages: int = 20, tolerance: float = 1e-6, substeps: int = 0,
                    inertia: bool = False):
    """The integrator a scene asks for by ``simulate.integrator`` (``inertia``: the
    quasi-static solver's inertia term, ``simulate.inertia``)."""
    if name == "quasi-static":
        return QuasiStatic(stages=stages, tolerance=tolerance, inertia=inertia)
    if name == "semi-implicit":
        return SemiImplicit(eta=eta, speed_limit=speed_limit, substeps=substeps)
    if name == "explicit-damping":
        return SemiImplicit(eta=0.5, d=damping, speed_limit=speed_limit, substeps=substeps)
    raise ValueError(f"unknown integrator {name!r}")
