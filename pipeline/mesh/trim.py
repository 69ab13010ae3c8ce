"""The parts of petals buried in other petals, cut away: :func:`buried`.

A lotus modelled with its sixteen petals' bases stuck into the centre has every pair of
petals through each other near the base, too deep to move apart (:mod:`pipeline.mesh.
separate` would have to move a base by most of its width). What lies beyond such a
crossing, on the side of the flower's centre, is hidden inside the other petal and the
centre in the model: this cuts it away. Each petal keeps its largest piece and any piece
further from the centre than that (on average); the faces a crossing runs through go
with the piece cut away, and a crossing that cuts no piece off (a hole through the
middle of a petal) is left to the separation's moves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.mesh.topology import components, face_normals, half_edges

#: a petal loses at most this share of its area (summed over the rounds); a piece that
#: would take it further stays (the lotus's deepest base is 35% of its petal with the row
#: beyond the cut; the rose bed's petals cross mid-petal, and cutting them would take
#: away what the user sees)
MOST = 0.4
#: rounds of cut and check (a cut can bare another crossing behind it)
ROUNDS = 4


@dataclass
class Trim:
    """Result of :func:`buried`."""

    keep: np.ndarray  #: (F,) bool, the faces kept
    lost: np.ndarray  #: (P,) the share of each petal's area cut away
    rounds: int  #: rounds that cut something away


def buried(vertices, faces, petal, centre, crossings, *, most: float = MOST,
           rounds: int = ROUNDS) -> Trim:
    """The faces to keep so that the parts of petals beyond a crossing, toward their
    flower's centre, are gone.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
    petal : (V,) int, each vertex's petal
    centre : (P, 3) float, the centre of each petal's flower
    crossings : callable, ``crossings(some_faces)`` gives the crossings to cut along in a
        subset of ``faces``: (k, 3) rows ``(a, b, f)``, an edge ``a-b`` of one petal through
        face ``f`` (an index into the subset) of another
    most : float, the largest share of a petal's area cut away
    rounds : int

    Returns
    -------
    Trim
        A face is cut away when it lies in a piece of its petal that a crossing cuts off,
        that is not its petal's largest, whose area-weighted distance to the centre is
        less than the largest piece's, within ``most`` of the petal's area; the
        crossing's faces next to a piece cut away go with it, with the row of faces
        beyond them (the cut rim stays clear of the other petal), and so does anything
        then no longer joined to the petal's largest piece. Deterministic: no random
        choice, no order from a hash.
    """
    X = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    petal = np.asarray(petal, dtype=np.int64)
    count = int(petal.max()) + 1 if len(petal) else 0
    area = 0.5 * np.linalg.norm(face_normals(X, F), axis=1)
    owner = petal[F[:, 0]]
    whole = np.bincount(owner, area, minlength=count)
    distance = np.linalg.norm(X[F].mean(axis=1) - centre[owner], axis=1)

    def lost(keep):  # (P,) each petal's share of area not kept
        kept = np.bincount(owner[keep], area[keep], minlength=count)
        return np.where(whole > 0, 1.0 - kept / np.maximum(whole, np.finfo(float).tiny), 0.0)

    keep = np.ones(len(F), dtype=bool)
    done = 0
    for _ in range(rounds):
        ids = np.flatnonzero(keep)
        found = np.asarray(crossings(F[ids]), dtype=np.int64).reshape(-1, 3)
        if not len(found):
            break
        cut = np.zeros(len(F), dtype=bool)
        cut[ids[found[:, 2]]] = True
        cut[ids[_faces_with_edges(F[ids], found[:, :2])]] = True
        away = _pieces_away(F, keep, cut, owner, area, distance, whole, lost(keep), most,
                            len(X))
        if not away.any():
            break
        keep &= ~away
        keep &= ~_cut_off(F, keep, owner, area, np.unique(owner[away]), len(X))
        done += 1
    return Trim(keep, lost(keep), done)


def _faces_with_edges(F, ends) -> np.ndarray:
    """Indices of the faces of ``F`` that have an edge with the two ends of a row of
    ``ends`` (k, 2)."""
    if not len(ends):
        return np.zeros(0, dtype=np.int64)
    n = int(max(F.max(), ends.max())) + 1
    wanted = np.unique(np.sort(ends, axis=1) @ np.array([n, 1]))
    he, _ = half_edges(F)  # (the faces' edges, a block of F per corner)
    hit = np.isin(np.sort(he, axis=1) @ np.array([n, 1]), wanted)
    return np.unique(np.tile(np.arange(len(F)), 3)[hit])


def _pieces_away(F, keep, cut, owner, area, distance, whole, lost, most, vertex_count):
    """(F,) bool: the faces to cut away this round (see :func:`buried`)."""
    rest = keep & ~cut
    piece = np.full(len(F), -1, dtype=np.int64)
    piece[rest] = components(F[rest], vertex_count)[F[rest, 0]]
    seam = np.full(len(F), -1, dtype=np.int64)  # the crossing's faces, in joined runs
    seam[cut] = components(F[cut], vertex_count)[F[cut, 0]]
    away = np.zeros(len(F), dtype=bool)
    budget = most - lost
    for p in np.unique(owner[cut]).tolist():
        mine_cut = cut & (owner == p)
        mine = rest & (owner == p)
        labels, inverse = np.unique(piece[mine], return_inverse=True)
        sizes = np.bincount(inverse, area[mine])
        if len(labels) < 2:
            continue
        largest = labels[int(np.argmax(sizes))]
        main = mine & (piece == largest)
        toward = np.average(distance[main], weights=area[main] + 1e-300)
        for label in labels.tolist():
            faces = mine & (piece == label)
            if label == largest or np.average(distance[faces], weights=area[faces] + 1e-300) >= toward:
                continue
            touching = np.zeros(vertex_count, dtype=bool)
            touching[F[faces].ravel()] = True
            runs = np.unique(seam[mine_cut][touching[F[mine_cut]].any(axis=1)])
            with_seam = faces | (mine_cut & np.isin(seam, runs))
            # and the row of faces beyond the seam: the cut rim stays an edge's height
            # from the other petal, not on it (contact starts with room)
            touching[F[with_seam].ravel()] = True
            with_seam |= mine & touching[F].any(axis=1)
            share = area[with_seam & ~away].sum() / whole[p]  # (runs shared: once)
            if share <= budget[p]:
                away |= with_seam
                budget[p] -= share
    return away


def _cut_off(F, keep, owner, area, petals, vertex_count) -> np.ndarray:
    """(F,) bool: the kept faces of ``petals`` no longer joined to their petal's largest
    piece (a sliver on the far side of a crossing cut away with its neighbour): a petal
    stays one sheet."""
    label = np.full(len(F), -1, dtype=np.int64)
    label[keep] = components(F[keep], vertex_count)[F[keep, 0]]
    off = np.zeros(len(F), dtype=bool)
    for p in petals.tolist():
        mine = keep & (owner == p)
        labels, inverse = np.unique(label[mine], return_inverse=True)
        if len(labels) > 1:
            largest = labels[int(np.argmax(np.bincount(inverse, area[mine])))]
            off |= mine & (label != largest)
    return off
