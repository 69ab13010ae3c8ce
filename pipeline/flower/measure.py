"""Measurements of a bloom: opening angle per petal, energies."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from pipeline.mesh import topology
from pipeline.mesh.hinge import dihedral_angles

#: a chord that turns less than this (radians, about 0.06 deg) to reach an open model
#: tells no direction of its own (:meth:`PetalFrames.opening_toward`)
TURNED = 1e-3


@dataclass
class PetalFrames:
    """Per petal, what the opening angle is measured against (taken on the initial mesh).

    The opening angle is the rotation of the chord from the base's centre to the tip,
    within the plane of the initial chord and the petal's outward direction (from the
    petal's centroid toward its midrib, i.e. away from the cup); positive is outward.
    In a flower (its axis known), outward is also away from the axis: a petal whose cup
    does not tell (nearly flat, or cupped the other way, as in a dense bud's inner
    whorls) has its direction turned to agree with the flower's, see :func:`_away`.
    """

    base_centers: np.ndarray  #: (P, 3) centroid of each petal's fixed base vertices
    tips: np.ndarray  #: (P,) tip vertex index
    chord_dirs: np.ndarray  #: (P, 3) unit initial chord
    outward_dirs: np.ndarray  #: (P, 3) unit outward direction, perpendicular to the chord

    @classmethod
    def from_mesh(cls, vertices, petal, base, on_axis, tips, plane,
                  flower_axis=None) -> PetalFrames:
        """``flower_axis``: (6,) point and unit direction from the receptacle toward
        the tips (nan or None: a lone petal, none), or ``(P, 6)`` each petal's flower's."""
        v = np.asarray(vertices, dtype=np.float64)
        count = int(petal.max()) + 1 if len(petal) else 0
        centers, chords, outs = [], [], []
        for p in range(count):
            mine = petal == p
            b = mine & base
            centroid = v[mine].mean(axis=0)
            center = v[b].mean(axis=0) if b.any() else centroid
            chord = v[tips[p]] - center
            length = np.linalg.norm(chord)
            chord /= length
            axis_pts = mine & on_axis
            ref = v[axis_pts].mean(axis=0) if axis_pts.any() else centroid
            # within the center plane, across the chord (a symmetric petal opens in its
            # center plane): the midrib's offset from the centroid says which side only.
            # That offset is small on a shallow cup, and off the plane where the triangles
            # are not symmetric (a Poisson-disc petal's turned the measure by up to 40 deg)
            out = np.cross(plane[p, :3], chord)
            if np.linalg.norm(out) < 1e-9:  # (a chord across the plane: the offset alone)
                out = ref - centroid
            out -= chord * (out @ chord)
            if out @ (ref - centroid) < 0.0:
                out = -out
            out /= np.linalg.norm(out)
            away = _away((center, centroid), chord, length, flower_axis if flower_axis is None
                         or np.ndim(flower_axis) == 1 else flower_axis[p])
            if away is not None and out @ away < 0.0:
                out = -out
            centers.append(center)
            chords.append(chord)
            outs.append(out)
        return cls(np.array(centers).reshape(-1, 3), np.asarray(tips, dtype=np.int64),
                   np.array(chords).reshape(-1, 3), np.array(outs).reshape(-1, 3))

    def opening_toward(self, X) -> PetalFrames:
        """The same frames with each petal's outward direction the way its chord turns to
        reach ``X`` (an open start's model: the bloom ends there, and it is open by
        definition; a bud found backward may curl so far that its chord and cup no longer
        tell, and a nearly flat petal's cup tells no direction at all): the opening is
        measured in the plane of the chord's turn. A petal whose chord does not turn
        keeps its outward direction, turned the way it goes."""
        chord = np.asarray(X)[self.tips] - self.base_centers
        turn = chord - np.einsum("ij,ij->i", chord, self.chord_dirs)[:, None] * self.chord_dirs
        size = np.linalg.norm(turn, axis=1)
        moved = size > TURNED * np.linalg.norm(chord, axis=1)
        sign = np.where(self.opening_angles(X) < 0.0, -1.0, 1.0)
        out = np.where(moved[:, None], turn / np.where(moved, size, 1.0)[:, None],
                       self.outward_dirs * sign[:, None])
        return dataclasses.replace(self, outward_dirs=out)

    def opening_angles(self, X) -> np.ndarray:
        """``(P,)`` opening angle of each petal in degrees (0 on the initial mesh)."""
        chord = np.asarray(X)[self.tips] - self.base_centers
        along = np.einsum("ij,ij->i", chord, self.chord_dirs)
        out = np.einsum("ij,ij->i", chord, self.outward_dirs)
        return np.degrees(np.arctan2(out, along))


def leans(X, petal, base, tips, axes) -> np.ndarray:
    """``(P,)`` how far each petal leans from its flower's axis: the angle in degrees
    between its chord (its base's centre to its tip) and the axis's direction (from the
    receptacle toward the tips), ``axes`` ``(P, 6)`` each petal's flower's point and
    direction (nan for none: nan); negative where the chord rises and leans in, across
    the axis (its part away from the axis points back toward it: a bud's petal whose tip
    curls over the centre, a rose's, leans in); a chord that falls hangs down, in or out.
    A bud's petals lean less than the open flower's; a bud found backward whose petals
    hang down leans more. Away from the axis is from the axis to the petal's base centre,
    or to its centroid where the base is on the axis (within a fiftieth of the chord);
    where both are, the angle is unsigned."""
    X = np.asarray(X, dtype=np.float64)
    petal = np.asarray(petal)
    count = len(tips)
    base = np.asarray(base, dtype=bool)
    total = np.zeros((count, 3))
    np.add.at(total, petal[base], X[base])
    n = np.bincount(petal[base], minlength=count)[:, None]
    centre = total / np.maximum(n, 1)
    chord = X[np.asarray(tips)] - centre
    a = np.asarray(axes, dtype=np.float64)
    direction = a[:, 3:] / np.linalg.norm(a[:, 3:], axis=1)[:, None]
    length = np.linalg.norm(chord, axis=1)
    cos = np.einsum("ij,ij->i", chord, direction) / length
    angle = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    whole = np.zeros((count, 3))
    np.add.at(whole, petal, X)
    centroid = whole / np.maximum(np.bincount(petal, minlength=count), 1)[:, None]
    sign = np.ones(count)
    for point in (centroid, centre):  # (the base centre's, where it is off the axis)
        r = point - a[:, :3]
        r -= direction * np.einsum("ij,ij->i", r, direction)[:, None]
        off = np.linalg.norm(r, axis=1) > 0.02 * length
        inward = (np.einsum("ij,ij->i", chord, r) < 0.0) & (cos > 0.0)
        sign = np.where(off, np.where(inward, -1.0, 1.0), sign)
    return sign * angle


def _away(where, chord, length: float, flower_axis) -> np.ndarray | None:
    """The way a petal opens, as the flower tells it: away from the axis and down it,
    ``r - a`` (``r`` the unit direction from the axis to the petal, ``a`` the axis's),
    without its part along the petal's chord. For a closed bud's petal that is ``r``;
    for one lying flat, ``-a``; for one at 45 degrees, both. ``where``: the petal's base
    centre, then its centroid: ``r`` is the first's that is off the axis by more than a
    fiftieth of the petal's ``length``. The base first: a bud's petal may lean over the
    axis (an open lily's bud, found backward, has one whose centroid is across it); the
    centroid where the bases meet on the axis (an open flower of sheets joined at its
    centre). None where it does not tell: no axis, both on it, or a petal along
    ``r - a`` itself (turned down 45 degrees)."""
    fa = None if flower_axis is None else np.asarray(flower_axis, dtype=np.float64)
    if fa is None or fa.shape != (6,) or not np.all(np.isfinite(fa)):
        return None
    a = fa[3:] / np.linalg.norm(fa[3:])
    for point in where:
        r = point - fa[:3]
        r -= a * (r @ a)
        size = np.linalg.norm(r)
        if size > 0.02 * length:
            break
    else:
        return None
    d = r / size - a
    d -= chord * (d @ chord)
    return d if np.linalg.norm(d) > 0.25 else None


def section_weights(hinges, hinge_edge_ends_s, hinge_edge_ends_x) -> np.ndarray:
    """Weight of each hinge in the cross-section curvature: how much its edge runs along
    the petal (along s rather than across x), so that its fold bends the cross-section."""
    ds = hinge_edge_ends_s[:, 1] - hinge_edge_ends_s[:, 0]
    dx = hinge_edge_ends_x[:, 1] - hinge_edge_ends_x[:, 0]
    return ds ** 2 / np.maximum(ds ** 2 + dx ** 2, 1e-300)


def cross_section_curvature(X, hinges, weights, petal_of_hinge, petals: int) -> np.ndarray:
    """``(P,)`` mean |dihedral angle| (radians per mean edge) over each petal's hinges
    that run along the petal, weighted by :func:`section_weights`."""
    theta = np.abs(dihedral_angles(np.asarray(X, dtype=np.float64), hinges))
    out = np.zeros(petals)
    for p in range(petals):
        mine = petal_of_hinge == p
        w = weights[mine]
        out[p] = float((w * theta[mine]).sum() / max(w.sum(), 1e-300))
    return out


def wrinkle_count(X, loops, vertex_normals) -> int:
    """Sign changes, along each boundary loop, of the rim's normal displacement from its
    neighbours' mean two vertices away: ``(x_i - (x_{i-2} + x_{i+2}) / 2) . n_i``; values
    under 0.01 mean edges are ignored. A smoothly curved rim has none or two; each
    wrinkle adds two."""
    total = 0
    for loop in loops:
        if len(loop) < 5:
            continue
        x = X[loop]
        d = np.einsum("ij,ij->i", x - 0.5 * (np.roll(x, 2, axis=0) + np.roll(x, -2, axis=0)),
                      vertex_normals[loop])
        sign = np.sign(np.where(np.abs(d) < 0.01, 0.0, d))
        sign = sign[sign != 0]
        if len(sign) > 1:
            total += int(np.sum(sign != np.roll(sign, 1)))
    return total


def gaussian_curvature_sign(X, faces, petal, interior) -> np.ndarray:
    """``(P,)`` sign of each petal's total Gaussian curvature over its interior vertices
    (angle defect 2 pi - sum of angles): +1 cup-like, -1 saddle-like."""
    X = np.asarray(X, dtype=np.float64)
    p = X[faces]
    angles = np.zeros((len(faces), 3))
    for k in range(3):
        a = p[:, (k + 1) % 3] - p[:, k]
        b = p[:, (k + 2) % 3] - p[:, k]
        cos = np.einsum("ij,ij->i", a, b) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
        angles[:, k] = np.arccos(np.clip(cos, -1.0, 1.0))
    total = np.zeros(len(X))
    np.add.at(total, faces.ravel(), angles.ravel())
    defect = np.where(interior, 2.0 * np.pi - total, 0.0)
    count = int(petal.max()) + 1
    return np.array([np.sign(defect[petal == q].sum()) for q in range(count)], dtype=np.int64)


def rim_bending(X, hinges, rim) -> float:
    """Mean |dihedral angle| (radians) over the hinges that touch the boundary (``rim``,
    a per-hinge mask): how sharply the rim is folded. A buckled rim scores high."""
    theta = np.abs(dihedral_angles(np.asarray(X, dtype=np.float64), hinges))
    return float(theta[rim].mean()) if rim.any() else 0.0


#: growth.start = auto: a flower whose petals' base-to-tip chords lean (median) this far
#: from its axis is already open (the project's buds: 9 deg; the open models: 49-95 deg)
OPEN_CHORD = 30.0
#: ... and whose petals' tips turn outward, away from its axis, by more than this (median;
#: the angle of the last fifth of each midrib from the axis, positive outward): a closed
#: bud of petals leaning out at the base curls its tips back in over its centre (the
#: lotus: chords 37.7 deg, tips -4.5 deg; the open models' tips 15-131 deg)
OPEN_TIP = 5.0
#: ... or whose outer petals (the 90th percentile of the chords' lean, and of the tips'
#: turn over OPEN_TIP) lean this far: an open flower of whorls whose inner petals stand
#: (the water lily: median 26.5 deg, its outer whorl 79.6 deg, tips 97 deg out; no bud
#: of the project leans its outer petals past 35 deg, the closed lotus 58.2)
OPEN_OUTER = 60.0
#: ... or whose petals are rolled back: more than this share of the flower's squared
#: curvature curves away from its inside (the shell's forms, ``Prepared.recurve``). A
#: bud's petals cup over its centre (the default buds 0.3-0.4%, the lotus 3.4%, the
#: tulip 36%); rims' growth would close rolled-back petals (an open rose of 50 petals,
#: 83%, whose inner whorls stand: chords 17.7 deg, the outer 57.9; bloomed forward every
#: petal closed 25-59 deg). The open models: 18-83%
OPEN_RECURVE = 0.5
#: ... and a lone petal whose surface turns (median over its rims and midrib) less than
#: this from base to tip and across is already open (a cupped bud petal: 89 deg; the
#: external single petals: 0-53 deg)
OPEN_CUP = 45.0


@dataclass(frozen=True)
class Start:
    """How the bloom starts, decided from the model (``growth.start = "auto"``)."""

    start: str  #: "bud": bloom forward from the mesh; "open": the mesh is the open flower
    figure: float  #: the measure it was decided on, degrees
    reason: str  #: one line: the measure, its value and the threshold


def bloom_start(vertices, faces, petal, base, tip, s, x, on_axis, flower_axis,
                recurve=None) -> Start:
    """Whether the model is a closed bud or an open flower.

    A flower (two petals or more, its axis known): the median angle between each
    petal's base-to-tip chord and the flower's axis (toward the tips); a bud's petals
    rise along the axis (under :data:`OPEN_CHORD`), an open flower's spread, and so do
    the outer petals of an open flower of whorls (:data:`OPEN_OUTER`); a flower whose
    petals rise but are rolled back is open too (``recurve``, a callable giving the
    share of the flower's squared curvature that curves away from its inside, or None
    where it cannot tell; asked only then: over :data:`OPEN_RECURVE`). A lone
    petal: how far its surface turns, the median over the petal of the angle between
    the normals at its base and tip along the midrib and between its two rims across;
    a bud petal is a deep cup (over :data:`OPEN_CUP`), an open one nearly flat."""
    v = np.asarray(vertices, dtype=np.float64)
    petal = np.asarray(petal)
    count = int(petal.max()) + 1
    fa = np.asarray(flower_axis, dtype=np.float64)
    if count >= 2 and fa.shape == (6,) and np.all(np.isfinite(fa)):
        d = fa[3:] / np.linalg.norm(fa[3:])
        s, on_axis = np.asarray(s), np.asarray(on_axis, bool)
        angles, turns = [], []
        for p in range(count):
            mine = petal == p
            held = mine & np.asarray(base, bool)
            chord = v[tip[p]] - v[held if held.any() else mine].mean(axis=0)
            angles.append(np.degrees(np.arccos(np.clip(chord @ d / np.linalg.norm(chord), -1, 1))))
            turns.append(_tip_turn(v, mine, on_axis, s, v[tip[p]], fa[:3], d))
        lean, turn = float(np.median(angles)), float(np.median(turns))
        outer, outer_turn = float(np.percentile(angles, 90)), float(np.percentile(turns, 90))
        spread = lean > OPEN_CHORD and turn > OPEN_TIP
        whorl = outer > OPEN_OUTER and outer_turn > OPEN_TIP
        rolled = None if spread or whorl or recurve is None else recurve()
        back = rolled is not None and rolled > OPEN_RECURVE
        start = "open" if spread or whorl or back else "bud"
        return Start(start, lean, f"the petals' base-to-tip chords lean {lean:.1f} deg (median) "
                     f"from the flower's axis, their tips turn {turn:.1f} deg outward; a bud's "
                     f"lean is under {OPEN_CHORD:g}, or its tips under {OPEN_TIP:g}"
                     + (f"; but its outer petals lean {outer:.1f} deg, tips {outer_turn:.1f} deg "
                        f"out (90th percentile; over {OPEN_OUTER:g}: an open flower of whorls)"
                        if whorl and not spread else "")
                     + (f"; {100 * rolled:.0f}% of its squared curvature rolls back, away "
                        f"from its inside (over {100 * OPEN_RECURVE:g}%: an open flower)"
                        if rolled is not None else ""))
    normals = topology.vertex_normals(v, faces)
    turns = []
    for p in range(count):
        mine = petal == p
        band = mine & (s > 0.4) & (s < 0.7)
        pairs = ((mine & (s < 0.15) & on_axis, mine & (s > 0.85) & on_axis),
                 (band & (x < -0.8), band & (x > 0.8)))
        for a, b in pairs:
            if a.any() and b.any():
                na, nb = normals[a].mean(axis=0), normals[b].mean(axis=0)
                cos = na @ nb / max(np.linalg.norm(na) * np.linalg.norm(nb), 1e-300)
                turns.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    cup = float(np.median(turns)) if turns else 90.0
    start = "open" if cup < OPEN_CUP else "bud"
    return Start(start, cup, f"the petal's surface turns {cup:.1f} deg (median, base to tip and "
                 f"rim to rim); a bud petal's turns over {OPEN_CUP:g}")


def _tip_turn(v, mine, on_axis, s, tip, point, direction) -> float:
    """How far a petal's tip turns outward from the flower's axis (through ``point``
    along ``direction``), in degrees: the angle from the axis of the last fifth of its
    midrib (the tip from the mean of the midrib's vertices at s 0.7-0.9), positive away
    from the axis, negative toward it (a tip curled in over the centre)."""
    band = mine & (s > 0.7) & (s < 0.9)
    mid = band & on_axis
    seg = tip - v[mid if mid.any() else band if band.any() else mine].mean(axis=0)
    r = (tip - point) - ((tip - point) @ direction) * direction
    out = r / max(float(np.linalg.norm(r)), 1e-300)
    return float(np.degrees(np.arctan2(seg @ out, seg @ direction)))


#: effects.collisions.enabled = auto: petals whose boxes, grown by this fraction of the
#: median petal length, overlap can come within reach of each other as they bloom
REACH = 0.5


def petals_within_reach(vertices, petal, lengths) -> list[tuple[int, int]]:
    """Pairs of petals that can meet: their bounding boxes, each grown by
    :data:`REACH` of the median petal length (``lengths``), overlap. Over petals, not
    vertices (a file of hundreds of petals: boxes, one pass each)."""
    v = np.asarray(vertices, dtype=np.float64)
    petal = np.asarray(petal)
    count = int(petal.max()) + 1
    if count < 2:
        return []
    grow = REACH * float(np.median(lengths))
    low = np.full((count, 3), np.inf)
    high = np.full((count, 3), -np.inf)
    np.minimum.at(low, petal, v)
    np.maximum.at(high, petal, v)
    low, high = low - grow, high + grow
    order = np.argsort(low[:, 0], kind="stable")
    pairs = []
    for k, a in enumerate(order):  # sweep along x: only boxes that overlap in x are compared
        for b in order[k + 1:]:
            if low[b, 0] > high[a, 0]:
                break
            if np.all(low[a] <= high[b]) and np.all(low[b] <= high[a]):
                pairs.append((int(min(a, b)), int(max(a, b))))
    return sorted(pairs)
