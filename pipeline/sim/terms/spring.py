"""The spring: ``1/2 k (l - L)^2`` between two vertices, compiled. One place for the
stretch springs on the edges (Eq. 2) and the connection springs between petals: its
tension and energy (:func:`_spring`) and its 3x3 Hessian block (:func:`_spring_block`)."""

from __future__ import annotations

from numba import njit


@njit(cache=True, inline="always")
def _spring(length, rest, k):
    """A spring ``k (length - rest)``: its tension and energy. One place for stretch and
    connection springs; the caller adds ``tension / length * d`` to ``F[i]`` and takes it
    from ``F[j]`` (``d = x_j - x_i``) when ``length > 0``.

    It takes no array on purpose: an array handed to an inlined helper that branches
    costs an atomic reference count increment and decrement per call (per edge)."""
    stretch = length - rest
    tension = k * stretch
    return tension, 0.5 * tension * stretch


@njit(cache=True, inline="always")
def _spring_block(length, rest, k):
    """A spring's Hessian block ``K = along u u^T + across I`` (``u`` the unit vector
    along it): returns ``(along, across)``. Along the spring its stiffness is ``k``;
    across, ``k (1 - L / l)``, negative for a compressed spring. The spring adds ``K`` at
    (i, i) and (j, j), ``-K`` at (i, j) and (j, i)."""
    across = k * (1.0 - rest / length)
    along = k - across
    return along, across


@njit(cache=True, inline="always")
def _pull(F, i, j, c, dx, dy, dz):
    """Add a spring's force ``c (dx, dy, dz)`` (``c``: its tension over its length,
    ``(dx, dy, dz)`` from ``i`` to ``j``) to ``i``, and the opposite to ``j``."""
    F[i, 0] += c * dx
    F[i, 1] += c * dy
    F[i, 2] += c * dz
    F[j, 0] -= c * dx
    F[j, 1] -= c * dy
    F[j, 2] -= c * dz
