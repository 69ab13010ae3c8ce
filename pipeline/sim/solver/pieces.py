"""Petals that do not interact, each a problem of its own, and the threads the solver's
independent work runs in.

Without collisions or connection springs, petals share no term: each follows its own
path of equilibria (:func:`split`), so a petal that snaps costs iterations of its own
factorization only, and the line search of one does not hold back another. They, the
factorizations of the groups of one coupled Newton step and the pieces' forces and
Hessians run in a thread pool (:func:`pipeline.sim.threads.parallel_map`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from pipeline.sim.effects import Effects
from pipeline.sim.explicit.pushback import Collisions
from pipeline.sim.model import Model, State
from pipeline.sim.terms.center_plane import CenterPlane
from pipeline.sim.terms.growth import Curl


@dataclass
class Piece:
    """One connected piece (a petal): its vertices in the whole, and its own problem."""

    vertices: np.ndarray
    model: Model
    effects: Effects
    state: State
    solver: object = None  #: its own path follower (a QuasiStatic)


#: with contact, pieces (petals) are problems apart in clusters that cannot meet: each
#: piece's box grown by this many times the largest piece's box diagonal (a petal swings
#: about its base by at most its length; boxes that overlap are one cluster)
CLUSTER_REACH = 1.0


def clusters(positions: np.ndarray, label: np.ndarray, count: int, apart=None) -> np.ndarray:
    """``(count,)`` the cluster of each piece (``label`` (V,): each vertex's): pieces
    whose boxes, grown by :data:`CLUSTER_REACH` of the largest piece's box diagonal,
    overlap (directly or through others) are one cluster: the flowers of a bush, far
    enough apart, are each a cluster of their own. ``apart`` ``(count,)``: pieces of
    different labels (the flowers of a file) are never one cluster, however near."""
    from pipeline.flower.measure import REACH, petals_within_reach

    X = np.asarray(positions, dtype=np.float64)
    low = np.full((count, 3), np.inf)
    high = np.full((count, 3), -np.inf)
    np.minimum.at(low, label, X)
    np.maximum.at(high, label, X)
    size = float(np.linalg.norm(high - low, axis=1).max())
    pairs = np.asarray(petals_within_reach(X, label, np.full(count, CLUSTER_REACH * size / REACH)),
                       dtype=np.int64).reshape(-1, 2)
    if apart is not None:
        apart = np.asarray(apart, dtype=np.int64)
        pairs = pairs[apart[pairs[:, 0]] == apart[pairs[:, 1]]]
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(count, count))
    return connected_components(graph, directed=False)[1].astype(np.int64)


def split(model: Model, effects: Effects, positions=None) -> list[Piece]:
    """The mesh's connected pieces, each as a problem of its own; [] if it is one piece
    or if the pieces interact (connection springs: then they are one problem). Without
    those, petals do not interact: each is solved on its own, so a petal that snaps costs
    iterations of its own factorization only, and the line search of one does not hold
    back another. With contact, the pieces are gathered in clusters that cannot meet
    (:func:`clusters`, measured at ``positions``: a bush's flowers), each a problem of
    its own with its own contact; [] if that is one cluster. Pieces without springs are
    left where they are."""
    n = model.vertex_count
    e = model.edge_indices
    graph = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    count, label = connected_components(graph, directed=False)
    pinned_pieces = np.unique(label[model.pinned])
    for c in range(count):
        if c not in pinned_pieces and np.any(label[e[:, 0]] == c):
            raise ValueError(f"a piece of the mesh ({int(np.sum(label == c))} vertices) has no "
                             "fixed base vertex: with nothing holding it, it has no "
                             "equilibrium; check axis.base")
    if count <= 1 or effects.connections is not None:
        return []
    cluster = np.arange(count)
    if effects.collisions is not None:
        if positions is None:
            return []
        flower = effects.collisions.vertex_flower
        apart = None
        if flower is not None:  # (each piece's flower: a piece lies in one flower)
            apart = np.zeros(count, dtype=np.int64)
            apart[label] = flower
        cluster = clusters(positions, label, count, apart)
        if cluster.max() == 0:
            return []
    label = cluster[label]  # (from here on, a "piece" is a cluster of pieces)
    parts = []
    for c in range(int(label.max()) + 1):
        idx = np.flatnonzero(label == c)
        local = np.full(n, -1, dtype=np.int64)
        local[idx] = np.arange(len(idx))
        emask = label[e[:, 0]] == c
        if not emask.any():
            continue
        hmask = label[model.hinge_indices[:, 0]] == c
        sub = Model(
            vertex_count=len(idx), vertex_mass=model.vertex_mass[idx],
            vertex_inv_mass=model.vertex_inv_mass[idx], edge_indices=local[e[emask]],
            edge_rest_length=model.edge_rest_length[emask], edge_growth=model.edge_growth[emask],
            edge_stiffness=model.edge_stiffness[emask],
            hinge_indices=local[model.hinge_indices[hmask]],
            hinge_rest_cos=model.hinge_rest_cos[hmask], hinge_rest_sin=model.hinge_rest_sin[hmask],
            hinge_stiffness=model.hinge_stiffness[hmask])
        if model.shell is not None:
            edge_map = np.cumsum(emask) - 1
            sub.shell = model.shell.subset(label[model.shell.face_indices[:, 0]] == c, local,
                                           edge_map)
        fx = Effects(names=effects.names)
        if effects.curl is not None:
            k = effects.curl
            fx.curl = Curl(k.theta0[hmask].copy(), k.beta, k.cos_t[hmask].copy(),
                           k.sin_t[hmask].copy())
        if effects.center_plane is not None:
            cp = effects.center_plane
            mine = label[cp.vertices] == c
            fx.center_plane = CenterPlane(local[cp.vertices[mine]], cp.normals[mine],
                                          cp.height[mine])
        if effects.collisions is not None:  # (its contact: the quasi-static solver's)
            k = effects.collisions
            cell, offset, margin, slack = (float(x) for x in k.params)
            faces = k.faces[label[k.faces[:, 0]] == c]
            fx.collisions = Collisions.build(
                positions[idx], local[faces], k.petal[idx],  # (the whole's numbers:
                # a refusal of the cluster's start names the petals as the log does)
                offset=offset, max_edge=cell - 2.0 * (margin + offset + slack),
                thickness=k.thickness, margin=margin, slack=slack, pushback=False,
                left=k.left)
            if k.in_contact is not None:  # (the cluster's vertices in contact come first)
                fx.collisions.in_contact = int(np.sum(idx < k.in_contact))
        zeros = np.zeros((len(idx), 3))
        state = State(zeros.copy(), zeros.copy(), zeros.copy(), 0, 0.0, zeros.copy())
        parts.append(Piece(idx, sub, fx, state))
    return parts
