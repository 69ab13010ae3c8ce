"""Which parts of a flower model are petals: judged by shape and placement, named by hint.

A part is first measured on its own (:func:`_measure`): its length (first principal
extent), its mean width (area over length; half of that for a closed or two-layer
shell, whose area counts both sides), how thick it is for its width (ray-cast, see
:func:`pipeline.mesh.thickness.thickness`), whether it is open (boundary after
welding) and whether it is compact. That gives its form:

- ``narrow``: mean width under ``NARROW`` of its length (a stem, a filament, a style);
- ``shell``: thin closed shell or two layers (``LAYERED`` of its area has a roughly
  parallel layer behind it, at under ``THIN`` of its width): a thick petal's form;
- ``sheet``: open, one layer (boundary at least ``OPEN`` times the square root of the
  area): a petal's or a leaf's form;
- ``blob``: closed and compact (third extent at least ``COMPACT`` of the first): an
  anther, a receptacle;
- ``solid``: anything else.

Then placement decides. The petals are a ring: the largest group of at least three
alike sheets or shells (area within ``ALIKE_AREA``, length within ``ALIKE_LENGTH``)
whose centroids lie at similar distances (spread under ``RING_SPREAD``) from the line
through their mean along the normal of their plane, at azimuths all around it. That
line is the flower's axis; where the petals come nearest it is the base; up is where
their centroids are. A part that is itself a ring (petals joined in one mesh: round
in plan) stands for the ring when there is none and the file has other parts.
Around that frame: a narrow or solid part on the axis reaching further below the base
than above it is the stem; above it, the pistil; a compact one at the base, the
receptacle; off the axis above the base and within the ring, a stamen; another sheet
level with the ring, a petal; a smaller sheet at the base, a sepal; a sheet off the
ring, a leaf.

A part made of 2 or more alike sheets or shells (five petals in one OBJ group) is judged
piece by piece, and gets its pieces' most common verdict. A part of unlike pieces (a
whole flower in one mesh: petals, receptacle, stem) has each piece over ``CRUMB`` of its
largest judged on its own; where some are petals and some not, the part is a petal part
whose ``Verdict.faces`` are its petal pieces'. The pieces of a part are measured in one
pass (:func:`_measure_pieces`), and a part that is a moved, turned or scaled copy of an
earlier one (instancing) is measured as that one, moved.

Many flowers in one file (a bush, a bed, a branch): the sheets and shells are grouped
into flowers by where their bases gather (:func:`pipeline.mesh.flowers.flowers`), and
each flower's ring (with its inner whorls: further rings of alike sheets around nearly
the same axis, at or above the base) is found among its own; where the file names its
petals, only theirs. A part outside every ring is placed by its nearest flower. Where the
petals lie flat (a daisy seen edge-on), up along the axis is a guess, so a stem and a
pistil may swap.

A name containing petal, stem, leaf, sepal, stamen (anther, filament), pistil or
receptacle (one of them only) decides the kind instead; petals are still told thin or
thick by shape. Generic names (Circle.003, pCube14, Cylinder01, part_3) leave it to
shape. Every tolerance is relative to a part's or the flower's size.

The module is long because measuring a part, splitting a part of unlike pieces, finding
the flowers' rings and placing every other part around them are one judgement: each step
reads the measures and the frame (axis, base, up) the others make.
"""

from __future__ import annotations

import fnmatch
import re
from dataclasses import dataclass, field, replace

import numpy as np

from pipeline import forks
from pipeline.mesh import clean, topology
from pipeline.mesh.similar import Copies
from pipeline.mesh.thickness import thickness

KINDS = ("petal", "thick petal", "stem", "leaf", "sepal", "stamen", "pistil", "receptacle", "other")
PETAL_KINDS = ("petal", "thick petal")
HUB_KINDS = ("receptacle", "stamen", "pistil")  #: kinds at a flower's centre

WELD = 1e-5  #: vertices closer than this fraction of a part's diagonal are one
NARROW = 0.1  #: mean width / length below this: a stem, filament or style
LAYERED = 0.3  #: area fraction with a parallel layer behind it that makes a shell ...
THIN = 0.2  #: ... when that layer is nearer than this fraction of the width
OPEN = 1.0  #: an open sheet's boundary is at least this times sqrt(area)
COMPACT = 0.5  #: third / first principal extent of a blob
MAJOR = 0.2  #: a connected piece with this fraction of its part's largest piece's area counts
#: ... as one of a part's alike petals; a piece with this fraction of it is judged on its
#: own in a part that holds a whole flower (petals, receptacle and stem in one mesh)
CRUMB = 0.01
ALIKE_AREA = 2.0  #: petals of one ring differ in area by less than this factor ...
ALIKE_LENGTH = 1.5  #: ... and in length by less than this one
RING_SPREAD = 0.35  #: std / mean of the petals' distances from the axis
ROUND = 0.7  #: second / first extent of a part that is a whole ring of petals
#: a flat sheet on the axis at the base is the flower's centre (a low-poly blossom's
#: disc), not a petal or a sepal, when it is flat (third extent under FLAT of the
#: second), faces along the axis (its normal within acos(FACING) of it) and fills its
#: outline (area at least FILLS of its extents' rectangle: a disc 0.79, a hexagon 0.75;
#: a calyx's star of sepals less; the Blender lily's spiky cup is not flat)
FLAT, FACING, FILLS = 0.25, 0.9, 0.6
ON_AXIS = 0.05  #: a part is on the axis when its centroid is nearer than its own
#: half-width or this fraction of the petals' length
#: another ring of alike sheets in a flower, its axis within this angle of the petals',
#: at or above their base, is a whorl of petals (a water lily's inner whorls)
WHORL_DEGREES = 30.0
#: two parts that each ring an axis on their own are one flower (whorls in two meshes)
#: when each ring's base is within this fraction of a petal length of the other's axis
#: and their axes are within WHORL_DEGREES (a branch's blossoms lie a few tenths apart)
COAXIAL = 0.15
#: a flower's ring is sought from at most this many seeds (quantiles of petal area)
RING_SEEDS = 32

NAMES = {
    "petal": "petal", "stem": "stem", "stalk": "stem", "leaf": "leaf", "leaves": "leaf",
    "sepal": "sepal", "calyx": "sepal", "stamen": "stamen", "anther": "stamen",
    "filament": "stamen", "pistil": "pistil", "stigma": "pistil", "receptacle": "receptacle",
    "grass": "leaf", "foliage": "leaf", "twig": "stem", "branch": "stem",
}


@dataclass(frozen=True)
class Verdict:
    """What a part is (one of ``KINDS``) and why, with the measurements."""

    kind: str
    reason: str
    #: (F,) bool over the part's faces (as given): the pieces that are petals, where only
    #: some of a part's pieces are (a whole flower in one mesh); None: the whole part
    faces: np.ndarray | None = field(default=None, compare=False, repr=False)
    #: the flower this part holds on its own (its pieces ring an axis: a blossom in one
    #: mesh), numbered by the first such part of it (parts ringing one axis are one
    #: flower's whorls), or -1: petals of two such flowers are never one flower
    whole: int = field(default=-1, compare=False)

    @property
    def is_petal(self) -> bool:
        return self.kind in PETAL_KINDS


@dataclass
class _Shape:
    """Measurements of one part, or of one connected piece of a part."""

    vertices: np.ndarray  #: (V, 3) welded
    centroid: np.ndarray  #: (3,) area-weighted
    axes: np.ndarray  #: (3, 3) principal directions, rows, longest first
    extents: np.ndarray  #: (3,) max - min along each
    area: float
    length: float  #: first extent
    width: float  #: mean width (area / length, halved for a closed or layered shell)
    thickness: float  #: relative to the width; 0 for an open single sheet, inf if unknown
    layered: float  #: area fraction that has a parallel layer behind it
    form: str  #: narrow, shell, sheet, blob or solid


def _spread(tri: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """``(F, 3, 3)`` each triangle's own second moment about its centroid, per unit area
    (a uniform triangle's: a twelfth of its corners' outer products about the centroid).
    Added to the centroids' spread, a part's principal axes are its surface's, not its
    face centres' (a kite petal of two triangles: the two centres lie across it, and its
    width was taken for its length)."""
    d = tri - centres[:, None, :]
    return np.einsum("fia,fib->fab", d, d) / 12.0


def _measure(vertices: np.ndarray, faces: np.ndarray) -> _Shape:
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    diag = float(np.linalg.norm(np.ptp(v[f.ravel()], axis=0))) if len(f) else 0.0
    v, f, _ = clean.weld(v, f, WELD * diag) if diag > 0 else (v, f, 0)
    used = np.unique(f)
    remap = np.zeros(len(v), dtype=np.int64)
    remap[used] = np.arange(used.size)
    v, f = v[used], remap[f]
    tri = v[f]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    face_area = 0.5 * np.linalg.norm(cross, axis=1)
    area = float(face_area.sum())
    centres = tri.mean(axis=1)
    weight = face_area / area if area > 0 else np.full(len(f), 1.0 / max(len(f), 1))
    centroid = weight @ centres
    d = centres - centroid
    cov = (d * weight[:, None]).T @ d + np.einsum("f,fab->ab", weight, _spread(tri, centres)) \
        + 1e-30 * np.eye(3)
    _, vecs = np.linalg.eigh(cov)
    axes = vecs[:, ::-1].T
    extents = np.ptp((v - centroid) @ axes.T, axis=0)
    length = float(max(extents[0], 1e-300))
    _, he_edge, count = topology.unique_edges(f)
    edges = np.stack([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]).reshape(-1, 2)
    boundary = count[he_edge] == 1
    boundary_length = float(np.linalg.norm(v[edges[boundary, 0]] - v[edges[boundary, 1]], axis=1).sum())
    th = thickness(v, f)
    width, form = _form(extents, area, length, boundary_length, th.layered_fraction,
                        th.relative_thickness)
    rel = 0.0 if form == "sheet" else float(th.relative_thickness)
    return _Shape(v, centroid, axes, extents, area, length, width, rel, th.layered_fraction, form)


def _form(extents, area: float, length: float, boundary_length: float, layered: float,
          relative: float) -> tuple[float, str]:
    """``(width, form)`` of a piece from its measures: narrow, shell (two layers close
    together: a thick petal), sheet (open: rim long for its area), blob or solid."""
    is_shell = layered >= LAYERED and relative <= THIN
    is_open = boundary_length >= OPEN * np.sqrt(area) and not is_shell
    width = area / length if is_open else 0.5 * area / length
    if width < NARROW * length:
        return width, "narrow"
    if is_shell:
        return width, "shell"
    if is_open:
        return width, "sheet"
    return width, "blob" if extents[2] >= COMPACT * length else "solid"


def _moved_shape(shape: _Shape, k: float, rot: np.ndarray, t: np.ndarray) -> _Shape:
    """The measurements of a part's copy ``k x R^T + t`` (the relative ones unchanged)."""
    return _Shape(k * shape.vertices @ rot.T + t, k * shape.centroid @ rot.T + t,
                  shape.axes @ rot.T, k * shape.extents, k * k * shape.area, k * shape.length,
                  k * shape.width, shape.thickness, shape.layered, shape.form)


def _piece_labels(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """The part's connected pieces after welding (``WELD``): ``(welded faces (F, 3), piece
    of each face (F,), count)``, pieces numbered by their first face; a face with a
    repeated corner after welding is in no piece (-1)."""
    f = np.asarray(faces, dtype=np.int64)
    welded = _welded_faces(vertices, f)
    good = (welded[:, 0] != welded[:, 1]) & (welded[:, 1] != welded[:, 2]) & (welded[:, 2] != welded[:, 0])
    label = np.full(len(f), -1, dtype=np.int64)
    if not good.any():
        return welded, label, 0
    comp = topology.components(welded[good], len(vertices))[welded[good][:, 0]]
    _, first = np.unique(comp, return_index=True)
    rank = np.empty(comp.max() + 1, dtype=np.int64)
    rank[comp[np.sort(first)]] = np.arange(first.size)
    label[good] = rank[comp]
    return welded, label, int(first.size)


def _measure_pieces(vertices: np.ndarray, faces: np.ndarray, label: np.ndarray,
                    count: int) -> list[_Shape]:
    """:func:`_measure` of each of a part's pieces (``label``, -1: none), all in one pass:
    sums by piece and one ray cast (:func:`thickness` with ``own_component``), so a part
    of thousands of pieces (a tuft of grass) costs what one piece of its size does."""
    ok = label >= 0
    lab = label[ok]
    used, f = np.unique(np.asarray(faces, dtype=np.int64)[ok], return_inverse=True)
    f = f.reshape(-1, 3)
    v = np.asarray(vertices, dtype=np.float64)[used]
    vlab = np.empty(len(v), dtype=np.int64)
    vlab[f.ravel()] = np.repeat(lab, 3)
    tri = v[f]
    face_area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    nface = np.bincount(lab, minlength=count).astype(np.float64)
    area = np.bincount(lab, weights=face_area, minlength=count)
    centres = tri.mean(axis=1)
    weight = np.where(area[lab] > 0, face_area / np.where(area[lab] > 0, area[lab], 1.0),
                      1.0 / np.maximum(nface[lab], 1.0))
    centroid = np.stack([np.bincount(lab, weights=weight * centres[:, k], minlength=count)
                         for k in range(3)], 1)
    d = centres - centroid[lab]
    within = _spread(tri, centres)
    cov = np.empty((count, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            cov[:, a, b] = cov[:, b, a] = np.bincount(
                lab, weights=weight * (d[:, a] * d[:, b] + within[:, a, b]), minlength=count)
    cov += 1e-30 * np.eye(3)
    _, vecs = np.linalg.eigh(cov)
    axes = np.transpose(vecs[:, :, ::-1], (0, 2, 1))  # rows, longest first
    proj = np.einsum("ij,ikj->ik", v - centroid[vlab], axes[vlab])
    high = np.full((count, 3), -np.inf)
    low = np.full((count, 3), np.inf)
    np.maximum.at(high, vlab, proj)
    np.minimum.at(low, vlab, proj)
    extents = high - low
    he, _ = topology.half_edges(f)
    _, he_edge, edge_count = topology.unique_edges(f)
    rim = np.flatnonzero(edge_count[he_edge] == 1)
    rim_length = np.linalg.norm(v[he[rim, 0]] - v[he[rim, 1]], axis=1)
    boundary_length = np.bincount(lab[rim % len(f)], weights=rim_length, minlength=count)
    th = thickness(v, f, own_component=True)
    layered_area = np.bincount(lab, weights=face_area * th.layered, minlength=count)
    layered = np.where(area > 0, layered_area / np.where(area > 0, area, 1.0), 0.0)
    relative = np.full(count, np.inf)
    m = np.flatnonzero(th.layered)
    if m.size:
        r = th.face_thickness[m] / th.width[m]
        order = np.lexsort((r, lab[m]))  # by piece, then by r (ties by face: stable)
        g = lab[m][order]
        bounds = np.flatnonzero(np.r_[True, g[1:] != g[:-1], True])
        for a, b in zip(bounds[:-1], bounds[1:], strict=True):
            cum = np.cumsum(face_area[m][order[a:b]])
            relative[g[a]] = r[order[a:b]][np.searchsorted(cum, 0.5 * cum[-1])]
    order = np.argsort(vlab, kind="stable")
    points = np.split(v[order], np.cumsum(np.bincount(vlab, minlength=count))[:-1])
    shapes = []
    for c in range(count):
        length = float(max(extents[c, 0], 1e-300))
        width, form = _form(extents[c], area[c], length, boundary_length[c], layered[c],
                            relative[c])
        rel = 0.0 if form == "sheet" else float(relative[c])
        shapes.append(_Shape(points[c], centroid[c], axes[c], extents[c], float(area[c]), length,
                             float(width), rel, float(layered[c]), form))
    return shapes


def _part_units(vertices: np.ndarray, faces: np.ndarray) -> tuple[list[_Shape], list, bool]:
    """How a part is judged: ``(units, face masks, alike)``.

    - one piece (crumbs aside): ``([], [], False)``, the part is judged whole;
    - 2 or more alike sheets or shells (``MAJOR`` of the largest piece's area or more;
      five petals in one group) and perhaps a few crumbs: those pieces, judged together
      (``alike``: the part gets their most common verdict);
    - else several unlike pieces (a whole flower in one mesh: petals, receptacle,
      stem): every piece over ``CRUMB`` of the largest, each judged on its own.

    ``face masks`` give each unit's faces, (F,) bool over ``faces``."""
    v = np.asarray(vertices, dtype=np.float64)
    welded, label, count = _piece_labels(v, faces)
    if count < 2:
        return [], [], False
    tri = v[np.asarray(faces, dtype=np.int64)]
    face_area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    area = np.bincount(label[label >= 0], weights=face_area[label >= 0], minlength=count)
    if area.max() <= 0:
        return [], [], False
    major = np.flatnonzero(area >= MAJOR * area.max())
    units = np.flatnonzero(area >= CRUMB * area.max())
    if units.size < 2:
        return [], [], False
    shapes = _measure_pieces(v, welded, label, count)
    alike = (major.size >= 2 and area[major].min() * ALIKE_AREA >= area.max()
             and all(shapes[c].form in ("sheet", "shell") for c in major))
    chosen = major if alike else units
    return [shapes[c] for c in chosen], [label == c for c in chosen], bool(alike)


def _welded_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces re-indexed so that vertices within the weld tolerance share an index
    (the first of each group), the vertex array itself unchanged."""
    from scipy.spatial import cKDTree

    v = np.asarray(vertices, dtype=np.float64)
    diag = float(np.linalg.norm(np.ptp(v[faces.ravel()], axis=0)))
    pairs = cKDTree(v).query_pairs(WELD * diag, output_type="ndarray") if diag > 0 else []
    if len(pairs) == 0:
        return faces
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    n = len(v)
    g = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, group = connected_components(g, directed=False)
    first = np.full(group.max() + 1, n)
    np.minimum.at(first, group, np.arange(n))
    return first[group][faces]


def _name_kind(name: str) -> str | None:
    words = set(re.findall(r"[a-z]+", name.lower()))
    found = {kind for key, kind in NAMES.items()
             if key in words or any(w.startswith(key) for w in words)}
    return found.pop() if len(found) == 1 else None


def _describe(s: _Shape) -> str:
    if s.form == "sheet":
        return f"an open sheet {s.width / s.length:.2f} as wide as long"
    if s.form == "shell":
        return (f"a thin shell ({s.thickness:.2f} of its width thick over {s.layered:.0%} of it), "
                f"{s.width / s.length:.2f} as wide as long")
    if s.form == "narrow":
        return f"long and narrow (mean width {s.width / s.length:.3f} of its length)"
    if s.form == "blob":
        return f"a compact blob ({s.extents[2] / s.length:.2f} as thick as long)"
    return f"a solid {s.width / s.length:.2f} as wide as long"


@dataclass
class _Frame:
    """The flower's axis and the petals' ring."""

    origin: np.ndarray  #: (3,) a point on the axis
    axis: np.ndarray  #: (3,) unit, up (from the base toward the petals)
    base: float  #: axial coordinate of the petals' base
    radius: float  #: median distance of the petals' centroids from the axis
    length: float  #: median length of a petal
    members: list  #: indices of the units in the ring
    how: str  #: how the ring was found, for the reasons
    whorl: dict = field(default_factory=dict)  #: member -> why, for petals of an inner whorl

    def base_point(self) -> np.ndarray:
        """(3,) where the petals' base meets the axis."""
        return self.origin + self.base * self.axis

    def axial(self, p: np.ndarray) -> np.ndarray:
        return (p - self.origin) @ self.axis

    def radial(self, p: np.ndarray) -> np.ndarray:
        d = p - self.origin
        return np.linalg.norm(d - (d @ self.axis)[..., None] * self.axis, axis=-1)


def _ring(units: list[_Shape], candidates: list[int]) -> _Frame | None:
    """The largest ring of at least three alike sheets or shells around a common axis.

    Each seed gathers the candidates alike it; a group that does not ring an axis sheds
    the member farthest from the group's median centroid (a leaf below) and is tried
    again. Seeds are at most ``RING_SEEDS`` candidates spread over the range of areas,
    and a group is tried once however many seeds gather it."""
    best = None
    seeds = candidates
    if len(candidates) > RING_SEEDS:
        by_area = sorted(candidates, key=lambda k: (units[k].area, k))
        seeds = [by_area[i] for i in np.linspace(0, len(by_area) - 1, RING_SEEDS).round().astype(int)]
    log_area = np.log(np.array([units[k].area for k in candidates]))
    log_length = np.log(np.array([units[k].length for k in candidates]))
    tried = set()
    for c in seeds:
        a, length = np.log(units[c].area), np.log(units[c].length)
        near = ((np.abs(log_area - a) < np.log(ALIKE_AREA) / 2)
                & (np.abs(log_length - length) < np.log(ALIKE_LENGTH) / 2))
        group = [candidates[j] for j in np.flatnonzero(near)]
        if tuple(group) in tried:
            continue
        tried.add(tuple(group))
        frame = None
        while len(group) >= 3 and (frame := _fit_ring(units, group)) is None:
            p = np.array([units[k].centroid for k in group])
            group.pop(int(np.argmax(np.linalg.norm(p - np.median(p, axis=0), axis=1))))
        if frame is None:
            continue
        key = (len(group), sum(units[k].area for k in group))
        if best is None or key > best[0]:
            best = (key, frame)
    return best[1] if best else None


def _whorls(units: list[_Shape], group: list[int], frame: _Frame) -> None:
    """Add to ``frame.members`` (in place) the inner whorls of a flower's ``group`` of
    sheets: further rings of alike sheets around nearly the same axis (within
    ``WHORL_DEGREES``), at or above the petals' base (a water lily's petals come in
    whorls of shrinking size; a ring hanging below the base is left to be placed)."""
    rest = [k for k in group if k not in frame.members]
    while len(rest) >= 3:
        whorl = _ring(units, rest)
        if whorl is None:
            return
        level = float(np.median([frame.axial(units[k].centroid) for k in whorl.members])) - frame.base
        if (abs(float(whorl.axis @ frame.axis)) >= np.cos(np.radians(WHORL_DEGREES))
                and level >= -0.05 * frame.length):
            frame.members = list(frame.members) + list(whorl.members)
            for k in whorl.members:
                frame.whorl[k] = (f"one of {len(whorl.members)} alike in a whorl around the "
                                  "flower's axis")
        rest = [k for k in rest if k not in whorl.members]


def _whole_parts(units: list[_Shape], candidates: list[int], owner: list[int]) -> dict:
    """``{part: flower}`` for the parts whose own candidates (three or more) ring an axis
    (:func:`_ring`): a blossom in one mesh. Parts whose rings share an axis (each ring's
    base within ``COAXIAL`` of a petal length of the other's axis, the axes within
    ``WHORL_DEGREES``) are one flower's whorls, numbered by the first of them."""
    mine: dict[int, list[int]] = {}
    for k in candidates:
        mine.setdefault(owner[k], []).append(k)
    if len(mine) < 2:
        return {}
    rings = {i: ring for i, ks in mine.items() if len(ks) >= 3
             and (ring := _ring(units, ks)) is not None}
    if len(rings) < 2:
        return {}
    from scipy.spatial import cKDTree

    found = sorted(rings)
    centre = np.array([rings[i].base_point() for i in found])
    reach = COAXIAL * np.array([rings[i].length for i in found])
    flower = {i: i for i in found}
    # (whorls of one flower lie within a petal length of each other along the axis)
    for a, b in sorted(cKDTree(centre).query_pairs(2.0 * float(reach.max()) / COAXIAL)):
        ra, rb = rings[found[a]], rings[found[b]]
        if (ra.radial(centre[b]) < reach[a] and rb.radial(centre[a]) < reach[b]
                and abs(float(ra.axis @ rb.axis)) >= np.cos(np.radians(WHORL_DEGREES))):
            lo, hi = sorted((flower[found[a]], flower[found[b]]))
            flower = {i: lo if f == hi else f for i, f in flower.items()}
    return flower


def _frames(units: list[_Shape], candidates: list[int], several_parts: bool,
            whole: dict | None = None, owner: list[int] | None = None) -> list[_Frame]:
    """Each flower's frame: the candidates (sheets and shells) grouped into flowers by
    where their bases gather (:func:`pipeline.mesh.flowers.flowers`; the pieces of two
    parts that are flowers on their own, ``whole`` by part of ``owner``, never one), the
    ring of each flower (:func:`_ring`) with its inner whorls. Where no flower has a
    ring, the ring of all the candidates, else (a file of several parts) a part that is
    a whole ring."""
    from pipeline.mesh.flowers import flowers

    if not candidates:
        return []
    points = np.vstack([units[k].vertices for k in candidates])
    label = np.concatenate([np.full(len(units[k].vertices), j) for j, k in enumerate(candidates)])
    known = None
    if whole:
        known = np.array([whole.get(owner[k], -1) for k in candidates], dtype=np.int64)
    grouped = flowers(points, label, whole=known)
    frames = []
    for g in range(grouped.count):
        group = [candidates[j] for j in np.flatnonzero(grouped.flower == g)]
        frame = _ring(units, group) if len(group) >= 3 else None
        if frame is not None:
            _whorls(units, group, frame)
            frames.append(frame)
    if frames:
        return frames
    frame = _ring(units, candidates) or (_round_part(units, candidates) if several_parts else None)
    return [frame] if frame is not None else []


def _frame_of(units: list[_Shape], frames: list[_Frame]) -> list:
    """The frame each unit is placed by: its own flower's, else the nearest flower's (by
    the distance from its centroid to the flower's base, in that flower's petal
    lengths); None when there is no frame."""
    if not frames:
        return [None] * len(units)
    owner = {k: i for i, fr in enumerate(frames) for k in fr.members}
    base = np.array([fr.base_point() for fr in frames])
    length = np.array([fr.length for fr in frames])
    out = []
    for u, s in enumerate(units):
        if u in owner:
            out.append(frames[owner[u]])
            continue
        d = np.linalg.norm(base - s.centroid, axis=1) / np.maximum(length, 1e-300)
        out.append(frames[int(np.argmin(d))])
    return out


def _fit_ring(units: list[_Shape], group: list[int]) -> _Frame | None:
    p = np.array([units[k].centroid for k in group])
    centre = p.mean(axis=0)
    _, _, vt = np.linalg.svd(p - centre, full_matrices=False)
    normal = vt[2]
    d = p - centre
    radial_vec = d - np.outer(d @ normal, normal)
    radius = np.linalg.norm(radial_vec, axis=1)
    lengths = np.array([units[k].length for k in group])
    if radius.mean() < 0.05 * np.median(lengths) or radius.std() > RING_SPREAD * radius.mean():
        return None
    unit_dirs = radial_vec / radius[:, None]
    if np.linalg.norm(unit_dirs.mean(axis=0)) > 0.5:  # all to one side: not around an axis
        return None
    frame = _Frame(centre, normal, 0.0, float(np.median(radius)), float(np.median(lengths)),
                   list(group), f"one of {len(group)} alike ringed around the flower's axis")
    bases = []
    for k in group:
        v = units[k].vertices
        bases.append(frame.axial(v[np.argmin(frame.radial(v))]))
    return _orient(frame, float(np.median(bases)), frame.axial(p).mean())


def _orient(frame: _Frame, base: float, centre: float) -> _Frame:
    """Point the axis from the base toward the petals (kept as fitted if they are flat)."""
    if centre < base - 0.05 * frame.length:
        frame.axis = -frame.axis
        base, centre = -base, -centre
    frame.base = base
    return frame


def _round_part(units: list[_Shape], candidates: list[int]) -> _Frame | None:
    """A single part that is a whole ring of petals (round in plan)."""
    round_ = [k for k in candidates if units[k].extents[1] >= ROUND * units[k].extents[0]]
    if not round_:
        return None
    k = max(round_, key=lambda k: units[k].area)
    s = units[k]
    frame = _Frame(s.centroid, s.axes[2], 0.0, 0.25 * s.length, 0.5 * s.length, [k],
                   "the largest thin part, round in plan: the petals in one piece")
    v = s.vertices
    r = frame.radial(v)
    near = r <= 0.1 * r.max() + 1e-12
    return _orient(frame, float(np.median(frame.axial(v[near]))), float(frame.axial(v).mean()))


def voxel_cubes(vertices: np.ndarray, faces: np.ndarray) -> tuple[int, float] | None:
    """``(cubes, side)`` when a part is voxel art: every face axis-aligned and every vertex
    on one cubic lattice, with more than one cube's worth of lattice points; else None."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(f) < 12:
        return None
    v = v[np.unique(f)]
    fn = topology.face_normals(np.asarray(vertices, dtype=np.float64), f)
    n = np.abs(fn) / np.maximum(np.linalg.norm(fn, axis=1), np.finfo(float).tiny)[:, None]
    if n.max(axis=1).min() < 1.0 - 1e-6:
        return None
    size = float(np.ptp(v, axis=0).max())
    steps = []
    for axis in range(3):
        u = np.unique(v[:, axis])
        gaps = np.diff(u)
        if gaps.size == 0 or gaps.min() <= 1e-9 * size:
            return None
        steps.append(gaps.min())
    step = min(steps)
    if max(steps) > step * (1 + 1e-6):
        return None
    k = (v - v.min(axis=0)) / step
    if np.abs(k - np.round(k)).max() > 1e-4:
        return None
    points = len(np.unique(np.round(k).astype(np.int64), axis=0))
    if points <= 8:
        return None
    return max(1, len(f) // 12), step


#: what a forked worker measures parts from (inherited, not sent): ``(part, split)``
_TASKS: list | None = None


def _measured(k: int):
    """Part ``k`` of :data:`_TASKS` measured: ``(pieces, their face masks, alike)``, its
    pieces (``split``) or the part whole."""
    part, split = _TASKS[k]
    v, f = np.asarray(part.vertices, dtype=np.float64), np.asarray(part.faces)
    pieces, piece_masks, same = _part_units(v, f) if split else ([], [], False)
    if not pieces:
        pieces, piece_masks = [_measure(v, f)], [None]
    return pieces, piece_masks, same


def _each_measured(tasks: list, workers: int) -> list:
    """:func:`_measured` of every task, in order, in ``workers`` processes
    (:func:`pipeline.forks.each`)."""
    global _TASKS
    _TASKS = tasks
    try:
        return list(forks.each(_measured, len(tasks), workers))
    finally:
        _TASKS = None


def classify(parts, workers: int = 1) -> list[Verdict]:
    """Tell each part of a flower model what it is.

    Parameters
    ----------
    parts : sequence of objects with ``name``, ``vertices (V, 3)`` and ``faces (F, 3)``
        (:class:`pipeline.io.meshfile.Part`), in any units.
    workers : processes to measure the parts in (:mod:`pipeline.forks`).

    Returns
    -------
    list of Verdict
        One per part, in order: ``kind`` in ``KINDS``, ``reason`` a short phrase with
        the measurements.

    Notes
    -----
    Deterministic, and scale-free: a model in centimetres and the same in metres get
    the same verdicts. A part made of several alike sheets (five petals in one OBJ
    group) is judged as those petals, and is a petal if they are. See the module notes
    for the rules and thresholds.
    """
    parts = list(parts)
    hinted = [_name_kind(p.name) for p in parts]
    # units: parts, or their pieces (alike petals in one group, or a whole flower's parts)
    units: list[_Shape] = []
    owner: list[int] = []
    masks: list = []
    alike: list[bool] = []
    seen: dict = {}  # parts measured (split or not), for their copies
    copies: list = []
    for i, p in enumerate(parts):
        v, f = np.asarray(p.vertices, dtype=np.float64), np.asarray(p.faces)
        split = hinted[i] in (None, "petal")  # a name that decides the kind needs no pieces
        # a part that is a moved, turned or scaled copy of an earlier one (instanced
        # blossoms) is measured as that one, moved
        mine = seen.setdefault(split, Copies())
        copy = mine.find(v, f)
        if copy is None:
            mine.add(v, f, i)
        copies.append(copy)
    own = [i for i in range(len(parts)) if copies[i] is None]
    done = dict(zip(own, _each_measured([(parts[i], hinted[i] in (None, "petal")) for i in own],
                                        workers), strict=True))
    measured: list = []
    for i in range(len(parts)):
        if copies[i] is not None:
            j, k, rot, t = copies[i]
            pieces = [_moved_shape(shape, k, rot, t) for shape in measured[j][0]]
            piece_masks, same = measured[j][1], measured[j][2]
        else:
            pieces, piece_masks, same = done[i]
        measured.append((pieces, piece_masks, same))
        units += pieces
        masks += piece_masks
        owner += [i] * len(pieces)
        alike.append(same)
    mine_of: dict[int, list[int]] = {}
    for u, i in enumerate(owner):
        mine_of.setdefault(i, []).append(u)
    candidates = [u for u, s in enumerate(units)
                  if s.form in ("sheet", "shell") and hinted[owner[u]] in (None, "petal")]
    # where the file names its petals, its flowers are theirs (a tuft of grass also rings
    # an axis)
    named = [u for u in candidates if hinted[owner[u]] == "petal"]
    # a part whose own pieces ring an axis is a flower of its own: a branch's blossoms,
    # a few millimetres apart, are not grouped into one by their bases
    whole = _whole_parts(units, named or candidates, owner)
    frames = _frames(units, named, len(parts) > 1, whole, owner) if named else []
    frame_of = _frame_of(units, frames or _frames(units, candidates, len(parts) > 1, whole,
                                                  owner))

    verdicts = []
    for i, p in enumerate(parts):
        voxels = voxel_cubes(p.vertices, p.faces)
        if voxels is not None:
            verdicts.append(Verdict("other", f"voxel cubes (up to {voxels[0]} cubes of side "
                                             f"{voxels[1]:.3g}, every face on one lattice): voxel art "
                                             "has no petal surfaces to simulate"))
            continue
        mine = mine_of[i]
        if hinted[i] is not None:
            kind = hinted[i]
            forms = {units[u].form for u in mine}
            if kind == "petal" and "shell" in forms:
                kind = "thick petal"
            verdicts.append(Verdict(kind, f"named {p.name!r}; {_describe(units[mine[0]])}"))
            continue
        if len(mine) == 1:
            verdicts.append(Verdict(*_place(units, mine[0], frame_of[mine[0]])))
            continue
        kinds = [_place(units, u, frame_of[u]) for u in mine]
        petal = [k in PETAL_KINDS for k, _ in kinds]
        # several alike petals in one part take their most common verdict, unless the
        # pieces that are not petals sit at the hub (a blossom's disc, its stamens)
        hub = any(petal) and all(k in HUB_KINDS for (k, _), is_petal in zip(kinds, petal, strict=True)
                                 if not is_petal)
        if (alike[i] and not hub) or all(petal) or not any(petal):
            kind = max(set(k for k, _ in kinds), key=lambda k: (sum(1 for q, _ in kinds if q == k), k))
            why = next(r for k, r in kinds if k == kind)
            verdicts.append(Verdict(kind, f"{len(mine)} pieces; {why}"))
            continue
        # a whole flower in one mesh: its petal pieces are the petals, the rest is kept
        faces = np.zeros(len(p.faces), dtype=bool)
        for u, is_petal in zip(mine, petal, strict=True):
            if is_petal:
                faces |= masks[u]
        kind = "thick petal" if any(k == "thick petal" for k, _ in kinds) else "petal"
        tally = {}
        for k, _ in kinds:
            tally[k] = tally.get(k, 0) + 1
        others = ", ".join(f"{n} {k}" for k, n in sorted(tally.items()) if k not in PETAL_KINDS)
        why = next(r for (k, r), is_petal in zip(kinds, petal, strict=True) if is_petal)
        verdicts.append(Verdict(kind, f"a whole flower in one mesh ({len(mine)} pieces): "
                                      f"{sum(petal)} petals ({why}); {others}", faces))
    return [replace(v, whole=whole[i]) if i in whole else v for i, v in enumerate(verdicts)]


def _place(units: list[_Shape], u: int, frame: _Frame | None) -> tuple[str, str]:
    """Kind and reason of one unit from its form and where it sits in the flower."""
    s = units[u]
    what = _describe(s)
    petal = "thick petal" if s.form == "shell" else "petal"
    if frame is None:
        if s.form in ("sheet", "shell"):
            return petal, f"{what}; no ring of petals, so taken for a lone petal"
        return "other", f"{what}; no ring of petals to place it by"
    L = frame.length
    v = s.vertices
    axial = frame.axial(v) - frame.base
    below, above = float(max(-axial.min(), 0.0)), float(max(axial.max(), 0.0))
    centre_axial = float(frame.axial(s.centroid) - frame.base)
    centre_radial = float(frame.radial(s.centroid))
    attach = float(frame.radial(v).min())
    on_axis = centre_radial <= max(0.5 * s.width, ON_AXIS * L)
    if u in frame.members:
        return petal, (f"{what}, {frame.whorl.get(u, frame.how)}, attached {attach / L:.2f} of "
                       "its length from the axis")
    if (s.form == "shell" and on_axis and s.extents[1] >= ROUND * s.length
            and s.length < 0.7 * L and abs(centre_axial) < 0.5 * L):
        return "receptacle", (f"{what}, round, on the flower's axis at the petals' base, "
                              f"{s.length / L:.2f} of a petal's length")
    if (s.form == "sheet" and on_axis and s.extents[1] >= ROUND * s.length
            and s.length < 0.7 * L and abs(centre_axial) < 0.3 * L
            and s.extents[2] <= FLAT * s.extents[1] and abs(s.axes[2] @ frame.axis) >= FACING
            and s.area >= FILLS * s.extents[0] * s.extents[1]):
        return "receptacle", (f"{what}, a round disc facing along the flower's axis at the "
                              f"petals' base, {s.length / L:.2f} of a petal's length")
    if s.form in ("sheet", "shell"):
        level = abs(centre_axial - float(np.median([frame.axial(units[m].centroid) - frame.base
                                                    for m in frame.members])))
        if (0.5 * frame.radius <= centre_radial <= 1.6 * frame.radius and level < 0.5 * L
                and attach < 0.5 * L and s.length > 0.5 * L):
            return petal, f"{what}, level with the ring of petals ({centre_radial / frame.radius:.2f} " \
                          "of its radius from the axis)"
        if s.length < 0.7 * L and attach < 0.3 * L and -0.3 * L < centre_axial < 0.3 * L:
            return "sepal", (f"{what}, {s.length / L:.2f} of a petal's length, at the petals' base "
                             f"({centre_axial / L:+.2f} petal lengths along the axis)")
    if on_axis or s.form not in ("sheet", "shell"):
        return _place_solid(s, what, frame, below, above, centre_axial, centre_radial, on_axis)
    return "leaf", (f"{what}, off the ring of petals ({centre_axial / L:+.2f} petal lengths "
                    f"along the axis from their base, {centre_radial / L:.2f} from the axis)")


def _place_solid(s: _Shape, what: str, frame: _Frame, below: float, above: float,
                 centre_axial: float, centre_radial: float, on_axis: bool) -> tuple[str, str]:
    L = frame.length
    if on_axis:
        if s.form == "blob" and s.length < 0.3 * L and abs(centre_axial) < 0.5 * s.length:
            return "receptacle", (f"{what} on the flower's axis at the petals' base, "
                                  f"{s.length / L:.2f} of a petal's length")
        if below > above and below > 0.1 * L:
            return "stem", (f"{what} on the flower's axis, reaching {below / L:.2f} petal lengths "
                            "below the petals' base")
        if above >= below and above > 0.1 * L:
            return "pistil", (f"{what} on the flower's axis, reaching {above / L:.2f} petal lengths "
                              "above the petals' base")
        return "other", f"{what} on the flower's axis"
    if centre_axial > 0 and centre_radial < frame.radius + 0.5 * L:
        return "stamen", (f"{what}, off the axis ({centre_radial / L:.2f} petal lengths) inside the "
                          f"ring of petals, {centre_axial / L:+.2f} above their base")
    if centre_axial < 0 and s.form == "narrow":
        return "stem", f"{what}, below the petals' base ({centre_axial / L:+.2f} petal lengths)"
    return "other", (f"{what}, {centre_radial / L:.2f} petal lengths from the axis and "
                     f"{centre_axial / L:+.2f} along it from the petals' base")


def select(names, kinds, petals_globs=(), exclude_globs=()) -> list[bool]:
    """Which parts are petals: the verdict, overridden by the scene's globs.

    Parameters
    ----------
    names : sequence of str
        The parts' names.
    kinds : sequence of str or Verdict
        The verdicts of :func:`classify` (or their kinds).
    petals_globs, exclude_globs : sequence of str
        ``scene.petals`` and ``scene.exclude``: fnmatch patterns over part names
        (case-sensitive). A part matching ``petals_globs`` is a petal whatever its
        verdict; a part matching ``exclude_globs`` is never one (exclude wins).

    Returns
    -------
    list of bool, one per part.
    """
    out = []
    for name, kind in zip(names, kinds, strict=True):
        kind = getattr(kind, "kind", kind)
        chosen = kind in PETAL_KINDS or any(fnmatch.fnmatchcase(name, g) for g in petals_globs)
        out.append(chosen and not any(fnmatch.fnmatchcase(name, g) for g in exclude_globs))
    return out
