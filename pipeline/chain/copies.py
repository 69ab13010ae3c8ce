"""Flowers of a file of many that are copies of one another (instanced blossoms of a
branch): the bloom is the same problem turned, so it is found once and moved
(:func:`pipeline.chain.flowers.flowers_apart`)."""

from __future__ import annotations

import dataclasses

import numpy as np

from pipeline.mesh.similar import AS_EXPORTED, TOLERANCE, Copies
from pipeline.sim.run import Recording

#: a copied flower's s, x and growth ratios are its original's to within this (bloom
#: axis gives a copied petal its original's, so they are equal)
COPY = TOLERANCE


def seen() -> Copies:
    """An empty record of the flowers met so far, for :func:`copy_of`. A copy's vertices
    lie on its original's moved, turned and scaled to within :data:`~pipeline.mesh.
    similar.AS_EXPORTED` of its size: remesh places each copied petal by the motion that
    puts the input's petal on its original, and a file's 6 decimals or float32 leave that
    motion up to 1e-4 of a small petal off, differently for each petal of a blossom. A
    scaled copy is one: each flower of a file is solved at its own size (mean edge 1,
    :func:`pipeline.chain.flowers.solve`), as it would be alone in a file."""
    return Copies(scaled=True, tolerance=AS_EXPORTED)


def copy_of(k: int, part, shapes: Copies):
    """``(j, R, t, scale)`` if flower ``k`` (``part``, a :class:`~pipeline.sim.build.
    Prepared`) is flower ``j`` (an earlier one of ``shapes``, which this adds flower ``k``
    to otherwise) scaled by ``scale``, turned by ``R`` and moved by ``t``: the same faces
    (so edges and hinges), petals, fixed base, axis vertices, tips, growth ratios and
    stiffnesses, and its vertices those of ``j`` moved (:func:`seen`), its s and x to
    :data:`COPY`. None otherwise."""

    def alike(original, _rot) -> bool:
        other = original[1]
        return (all(np.array_equal(np.asarray(getattr(other, name)), np.asarray(getattr(part, name)))
                    for name in ("petal", "base", "on_axis", "tip"))
                and all(np.allclose(np.asarray(getattr(other, name), dtype=np.float64),
                                    np.asarray(getattr(part, name), dtype=np.float64),
                                    rtol=0.0, atol=COPY)
                        for name in ("s", "x", "alpha", "stiffness")))

    found = shapes.find(np.asarray(part.vertices), np.asarray(part.faces), accept=alike)
    if found is not None:
        return found[0][0], found[2], found[3], found[1]
    shapes.add(np.asarray(part.vertices), np.asarray(part.faces), (k, part))
    return None


def moved(run, rot: np.ndarray, t: np.ndarray, scale: float = 1.0):
    """A flower's bloom (:class:`~pipeline.chain.problem.Bloom`) for a copy of it scaled
    by ``scale``, turned by ``rot`` and moved by ``t`` (``X scale R^T + t``): its frames
    and bud moved, the rest kept (energies, angles, counts: each flower's figures are of
    its own problem, at mean edge 1); no wall time of its own."""
    rec = Recording(list(run.rec.time),
                    [scale * np.asarray(X) @ rot.T + t for X in run.rec.positions],
                    run.rec.diagnostics)
    return dataclasses.replace(run, bud=scale * np.asarray(run.bud) @ rot.T + t, rec=rec,
                               wall=0.0)
