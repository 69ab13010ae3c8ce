"""The physical terms of a scene, each a unit with one interface.

A term is a piece of the potential energy. Every one answers, at positions ``X (V, 3)``
and the growth it was last set to (:meth:`Term.at`):

- ``forces(X, F) -> energy``: adds ``-dE/dX`` to ``F (V, 3)`` and returns ``E``: what a
  dynamic integrator needs, and what the Newton solver sums (its gradient is minus it);
- ``energy(X)``, ``gradient(X)``: the same, on their own;
- ``hessian(X, project=False)``: ``d2E/dX2`` as a ``(3V, 3V)`` scipy matrix (``None``
  when the term has nothing there); ``project=True`` gives the positive semi-definite
  form the Newton solver factors where the term defines one (contact), else the exact.

The terms (docs/method.md, "Constraints and effects"), each built only when the scene has it
(:func:`build`):

- :class:`Stretch` (Eq. 2) and :class:`Bending` (Eq. 3, with the curl of Eq. 11 moving
  its rest angles when the scene curls); :class:`Elastic` is the two in one pass, the
  form the solvers run (``pipeline.sim.explicit.step.advance`` fuses the same arithmetic into its step);
- or, where the model is a shell (``simulate.model = "shell"``), one
  :class:`~pipeline.sim.terms.shell.ShellTerm` instead of the two: membrane and bending
  of the surface, in the elastic unit's place (the curl decays its rest curvature);
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

The paper's push-back (``pipeline/sim/explicit/pushback.py``) is a response after the step, not
an energy, and stays inside the explicit kernel.
"""

from __future__ import annotations

from pipeline.sim.terms.elastic import Elastic
from pipeline.sim.terms.fixed_base import FixedBase
from pipeline.sim.terms.shell import ShellTerm


class Terms:
    """What a scene's energy is made of: the elastic unit, the coupling terms (contact,
    connection springs) the scene has, and its constraints. Built by :func:`build`."""

    def __init__(self, elastic: Elastic | ShellTerm, coupling: list, constraints: list, model=None):
        self.elastic, self.coupling, self.constraints = elastic, coupling, constraints
        self.model = model  #: the model they were built of

    def __iter__(self):
        """The energy terms (the constraints are not)."""
        return iter([*self.elastic.units, *self.coupling])

    def names(self) -> list[str]:
        return [t.name for t in self] + [c.name for c in self.constraints]


def build(model, effects, *, contact=None, springs=None) -> Terms:
    """The terms of a scene: stretch and bending always (curl if the scene curls; the
    shell's one term instead where the model is a shell), the
    coupling terms given (``contact``: a :class:`~pipeline.sim.contact.Contact`;
    ``springs``: :class:`~pipeline.sim.contact.Springs`), the fixed base, and the center
    plane if the scene has it."""
    constraints = [FixedBase(model.pinned)]
    if effects.center_plane is not None:
        constraints.append(effects.center_plane)
    coupling = [t for t in (contact, springs) if t is not None]
    if getattr(model, "shell", None) is not None:  # the surface's own elasticity
        return Terms(ShellTerm(model, effects.curl), coupling, constraints, model)
    return Terms(Elastic.of(model, effects.curl), coupling, constraints, model)
