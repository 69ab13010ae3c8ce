"""The per-scene report: what each effect did, measured on sim.h5's frames.

Opening angle per petal, mean cross-section curvature, boundary wrinkles, petal
crossings, intersections (an exact triangle-triangle test, every frame), connection
breaks and the sign of each petal's Gaussian curvature, over time; written as JSON and
drawn as a small plot.

Whether the bloom is sound (:func:`soundness`, :func:`summary`): the frames with an
intersection, the last frame's distance to the model (an open start), and the petals
that did not open (under :data:`NOT_OPEN` degrees), and how far the flower closes
before it opens (over :data:`CLOSES_FIRST` degrees), in one line a batch log shows.
"""

from __future__ import annotations

import numpy as np

from pipeline.flower import measure
from pipeline.io import binding, userasset
from pipeline.mesh import topology
from pipeline.mesh.intersect import frame_intersections
from pipeline.mesh.remesh import boundary_loops
from pipeline.sim.explicit.pushback import build_face_grid, edges_through_faces

#: what the report reads from sim.h5 beyond what every sim.h5 holds
NEEDS = ("mesh/petal", "growth/hinges", "axis/s", "axis/x", "diagnostics/opening_angle_per_petal")
#: a petal whose opening at the last frame is under this (degrees) did not open
NOT_OPEN = 5.0
#: a petal of a flower of several that opens less than this share of the median opening
#: of its flower's petals lags behind them: caught under a neighbour, or turned in at its
#: bottom (the lotus's inner petals 7 and 10 opened 19.1 and 9.9 deg where the other
#: fourteen opened 51-77; the default buds' least is 0.70 of their median)
LAGS = 0.5
#: an open start's last frame further than this from the model (RMS, in petal lengths)
#: did not bloom back onto it
OFF_MODEL = 0.01
#: a flower whose opening (the mean over its petals) falls more than this (degrees) below
#: its start before it opens closes first: no bloom (hallgeirl's flower, from its found
#: bud, closed 38.7 deg by frame 11 and then opened 98; a daisy of the bush 23 deg)
CLOSES_FIRST = 5.0


def closing_dip(opening_per_petal) -> float:
    """How far a bloom's opening (the mean over its petals, ``(frames, petals)`` degrees
    from its first frame) falls below its start before it opens (degrees, 0 if never):
    over :data:`CLOSES_FIRST`, the flower closes first."""
    opening = np.asarray(opening_per_petal, dtype=np.float64)
    if not opening.size:
        return 0.0
    return float(max(0.0, -np.min(opening.reshape(len(opening), -1).mean(axis=1))))


def lagging(opening, flower=None) -> np.ndarray:
    """``(P,) bool``: the petals that did not open (under :data:`NOT_OPEN` degrees at the
    end, ``opening (P,)``) or lag their flower's (under :data:`LAGS` of the median opening
    of its petals; ``flower (P,)`` each petal's flower, None: one flower)."""
    opening = np.asarray(opening, dtype=np.float64)
    flower = np.zeros(len(opening), np.int64) if flower is None else np.asarray(flower)
    behind = opening < NOT_OPEN
    for k in np.unique(flower):
        mine = flower == k
        behind[mine] |= opening[mine] < LAGS * np.median(opening[mine])
    return behind


def crossings(X, faces, petal) -> int:
    """Edges of one petal that pass through a face of another: 0 when no petal has gone
    through another. Needs no history, so any frame can be checked alone."""
    X = np.ascontiguousarray(X, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    petal = np.asarray(petal, dtype=np.int64)
    edges, _, _ = topology.unique_edges(faces)
    length = np.linalg.norm(X[edges[:, 0]] - X[edges[:, 1]], axis=1)
    cell = float(max(length.max(), 1e-9))
    size = 4 * len(faces) + 1
    start, count = np.zeros(size + 1, dtype=np.int64), np.zeros(size, dtype=np.int64)
    items = np.zeros(27 * len(faces), dtype=np.int64)
    build_face_grid(X, faces, 0.0, cell, start, count, items)
    return int(edges_through_faces(X, edges, petal[edges[:, 0]], faces, petal[faces[:, 0]],
                                           cell, start, count, items))


def soundness(positions: np.ndarray, faces: np.ndarray, opening_per_petal: np.ndarray, *,
              distance_to_model: float | None = None, petal_names: list[str] | None = None,
              intersecting: list[bool] | None = None, petal=None, left=None,
              bud_closed: float | None = None, held_flowers=None,
              stopped: float | None = None, flower=None) -> dict:
    """Whether a bloom is sound, from its arrays.

    Parameters
    ----------
    positions : (T, V, 3) the frames.
    faces : (F, 3) int, the sheet's triangles.
    opening_per_petal : (T, P) each petal's opening angle in degrees (0 at frame 0).
    distance_to_model : the last frame's RMS distance to the open model over the mean
        petal length (sim.h5's ``distance_to_model``), or None (not an open start).
    petal_names : (P,) a name per petal (:func:`petal_names`), or None: "petal p".
    intersecting : whether each frame has an intersection, if already checked (of the
        frames as the user gets them: a file of staggered flowers has more than T); else
        checked here on ``positions``, exactly
        (:func:`pipeline.mesh.intersect.frame_intersections`).
    petal, left : (V,) each vertex's petal and (K, 2) the petal pairs left through each
        other as modelled (sim.h5's ``mesh/petal`` and ``mesh/left``), or None: those
        pairs' crossings are not counted (``left`` of the result: the pairs, named).
    bud_closed : an open start's bud in a flower: how much less its petals lean from
        their flower's axis than the model's (sim.h5's ``bud_closed``, degrees, the median
        over petals; negative: most hang open the other way, and the bloom closes them),
        or None.
    held_flowers : a file of many flowers: those kept as modelled because no bloom was
        found for them (sim.h5's ``flowers_kept_as_modelled``), or None.
    stopped : the growth where a bloom from a bud found no equilibrium past it and was
        held (sim.h5's ``bloom_stopped_at``), or None.

    Returns
    -------
    dict with ``frames`` (the frames checked), ``intersecting`` (a bool each), ``intersecting_frames``,
    ``distance_to_model`` (float or None), ``opening_final_per_petal`` (P degrees),
    ``did_not_open`` (P bools: under :data:`NOT_OPEN` degrees at the last frame),
    ``not_opened`` (one ``{"petal", "name", "opening"}`` per petal that did not open),
    ``lagging`` (the same for each petal that opened but lags its flower's, under
    :data:`LAGS` of their median, ``flower (P,)`` each petal's flower: not a verdict, a
    petal may be modelled to stay in) and
    ``closes_first`` (degrees: how far the mean opening falls below its start, 0 if never).
    """
    opening = np.asarray(opening_per_petal, dtype=np.float64).reshape(len(positions), -1)
    if intersecting is None:
        intersecting = frame_intersections(positions, faces, petal, left)
    left = [] if left is None else [f"{a}-{b}" for a, b in
                                     sorted(tuple(sorted(p)) for p in np.asarray(left).tolist())]
    final = opening[-1]
    names = list(petal_names) if petal_names is not None else [f"petal {p}" for p in
                                                                 range(len(final))]
    closed = final < NOT_OPEN
    behind = lagging(final, flower) & ~closed
    distance = None if distance_to_model is None else float(distance_to_model)
    dip = closing_dip(opening)
    return {
        "frames": int(len(intersecting)),
        "intersecting": [bool(b) for b in intersecting],
        "intersecting_frames": int(sum(bool(b) for b in intersecting)),
        "distance_to_model": distance,
        "opening_final_per_petal": final.tolist(),
        "did_not_open": closed.tolist(),
        "not_opened": [{"petal": int(p), "name": names[p], "opening": float(final[p])}
                       for p in np.flatnonzero(closed)],
        "lagging": [{"petal": int(p), "name": names[p], "opening": float(final[p])}
                    for p in np.flatnonzero(behind)],
        "left": left,
        "bud_closed": None if bud_closed is None else float(bud_closed),
        "flowers_kept_as_modelled": [int(k) for k in (held_flowers if held_flowers is not None
                                                      else [])],
        "bloom_stopped_at": None if stopped is None else float(stopped),
        "closes_first": dip,
    }


#: petals that did not open named one per log line, at most (the rest counted in one)
NAMED = 10


def warn_not_opened(not_opened: list[dict], warn) -> None:
    """A warning per petal that did not open (:func:`soundness`'s ``not_opened``), through
    ``warn(message)``: the first :data:`NAMED`, then how many more (a flower of fifty
    petals kept as modelled would fill a batch log; report.json names every one)."""
    for p in not_opened[:NAMED]:
        warn(f"{p['name']} did not open: {p['opening']:+.1f} deg at the end (under "
             f"{NOT_OPEN:g} deg)")
    if len(not_opened) > NAMED:
        warn(f"and {len(not_opened) - NAMED} more petals did not open (report.json's "
             "not_opened names each)")


def warn_lagging(sound: dict, warn) -> None:
    """A warning per petal that opened but lags its flower's (:func:`soundness`'s
    ``lagging``), through ``warn(message)``, as :func:`warn_not_opened`."""
    behind = sound.get("lagging") or []
    for p in behind[:NAMED]:
        warn(f"{p['name']} lags the others: {p['opening']:+.1f} deg at the end (under "
             f"{LAGS:g} of its flower's median)")
    if len(behind) > NAMED:
        warn(f"and {len(behind) - NAMED} more petals lag (report.json's lagging names each)")


def summary_line(sound: dict) -> str:
    """The one-line verdict of :func:`soundness`, e.g. "sound: 0 of 121 frames with an
    intersection (checked exactly); last frame 1.6e-13 petal lengths from the model; every
    petal opened (least 21.3 deg)"; "unsound:" when a frame has an intersection, a petal
    did not open, an open start's last frame is off the model (over :data:`OFF_MODEL`),
    or its bud is no more closed than the model (``bud_closed`` <= 0: the bloom closes),
    or a flower of many was kept as modelled (no bloom found for it), or the bloom
    stopped short of full growth (``bloom_stopped_at``), or the flower closes by more than
    :data:`CLOSES_FIRST` before it opens."""
    left = sound.get("left") or []
    checked = "checked exactly"
    if left:
        checked += ("; not between petals left through each other as modelled: "
                    + ", ".join(left[:6]) + (" ..." if len(left) > 6 else ""))
    parts = [f"{sound['intersecting_frames']} of {sound['frames']} frames with an intersection "
             f"({checked})"]
    off = sound["distance_to_model"] is not None and sound["distance_to_model"] > OFF_MODEL
    if sound["distance_to_model"] is not None:
        parts.append(f"last frame {sound['distance_to_model']:.2g} petal lengths (RMS) from "
                     "the model" + (f" (over {OFF_MODEL:g}: not back on it)" if off else ""))
    backward = (sound.get("bud_closed") is not None and sound["bud_closed"] <= 0.0)
    if backward:  # (the bud hangs open the other way: the "bloom" closes the flower)
        parts.append(f"the bud is {-sound['bud_closed']:.1f} deg more open than the model "
                     "(its petals lean further from the axis: the bloom closes them)")
    held = sound.get("flowers_kept_as_modelled") or []
    if held:
        parts.append(f"{len(held)} flower(s) kept as modelled, no bloom found: flower "
                     + ", ".join(str(k) for k in held[:10]) + (" ..." if len(held) > 10 else ""))
    cut = sound.get("bloom_stopped_at")
    if cut is not None:
        parts.append(f"the bloom stops at A = {cut:.3g} (no equilibrium past it): the frames "
                     "after hold it")
    dip = sound.get("closes_first") or 0.0
    first = dip > CLOSES_FIRST
    if first:
        parts.append(f"the flower closes {dip:.1f} deg (mean over its petals) before it opens")
    final = sound["opening_final_per_petal"]
    if sound["not_opened"]:
        shown = ", ".join(f"{d['name']} {d['opening']:+.1f} deg" for d in sound["not_opened"][:6])
        more = len(sound["not_opened"]) - 6
        parts.append(f"{len(sound['not_opened'])} of {len(final)} petal(s) did not open (under "
                     f"{NOT_OPEN:g} deg): {shown}" + (f" and {more} more" if more > 0 else ""))
    elif final:
        parts.append(f"every petal opened (least {min(final):.1f} deg)")
    sound_ = (sound["intersecting_frames"] == 0 and not sound["not_opened"] and not off
              and not backward and not held and cut is None and not first)
    return ("sound: " if sound_ else "unsound: ") + "; ".join(parts)


def summary(positions: np.ndarray, faces: np.ndarray, opening_per_petal: np.ndarray, *,
            distance_to_model: float | None = None,
            petal_names: list[str] | None = None) -> str:
    """:func:`summary_line` of :func:`soundness` (the arguments are its): the line
    `bloom simulate` prints at its end."""
    return summary_line(soundness(positions, faces, opening_per_petal,
                                  distance_to_model=distance_to_model, petal_names=petal_names))


def petal_names(petal: np.ndarray, part_names=None, part: np.ndarray | None = None,
                bindings: dict | None = None, faces: np.ndarray | None = None,
                asset_names: list[str] | None = None) -> list[str]:
    """A name per petal: "petal p (<part>)", the part from ``mesh/part_names`` and
    ``mesh/part`` (per vertex) where given, else from the binding (``bindings``: part ->
    :class:`pipeline.io.binding.Binding`, onto ``faces``; the part most of whose bound points
    lie on the petal, named by ``asset_names``), else "petal p"."""
    petal = np.asarray(petal)
    count = int(petal.max()) + 1 if len(petal) else 0
    owner: list = [None] * count
    if part_names is not None and part is not None:
        names = [n.decode() if isinstance(n, bytes) else str(n) for n in part_names]
        part = np.asarray(part)
        for p in range(count):
            mine = np.flatnonzero(petal == p)
            if len(mine):
                owner[p] = names[int(part[mine[0]])]
    elif bindings and faces is not None and asset_names is not None:
        face_petal = petal[np.asarray(faces)[:, 0]]
        votes = np.zeros((count, len(asset_names)), dtype=np.int64)
        for i, b in sorted(bindings.items()):
            votes[:, i] = np.bincount(face_petal[b.face[b.face >= 0]], minlength=count)[:count]
        for p in range(count):
            if votes[p].max() > 0:
                owner[p] = asset_names[int(np.argmax(votes[p]))]
    return [f"petal {p} ({name})" if name else f"petal {p}" for p, name in enumerate(owner)]


def compute(sim) -> dict:
    """Measure an open sim.h5 (an :class:`artifact.Artifact`)."""
    X = sim["frames/positions"]
    t = sim["frames/time"]
    faces, petal = sim["mesh/faces"], sim["mesh/petal"]
    hinges, s, x = sim["growth/hinges"], sim["axis/s"], sim["axis/x"]
    petals = int(petal.max()) + 1
    boundary = topology.boundary_vertices(faces, len(petal))
    loops = boundary_loops(faces)
    weights = measure.section_weights(hinges, s[hinges[:, :2]], x[hinges[:, :2]])
    hinge_petal = petal[hinges[:, 0]]
    rim = boundary[hinges].any(axis=1)
    curvature, wrinkles, crossing, rim_fold = [], [], [], []
    for frame in X:
        rim_fold.append(measure.rim_bending(frame, hinges, rim))
        curvature.append(measure.cross_section_curvature(frame, hinges, weights, hinge_petal, petals))
        wrinkles.append(measure.wrinkle_count(frame, loops, topology.vertex_normals(frame, faces)))
        crossing.append(crossings(frame, faces, petal) if petals > 1 else 0)
    curvature = np.asarray(curvature)
    # ipctk's exact test, self-contact included (simulate ran it and kept the answer)
    left = sim["mesh/left"] if "mesh/left" in sim else None
    intersecting = (sim["diagnostics/intersecting"].tolist() if "diagnostics/intersecting" in sim
                    else frame_intersections(X, faces, petal, left))
    diag = {k: sim[f"diagnostics/{k}"] for k in ("opening_angle_per_petal", "kinetic_energy")}
    distance = sim.attrs.get("distance_to_model")
    closed = sim.attrs.get("bud_closed")
    sound = soundness(X, faces, diag["opening_angle_per_petal"],
                      held_flowers=sim.attrs.get("flowers_kept_as_modelled"),
                      stopped=sim.attrs.get("bloom_stopped_at"),
                      distance_to_model=None if distance is None else float(distance),
                      bud_closed=None if closed is None else float(closed),
                      petal_names=_names(sim, petal, faces), intersecting=intersecting,
                      petal=petal, left=left,
                      flower=sim["flower/petal_flower"][:] if "flower/petal_flower" in sim
                      else None)
    report = {
        "scene": sim.config().get("scene", {}).get("name", "") or sim.path.parent.name,
        "effects": [e for e in str(sim.attrs.get("effects", "")).split(",") if e],
        "time": t.tolist(),
        "opening_angle_per_petal": diag["opening_angle_per_petal"].tolist(),
        "opening_angle_final_mean": float(diag["opening_angle_per_petal"][-1].mean()),
        "cross_section_curvature": curvature.mean(axis=1).tolist(),
        "cross_section_curvature_per_petal_final": curvature[-1].tolist(),
        "boundary_wrinkles": wrinkles,
        "rim_bending": rim_fold,
        "crossings": crossing,
        "intersecting": intersecting,
        "intersecting_frames": int(sum(intersecting)),
        "gaussian_curvature_sign": {
            "start": measure.gaussian_curvature_sign(X[0], faces, petal, ~boundary).tolist(),
            "end": measure.gaussian_curvature_sign(X[-1], faces, petal, ~boundary).tolist()},
        "kinetic_energy_final": float(diag["kinetic_energy"][-1]),
        "distance_to_model": sound["distance_to_model"],
        "opening_final_per_petal": sound["opening_final_per_petal"],
        "did_not_open": sound["did_not_open"],
        "not_opened": sound["not_opened"],
        "flowers_kept_as_modelled": sound["flowers_kept_as_modelled"],
        "bloom_stopped_at": sound["bloom_stopped_at"],
        "summary": summary_line(sound),
    }
    if "effects/connections/broken_step" in sim:
        broken = sim["effects/connections/broken_step"]
        h = float(sim.attrs["h"])
        times = np.sort(broken[broken >= 0]) * h
        report["connections"] = {
            "count": int(len(broken)), "broken": int(len(times)),
            "first_break_time": float(times[0]) if len(times) else None,
            "last_break_time": float(times[-1]) if len(times) else None,
            "intact": sim["diagnostics/connections_intact"].tolist()}
    if "diagnostics/contacts" in sim:
        report["contacts"] = sim["diagnostics/contacts"].tolist()
    return report


def _names(sim, petal, faces) -> list[str]:
    """:func:`petal_names` from what sim.h5 holds: ``mesh/part_names`` and ``mesh/part``
    where carried, else the binding and the input asset's part names."""
    if "mesh/part_names" in sim and "mesh/part" in sim:
        return petal_names(petal, sim["mesh/part_names"], sim["mesh/part"])
    asset = userasset.read(sim)
    bindings = binding.read_bindings(sim)
    if asset is None or not bindings:
        return petal_names(petal)
    return petal_names(petal, bindings=bindings, faces=faces, asset_names=asset.names)


def plot(report: dict, path) -> None:
    """A 2x2 figure: opening per petal, cross-section curvature, wrinkles, and crossings
    (with the intact connection springs when there are any)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.asarray(report["time"])
    fig, ax = plt.subplots(2, 2, figsize=(8, 5.5), constrained_layout=True)
    ax[0, 0].plot(t, np.asarray(report["opening_angle_per_petal"]), lw=1)
    ax[0, 0].set(title="opening angle per petal", ylabel="degrees")
    ax[0, 1].plot(t, report["cross_section_curvature"], color="k")
    ax[0, 1].set(title="mean cross-section curvature", ylabel="rad per edge")
    ax[1, 0].plot(t, report["boundary_wrinkles"], color="tab:purple", label="wrinkles (sign changes)")
    twin = ax[1, 0].twinx()
    twin.plot(t, report["rim_bending"], color="tab:orange", label="rim bending (rad)")
    ax[1, 0].legend(loc="upper left", fontsize=8)
    twin.legend(loc="lower right", fontsize=8)
    ax[1, 0].set(title="the rim", xlabel="time")
    ax[1, 1].plot(t, report["crossings"], color="tab:red", label="edges through another petal")
    if "connections" in report:
        ax[1, 1].plot(t, report["connections"]["intact"], color="tab:green",
                      label="connection springs intact")
    ax[1, 1].legend(fontsize=8)
    ax[1, 1].set(title="crossings / connections", xlabel="time")
    title = report["scene"] + (" (" + ", ".join(report["effects"]) + ")" if report["effects"] else "")
    fig.suptitle(title)
    fig.savefig(path, dpi=80)
    plt.close(fig)
