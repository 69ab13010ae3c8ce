"""Whether triangles pass through each other, frame by frame: the exact test (ipctk's
edge through a triangle) that the report, the crossing of a file's flowers and the
studies count. :func:`frame_intersections`: any two triangles of the mesh (petals
against each other and each against itself), but pairs of petals left through each
other as modelled; :func:`crossings_between`: only between groups (flowers, sides).
A large test is spread over worker processes, runs of frames each: the answers are
the same, each frame's own."""

from __future__ import annotations

import numpy as np

from pipeline import forks
from pipeline.mesh.ipc import Filter
from pipeline.mesh.ipc import ipctk as one_thread

#: frames times vertices from which the exact test runs in worker processes (under it,
#: the fork costs more than it saves)
SPREAD_WORK = 2_000_000
_TASK = None  #: (a checker's maker, the frames, their chunks): what forked workers read


def _chunk(c: int) -> list[bool]:
    make, frames, chunks = _TASK
    check = make(frames[chunks[c][0]])
    return [check(frames[t]) for t in chunks[c]]


def _per_frame(make, frames, workers: int = 1) -> list[bool]:
    """``check(X)`` for each frame ``X`` of ``frames``, ``check = make(X0)`` (a checker,
    its collision meshes built once, at a first frame ``X0``): in this process, or
    (``workers`` > 1, a large enough test: :data:`SPREAD_WORK`) in forked processes,
    each a run of frames (:func:`pipeline.forks.each`). The answers are the same either
    way: each is one frame's, exact."""
    global _TASK
    count = len(frames)
    if not count:
        return []
    if workers <= 1 or count < forks.MANY or count * len(frames[0]) < SPREAD_WORK:
        check = make(frames[0])
        return [check(X) for X in frames]
    chunks = np.array_split(np.arange(count), forks.MANY * max(1, -(-workers // forks.MANY)))
    _TASK = (make, frames, [c.tolist() for c in chunks])
    try:
        return [hit for run in forks.each(_chunk, len(chunks), workers) for hit in run]
    finally:
        _TASK = None


def _collision_mesh(faces, X0):
    """ipctk (on one thread), and the faces, edges and collision mesh of ``faces`` at
    ``X0``: ``(ipctk, F, E, mesh)`` (the caller keeps ``F`` and ``E`` alive with it)."""
    ipctk = one_thread()
    F = np.asfortranarray(faces, dtype=np.int32)
    E = ipctk.edges(F)
    return ipctk, F, E, ipctk.CollisionMesh(np.asfortranarray(X0, dtype=np.float64), E, F)


def crossings_between(frames, faces, group, petal=None, left=None, workers: int = 1,
                      first: bool = False) -> list[bool]:
    """For each frame ``(V, 3)`` of ``frames``, whether a triangle of one group passes
    through one of another (ipctk's exact edge-through-triangle test): ``group (V,)``
    each vertex's group (a flower, a side); two triangles of one group are not looked
    at, nor (``petal (V,)`` each vertex's, ``left (K, 2)``) two of a pair of petals left
    through each other as modelled, as :func:`frame_intersections` does not.
    ``workers``: processes to spread a large test over (:func:`_per_frame`); ``first``:
    only up to the first frame that crosses (the rest are not looked at, and are
    False)."""
    pairs = [] if petal is None or left is None else np.asarray(left).reshape(-1, 2).tolist()

    def make(X0):
        ipctk, F, E, mesh = _collision_mesh(faces, X0)
        keep = Filter(group, petal=petal, pairs=pairs)
        keep.apply(mesh)
        # (the arrays the mesh and its filter read live with the checker)
        return lambda X, lives=(F, E, keep): bool(
            ipctk.has_intersections(mesh, np.asfortranarray(X, dtype=np.float64)))

    if first:
        check, out = None, [False] * len(frames)
        for t, X in enumerate(frames):
            check = check or make(X)
            if check(X):
                out[t] = True
                break
        return out
    return _per_frame(make, frames, workers)


def frame_intersections(frames, faces, petal=None, left=None, workers: int = 1) -> list[bool]:
    """For each frame ``(V, 3)`` of ``frames``, whether any two triangles of the mesh
    intersect (an exact edge-through-triangle test by ipctk; petals against each other
    and each against itself).

    ``petal`` ``(V,)`` and ``left`` ``(K, 2)``: the two petals of a pair of ``left`` (left
    through each other as modelled: remesh could not move them apart) may pass through
    each other; every other pair of petals, and each petal against itself, is checked:
    one test of the whole mesh with those pairs left out (and with them the pairs'
    petals against themselves), and one of each of those petals alone. ``workers``:
    processes to spread a large test over (:func:`_per_frame`)."""
    pairs = [] if petal is None or left is None else np.asarray(left).reshape(-1, 2).tolist()

    def make(X0):
        ipctk, F, E, mesh = _collision_mesh(faces, X0)
        keep, alone = None, []
        if pairs:
            own = np.asarray(petal)
            keep = Filter(petal=own, pairs=pairs, selves=False)
            keep.apply(mesh)
            face_petal = own[np.asarray(faces)[:, 0]]
            for p in sorted({q for pair in pairs for q in pair}):  # (each on its own
                # vertices: memory linear in the mesh)
                mine = F[face_petal == p]
                if len(mine):
                    verts = np.unique(mine)
                    f = np.asfortranarray(np.searchsorted(verts, mine), dtype=np.int32)
                    e = ipctk.edges(f)
                    alone.append((verts, (f, e), ipctk.CollisionMesh(
                        np.asfortranarray(X0[verts], dtype=np.float64), e, f)))

        # (the arrays the meshes and the filter read live with the checker)
        def check(X, lives=(F, E, keep)):
            X = np.asfortranarray(X, dtype=np.float64)
            return bool(ipctk.has_intersections(mesh, X)) or any(
                ipctk.has_intersections(m, np.asfortranarray(X[verts]))
                for verts, _, m in alone)

        return check

    return _per_frame(make, frames, workers)
