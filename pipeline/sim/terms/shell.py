"""A thin shell whose energy is a property of the surface, not of its triangles
(``simulate.model = "shell"``): its units (:func:`moduli`, in units of the petal size, so
that the same deformation has the same energy at any mesh resolution), what it adds to a
model (:class:`ShellData`), its Hessian's blocks (:class:`ShellBlocks`) and the term the
solver runs (:class:`ShellTerm`).

The paper's model (Eq. 2-3) gives every spring one ``K_s`` and every hinge one ``K_b``,
so the same petal triangulated twice is two different materials (issue 31). The shell is
a discretization of a continuum shell (Koiter's energy, St. Venant-Kirchhoff material):
a membrane energy from each face's strain against its grown rest metric, and a bending
energy from a patch-quadratic second fundamental form. The discretization and its
derivatives are in :mod:`pipeline.sim.terms.shell_kernels`; the stencils the kernels
read in :mod:`pipeline.sim.terms.shell_stencil`.
"""

from __future__ import annotations

import dataclasses
from collections import namedtuple
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from pipeline.mesh import topology
from pipeline.sim.blocks import Part
from pipeline.sim.budshape import BudShape, bloom_form
from pipeline.sim.terms.shell_kernels import (
    KERNEL_SCRATCH,
    rest_dets,
    second_form,
    shell_forces,
    shell_hessian,
    shell_rounding,
)
from pipeline.sim.terms.shell_stencil import (
    clamped_anchors,
    crease_angles,
    creases,
    face_edges,
    face_opposite,
    face_pattern,
    face_stencil,
    ghost_rows,
)
from pipeline.sim.terms.term import Term
from pipeline.sim.threads import parallel_map


def petal_size(vertices, faces, petal=None) -> float:
    """The length the shell's units are given in: ``sqrt`` of the mean petal area (mesh
    units). An area converges under refinement (to second order on a smooth surface),
    unlike a length measured along edges, and does not care where the base or the tip
    vertex falls."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]),
                                axis=1).sum()
    count = 1 if petal is None or len(petal) == 0 else int(np.max(petal)) + 1
    return float(np.sqrt(area / count))


#: defaults, chosen so that the default petal (assets/petal.obj, 317 vertices, mean
#: edge 1) matches the paper's springs (K_s = 0.1, K_b = 0.0005; see ``moduli``):
#: Poisson's ratio of a triangular lattice of springs ...
POISSON = 1.0 / 3.0


def moduli(size: float, stretch_modulus: float, thickness: float, poisson: float,
           face_thickness=None):
    """Per-face stretch modulus ``Y`` and bending modulus ``D`` in mesh units, from
    units that do not depend on the mesh:

    - ``stretch_modulus``: Young's modulus times thickness, energy per area, area in
      units of the petal size ``L`` (``size``, mesh units): ``Y = stretch_modulus /
      L^2``. Then a given strain field has the same membrane energy at any resolution;
    - ``thickness``: relative to ``L``: ``t = thickness L`` (mesh units), and ``D = Y
      t^2 / (12 (1 - nu^2))``: bending against stretching is fixed in units of the
      petal;
    - ``face_thickness (F,)`` (mesh units, 0 where unknown): a face with a thickness of
      its own has ``Y_f = Y t_f / t`` and ``D_f = Y_f t_f^2 / (12 (1 - nu^2))`` (bending
      ~ t^3, stretching ~ t; the material is the one of the configured sheet).

    How the paper's springs map: a lattice of equilateral triangles of edge ``l`` with
    springs ``K_s`` is a sheet of stretch modulus ``2 K_s / sqrt(3)`` and Poisson's ratio
    1/3; its hinges ``K_b (1 - cos(theta - theta0))`` bend a cylinder with ``D = sqrt(3)
    / 2 K_b`` (``l = 1``).
    """
    young = stretch_modulus / size ** 2
    t = thickness * size
    k = 1.0 / (12.0 * (1.0 - poisson ** 2))
    if face_thickness is None:
        return young, young * t * t * k
    tf = np.asarray(face_thickness, dtype=np.float64)
    own = tf > 0.0
    y = np.where(own, young * tf / t, young)
    tt = np.where(own, tf, t)
    return y, y * tt * tt * k


#: the petal size (mesh units) at which the moduli's defaults were matched to the paper's
#: springs: the default petal, assets/petal.obj at 317 vertices and mean edge 1
REFERENCE_SIZE = 15.3677


def contact_stiffness(data: ShellData) -> float:
    """The contact barrier's stiffness for a shell (its curvature at the middle of its
    band, mesh units; :meth:`pipeline.sim.terms.contact.Contact.build`): the same pressure
    against distance, in units of the petal, at any resolution. The barrier acts per
    pair of primitives, about one pair per vertex area, and the pipeline's meshes have
    mean edge 1: so its pressure is its stiffness over a fixed area, and a stiffness
    that follows the sheet's own (``Y``, ~ 1/L^2 in mesh units, as the springs'
    ``K_s``) would make the barrier (L / L_ref)^2 times stiffer in petal units on a
    mesh of petal size ``L``: 16 times from 1x to 16x the vertices. Scaled by
    ``(REFERENCE_SIZE / L)^2``: at the reference petal it is the springs' ``K_s``
    equivalent (as before)."""
    ks = float(np.sqrt(3.0) / 2.0 * data.face_stretch.max())
    return ks * (REFERENCE_SIZE / data.size) ** 2


def paper_equivalent(size: float, stretch_stiffness: float = 0.1,
                     bending_stiffness: float = 0.0005) -> tuple[float, float]:
    """``(stretch_modulus, thickness)`` of the sheet the paper's spring network is, on a
    mesh of mean edge 1 whose petal size is ``size`` (see :func:`moduli`)."""
    young = 2.0 * stretch_stiffness / np.sqrt(3.0)
    bend = np.sqrt(3.0) / 2.0 * bending_stiffness
    t = np.sqrt(bend * 12.0 * (1.0 - POISSON ** 2) / young)
    return young * size ** 2, t / size


@dataclass
class ShellData:
    """What the shell adds to a :class:`~pipeline.sim.model.Model` (whose edges keep
    their rest lengths and growth ratios: the rest metric is made of them)."""

    face_indices: np.ndarray  #: (F, 3) int64 corners q0, q1, q2 (counter-clockwise)
    #: (F, 3) int64 the vertex across the edge opposite q_i, or on the boundary a stand-in
    #: (:func:`face_stencil`; -1: none, the ghost row)
    face_opposite: np.ndarray
    face_ghost: np.ndarray  #: (F, 3, 3) patch rows of the boundary edges (:func:`ghost_rows`)
    face_edges: np.ndarray  #: (F, 3) int64 the model's edge opposite q_i
    face_rest_form: np.ndarray  #: (F, 3) (b11, b12, b22) of the bud, growth 0
    face_rest_det: np.ndarray  #: (F,) det of the rest metric at growth 0 (mesh units^4)
    face_stretch: np.ndarray  #: (F,) stretch modulus Y (energy per mesh area)
    face_bending: np.ndarray  #: (F,) bending modulus D (energy)
    poisson: float  #: Poisson's ratio
    size: float  #: the petal size L the moduli were given in (mesh units)
    #: (K, 3) fixed points beyond the clamped base edge (:func:`clamped_anchors`); a face's
    #: stencil names anchor k as vertex ``V + k``
    anchors: np.ndarray = None
    vertex_count: int = 0  #: V (stencil entries from V on are anchors)
    #: (F, 3, 2) the stiffness and rest angle (growth 0) of the crease a face carries
    #: across the edge opposite each corner (stiffness 0: none; :func:`creases`)
    face_crease: np.ndarray = None
    #: (F, 3) the part of ``face_rest_form`` that the bloom adds: absent from the bud,
    #: grown in with A (an open start's, :func:`bloom_form`; zero: none)
    face_bloom_form: np.ndarray = None
    #: an open start's bud shape (:class:`BudShape`), kept for :meth:`rest_on`; None: none
    bud: BudShape | None = None

    def __post_init__(self):
        if self.face_bloom_form is None:
            self.face_bloom_form = np.zeros((len(self.face_indices), 3))

    @property
    def face_count(self) -> int:
        return len(self.face_indices)

    @classmethod
    def build(cls, vertices, faces, model, *, stretch_modulus: float, thickness: float,
              poisson: float = POISSON, petal=None, vertex_thickness=None,
              clamp: bool = True) -> ShellData:
        """From the bud (``vertices``, ``faces``) and its model (rest lengths and growth
        of its edges). ``vertex_thickness (V,)``: a mid-surface's thickness (mesh units;
        0 where unknown), or None. ``clamp``: a boundary edge whose ends are fixed (the
        model's ``pinned``) is clamped (:func:`clamped_anchors`)."""
        X = np.ascontiguousarray(vertices, dtype=np.float64)
        f = np.ascontiguousarray(faces, dtype=np.int64)
        fe = face_edges(f, model.edge_indices)
        det0 = np.empty(len(f))
        rest_dets(fe, model.edge_rest_length, model.edge_growth, det0)
        if np.any(det0 <= 0.0):
            raise ValueError(f"{int(np.sum(det0 <= 0))} faces have no area")
        size = petal_size(X, f, petal)
        tf = None
        if vertex_thickness is not None:
            t = np.asarray(vertex_thickness, dtype=np.float64)[f]
            tf = np.where(np.all(t > 0.0, axis=1), t.mean(axis=1), 0.0)
            if not np.any(tf > 0.0):
                tf = None
        young, bend = moduli(size, stretch_modulus, thickness, poisson, tf)
        young = np.ascontiguousarray(np.broadcast_to(young, (len(f),)), dtype=np.float64)
        bend = np.ascontiguousarray(np.broadcast_to(bend, (len(f),)), dtype=np.float64)
        crease, opp = creases(X, f, face_stencil(X, f), bend)
        ghost = np.ascontiguousarray(ghost_rows(X, f, np.where(crease[:, :, 0] > 0.0, -1, opp)))
        form = np.empty((len(f), 3))
        second_form(X, f, opp, ghost, crease, form)
        anchors = np.zeros((0, 3))
        pinned = getattr(model, "pinned", None)
        if clamp and pinned is not None and np.any(pinned):
            held, corner, anchors = clamped_anchors(X, f, face_opposite(f), pinned)
            opp[held, corner] = len(X) + np.arange(len(held))
            Xa = np.concatenate([X, anchors])
            form = np.empty((len(f), 3))
            second_form(Xa, f, opp, ghost, crease, form)
        return cls(f, opp, ghost, fe, form, det0, young, bend, float(poisson), size, anchors,
                   len(X), crease)

    def _with_anchors(self, positions) -> np.ndarray:
        X = np.ascontiguousarray(positions, dtype=np.float64)
        if self.anchors is not None and len(self.anchors):
            X = np.concatenate([X, self.anchors])
        return X

    def form_at(self, positions) -> np.ndarray:
        """``(F, 3)``: each face's second fundamental form at ``positions`` (V, 3)."""
        form = np.empty((self.face_count, 3))
        second_form(self._with_anchors(positions), self.face_indices, self.face_opposite,
                    self.face_ghost, self.face_crease, form)
        return form

    def rest_on(self, positions, rest0, growth, beta: float = 0.0,
                bud: BudShape | None = None, lifted=None) -> ShellData:
        """This shell with ``positions`` as its rest shape at full growth (A = 1; an open
        start's model, :mod:`pipeline.sim.reverse`): the rest curvature at growth 0 is
        ``positions``' own second fundamental form divided by what growth and curl
        multiply it by on the way to A = 1 (``(det abar(1) / det abar(0))^(1/4)`` and
        ``1 - beta``), so that at A = 1 it is ``positions``' own. ``rest0``, ``growth``:
        the model's edges' rest lengths at growth 0 and growth ratios. ``bud``: the bud's
        shape (given, or kept from an earlier ``rest_on``): the part of ``positions``'
        curvature the bud has not (:func:`bloom_form`) grows in with A. ``lifted`` (V, 3),
        if given: the bud's rest curvature is measured there instead (the bud shape's
        part taken from it as from ``positions``'), and becomes ``positions``' own as A
        goes to 1 (an open start's closing lift grown into the rest shape,
        :func:`pipeline.sim.reverse.lift_faded`)."""
        X = self._with_anchors(positions)
        form = self.form_at(positions)
        crease = self.face_crease.copy()  # (a crease's angle stays as growth goes: curl's only)
        crease[:, :, 1] = crease_angles(X, self.face_indices, self.face_opposite,
                                        self.face_crease) / (1.0 - beta)
        det0, det1 = np.empty(self.face_count), np.empty(self.face_count)
        rest0 = np.ascontiguousarray(rest0, dtype=np.float64)
        growth = np.ascontiguousarray(growth, dtype=np.float64)
        rest_dets(self.face_edges, rest0, growth, det0)
        rest_dets(self.face_edges, rest0 * (1.0 + growth), np.zeros_like(growth), det1)
        if np.any(det0 <= 0.0) or np.any(det1 <= 0.0):
            raise ValueError(f"{int(np.sum((det0 <= 0.0) | (det1 <= 0.0)))} faces have no "
                             "rest area")
        k = np.sqrt(np.sqrt(det0 / det1)) / (1.0 - beta)
        bud = self.bud if bud is None else bud
        added = (np.zeros_like(form) if bud is None
                 else bloom_form(X, self.face_indices, form, bud, self.size))
        if lifted is not None:  # (what the lift adds to the bud's curvature fades out too)
            added = added + form - self.form_at(lifted)
        return dataclasses.replace(self, face_rest_form=form * k[:, None], face_rest_det=det0,
                                   face_crease=crease, face_bloom_form=added * k[:, None],
                                   bud=bud)

    def equivalent(self) -> tuple[float, float]:
        """The paper's (K_s, K_b) of the same sheet (mean over faces), for what still
        counts in springs: the contact barrier's stiffness, the solver's scales."""
        return (float(np.sqrt(3.0) / 2.0 * self.face_stretch.mean()),
                float(2.0 / np.sqrt(3.0) * self.face_bending.mean()))

    def subset(self, face_mask, vertex_map, edge_map) -> ShellData:
        """The faces ``face_mask`` of a piece, renumbered by ``vertex_map (V,)`` and
        ``edge_map (E,)`` (old index -> new)."""
        opp = self.face_opposite[face_mask]
        count = int(np.max(vertex_map)) + 1  # (the piece's vertices: anchors follow them)
        anchor = opp >= self.vertex_count
        inside = (opp >= 0) & ~anchor
        return ShellData(
            vertex_map[self.face_indices[face_mask]],
            np.where(inside, vertex_map[np.where(inside, opp, 0)],
                     np.where(anchor, opp - self.vertex_count + count, -1)),
            self.face_ghost[face_mask], edge_map[self.face_edges[face_mask]],
            self.face_rest_form[face_mask], self.face_rest_det[face_mask],
            self.face_stretch[face_mask], self.face_bending[face_mask], self.poisson,
            self.size, self.anchors, count, self.face_crease[face_mask],
            self.face_bloom_form[face_mask],
            None if self.bud is None else dataclasses.replace(
                self.bud, inside=self.bud.inside[face_mask]))


#: What the dynamic integrators' step (:func:`pipeline.sim.explicit.step.advance`) takes of
#: the shell, by name: ``on`` (False: the paper's springs, every array empty), the
#: positions' work array ``points`` (V + anchors), the face data and the curl's ``beta``.
KernelShell = namedtuple("KernelShell", [
    "on", "points", "faces", "opposite", "ghost", "crease", "face_edges", "young", "bend", "nu",
    "form", "bloom_form", "det0", "beta", "scratch"])


def kernel_shell(model, curl=None) -> KernelShell:
    """The shell of ``model`` as the step kernel takes it (empty for the paper's springs).
    ``curl``: the scene's curl effect (its ``beta`` decays the rest curvature)."""
    sh = model.shell
    if sh is None:
        return KernelShell(False, np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64),
                           np.zeros((0, 3), dtype=np.int64), np.zeros((0, 3, 3)),
                           np.zeros((0, 3, 2)), np.zeros((0, 3), dtype=np.int64), np.zeros(0),
                           np.zeros(0), 0.0, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), 0.0,
                           np.zeros(KERNEL_SCRATCH))
    anchors = sh.anchors if sh.anchors is not None else np.zeros((0, 3))
    points = np.concatenate([np.zeros((model.vertex_count, 3)), anchors])
    return KernelShell(True, points, sh.face_indices, sh.face_opposite, sh.face_ghost,
                       sh.face_crease, sh.face_edges, sh.face_stretch, sh.face_bending, sh.poisson,
                       sh.face_rest_form, sh.face_bloom_form, sh.face_rest_det,
                       0.0 if curl is None else float(curl.beta), np.zeros(KERNEL_SCRATCH))


@dataclass
class ShellBlocks:
    """The shell's Hessian as 3x3 blocks: the pattern (:func:`face_pattern`), each face's
    slots and the data it is assembled into (built once; assembly allocates nothing).
    The quasi-static solver reads ``indptr``, ``indices`` and ``data``."""

    indptr: np.ndarray
    indices: np.ndarray
    face_slots: np.ndarray  #: (F, 36)
    data: np.ndarray  #: (nnz, 3, 3)

    @classmethod
    def build(cls, model) -> ShellBlocks:
        sh = model.shell
        indptr, indices, slots = face_pattern(model.vertex_count, sh.face_indices,
                                              sh.face_opposite)
        return cls(indptr, indices, slots, np.zeros((len(indices), 3, 3)))

    def matrix(self):
        n = 3 * (len(self.indptr) - 1)
        return sp.bsr_matrix((self.data, self.indices, self.indptr), shape=(n, n))


#: faces from which a mesh of several pieces has its forces taken piece by piece in
#: threads (:meth:`ShellTerm._apart`; below, the pool costs more than it saves)
PIECES_FROM = 1000


class ShellTerm(Term):
    """The shell's energy (membrane and bending) as a term (:class:`~pipeline.sim.terms.term.Term`'s
    interface, and :class:`~pipeline.sim.terms.elastic.Elastic`'s: ``assemble`` into the
    solver's blocks, ``rounding``). With curl, the rest curvature decays as ``1 - A
    beta`` (Eq. 11, B = A)."""

    name = "shell"

    def __init__(self, model, curl=None):
        self.model, self.shell = model, model.shell
        self.beta = 0.0 if curl is None else float(curl.beta)
        self.A, self.curl = 0.0, 1.0
        self._scratch = np.zeros(KERNEL_SCRATCH)
        self._blocks = None
        #: each face's row sums of |H| (:func:`shell_rounding`), as the last assembly or
        #: full rounding left them
        self._h = np.zeros((self.shell.face_count, 6))
        self._h_taken = False  #: whether ``_h`` holds every face's (else: take them)
        self._rows = np.arange(self.shell.face_count)
        self._pieces = None  #: :meth:`_apart`'s, found at the first use
        anchors = self.shell.anchors
        self._points = None if anchors is None or len(anchors) == 0 else np.zeros(
            (model.vertex_count + len(anchors), 3))
        if self._points is not None:
            self._points[model.vertex_count:] = anchors

    def _with_anchors(self, X):
        """X followed by the clamped edges' fixed anchors (the stencils' vertices V...)."""
        if self._points is None:
            return X
        self._points[:len(X)] = X
        return self._points

    @property
    def units(self) -> tuple:
        """The energy terms it is made of (one)."""
        return (self,)

    def at(self, growth: float) -> ShellTerm:
        self.A = float(growth)
        self.curl = 1.0 - self.A * self.beta
        return self

    def _args(self, faces=None):
        m, sh = self.model, self.shell
        if faces is None:
            return (sh.face_indices, sh.face_opposite, sh.face_ghost, sh.face_crease,
                    sh.face_edges,
                    m.edge_rest_length, m.edge_growth, sh.face_stretch, sh.face_bending,
                    sh.poisson, sh.face_rest_form, sh.face_bloom_form, sh.face_rest_det)
        return (sh.face_indices[faces], sh.face_opposite[faces], sh.face_ghost[faces],
                sh.face_crease[faces], sh.face_edges[faces], m.edge_rest_length, m.edge_growth,
                sh.face_stretch[faces], sh.face_bending[faces], sh.poisson,
                sh.face_rest_form[faces], sh.face_bloom_form[faces], sh.face_rest_det[faces])

    def _apart(self) -> list | None:
        """The mesh's pieces (petals: no face's stencil reaches another's), each as
        ``(faces, kernel arguments, scratch)``, for the force and rounding kernels to
        run on at once in threads; None for one piece or a small mesh (one call is
        cheaper than the pool). Each vertex's sum runs over its faces in the same order
        as in one call, so the forces are the same bits; the energy is the pieces' sum."""
        if self._pieces is None:
            self._pieces = []
            faces = self.shell.face_indices
            if len(faces) >= PIECES_FROM and self.model.vertex_count:
                # (Model.pieces; a model here need only have edges: the tests' do not)
                label = topology.components(self.model.edge_indices,
                                            self.model.vertex_count)[faces[:, 0]]
                if label.max() > 0:
                    self._pieces = [(f, self._args(f), np.zeros(KERNEL_SCRATCH))
                                    for f in (np.flatnonzero(label == k)
                                              for k in range(label.max() + 1))]
        return self._pieces or None

    def forces(self, X, F) -> float:
        P = self._with_anchors(X)
        pieces = self._apart()
        if pieces is None:
            return shell_forces(P, *self._args(), self.A, self.curl, F, self._scratch)
        return sum(parallel_map(
            lambda p: shell_forces(P, *p[1], self.A, self.curl, F, p[2]), pieces))

    def part_forces(self, X, F, parts) -> float:
        """:meth:`forces` of the faces of ``parts`` alone (pieces no face joins to
        another, :class:`pipeline.sim.blocks.Part`): their energy, their forces added to
        ``F`` (a descent that moves one group of petals compares these)."""
        P = self._with_anchors(X)
        total = 0.0
        for part in parts:
            args = part.static[0] if part.static is not None else self._args(part.faces)
            total += shell_forces(P, *args, self.A, self.curl, F, self._scratch)
        return total

    def energy(self, X) -> float:
        return self.forces(X, np.zeros_like(X, dtype=np.float64))

    def gradient(self, X) -> np.ndarray:
        F = np.zeros_like(X, dtype=np.float64)
        self.forces(X, F)
        return -F

    def assemble(self, X, blocks: ShellBlocks, part: Part | None = None) -> None:
        """The Hessian at X into ``blocks`` (zeroed first). ``part``: a piece of the mesh
        no face joins to another (:class:`pipeline.sim.blocks.Part`, its ``faces``):
        only its blocks are zeroed and assembled, with the part's own scratch."""
        if part is None:
            blocks.data[:] = 0.0
            shell_hessian(self._with_anchors(X), *self._args(), self.A, self.curl, blocks.data,
                          blocks.face_slots, self._rows, self._h, self._scratch)
            return
        if part.static is None:
            part.static = (self._args(part.faces), blocks.face_slots[part.faces],
                           np.zeros(KERNEL_SCRATCH))
        args, slots, scratch = part.static
        blocks.data[part.blocks] = 0.0
        points = X
        if self._points is not None:  # (parts in threads: each its own copy of X + anchors)
            points = np.concatenate([X, self.shell.anchors])
        shell_hessian(points, *args, self.A, self.curl, blocks.data, slots, part.faces, self._h,
                      scratch)

    def hessian(self, X, project: bool = False):
        if self._blocks is None:
            self._blocks = ShellBlocks.build(self.model)
        self.assemble(X, self._blocks)
        return self._blocks.matrix().tocsr()

    def rounding(self, X, per_vertex, fresh: bool = False) -> float:
        """The force scale per vertex and the energy's (:func:`shell_rounding`). Each
        face's Hessian is taken here if ``fresh``, the first time, or after
        :meth:`forget`; otherwise the row sums of ``|H|`` that the last assembly left
        are used (a bound of the rounding need not be of this very X: the Hessian
        moves little from one Newton iterate to the next, and the gradient's part is of
        X), which cuts this from ten force evaluations' work to one. The solver takes
        it fresh where it decides on it (converged at rounding, a collapsed triangle)."""
        full = fresh or not self._h_taken
        P = self._with_anchors(X)
        per_vertex[:] = 0.0
        pieces = self._apart()
        if pieces is None:
            energy = shell_rounding(P, *self._args(), self.A, self.curl, full, self._rows,
                                    self._h, per_vertex, self._scratch)
        else:
            energy = sum(parallel_map(
                lambda p: shell_rounding(P, *p[1], self.A, self.curl, full, p[0], self._h,
                                         per_vertex, p[2]), pieces))
        self._h_taken = True
        return energy

    def forget(self) -> None:
        """Drop the row sums the assemblies left (the next :meth:`rounding` takes its
        own): the path went back to a state they are not of."""
        self._h_taken = False

    def snapshot(self):
        """What a checkpoint keeps of this term: the row sums :meth:`rounding` reads."""
        return self._h.copy() if self._h_taken else None

    def restore(self, saved) -> None:
        if saved is not None:
            self._h[:] = saved
            self._h_taken = True
