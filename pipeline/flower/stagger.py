"""Many flowers in one file, staggered in time: each flower holds its bud until its own
start frame, then blooms as the run did, then holds the last frame.

The flowers of a file bloom in one run, all on the same growth schedule (their petals are
independent pieces: the solver follows each on its own). A flower's motion depends only on
its own growth, so a flower that starts ``k`` frames later is the same run shifted by ``k``
frames: frame ``j`` of flower ``f`` is the run's frame ``clamp(j - start[f], 0, T - 1)``.
The start frames are drawn once from a seeded generator (``scene.stagger`` and
``scene.stagger_seed``), the first flower's at 0, so the same scene gives the same starts;
``auto`` spreads a file of many flowers over a quarter of the frames. Staggered flowers
bloom as problems apart: each from its own bud, with contact among its own petals only
(their petals are never in one equilibrium: each is at its own stage of growth). The
render and the export use the staggered frames, and the frames' check of simulate looks
at them too (a crossing between two flowers is one the user would see).
"""

from __future__ import annotations

import numpy as np

from pipeline.mesh.topology import by_label


def start_frames(flowers: int, spread: int, seed: int) -> np.ndarray:
    """``(flowers,)`` each flower's start frame, in ``[0, spread]``, the earliest 0 (no
    spread, or one flower: all 0)."""
    if flowers <= 1 or spread <= 0:
        return np.zeros(max(flowers, 0), dtype=np.int64)
    starts = np.random.default_rng(seed).integers(0, spread + 1, size=flowers)
    return (starts - starts.min()).astype(np.int64)


def staggered(positions, vertex_flower, starts) -> np.ndarray:
    """``(T + max(starts), V, 3)``: the run's frames ``positions (T, V, 3)`` with each
    vertex's flower (``vertex_flower (V,)``) shifted by its start frame."""
    P = np.asarray(positions)
    starts = np.asarray(starts, dtype=np.int64)
    flower = np.asarray(vertex_flower, dtype=np.int64)
    frames = len(P) + int(starts.max(initial=0))
    out = np.empty((frames, *P.shape[1:]), dtype=P.dtype)
    for start, mine in zip(starts, by_label(flower, len(starts)), strict=True):
        source = np.clip(np.arange(frames) - start, 0, len(P) - 1)
        out[:, mine] = P[source[:, None], mine[None, :]]
    return out


#: scene.stagger = auto: a file of many flowers spreads their starts over this fraction of
#: the frames
AUTO_SPREAD = 0.25


def spread(cfg, flowers: int, frames: int) -> int:
    """The spread of the start frames of ``flowers`` flowers in a run of ``frames``:
    ``scene.stagger``, or for ``auto`` :data:`AUTO_SPREAD` of the frames when there are
    many (0 for one)."""
    said = cfg["scene.stagger"]
    if said == "auto":
        return int(AUTO_SPREAD * frames) if flowers > 1 else 0
    return int(said)


def flower_count(src) -> int:
    """How many flowers an artifact holds (1 without ``flower/petal_flower``)."""
    if "flower/petal_flower" not in src:
        return 1
    petal_flower = np.asarray(src["flower/petal_flower"], dtype=np.int64)
    return int(petal_flower.max()) + 1 if len(petal_flower) else 1


def of_run(src, cfg) -> np.ndarray | None:
    """The start frames of a simulate artifact's flowers as the scene sets them (flowers
    that bloomed together, ``flower/together``, start together: :func:`together`), or
    None when there is nothing to stagger (one flower, no spread)."""
    flowers = flower_count(src)
    wide = spread(cfg, flowers, len(src["frames/positions"]))
    if wide <= 0 or flowers <= 1:
        return None
    starts = start_frames(flowers, wide, cfg["scene.stagger_seed"])
    if "flower/together" in src:
        starts = together(starts, src["flower/together"])
    return starts if starts.any() else None


def together(starts, cluster) -> np.ndarray:
    """``starts`` with the flowers that bloom together (``cluster (K,)``: each flower's
    cluster, the same number for flowers of one problem) starting at the earliest of
    their frames."""
    out = np.array(starts, dtype=np.int64)
    cluster = np.asarray(cluster, dtype=np.int64)
    for c in np.unique(cluster):
        mine = cluster == c
        out[mine] = out[mine].min()
    return out


def vertex_flowers(src) -> np.ndarray:
    """``(V,)`` the flower of each vertex of a simulate artifact."""
    return np.asarray(src["flower/petal_flower"], dtype=np.int64)[np.asarray(src["mesh/petal"])]
