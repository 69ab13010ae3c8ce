"""Which flowers of a file pass through each other in the frames the user sees: each at
its own stage of growth, staggered by its start frame (:mod:`pipeline.flower.stagger`),
checked exactly (ipctk's edge-through-triangle test) on the flowers asked about only."""

from __future__ import annotations

import numpy as np

from pipeline.flower import stagger
from pipeline.mesh.intersect import crossings_between
from pipeline.sim.build import Prepared


def seen(members: list, positions, parts: list, prep: Prepared, starts,
         against_first: bool = False, frames=None, workers: int = 1,
         first: bool = False) -> np.ndarray:
    """``(T',)`` whether a flower of ``members`` passes through another of them in each
    frame the user sees (staggered by ``starts``; ``frames``: only those), on their
    vertices only. ``against_first``: only the first against the others; ``workers``:
    processes a large test is spread over; ``first``: only up to the first frame that
    crosses (enough for ``.any()``; the frames after it are False)."""
    sub = np.concatenate([parts[j][1] for j in members])
    local = np.repeat(np.arange(len(members)), [len(parts[j][1]) for j in members])
    new = np.full(len(prep.vertices), -1, dtype=np.int64)
    new[sub] = np.arange(len(sub))
    faces = np.asarray(prep.faces, dtype=np.int64)
    faces = new[faces[np.all(new[faces] >= 0, axis=1)]]
    shown = positions[:, sub]
    if starts is not None:
        shown = stagger.staggered(shown, local, np.asarray(starts)[members])
    if frames is not None:  # (frames of the whole: past this one's last, it holds it)
        shown = shown[np.minimum(frames, len(shown) - 1)]
    return np.asarray(crossings_between(shown, faces, local != 0 if against_first else local,
                                        petal=np.asarray(prep.petal)[sub], left=prep.left,
                                        workers=workers, first=first),
                      dtype=bool)


def boxes(positions, parts: list) -> np.ndarray:
    """``(K, 2, 3)`` each flower's box over the whole bloom."""
    return np.stack([np.stack([positions[:, idx].min(axis=(0, 1)),
                               positions[:, idx].max(axis=(0, 1))]) for _, idx in parts])


def near(k: int, boxes) -> np.ndarray:
    """The flowers whose box meets flower ``k``'s, but ``k``."""
    lo, hi = boxes[:, 0], boxes[:, 1]
    meet = np.flatnonzero(np.all((lo <= hi[k]) & (hi >= lo[k]), axis=1))
    return meet[meet != k]


def count(k: int, positions, parts: list, prep: Prepared, starts, boxes,
          frames=None) -> int:
    """How many frames the user sees (staggered by ``starts``; ``frames``: of those)
    flower ``k`` passes through a flower whose box (over the whole bloom, ``boxes
    (flowers, 2, 3)``) meets its own: on those flowers' vertices only."""
    others = near(k, boxes)
    if not len(others):
        return 0
    return int(seen([k, *others.tolist()], positions, parts, prep, starts,
                    against_first=True, frames=frames).sum())
