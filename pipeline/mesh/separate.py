"""Petals that pass through or touch each other, moved apart: :func:`separate`.

For each pair of petals that cross, the side most of their overlap lies on (by area)
decides which way each goes; the vertices on the wrong side, and those joined to a
crossing, are pushed across, shared between the two petals, by one smooth least-squares
move per round; rounds go on until ipctk's exact test finds no crossing and no pair is
nearer than the gap. Pairs too far into each other are put back as modelled; in the
rounds, chains of such pairs join their petals in one group the test leaves alone, and
at the end the pairs of a group that cross or touch are those left (the others keep
contact). The module is long because those steps (finding the crossings and
the sides, the pushes, the smooth move, the rounds and the refusal that names the pairs)
share per-pair records and are only meaningful together."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.sparse.linalg import splu
from scipy.spatial import cKDTree

from pipeline.mesh.ipc import Filter
from pipeline.mesh.ipc import ipctk as one_thread
from pipeline.mesh.nearest import Triangles
from pipeline.mesh.topology import by_label, face_normals, unique_edges, vertex_normals

#: no vertex moves further than this fraction of its petal's length
MAX_MOVE = 0.15
#: rounds of push and check before giving up
MAX_ITERATIONS = 40
#: ... or this many rounds in a row without fewer crossings than the fewest so far, with
#: more than the input had (a lotus whose sixteen thick petals all run through each other:
#: 40 rounds took 8 minutes and parted none; its crossings went 2199, 6377, 8479, 9501,
#: ... from the first push on) ...
STALL = 3
#: ... or this many with no fewer at all: a count that wanders under the input's may
#: still end at none (the tulip at 1,500 vertices a petal: 19, 5, 3, 11, 13, 12, 13, 0;
#: souki202: 48, 50, 5, 0; the others fall every round)
STALL_UNDER = 8
#: a vertex on the wrong side, or too close, is pushed to this many gaps from the other petal
#: (the check asks for one gap: the margin lets a round end clean)
PUSH = 1.5
#: pairs of petals apart but nearer than this many gaps keep their distance while others
#: are pushed (a stack of petals moves together), or are pushed apart to ``PUSH`` gaps
KEEP = 3.0
#: weight of a push against the smoothness of the move (the spring between neighbours is 1)
WEIGHT = 1e1
#: a move fades away over this fraction of a petal's length (at least SPREAD_EDGES mean
#: edges), and is zero beyond four times that
SPREAD = 0.05
SPREAD_EDGES = 2.0


@dataclass
class Separation:
    """Result of :func:`separate`."""

    vertices: np.ndarray  #: (V, 3) the petals moved apart (a copy, equal to the input when clean)
    crossed: list = field(default_factory=list)  #: petal pairs (a, b) through each other before
    close: list = field(default_factory=list)  #: pairs closer than the gap (not through) before
    moved: int = 0  #: vertices that moved at all
    largest: float = 0.0  #: largest move of a vertex, in its petal's lengths
    rms: float = 0.0  #: RMS move over all vertices, each in its petal's lengths
    iterations: int = 0  #: rounds of push and check
    distance: float = np.inf  #: smallest distance between two petals after (inf: none near)
    length: np.ndarray = None  #: (P,) the length of each petal the moves are measured in
    #: petal pairs left through each other as modelled, or touching (``leave=True``):
    #: too far into each other to move apart within the bounds, their petals put back as
    #: they were; contact between the two of a pair is off, each keeps it with every
    #: other petal
    left: list = field(default_factory=list)
    reason: str = ""  #: why the first of ``left`` could not be separated
    #: the pairs the rounds gave up on (their petals put back; ``left`` holds the pairs of
    #: the petals chained by these that cross or touch at the end)
    stuck: list = field(default_factory=list)


class SeparationError(ValueError):
    """The petal ``pairs`` cannot be moved apart within the bounds, for ``reason``."""

    def __init__(self, pairs, reason: str):
        self.pairs = [tuple(int(x) for x in p) for p in pairs]
        self.reason = reason
        super().__init__(f"petals {_names(self.pairs)} cannot be separated: {reason}")


def separate(vertices: np.ndarray, faces: np.ndarray, petal: np.ndarray, gap: float, *,
             max_move: float = MAX_MOVE, max_iterations: int = MAX_ITERATIONS,
             progress=None, leave: bool = False) -> Separation:
    """Move petals that pass through or touch each other apart, by as little as it takes.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int, consistently oriented within each petal
    petal : (V,) int, the petal of each vertex (petals share no vertex)
    gap : float, the smallest distance two petals may have after (same units as vertices)
    max_move : float, the bound on any vertex's move, as a fraction of its petal's length
    max_iterations : int, the bound on the rounds of push and check
    leave : bool, where pairs cannot be moved apart within the bounds, put both petals
        back as they were and leave them through each other (``Separation.left``), and
        separate the others, instead of raising

    Returns
    -------
    Separation
        ``vertices`` such that no edge of one petal passes through a triangle of another
        (ipctk's exact test) and no two petals are closer than ``gap``; what moved and how far.

    Raises
    ------
    SeparationError
        naming the petal pairs, when they are still through each other or closer than the
        gap after ``max_iterations`` rounds, or a vertex would move further than
        ``max_move`` (and not ``leave``); or a move folds a petal over itself.

    Notes
    -----
    Each round finds the edges of one petal that pass through a triangle of another
    (ipctk's exact test). For each pair of petals so found, their overlap around the
    crossings (the vertices of either petal lying over or under the other, within reach,
    joined to a crossing through vertices on the same side of it) decides which side of
    the other each belongs on: the side most of the overlap is on, weighted by area. It
    is decided once per pair and kept, and per pair, not once for the flower, so a
    pinwheel (each petal over one neighbour and under the other) is separated as it lies.
    Every vertex joined to a crossing on the wrong side asks to move across, to ``PUSH``
    gaps on its side; every pair of primitives of two petals apart but nearer than
    ``KEEP`` gaps (ipctk's distances: vertex-triangle, edge-edge) asks to be ``PUSH``
    gaps apart, or to keep its distance, so that petals stacked close move together.
    One least-squares solve finds the smallest, smoothest move that does it: each ask is
    an equation (of weight ``WEIGHT``) on the relative move of the two petals along the
    direction that parts them (so it is shared between them), against the bending and
    stretching of the move and a pull back to where each vertex was, which make a move
    fade over ``SPREAD`` of a petal's length (a neighbourhood: no spike, no fold). Rounds
    go on until the exact test finds no crossing and no pair is nearer than the gap.
    The fixed base of a petal is not known yet (this runs before the axis is found): it
    moves like the rest.

    A clean input (nothing through anything, nothing nearer than ``gap``) comes back
    unchanged, bit for bit. The result does not depend on ipctk's threads (every list it
    gives is sorted first): the same bits every run. The cost is about linear in the
    vertices: crossings through ipctk's BVH, closest points through a k-d tree per pair
    of petals that cross, and one sparse solve over the vertices near a move.
    """
    ipctk = one_thread()

    X0 = np.array(vertices, dtype=np.float64)
    F = np.ascontiguousarray(faces, dtype=np.int64)
    petal = np.ascontiguousarray(petal, dtype=np.int64)
    if len(X0) == 0 or len(F) == 0:
        return Separation(X0, length=np.zeros(0))
    count = int(petal.max()) + 1
    length = _petal_lengths(X0, petal, count)
    E = np.asarray(ipctk.edges(np.asfortranarray(F, dtype=np.int32)), dtype=np.int64)
    # (ipctk keeps references to these arrays: they must live as long as the mesh)
    rest, edges32, faces32 = (np.asfortranarray(X0), np.asfortranarray(E, dtype=np.int32),
                              np.asfortranarray(F, dtype=np.int32))
    patches = np.ascontiguousarray(petal, dtype=np.int32)
    mesh = ipctk.CollisionMesh(rest, edges32, faces32)
    mesh.can_collide = ipctk.make_vertex_patches_filter(patches)
    left: list = []
    reason = ""

    def put_back(pairs) -> np.ndarray:
        """The petals of ``pairs`` back as modelled; the patches with every pair of
        ``left`` joined, given to the mesh's filter (so that neither the test nor the
        pushes see those pairs again). Returns the patches."""
        back = np.isin(petal, [q for pair in pairs for q in pair])
        X[back] = X0[back]
        joined = np.ascontiguousarray(joined_labels(petal, count, left), dtype=np.int32)
        mesh.can_collide = ipctk.make_vertex_patches_filter(joined)
        return joined

    def leave_all(pairs) -> None:
        """Leave ``pairs`` as modelled, and whatever then crosses them across patches
        too, until nothing does."""
        nonlocal left, patches
        while pairs:
            left = left + pairs
            patches = put_back(left)
            pairs = _pair_list(crossings(X, F, E, patches), E, F, petal)

    graph = _graph(E, len(X0))
    area = _vertex_areas(X0, F)
    edge = _mean_edge(X0, E)
    spread = np.maximum(SPREAD * length, SPREAD_EDGES * edge)  # (P,)

    folded0 = _folded(X0, F, petal)
    X = X0.copy()
    crossed0 = close0 = None
    sides: dict = {}
    counts = []  # (crossing edges, round by round)
    for it in range(max_iterations + 1):
        crossing = crossings(X, F, E, patches)
        counts.append(len(crossing))
        near = _near(mesh, X, petal, gap, crossing)
        close = [c for c in near if c[2] < gap]
        if progress is not None:  # (a round on a studio model takes seconds)
            progress("separating petals", it, max_iterations,
                     f"round {it + 1}: {len(close)} close contact(s)")
        if crossed0 is None:
            crossed0 = _pair_list(crossing, E, F, petal)
            close0 = sorted({(a, b) for a, b, _, _ in close} - set(crossed0))
            if not crossed0 and not close0:
                return Separation(X0, moved=0, distance=_min_distance(mesh, X0, gap),
                                  length=length)
        if not len(crossing) and not close:
            break
        stalled = _stalled(counts)
        if it == max_iterations or stalled:
            pairs = _involved(crossing, close, E, F, petal)
            why = (f"still {_state(crossing, close, E, F, petal)} after {it} rounds"
                   + (f", the last {stalled} with no fewer crossings" if it < max_iterations
                      else ""))
            if not leave:
                raise SeparationError(pairs, why)
            leave_all(pairs)
            reason = reason or why
            break
        rows = _overlap_rows(X, F, E, petal, crossing, area, length, max_move, gap, sides)
        rows += [(ids[None], grad[None], np.array([need])) for _, _, _, (ids, grad, need) in near]
        D = _solve(X, graph, rows, petal, spread / edge)
        X = X + D
        reach = np.linalg.norm(X - X0, axis=1) / length[petal]
        if reach.max() > max_move:
            worst = int(np.argmax(reach))
            pairs = _involved(crossing, close, E, F, petal)
            mine = _culprits(X0, petal, reach > max_move, pairs) or pairs
            why = (f"a vertex of petal {petal[worst]} would move {reach[worst]:.1%} of its "
                   f"length (at most {max_move:.0%})")
            if not leave:
                raise SeparationError([p for p in pairs if petal[worst] in p] or pairs, why)
            left, reason = left + mine, reason or why  # (those pairs left as modelled)
            patches = put_back(mine)
            for pair in mine:
                sides.pop(pair, None)
    folded = sorted(set(_folded(X, F, petal)) - set(folded0))
    if folded:  # (the moves are smooth: this is a petal folded over itself at its base)
        why = f"it would fold petal(s) {', '.join(str(p) for p in folded)} over itself"
        pairs = [pair for pair in crossed0 + close0 if set(pair) & set(folded)]
        if not (leave and pairs):
            raise SeparationError(crossed0 + close0, why)
        leave_all(sorted(set(pairs) - set(left)))
        reason = reason or why
    move = np.linalg.norm(X - X0, axis=1) / length[petal]
    stuck, keep = sorted(set(left)), None
    if left:  # (pair by pair: what crosses or touches at the end, in the rounds' groups)
        left = _left_pairs(mesh, X, F, E, petal, joined_labels(petal, count, left), gap)
        keep = Filter(petal, petal=petal, pairs=left)  # (lives as long as the mesh)
        keep.apply(mesh)
    return Separation(X, crossed0, close0, int(np.count_nonzero(np.any(X != X0, axis=1))),
                      float(move.max()), float(np.sqrt(np.mean(move ** 2))), it,
                      _min_distance(mesh, X, gap), length, left, reason, stuck)


def _stalled(counts: list[int]) -> int:
    """Whether separation gives up, from the crossing edges of each round so far: the
    rounds since the count last fell below its fewest, when they reach :data:`STALL` with
    more crossings than the input had, or :data:`STALL_UNDER` with fewer; else 0."""
    last = counts[-1]
    since = len(counts) - 1 - int(np.argmin(counts))  # (argmin: the first fewest)
    need = STALL if last > counts[0] else STALL_UNDER
    return since if last and since >= need else 0


def _culprits(X0, petal, over, pairs) -> list[tuple[int, int]]:
    """The pairs (of ``pairs``) whose moves took vertices ``over`` (V,) too far: for each
    petal with such vertices, its pair with the petal nearest to them (as modelled). A
    pair crossing deep in one place is left; its petals' shallow crossings elsewhere are
    still separated."""
    out = set()
    for b in np.unique(petal[over]).tolist():
        others = [q for pair in pairs if b in pair for q in pair if q != b]
        if not others:
            continue
        near = [cKDTree(X0[petal == q]).query(X0[over & (petal == b)])[0].min() for q in others]
        q = others[int(np.argmin(near))]
        out.add((min(b, q), max(b, q)))
    return sorted(out)


def _left_pairs(mesh, X, F, E, petal, group, gap) -> list[tuple[int, int]]:
    """The pairs of petals of one group (``group`` (V,): each vertex's; petals joined by
    chains of pairs left as modelled in the rounds) that pass through each other at ``X``
    or are nearer than ``gap``: those left as modelled, with no contact between the two.
    The rest of a group's pairs keep contact: the first rose of the rose bed is one group
    (63 pairs left in the rounds chain its 50 petals), and of its 1,225 pairs 255 cross at
    the end and 11 more are nearer than the gap.
    ``mesh``: the collision mesh, given every petal pair (its filter is set here)."""
    crossing = _pair_list(crossings(X, F, E, petal), E, F, petal)
    keep = Filter(petal, petal=petal, pairs=crossing)  # (lives until the search is done)
    keep.apply(mesh)
    found = one_thread().NormalCollisions()
    found.build(mesh, np.asfortranarray(X), gap)
    edges, faces = mesh.edges, mesh.faces
    near = set()
    for k in range(len(found)):  # (found[k] refers into found: let go of it first)
        ids = {int(petal[i]) for i in found[k].vertex_ids(edges, faces) if i >= 0}
        if len(ids) == 2:
            near.add(tuple(sorted(ids)))
    same = np.zeros(int(petal.max()) + 1, dtype=np.int64)
    same[petal] = group
    return sorted(p for p in set(crossing) | near if same[p[0]] == same[p[1]])


def joined_labels(petal, count: int, pairs) -> np.ndarray:
    """``(V,)`` each vertex's label: its petal, or, for petals joined by ``pairs`` (and
    chains of them; ``count`` petals), the smallest petal of their group."""
    if len(pairs) == 0:
        return np.asarray(petal, dtype=np.int64).copy()
    a, b = np.asarray(pairs, dtype=np.int64).T
    graph = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(count, count))
    label = connected_components(graph, directed=False)[1]
    smallest = np.full(label.max() + 1, count, dtype=np.int64)
    np.minimum.at(smallest, label, np.arange(count))
    return smallest[label][petal]


# --- finding what to move -------------------------------------------------------------------

def crossings(X, F, E, petal, left=()) -> np.ndarray:
    """(k, 2) the (edge, face) pairs of different petals where the edge passes through the
    face (ipctk's exact test, the one ``has_intersections`` makes), sorted; none of two
    petals of a pair of ``left`` (pairs ``(a, b)``, left through each other)."""
    ipctk = one_thread()

    Xf = np.asfortranarray(X)
    broad = ipctk.LBVH()
    broad.build(Xf, np.asfortranarray(E, dtype=np.int32), np.asfortranarray(F, dtype=np.int32), 0.0)
    found = broad.detect_edge_face_candidates()
    if not found:
        return np.zeros((0, 2), dtype=np.int64)
    ids = np.array([(c.edge_id, c.face_id) for c in found], dtype=np.int64)
    ids = ids[petal[E[ids[:, 0], 0]] != petal[F[ids[:, 1], 0]]]
    if len(left):
        ids = ids[~_among(petal[E[ids[:, 0], 0]], petal[F[ids[:, 1], 0]], left)]
    # (a cheap first look: the edge's ends on either side of the face's plane, or on it)
    tri = X[F[ids[:, 1]]]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    side0 = np.einsum("ij,ij->i", X[E[ids[:, 0], 0]] - tri[:, 0], n)
    side1 = np.einsum("ij,ij->i", X[E[ids[:, 0], 1]] - tri[:, 0], n)
    scale = np.linalg.norm(n, axis=1) * np.abs(tri - tri.mean(axis=1, keepdims=True)).max(axis=(1, 2))
    ids = ids[(side0 * side1 <= 0) | (np.minimum(np.abs(side0), np.abs(side1)) <= 1e-9 * scale)]
    hit = [k for k, (e, f) in enumerate(ids) if ipctk.is_edge_intersecting_triangle(
        X[E[e, 0]], X[E[e, 1]], X[F[f, 0]], X[F[f, 1]], X[F[f, 2]])]
    out = ids[hit]
    return out[np.lexsort((out[:, 1], out[:, 0]))]


def _among(a, b, pairs) -> np.ndarray:
    """Whether each ``(a[i], b[i])`` (either order) is one of ``pairs``."""
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    n = int(max(np.max(a, initial=0), np.max(b, initial=0), pairs.max(initial=0))) + 1
    keys = np.minimum(pairs[:, 0], pairs[:, 1]) * n + np.maximum(pairs[:, 0], pairs[:, 1])
    return np.isin(np.minimum(a, b) * n + np.maximum(a, b), keys)


def crossed_pairs(X, F, petal, left=()) -> list[tuple[int, int]]:
    """The pairs of petals (``petal`` (V,): each vertex's; or of any labels) with an edge
    of one through a triangle of the other (ipctk's exact test), sorted, but the pairs of
    ``left``: one pass over the mesh (a BVH), not a test per pair."""
    ipctk = one_thread()
    F = np.ascontiguousarray(F, dtype=np.int64)
    E = np.asarray(ipctk.edges(np.asfortranarray(F, dtype=np.int32)), dtype=np.int64)
    petal = np.ascontiguousarray(petal, dtype=np.int64)
    return _pair_list(crossings(np.asarray(X, dtype=np.float64), F, E, petal, left), E, F, petal)


def _folded(X, F, petal) -> list[int]:
    """The petals that pass through themselves (ipctk's exact test, each petal alone,
    on its own vertices: the work grows with the mesh, not with petals times vertices)."""
    ipctk = one_thread()

    Xf = np.asfortranarray(X)
    F32 = np.asfortranarray(F, dtype=np.int32)
    whole = ipctk.CollisionMesh(Xf, ipctk.edges(F32), F32)
    if not ipctk.has_intersections(whole, Xf):
        return []
    out = []
    n = int(petal.max()) + 1
    for p, (verts, faces) in enumerate(zip(by_label(petal, n), by_label(petal[F[:, 0]], n), strict=True)):
        if not len(faces):
            continue
        sub = np.asfortranarray(np.searchsorted(verts, F[faces]), dtype=np.int32)
        Xp = np.asfortranarray(X[verts])
        if ipctk.has_intersections(ipctk.CollisionMesh(Xp, ipctk.edges(sub), sub), Xp):
            out.append(p)
    return out


def _pair_list(crossing, E, F, petal) -> list[tuple[int, int]]:
    if not len(crossing):
        return []
    a, b = petal[E[crossing[:, 0], 0]], petal[F[crossing[:, 1], 0]]
    return sorted({(int(min(x, y)), int(max(x, y))) for x, y in zip(a, b, strict=True)})


def _near(mesh, X, petal, gap, crossing):
    """Pairs of primitives (vertex-triangle, edge-edge, ...) of two petals that are apart
    (not through each other) and nearer than ``KEEP`` gaps: ``[(a, b, distance, row)]``,
    the row asking them to ``PUSH`` gaps apart, or to keep their distance when further
    (see :func:`_solve`). Pairs of petals that cross are :func:`_overlap_rows`'s."""
    ipctk = one_thread()

    Xf = np.asfortranarray(X)
    found = ipctk.NormalCollisions()
    found.build(mesh, Xf, KEEP * gap)
    if len(found) == 0:
        return []
    crossed = set()
    if len(crossing):
        crossed = set(_pair_list(crossing, mesh.edges.astype(np.int64),
                                 mesh.faces.astype(np.int64), petal))
    edges, faces = mesh.edges, mesh.faces
    out = []
    for k in range(len(found)):
        row = _near_row(found, k, Xf, edges, faces, petal, gap, crossed)
        if row is not None:
            out.append(row)
    return sorted(out, key=lambda r: (r[0], r[1], tuple(r[3][0])))


def _near_row(found, k, Xf, edges, faces, petal, gap, crossed):
    """:func:`_near`'s entry of the ``k``-th collision of ``found``, or None. (``found[k]``
    refers into ``found``: it must be let go of first, as it is here, on returning.)"""
    c = found[k]
    ids = [int(i) for i in c.vertex_ids(edges, faces) if i >= 0]
    pair = tuple(sorted({int(petal[i]) for i in ids}))
    if len(pair) != 2 or pair in crossed:
        return None
    x = c.dof(Xf, edges, faces)
    d = float(np.sqrt(c.compute_distance(x)))
    if d >= KEEP * gap:
        return None
    grad = np.asarray(c.compute_distance_gradient(x)).reshape(-1, 3)[:len(ids)]
    if not np.linalg.norm(grad) > 0.0:
        return None
    # the distance's gradient (ipctk's is the squared distance's): d(d) = grad . dx / (2 d)
    return (pair[0], pair[1], d,
            (np.array(ids), grad / (2.0 * max(d, 1e-300)), max(PUSH * gap - d, 0.0)))


def _overlap_rows(X, F, E, petal, crossing, area, length, max_move, gap, sides) -> list:
    """For each pair of petals that cross: the rows (see :func:`_solve`) asking the
    vertices on the wrong side of the other petal, joined to a crossing, across to
    ``PUSH`` gaps on the right side, and the vertices nearer than the gap away.

    ``sides`` maps a pair ``(a, b)`` (a < b) to the side of ``b`` (+1: where ``b``'s
    normals point) that ``a`` belongs on; a pair not in it yet is decided here (and
    added, so that later rounds keep it): the side most of their overlap is on, by area.
    The overlap is every vertex of either petal over or under the other (its closest
    point there inside it, not on its rim), within reach, joined to a crossing through
    vertices on the same side; a vertex of ``b`` counts for the side of ``b`` that ``a``
    is then on (by the sign of the cosine between their normals)."""
    rows = []
    normals = vertex_normals(X, F)
    rim = _rim(F, E, petal)
    ea, fb = petal[E[crossing[:, 0], 0]], petal[F[crossing[:, 1], 0]]
    found = []
    for a, b in _pair_list(crossing, E, F, petal):
        reach = max_move * (length[a] + length[b])
        mine = crossing[((ea == a) & (fb == b)) | ((ea == b) & (fb == a))]
        recs = [_records(X, F, petal, normals, rim, p, q, reach) for p, q in ((a, b), (b, a))]
        # each record's side in a's terms: +1 where a lies on the side of b's normals
        for k, r in enumerate(recs):
            r["says"] = np.sign(r["s"]) if k == 0 else -np.sign(r["s"]) * np.sign(r["kappa"])
        found.append((a, b, mine, recs))
    _joined(E, F, rim, found)
    for a, b, mine, recs in found:
        if (a, b) not in sides:  # the side most of the overlap is on (a tie: b's normal side)
            weight = [sum(float(area[r["vertex"][r["joined"] & (r["says"] == sg)]].sum())
                          for r in recs) for sg in (1.0, -1.0)]
            sides[(a, b)] = 1.0 if weight[0] >= weight[1] else -1.0
        side = sides[(a, b)]
        for k, r in enumerate(recs):  # (the side of the other each belongs on, by its normal)
            belongs = side if k == 0 else -side * np.sign(r["kappa"])
            rows.append(_push_rows(r, F, belongs, side, gap))
        rows.append(_crossing_rows(X, F, E, petal, normals, mine, a, side, gap))
    return [block for block in rows if len(block[2])]


def _push_rows(r, F, belongs, side, gap):
    """The rows of the records ``r`` of one petal against the other (a block: ``ids``
    (m, 4), ``grad`` (m, 4, 3), ``need`` (m,)): each vertex on the wrong side (``side``:
    the side of ``b`` that ``a`` belongs on, the records' ``says`` in a's terms) across to
    ``PUSH`` gaps on the side of the other it ``belongs`` on (by the other's normal: a
    scalar, or one per record), and each vertex nearer than the gap away: along the
    other's normal where it is over or under it, else straight away from it."""
    wrong = r["joined"] & (r["says"] != side)
    want = np.where(wrong, belongs, np.sign(r["s"]))
    pick = np.flatnonzero(wrong | (r["d"] < gap))
    normal = wrong[pick] | r["over"][pick]
    u = r["dv"][pick]
    norm = np.linalg.norm(u, axis=1)
    w = want[pick]
    direction = np.where(normal[:, None], w[:, None] * r["n"][pick],
                         u / np.where(norm > 0.0, norm, 1.0)[:, None])
    have = np.where(normal, w * r["s"][pick], norm)
    need = PUSH * gap - have
    keep = (normal | (norm > 0.0)) & (need > 0.0)
    pick, direction, need = pick[keep], direction[keep], need[keep]
    ids = np.column_stack([r["vertex"][pick], F[r["face"][pick]]])
    grad = np.concatenate([direction[:, None], -r["bary"][pick][:, :, None] * direction[:, None]],
                          axis=1)
    return ids, grad, need


def _crossing_rows(X, F, E, petal, normals, mine, a, side, gap):
    """Every crossing ``(edge, face)`` of ``mine`` asks too (a block of rows, as
    :func:`_push_rows`): its edge's ends on the wrong side across the face's plane (an
    edge through a petal's rim may have neither end over or under it)."""
    e, f = mine[:, 0], mine[:, 1]
    tri = X[F[f]]
    nf = face_normals(X, F[f])
    nf /= np.maximum(np.linalg.norm(nf, axis=1), 1e-300)[:, None]
    # the side of the face's petal that the edge's belongs on: a's side of b, or b's side
    # of a (by a's normal)
    flip = np.where(np.einsum("ij,ij->i", normals[E[e, 0]], nf) >= 0.0, 1.0, -1.0)
    want = np.where(petal[E[e, 0]] != a, -side * flip, side)
    ends = X[E[e]]
    t = np.einsum("ikj,ij->ik", ends - tri[:, :1], nf)
    same = t[:, 0] == t[:, 1]
    frac = np.where(same, 0.5, t[:, 0] / np.where(same, 1.0, t[:, 0] - t[:, 1]))
    cut = ends[:, 0] + (ends[:, 1] - ends[:, 0]) * frac[:, None]
    bary = _plane_bary(cut, tri)
    need = PUSH * gap - want[:, None] * t  # (n, 2): each end of each crossing's edge
    d = want[:, None] * nf
    ids = np.stack([np.column_stack([E[e, k], F[f]]) for k in range(2)], axis=1)
    grad = np.concatenate([d[:, None], -bary[:, :, None] * d[:, None]], axis=1)
    ask = need > 0.0  # (in the order of the crossings, each edge's first end then its second)
    return ids[ask], np.broadcast_to(grad[:, None], (len(e), 2, 4, 3))[ask], need[ask]


def _rim(F, E, petal) -> dict:
    """The mesh's boundary: ``vertex (V,) bool``, and ``edges``, sorted keys ``i * count + j``
    (i < j) of its boundary edges; and each petal's vertices, faces and edges
    (``verts``, ``faces``, ``edge_rows``: lists by petal, ascending), so that a pair's
    records look at its two petals only, not the whole mesh; ``near``, each petal's
    look-up for closest points (:func:`_records` fills it: once a round, not once a pair)."""
    count = len(petal)
    edges, _, uses = unique_edges(F)
    rim = edges[uses == 1]
    vertex = np.zeros(count, dtype=bool)
    vertex[rim.ravel()] = True
    n = int(petal.max()) + 1
    return {"vertex": vertex, "edges": np.sort(rim[:, 0] * count + rim[:, 1]), "count": count,
            "verts": by_label(petal, n), "faces": by_label(petal[F[:, 0]], n),
            "edge_rows": by_label(petal[E[:, 0]], n), "near": {}}


def _joined(E, F, rim, found) -> None:
    """Sets each record's ``joined`` (n,) bool, of every pair in ``found`` (``(a, b,
    crossings, records)``): over or under the other petal and joined to a crossing (an
    end of one of the pair's crossings) through its petal's edges, by vertices over or
    under the other petal on the same side. (One graph for all records: one search.)"""
    rows, cols, seeded, first = [], [], [], [0]
    for a, b, mine, recs in found:
        seeds = np.unique(np.r_[E[mine[:, 0]].ravel(), F[mine[:, 1]].ravel()])
        for p, r in zip((a, b), recs, strict=True):
            v = r["vertex"][r["over"]]  # (ascending: the records are in vertex order)
            says = r["says"][r["over"]]
            e = E[rim["edge_rows"][p]]
            i = np.minimum(np.searchsorted(v, e), max(len(v) - 1, 0))
            keep = (v[i[:, 0]] == e[:, 0]) & (v[i[:, 1]] == e[:, 1]) if len(v) else \
                np.zeros(len(e), dtype=bool)
            i = i[keep]
            i = i[says[i[:, 0]] == says[i[:, 1]]]
            rows.append(i[:, 0] + first[-1])
            cols.append(i[:, 1] + first[-1])
            seeded.append(np.isin(v, seeds))
            first.append(first[-1] + len(v))
    n = first[-1]
    seeded = np.concatenate(seeded) if seeded else np.zeros(0, dtype=bool)
    if n:
        rows, cols = np.concatenate(rows), np.concatenate(cols)
        graph = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
        label = connected_components(graph, directed=False)[1]
        hit = np.zeros(label.max() + 1, dtype=bool)
        hit[label[seeded]] = True
        seeded = hit[label]
    k = 0
    for _, _, _, recs in found:
        for r in recs:
            r["joined"] = np.zeros(len(r["vertex"]), dtype=bool)
            r["joined"][r["over"]] = seeded[first[k]:first[k + 1]]
            k += 1


def _plane_bary(point, tri) -> np.ndarray:
    """(n, 3) barycentric coordinates of each ``point`` (n, 3)'s projection on the plane
    of its triangle ``tri`` (n, 3, 3), clamped to the triangle (non-negative, summing to
    1; the centre for a degenerate triangle)."""
    e0, e1, p = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], point - tri[:, 0]
    dot = lambda x, y: np.einsum("ij,ij->i", x, y)  # noqa: E731
    d00, d01, d11 = dot(e0, e0), dot(e0, e1), dot(e1, e1)
    denom = d00 * d11 - d01 * d01
    good = denom > 0.0
    denom = np.where(good, denom, 1.0)
    v = (d11 * dot(p, e0) - d01 * dot(p, e1)) / denom
    w = (d00 * dot(p, e1) - d01 * dot(p, e0)) / denom
    out = np.clip(np.column_stack([1.0 - v - w, v, w]), 0.0, None)
    out = np.where(good[:, None], out, 1.0 / 3.0)
    return out / out.sum(axis=1, keepdims=True)


def _records(X, F, petal, normals, rim, a, b, reach) -> dict:
    """Each vertex of petal ``a`` within ``reach`` of petal ``b``: its closest point on
    ``b`` (``face``, barycentric coordinates ``bary``), distance ``d``, the offset ``dv``
    from that point, ``b``'s normal there ``n`` (its vertex normals blended), the signed
    distance ``s`` along it, whether the vertex is over or under ``b`` (``over``: the
    closest point is not on ``b``'s rim, ``rim`` of :func:`_rim`), and ``kappa``: the
    cosine between ``a``'s normal at the vertex and ``n``."""
    va, fb = rim["verts"][a], rim["faces"][b]
    if b not in rim["near"]:
        rim["near"][b] = Triangles(X, F, fb)
    r, f, bary, d = rim["near"][b].nearest(X[va], reach)
    keep = d <= reach
    r, f, bary, d = r[keep], f[keep], bary[keep], d[keep]
    v = va[r]
    c = np.einsum("ij,ijk->ik", bary, X[F[f]])
    n = np.einsum("ij,ijk->ik", bary, normals[F[f]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    dv = X[v] - c
    s = np.einsum("ij,ij->i", dv, n)
    # over or under b: the closest point is inside b, not on its rim (a rim edge or vertex)
    zero = bary <= 0.0
    corners = F[f]
    on_rim = np.where(zero.sum(axis=1) == 2, rim["vertex"][corners[np.arange(len(f)),
                                                                    np.argmax(~zero, axis=1)]],
                      False)
    single = zero.sum(axis=1) == 1
    k = np.argmax(zero, axis=1)
    ends = np.sort(np.stack([corners[np.arange(len(f)), (k + 1) % 3],
                             corners[np.arange(len(f)), (k + 2) % 3]], axis=1), axis=1)
    key = ends[:, 0] * rim["count"] + ends[:, 1]
    if len(rim["edges"]):  # (a key among the sorted rim edges' keys)
        at = np.minimum(np.searchsorted(rim["edges"], key), len(rim["edges"]) - 1)
        on_rim |= single & (rim["edges"][at] == key)
    over = ~on_rim
    kappa = np.einsum("ij,ij->i", normals[v], n)
    return {"vertex": v, "face": f, "bary": bary, "d": d, "dv": dv, "n": n, "s": s,
            "over": over, "kappa": kappa}


# --- moving --------------------------------------------------------------------------------

def _solve(X, graph, rows, petal, spread) -> np.ndarray:
    """The smallest, smoothest move ``D (V, 3)`` that does what ``rows`` ask.

    ``rows`` is a list of blocks ``(ids (m, k), grad (m, k, 3), need (m,))``, each row of
    which asks ``sum_j grad_j . D[ids_j] = need``, with weight ``WEIGHT``. Against the
    rows, per vertex ``i`` of spread ``l`` (its petal's, in mean edges): ``l^2 |(L D)_i|^2``
    (bending: ``L`` is the mesh's graph Laplacian), ``|D_i - D_j|^2`` per edge
    (stretching) and ``|D_i|^2 / l^2`` (the pull back), so that a move fades over about
    ``l`` edges. Only the vertices within four spreads of one asked to move are free; the
    others stay where they are."""
    asked = np.unique(np.concatenate([ids.ravel() for ids, _, _ in rows]))
    hops = np.ceil(4.0 * float(spread.max()))
    reach = dijkstra(graph, indices=asked, unweighted=True, limit=hops, min_only=True)
    free = np.flatnonzero(np.isfinite(reach))
    n = len(free)
    slot = np.full(len(X), -1, dtype=np.int64)
    slot[free] = np.arange(n)
    lap = sp.diags(np.asarray(graph.sum(axis=1)).ravel()) - graph
    cols = lap[:, free]
    scale = spread[petal[free]]
    A = (sp.diags(scale) @ (cols.T @ cols) @ sp.diags(scale) + lap[free][:, free]
         + sp.diags(1.0 / scale ** 2))
    A = sp.kron(A, sp.identity(3), format="csr")
    first = np.cumsum([0] + [len(need) for _, _, need in rows])
    row_of = np.concatenate([np.repeat(np.arange(len(need)) + first[k], 3 * ids.shape[1])
                             for k, (ids, _, need) in enumerate(rows)])
    vertex = np.concatenate([ids.ravel() for ids, _, _ in rows])
    col = (3 * slot[vertex][:, None] + np.arange(3)).ravel()
    val = np.concatenate([np.asarray(grad, dtype=np.float64).ravel() for _, grad, _ in rows])
    J = sp.csr_matrix((val, (row_of, col)), shape=(first[-1], 3 * n))
    need = np.concatenate([need for _, _, need in rows]).astype(np.float64)
    # (on a studio model this solve is much of a round. The matrix is symmetric positive
    # definite: SuperLU in its symmetric mode (a minimum-degree ordering of A + A^T, no
    # pivoting off the diagonal) solves the rose bed's first, 74,781 unknowns, in 4.4 s
    # against 15.0 s by its default column ordering, to the same residual (2e-15);
    # qdldl's LDL^T and Jacobi-preconditioned CG were no faster than the default, nor
    # five factorizations, one per rose of the bed, than one of all: 5.9 s against 6.5)
    lu = splu((A + WEIGHT * (J.T @ J)).tocsc(), permc_spec="MMD_AT_PLUS_A",
              diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    d = lu.solve(WEIGHT * (J.T @ need))
    D = np.zeros_like(X)
    D[free] = d.reshape(-1, 3)
    return D


# --- measures ------------------------------------------------------------------------------

def _petal_lengths(X, petal, count) -> np.ndarray:
    """(P,) each petal's length: its diameter, found by two sweeps (the vertex furthest
    from the centroid, then the vertex furthest from that)."""
    out = np.zeros(count)
    for p in range(count):
        pts = X[petal == p]
        if len(pts) < 2:
            continue
        far = pts[np.argmax(np.linalg.norm(pts - pts.mean(axis=0), axis=1))]
        out[p] = np.linalg.norm(pts - far, axis=1).max()
    return np.where(out > 0.0, out, max(out.max(), 1.0))


def _mean_edge(X, E) -> float:
    return float(np.linalg.norm(X[E[:, 0]] - X[E[:, 1]], axis=1).mean())


def _graph(E, n) -> sp.csr_matrix:
    return sp.coo_matrix((np.ones(2 * len(E)), (np.r_[E[:, 0], E[:, 1]], np.r_[E[:, 1], E[:, 0]])),
                         shape=(n, n)).tocsr()


def _vertex_areas(X, F) -> np.ndarray:
    a = 0.5 * np.linalg.norm(face_normals(X, F), axis=1) / 3.0
    out = np.zeros(len(X))
    for c in range(3):
        np.add.at(out, F[:, c], a)
    return out


def _min_distance(mesh, X, reach) -> float:
    ipctk = one_thread()

    Xf = np.asfortranarray(X)
    found = ipctk.NormalCollisions()
    found.build(mesh, Xf, 4.0 * reach)
    return float(np.sqrt(found.compute_minimum_distance(mesh, Xf))) if len(found) else np.inf


def _involved(crossing, close, E, F, petal) -> list[tuple[int, int]]:
    return sorted(set(_pair_list(crossing, E, F, petal)) | {(a, b) for a, b, _, _ in close})


def _names(pairs) -> str:
    return ", ".join(f"{a}-{b}" for a, b in pairs)


def _state(crossing, close, E, F, petal) -> str:
    parts = []
    if len(crossing):
        parts.append(f"through each other ({_names(_pair_list(crossing, E, F, petal))})")
    if close:
        parts.append(f"nearer than the gap ({_names(sorted({(a, b) for a, b, _, _ in close}))})")
    return " and ".join(parts)
