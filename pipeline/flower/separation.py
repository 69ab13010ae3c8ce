"""The remesh stage's separation of petal sheets that start through each other or touching
(:func:`pipeline.mesh.separate.separate`), with the stage's words: petals named by their
parts, the figures for the log and the artifact, a refusal in one line."""

from __future__ import annotations

import logging

import numpy as np

from pipeline.errors import BloomError
from pipeline.mesh import symmetry
from pipeline.mesh.separate import SeparationError, separate

KEY = "remesh.separate"
#: pairs named in a line of the log (all are in remesh.h5's separation attribute)
SHOWN = 12
log = logging.getLogger("bloom")


def separate_sheets(sheets, *, gap: float, names: list[str], where: str, progress=None) -> dict:
    """Move the petal sheets of ``sheets`` (a :class:`pipeline.flower.petals.Petals`, mean
    edge 1) apart in place, so that no two pass through each other and none are nearer
    than ``gap`` (mesh units); refresh ``asymmetry_after`` of the petals that moved.

    ``names`` are the input's part names (``sheets.part`` indexes them). Returns what it
    did (for the log and the artifact's ``separation`` attribute): the petal pairs through
    each other and too close before, named, the vertices moved, the largest and RMS move in
    petal lengths, the rounds, the gap and the distance of the nearest petals after.

    Petals too far into each other to move apart within the bounds have the parts beyond
    their crossings toward the flower's centre cut away, where that is a small share of the
    petal (:func:`pipeline.mesh.trim.buried`: the parts hidden inside the other petal and
    the centre; ``cut``, each petal's share of area, the mesh's faces and vertices go with
    them), and are moved apart again. What is still through another is left as modelled,
    named in a warning: ``left``, the pairs (contact between the two of a pair is off;
    each keeps it with every other petal). Raises :class:`BloomError` naming ``where``
    (the input file), the parts and the key when a move would fold a petal over itself."""
    petal = sheets.petal
    part_of = np.zeros(int(petal.max()) + 1, dtype=np.int64)
    part_of[petal] = sheets.part

    def pairs(found) -> str:
        """"0-1, 1-2 (0: 'a', 1: 'b', 2: 'c')", or "... (of part 'a')" when one part;
        the first :data:`SHOWN` pairs and how many more (a rose bed has hundreds)."""
        if not found:
            return ""
        more = len(found) - SHOWN
        found = found[:SHOWN]
        petals = sorted({p for pair in found for p in pair})
        parts = [names[part_of[p]] for p in petals]
        which = (f"of part {parts[0]!r}" if len(set(parts)) == 1 else
                 ", ".join(f"{p}: {n!r}" for p, n in zip(petals, parts, strict=True)))
        return (", ".join(f"{a}-{b}" for a, b in found)
                + (f" and {more} more pair(s)" if more > 0 else "") + f" ({which})")

    def moved_apart():
        try:
            return separate(sheets.vertices, sheets.faces, sheets.petal, gap, progress=progress,
                            leave=True)
        except SeparationError as exc:
            raise BloomError(
                f"petals {pairs(exc.pairs)} pass through or touch each other and cannot "
                f"be separated: {exc.reason}; fix them in the input mesh, or set {KEY} = false "
                "and effects.collisions.enabled = false (the run then lets them pass through "
                "each other)", where=where) from None

    done = first = moved_apart()
    cut = _cut_buried(sheets, done.stuck) if done.stuck else None
    if cut is not None:
        log.info("%s: cut away the parts of petals buried in other petals toward the centre "
                 "(too deep to move apart): %s (%s)", where, ", ".join(
                     f"petal {p} {share:.0%}" for p, share in enumerate(cut.lost.tolist())
                     if share > 0), KEY)
        done = moved_apart()  # (the cut petals, from where they were modelled)
    petal = sheets.petal
    if done.left:
        log.warning("%s: petals %s pass through or touch each other too far to move apart "
                    "(%s): they are left as modelled, with no contact between the two of a "
                    "pair (each keeps it with every other petal; %s)", where,
                    pairs(done.left), done.reason, KEY)
    moved = np.unique(petal[np.any(done.vertices != sheets.vertices, axis=1)])
    sheets.vertices = done.vertices
    changed = np.union1d(moved, [] if cut is None else np.flatnonzero(cut.lost)).astype(np.int64)
    for p in changed:
        sheets.asymmetry_after[p] = symmetry.asymmetry(done.vertices[petal == p], sheets.plane[p])
    return {"gap": float(gap), "crossed": [list(p) for p in first.crossed],
            "cut": [] if cut is None else cut.lost.tolist(),
            "crossed_parts": pairs(first.crossed), "close": [list(p) for p in first.close],
            "close_parts": pairs(first.close), "moved": done.moved,
            "moved_petals": [int(p) for p in moved], "largest": done.largest, "rms": done.rms,
            "rounds": done.iterations, "left": [list(p) for p in done.left],
            "left_parts": pairs(done.left),
            "distance": done.distance if np.isfinite(done.distance) else None}


def _cut_buried(sheets, left):
    """Cut away, in place, the parts of the petals of ``left`` (pairs through each other
    too deep to move apart) beyond their crossings toward their flower's centre
    (:func:`pipeline.mesh.trim.buried`), in each flower where that parts them all; the
    result, or None when nothing was cut."""
    from pipeline.mesh.ipc import ipctk
    from pipeline.mesh.separate import crossings
    from pipeline.mesh.trim import MOST, buried

    X, petal = sheets.vertices, sheets.petal
    n = int(petal.max()) + 1
    pairs = np.unique([min(a, b) * n + max(a, b) for a, b in left])  # (each pair as one key)

    def found(faces):
        E = np.asarray(ipctk().edges(np.asfortranarray(faces, dtype=np.int32)), dtype=np.int64)
        c = crossings(X, faces, E, petal)
        a, b = petal[E[c[:, 0], 0]], petal[faces[c[:, 1], 0]]
        c = c[np.isin(np.minimum(a, b) * n + np.maximum(a, b), pairs)]
        return np.column_stack([E[c[:, 0]], c[:, 1]])

    F = sheets.faces
    trim = buried(X, F, petal, sheets.flower_centre[sheets.petal_flower], found)
    # a flower is cut only where the cut parts all its petals, within MOST of each: else
    # (a rose whose petals cross mid-petal) the cut would take what the user sees and
    # still leave them through each other, and the flower stays as modelled
    flower = sheets.petal_flower
    still = found(F[trim.keep])
    ids = np.flatnonzero(trim.keep)
    bad = np.union1d(flower[petal[F[ids[still[:, 2]], 0]]], flower[trim.lost > MOST + 1e-9])
    back = np.isin(flower[petal[F[:, 0]]], bad)
    trim.keep[back] = True
    trim.lost[np.isin(flower, bad)] = 0.0
    if not trim.lost.any():
        return None
    sheets.keep_faces(trim.keep)
    return trim
