"""From a user's mesh to clean, isotropic, symmetric petal sheets at mean edge 1.

The remesh stage's work, :func:`prepare_parts`, on a file's named parts:

1. classify the parts (petal sheets, thick petals, whole flowers in one mesh, flowers of
   a file of many; receptacles, stems, leaves and stamens kept in place) and clean each
   petal part on its own (weld, drop dust and degenerate faces, orient; a thick petal
   replaced by its mid-surface); every part that cannot be simulated is named in one
   error;
2. split each petal part into its petals;
3. scale so the mean edge is 1;
4. per petal: find the center plane; remesh to the target edge (boundary included);
   make the petal mirror-symmetric about its plane;
5. scale again so the result's mean edge is exactly 1.

The module is long because a user's file is judged part by part before any sheet is
remeshed: the judging (closed, thick, lobed, a ring of petals) and the remeshing share
the per-part records that make one error message name every bad part.
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass, field

import numpy as np

from pipeline import forks
from pipeline.config import KEYS
from pipeline.errors import BloomError
from pipeline.mesh import clean, remesh, repair, symmetry, topology
from pipeline.mesh.similar import Copies

#: how close to the center plane (in mean edges) a vertex is snapped onto it before the
#: cut, with and without a remesh after (remeshed souki202: 0.05 gives min angle 6.0
#: deg, 0.1 gives 1.5, 0.2 gives 0.35)
SNAP, SNAP_REMESHED = 0.2, 0.05
#: a sharp rim corner (the tip) this close to the plane (in mean edges) goes onto it before
#: a remesh (souki202's needle tips, 0.15 off the plane, made a 142 deg notch between two
#: tips whose one triangle cannot have both other angles at 20 deg)
SNAP_CORNER = 0.5
#: a petal with fewer vertices than this (and no remesh.target_edge or petal_vertices set)
#: is remeshed to about this many: a coarse model has too few hinges to bend smoothly
MIN_PETAL_VERTICES = 100
#: ... but not past this many vertices in all for the file's coarse petals (a branch of a
#: thousand blossoms of a few vertices a petal would become half a million vertices):
#: then each coarse petal is remeshed to this over the petal count, never below its own
COARSE_BUDGET = 50_000
#: the default of remesh.max_petal_vertices: a petal with more vertices than this (and no
#: remesh.target_edge or petal_vertices set) is remeshed to about this many: the shell's
#: bloom converges from about 200 vertices a petal (docs/shell.md), so a studio's dense
#: petal (the tulip's 3,500) costs minutes of simulate and changes no shape; the user's
#: own mesh keeps its detail through the binding
MAX_PETAL_VERTICES = KEYS["remesh.max_petal_vertices"].default
DUST = 0.01  #: connected pieces under this fraction of their part's area are dropped
LAYERED = 0.5  #: a sheet this much of whose area has a second layer behind it is a slab
#: a mid-surface must cover at least this fraction of half its shell's area (a shell's
#: two sides each have about half): less, and it is a few faces left over, not a petal
MIN_MID_AREA = 0.25
#: a folded or degenerate triangle under this fraction of the median area is refused
FLAT_AREA = 0.01


@dataclass
class Petals:
    vertices: np.ndarray  #: (V, 3) mean edge 1
    faces: np.ndarray  #: (F, 3)
    petal: np.ndarray  #: (V,) petal id
    plane: np.ndarray  #: (P, 4) center plane of each petal (unit normal, offset)
    scale: float  #: mesh units per input unit
    asymmetry_before: np.ndarray  #: (P,) RMS mirror distance before, in output units
    asymmetry_after: np.ndarray  #: (P,)
    report: clean.CleanReport
    edge_target: np.ndarray  #: (P,) remesh target edge in input units (0: not remeshed)
    dropped: list = field(default_factory=list)  #: descriptions of parts left out
    notes: list = field(default_factory=list)  #: one line per thing worth telling
    #: petals that could not be made mirror-symmetric (symmetrize asked): a later stage can
    #: turn on the center-plane constraint for them
    unsymmetrized: list = field(default_factory=list)
    min_angle: np.ndarray = None  #: (P,) smallest angle per petal, corners excepted (remesh.quality)
    part: np.ndarray = None  #: (V,) the input part each vertex came from
    thickness: np.ndarray = None  #: (V,) mid-surface thickness in output units (0: a sheet)
    parts: list = field(default_factory=list)  #: per input part: {name, kind, reason, role}
    kept_parts: dict = field(default_factory=dict)  #: input index -> (vertices, faces), not petals
    #: input index -> (vertices, faces) of the petal sheets ``scene.flower`` left out (the
    #: other flowers of a part that holds several; input units): their pieces of the
    #: user's mesh stay where they are
    unpicked: dict = field(default_factory=dict)
    flower: np.ndarray = None  #: (V,) the flower each vertex's petal belongs to
    petal_flower: np.ndarray = None  #: (P,) the flower of each petal
    flower_centre: np.ndarray = None  #: (K, 3) where each flower's petal bases gather (output units)
    flower_picked: int = -1  #: the flower scene.flower kept (its index among all), -1: all
    #: part name -> {pieces, petals, area_kept, area_in (input units, one side), lost}
    found: dict = field(default_factory=dict)
    kept_sheets: list = field(default_factory=list)  #: the input sheet of each petal (others left out)
    #: (V,) the vertices of the rims a cut made (the parts of petals buried in others cut
    #: away, :meth:`keep_faces`): where such a petal leaves the centre, its base; None: no cut
    cut_rim: np.ndarray = None

    def keep_faces(self, keep: np.ndarray) -> None:
        """Keep the faces ``keep`` (F,) bool and the vertices they use, in place (every
        per-vertex array follows; the petals keep their numbers); the rims the cut makes
        are :attr:`cut_rim`."""
        rim = topology.boundary_vertices(self.faces, len(self.vertices))
        used, new = topology.used_vertices(self.faces[keep], len(self.vertices))
        self.faces = new[self.faces[keep]].astype(self.faces.dtype)
        for name in ("vertices", "petal", "part", "thickness", "flower", "cut_rim"):
            value = getattr(self, name)
            if value is not None:
                setattr(self, name, value[used])
        made = topology.boundary_vertices(self.faces, len(self.vertices)) & ~rim[used]
        self.cut_rim = made if self.cut_rim is None else self.cut_rim | made


def _build(v, f, petal, report, *, target_edge, petal_vertices, symmetrize, dropped=(),
           most: int = MAX_PETAL_VERTICES,
           labels=None, part_of=None, thick=None, notes=None, where: str = "",
           progress=None, workers: int = 1) -> Petals:
    """Steps 3 to 5 (see the module notes) on clean petal sheets ``v, f`` labelled ``petal``.

    ``labels[p]`` names petal ``p`` in the notes ("petal 3 (Cylinder04)"); ``part_of[p]`` is
    the input part it came from; ``thick[p]`` is None for a sheet, else ``(points, thickness)``
    of its mid-surface in input units (carried to the remeshed vertices by nearest point).
    The petals are done in ``workers`` processes (:func:`_each_petal`).
    """
    count = int(petal.max()) + 1
    labels = labels or [f"petal {p}" for p in range(count)]
    scale = 1.0 / clean.mean_edge_length(v, f)
    v = v * scale
    out_v, out_f, out_petal, planes, before, after, targets = [], [], [], [], [], [], []
    offset = 0
    notes = list(notes or [])
    out_part, out_thick = [], []
    unsymmetrized, quality, broken, kept = [], [], [], []
    groups = _groups(petal, f, count)
    least = min(MIN_PETAL_VERTICES, COARSE_BUDGET // max(count, 1))
    if least < MIN_PETAL_VERTICES and target_edge <= 0 and petal_vertices <= 0:
        notes.append(f"{count} petals: a coarse petal is remeshed to about {least} vertices, "
                     f"not {MIN_PETAL_VERTICES} ({COARSE_BUDGET} in all for the file; "
                     "remesh.petal_vertices sets it)")
    tasks = [(v[idx], lf, target_edge, petal_vertices, symmetrize, labels[p], scale, least, most)
             for p, (idx, lf) in enumerate(groups)]
    # a petal that is a copy of another (moved, turned, and scaled unless the target edge
    # is absolute) is remeshed once: instanced blossoms, a bush of one daisy's copies
    source = _copies([t[0] for t in tasks], [t[1] for t in tasks], scaled=target_edge <= 0)
    own = [p for p in range(count) if source[p] is None]
    done_own = {}
    for k, (p, done) in enumerate(zip(own, _each_petal([tasks[p] for p in own], workers),
                                      strict=True)):
        done_own[p] = done
        if progress is not None:
            progress("remeshing petals", k + 1, len(own), labels[p])
    copies = count - len(own)
    if copies:
        notes.append(f"{copies} of {count} petals are copies of others (moved, turned or "
                      f"scaled): remeshed once for each of {len(own)} shapes")
    for p in range(count):
        if source[p] is None:
            done = done_own[p]
        else:
            done = _moved(done_own[source[p][0]], *source[p][1:])
        notes += done["notes"]
        if done["broken"]:
            broken.append((labels[p], done["broken"]))
            continue
        pts, lf = done["vertices"], done["faces"]
        if symmetrize and not done["mirrored"]:
            unsymmetrized.append(len(out_v))
        quality.append(done["worst"])
        before.append(done["before"])
        after.append(done["after"])
        targets.append(done["h"])
        planes.append(done["plane"])
        out_v.append(pts)
        out_f.append(lf + offset)
        out_petal.append(np.full(len(pts), len(out_petal), dtype=np.int64))
        kept.append(p)
        out_part.append(np.full(len(pts), part_of[p] if part_of is not None else 0, dtype=np.int64))
        out_thick.append(_carried_thickness(pts, thick[p] if thick is not None else None, scale))
        offset += len(pts)
    if broken and not kept:
        raise BloomError(f"{len(broken)} petal(s) still fold after remeshing: "
                         + "; ".join(f"{label}: {why}" for label, why in broken)
                         + "; the sheet folds over itself (a mid-surface of a crumpled shell, or "
                         "a self-intersecting petal); repair it in the modelling tool, or leave "
                         "it out with scene.exclude", where=where)
    for label, why in broken:  # the others are simulated; these are lost petals
        notes.append(f"{label}: warning: left out: it still folds after remeshing ({why})")
    v, f = np.vstack(out_v), np.vstack(out_f)
    again = 1.0 / clean.mean_edge_length(v, f)
    planes = np.array(planes)
    planes[:, 3] *= again
    return Petals(v * again, f, np.concatenate(out_petal), planes, scale * again,
                  np.asarray(before) * again, np.asarray(after) * again, report,
                  np.asarray(targets) / scale, dropped=list(dropped), notes=notes,
                  unsymmetrized=unsymmetrized, min_angle=np.asarray(quality), kept_sheets=kept,
                  part=np.concatenate(out_part), thickness=np.concatenate(out_thick) * again)


def _each_petal(tasks: list, workers: int):
    """:func:`_one_petal` of every task, yielded in order: in this process, or (``workers``
    > 1, at least :data:`pipeline.forks.MANY` petals, and a system that forks) in a pool of
    forked processes. Each petal's result depends on the petal alone, so the output is
    the same bit for bit either way.

    Forked (:mod:`pipeline.forks`): what a worker runs (remeshing, numba kernels, k-d
    trees) starts no thread pool of its own that a fork could leave locked (Embree's,
    from the ray casts before, is not used)."""
    if workers <= 1 or len(tasks) < forks.MANY or not forks.can_fork():
        for task in tasks:
            yield _one_petal(*task)
        return
    with forks.pool(min(workers, len(tasks))) as pool:
        yield from pool.map(_one_task, tasks, chunksize=1)


#: what a forked worker cleans parts from (inherited from the parent, not sent): the
#: tasks ``(part, its faces, verdict, index)`` and the dust and closed-parts settings
_PART_TASKS: tuple | None = None


def _clean_part(k: int) -> _PartSheets:
    tasks, dust, closed_parts = _PART_TASKS
    part, part_faces, verdict, i = tasks[k]
    return _part_sheets(part, part_faces, verdict, i, dust=dust, closed_parts=closed_parts)


def _each_part(tasks: list, dust: float, closed_parts: str, workers: int):
    """:func:`_part_sheets` of every task ``(part, faces, verdict, index)``, yielded in
    order, in ``workers`` processes (:func:`pipeline.forks.each`: a part's outcome
    depends on the part alone)."""
    global _PART_TASKS
    _PART_TASKS = (tasks, dust, closed_parts)
    try:
        yield from forks.each(_clean_part, len(tasks), workers)
    finally:
        _PART_TASKS = None


def _copies(points: list, faces: list, scaled: bool) -> list:
    """For each sheet: None if it is remeshed itself, else ``(k, s, R, t)``: it is sheet
    ``k`` (an earlier one, remeshed itself) times ``s``, turned by ``R`` and moved by
    ``t`` (``s`` = 1 unless ``scaled``). Sheets are compared only when their faces are
    the same array (instanced copies are), by the best similarity transform
    (:class:`pipeline.mesh.similar.Copies`), reflections refused."""
    seen = Copies(scaled)
    out = []
    for p, (pts, lf) in enumerate(zip(points, faces, strict=True)):
        found = seen.find(pts, lf)
        if found is None:
            seen.add(pts, lf, p)
        out.append(found)
    return out


def _moved(done: dict, s: float, rot: np.ndarray, t: np.ndarray) -> dict:
    """A remeshed petal's result (:func:`_one_petal`) for a copy of it: moved as the copy
    is from the petal (its notes stay with the petal)."""
    if done["broken"]:
        return {"notes": [], "broken": done["broken"]}
    n = rot @ done["plane"][:3]
    plane = np.r_[n, s * done["plane"][3] + n @ t]
    return {**done, "vertices": s * done["vertices"] @ rot.T + t, "plane": plane,
            "h": s * done["h"], "before": s * done["before"], "after": s * done["after"],
            "notes": []}


def _one_task(task):
    return _one_petal(*task)


def _one_petal(pts, lf, target_edge, petal_vertices, symmetrize, label, scale,
               least: int = MIN_PETAL_VERTICES, most: int = MAX_PETAL_VERTICES) -> dict:
    """One petal (mean edge 1 units) through steps 4 and 5: its center plane, the remesh
    target, :func:`_petal`, and the checks after. Returns a dict: ``vertices``, ``faces``,
    ``plane``, ``h``, ``before``/``after`` (asymmetry), ``worst`` (smallest angle),
    ``mirrored``, ``notes``, and ``broken`` (why it is left out, or "")."""
    notes = []
    plane, err = symmetry.mirror_plane(pts)
    h = (target_edge * scale if target_edge > 0 else
         remesh.target_for_vertices(pts, lf, petal_vertices) if petal_vertices > 0 else 0.0)
    if h == 0.0 and len(pts) < least:  # a coarse model: too few hinges to bend
        h = remesh.target_for_vertices(pts, lf, least)
        notes.append(f"{label}: {len(pts)} vertices: remeshed to about {least} "
                     "(remesh.petal_vertices sets it)")
    elif h == 0.0 and 0 < most < len(pts):  # a studio's dense petal
        h = remesh.target_for_vertices(pts, lf, most)
        notes.append(f"{label}: {len(pts)} vertices: remeshed to about {most} "
                     "(remesh.max_petal_vertices sets it)")
    try:
        pts, lf, h, note, mirrored = _petal(pts, lf, plane, h, symmetrize, label, scale)
    except ValueError as exc:  # no sheet the remesher can take, nor the input's
        return {"notes": notes, "broken": _one_line(exc)}
    notes += note
    pts, lf, ears = remesh.drop_ears(pts, lf)
    if ears:
        notes.append(f"{label}: dropped {ears} ear(s) on its rim (a face on one vertex of its "
                     f"own, under {remesh.EAR_ANGLE:g} deg: growth would crush it)")
    pts, lf, folds = remesh.drop_rim_folds(pts, lf)
    if folds:
        notes.append(f"{label}: dropped {folds} face(s) on its rim folded over their "
                     "neighbours or through the petal, or around such a fold (a crumpled "
                     "tip or a tucked rim would pass through itself)")
    pts, lf, flaps = remesh.drop_flaps(pts, lf)
    if flaps:
        notes.append(f"{label}: dropped {flaps} face(s) joined to it by a vertex only (a flap "
                     "within a hair of the petal: it would fold through it)")
    try:  # what growth needs of a sheet: each edge of one or two faces, one orientation
        topology.hinges(lf)
    except ValueError as exc:
        return {"notes": notes, "broken": _one_line(exc)}
    face_quality = remesh.face_quality(pts, lf)
    worst = float(face_quality.min())  # remesh.quality
    area = 0.5 * np.linalg.norm(topology.face_normals(pts, lf), axis=1)
    bad = face_quality == 0.0  # inverted or degenerate
    flat = int(np.sum(bad & (area < FLAT_AREA * np.median(area))))
    if flat:  # its bending force is singular: the simulator gains energy from it
        return {"notes": notes, "broken": f"{flat} folded triangle(s) of almost no area"}
    if bad.any():
        notes.append(f"{label}: warning: {int(bad.sum())} triangle(s) folded over "
                     "their neighbours after remeshing")
    elif worst < remesh.MIN_ANGLE:
        notes.append(f"{label}: warning: smallest angle {worst:.1f} deg is still below "
                     f"{remesh.MIN_ANGLE:g} after remeshing")
    ratio = remesh.edge_ratio(pts, lf)
    if ratio < remesh.MIN_EDGE:
        notes.append(f"{label}: warning: shortest edge {ratio:.2f} of "
                     f"the mean is still below {remesh.MIN_EDGE:g} after remeshing")
    return {"vertices": pts, "faces": lf, "plane": plane, "h": h, "before": err,
            "after": symmetry.asymmetry(pts, plane) if symmetrize or h else err, "worst": worst,
            "mirrored": mirrored, "notes": notes, "broken": ""}


def _groups(label: np.ndarray, f: np.ndarray, count: int):
    """Each group's vertices and faces, for a mesh whose every face lies in one group of
    ``label (V,)``: ``[(vertex indices (ascending), its faces in local indices)]``, in one
    pass over the arrays (a mask per group would cost groups x vertices)."""
    v_order = np.argsort(label, kind="stable")
    v_bounds = np.r_[0, np.cumsum(np.bincount(label, minlength=count))]
    face_group = label[f[:, 0]]
    f_order = np.argsort(face_group, kind="stable")
    f_bounds = np.r_[0, np.cumsum(np.bincount(face_group, minlength=count))]
    out = []
    for p in range(count):
        idx = v_order[v_bounds[p]:v_bounds[p + 1]]
        out.append((idx, np.searchsorted(idx, f[f_order[f_bounds[p]:f_bounds[p + 1]]])))
    return out


def _carried_thickness(pts: np.ndarray, thick, scale: float) -> np.ndarray:
    """(len(pts),) thickness at a petal's (scaled) vertices: 0 for a sheet, else that of the
    nearest mid-surface vertex, in the same scaled units."""
    if thick is None:
        return np.zeros(len(pts))
    from scipy.spatial import cKDTree

    points, value = thick
    _, nearest = cKDTree(np.asarray(points) * scale).query(pts)
    return np.asarray(value, dtype=np.float64)[nearest] * scale


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _pieces(v: np.ndarray, f: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """A clean mesh's connected pieces, each ``(vertices, faces)``, in order of first vertex."""
    label = topology.components(f, len(v))
    return [(v[idx], lf) for idx, lf in _groups(label, f, int(label.max()) + 1)]


def _area(v: np.ndarray, f: np.ndarray) -> float:
    return 0.5 * float(np.linalg.norm(topology.face_normals(v, f), axis=1).sum())


def _is_closed(v: np.ndarray, f: np.ndarray) -> bool:
    return not topology.boundary_vertices(f, len(v)).any()


def _thick_sheets(v, f, pieces):
    """Mid-surfaces of a thick petal part: one per closed piece (several solidified petals in
    one group), else one of the whole part (two separate open sides). A piece with no
    mid-surface is sampled as a height field over its lobes (:func:`_lobe_sheets`).
    Returns ``([(vertices, faces, thickness)], lost)``, ``lost`` a line per piece that gave
    no sheet; raises ValueError with midsurface's reason when the part gives none."""
    if len(pieces) == 1 or not any(_is_closed(pv, pf) for pv, pf in pieces):
        return [_mid(v, f)], []
    made, failed = [], []
    for k, (pv, pf) in enumerate(pieces):
        try:
            made.append(_mid(pv, pf))
            continue
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            reason = _one_line(exc)
        try:  # no clean mid-surface: this piece's own height field
            lobe = _lobe_sheets(pv, pf)
        except ValueError:
            lobe = []
        if lobe:
            made += lobe
        else:
            failed.append(f"piece {k + 1} of {len(pieces)}: {reason}")
    if not made:
        raise ValueError("; ".join(failed))
    return made, failed


def _mid(v, f):
    from pipeline.mesh.midsurface import midsurface

    m = midsurface(v, f)
    sv, sf, t = _cleaned_sheet(m.vertices, m.faces, m.thickness)
    kept = _area(sv, sf) / max(0.5 * _area(v, f), 1e-300) if len(sf) else 0.0
    if kept < MIN_MID_AREA:  # (petals fused in one solid: a sheet for each pair of sides)
        m = midsurface(v, f, many=True)
        sv, sf, t = _cleaned_sheet(m.vertices, m.faces, m.thickness)
        kept = _area(sv, sf) / max(0.5 * _area(v, f), 1e-300) if len(sf) else 0.0
    if kept < MIN_MID_AREA:
        raise ValueError(f"its mid-surface covers only {kept:.0%} of one side ({len(sf)} faces); "
                         "the part is not two parallel sides (a low-poly cage, a crumpled or "
                         "self-intersecting shell?)")
    return sv, sf, t


def _sound_sheet(v: np.ndarray, f: np.ndarray) -> bool:
    """Whether a sheet is what the remesher and the hinges need: every edge of one or two
    faces, one orientation, a rim that passes each vertex once."""
    if len(f) == 0:
        return True
    try:
        topology.hinges(f)
    except ValueError:
        return False
    return remesh.pinched_rim(f, len(v)) == 0


def _cleaned_sheet(vertices, faces, thickness):
    """A made sheet cleaned (:func:`clean.clean_mesh`) with its per-vertex thickness carried
    to the vertices kept (matched by position: welding merges and reorders)."""
    from scipy.spatial import cKDTree

    sv, sf, _ = clean.clean_mesh(vertices, faces)
    if not _sound_sheet(sv, sf):
        # welding joined two parts of the made sheet that came within the weld distance (a
        # lotus petal's mid-surface touching itself: an edge of three faces, a rim through
        # a vertex twice, a twist no orientation fits); its points are its own, not welded
        sv, sf, _ = clean.clean_mesh(vertices, faces, weld_tolerance=0.0)
    if not _sound_sheet(sv, sf):
        sf, _ = repair.resolve_nonmanifold_edges(sv, sf)
        sf = sf[repair.manifold_fans(sf, len(sv))]
        sv, sf, _ = repair.split_fans(sv, sf)
        used = np.unique(sf)
        sv, sf = sv[used], np.searchsorted(used, sf)
        sf, _ = clean.orient_consistently(sf, len(sv))
    _, nearest = cKDTree(vertices).query(sv)
    return sv, sf, np.asarray(thickness)[nearest]


def _lobe_sheets(v, f):
    """Sheets of a petal part that has no mid-surface: one per lobe of the ring it makes
    (:func:`pipeline.mesh.lobes.lobes`; the hub where they join left out), each sampled as a
    height field (:func:`pipeline.mesh.heightfield.height_sheet`). Returns
    ``[(vertices, faces, thickness)]``, lobes under ``DUST`` of the largest left out;
    raises ValueError for a lobe that is two layers as far apart as a solid's
    (``MAX_RELATIVE_THICKNESS`` of its width: a box, a sphere, a block of voxels)."""
    from pipeline.mesh.heightfield import height_sheet
    from pipeline.mesh.lobes import lobes
    from pipeline.mesh.midsurface import MAX_RELATIVE_THICKNESS

    split = lobes(v, f)
    made = []
    for k in range(split.count):
        mine = (split.label == k) & (split.radius >= split.hub_radius)
        if not mine.any():
            continue
        h = height_sheet(v, f[mine])
        if h.two_sided and h.relative_thickness > MAX_RELATIVE_THICKNESS:
            raise ValueError(f"a solid: {h.relative_thickness:.2f} as thick as wide")
        sv, sf, t = _cleaned_sheet(h.vertices, h.faces, h.thickness)
        if len(sf):
            made.append((sv, sf, t))
    areas = np.array([_area(sv, sf) for sv, sf, _ in made])
    return [m for m, a in zip(made, areas, strict=True) if a >= DUST * areas.max()] if made else []


#: the petals of a ring split from one sheet differ in area by at most this factor
ALIKE_LOBES = 4.0


def _ring_petals(v, f):
    """The petals of one sheet that is a ring of them joined at a hub
    (:func:`pipeline.mesh.lobes.lobes`), or None when it is not (fewer than three lobes, or
    lobes unlike in area by more than ``ALIKE_LOBES``). The hub is left out, and so is
    every face touching a vertex of another petal, so that no two petals share a point."""
    from pipeline.mesh.lobes import lobes

    split = lobes(v, f)
    if split.count < 3:
        return None
    d = v - split.centre
    radius = np.linalg.norm(d - np.outer(d @ split.axis, split.axis), axis=1)
    # cut along the mesh's own edges: a face is out when any corner is inside the hub
    label = np.where(radius[f].min(axis=1) >= split.hub_radius, split.label, -1)
    pairs = np.unique(np.stack([f[label >= 0].ravel(), np.repeat(label[label >= 0], 3)], 1), axis=0)
    shared = np.bincount(pairs[:, 0], minlength=len(v)) > 1
    ok = (label >= 0) & ~shared[f].any(axis=1)
    near_cut = radius[f].min(axis=1) < split.hub_radius + 3.0 * clean.mean_edge_length(v, f)
    out = []
    for k in range(split.count):
        mine = np.flatnonzero(ok & (label == k))
        for _ in range(8):  # teeth left along the cut: faces there with two edges on the rim
            _, he_edge, count = topology.unique_edges(f[mine])
            tooth = ((count[he_edge] == 1).reshape(3, -1).sum(axis=0) >= 2) & near_cut[mine]
            if not tooth.any() or tooth.all():
                break
            mine = mine[~tooth]
        if mine.size == 0:
            return None
        used = np.unique(f[mine])
        pieces = _pieces(v[used], np.searchsorted(used, f[mine]))
        out.append(max(pieces, key=lambda pc: _area(*pc)))
    areas = np.array([_area(pv, pf) for pv, pf in out])
    return out if areas.max() <= ALIKE_LOBES * areas.min() else None


@dataclass
class _Judged:
    name: str
    vertices: np.ndarray
    faces: np.ndarray


def _unique_faces(faces: np.ndarray) -> np.ndarray:
    """Faces without repeats of the same three vertices (whichever way wound), first kept."""
    f = np.asarray(faces, dtype=np.int64)
    _, first = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
    return f if len(first) == len(f) else f[np.sort(first)]


def prepare_parts(mesh_file, *, where: str, target_edge: float = 0.0, petal_vertices: int = 0,
                  max_petal_vertices: int = MAX_PETAL_VERTICES, symmetrize: bool = True,
                  closed_parts: str = "refuse", petals_globs=(),
                  exclude_globs=(), dust: float = DUST, flower: str = "all",
                  progress=None, workers: int = 1) -> Petals:
    """The remesh stage on a file's named parts (:func:`pipeline.io.meshfile.read_parts`).

    Each part is classified (:func:`pipeline.flower.classify.classify`) and chosen by the
    scene's globs (:func:`~pipeline.flower.classify.select`). A chosen part is cleaned on its
    own, loses its dust (connected pieces under ``dust`` of its area), and gives one sheet
    per connected piece; a thick petal (or a closed or two-layer piece) becomes its
    mid-surface. A part that holds a whole flower (petals, receptacle and stem in one mesh)
    gives its petal pieces only. The sheets are grouped into flowers
    (:func:`pipeline.mesh.flowers.flowers`); ``flower`` ("all", a flower's index, or a
    glob over part names: the flowers those parts' petals are in) keeps some. The sheets
    then go through steps 3 to 5 of :func:`prepare`. Parts that are not petals are
    returned untouched in ``kept_parts`` (and a whole flower's other pieces, under its
    index). ``progress(what, done, total, detail)``, if given, is called as the petals are
    done; ``workers`` processes remesh them (:func:`pipeline.forks.workers`).

    Raises one :class:`BloomError` naming every petal part that cannot be simulated (and,
    when no petal is left, what every part is).
    """
    from pipeline.flower.classify import classify, select
    from pipeline.mesh.flowers import flowers

    report = progress or (lambda what, done, total, detail="": None)
    parts = list(mesh_file.parts)
    # judged without stacked duplicate faces (a face written twice, either way round, would
    # close a sheet into a "solid"); the parts themselves are kept as read
    unique = [_unique_faces(p.faces) for p in parts]
    report("classifying parts", 0, len(parts))
    verdicts = classify([_Judged(p.name, p.vertices, u) for p, u in zip(parts, unique, strict=True)],
                        workers=workers)
    names = [p.name for p in parts]
    chosen = select(names, verdicts, petals_globs, exclude_globs)
    excluded = [not c and any(fnmatch.fnmatchcase(n, g) for g in exclude_globs)
                for n, c in zip(names, chosen, strict=True)]
    total = clean.CleanReport()
    sheets = []  # (vertices, faces, part index, thickness or None)
    hubs = []  # the sheets of one flower that one sheet joined at a hub gave
    problems, failing, dropped, notes, info = [], [], [], [], []
    found = {}  # part index -> {"pieces": petal pieces, "area": their area (one side), "lost": ...}
    rest = {}  # part index -> (vertices, faces): a whole flower's pieces that are not petals
    # the parts to clean: each a copy of an earlier one (instanced blossoms: then it gives
    # that part's sheets, moved) or cleaned itself, side by side in ``workers`` processes
    seen, plan, copies = {}, {}, 0  # plan: part index -> (its faces, copy found or None)
    for i, (part, verdict) in enumerate(zip(parts, verdicts, strict=True)):
        role = "petal" if chosen[i] else "excluded" if excluded[i] else "kept"
        info.append({"name": part.name, "kind": verdict.kind, "reason": _one_line(verdict.reason),
                     "role": role})
        if not chosen[i]:
            continue
        part_faces = part.faces
        if verdict.faces is not None and verdict.is_petal and not any(
                fnmatch.fnmatchcase(part.name, g) for g in petals_globs):
            # a whole flower in one mesh: its petal pieces are the petals, the rest is kept
            part_faces = unique[i][verdict.faces]
            rest[i] = (np.asarray(part.vertices), unique[i][~verdict.faces])
        mine = seen.setdefault(verdict.kind, Copies())
        copy = mine.find(part.vertices, part_faces)
        if copy is None:
            mine.add(part.vertices, part_faces, i)
        plan[i] = (part_faces, copy)
    tasks = [(parts[i], plan[i][0], verdicts[i], i) for i in plan if plan[i][1] is None]
    outcomes = {}
    for k, done in enumerate(_each_part(tasks, dust, closed_parts, workers)):
        report("cleaning petal parts", k, len(tasks), f"part {parts[tasks[k][3]].name!r}")
        outcomes[tasks[k][3]] = done
    for i, (part_faces, copy) in plan.items():
        part = parts[i]
        original = None if copy is None else outcomes[copy[0]]
        if original is not None and original.sheets and not original.problem:
            done = _moved_part(original, i, *copy[1:])
            copies += 1
        else:  # (itself; or a copy of a part that gave no sheet: cleaned itself too)
            done = outcomes[i] if copy is None else _part_sheets(
                part, part_faces, verdicts[i], i, dust=dust, closed_parts=closed_parts)
            notes += done.notes
        for name, value in vars(done.counts).items():
            if name != "notes":
                setattr(total, name, getattr(total, name) + value)
        hubs += [[len(sheets) + k for k in hub] for hub in done.hubs]
        sheets += done.sheets
        if done.found is not None:
            found[i] = done.found
        if done.problem:
            problems.append(done.problem)
            failing.append(part.name)
        if done.dropped:
            dropped.append(done.dropped)
            info[i]["role"] = "kept"  # carried forward untouched, as a part that is not a petal
            rest.pop(i, None)
    if copies:
        notes.append(f"{copies} petal part(s) are copies of others (moved, turned or scaled): "
                     "cleaned as those")
    if problems and sheets:
        raise BloomError(f"{len(problems)} petal part(s) cannot be simulated: " + "; ".join(problems)
                         + "; fix them, or leave them out with scene.exclude = ["
                         + ", ".join(f'"{name}"' for name in failing) + "]", where=where)
    if not sheets:
        others = [f"{d['name']}: {d['kind']} (not a petal{', excluded' if d['role'] == 'excluded' else ''}: "
                  f"{d['reason']})" for d in info if d["role"] != "petal"]
        hint = ("; name the petals with scene.petals = [\"glob\"]" if not problems else
                "; repair the part(s) named and export again, or name the petals with scene.petals")
        raise BloomError("no petals: " + "; ".join(problems + others) + hint, where=where)
    grouped = flowers(np.vstack([sv for sv, _, _, _ in sheets]),
                      np.concatenate([np.full(len(sv), k) for k, (sv, _, _, _) in enumerate(sheets)]),
                      joined=hubs, whole=np.array([verdicts[i].whole for _, _, i, _ in sheets],
                                                  dtype=np.int64))
    picked = _pick_flower(flower, grouped, [i for _, _, i, _ in sheets], names, where)
    unpicked: dict = {}
    if picked is not None:
        notes.append(f"scene.flower = {flower!r}: flower {picked} of {grouped.count} "
                     f"({int(np.sum(grouped.flower == picked))} petals)")
        keep = np.flatnonzero(grouped.flower == picked)
        for k in np.flatnonzero(grouped.flower != picked).tolist():
            sv, sf, i, _ = sheets[k]
            unpicked.setdefault(i, []).append((sv, sf))
        sheets = [sheets[k] for k in keep]
        sheet_flower = np.zeros(len(sheets), dtype=np.int64)
        centres = grouped.centre[[picked]]
    else:
        sheet_flower, centres = grouped.flower, grouped.centre
    offsets = np.cumsum([0] + [len(sv) for sv, _, _, _ in sheets])
    v = np.vstack([sv for sv, _, _, _ in sheets])
    f = np.vstack([sf + o for (_, sf, _, _), o in zip(sheets, offsets, strict=False)])
    petal = np.concatenate([np.full(len(sv), k, dtype=np.int64) for k, (sv, _, _, _) in enumerate(sheets)])
    labels = [f"petal {k} ({names[i]})" for k, (_, _, i, _) in enumerate(sheets)]
    result = _build(v, f, petal, total, target_edge=target_edge, petal_vertices=petal_vertices,
                    most=max_petal_vertices, where=where,
                    symmetrize=symmetrize, dropped=dropped, labels=labels,
                    part_of=[i for _, _, i, _ in sheets], thick=[t for _, _, _, t in sheets],
                    notes=notes, progress=report, workers=workers)
    result.parts = info
    result.kept_parts = {i: (np.asarray(p.vertices), np.asarray(p.faces))
                         for i, p in enumerate(parts) if info[i]["role"] != "petal"}
    result.kept_parts.update({i: pf for i, pf in rest.items() if len(pf[1])})
    result.unpicked = {i: topology.stack(got)[:2] for i, got in unpicked.items()}
    result.petal_flower = np.asarray(sheet_flower, dtype=np.int64)[result.kept_sheets]
    result.flower = result.petal_flower[result.petal]
    result.flower_centre = np.asarray(centres) * result.scale
    result.flower_picked = -1 if picked is None else int(picked)
    result.found = _petals_found(result, found, names, notes, picked is not None)
    return result


def _pick_flower(flower: str, grouped, sheet_part: list[int], names: list[str], where: str):
    """The flower ``scene.flower`` names: None for "all"; an index (0-based, in the order
    of the flowers' first petals); or a glob over part names: the one flower whose petals
    come from the parts it matches. Raises BloomError naming the key otherwise."""
    text = str(flower).strip()
    if text in ("", "all"):
        return None
    if text.lstrip("-").isdigit():
        k = int(text)
        if not 0 <= k < grouped.count:
            raise BloomError(f"scene.flower: {k} is not a flower here: the mesh has {grouped.count} "
                             f"flower(s), 0 to {grouped.count - 1}", where=where)
        return k
    hit = sorted({int(grouped.flower[k]) for k, i in enumerate(sheet_part)
                  if fnmatch.fnmatchcase(names[i], text)})
    if len(hit) != 1:
        have = ", ".join(sorted({names[i] for i in sheet_part})[:8])
        what = "no petal part" if not hit else f"parts in {len(hit)} flowers ({hit[:8]})"
        raise BloomError(f"scene.flower: {text!r} matches {what}; give a flower's index (0 to "
                         f"{grouped.count - 1}) or a petal part's name ({have}...)", where=where)
    return hit[0]


#: a petal part that keeps less than this share of its petal area (one side of a thick
#: petal) after remeshing has lost petals: a warning names it
MIN_AREA_KEPT = 0.5


def _petals_found(result: Petals, found: dict, names: list[str], notes: list,
                  picked: bool = False) -> dict:
    """Per petal part: petal pieces in, petals out, and the share of the input's petal
    area kept (sheet area over the pieces' area, one side of a thick one); a warning in
    ``notes`` for a part that lost pieces or kept under ``MIN_AREA_KEPT`` of its area
    (unless one flower was ``picked``: the others' petals are left out on purpose)."""
    area = np.zeros(len(names))
    count = np.zeros(len(names), dtype=np.int64)
    fn = topology.face_normals(result.vertices, result.faces)
    face_part = result.part[result.faces[:, 0]]
    np.add.at(area, face_part, 0.5 * np.linalg.norm(fn, axis=1) / result.scale ** 2)
    pairs = np.unique(np.stack([result.part, result.petal], axis=1), axis=0)
    count += np.bincount(pairs[:, 0], minlength=len(names))
    out = {}
    for i, rec in sorted(found.items()):
        share = float(area[i] / rec["area"]) if rec["area"] > 0 else 0.0
        out[names[i]] = {"pieces": rec["pieces"], "petals": int(count[i]), "area_kept": share,
                         "area_in": rec["area"], "lost": len(rec["lost"])}
        if not picked and (rec["lost"] or share < MIN_AREA_KEPT):
            notes.append(f"{names[i]}: warning: petals lost: {int(count[i])} petal(s) from "
                         f"{rec['pieces']} petal piece(s), {share:.0%} of its petal area kept")
    return out


@dataclass
class _PartSheets:
    """What :func:`_part_sheets` makes of one petal part."""

    sheets: list  #: [(vertices, faces, part index, thickness or None)], raw (before ring splits)
    counts: clean.CleanReport  #: what was repaired or dropped
    notes: list
    found: dict | None  #: {"pieces", "area" (one side), "lost"}, None if it gave no sheet
    problem: str = ""  #: why it cannot be simulated ("" if it can)
    dropped: str = ""  #: a closed part left out (remesh.closed_parts = "drop")
    #: the sheets (indices into ``sheets``) that one sheet joined at a hub gave: one
    #: flower each, however wide the hub left out
    hubs: list = field(default_factory=list)


def _moved_part(done: _PartSheets, i: int, k: float, rot: np.ndarray, t: np.ndarray) -> _PartSheets:
    """A cleaned part's outcome for a copy of it (part ``i``), moved as the copy is."""
    sheets = [(k * sv @ rot.T + t, sf, i, None if th is None else (k * th[0] @ rot.T + t, k * th[1]))
              for sv, sf, _, th in done.sheets]
    found = None if done.found is None else {**done.found, "area": k * k * done.found["area"]}
    return _PartSheets(sheets, done.counts, [], found, hubs=done.hubs)


def _part_sheets(part, part_faces, verdict, i: int, *, dust: float, closed_parts: str) -> _PartSheets:
    """One petal part cleaned (``part_faces`` of its vertices) and made into sheets, as
    :func:`prepare_parts` describes; a sheet of petals joined at a hub split into them, and
    slits zipped."""
    done = _raw_part_sheets(part, part_faces, verdict, i, dust=dust, closed_parts=closed_parts)
    sheets = []
    for sv, sf, _, t in done.sheets:  # petals joined in one sheet at a hub (a low-poly star)
        petals_of = _ring_petals(sv, sf)
        if petals_of is None:
            sheets.append((sv, sf, i, t))
            continue
        done.counts.ring_splits += 1
        done.notes.append(f"{part.name}: one sheet of {len(petals_of)} petals joined at a hub: "
                          "split into its petals, the hub left out")
        done.hubs.append(list(range(len(sheets), len(sheets) + len(petals_of))))
        sheets += [(pv, pf, i, t) for pv, pf in petals_of]
    for k, (sv, sf, _, t) in enumerate(sheets):
        sv, sf, zipped = repair.zip_slits(sv, sf)  # a sliver dropped in a mid-surface, a seam
        if zipped:
            done.counts.zipped_vertices += zipped
            done.notes.append(f"{part.name}: closed a slit in its sheet ({zipped} rim vertex "
                              "pair(s) merged)")
            sheets[k] = (sv, sf, i, t)
    done.sheets = sheets
    return done


def _raw_part_sheets(part, part_faces, verdict, i: int, *, dust: float,
                     closed_parts: str) -> _PartSheets:
    label = f"{part.name}"
    total = clean.CleanReport()
    notes = []
    v, f, cleaned = clean.clean_mesh(part.vertices, part_faces)
    for key in ("welded", "degenerate_faces", "duplicate_faces", "opposite_duplicate_faces",
                "unreferenced", "flipped_faces"):
        setattr(total, key, getattr(total, key) + getattr(cleaned, key))
    if len(f) == 0:
        return _PartSheets([], total, notes, None,
                           f"{label}: no triangles left after removing degenerate faces")
    _, _, count = topology.unique_edges(f)
    if np.any(count > 2):  # a rib or fin on the sheet, sheets welded along a seam
        bad = int(np.sum(count > 2))
        f, gone = repair.resolve_nonmanifold_edges(v, f)
        total.nonmanifold_edges += bad
        total.nonmanifold_faces += gone
        notes.append(f"{label}: {bad} non-manifold edges: kept the two faces the surface "
                     f"goes on through at each, dropped {gone} face(s)")
    v, f, copies = repair.split_fans(v, f)  # pieces touching at a vertex come apart
    total.split_vertices += copies
    pieces = _pieces(v, f)
    areas = np.array([_area(pv, pf) for pv, pf in pieces])
    # dust by the largest piece, not the part: a petal of a part of 250 is 0.4% of it
    small = areas < dust * areas.max()
    if small.any() and not small.all():
        total.dust_pieces += int(small.sum())
        total.dust_faces += int(sum(len(pieces[k][1]) for k in np.flatnonzero(small)))
        notes.append(f"{label}: dropped {int(small.sum())} piece(s) of dust (under {dust:.0%} "
                     "of its largest piece's area)")
        pieces = [pc for pc, s in zip(pieces, small, strict=True) if not s]
        areas = areas[~small]
        keep = np.concatenate([pv for pv, _ in pieces])
        v, f = keep, np.vstack([pf + o for (_, pf), o in
                                zip(pieces, np.cumsum([0] + [len(pv) for pv, _ in pieces[:-1]]),
                                    strict=True)])
    # told by the cleaned geometry: a closed or two-layer piece, or (a thick petal's two
    # separate sides) a part of several pieces that is two layers; a stacked duplicate
    # that made the verdict "thick" is gone by now
    thick = any(_is_closed(pv, pf) or clean.layered_fraction(pv, pf)[0] > LAYERED
                for pv, pf in pieces)
    if not thick and verdict.kind == "thick petal" and len(pieces) == 2:
        # two separate open sides; a part of many petals that cross one another (a rose
        # bed's) is not two layers of one petal
        thick = clean.layered_fraction(v, f)[0] > LAYERED
    # the input's petal area: one side of a thick petal (its mid-surface covers that)
    found = {"pieces": len(pieces), "area": float(areas.sum()) * (0.5 if thick else 1.0),
             "lost": []}
    if not thick:
        return _PartSheets([(pv, pf, i, None) for pv, pf in pieces], total, notes, found)
    try:
        made, lost = _thick_sheets(v, f, pieces)
        if lost:
            found["lost"] = lost
            notes.append(f"{label}: warning: {len(lost)} of {len(pieces)} petal piece(s) gave no "
                         "sheet, left out: " + "; ".join(lost))
    except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
        try:  # no clean mid-surface: a coarse cage, hems, petals joined at a hub
            made = _lobe_sheets(v, f)
        except ValueError:
            made = None
        if made:
            total.height_sheets += len(made)
            notes.append(f"{label}: no mid-surface ({_one_line(exc)}); simulated as "
                         f"{len(made)} sheet(s) sampled over its lobes")
            return _PartSheets([(sv, sf, i, (sv, t)) for sv, sf, t in made], total, notes, found)
        if closed_parts == "drop" and all(_is_closed(pv, pf) for pv, pf in pieces):
            return _PartSheets([], total, notes, None, dropped=(
                f"{part.name} (closed, {len(v)} vertices: {_one_line(exc)})"))
        return _PartSheets([], total, notes, None, f"{label}: cannot become a sheet: {_one_line(exc)}")
    total.midsurfaces += len(made)
    notes.append(f"{label}: a thick petal: simulated as its mid-surface "
                 + ", ".join(f"(thickness {np.median(t):.3g})" for _, _, t in made))
    return _PartSheets([(sv, sf, i, (sv, t)) for sv, sf, t in made], total, notes, found)


def _remesh_half(h: float):
    """The remesh step of :func:`symmetry.mirrored_mesh`: isotropic at ``h``, then
    :func:`remesh.improve` with the cut's vertices free to slide along it (they get
    first coordinate 0 there, and sliding between two of them keeps it exactly 0).
    Ends of the cut closer than :data:`remesh.MIN_EDGE` times ``h`` to an earlier one are
    not held: a rim that zigzags across the plane at the tip (the lotus's) would keep
    them as a cluster of tiny triangles no later step may mend (edges 0.01 of the mean)."""
    def redo(v, f, fixed):
        fixed = fixed.copy()
        for i in np.flatnonzero(fixed).tolist():
            if fixed[i]:
                near = np.linalg.norm(v[fixed] - v[i], axis=1) < remesh.MIN_EDGE * h
                fixed[np.flatnonzero(fixed)[near]] = False
                fixed[i] = True
        v, f, fixed = remesh.isotropic(v, f, h, fixed=fixed)
        seam = topology.boundary_vertices(f, len(v)) & (v[:, 0] == 0.0) & ~fixed
        v, f, fixed, _ = remesh.improve(v, f, fixed, seam)
        return v, f, fixed
    return redo


#: a symmetrized petal remeshed more than this many times coarser than its own edges is
#: first remeshed to half the target (:func:`_petal`)
COARSER = 4.0
#: the most times a petal is cut finer before a remesh finer than it (:func:`_smooth_finer`)
SMOOTH_CUTS = 3
#: a petal of fewer vertices is a low-poly model whose facets are its shape, remeshed as
#: it was before either mend: the smooth surface through a handful of vertices is a guess
#: (the daisy bush's rays, 8 vertices each, lifted so, bloomed from a bud that hangs open
#: the other way; put back on their facets after the improvement, through each other in
#: 12 of 147 frames, 0 as they were)
SMOOTH_FROM = 30


def _smooth_finer(pts, lf, h):
    """A petal to be remeshed finer than it is (edge ``h`` under its own), cut finer first
    (:func:`pipeline.mesh.subdivide.subdivide`: each new vertex on the smooth surface
    through the old, the outline on its curve) until its mean edge is at most ``h``: the
    remesher projects its vertices onto the input's triangles, so a coarse petal's new
    vertices would lie on its flat facets. (A six-petal bud of 50 vertices a petal on an
    irregular mesh, remeshed to about 100: its surface 0.8% of the petal's size inside the
    true one, on the chords, and the bloom 2.3% off its finest run's shape.)"""
    from pipeline.mesh.subdivide import subdivide

    for _ in range(SMOOTH_CUTS):
        if clean.mean_edge_length(pts, lf) <= h:
            break
        pts, lf, _ = subdivide(pts, lf)
    return pts, lf


def _remeshed(pts, lf, h):
    """A sheet remeshed at edge ``h`` and improved towards the quality bound. If it
    misses the bound, remeshed once more from there, kept if that meets it: the
    improvement can clip a needle off the rim (:func:`remesh.improve`), whose short base
    is then a rim edge that the remesh's boundary pass collapses."""
    src, src_f = pts, lf
    try:
        pts, lf, _ = remesh.isotropic(pts, lf, h)
    except ValueError:  # a sheet the remesher cannot take (its rim touches itself): as it is
        return pts, lf
    pts, lf, _, _ = remesh.improve(pts, lf)
    if not remesh.meets_bound(pts, lf):
        try:
            again, again_f, _ = remesh.isotropic(pts, lf, h)
        except ValueError:
            return _onto(src, src_f, pts, lf)
        again, again_f, _, _ = remesh.improve(again, again_f)
        if remesh.meets_bound(again, again_f):
            return _onto(src, src_f, again, again_f)
    return _onto(src, src_f, pts, lf)


def _onto(src, src_f, v, f):
    """The remeshed sheet ``v, f`` put back onto the sheet ``src, src_f`` it was made from,
    where that keeps the quality bound (else as it is): each inner vertex at its closest
    point on ``src``'s triangles, each rim vertex at its closest point on ``src``'s rim.
    The improvement moves vertices in the remeshed sheet's own tangent planes, and a
    second remesh projects onto the first's triangles: a petal remeshed to 50 vertices
    from a fine one lay up to 1.5% of its size off its surface, 0.4% on average, all on
    the chords' side."""
    from pipeline.mesh.nearest import closest_points

    if len(src) < SMOOTH_FROM:  # (a low-poly petal: remeshed on its facets as it was)
        return v, f
    src = np.asarray(src, dtype=np.float64)
    rim = topology.boundary_vertices(f, len(v))
    out = np.array(v, dtype=np.float64)
    inner = np.flatnonzero(~rim)
    if len(inner):
        face, bary = closest_points(out[inner], src, src_f)
        out[inner] = np.einsum("ij,ijk->ik", bary, src[np.asarray(src_f)[face]])
    edges, _, uses = topology.unique_edges(np.asarray(src_f))
    a, b = src[edges[uses == 1, 0]], src[edges[uses == 1, 1]]
    ab = b - a
    for i in np.flatnonzero(rim):
        t = np.clip(np.einsum("ij,ij->i", out[i] - a, ab) / np.maximum(
            np.einsum("ij,ij->i", ab, ab), 1e-300), 0.0, 1.0)
        near = a + t[:, None] * ab
        out[i] = near[np.argmin(np.einsum("ij,ij->i", near - out[i], near - out[i]))]
    if remesh.meets_bound(out, f) or not remesh.meets_bound(v, f):
        return out, f
    return v, f


def _shortfall(pts, lf) -> str:
    """What of the quality bound a sheet misses, for the notes ("" if it meets it:
    :func:`remesh.meets_bound`)."""
    worst, ratio = remesh.quality(pts, lf), remesh.edge_ratio(pts, lf)
    why = []
    if worst < remesh.MIN_ANGLE:
        why.append(f"triangles below {remesh.MIN_ANGLE:g} deg (min {worst:.1f} deg)")
    if ratio < remesh.MIN_EDGE:
        why.append(f"edges below {remesh.MIN_EDGE:g} of the mean (shortest {ratio:.2f})")
    return " and ".join(why)


#: moving vertices is tried on a sheet's own triangles when at most this share of them
#: (or FEW_BAD_COUNT) miss the quality bound; a sheet bad all over is remeshed
FEW_BAD, FEW_BAD_COUNT = 0.02, 20


def _few_bad(pts, lf) -> bool:
    bad = int(np.sum(remesh.face_quality(pts, lf) < remesh.MIN_ANGLE))
    return bad <= max(FEW_BAD_COUNT, FEW_BAD * len(lf))


def _fixed_quality(pts, lf, h, what, scale):
    """The sheet itself if it meets :data:`remesh.MIN_ANGLE`, else remeshed at ``h``."""
    why = _shortfall(pts, lf)
    if not why:
        return pts, lf, []
    # the user's triangles if moving vertices along the surface is enough (tried only where
    # few triangles miss the bound: moves do not mend a sheet bad all over, and trying
    # them on each of its thousands of triangles cost minutes on the lotus)
    if _few_bad(pts, lf):
        moved, _, _, _ = remesh.improve(pts, lf, moves_only=True)
        if remesh.meets_bound(moved, lf):
            count = int(np.sum(np.any(moved != pts, axis=1)))
            return moved, lf, [f"{what}: {why}: moved {count} vertices along the surface, "
                               "triangles kept"]
    pts, lf = _remeshed(pts, lf, h)
    return pts, lf, [f"{what}: {why}: "
                     f"remeshed at edge {h / scale:.4g}"]


def _petal(pts, lf, plane, h, symmetrize, what, scale):
    """One petal's sheet made symmetric (if asked) and of :data:`remesh.MIN_ANGLE` quality.

    Returns ``(vertices, faces, h, notes, mirrored)``; ``h`` is the remesh target used
    (0: the input's own triangles were kept)."""
    own = clean.mean_edge_length(pts, lf)
    if 0.0 < h < own and len(pts) >= SMOOTH_FROM:
        pts, lf = _smooth_finer(pts, lf, h)
        own = clean.mean_edge_length(pts, lf)
    elif symmetrize and h > COARSER * own:
        # much coarser than the input: the cut along the center plane would keep the
        # input's spacing along the seam, and the mirrored half's remesh its short edges
        # there (a bud of 5,000 vertices a petal remeshed to 50: every mirrored petal
        # refused for edges under a quarter of the mean, and left unsymmetrized)
        pts, lf = _remeshed(pts, lf, 0.5 * h)
        own = clean.mean_edge_length(pts, lf)
    if not symmetrize:
        if h:
            pts, lf = _remeshed(pts, lf, h)
            return pts, lf, h, [], False
        out, out_f, note = _fixed_quality(pts, lf, own, what, scale)
        return out, out_f, (own if len(out_f) != len(lf) or np.any(out_f != lf) else 0.0), note, False
    if h == 0.0:
        partner = symmetry.mirror_pairs(pts, plane, lf)
        if partner is not None:
            paired = symmetry.symmetrize(pts, plane, partner)
            why = _shortfall(paired, lf)
            if not why:
                return paired, lf, 0.0, [], True
            # keep the user's (paired) triangles: move vertices in the tangent plane only,
            # then average with the mirror image again (pairs stay pairs)
            moved = remesh.improve(paired, lf, moves_only=True)[0] if _few_bad(paired, lf) else paired
            changed = np.any(moved != paired, axis=1)
            changed |= changed[partner]
            moved[changed] = symmetry.symmetrize(moved, plane, partner)[changed]
            if changed.any() and remesh.meets_bound(moved, lf):
                count = int(changed.sum())
                return moved, lf, 0.0, [f"{what}: {why}: moved {count} vertices along the "
                                        "surface, triangles kept"], True
        else:
            try:
                # snap near-plane vertices so the cut makes few slivers; kept if it makes none
                cut, cut_f, _ = symmetry.mirrored_mesh(pts, lf, plane, snap=SNAP * own)
                why = _shortfall(cut, cut_f)
                if not why:
                    return cut, cut_f, 0.0, [f"{what}: cut along its center plane and mirrored"], True
            except ValueError:
                why = _shortfall(pts, lf)
    target = h or own
    try:
        # before a remesh (which resamples the cut) snap far less, or the snap distorts the half
        out, out_f, _ = symmetry.mirrored_mesh(pts, lf, plane, snap=SNAP_REMESHED * own,
                                               remesh=_remesh_half(target),
                                               snap_corners=SNAP_CORNER * own)
    except ValueError as exc:
        fixed, fixed_f, note = _fixed_quality(pts, lf, target, what, scale)
        kept = len(fixed_f) == len(lf) and np.all(fixed_f == lf)
        return fixed, fixed_f, (0.0 if kept else target), note + [
            f"{what}: warning: cannot be mirrored ({exc}); left unsymmetrized"], False
    if len(out_f) == 0:
        missed = "no triangles (the cut left a line)"
    elif topology.components(out_f, len(out)).max() > 0:
        missed = "pieces (the center plane cuts the petal more than once)"
    else:
        missed = _shortfall(out, out_f)
    if missed:
        # the cut met the rim in a notch or a slit the mirrored remesh cannot mend, or cut
        # a curled petal into pieces; the simulator needs a sound sheet more than symmetry
        fixed, fixed_f = _remeshed(pts, lf, target)
        # unsymmetrized also when it mends folded triangles the mirrored one kept (a low-poly
        # cage's mid-surface, clach's petals): they would fold the simulated sheet
        folded = (len(out_f) > 0 and len(fixed_f) > 0
                  and np.any(remesh.face_quality(out, out_f) == 0.0)
                  and not np.any(remesh.face_quality(fixed, fixed_f) == 0.0))
        if not _shortfall(fixed, fixed_f) or missed.startswith("pieces") or folded:
            return fixed, fixed_f, target, [
                f"{what}: warning: mirrored, it kept {missed}; remeshed at edge "
                f"{target / scale:.4g}, unsymmetrized"], False
    if h:
        return out, out_f, h, [f"{what}: cut along its center plane and mirrored, remeshed at "
                               f"edge {h / scale:.4g}"], True
    return out, out_f, target, [f"{what}: {why or 'not mirror-paired'}: cut along its center "
                                f"plane, remeshed at edge "
                                f"{target / scale:.4g} and mirrored"], True
