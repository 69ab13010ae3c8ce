"""``growth.start = "open"``: the input mesh is the open flower; find the bud it grew from.

The open model is taken as the rest state at full growth, A = 1: a rest length at A is
``rest0 (1 + A c alpha)`` with ``rest0 = L_open / (1 + c alpha)`` (``c`` is
``growth.close``), so at A = 1 every spring has the model's own length; with curl, the
rest angle ``(1 - B c beta) theta0`` is the model's own at B = 1. The model is then the
minimum of the elastic energy at A = 1 (every term is zero there, and the fixed base
takes away the rigid motions).

The bud is found by following the path of equilibria backward, A from 1 down to 0, with
the quasi-static Newton solver (:mod:`quasistatic`), with whatever effects the scene
enabled that it can run (contact among them, so closing petals press on each other and
never cross). The bloom is then a fresh forward run from that bud with the scene's own
integrator and schedule. Its last frame lands on the model up to the solver's tolerance
(quasi-static), or up to what the damping has left (dynamic); that distance is measured
and recorded (:func:`distance_to_model`). Where that run finds no equilibrium, the bloom
is the path back played forward (:func:`retrace`).

The path to the bud is one of :data:`PATHS`: *lifted* (from the model nudged toward
closing, whose rest state the path keeps), *own* (the model's own), or *faded* (the model's
own, with that nudge grown into its rest state at the bud and fading out over the bloom,
:func:`lift_faded`).

The module is long because the open start is one search: the bud's model, the lift that
picks the branch, the search and its retries, and the path back share the model's rest
state and the figures the artifact records.
"""

from __future__ import annotations

import dataclasses
import logging
import time

import numpy as np

from pipeline.errors import BloomError
from pipeline.mesh.hinge import edge_lengths, hinge_cos_sin
from pipeline.sim.budshape import BudShape, inner_sides, recurve_share
from pipeline.sim.effects import Params, flower_axis_or_guess
from pipeline.sim.model import Model, State
from pipeline.sim.run import Recording, hold_last, openings
from pipeline.sim.run import run as integrate
from pipeline.sim.solver.newton import NotConverged
from pipeline.sim.solver.quasistatic import QuasiStatic
from pipeline.sim.terms.contact import Contact, ContactError
from pipeline.sim.terms.shell_kernels import rest_dets

log = logging.getLogger("bloom")

#: growth.start = open: the paths to the bud (:func:`open_start`)
PATHS = ("lifted", "own", "faded")
#: growth.start = open: the nudge toward closing that picks the bud's branch, in petal
#: lengths at the tip (see :func:`find_bud`)
LIFT = 0.05
#: a lift that leaves a triangle under this fraction of its own shape quality (twice its
#: area over its longest edge squared) folds it: the path's rest state would hold a crease
#: that the closing growth collapses (pchinyun's Solidify petal: its tip triangle at 0.108
#: of its quality under ``s^2 + x^2``, collapsed at A = 0.5; every other external model
#: keeps 0.33 or more, the project's open lily 0.71)
FOLD = 0.25


class Backward:
    """A(t) from 1 at t = 0 down to 0 at t = 1 (linear): the path from the model to its bud."""

    def growth_at(self, t: float) -> float:
        return float(min(max(1.0 - t, 0.0), 1.0))


class Played:
    """A control played backward: A at time t is ``control``'s at ``end - t``."""

    def __init__(self, control, end: float):
        self.control, self.end = control, float(end)

    def growth_at(self, t: float) -> float:
        return self.control.growth_at(self.end - t)


def retrace(model: Model, open_positions, control, integrator, effects, *, steps: int,
            frames: int, h: float, petals_at=None, progress=None):
    """The bloom as the path of equilibria from the model to its bud, played forward:
    ``integrator`` (quasi-static) follows the model's own path with ``control`` played
    backward (A from 1 down to 0, frame by frame), and the frames are put in forward
    order. Every frame is an equilibrium of the model at its growth, the last is the
    model itself and the first the bud the path reaches. Where the forward path from a
    bud leaves the branch the bud was found on (a fold: a petal that closed smoothly
    snaps or crumples as it opens), this is the bloom on that branch.

    Where the path back finds no equilibrium before the bud (a triangle collapsing near
    A = 0: the water lily's creased petal tip), it is kept as far as it went: the bloom
    starts from its last equilibrium, held over the frames below that growth.

    Returns ``(recording, wall seconds, stopped)``: positions and the state's diagnostics
    reversed, the integrator's counts (work done so far) and the times as recorded; the
    opening angles measured from the first frame, in the petal frames ``petals_at(bud)``
    gives (if given); ``stopped``: None, or ``(growth, vertex)`` where the path back
    stopped and the vertex the solver named."""
    back = Played(control, steps * h)
    state = State.at_rest(model, np.asarray(open_positions, dtype=np.float64), back)
    effects.constrain(state.forces)
    clock, stopped = time.perf_counter(), None
    try:
        rec, wall = integrate(model, state, back, integrator, steps=steps, frames=frames,
                              h=h, effects=effects, progress=progress)
    except NotConverged as exc:
        if len(exc.recording.time) < 2:  # (not one frame of the path: nothing to keep)
            raise
        rec, wall = hold_last(exc.recording, exc.frame_steps, h), time.perf_counter() - clock
        stopped = (float(exc.recording.diagnostics["growth"][-1]), int(exc.vertex))
    counts = set(integrator.diagnostics())
    out = Recording(time=rec.time, positions=rec.positions[::-1],
                    diagnostics={k: (v if k in counts else v[::-1])
                                 for k, v in rec.diagnostics.items()})
    petals = None if petals_at is None else petals_at(out.positions[0])
    if petals is not None and len(petals.tips):
        for X in out.positions:
            for name, value in openings(petals, X).items():
                out.add(name, value)
    return out, wall, stopped


#: a shell's triangle whose rest area at the bud would be under this fraction of what an
#: even growth of its edges gives (or over its inverse) has its edges' growth ratios evened
#: out toward their mean: a sliver (angles of 17, 18 and 145 deg in a rose's remeshed petal)
#: whose long edge grows less than a short one has no triangle at all at the bud (its
#: three lengths break the triangle inequality). 6 of the rose bed's 40,650 triangles are
#: under 0.5; the next is at 0.83
EVEN = 0.5


def even_growth(face_edges, full, growth):
    """Growth ratios ``(E,)`` such that every triangle ``face_edges (F, 3)`` whose edges
    are ``full`` long at A = 1 keeps, at A = 0 (``full / (1 + growth)``), a rest area
    within a factor :data:`EVEN` of what its edges' mean growth gives: the ratios of a
    triangle outside it are halved toward their mean, until none is. Returns the ratios
    (a copy, equal to the input where no triangle is outside) and the triangles changed
    (sorted)."""
    growth = np.array(growth, dtype=np.float64)
    full = np.ascontiguousarray(full, dtype=np.float64)
    det1 = np.empty(len(face_edges))
    rest_dets(face_edges, full, np.zeros_like(full), det1)
    changed: set = set()
    for _ in range(64):  # (64 halvings leave a triangle's ratios equal to rounding)
        det0 = np.empty(len(face_edges))
        rest_dets(face_edges, full / (1.0 + growth), growth, det0)
        even = (1.0 + growth[face_edges].mean(axis=1)) ** 4
        ratio = det0 * even / np.where(det1 > 0.0, det1, np.inf)
        bad = np.flatnonzero((det1 > 0.0) & ~((ratio >= EVEN) & (ratio <= 1.0 / EVEN)))
        if not len(bad):
            break
        for f in bad:  # (in order: a ratio shared by two such triangles moves for both)
            e = face_edges[f]
            mean = growth[e].mean()
            growth[e] = mean + 0.5 * (growth[e] - mean)
        changed.update(bad.tolist())
    return growth, sorted(changed)


def open_model(model: Model, close: float, positions=None, beta: float = 0.0,
               petal=None, bud: BudShape | None = None) -> Model:
    """The model whose rest lengths reach the mesh's own at A = 1: ``rest0 = L / (1 + c
    alpha)``, growth ratios ``c alpha``. A shell's rest curvature too: ``positions``' (the
    mesh's) at A = 1, with the curl's ``beta`` (already times ``c``) decaying it on the
    way (:meth:`~pipeline.sim.terms.shell.ShellData.rest_on`); and its slivers' growth
    ratios evened out where the bud would crush them (:func:`even_growth`, logged, the
    petals named by ``petal (V,)`` if given). ``bud``: a shell's bud shape (its cup and
    whether the model's recurve is left out of it; None: the model's own curvature)."""
    growth = float(close) * model.edge_growth
    if np.any(1.0 + growth <= 0.0):
        raise ValueError("growth.close: a growth ratio times it is <= -1 (a rest length "
                         "at the bud would be zero or negative)")
    if model.shell is not None:
        before = growth
        growth, changed = even_growth(model.shell.face_edges, model.edge_rest_length, growth)
        if changed:
            which = ""
            if petal is not None:
                owners = np.unique(np.asarray(petal)[model.shell.face_indices[changed, 0]])
                which = f" of petal(s) {', '.join(map(str, owners.tolist()))}"
            log.info("growth.start = open: %d sliver triangle(s)%s would have no rest area "
                     "at the bud (their edges' growth ratios differ too much): their ratios "
                     "evened out toward their mean (largest change %.3g)", len(changed),
                     which, float(np.abs(growth - before).max()))
    rest = model.edge_rest_length / (1.0 + growth)
    growth = np.ascontiguousarray(growth)
    shell = model.shell
    if shell is not None:
        if positions is None:
            raise ValueError("an open shell needs the model's positions (its curvature)")
        shell = shell.rest_on(positions, rest, growth, beta, bud)
    return dataclasses.replace(model, edge_rest_length=rest, edge_growth=growth, shell=shell)


def open_rest_angle(rest_angle: np.ndarray, beta: float) -> np.ndarray:
    """Rest dihedral angles at the bud such that curl (``theta0 (1 - B beta)``, Eq. 11)
    gives the model's own at B = 1."""
    if beta >= 1.0:
        raise ValueError(f"effects.curl.beta: {beta:g} x growth.close is 1 or more; curl "
                         "cannot be undone from an open model (its rest angles would be "
                         "infinite)")
    return np.asarray(rest_angle, dtype=np.float64) / (1.0 - beta)


class _Bud:
    """A(t) = 0: the bud's growth, held."""

    def growth_at(self, t: float) -> float:
        return 0.0


def rest_at(model: Model, positions, beta: float = 0.0) -> Model:
    """``model`` with its rest lengths and angles measured on ``positions`` (the growth
    ratios kept): rest lengths ``L / (1 + alpha)``, so that they are ``positions``' at A = 1.
    A shell's rest curvature too (:meth:`~pipeline.sim.terms.shell.ShellData.rest_on`;
    ``beta``: the curl's, which decays it on the way to A = 1)."""
    X = np.ascontiguousarray(positions, dtype=np.float64)
    length = np.empty(model.edge_count)
    edge_lengths(X, model.edge_indices, length)
    cos0, sin0 = np.empty(model.hinge_count), np.empty(model.hinge_count)
    hinge_cos_sin(X, model.hinge_indices, cos0, sin0)
    growth = model.edge_growth
    if model.shell is not None:  # (a sliver the lift flattens further: see even_growth)
        growth = even_growth(model.shell.face_edges, length, growth)[0]
    rest = length / (1.0 + growth)
    shell = None if model.shell is None else model.shell.rest_on(X, rest, growth, beta)
    return dataclasses.replace(model, edge_rest_length=rest, edge_growth=growth,
                               hinge_rest_cos=cos0, hinge_rest_sin=sin0, shell=shell)


def lift_faded(model: Model, positions, lift, beta: float = 0.0) -> Model:
    """The open shell ``model`` (:func:`open_model`'s, at the mesh ``positions``) with the
    closing ``lift`` grown into its rest state at the bud, fading out over the bloom: at
    A = 0 its rest lengths and curvature are those of ``positions + lift`` (its growth
    ratios and bud shape undone from them as from the mesh), at A = 1 still the mesh's
    own, and in between the kernels' linear growth. The model's own path from the mesh
    then feels the lift from the first step on and closes on the branch the lift picks,
    and a bloom that retraces that path ends on the mesh itself (a lifted path's rest
    state is the lifted mesh's all the way: the bud it reaches may lie on no path back to
    the mesh). Raises ValueError where a face would have no rest area."""
    X = np.ascontiguousarray(positions, dtype=np.float64)
    up = np.ascontiguousarray(X + lift)
    full, lifted = np.empty(model.edge_count), np.empty(model.edge_count)
    edge_lengths(X, model.edge_indices, full)
    edge_lengths(up, model.edge_indices, lifted)
    rest = lifted / (1.0 + model.edge_growth)
    growth = np.ascontiguousarray(full / rest - 1.0)
    shell = model.shell.rest_on(X, rest, growth, beta, lifted=up)
    return dataclasses.replace(model, edge_rest_length=rest, edge_growth=growth, shell=shell)


def find_bud(model: Model, open_positions, effects, *, stages: int, tolerance: float,
             lift=None, settle_effects=None, petal=None, beta: float = 0.0):
    """The equilibrium at A = 0 reached from the model (at A = 1) along the path of
    equilibria. Returns ``(positions, solver)``; the solver's diagnostics say what it took.

    ``lift`` ``(V, 3)``, if given, picks the branch where the path forks (a flat petal
    can close up or down): the path is followed from the model moved by ``lift`` (rest
    lengths and angles measured there), and the bud it reaches is then settled at A = 0
    on the model itself (``settle_effects``: fresh effects for that solve), so the bud
    is the model's own equilibrium, on the branch the lift chose. ``petal`` ``(V,)``
    names the petals in the log (of the solver's rescues); ``beta`` is the curl's (a
    shell's rest curvature on the lifted path, :func:`rest_at`)."""
    backward = Backward()
    solver = QuasiStatic(stages=stages, tolerance=tolerance, petal=petal)
    start = np.asarray(open_positions, dtype=np.float64)
    if lift is not None:
        start = start + lift
    path_model = model if lift is None else rest_at(model, start, beta)
    state = State.at_rest(path_model, start, backward)
    solver.advance(path_model, state, backward, 1, 1.0, effects)
    if lift is None:
        return state.positions.copy(), solver
    settle = QuasiStatic(stages=stages, tolerance=tolerance, perturbation=0.0, petal=petal)
    bud = State.at_rest(model, state.positions, _Bud())
    settle.advance(model, bud, _Bud(), 0, 1.0, settle_effects if settle_effects is not None else effects)
    solver.iterations += settle.iterations
    return bud.positions.copy(), solver


def closing_lift(positions, s, x, pinned, up, size: float) -> np.ndarray:
    """``(V, 3)``: each free vertex moved by ``size (s^2 + x^2) / 2`` along ``up`` (the
    flower's axis, toward its open side; ``s`` along the petal, ``x`` across it): every
    petal is nudged into a cup that closes over the flower, not one that folds under it."""
    s, x = np.asarray(s, dtype=np.float64), np.asarray(x, dtype=np.float64)
    lift = size * 0.5 * (s ** 2 + x ** 2)[:, None] * np.asarray(up)  # ((3,) or (V, 3))
    lift[np.asarray(pinned, bool)] = 0.0
    return lift


def triangle_quality(positions, faces) -> np.ndarray:
    """``(F,)`` twice each triangle's area over its longest edge squared (0: collapsed;
    0.87 equilateral)."""
    X = np.asarray(positions, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    a, b, c = X[f[:, 0]], X[f[:, 1]], X[f[:, 2]]
    longest = np.max([np.sum((b - a) ** 2, axis=1), np.sum((c - b) ** 2, axis=1),
                      np.sum((a - c) ** 2, axis=1)], axis=0)
    return np.linalg.norm(np.cross(b - a, c - a), axis=1) / longest


def plane_across(positions, petal, plane) -> np.ndarray:
    """``(V,)`` a cross-section coordinate smooth in space: each vertex's signed distance
    to its petal's center plane over the largest in that petal. (``x`` is not smooth where
    a petal narrows: near its tip it runs from -1 to 1 within an edge or two.)"""
    X = np.asarray(positions, dtype=np.float64)
    petal = np.asarray(petal, dtype=np.int64)
    pl = np.asarray(plane, dtype=np.float64).reshape(-1, 4)[petal]
    d = np.einsum("ij,ij->i", X, pl[:, :3]) + pl[:, 3]
    largest = np.zeros(int(petal.max()) + 1 if len(petal) else 0)
    np.maximum.at(largest, petal, np.abs(d))
    return d / np.where(largest > 0.0, largest, 1.0)[petal]


def unfolded_lift(positions, faces, petal, plane, s, x, pinned, up, size):
    """The closing lift (:func:`closing_lift`), mended where it would fold a triangle
    (leave it under :data:`FOLD` of its own quality): then across each petal it follows
    the distance from the center plane (:func:`plane_across`) instead of ``x``. Returns
    ``(lift, folded)``: ``folded`` the petals whose triangles ``s^2 + x^2`` folded (empty:
    that lift is kept as it is)."""
    lift = closing_lift(positions, s, x, pinned, up, size)
    quality = triangle_quality(positions, faces)
    folded = triangle_quality(np.asarray(positions) + lift, faces) < FOLD * quality
    if not folded.any():
        return lift, []
    petals = sorted({int(p) for p in np.asarray(petal)[np.asarray(faces)[folded, 0]]})
    return closing_lift(positions, s, plane_across(positions, petal, plane), pinned, up,
                        size), petals


def contact_free(lift, positions, effects):
    """The lift, cut short where it would bring petals nearer than the contact's gap
    (petals that lie close in the model, a pinwheel's, pressed into each other by it): to
    half the largest fraction of the straight move that keeps them apart (continuous
    collision detection). As it is without contact. The flowers of a file of many are cut
    each on its own (their petals never meet: each flower is a problem of its own)."""
    c = effects.collisions
    if c is None:
        return lift
    X = np.asarray(positions, dtype=np.float64)
    out = np.array(lift, dtype=np.float64)
    flower = c.vertex_flower
    groups = [np.arange(len(X))] if flower is None else [
        np.flatnonzero(flower == f) for f in range(int(flower.max()) + 1)]
    cuts = []
    for f, idx in enumerate(groups):
        faces, petal = c.faces, c.petal
        if flower is not None:  # (the flower's own faces, on its own vertices)
            faces = np.searchsorted(idx, faces[flower[faces[:, 0]] == f])
            petal = petal[idx]
        contact = Contact.build(X[idx], faces, petal, gap=c.thickness, stiffness=1.0,
                                left=c.left, count=None if c.in_contact is None
                                else int(np.sum(idx < c.in_contact)))
        fraction = contact.max_step(X[idx], X[idx] + out[idx])
        if fraction < 1.0:
            out[idx] *= 0.5 * fraction
            cuts.append((f, 0.5 * fraction))
    if cuts and flower is None:
        log.info("growth.start = open: the closing lift would press petals into each other; "
                 "cut to %.3g of it (%.3g petal lengths at the tip)", cuts[0][1],
                 cuts[0][1] * LIFT)
    elif cuts:
        log.info("growth.start = open: the closing lift would press petals into each other "
                 "in %d of %d flowers; cut to %s of it", len(cuts), len(groups),
                 ", ".join(f"{cut:.3g} (flower {f})" for f, cut in cuts))
    return out


def petal_lengths(positions, petal, base) -> np.ndarray:
    """``(P,)`` each petal's length: the farthest of its vertices from its base's centre."""
    X = np.asarray(positions)
    out = np.zeros(int(np.max(petal)) + 1)
    for p in range(len(out)):
        mine = petal == p
        held = mine & base
        centre = X[held].mean(axis=0) if held.any() else X[mine].mean(axis=0)
        out[p] = np.linalg.norm(X[mine] - centre, axis=1).max()
    return out


def distance_to_model(positions, model_positions, petal, base) -> float:
    """RMS distance of the vertices from the model, over the mean petal length."""
    d = np.linalg.norm(np.asarray(positions) - np.asarray(model_positions), axis=1)
    return float(np.sqrt(np.mean(d ** 2)) / petal_lengths(model_positions, petal, base).mean())


#: growth.start = open with growth.close left at its default: a bud whose petals are less
#: than this much more closed than the model (degrees, the mean over petals of the
#: opening angle's change) is searched again closing twice as far, up to
#: :data:`MOST_CLOSE` times the default (a flat petal, whose rim's growth undone curls
#: it across far more than it closes: dimontel's bud, 8.7 deg at 1, 111.9 at 3)
CLOSED = 20.0
MOST_CLOSE = 4.0

#: growth.start = open: where the path to the bud finds no equilibrium (a petal that
#: crumples as it closes: a rose's rolled rim), it is tried again closing half as far,
#: this many times, before the run is refused
CLOSE_TRIES = 2


def _find_bud_closing(cfg, close, model, positions, rest_angle, params, build_effects, petal,
                      base, s, x, flower_axis, faces, plane, path="lifted", bud_shape=None,
                      unlifted=False):
    """:func:`open_start`'s bud search at ``close`` (``growth.close``): the bud, the solver,
    and the model, rest angles and effect parameters that grow from it back to the mesh.
    ``path`` (:data:`PATHS`): from the model nudged toward closing, along the model's own
    path, or along it with the nudge grown into the rest state (a shell's).
    ``bud_shape``: a shell's (:func:`bud_shape_of`). ``unlifted``: where contact cuts the
    lift to nothing (petals that start within the gap of each other), no search is made
    (the bud and the solver None): the lifted path would be the model's own."""
    beta = 0.0
    if cfg["effects.curl.enabled"] is True:
        params = params.but(curl={"beta": close * params.curl.beta})
        rest_angle = open_rest_angle(rest_angle, params.curl.beta)
        beta = params.curl.beta
    model = open_model(model, close, positions, beta, petal, bud_shape)
    if path == "own":
        bud, solver = find_bud(model, positions, build_effects(positions),
                               stages=cfg["simulate.stages"], tolerance=cfg["simulate.tolerance"],
                               petal=np.asarray(petal), beta=beta)
        return bud, solver, model, rest_angle, params
    _, up = flower_axis_or_guess(positions, flower_axis)
    if up.ndim == 2:  # (each petal's flower's axis)
        up = up[np.asarray(petal)]
    size = LIFT * petal_lengths(positions, petal, base).mean()
    if faces is not None and plane is not None:
        lift, folded = unfolded_lift(positions, faces, petal, plane, s, x, base, up, size)
        if folded:
            log.info("growth.start = open: the closing lift (s^2 + x^2) would fold a "
                     "triangle of petal(s) %s (under %g of its shape); lifted by the "
                     "distance from each center plane instead", ", ".join(map(str, folded)),
                     FOLD)
    else:
        lift = closing_lift(positions, s, x, base, up, size)
    at_model = build_effects(positions)  # (the settle's; contact_free only reads it)
    if path == "faded":  # (the path starts on the model itself: the lift is a rest state)
        model = lift_faded(model, positions, lift, beta)
        bud, solver = find_bud(model, positions, at_model, stages=cfg["simulate.stages"],
                               tolerance=cfg["simulate.tolerance"], petal=np.asarray(petal),
                               beta=beta)
        return bud, solver, model, rest_angle, params
    lift = contact_free(lift, positions, at_model)
    if unlifted and not np.any(lift):
        return None, None, model, rest_angle, params
    bud, solver = find_bud(model, positions, build_effects(positions + lift),
                           stages=cfg["simulate.stages"], tolerance=cfg["simulate.tolerance"],
                           lift=lift, settle_effects=at_model, petal=np.asarray(petal),
                           beta=beta)
    return bud, solver, model, rest_angle, params


def bud_shape_of(cfg, model: Model, positions, petal, s, flower_axis) -> BudShape | None:
    """The shell's bud shape the scene asks for (``growth.cup``, ``growth.recurve``; the
    inside found once for every search); None for the paper's springs."""
    if getattr(model, "shell", None) is None:
        return None
    return BudShape(inner_sides(positions, model.shell.face_indices, petal, s, flower_axis),
                    cfg["growth.cup"], cfg["growth.recurve"])


def open_start(cfg, model: Model, positions, rest_angle, params: Params, build_effects, petal,
               base, s, x, flower_axis, where: str, *, faces=None, plane=None,
               path: str = "lifted", closed_by=None, unlifted: bool = False):
    """``growth.start = "open"``: the model at A = 1, the bud at A = 0. Returns the bud's
    positions, the model, rest angles and effect parameters that grow from it back to
    the mesh, and figures for the artifact (``bud_seconds``, ``bud_newton_iterations``,
    ``bud_distance``, ``bud_close``: the growth.close it closed by, halved where the
    full one found no equilibrium; ``bud_path``: the path it took, :data:`PATHS`; from
    the lifted model, no bud down to the last halving tries the model's own path).
    ``build_effects(positions)`` builds the scene's effects at ``positions``. With
    ``faces`` and ``plane`` (each petal's center plane) a lift that
    would fold a triangle is mended (:func:`unfolded_lift`). ``path``: the path to the
    bud starts from the model nudged toward closing (lifted: :func:`closing_lift` picks
    the branch where a flat petal could close either way), or from the model itself
    (own: the path a bloom from that bud retraces, where it has no fork; faded: the same
    with the nudge grown into its rest state, :func:`lift_faded`).
    ``closed_by(bud)``: how much more closed a bud is than the model (degrees); with
    growth.close at its default, a bud under :data:`CLOSED` is searched again closing
    twice as far (up to :data:`MOST_CLOSE` times). ``unlifted``: where contact cuts the
    lift to nothing, no bud is searched for (the bud returned is None, ``bud_path``
    "own"): the lifted path would be the model's own, which the caller follows once, as
    the path back (:func:`retrace`). Raises :class:`BloomError` naming the key to change."""
    close = cfg["growth.close"]
    clock = time.perf_counter()
    shape = bud_shape_of(cfg, model, positions, petal, s, flower_axis)
    for attempt in range(CLOSE_TRIES + 1):
        try:
            found = _find_bud_closing(cfg, close, model, positions, rest_angle, params,
                                      build_effects, petal, base, s, x, flower_axis, faces,
                                      plane, path, shape, unlifted)
            break
        except NotConverged as exc:
            if attempt == CLOSE_TRIES and path == "lifted":  # the model's own path, before
                # refusing
                log.warning("growth.start = open: with the closing lift the path to the bud "
                            "found no equilibrium down to growth.close = %g; searching along "
                            "the model's own path", close)
                return open_start(cfg, model, positions, rest_angle, params, build_effects,
                                  petal, base, s, x, flower_axis, where, faces=faces,
                                  plane=plane, path="own", closed_by=closed_by)
            if attempt == CLOSE_TRIES:
                tried = (f" (tried closing down to growth.close = {close:g})"
                         if CLOSE_TRIES else "")
                raise BloomError(f"growth.close: finding the bud, the quasi-static solver "
                                 f"found {exc} (petal {int(petal[exc.vertex])}){tried}; remedy: "
                                 "a smaller growth.close, or more simulate.stages",
                                 where=where) from None
            log.warning("growth.start = open: closing by growth.close = %g, the path to the "
                        "bud found no equilibrium at A = %.4g (petal %d); closing half as far",
                        close, exc.growth, int(petal[exc.vertex]))
            close *= 0.5
        except ContactError as exc:
            raise BloomError(f"{exc.key}: finding the bud: {exc}", where=where) from None
        except ValueError as exc:
            raise BloomError(f"growth.start: finding the bud: {exc}", where=where) from None
    if found[0] is None:  # (the lift cut to nothing: the model's own path, not searched)
        log.info("growth.start = open: with the lift cut to nothing the path to the bud is "
                 "the model's own: followed once, as the path back, its frames the bloom")
        return (None, *found[2:], {"bud_seconds": 0.0, "bud_newton_iterations": 0,
                                   "bud_close": close, "bud_path": "own",
                                   **_bud_shape_info(found[2], positions)})
    if closed_by is not None and "growth.close" not in cfg.given and close == cfg["growth.close"]:
        turned = closed_by(found[0])
        while turned < CLOSED and 2.0 * close <= MOST_CLOSE * cfg["growth.close"]:
            log.info("growth.start = open: the bud at growth.close = %g is %.1f deg more "
                     "closed than the model (under %g); closing twice as far", close, turned,
                     CLOSED)
            try:
                again = _find_bud_closing(cfg, 2.0 * close, model, positions, rest_angle,
                                          params, build_effects, petal, base, s, x,
                                          flower_axis, faces, plane, path, shape)
            except (NotConverged, ContactError, ValueError) as exc:
                log.info("growth.start = open: no bud at growth.close = %g (%s); the one at "
                         "%g kept", 2.0 * close, str(exc).split(";")[0], close)
                break
            more = closed_by(again[0])
            if not more > turned:  # (closing further found a bud no more closed: hallgeirl's
                # at 2 hangs open the other way, -6.6 deg)
                log.info("growth.start = open: the bud at growth.close = %g is %.1f deg more "
                         "closed than the model, no more than at %g; the one at %g kept",
                         2.0 * close, more, close, close)
                break
            close, found, turned = 2.0 * close, again, more
    bud, solver, model, rest_angle, params = found
    seconds = time.perf_counter() - clock
    moved = distance_to_model(bud, positions, petal, base)
    log.info("growth.start = open: found the bud in %.2f s (%d Newton iterations); it is %.3g "
             "petal lengths (RMS) from the model", seconds, solver.iterations, moved)
    info = {"bud_seconds": seconds, "bud_newton_iterations": solver.iterations,
            "bud_distance": moved, "bud_close": close, "bud_path": path,
            **_bud_shape_info(model, positions)}
    return bud, model, rest_angle, params, info


def _bud_shape_info(model: Model, positions) -> dict:
    """A shell's bud shape, logged, and the model's recurve share for the artifact
    (``recurve_share``); nothing for the paper's springs."""
    sh = getattr(model, "shell", None)
    if sh is None or sh.bud is None:
        return {}
    X = np.asarray(positions, dtype=np.float64)
    share = recurve_share(X, sh.face_indices, sh.form_at(X), sh.bud.inside)
    shape = ([f"cupped toward the flower's inside (curvature {sh.bud.cup:g} / petal size, "
              "growth.cup)"] if sh.bud.cup > 0.0 else [])
    if sh.bud.recurve:
        shape.append(f"not rolled back: the model's recurve ({100 * share:.0f}% of its "
                     "squared curvature) grows in over the bloom (growth.recurve)")
    if shape:
        log.info("growth.start = open: the bud is %s", " and ".join(shape))
    return {"recurve_share": share}
