"""Which flower each petal belongs to, in a file of many flowers (a bush, a bed, a branch)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pipeline.mesh import topology

#: a petal's two ends are the points within this fraction of its length of either end
#: of its principal axis
END = 0.15
#: the base is the end with more other petals within this fraction of the petal's
#: length of it: a flower's petals gather at their bases
NEAR = 0.25
#: two petals are of one flower when their bases are closer than this fraction of the
#: shorter one's length (the 10 daisies of a bush and the 5 roses of a bed come apart
#: the same from 0.25 to 1.0)
LINK = 0.5
#: points per petal the neighbour search looks at (evenly spread over its vertices)
SAMPLE = 64


class Flowers(NamedTuple):
    """Result of :func:`flowers`."""

    flower: np.ndarray  #: (P,) int, the flower of each petal, numbered by its first petal
    count: int  #: number of flowers
    base: np.ndarray  #: (P, 3) each petal's base end (mean of its points there)
    tip: np.ndarray  #: (P, 3) each petal's other end
    length: np.ndarray  #: (P,) each petal's length along its principal axis
    centre: np.ndarray  #: (K, 3) mean of the bases of each flower's petals


def _principal(points: np.ndarray, label: np.ndarray, count: int):
    """Per label: centroid (P, 3) and unit principal direction (P, 3), in one pass."""
    _, mean, _, _, axes = topology.grouped_moments(points, label, count)
    return mean, axes[:, :, 2]


def _nearest_other(tree, owner: np.ndarray, at: np.ndarray, petal: np.ndarray,
                   k: int) -> np.ndarray:
    """``(n,)`` the distance from each point ``at`` to the nearest sampled point of a
    petal other than ``petal`` (inf if none among its ``k`` nearest: ``k`` one more than
    any petal's sample, so one is found whenever another petal exists)."""
    d, j = tree.query(at, k=k)
    d, j = d.reshape(len(at), -1), j.reshape(len(at), -1)
    valid = j < len(owner)
    other = valid & (owner[np.where(valid, j, 0)] != petal[:, None])
    return np.where(other, d, np.inf).min(axis=1)


def flowers(points: np.ndarray, label: np.ndarray, link: float = LINK,
            joined: list | None = None, whole: np.ndarray | None = None) -> Flowers:
    """Group petals into flowers: petals whose bases gather at one place are one flower.

    Parameters
    ----------
    points : (N, 3) float
        The petals' points (their vertices), in any units.
    label : (N,) int
        The petal of each point, ``0 .. P-1``; every petal has at least one point.
    link : float
        Two petals are linked when their bases are closer than ``link`` times the
        shorter petal's length; flowers are the linked groups.
    joined : list of lists of petal indices, optional
        Petals known to be of one flower whatever their bases' distance: those one sheet
        held, joined at a hub the remesh left out (a flower modelled as one solid, whose
        hub can be wider than its petals are long).
    whole : (P,) int, optional
        The flower each petal is known to belong to, from a part that holds a whole
        flower (:attr:`pipeline.flower.classify.Verdict.whole`), or -1: the petals of
        one known flower are one flower, and petals of two are never linked, however
        near their bases (a branch's blossoms, each one mesh, a few millimetres apart:
        a coarse kite whose base is taken at its tip reaches the next blossom).

    Returns
    -------
    Flowers
        ``flower (P,)``, ``count``, each petal's ``base``, ``tip`` and ``length``, and
        each flower's ``centre``.

    Notes
    -----
    A petal's ends are the mean of its points within ``END`` of its length of either end
    of its principal axis. Its base is the end that more other petals come near (within
    ``NEAR`` of its length): the petals of a flower meet at the receptacle, their tips
    are apart. Where neither end has more (a lone petal, a flower of two, a low-poly
    blossom's petals whose bases lie a little apart), the end nearer another petal is
    the base, or (alone) the narrower end. Petals cluster by
    their bases, not by where they touch: two flowers of a bush whose petals cross at
    the tips stay two. Each petal is measured on at most ``SAMPLE`` of its points, so
    the cost is one k-d tree over ``SAMPLE`` P points and grows linearly with P.
    Deterministic, scale-free and independent of the order of the points within a petal
    (up to rounding).
    """
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pts = np.asarray(points, dtype=np.float64)
    lab = np.asarray(label, dtype=np.int64)
    count = int(lab.max()) + 1 if len(lab) else 0
    if count == 0:
        empty = np.zeros((0, 3))
        return Flowers(np.zeros(0, dtype=np.int64), 0, empty, empty, np.zeros(0), empty)
    centroid, axis = _principal(pts, lab, count)
    t = np.einsum("ij,ij->i", pts - centroid[lab], axis[lab])
    high = np.full(count, -np.inf)
    low = np.full(count, np.inf)
    np.maximum.at(high, lab, t)
    np.minimum.at(low, lab, t)
    length = high - low
    ends, widths = [], []
    for at_low in (True, False):
        near = t <= low[lab] + END * length[lab] if at_low else t >= high[lab] - END * length[lab]
        n = np.maximum(np.bincount(lab[near], minlength=count), 1)
        end = np.stack([np.bincount(lab[near], weights=pts[near, k], minlength=count)
                        for k in range(3)], 1) / n[:, None]
        ends.append(end)
        spread = np.zeros(count)
        np.maximum.at(spread, lab[near], np.linalg.norm(pts[near] - end[lab[near]], axis=1))
        widths.append(spread)

    # a sample of each petal's points for the neighbour search: every k-th, k per petal
    order = np.argsort(lab, kind="stable")
    sizes = np.bincount(lab, minlength=count)
    first = np.r_[0, np.cumsum(sizes)[:-1]]
    rank = np.arange(len(lab)) - first[lab[order]]
    stride = np.maximum(sizes // SAMPLE, 1)
    keep = order[rank % stride[lab[order]] == 0]
    tree = cKDTree(pts[keep])
    owner = lab[keep]
    others = []
    for end in ends:
        near_petals = []
        for p, found in enumerate(tree.query_ball_point(end, NEAR * length)):
            petals = np.unique(owner[np.asarray(found, dtype=np.int64)])
            near_petals.append(petals.size - int(np.any(petals == p)))
        others.append(np.array(near_petals))
    base_low = others[0] > others[1]
    tie = others[0] == others[1]
    if tie.any() and count > 1:
        # the end nearer another petal (a blossom's coarse petals, whose bases lie a
        # little over NEAR apart; the mean of the file's other petals was the middle of
        # a branch, and half of its blossoms' petals took their tips for their bases)
        tied = np.flatnonzero(tie)
        k = min(len(keep), int(np.max(np.bincount(owner, minlength=count))) + 1)
        near_low, near_high = (_nearest_other(tree, owner, end[tied], tied, k) for end in ends)
        base_low[tied] = near_low <= near_high
    elif tie.any():  # alone: the narrower end
        base_low = np.where(tie, widths[0] <= widths[1], base_low)
    base = np.where(base_low[:, None], ends[0], ends[1])
    tip = np.where(base_low[:, None], ends[1], ends[0])

    scale = np.where(length > 0, length, 0.0)
    pairs = cKDTree(base).query_pairs(link * float(scale.max()), output_type="ndarray")
    if len(pairs):
        d = np.linalg.norm(base[pairs[:, 0]] - base[pairs[:, 1]], axis=1)
        pairs = pairs[d < link * np.minimum(scale[pairs[:, 0]], scale[pairs[:, 1]])]
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if whole is not None and len(pairs):
        known = np.asarray(whole, dtype=np.int64)[pairs]
        pairs = pairs[~((known[:, 0] >= 0) & (known[:, 1] >= 0) & (known[:, 0] != known[:, 1]))]
    hubs = [(int(hub[0]), int(q)) for hub in joined or [] for q in hub[1:]]
    if whole is not None:  # (each known flower's petals chained, first to each)
        known = np.asarray(whole, dtype=np.int64)
        at = np.flatnonzero(known >= 0)
        _, first, which = np.unique(known[at], return_index=True, return_inverse=True)
        lead = at[first][which]
        hubs += [(int(a), int(b)) for a, b in zip(lead, at, strict=True) if a != b]
    if hubs:
        pairs = np.vstack([pairs, np.asarray(hubs, dtype=np.int64)])
    g = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(count, count))
    _, group = connected_components(g, directed=False)
    # numbered by each flower's first petal, so the labels do not depend on scipy
    _, first_petal = np.unique(group, return_index=True)
    rank = np.empty_like(first_petal)
    rank[np.argsort(first_petal)] = np.arange(first_petal.size)
    flower = rank[group]
    k = int(flower.max()) + 1
    per = np.maximum(np.bincount(flower, minlength=k), 1)
    centre = np.stack([np.bincount(flower, weights=base[:, j], minlength=k) for j in range(3)], 1)
    return Flowers(flower, k, base, tip, length, centre / per[:, None])
