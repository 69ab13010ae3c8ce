"""The stable time step of the semi-implicit scheme (Eq. 7-8), estimated from the model.

Stability of the scheme
-----------------------
On a mode ``x'' = -omega^2 x`` (unit mass) one step maps ``(x, h v)`` by::

    [[1 - z^2/2,                           1                ],
     [-z^2 (eta + (1 - eta)(1 - z^2/2)),   d - z^2 (1 - eta)]]      z = h omega

with determinant ``d (1 - z^2/2) + eta z^2`` and trace ``1 + d - z^2 (3/2 - eta)``. Its
spectral radius stays <= 1 (Jury's conditions) while ``z <= z_max(eta, d)``, with
``z_max^2`` the smallest of ``4 (1 + d) / (3 - 4 eta + d)`` and, from the determinant,
``(1 - d) / (eta - d/2)`` when ``eta > d/2``. For ``d = 1`` that is ``sqrt(2 / (1 - eta))``:
2.0 at eta = 0.5, 1.633 at 0.25, 1.491 at 0.1 (the default), 1.414 at 0; the explicit
damping of Eq. 9 (``eta = 1/2, d < 1``) is stable only to ``sqrt 2``. (Checked against
the amplification matrix's eigenvalues in the tests.)

omega_max
---------
``omega_max^2`` is the largest eigenvalue of ``M^-1 H`` over the free vertices, ``H`` the
Hessian of the elastic energy at the current positions, rest lengths and rest angles
(:func:`pipeline.sim.terms.elastic.hessian`, the quasi-static solver's), plus the intact connection springs.
It is the largest eigenvalue of the symmetric ``S = D H D``, ``D = M^-1/2`` (0 on pinned
vertices). Two estimates:

- Gershgorin: ``max_r (S_rr + sum_c |S_rc|)``, an upper bound (connection springs added by
  the triangle inequality, so still one);
- Lanczos: ``LANCZOS_STEPS`` steps (full reorthogonalization) from a fixed start vector,
  shifted by the Gershgorin lower bound so the top of the spectrum is the part it finds;
  the top Ritz value plus its residual norm (an eigenvalue lies within that of it).

The estimate is the smaller of the two. The center-plane constraint (a projection) can
only lower the top eigenvalue, and collisions add no stiffness, so neither enters.
Everything runs serially in a fixed order: the same state gives the same estimate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from pipeline.sim.blocks import Blocks
from pipeline.sim.terms.connections import connection_blocks
from pipeline.sim.terms.elastic import hessian
from pipeline.sim.terms.shell import ShellBlocks, ShellTerm

LANCZOS_STEPS = 24


def scheme_limit(eta: float, d: float = 1.0) -> float:
    """The largest ``h omega`` at which the scheme is stable (spectral radius <= 1)."""
    z2 = 4.0 * (1.0 + d) / (3.0 - 4.0 * eta + d)
    if eta > 0.5 * d:
        z2 = min(z2, (1.0 - d) / (eta - 0.5 * d))
    elif eta < 0.5 * d:
        z2 = min(z2, (1.0 + d) / (0.5 * d - eta))
    return math.sqrt(max(z2, 0.0))


def amplification(z: float, eta: float, d: float = 1.0) -> np.ndarray:
    """The matrix one step applies to ``(x, h v)`` of a mode with ``h omega = z``."""
    w = z * z
    return np.array([[1.0 - 0.5 * w, 1.0],
                     [-w * (eta + (1.0 - eta) * (1.0 - 0.5 * w)), d - w * (1.0 - eta)]])


@njit(cache=True)
def gershgorin(indptr, indices, data, scale, pairs, blocks):
    """Upper and lower Gershgorin bounds on the eigenvalues of ``S = D H D`` (``scale`` is
    D's diagonal per vertex; rows of pinned vertices, scale 0, are left out), the
    connection springs' ``blocks`` included."""
    n = indptr.shape[0] - 1
    center = np.zeros((n, 3))
    radius = np.zeros((n, 3))
    for r in range(n):
        sr = scale[r]
        if sr == 0.0:
            continue
        for p in range(indptr[r], indptr[r + 1]):
            col = indices[p]
            s = sr * scale[col]
            if s == 0.0:
                continue
            for a in range(3):
                for b in range(3):
                    v = s * data[p, a, b]
                    if col == r and a == b:
                        center[r, a] += v
                    else:
                        radius[r, a] += abs(v)
    for c in range(pairs.shape[0]):
        i = pairs[c, 0]
        j = pairs[c, 1]
        for a in range(3):
            for b in range(3):
                v = blocks[c, a, b]
                if scale[i] > 0.0:
                    if a == b:
                        center[i, a] += scale[i] * scale[i] * v
                    else:
                        radius[i, a] += scale[i] * scale[i] * abs(v)
                    radius[i, a] += scale[i] * scale[j] * abs(v)
                if scale[j] > 0.0:
                    if a == b:
                        center[j, a] += scale[j] * scale[j] * v
                    else:
                        radius[j, a] += scale[j] * scale[j] * abs(v)
                    radius[j, a] += scale[i] * scale[j] * abs(v)
    hi = -np.inf
    lo = np.inf
    for r in range(n):
        if scale[r] == 0.0:
            continue
        for a in range(3):
            hi = max(hi, center[r, a] + radius[r, a])
            lo = min(lo, center[r, a] - radius[r, a])
    if hi == -np.inf:
        return 0.0, 0.0
    return hi, lo


@njit(cache=True)
def _apply(indptr, indices, data, scale, pairs, blocks, shift, x, y):
    """``y = (D H D + shift I) x`` (x, y: ``(V, 3)``)."""
    n = indptr.shape[0] - 1
    for r in range(n):
        y[r, 0] = 0.0
        y[r, 1] = 0.0
        y[r, 2] = 0.0
        sr = scale[r]
        if sr == 0.0:
            continue
        for p in range(indptr[r], indptr[r + 1]):
            col = indices[p]
            s = sr * scale[col]
            if s == 0.0:
                continue
            for a in range(3):
                y[r, a] += s * (data[p, a, 0] * x[col, 0] + data[p, a, 1] * x[col, 1]
                                + data[p, a, 2] * x[col, 2])
        for a in range(3):
            y[r, a] += shift * x[r, a]
    for c in range(pairs.shape[0]):
        i = pairs[c, 0]
        j = pairs[c, 1]
        for a in range(3):
            di = 0.0
            for b in range(3):
                di += blocks[c, a, b] * (scale[i] * x[i, b] - scale[j] * x[j, b])
            y[i, a] += scale[i] * di
            y[j, a] -= scale[j] * di


@njit(cache=True)
def _dot(a, b):
    s = 0.0
    for r in range(a.shape[0]):
        s += a[r, 0] * b[r, 0] + a[r, 1] * b[r, 1] + a[r, 2] * b[r, 2]
    return s


@njit(cache=True)
def _axpy(c, x, y):
    for r in range(x.shape[0]):
        y[r, 0] += c * x[r, 0]
        y[r, 1] += c * x[r, 1]
        y[r, 2] += c * x[r, 2]


@njit(cache=True)
def _scale(x, c):
    for r in range(x.shape[0]):
        x[r, 0] *= c
        x[r, 1] *= c
        x[r, 2] *= c


@njit(cache=True)
def lanczos(indptr, indices, data, scale, pairs, blocks, shift, Q, alpha, beta):
    """Lanczos on ``D H D + shift I`` from the fixed start vector in ``Q[0]`` (zero on pinned
    vertices), with full reorthogonalization: ``alpha (m,)``, ``beta (m,)`` of the
    tridiagonal matrix (``beta[m-1]`` is the residual's norm). Returns the steps done
    (fewer when an invariant subspace is found)."""
    m = Q.shape[0] - 1
    norm = math.sqrt(_dot(Q[0], Q[0]))
    if norm == 0.0:
        return 0
    _scale(Q[0], 1.0 / norm)
    for k in range(m):
        w = Q[k + 1]
        _apply(indptr, indices, data, scale, pairs, blocks, shift, Q[k], w)
        alpha[k] = _dot(Q[k], w)
        for _ in range(2):  # twice is enough (Kahan)
            for i in range(k + 1):
                _axpy(-_dot(Q[i], w), Q[i], w)
        b = math.sqrt(_dot(w, w))
        beta[k] = b
        if b <= 1e-12 * max(abs(alpha[k]), 1e-300):
            return k + 1
        _scale(w, 1.0 / b)
    return m


@dataclass
class Estimate:
    gershgorin: float  #: upper bound on omega_max^2
    lanczos: float  #: Lanczos' top Ritz value plus its residual (nan if not run)
    omega2: float  #: the estimate: the smaller of the two

    @property
    def omega(self) -> float:
        return math.sqrt(max(self.omega2, 0.0))


@dataclass
class StableStep:
    """The Hessian's pattern and work arrays for one model, built once."""

    blocks: Blocks  #: the Hessian, as last assembled by :meth:`estimate`
    scale: np.ndarray  #: (V,) 1/sqrt(mass), 0 on pinned vertices
    start: np.ndarray  #: (V, 3) the fixed Lanczos start vector
    steps: int = LANCZOS_STEPS

    @classmethod
    def build(cls, model, steps: int = LANCZOS_STEPS) -> StableStep:
        scale = np.sqrt(model.vertex_inv_mass)
        k = np.arange(3 * model.vertex_count, dtype=np.float64)
        start = (np.cos(2.399963229728653 * k) + 0.5 * np.cos(0.7548776662466927 * k * k))
        start = np.ascontiguousarray(start.reshape(-1, 3) * (scale > 0.0)[:, None])
        blocks = ShellBlocks.build(model) if model.shell is not None else Blocks.build(model)
        return cls(blocks, scale, start, steps)

    def estimate(self, model, positions, A: float, cos0, sin0, connections=None,
                 curl=None, tighten: bool = True) -> Estimate:
        """omega_max^2 at ``positions``, growth ``A`` (rest lengths), rest angles
        ``cos0, sin0`` (a shell: its rest curvature decayed by the ``curl`` effect's beta)
        and the intact ``connections`` (an :class:`effects.Connections`)."""
        X = np.ascontiguousarray(positions, dtype=np.float64)
        H = self.blocks
        if model.shell is not None:
            ShellTerm(model, curl).at(A).assemble(X, H)
        else:
            hessian(X, model.edge_indices, model.edge_rest_length, model.edge_growth,
                    model.edge_stiffness, model.hinge_indices, cos0, sin0,
                    model.hinge_stiffness, A, H.data, H.edge_slots, H.hinge_slots, H.work)
        if connections is not None and len(connections.pairs):
            pairs = connections.pairs
            blocks = np.zeros((len(pairs), 3, 3))
            connection_blocks(X, pairs, connections.rest, connections.stiffness,
                               connections.alive, blocks)
        else:
            pairs, blocks = np.zeros((0, 2), dtype=np.int64), np.zeros((0, 3, 3))
        hi, lo = gershgorin(H.indptr, H.indices, H.data, self.scale, pairs, blocks)
        if not tighten or self.steps <= 0 or not math.isfinite(hi):
            return Estimate(hi, math.nan, hi)
        shift = max(0.0, -lo)
        Q = np.zeros((self.steps + 1, *self.start.shape))
        Q[0] = self.start
        alpha = np.zeros(self.steps)
        beta = np.zeros(self.steps)
        m = lanczos(H.indptr, H.indices, H.data, self.scale, pairs, blocks, shift,
                    Q, alpha, beta)
        if m == 0:
            return Estimate(hi, math.nan, hi)
        T = np.diag(alpha[:m]) + np.diag(beta[:m - 1], 1) + np.diag(beta[:m - 1], -1)
        theta, S = np.linalg.eigh(T)
        top = float(theta[-1] + abs(beta[m - 1] * S[-1, -1])) - shift
        return Estimate(hi, top, min(hi, top))


def rest_angles(model, control, effects, t: float) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin of the rest angles at time ``t`` (the curl effect's, if on)."""
    curl = getattr(effects, "curl", None)
    if curl is None:
        return model.hinge_rest_cos, model.hinge_rest_sin
    factor = control.growth_at(t) * curl.beta
    angle = (1.0 - factor) * curl.theta0
    return np.cos(angle), np.sin(angle)
