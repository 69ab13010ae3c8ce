"""An open model's bud shape (``growth.start = "open"`` with the shell): what the bud has
in place of the model's own curvature, which the bloom turns into the model's.

Undoing the growth alone would keep the model's curvature in the bud, so that a petal
modelled with its tip or rim rolled back rolls further back as its rims shorten, and a
flat petal may cup either way. The bud instead leaves out the model's *recurve* (its
curvature away from the flower's inside, ``growth.recurve``) and is *cupped* toward the
inside (``growth.cup``); both fade out over the bloom (the shell's rest curvature,
:meth:`pipeline.sim.terms.shell.ShellData.rest_on`). Forms are a face's second
fundamental form ``(b11, b12, b22)`` in its corners' barycentric coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.sim.effects import flower_axis_or_guess, has_flower_axis


@dataclass(frozen=True)
class BudShape:
    """What an open model's bud has in place of the model's own curvature
    (``growth.recurve``, ``growth.cup``; :mod:`pipeline.sim.reverse`)."""

    inside: np.ndarray  #: (F,) +-1: the side of each face's normal toward the flower's inside
    cup: float = 0.0  #: the bud's curvature toward the inside, in 1 / the petal size
    recurve: bool = True  #: whether the model's curvature away from the inside is left out


def face_metrics(X, faces) -> np.ndarray:
    """``(F, 3)``: each face's metric ``(e1.e1, e1.e2, e2.e2)`` at positions ``X``."""
    F = np.asarray(faces)
    e1, e2 = X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]]
    return np.stack([np.einsum("ij,ij->i", e1, e1), np.einsum("ij,ij->i", e1, e2),
                     np.einsum("ij,ij->i", e2, e2)], axis=1)


def bloom_form(X, faces, form, bud: BudShape, size: float) -> np.ndarray:
    """``(F, 3)``: the part of the model's second fundamental form ``form`` that its bud
    has not, and the bloom grows in: the recurve (:func:`recurve_form`, if
    ``bud.recurve``) less the bud's cup, ``bud.cup / size`` times the metric toward the
    inside (a bowl of that curvature every way). The bud's rest curvature is ``form``
    less this: not rolled back, cupped over the flower (which picks the side a flat
    petal closes to, where its rims' growth undone could cup it either way)."""
    inside = np.asarray(bud.inside, dtype=np.float64)
    added = recurve_form(X, faces, form, inside) if bud.recurve else np.zeros_like(form)
    return added - (bud.cup / size * inside)[:, None] * face_metrics(X, faces)


def recurve_form(X, faces, form, inside) -> np.ndarray:
    """``(F, 3)``: the part of each face's second fundamental form ``form (F, 3)`` (b11,
    b12, b22 in its corners' barycentric coordinates, at positions ``X``) that curves
    away from the flower's inside, ``inside (F,)`` (+-1: the side of the face's normal,
    ``e1 x e2``, toward it): the form restricted to its principal curvatures of the
    other sign, ``a V min(k, 0) V^T a`` with ``b v = k a v``, ``a`` the face's metric.
    A petal's tip or rim rolled back, a lily's recurved petal: an open model's recurve,
    which its bud does not have (zero on a face curved only toward the inside, a cup)."""
    g = face_metrics(X, faces)
    a = np.empty((len(g), 2, 2))
    a[:, 0, 0], a[:, 1, 1] = g[:, 0], g[:, 2]
    a[:, 0, 1] = a[:, 1, 0] = g[:, 1]
    b = np.empty((len(g), 2, 2))
    b[:, 0, 0], b[:, 1, 1] = form[:, 0], form[:, 2]
    b[:, 0, 1] = b[:, 1, 0] = form[:, 1]
    b *= np.asarray(inside, dtype=np.float64)[:, None, None]
    L = np.linalg.cholesky(a)
    Li = np.linalg.inv(L)
    k, Q = np.linalg.eigh(Li @ b @ np.swapaxes(Li, 1, 2))
    away = L @ (Q * np.minimum(k, 0.0)[:, None, :]) @ np.swapaxes(Q, 1, 2) @ np.swapaxes(L, 1, 2)
    away *= np.asarray(inside, dtype=np.float64)[:, None, None]
    return np.ascontiguousarray(np.stack([away[:, 0, 0], 0.5 * (away[:, 0, 1] + away[:, 1, 0]),
                                          away[:, 1, 1]], axis=1))


def recurve_share(X, faces, form, inside) -> float:
    """How much of the surface's curvature ``form (F, 3)`` is its recurve
    (:func:`recurve_form`, ``inside`` as there): the area-weighted sum of the recurve's
    squared principal curvatures over that of ``form``'s, in [0, 1]."""
    out = recurve_form(X, faces, form, inside)
    g11, g12, g22 = face_metrics(X, faces).T
    det = g11 * g22 - g12 * g12
    area = 0.5 * np.sqrt(np.maximum(det, 0.0))

    def squared(b):  # tr((a^-1 b)^2), the sum of the squared principal curvatures
        i11, i12, i22 = g22 / det, -g12 / det, g11 / det
        m11 = i11 * b[:, 0] + i12 * b[:, 1]
        m12 = i11 * b[:, 1] + i12 * b[:, 2]
        m21 = i12 * b[:, 0] + i22 * b[:, 1]
        m22 = i12 * b[:, 1] + i22 * b[:, 2]
        return m11 * m11 + 2.0 * m12 * m21 + m22 * m22

    ok = det > 0.0
    whole = float(np.sum(area[ok] * squared(form[ok])))
    return float(np.sum(area[ok] * squared(out[ok])) / whole) if whole > 0.0 else 0.0


def inner_sides(positions, faces, petal, s, flower_axis) -> np.ndarray:
    """``(F,)`` +-1: for each face, the sign that turns its normal (``e1 x e2``) toward
    the flower's inside, one sign per petal: that of the area-weighted sum, over the
    petal's half nearest its base (``s`` < 1/2, where a recurved tip does not turn it),
    of the normals along the inward direction (up the flower's axis, toward its open
    side, plus toward the axis: a flat open petal's upper side, a standing petal's
    inner side; a lone petal: up, :func:`~pipeline.sim.effects.flower_axis_or_guess`)."""
    X = np.asarray(positions, dtype=np.float64)
    F = np.asarray(faces)
    point, up = flower_axis_or_guess(X, flower_axis)
    owner = np.asarray(petal)[F[:, 0]]
    each = up.ndim == 2  # (each petal's flower's axis)
    if each:
        point, up = point[owner], up[owner]
    inward = np.broadcast_to(up, (len(F), 3))
    if has_flower_axis(flower_axis):
        radial = X[F].mean(axis=1) - point
        radial -= (np.einsum("ij,ij->i", radial, up)[:, None] * up if each
                   else np.outer(radial @ up, up))
        inward = inward - radial / np.maximum(np.linalg.norm(radial, axis=1), 1e-300)[:, None]
    normal = np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])
    along = np.einsum("ij,ij->i", normal, inward) * (np.asarray(s)[F].mean(axis=1) < 0.5)
    total = np.bincount(owner, weights=along, minlength=int(owner.max()) + 1)
    return np.where(total[owner] >= 0.0, 1.0, -1.0)
