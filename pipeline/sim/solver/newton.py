"""Newton's method on the scene's energy at one growth A: the equilibrium grad U = 0.

The Hessian is the analytic one (:mod:`pipeline.sim.terms`). Where it is positive
definite the step is Newton's, and near a stable equilibrium convergence is quadratic;
a later step of the same solve may reuse the factorization (a chord step) if the step it
gives is a tenth of the last one or less. Where it is not (the path passes a
bifurcation or a snap, or the prediction is far off), the energy is first searched along
a direction of negative curvature read from the factors, then the step solves
``(H + mu I) p = -g`` with ``mu`` raised until that is positive definite (see
:meth:`Newton.solve`). Every step is cut to what continuous collision detection allows
when the scene has contact, then searched backtracking on the energy (Armijo). An
energy asked for again at the same point and growth is the last evaluation's.

The module is long because a solve is one loop whose parts share its state (the groups'
factorizations, which of them converged, the line search's accepted energy): the step,
the chord, the shift, the descent and the line search read best beside it."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.sim.blocks import constrain
from pipeline.sim.effects import Effects
from pipeline.sim.energy import Terms
from pipeline.sim.energy import build as build_terms
from pipeline.sim.model import Model
from pipeline.sim.solver.system import System
from pipeline.sim.terms.connections import Springs
from pipeline.sim.terms.contact import Contact
from pipeline.sim.terms.inertia import Inertia
from pipeline.sim.threads import dot, parallel_map

#: how far (mesh units) a search along a direction of negative curvature may go
DESCENT = 2.0
#: its first length (1e-3 times 2^6): the best is 0.03-0.26 in 80% of hallgeirl's 530
#: searches (from 1e-3 each took 8.4 energies, most on lengths never the best)
DESCENT_FIRST = 0.064

#: a gradient component below this many times ``eps`` times the force scale (the size of
#: what the force kernel adds and subtracts at that vertex,
#: :func:`~pipeline.sim.terms.elastic.rounding_scale`)
#: is rounding: Newton's own steps end at 0.1-0.2 of it on the project's buds
#: with contact, a residual force under this fraction of the force scale is converged
#: (see :meth:`Newton.solve`)
PRESSED = 1e-6
ROUNDING_FACTOR = 2.0
#: a group's factorization is reused for a step at most this fraction of its last one
CHORD = 0.1
EPS = float(np.finfo(np.float64).eps)
#: a sheet whose force scale (what the elastic kernel adds and subtracts at a vertex,
#: :meth:`Newton.rounding`) passes this many times its scale where the path started has a
#: triangle collapsed to (nearly) no area: its bending force grows as 1 / height^2, and
#: the rounding level with it, so that any residual would pass for converged. No such
#: state is an equilibrium. (On the project's scenes and the external models the scale
#: stays within 3 times its start; a triangle of 1e-3 of the mean edge high gives ~1e3.)
OUT_OF_SCALE = 1e4


@dataclass
class Failure:
    """Why Newton stopped without an equilibrium."""

    residual: float  #: largest gradient component left (force units)
    scale: float  #: the force scale there (eps * scale * ROUNDING_FACTOR: the rounding level)
    #: stalled (no descent along the step), iterations, shift (no shift helped), or
    #: degenerate (the sheet's forces went out of scale: a triangle collapsed)
    how: str
    inertia: str  #: the Hessian's last factorization: definite, indefinite or singular
    vertex: int = -1  #: where: the largest residual force (degenerate: the largest force scale)
    #: degenerate: the force scale there over the sheet's where the path started
    out_of_scale: float = 0.0

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


def _largest(g) -> int:
    """The vertex of the largest component of a flattened per-vertex vector."""
    return int(np.argmax(np.abs(g))) // 3 if len(g) else -1


@dataclass
class Counters:
    """What the solver has done so far (a frame's diagnostics)."""

    iterations: int = 0  #: Newton iterations (and predictor steps), all increments
    increments: int = 0  #: growth increments solved
    shifted: int = 0  #: factorizations retried with a larger shift mu
    descents: int = 0  #: searches along a direction of negative curvature
    ccd_cuts: int = 0  #: steps cut short by continuous collision detection
    breaks: int = 0  #: connection springs broken (each break redoes its increment)
    #: rescues: increments where Newton found no equilibrium even after the usual halvings,
    #: stepped through (:meth:`~pipeline.sim.solver.quasistatic.QuasiStatic._rescue`)
    rescues: int = 0
    rescue_halvings: int = 0  #: halvings past the usual limit in those rescues
    rescue_inertia_steps: int = 0  #: implicit Euler steps (the snap as a motion) in them


@dataclass
class _Memo:
    """:meth:`Newton.energy`'s last evaluation: what it was of (``key``: the terms, the
    growth and the contact's parameters; ``X``) and what it gave."""

    key: tuple
    X: np.ndarray
    energy: float
    forces: np.ndarray
    coupling: np.ndarray | None  #: the coupling terms' forces (None: no coupling term)

    def holds(self, key: tuple | None, X) -> bool:
        """Whether it is the evaluation of ``key`` at ``X`` (key None: nothing is kept)."""
        return (key is not None and self.key[0] is key[0] and self.key[1:] == key[1:]
                and np.array_equal(self.X, X))


@dataclass
class Newton:
    """Newton's method on one model's energy (see the module docstring). Holds what a
    solve carries from one call to the next: the linear systems (:class:`System`), the
    terms (built once per model, set to a growth by :meth:`at`), the coupling terms the
    scene has (contact, connection springs), and the rounding level of the last
    iterate."""

    tolerance: float  #: converged when a step moves no vertex further (mesh units)
    max_iterations: int  #: iterations per solve before it gives up
    counts: Counters  #: the counters it adds to (its path follower's)
    contact: Contact | None = None  #: the barrier, if the scene has collisions
    springs: Springs | None = None  #: the connection springs, if the scene has them
    system: System | None = None  #: the linear algebra (None: not built yet)
    #: the scene's terms (:func:`~pipeline.sim.energy.build`), at the growth last set (:meth:`at`)
    terms: Terms | None = None
    #: the inertia term of the increment being solved (None: the quasi-static path)
    dyn: Inertia | None = None
    energy_rounding: float = 0.0  #: the energy's rounding level at the last iterate
    #: the sheet's force scale where the path started (the largest over its free vertices
    #: of the elastic kernel's, :meth:`rounding`); 0: not measured (no check)
    reference: float = 0.0
    #: the elastic force scale at the last iterate and the vertex where it is largest
    sheet: tuple = (0.0, -1)
    residuals: list = field(default_factory=list, repr=False)  #: per iteration of the last solve
    _scale_work: np.ndarray | None = field(default=None, repr=False)
    _coupling: np.ndarray | None = field(default=None, repr=False)  #: their last forces
    _limited: bool = field(default=False, repr=False)  #: the last line search was cut by CCD
    #: the energy at the step the last line search took, whose forces it left in its
    #: scratch (None: not since); the next iteration starts from them
    _accepted: float | None = field(default=None, repr=False)
    #: a checkpoint's state of the elastic term, put back when the terms are built
    restored: object = field(default=None, repr=False)
    _growth: float = field(default=float("nan"), repr=False)  #: the growth last set
    #: the last evaluation of :meth:`energy` (:class:`_Memo`), or None: none kept
    _memo: _Memo | None = field(default=None, repr=False)

    def at(self, model: Model, effects: Effects, A: float) -> None:
        """Set the scene's terms (built once per model, :func:`~pipeline.sim.energy.build`) to growth A:
        every evaluation below (energy, gradient, Hessian, rounding) is of the growth
        last set here."""
        if self.terms is None or self.terms.model is not model:
            self.terms = build_terms(model, effects, contact=self.contact,
                                      springs=self.springs)
            self.terms.elastic.restore(self.restored)
            self.restored = None
        self.terms.elastic.at(A)
        self._growth = A

    def assemble(self, X, groups=None) -> None:
        """The constrained Hessian at X into the system's blocks; its elastic part only
        in the blocks of ``groups`` if given (the others' are not read until they are
        assembled again)."""
        s = self.system
        H = s.blocks
        elastic = self.terms.elastic
        parts = [p for gr in (s.groups if groups is None else groups) for p in gr.parts]
        if len(parts) > 1:  # (pieces touch blocks apart: they are assembled in threads)
            parallel_map(lambda p: elastic.assemble(X, H, p), parts)
        elif parts:
            elastic.assemble(X, H, parts[0])
        constrain(H.indptr, H.indices, H.data, s.pinned, s.plane_row, s.normals)
        if s.project is not None:
            s.couple([t.hessian(X, project=True) for t in self.terms.coupling])

    def links(self, X) -> np.ndarray:
        """(k, 2) vertex pairs the coupling terms join at X: the contacts within the
        barrier's band and the intact connection springs."""
        links = [np.zeros((0, 2), dtype=np.int64)]
        if self.contact is not None:
            links.append(self.contact.linked(X))
        if self.springs is not None:
            c = self.springs.connections
            links.append(np.asarray(c.pairs, dtype=np.int64)[np.asarray(c.alive, dtype=bool)])
        return np.concatenate(links)

    def _memo_key(self) -> tuple | None:
        """What an evaluation of :meth:`energy` depends on besides X, or None where that
        is not all (the inertia term's prediction, connection springs that break as
        their forces are taken)."""
        if self.dyn is not None or self.springs is not None:
            return None
        c = self.contact
        return (self.terms, self._growth, None if c is None else (c.gap, c.band, c.kappa))

    def by_parts(self) -> bool:
        """Whether :meth:`energy` can be taken of some pieces alone (the elastic term
        has ``part_forces``; not with the inertia term, which moves every vertex)."""
        return self.dyn is None and hasattr(self.terms.elastic, "part_forces")

    def energy(self, X, scratch, parts=None) -> float:
        """The energy at X; the forces into ``scratch``. With coupling terms, their
        forces are also kept (``_coupling``) for :meth:`rounding`. The same X at the same
        growth as the last evaluation is not evaluated again (a predictor's step is the
        first iterate of the solve after it; a converged solve's X is the frame's): its
        results come back, the same bits. ``parts`` (where :meth:`by_parts`): only these
        pieces' elastic energy and the coupling terms' (the energy up to a constant along
        a move of these pieces alone: a group's descent)."""
        if parts is not None:
            return self._evaluate(X, scratch, parts)
        key = self._memo_key()
        memo = self._memo
        if memo is not None and memo.holds(key, X):
            scratch[:] = memo.forces
            if memo.coupling is not None:
                self._coupling = memo.coupling.copy()
            return memo.energy
        energy = self._evaluate(X, scratch)
        self._memo = None if key is None else _Memo(
            key, X.copy(), energy, scratch.copy(),
            self._coupling.copy() if self._coupling is not None and self.terms.coupling
            else None)
        return energy

    def _evaluate(self, X, scratch, parts=None) -> float:
        """:meth:`energy`, evaluated (of the pieces ``parts`` only, if given)."""
        scratch[:] = 0.0
        if parts is None:
            energy = self.terms.elastic.forces(X, scratch)
        else:
            energy = self.terms.elastic.part_forces(X, scratch, parts)
        if self.dyn is not None:
            energy += self.dyn.forces(X, scratch)
        coupled = self.terms.coupling
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

    def solve(self, model, state, effects, A: float) -> Failure | None:
        """:meth:`_solve`; where it fails, the elastic term forgets what its rounding
        bound read from this solve's assemblies (the path goes back to where it was: an
        iterate's Hessian, a collapsing triangle's, is no bound there)."""
        failure = self._solve(model, state, effects, A)
        if failure is not None:
            self.terms.elastic.forget()
        return failure

    def _solve(self, model, state, effects, A: float) -> Failure | None:
        """Newton iterations at growth A; None when converged, else why not.

        The pieces (petals) are grouped: those a contact or a connection spring joins
        are one linear system, the others each their own (:meth:`_System.regroup`), and
        each group is factored, and converges, apart. A group is converged when its
        residual force is at the rounding level of the forces (:meth:`rounding`),
        whatever its Hessian's inertia (a piece free to turn, or at a bifurcation, has a
        singular Hessian at its equilibrium: that is no reason to go on); or below
        ``tolerance`` times the softest stiffness that matters with its Hessian
        positive definite (then the tangent predictor can use it); or when a Newton
        step moved it less than ``tolerance``. A converged group stays put while the
        others iterate (unless a new contact joins it to one of them).

        Where a group's H is positive definite the step is Newton's. A group's last
        factorization (of the equilibrium before, if it was positive definite and
        unshifted) is reused for as long as each step is at most ``CHORD`` times the one
        before it, the predictor's first, or under ``tolerance`` (the group converges
        with it) (a chord step: the Hessian has barely changed where it matters; a
        factorization is most of an iteration's cost); otherwise it is factored afresh.
        Where H is not positive definite (the path is at a
        bifurcation or a snap, or the prediction is far off), the energy is first
        searched along a direction of negative curvature read from the factorization
        (so a saddle is left in one step rather than by slow amplification of the
        perturbation); then the step solves ``(H + mu I) p = -g`` with ``mu`` grown
        tenfold until the factorization is positive definite (an implicit Euler step of
        the gradient flow, time step ``1/sqrt(mu)``).
        """
        X = state.positions
        self.at(model, effects, A)
        scratch = np.empty_like(X)
        residual = np.inf
        floor = 1e-3 * float(model.hinge_stiffness.max(initial=0.0) or model.edge_stiffness.max())
        top = 1e6 * float(model.edge_stiffness.max())  #: a shift past this: none helps
        system = self.system
        self.residuals = []
        scale = 0.0
        done: set = set()  #: groups converged by their step
        stale: set = set()  #: groups whose factorization a chord step failed with
        #: groups whose factorization a chord step may use (the last solve's too)
        fresh: set = {gr.key for gr in system.groups
                      if gr.solver is not None and gr.positive and gr.shift == 0.0}
        chord: dict = {}  #: whether a group's step reuses its factorization
        self._accepted = None
        for _ in range(self.max_iterations):
            if self._accepted is not None:  # (the line search left X's forces in scratch)
                energy, g = self._accepted, self.constrained(-scratch)
                self._accepted = None
            else:
                energy, g = self.gradient(X, scratch)
            residual = float(np.abs(g).max())
            self.residuals.append(residual)
            scale, self.energy_rounding = self.rounding(X)
            rounding = ROUNDING_FACTOR * EPS * scale
            if residual <= rounding or self._out_of_scale():
                # (the bound read from the last assembly decides nothing: taken afresh)
                scale, self.energy_rounding = self.rounding(X, fresh=True)
                rounding = ROUNDING_FACTOR * EPS * scale
            if self._out_of_scale():
                # (before the test at rounding: that level has gone out of scale too)
                return Failure(residual, scale, "degenerate", self.factor_inertia(),
                               vertex=self.sheet[1], out_of_scale=self.sheet[0] / self.reference)
            if residual <= rounding:
                return None  # at rounding: no step can do better
            # a mode as soft as floor moves less than tolerance
            if residual <= self.tolerance * floor and system.tangent:
                return None
            if system.project is not None and system.regroup(self.links(X)):
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
                    size = float(np.abs(trial).max())
                    chord[gr.key] = size <= CHORD * gr.moved or size < self.tolerance
                    if chord[gr.key]:
                        solved[gr.key] = trial  # (the step, unless g changes below)
            if not moving:
                return None
            self.counts.iterations += 1
            lost = []  # groups whose Hessian is not positive definite
            factored = [gr for gr in moving if not chord[gr.key]]
            if factored:
                self.assemble(X, factored)
            downs = []  # (the groups' directions of negative curvature)
            for gr, (positive, down) in zip(factored, parallel_map(system.factor, factored), strict=True):
                fresh.add(gr.key)
                stale.discard(gr.key)
                if not positive:
                    lost.append(gr)
                    if down is not None:
                        downs.append((gr, self.downhill(self.constrained(down), g)))
            if self.contact is not None and len(downs) > 1:
                # (one sweep for all the groups' searches: each moves its group alone)
                self.contact.cover(X, X + DESCENT * sum(d for _, d in downs))
            for gr, d in downs:
                self.counts.descents += 1
                energy = self.descend(X, scratch, energy, d,
                                      gr.parts if self.by_parts() else None)
            if lost:
                energy, g = self.gradient(X, scratch)
                shifts = parallel_map(lambda gr: system.shifted(gr, floor, top), lost)
                for mu, rejected in shifts:  # (mu None: no shift helps)
                    self.counts.shifted += rejected
                    if mu is None:
                        return Failure(residual, scale, "shift", self.factor_inertia(),
                                       vertex=_largest(g))
            step = system.solve(-g, moving, None if lost else solved)
            length = self.line_search(X, scratch, energy, g, step)
            if length == 0.0:
                reused = [gr.key for gr in moving if chord[gr.key]]
                if reused:  # an old factorization is no excuse: factor afresh
                    stale.update(reused)
                    continue
                return Failure(residual, scale, "stalled", self.factor_inertia(lost),
                               vertex=_largest(g))
            # (a step cut by CCD is no sign of convergence: the whole step was not small)
            for gr in moving:
                gr.moved = length * float(np.abs(step[gr.dofs]).max())
                if gr.shift == 0.0 and not self._limited and gr.moved < self.tolerance:
                    done.add(gr.key)
            # petals pressed together: the barrier's projected Hessian over-stiffens the
            # contact and Newton converges linearly there (0.3% a step on lily_open's
            # bud); a force a millionth of the force scale is converged
            if self.contact is not None and residual <= PRESSED * scale:
                done.update(gr.key for gr in moving if gr.shift == 0.0)
            if all(gr.key in done for gr in moving):  # (the others had converged)
                return None  # (the factorization is that of the equilibrium, to rounding)
        return Failure(residual, scale, "iterations", self.factor_inertia(),
                       vertex=_largest(self.constrained(-scratch)) if self._accepted is not None
                       else -1)

    def _out_of_scale(self) -> bool:
        """Whether the sheet's force scale at the last iterate is :data:`OUT_OF_SCALE`
        times where the path started (a triangle collapsed)."""
        return self.reference > 0.0 and self.sheet[0] > OUT_OF_SCALE * self.reference

    def sheet_scale(self, X) -> float:
        """The sheet's force scale at X (the elastic kernel's, largest over the free
        vertices: :meth:`rounding`), at the growth last set."""
        self.rounding(X, fresh=True)
        return self.sheet[0]

    def factor_inertia(self, lost=None) -> str:
        """The last factorizations' inertia, as a failure names it."""
        groups = self.system.groups if lost is None else lost
        if any(g.solver is None for g in groups):
            return "singular"
        return "definite" if all(g.positive for g in groups) else "indefinite"

    def rounding(self, X, fresh: bool = False) -> tuple[float, float]:
        """The force scale (the largest, over the vertices, of what the force kernel adds
        and subtracts there: :func:`~pipeline.sim.terms.elastic.rounding_scale`) and the rounding level of
        the energy. ``eps`` times the force scale bounds the gradient that rounding
        alone leaves (of coordinates, lengths, angles and sums), on any machine: a
        residual below it is no reason to iterate. Both scale with the stiffnesses and
        with the mesh's size, as the forces do. ``fresh``: the elastic term's bound of
        X itself (the shell's reads the Hessians of the last assembly otherwise)."""
        per_vertex = self._scale_work
        if per_vertex is None or len(per_vertex) != len(X):
            per_vertex = self._scale_work = np.empty(len(X))
        energy = self.terms.elastic.rounding(X, per_vertex, fresh=fresh)
        free = ~self.system.pinned
        if free.any():  # (the sheet's own: what a collapsed triangle drives out of scale)
            worst = int(np.argmax(np.where(free, per_vertex, -np.inf)))
            self.sheet = (float(per_vertex[worst]), worst)
        if self.dyn is not None:  # the inertia term's force w (x - x_pred)
            x_pred, weight = self.dyn.predicted, self.dyn.weight
            size = np.abs(X).max(axis=1) + np.abs(x_pred).max(axis=1)
            per_vertex += weight * size
            energy += float(np.sum(weight * size * size))
        if self._coupling is not None:  # the contacts' and springs' forces at X (just taken)
            per_vertex += np.abs(self._coupling).max(axis=1)
            if self.springs is not None:
                self.springs.scale(X, per_vertex)
        force = float(per_vertex[free].max()) if free.any() else 0.0
        return force, EPS * energy

    def gradient(self, X, scratch) -> tuple[float, np.ndarray]:
        """Energy and gradient (flattened) with the constraints applied, from the force
        kernel."""
        energy = self.energy(X, scratch)
        return energy, self.constrained(-scratch)

    def constrained(self, vec: np.ndarray) -> np.ndarray:
        """``vec`` (per vertex) without what the constraints forbid: nothing for a fixed
        vertex, no normal part for a center-plane vertex. Flattened copy."""
        out = np.array(vec, dtype=np.float64).reshape(-1, 3)
        for constraint in self.terms.constraints:
            constraint.project(out)
        return out.ravel()

    def line_search(self, X, scratch, energy, g, step) -> float:
        """Backtracking (Armijo) along ``step``, from the longest step that continuous
        collision detection allows (1 without contact); moves X and returns the step
        length taken (0: none found). A change within rounding of the energy is accepted
        (as :meth:`rounding` measures it, or 1e-14 of the energy)."""
        slope = dot(g, step)
        length = 1.0
        base = X.copy()
        self._limited = False
        if self.contact is not None:
            cap = self.contact.max_step(base, base + step.reshape(-1, 3))
            if cap < 1.0:
                length, self._limited = cap, True
                self.counts.ccd_cuts += 1
        # two energies each within their rounding differ by up to twice it: a step whose
        # predicted change is below that cannot be judged by the energy (near an
        # equilibrium, where only the gradient still tells), so it is taken as Newton's
        blind = 2.0 * self.energy_rounding
        while length >= 1e-6:
            X[:] = base + length * step.reshape(-1, 3)
            trial = self.energy(X, scratch)
            change = abs(trial - energy)
            if (trial <= energy + 1e-4 * length * slope or change <= 1e-14 * abs(energy)
                    or (change <= blind and length * abs(slope) <= blind)):
                self._accepted = trial
                return length
            length *= 0.5
        X[:] = base
        return 0.0

    @staticmethod
    def downhill(down, g) -> np.ndarray:
        """The direction ``down`` (flattened) as :meth:`descend` searches it: per vertex,
        its largest component 1, its sign downhill on the energy of gradient ``g``."""
        d = down.reshape(-1, 3) / np.abs(down).max()
        return -d if dot(g, down) > 0.0 else d

    def descend(self, X, scratch, energy, d, parts=None) -> float:
        """Move X along the downhill negative-curvature direction ``d``
        (:meth:`downhill`), by the length that lowers the energy most among 1e-3 times
        powers of 2 (at most :data:`DESCENT` mesh units): from :data:`DESCENT_FIRST`,
        doubled while the energy falls, or else halved until it falls below X's and on
        while it falls (down to 1e-3); returns the energy there (``energy`` is X's).
        ``parts``: the pieces ``d`` moves (one group's; only where :meth:`by_parts`): the
        energies compared are those pieces' and the coupling terms' (the rest does not
        change along ``d``), and what is returned is that part of the energy."""
        if parts is not None:
            energy = self.energy(X, scratch, parts)
        base = X.copy()
        top = DESCENT  # (no further than contact allows)
        if self.contact is not None:
            top *= self.contact.max_step(base, base + top * d)

        best, best_length, grow = energy, 0.0, None
        length, low = DESCENT_FIRST, DESCENT_FIRST / 64.0  # (1e-3, on the lattice)
        while length > top and length > low:
            length *= 0.5
        while low <= length <= top:
            X[:] = base + length * d
            trial = self.energy(X, scratch, parts)
            if trial < best:
                best, best_length = trial, length
            elif grow or best_length > 0.0:
                break
            grow = (trial < energy) if grow is None else grow
            length *= 2.0 if grow else 0.5
        X[:] = base + best_length * d
        return best
