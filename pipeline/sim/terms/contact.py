"""Contact that cannot be crossed, for the quasi-static (Newton) energy.

Contact (:class:`Contact`) is the incremental-potential barrier of IPC (Li et al. 2020)
through ipctk: for every pair of primitives of two *different* petals (vertex-face,
edge-edge, and their degenerate cases) closer than ``gap + band``, a barrier
``kappa b(d)`` that is zero at ``d = gap + band`` and infinite at ``d = gap``. Every
Newton step (line search, negative-curvature search) is first limited by continuous
collision detection (:meth:`Contact.max_step`), so no iterate ever comes closer than
``gap``, let alone crosses: the energy stays finite and the barrier keeps it that way.

- A petal keeps off itself too (ipctk leaves out primitives that share a vertex),
  everywhere but where its own primitives start within the barrier's reach of each
  other (:func:`_own_contact`: a rim's hairpin turn, a sliver; those few vertices are
  left to themselves, the rest of the petal keeps off itself; with contact between
  petals only for all, the lotus's petal 2 folded through itself in one frame). Where a
  petal passes through itself or another at the start, contact is between petals only.
  The exact intersection test of the report
  (:func:`pipeline.mesh.intersect.frame_intersections`) checks
  self-intersections.
- Two petals that remesh left through each other as modelled (``left``) have no contact
  between them; each keeps it with every other petal (the pairs are left out of ipctk's
  filter one by one, :class:`pipeline.mesh.ipc.Filter`, not joined in groups: on the
  rose bed, groups joined by chains of such pairs took in whole roses, and their petals
  passed through each other in 931 pairs more than modelled). The petals of such a pair
  have no contact with themselves either (ipctk's filter keeps apart vertices of one
  patch, and a pair is one patch); every other petal keeps off itself. (Until
  2026-12-03 one pair left so took every petal's own contact away.)
- ``gap`` is the key ``effects.collisions.thickness``; the band over which the barrier
  acts is as wide again, so petals feel each other from ``2 gap`` on.
- ``kappa`` makes the barrier as stiff, at the middle of its band, as the stiffest
  stretch spring of the model: a pressing force of the order of the elastic forces
  stops within the band (it scales with the problem, as the springs do). A shell's is
  in units of the petal instead (:func:`pipeline.sim.terms.shell.contact_stiffness`:
  the same pressure against distance at any resolution).
- The Hessian is ipctk's, projected to positive semi-definite per contact (it adds no
  negative curvature of its own; the elastic Hessian stays exact).
- ipctk runs on one thread, set once (:func:`pipeline.mesh.ipc.ipctk`): the artifacts must be
  bit-reproducible, and ipctk's threads are not. Its parallel sums depend on the
  scheduling, and so, it was measured, does the rest: with its broad phase and CCD in two
  threads, the same 14-petal open flower found its bud in 818, 813, 819 and 807 Newton
  iterations on four runs (one thread: 818 every run, the same bits). The solver's own
  threads (the groups' factorizations) keep both cores busy. The active set is still
  put in one order (:func:`_canonical`), whatever order the candidates come in.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from pipeline.mesh.ipc import Filter
from pipeline.mesh.ipc import ipctk as one_thread
from pipeline.mesh.separate import crossed_pairs
from pipeline.sim.terms.term import Term


class ContactError(RuntimeError):
    """The bud cannot start under contact: ``key`` is the config key to name."""

    def __init__(self, message: str, key: str = "effects.collisions"):
        self.key = key
        super().__init__(message)


def _canonical(collisions) -> None:
    """The active set ``collisions`` (an ipctk.NormalCollisions) with each kind of contact
    sorted by its primitives' ids: the broad phase in threads finds its candidates in an
    order the scheduling decides, and the barrier's sums run over the active set in its
    order; sorted, they are the same bits with any number of threads."""
    for kind, key in (("vv_collisions", lambda c: (c.vertex0_id, c.vertex1_id)),
                      ("ev_collisions", lambda c: (c.edge_id, c.vertex_id)),
                      ("ee_collisions", lambda c: (c.edge0_id, c.edge1_id)),
                      ("fv_collisions", lambda c: (c.face_id, c.vertex_id))):
        found = getattr(collisions, kind)
        if len(found) > 1:
            setattr(collisions, kind, sorted(found, key=key))


def barrier_curvature(d: float, gap: float, band: float) -> float:
    """``d^2/dd^2`` of ipctk's barrier (kappa = 1) at distance ``d`` from a primitive:
    ``b(s) = -(s - S)^2 ln(s / S)`` of ``s = d^2 - gap^2``, ``S = (gap + band)^2 - gap^2``."""
    s = d * d - gap * gap
    S = (gap + band) ** 2 - gap * gap
    r = s - S
    log = math.log(s / S)
    b1 = -2.0 * r * log - r * r / s
    b2 = -2.0 * log - 4.0 * r / s + r * r / (s * s)
    return b2 * 4.0 * d * d + 2.0 * b1


@dataclass
class Contact(Term):
    """The barrier between petals and its CCD (see the module docstring)."""

    name = "contact"

    mesh: object  #: ipctk.CollisionMesh over all vertices, a petal never against itself
    petal: np.ndarray  #: (V,) petal of each vertex
    gap: float  #: distance no two petals come closer than (mesh units)
    band: float  #: the barrier acts from gap + band down to gap
    kappa: float  #: barrier stiffness
    #: the config key the gap comes from, and its unit in mesh units (the shell's gap is
    #: in units of the petal size): what a message names
    key: str = "effects.collisions.thickness"
    unit: float = 1.0
    potential: object = field(repr=False, default=None)  #: ipctk.BarrierPotential
    ccd: object = field(repr=False, default=None)  #: narrow phase (Additive CCD)
    collisions: object = field(repr=False, default=None)  #: active set, built at the last X
    _at: np.ndarray | None = field(repr=False, default=None)  #: X the active set is of
    #: broad-phase candidates of the last move (:meth:`sweep`), and the box each vertex
    #: swept: valid for any X whose every vertex lies in its box
    candidates: object = field(repr=False, default=None)
    _low: np.ndarray | None = field(repr=False, default=None)
    _high: np.ndarray | None = field(repr=False, default=None)
    #: the vertex patches of the collision filter (two vertices of one patch never
    #: collide), or None (every petal keeps off itself too): :func:`_own_contact`
    _patches: np.ndarray | None = field(repr=False, default=None)
    #: petal pairs left through each other as modelled (``(K, 2)``; no contact between the
    #: two of a pair), or None
    left: np.ndarray | None = field(repr=False, default=None)
    _filter: object = field(repr=False, default=None)  #: the mesh's (its arrays live here)
    #: the contact's vertices are the first ``count`` (a mesh cut finer for the solve
    #: keeps its contact on the coarse mesh's triangles, whose vertices come first), or
    #: None: all
    count: int | None = None

    @classmethod
    def build(cls, positions, faces, petal, *, gap: float, stiffness: float,
              left=None, count: int | None = None) -> Contact:
        """``stiffness``: what the barrier's curvature is at the middle of its band.
        A petal keeps off the others and off itself (its triangles that share no vertex),
        where the start allows it (:func:`_own_contact`). ``left`` ``(K, 2)``: petal
        pairs left through each other as modelled, with no contact between the two (each
        keeps it with every other petal), or None. ``count``: only the first ``count``
        vertices are in contact (``faces`` on them), or None: all."""
        ipctk = one_thread()
        X = np.asfortranarray(np.asarray(positions)[:count], dtype=np.float64)
        F = np.asfortranarray(faces, dtype=np.int32)
        mesh = ipctk.CollisionMesh(X, ipctk.edges(F), F)
        petal = np.ascontiguousarray(np.asarray(petal)[:count], dtype=np.int32)
        left = None if left is None or not len(left) else np.asarray(left, dtype=np.int64)
        pairs = () if left is None else left.tolist()
        # every pair of petals but those left, and each petal off itself but the pairs'
        # (a patch filter keeps a pair's two petals from each other and from themselves)
        apart = Filter(petal=petal, pairs=pairs, selves=False)
        apart.apply(mesh)
        patches = _own_contact(mesh, X, petal, 2.0 * gap)
        keep = apart if patches is None else apart.also(patches)
        keep.apply(mesh)
        band = gap
        kappa = stiffness / barrier_curvature(gap + 0.5 * band, gap, band)
        contact = cls(mesh, petal, float(gap), float(band), float(kappa), count=count)
        contact._patches, contact.left, contact._filter = patches, left, keep
        contact.potential = ipctk.BarrierPotential(contact.band, contact.kappa)
        contact.ccd = ipctk.AdditiveCCD()
        return contact

    # --- the start ----------------------------------------------------------------------
    def check_start(self, X) -> None:
        """Refuse a bud the barrier cannot start from: petals through each other, or
        touching; names the petal pairs. Petals closer than the gap (but apart) make the
        gap half their distance (logged)."""
        ipctk = one_thread()
        X = self._mine(X)
        if ipctk.has_intersections(self.mesh, X):
            pairs = self.intersecting_pairs(X)
            raise ContactError(
                f"petals {_pairs(pairs)} pass through each other in the bud: contact cannot "
                "start from an intersecting bud; fix the input mesh, or disable "
                "effects.collisions (the push-back of the semi-implicit scheme)")
        close = self.close_pairs(X, self.gap)
        if close:
            worst = min(d for _, _, d in close)
            if worst <= 1e-6 * self.gap:  # (a distance the barrier cannot keep)
                raise ContactError(
                    f"petals {_pairs([(a, b) for a, b, _ in close])} touch in the bud "
                    f"(down to {worst:.3g} apart): contact cannot start from petals that "
                    "touch; fix the input mesh, or disable effects.collisions",
                    key=self.key)
            # petals that start closer than the gap: the gap is what they start with, halved
            # (the barrier then acts from there down), and the log says so
            gap = 0.5 * worst
            logging.getLogger("bloom").warning(
                "petals %s start closer than %s = %.3g (down to %.3g apart): contact keeps a "
                "gap of %.3g instead", _pairs([(a, b) for a, b, _ in close]), self.key,
                self.gap / self.unit, worst / self.unit, gap / self.unit)
            self._regap(gap)

    def _regap(self, gap: float) -> None:
        """Keep ``gap`` (band as wide), with the barrier as stiff at its band's middle as
        before."""
        ipctk = one_thread()
        stiffness = self.kappa * barrier_curvature(self.gap + 0.5 * self.band, self.gap,
                                                   self.band)
        self.gap = self.band = float(gap)
        self.kappa = float(stiffness / barrier_curvature(gap + 0.5 * gap, gap, gap))
        self.potential = ipctk.BarrierPotential(self.band, self.kappa)
        self.collisions, self._at, self.candidates = None, None, None

    def intersecting_pairs(self, X) -> list[tuple[int, int]]:
        """Petal pairs that intersect at X (an edge of one through a triangle of the
        other: one pass over the mesh, :func:`pipeline.mesh.separate.crossed_pairs`), but
        those left through each other."""
        return crossed_pairs(self._mine(X), self.mesh.faces, self.petal,
                             () if self.left is None else self.left)

    def close_pairs(self, X, distance: float) -> list[tuple[int, int, float]]:
        """Petal pairs closer than ``distance`` at X, with their smallest distance."""
        ipctk = one_thread()
        X = self._mine(X)
        found = ipctk.NormalCollisions()
        found.build(self.mesh, X, distance)
        edges, faces = self.mesh.edges, self.mesh.faces
        best: dict[tuple[int, int], float] = {}
        for k in range(len(found)):
            # (found[k] refers into found: it must not outlive it, or freeing it crashes)
            ids = sorted({int(self.petal[i]) for i in found[k].vertex_ids(edges, faces) if i >= 0})
            d = math.sqrt(found[k].compute_distance(X, edges, faces))
            if len(ids) == 2:
                key = (ids[0], ids[1])
                best[key] = min(best.get(key, math.inf), d)
        return [(a, b, d) for (a, b), d in sorted(best.items()) if d < distance]

    def snapshot(self) -> dict:
        """What the barrier carries from one step to the next: its gap (the bud may have
        narrowed it, :meth:`check_start`) and the boxes of its last sweep."""
        return {"gap": self.gap, "band": self.band, "kappa": self.kappa,
                "low": self._low, "high": self._high}

    def restore(self, saved: dict) -> None:
        """Put back a :meth:`snapshot`: the same gap, and the same sweep's candidates."""
        ipctk = one_thread()
        self.gap, self.band, self.kappa = (float(saved[k]) for k in ("gap", "band", "kappa"))
        self.potential = ipctk.BarrierPotential(self.band, self.kappa)
        self.collisions, self._at, self.candidates = None, None, None
        self._low = self._high = None
        if saved["low"] is not None:
            self._low = np.asfortranarray(saved["low"], dtype=np.float64)
            self._high = np.asfortranarray(saved["high"], dtype=np.float64)
            self.candidates = ipctk.Candidates()
            self.candidates.build(self.mesh, self._low, self._high, self.gap + self.band)

    # --- energy, gradient, Hessian ------------------------------------------------------
    def sweep(self, X0, X1, margin: float = 0.0) -> None:
        """Broad phase once for a region: each vertex's box over the straight move
        X0 -> X1, widened by ``margin``; the candidates are every pair of primitives
        that can come within the barrier's reach while each vertex stays in its box.
        So the active sets (:meth:`_active`) and the CCD (:meth:`max_step`) of any
        position or move inside the boxes are those a full broad phase would give, at
        a narrow phase's cost: one sweep serves a growth increment's iterations as
        long as they stay in it."""
        ipctk = one_thread()
        X0, X1 = self._mine(X0), self._mine(X1)
        low = np.asfortranarray(np.minimum(X0, X1) - margin, dtype=np.float64)
        high = np.asfortranarray(np.maximum(X0, X1) + margin, dtype=np.float64)
        self.candidates = ipctk.Candidates()
        self.candidates.build(self.mesh, low, high, self.gap + self.band)
        self._low, self._high = low, high

    def _mine(self, X) -> np.ndarray:
        """The contact's vertices' rows of ``X`` (:attr:`count`)."""
        return np.asfortranarray(np.asarray(X)[:self.count], dtype=np.float64)

    def _swept(self, X) -> bool:
        X = np.asarray(X)[:self.count]
        return (self.candidates is not None and bool(np.all(self._low <= X))
                and bool(np.all(X <= self._high)))

    def _active(self, X):
        """The pairs within the barrier's band at ``X`` (the contact's rows,
        :meth:`_mine`), built once per position."""
        if self._at is None or not np.array_equal(self._at, X):
            ipctk = one_thread()
            self.collisions = ipctk.NormalCollisions()
            if self._swept(X):
                self.collisions.build(self.candidates, self.mesh, X, self.band, self.gap)
            else:
                self.collisions.build(self.mesh, X, self.band, self.gap)
            _canonical(self.collisions)
            self._at = X.copy()
        return self.collisions

    def forces(self, X, F) -> float:
        """The barrier's energy at X; subtracts its gradient from the forces ``F``
        (V, 3). Infinite where a pair is at or below the gap."""
        X = self._mine(X)
        active = self._active(X)
        if len(active) == 0:
            return 0.0
        energy = float(self.potential(active, self.mesh, X))
        if math.isfinite(energy):
            F[:len(X)] -= self.potential.gradient(active, self.mesh, X).reshape(-1, 3)
        return energy

    def hessian(self, X, project: bool = False) -> sp.csc_matrix | None:
        """The barrier's Hessian at X (3V x 3V), each contact's projected to positive
        semi-definite (``project``, as the solver takes it) or exact; None when no pair
        is within the band."""
        ipctk = one_thread()
        n = len(X)
        X = self._mine(X)
        active = self._active(X)
        if len(active) == 0:
            return None
        how = ipctk.PSDProjectionMethod.CLAMP if project else ipctk.PSDProjectionMethod.NONE
        H = self.potential.hessian(active, self.mesh, X, how)
        if len(X) < n:  # (the vertices past the contact's: no entries)
            H = sp.csc_matrix(H)
            H.resize((3 * n, 3 * n))
        return H

    def linked(self, X) -> np.ndarray:
        """(k, 2) vertex pairs that the contacts within the barrier's band join at X (the
        Hessian couples their unknowns): each contact's vertices, chained to its first."""
        active = self._active(self._mine(X))
        edges, faces = self.mesh.edges, self.mesh.faces
        pairs = []
        for k in range(len(active)):
            ids = [int(i) for i in active[k].vertex_ids(edges, faces) if i >= 0]
            pairs.extend((ids[0], i) for i in ids[1:])
        return np.array(pairs, dtype=np.int64).reshape(-1, 2)

    def active_count(self, X) -> int:
        return len(self._active(self._mine(X)))

    # --- steps ----------------------------------------------------------------------------
    def cover(self, X0, X1) -> None:
        """Sweep the straight move X0 -> X1 (:meth:`sweep`, with a margin of the
        barrier's band) unless the last sweep holds it."""
        if not (self._swept(X0) and self._swept(X1)):
            self.sweep(X0, X1, self.gap + self.band)

    def max_step(self, X0, X1) -> float:
        """The largest fraction of the straight move X0 -> X1 along which no two petals
        come closer than the gap (continuous collision detection, with ipctk's
        conservative rescaling): 1.0 is the whole move. Sweeps the move first
        (:meth:`sweep`, with a margin of the barrier's band) unless the last sweep holds
        it: its candidates serve the CCD and the active sets along it."""
        self.cover(X0, X1)
        return float(self.candidates.compute_collision_free_stepsize(
            self.mesh, self._mine(X0), self._mine(X1), self.gap, self.ccd))


def own_spots(positions, faces, petal, gap: float, left=None) -> np.ndarray:
    """``(V,)`` the spot of each vertex (a label), or -1: the spots that the contact with
    gap ``gap`` leaves to themselves at ``positions`` (a petal's own triangles within the
    barrier's reach of each other: a rim's hairpin turn, :func:`_own_contact`), with
    their rings; none where no spot is, or where contact is between petals only."""
    petal = np.asarray(petal)
    patches = Contact.build(positions, faces, petal, gap=gap, stiffness=1.0,
                            left=left)._patches
    if patches is None or np.array_equal(patches, petal):
        return np.full(len(petal), -1, dtype=np.int64)
    patches = np.asarray(patches, dtype=np.int64)
    return np.where(np.bincount(patches, minlength=len(patches))[patches] > 1, patches, -1)


def _own_contact(mesh, X, petal, reach: float) -> np.ndarray | None:
    """Where the barrier can keep each petal off itself from the start ``X``: everywhere
    but among the primitives of one petal that share no vertex and are within the
    barrier's ``reach`` of each other (they would feel it at rest: a hairpin turn of a
    rim, a flap, a sliver). Those primitives' vertices, with their rings, are joined in
    patches (the vertices of one patch never collide; the filter only takes pairs away, so
    none within reach is left between patches); every other vertex is a patch of its own,
    so the rest of the petal keeps off itself. Returns the patches (``(V,)`` int32), or
    None where no vertex is joined. Where a petal passes through itself or another at
    ``X`` (but for pairs the mesh's filter leaves out: petals left through each other as
    modelled), contact is between petals only (every petal one patch). Logged."""
    ipctk = one_thread()
    log = logging.getLogger("bloom")
    if ipctk.has_intersections(mesh, X):
        log.info("contact: between petals only, not of a petal with itself (a petal, or two, "
                 "pass through themselves or each other at the start)")
        return petal
    edges, faces = mesh.edges, mesh.faces
    root = np.arange(len(petal), dtype=np.int64)
    ring: dict[int, set] = {}  # (each vertex's neighbours, once a petal is near itself)

    def find(i: int) -> int:
        while root[i] != i:
            root[i] = root[root[i]]
            i = int(root[i])
        return i

    found = ipctk.NormalCollisions()
    found.build(mesh, X, reach)
    joined = False
    for k in range(len(found)):
        ids = [int(i) for i in found[k].vertex_ids(edges, faces) if i >= 0]
        if len({int(petal[i]) for i in ids}) != 1:
            continue  # (between petals: the start's check, Contact.check_start)
        # with their rings: a triangle that has a vertex outside the patch still stops
        # the patch's vertices at the gap (ipctk keeps a pair if any two of its vertices
        # may collide)
        if not ring:
            for a, b in np.asarray(edges):
                ring.setdefault(int(a), set()).add(int(b))
                ring.setdefault(int(b), set()).add(int(a))
        ids = sorted(set(ids).union(*(ring[i] for i in ids)))
        first = find(ids[0])
        for i in ids[1:]:
            other = find(i)
            if other != first:
                root[max(first, other)] = min(first, other)
                first = min(first, other)
                joined = True
    if not joined:
        return None
    patches = np.ascontiguousarray([find(i) for i in range(len(root))], dtype=np.int32)
    held = np.bincount(patches, minlength=len(patches)) > 1
    near = np.unique(np.asarray(petal)[held[patches]])
    log.info("contact: petal(s) %s keep off themselves but where their own triangles start "
             "within %.3g of each other (%d vertices, in %d spot(s), left to themselves); "
             "every petal keeps off the others", ", ".join(map(str, near.tolist())), reach,
             int(np.sum(held[patches])), int(np.sum(held)))
    return patches


def _pairs(pairs) -> str:
    return ", ".join(f"{a}-{b}" for a, b in pairs) or "(none found pairwise)"
