"""Procedural petals and closed buds, for tests and default scenes.

A petal is an obovate outline (narrow straight base, widest at 60% of its length,
rounded tip), triangulated isotropically and mirror-symmetric by construction: one half
is triangulated (Delaunay of a jittered triangular lattice plus boundary samples) and
mirrored across the midrib. It is then bent into a bud: the midrib follows an arc that
leans out from the receptacle and back in toward the flower's axis, and the width wraps
around the flower's axis, so every petal is cupped across its width. Petals stand in
whorls or a spiral, each layer a little outside the one before, overlapping as petals
in a bud do. The flower's axis is +z, the receptacle at the origin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay, cKDTree

from pipeline.mesh import topology


@dataclass(frozen=True)
class Outline:
    """Half-width of a petal of length 1 as a function of s in [0, 1]."""

    base_half_width: float = 0.07
    max_half_width: float = 0.30
    widest_at: float = 0.6

    def half_width(self, s: np.ndarray) -> np.ndarray:
        s = np.clip(np.asarray(s, dtype=np.float64), 0.0, 1.0)
        c, w0, W = self.widest_at, self.base_half_width, self.max_half_width
        lower = w0 + (W - w0) * (1.0 - (1.0 - s / c) ** 2)
        upper = W * np.sqrt(np.clip(1.0 - ((s - c) / (1.0 - c)) ** 2, 0.0, 1.0))
        return np.where(s <= c, lower, upper)


def _resample(points: np.ndarray, spacing: float) -> np.ndarray:
    """Points evenly spaced by arc length along a polyline, both ends kept."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    arc = np.r_[0.0, np.cumsum(seg)]
    n = max(int(np.ceil(arc[-1] / spacing)), 1)
    t = np.linspace(0.0, arc[-1], n + 1)
    return np.stack([np.interp(t, arc, points[:, 0]), np.interp(t, arc, points[:, 1])], axis=1)


def _half_points(outline: Outline, spacing: float, rng: np.random.Generator) -> np.ndarray:
    """2D points (u >= 0, s) of one half of the flat petal: boundary, midrib and interior."""
    s_fine = np.linspace(0.0, 1.0, 2001)
    curve = np.stack([outline.half_width(s_fine), s_fine], axis=1)
    rim = _resample(curve, spacing)  # from the base corner (w0, 0) to the tip (0, 1)
    base = _resample(np.array([[0.0, 0.0], [outline.base_half_width, 0.0]]), spacing)[:-1]
    n_mid = max(int(np.round(1.0 / spacing)), 2)
    mid_s = np.linspace(0.0, 1.0, n_mid + 1)[1:-1]
    mid_s = mid_s + rng.uniform(-0.12, 0.12, mid_s.size) * spacing
    midrib = np.stack([np.zeros_like(mid_s), mid_s], axis=1)
    fixed = np.concatenate([base, rim, midrib])
    # interior: triangular lattice in columns parallel to the midrib, jittered
    du = spacing * np.sqrt(3.0) / 2.0
    cols = []
    for m in range(1, int(outline.max_half_width / du) + 2):
        s = (np.arange(-1, int(1.0 / spacing) + 2) + 0.5 * (m % 2)) * spacing
        cols.append(np.stack([np.full_like(s, m * du), s], axis=1))
    inner = np.concatenate(cols)
    inner = inner + rng.uniform(-0.15, 0.15, inner.shape) * spacing
    inside = (inner[:, 1] > 0) & (inner[:, 1] < 1) & (inner[:, 0] < outline.half_width(inner[:, 1]))
    inner = inner[inside]
    dist, _ = cKDTree(fixed).query(inner)
    inner = inner[dist > 0.6 * spacing]
    return np.concatenate([fixed, inner])


def flat_petal(outline: Outline, spacing: float, rng: np.random.Generator):
    """A flat, mirror-symmetric petal of length 1 in the (u, s) plane.

    Returns ``(points (V, 2), faces (F, 3))``, counter-clockwise seen from +normal.

    Notes
    -----
    Only the half ``u >= 0`` is triangulated; the other half is its mirror image, so
    vertices pair up across the midrib and midrib vertices lie exactly on ``u = 0``.
    """
    half = _half_points(outline, spacing, rng)
    tri = Delaunay(half).simplices
    p = half[tri]
    area = 0.5 * ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
                  - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1]))
    keep = np.abs(area) > 1e-6 * spacing ** 2
    tri, area = tri[keep], area[keep]
    tri[area < 0] = tri[area < 0][:, [0, 2, 1]]
    on_mid = half[:, 0] <= 1e-12
    mirror_of = np.arange(len(half))
    off = np.flatnonzero(~on_mid)
    mirror_of[off] = len(half) + np.arange(off.size)
    points = np.concatenate([half, half[off] * [-1.0, 1.0]])
    faces = np.concatenate([tri, mirror_of[tri][:, [0, 2, 1]]])
    return points, faces


@dataclass(frozen=True)
class BudShape:
    """How flat petals are bent into a closed bud (lengths relative to a petal of 1)."""

    receptacle_radius: float = 0.06  #: distance of the petals' bases from the axis
    bulge: float = 0.30  #: how far the petals bow out from the axis at their widest
    closure: float = 0.85  #: fraction of a half sine the profile runs (1 closes the top)
    min_cup_radius: float = 0.22  #: cross-sections are arcs of at least this radius
    layer_gap: float = 0.06  #: radial distance between successive layers of petals


def bud_profile(s: np.ndarray, shape: BudShape, length: float = 1.0):
    """Midrib of a petal in its meridian plane: distance from the axis and height at s."""
    s_fine = np.linspace(0.0, 1.0, 4001)
    r = shape.receptacle_radius + shape.bulge * np.sin(np.pi * shape.closure * s_fine)
    dr = np.diff(r) * length
    ds = length / (s_fine.size - 1)
    dz = np.sqrt(np.clip(ds * ds - dr * dr, 0.0, None))
    z = np.r_[0.0, np.cumsum(dz)]
    return np.interp(s, s_fine, r * length), np.interp(s, s_fine, z)


def bend_into_bud(points: np.ndarray, azimuth: float, layer: float, shape: BudShape,
                  length: float = 1.0) -> np.ndarray:
    """Map flat petal points ``(u, s)`` onto the bud: the midrib runs in the meridian
    plane at ``azimuth``; each cross-section is an arc bending toward the flower's axis
    (the cup), of radius the midrib's distance from the axis but at least
    ``min_cup_radius``, so lengths across the petal are kept."""
    u, s = points[:, 0] * length, points[:, 1]
    radius, height = bud_profile(s, shape, length)
    radius = radius + layer * shape.layer_gap * length
    cup = np.maximum(radius, shape.min_cup_radius * length)
    a = u / cup
    outward = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
    across = np.array([-np.sin(azimuth), np.cos(azimuth), 0.0])
    along_r = radius - cup * (1.0 - np.cos(a))
    return (along_r[:, None] * outward + (cup * np.sin(a))[:, None] * across
            + height[:, None] * np.array([0.0, 0.0, 1.0]))


def _spacing_for(outline: Outline, vertices: int, rng_seed: int) -> float:
    """Lattice spacing that gives about ``vertices`` vertices on one petal."""
    s = np.linspace(0, 1, 2001)
    area = 2.0 * np.trapezoid(outline.half_width(s), s)
    spacing = np.sqrt(area / (0.866 * max(vertices, 12)))
    for _ in range(4):  # correct for the boundary samples
        n = len(flat_petal(outline, spacing, np.random.default_rng(rng_seed))[0])
        spacing *= np.sqrt(n / vertices)
    return spacing


def petal_layers(count: int) -> np.ndarray:
    """Radial layer of each petal: one whorl up to 3; from 4, petals alternate inner and
    outer, and with an odd count the last sits between its two neighbours (so that no
    two neighbours share a layer, and their overlapping rims do not cross)."""
    if count <= 3:
        return np.zeros(count)
    layers = (np.arange(count) % 2).astype(np.float64)
    if count % 2:
        layers[-1] = 0.5
    return layers


def bud(petals: int = 6, vertices: int = 1800, seed: int = 0, shape: BudShape = BudShape(),
        *, crossing: bool = False):
    """A closed bud of ``petals`` petals and about ``vertices`` vertices in all.

    Returns ``(vertices (V, 3), faces (F, 3), petal (V,))``; petal ``p`` is a separate
    connected component, mirror-symmetric about its own center plane. The same seed
    gives the same mesh.

    No two petals pass through each other (ipctk's exact test), so that contact can
    start from the bud: where the bud of ``shape`` would have them cross (dense buds,
    whose neighbours overlap more than two deep, and coarse ones, whose cups turn about
    other centres near base and tip), it is rebuilt untangled (:func:`_untangled`).
    ``crossing=True`` keeps the crossings (a bud made to be crossed, for tests).
    """
    if petals < 1:
        raise ValueError("a bud needs at least one petal")
    outline = Outline()
    spacing = _spacing_for(outline, vertices // petals, seed)

    def flat(p, rng):
        jitter = Outline(outline.base_half_width,
                         outline.max_half_width * (1.0 + rng.uniform(-0.04, 0.04)),
                         outline.widest_at + rng.uniform(-0.03, 0.03))
        return flat_petal(jitter, spacing, rng)

    return bend_bud(flat, petals, seed, shape, crossing=crossing)


def bend_bud(flat, petals: int, seed: int = 0, shape: BudShape = BudShape(), *,
             crossing: bool = False, untangled: bool = False):
    """The flat petals ``flat(p, rng) -> (points (V, 2), faces)`` bent into a closed bud
    (:func:`bend_into_bud`), each at its azimuth and layer (:func:`petal_layers`), its
    length jittered by up to 4%. Where two petals would cross (ipctk's exact test) the
    bud is made again untangled (:func:`_untangled`: one profile for all, each whorl on
    a surface of revolution of its own), unless ``crossing``."""
    rng = np.random.default_rng(seed)
    layers = petal_layers(petals)
    if untangled:
        shape, layers = _untangled(petals, shape)
    meshes = []
    for p in range(petals):
        pts, tri = flat(p, rng)
        azimuth = 2.0 * np.pi * p / petals + rng.uniform(-0.04, 0.04)
        length = 1.0 + rng.uniform(-0.04, 0.04)
        if untangled:  # (the draws stay, so each petal's own jitter is as before)
            azimuth, length = 2.0 * np.pi * p / petals, 1.0
        meshes.append((bend_into_bud(pts, azimuth, layers[p], shape, length), tri))
    out = topology.stack(meshes)
    if crossing or untangled or petals == 1 or not _crossed(*out):
        return out
    return bend_bud(flat, petals, seed, shape, untangled=True)


def _crossed(vertices, faces, petal) -> bool:
    """Whether two petals pass through each other (ipctk's exact test)."""
    import ipctk

    X = np.asfortranarray(vertices, dtype=np.float64)
    F = np.asfortranarray(faces, dtype=np.int32)
    mesh = ipctk.CollisionMesh(X, ipctk.edges(F), F)
    mesh.can_collide = ipctk.make_vertex_patches_filter(np.ascontiguousarray(petal, np.int32))
    return bool(ipctk.has_intersections(mesh, X))


#: petals of one whorl leave this fraction of their spacing free between them
WHORL_MARGIN = 0.85


def _untangled(petals: int, shape: BudShape) -> tuple[BudShape, np.ndarray]:
    """A shape and layers whose bud cannot cross: every cross-section an arc about the
    flower's axis (no cup tighter than that), so each whorl lies on a surface of
    revolution of its own, the whorls nested ``layer_gap`` apart; as many whorls as it
    takes, and a receptacle wide enough, that petals of one whorl do not overlap
    (angular width at most ``WHORL_MARGIN`` of their spacing, the widest outline
    allowed for: the jitter adds up to 4%)."""
    outline = Outline(max_half_width=1.04 * Outline().max_half_width, widest_at=0.63)
    s = np.linspace(0.0, 1.0, 401)
    width = 2.0 * np.maximum(outline.half_width(s), Outline(widest_at=0.57).half_width(s))
    for whorls in range(1, petals + 1):
        room = WHORL_MARGIN * 2.0 * np.pi * whorls / petals
        for receptacle in np.linspace(shape.receptacle_radius, 0.25, 39):
            trial = BudShape(float(receptacle), shape.bulge, shape.closure, 0.0, shape.layer_gap)
            radius, _ = bud_profile(s, trial)
            if np.all(width / radius <= room):
                return trial, _whorl_layers(petals, whorls)
    raise ValueError(f"no untangled bud of {petals} petals")


def _whorl_layers(petals: int, whorls: int) -> np.ndarray:
    """Layer of each petal: petal p in whorl ``p % whorls``, except where the circle
    closes unevenly (``petals % whorls``): a petal fewer than ``whorls`` places from one
    of its whorl goes to a whorl of its own, outside the others."""
    layers = np.zeros(petals)
    members: dict[int, list[int]] = {}
    extra = whorls
    for p in range(petals):
        layer = p % whorls
        near = [q for q in members.get(layer, []) if min((p - q) % petals, (q - p) % petals)
                < whorls]
        if near:
            layer, extra = extra, extra + 1
        members.setdefault(layer, []).append(p)
        layers[p] = layer
    return layers


@dataclass(frozen=True)
class OpenShape:
    """An open, recurved flower (a lily: Liang & Mahadevan 2011). Each tepal's midrib
    leaves the receptacle ``lean`` degrees from the flower's axis and turns steadily
    outward and down to ``recurve`` degrees at its tip; its cross-section is a trough
    (an arc of radius ``trough`` curving up, toward the flower's inside)."""

    receptacle_radius: float = 0.2
    lean: float = 20.0
    recurve: float = 125.0
    trough: float = 0.6
    inner_lean: float = 12.0  #: the inner whorl stands more upright
    inner_recurve: float = 110.0
    inner_width: float = 1.2  #: inner tepals are broader (relative max half-width)


def open_midrib(s: np.ndarray, lean: float, recurve: float, length: float = 1.0):
    """Midrib of an open tepal in its meridian plane: distance from the axis and height
    at ``s``, the angle from the axis rising as ``lean + (recurve - lean) s^2``."""
    s_fine = np.linspace(0.0, 1.0, 4001)
    phi = np.radians(lean + (recurve - lean) * s_fine ** 2)
    ds = length / (s_fine.size - 1)
    r = np.r_[0.0, np.cumsum(0.5 * (np.sin(phi[1:]) + np.sin(phi[:-1])) * ds)]
    z = np.r_[0.0, np.cumsum(0.5 * (np.cos(phi[1:]) + np.cos(phi[:-1])) * ds)]
    angle = np.interp(s, s_fine, phi)
    return np.interp(s, s_fine, r), np.interp(s, s_fine, z), angle


def bend_open(points: np.ndarray, azimuth: float, lean: float, recurve: float, trough: float,
              receptacle_radius: float, length: float = 1.0) -> np.ndarray:
    """Map flat petal points ``(u, s)`` onto an open tepal at ``azimuth``; lengths along
    the midrib and across it are kept."""
    u, s = points[:, 0] * length, points[:, 1]
    r, z, phi = open_midrib(s, lean, recurve, length)
    r = r + receptacle_radius * length
    outward = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
    across = np.array([-np.sin(azimuth), np.cos(azimuth), 0.0])
    up = np.array([0.0, 0.0, 1.0])
    # the tepal's inner normal in the meridian plane: toward the axis and up
    n_r, n_z = -np.cos(phi), np.sin(phi)
    a = u / (trough * length)
    lift = trough * length * (1.0 - np.cos(a))
    return ((r + lift * n_r)[:, None] * outward + (trough * length * np.sin(a))[:, None] * across
            + (z + lift * n_z)[:, None] * up)


def open_flower(tepals: int = 6, vertices: int = 1800, seed: int = 0,
                shape: OpenShape = OpenShape()):
    """An open lily of ``tepals`` tepals (outer and inner whorls alternating) and about
    ``vertices`` vertices, as :func:`bud` returns it. The same seed gives the same mesh."""
    if tepals < 1:
        raise ValueError("a flower needs at least one tepal")
    rng = np.random.default_rng(seed)
    outline = Outline(max_half_width=0.22)
    spacing = _spacing_for(outline, vertices // tepals, seed)
    meshes = []
    for p in range(tepals):
        inner = tepals > 3 and p % 2 == 1
        width = outline.max_half_width * (shape.inner_width if inner else 1.0)
        jitter = Outline(outline.base_half_width, width * (1.0 + rng.uniform(-0.03, 0.03)),
                         outline.widest_at + rng.uniform(-0.03, 0.03))
        flat, tri = flat_petal(jitter, spacing, rng)
        azimuth = 2.0 * np.pi * p / tepals + rng.uniform(-0.03, 0.03)
        lean, recurve = ((shape.inner_lean, shape.inner_recurve) if inner
                         else (shape.lean, shape.recurve))
        length = 1.0 + rng.uniform(-0.03, 0.03)
        meshes.append((bend_open(flat, azimuth, lean, recurve, shape.trough,
                                 shape.receptacle_radius * (0.6 if inner else 1.0), length), tri))
    return topology.stack(meshes)


def write_obj(path, vertices: np.ndarray, faces: np.ndarray, petal_ids: np.ndarray, header: str) -> None:
    """Write an OBJ with one ``o`` group per petal (plain text, fixed precision)."""
    lines = [f"# {line}" for line in header.splitlines()]
    lines += [f"v {x:.9f} {y:.9f} {z:.9f}" for x, y, z in vertices]
    face_petal = petal_ids[faces[:, 0]]
    for p in np.unique(petal_ids):
        lines.append(f"o petal_{p}")
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces[face_petal == p]]
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
