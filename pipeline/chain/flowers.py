"""A file of many flowers in the simulate stage (:func:`flowers_apart`): each flower a
problem of its own (:func:`pipeline.chain.problem.problem`), a copy of another bloomed
once and moved (:mod:`pipeline.chain.copies`), the others side by side in
``simulate.workers`` forked processes, put together into one bloom. Where flowers pass
through each other (:mod:`pipeline.chain.crossing`), a copy blooms on its own and a
cluster blooms together.

The module is long because blooming the flowers apart, blooming again those that cross
and putting them back into one bloom read and update the same runs and positions, and
share the pool of workers."""

from __future__ import annotations

import dataclasses
import logging
from concurrent.futures import wait
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from pipeline.chain import copies, crossing, problem
from pipeline.chain.problem import Job, Result
from pipeline.errors import BloomError
from pipeline.flower import stagger
from pipeline.forks import can_fork, pool, workers
from pipeline.mesh import clean
from pipeline.mesh.topology import components
from pipeline.progress import Board, Progress
from pipeline.review import report
from pipeline.sim.build import Prepared
from pipeline.sim.effects import ORDER
from pipeline.sim.reverse import distance_to_model
from pipeline.sim.run import Recording

log = logging.getLogger("bloom")

#: a file of many flowers: how each frame's diagnostic of the whole is made of the
#: flowers' (the rest are sums: energies, counts)
_SAME = ("growth", "curl_factor")
_LARGEST = ("max_speed", "center_plane_drift", "stable_step")

#: what a forked worker blooms from, inherited from the parent (not sent): each flower's
#: problem and vertices (:meth:`~pipeline.sim.build.Prepared.flower_part`), the
#: :class:`Job` and the checkpoint path
_TASK: tuple | None = None
#: where forked workers post how far their flower has got (:class:`~pipeline.progress.Board`)
_BOARD: Board | None = None
#: seconds between the parent's looks at the workers' board, and between its log lines
#: at least while flowers bloom in workers (under make: a bed of roses blooms for minutes)
TICK, HEARTBEAT = 1.0, 30.0


class _Kept(logging.Handler):
    """A forked worker's log: kept, and sent back with the flower's bloom, so that the
    log reads flower after flower as it does in one process."""

    lines: list = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append((record.levelno, record.getMessage()))


def _worker_start() -> None:
    """A forked worker's start: the log is kept for the parent (:class:`_Kept`). (The
    thread pools the parent made are forgotten at every fork: ``os.register_at_fork`` in
    :mod:`pipeline.sim.threads` and :mod:`pipeline.sim.solver.ldl`.)"""
    bloom = logging.getLogger("bloom")
    bloom.handlers, bloom.propagate = [_Kept()], False


def solve(part: Prepared, job: Job, ckpt: Path, label: str):
    """The bloom of a flower of a file of many (or of flowers that bloom together) as it
    would be alone in a file: solved at its own size, its mean edge 1 (remesh scales a
    file so), and given back in the file's units, a vertex that did not move (the fixed
    base) exactly where it was. A blossom scaled 1.25 blooms as the same blossom does,
    1.25 times the size; solved at the file's scale, two such copies opened 62-89 and
    55-58 deg (what in the solve is in mesh units, ``simulate.tolerance`` for one, was
    not measured apart)."""
    rest = np.asarray(part.vertices, dtype=np.float64)
    size = clean.mean_edge_length(rest, np.asarray(part.faces))
    unit = part.scaled(1.0 / size)
    run = problem.problem(unit, job, ckpt, label=label)

    def back(X):  # (a vertex where it was, the fixed base, exactly where it was)
        X = np.asarray(X, dtype=np.float64)
        out = size * X
        still = np.all(X == unit.vertices, axis=1)
        out[still] = rest[still]
        return out

    rec = Recording(list(run.rec.time), [back(X) for X in run.rec.positions],
                    run.rec.diagnostics)
    return dataclasses.replace(run, bud=back(run.bud), rec=rec)


def _bloom_flower(k: int):
    """In a forked worker: :func:`_bloom_one`, with the log lines (level, message) it
    wrote, for the parent to write."""
    _Kept.lines = []
    if _BOARD is not None:
        _BOARD.serve(k)
    k, run, why = _bloom_one(k)
    return k, run, why, _Kept.lines


def _bloom_one(k: int):
    """Flower ``k``'s bloom (:func:`~pipeline.chain.problem.problem`), as ``(k, bloom,
    None)``, or ``(k, None, why)`` where it is refused. Its effects are kept as what the
    put-together bloom reads of them (their names, the connection springs), so that a
    worker can send it back."""
    parts, job, ckpt, labels = _TASK
    part, idx = parts[k]
    if labels is None:
        label, suffix = f"flower {k}", f"-flower{k}"
        log.info("flower %d of %d: %d petal(s), %d vertices", k, len(parts), len(part.tip),
                 len(idx))
    else:
        label, suffix = labels[k]
    try:
        run = solve(part, job, ckpt.with_name(f"{ckpt.name}{suffix}"), label)
    except BloomError as exc:
        return k, None, str(exc).removeprefix(f"{job.where}: ")
    c = run.effects.connections
    kept = SimpleNamespace(names=list(run.effects.names), connections=None if c is None else
                           SimpleNamespace(pairs=np.asarray(c.pairs),
                                           broken_step=np.asarray(c.broken_step)))
    return k, dataclasses.replace(run, effects=kept), None


def _bloom_all(parts: list, job: Job, ckpt: Path, own: list, labels: list | None = None):
    """``(k, bloom or None, why refused or None)`` of each flower of ``own`` (``labels``:
    each problem's ``(label, checkpoint suffix)``, for problems that are not one flower
    each), in order: in
    this process, or (``simulate.workers`` > 1, two flowers or more, a system that
    forks) in a pool of forked processes, the largest started first, each flower's
    problem its own, so the blooms
    are the same bits either way (:mod:`pipeline.forks`). A worker starts with no
    thread pool (the parent's has no threads in it after the fork), shows no bar and
    keeps its log: this process writes each flower's log as it comes back, in order,
    and counts the flowers."""
    global _TASK, _BOARD
    many = workers(job.cfg["simulate.workers"])
    forks = can_fork()
    _TASK = (parts, job if many <= 1 or len(own) < 2 or not forks
             else dataclasses.replace(job, progress=False), ckpt, labels)
    try:
        if many <= 1 or len(own) < 2 or not forks:
            for k in own:
                yield _bloom_one(k)
            return
        if labels is None:
            log.info("%d of %d flowers to bloom, %d side by side (simulate.workers)", len(own),
                     len(parts), min(many, len(own)))
        else:
            log.info("%d problems of flowers together to solve, %d side by side "
                     "(simulate.workers)", len(own), min(many, len(own)))
        _BOARD = Board(len(parts))
        with (pool(min(many, len(own)), initializer=_worker_start) as workers_,
              Progress(len(own), "simulate flowers", job.progress,
                       heartbeat=HEARTBEAT) as bar):
            # the largest problems first (by vertices), so that none starts last and runs
            # alone while the other workers wait (the daisy bush's two daisies that bloom
            # together, 3,190 vertices, ran alone for its last minutes); taken in order
            started = {k: workers_.submit(_bloom_flower, k)
                       for k in sorted(own, key=lambda k: -len(parts[k][1]))}
            for k in own:
                while not started[k].done():  # (what the workers are doing, shown)
                    wait([started[k]], timeout=TICK)
                    pending = [j for j in own if not started[j].done()]
                    share, doing = _BOARD.read(pending)
                    bar.reach(len(own) - len(pending) + share, doing)
                _, run, why, lines = started[k].result()
                for level, line in lines:
                    log.log(level, "%s", line)
                bar.reach(sum(f.done() for f in started.values()), "")
                yield k, run, why
    finally:
        _TASK = _BOARD = None


def _own_where_copies_cross(runs: dict, source: dict, parts: list, prep: Prepared, job: Job,
                            ckpt: Path, positions, starts, whole: np.ndarray) -> np.ndarray:
    """A copy blooms as its original does, moved; but the original's neighbours are not
    its own. Each copy whose moved bloom passes through a neighbouring flower, in a frame
    the user sees, blooms on its own as well (rounding can pick another branch of its
    path), and keeps the bloom that crosses in fewer frames: ``runs`` and ``positions``
    updated in place, the choice logged. ``whole``: the frames in which flowers cross
    (:func:`~pipeline.chain.crossing.seen` of them all: a branch has a thousand copies,
    looked at only where that finds one); returns it, looked at again if a copy
    changed."""
    copied = sorted(k for k in runs if source[k] is not None)
    if not copied or not whole.any():
        return whole
    at = np.flatnonzero(whole)
    boxes = crossing.boxes(positions, parts)
    crossed = {k: n for k in copied
               if (n := crossing.count(k, positions, parts, prep, starts, boxes, frames=at))}
    if not crossed:
        return whole
    log.info("%d copied flower(s) pass through a neighbour when moved (%s): each blooms on "
             "its own", len(crossed), ", ".join(f"flower {k} in {n} frame(s)"
                                                 for k, n in crossed.items()))
    for k, run, why in _bloom_all(parts, job, ckpt, list(crossed)):
        idx = parts[k][1]
        if run is None:
            log.info("flower %d: its own bloom is refused (%s); it blooms as flower %d, "
                     "moved", k, why, source[k][0])
            continue
        kept = positions[:, idx].copy()
        positions[:, idx] = np.asarray(run.rec.positions)
        own = crossing.count(k, positions, parts, prep, starts, boxes)
        if own < crossed[k]:
            runs[k] = (run, idx)
            log.info("flower %d blooms on its own: it crosses a neighbour in %d frame(s), "
                     "%d as a copy", k, own, crossed[k])
        else:
            positions[:, idx] = kept
            log.info("flower %d blooms as flower %d, moved: on its own it crosses a "
                     "neighbour in %d frame(s), %d as a copy", k, source[k][0], own,
                     crossed[k])
    return crossing.seen(list(range(len(parts))), positions, parts, prep, starts,
                         workers=workers(job.cfg["simulate.workers"]))


#: flowers that cross blooming apart bloom together only if that ends near the model (an
#: open start): within this many times what the report counts as on it
#: (:data:`pipeline.review.report.OFF_MODEL`, RMS in petal lengths), or within
#: :data:`TOGETHER_APART` times the farthest of their blooms apart. A petal through
#: another is seen in every frame it lasts; a bloom a few hundredths of a petal off its
#: model is hardly seen (two daisies of the daisy bush: 13 frames crossing apart, 0.019
#: off; together none, 0.037 off)
TOGETHER_OFF = 5.0
TOGETHER_APART = 1.5


def _together_where_flowers_cross(runs: dict, parts: list, prep: Prepared, job: Job,
                                  ckpt: Path, positions, starts, whole: np.ndarray):
    """Flowers that bloom apart can pass through each other: in the frames the user
    sees (staggered by ``starts``), each flower is at its own stage of growth. The
    flowers that do (found pair by pair) bloom together, each cluster as one problem
    (:meth:`~pipeline.sim.build.Prepared.flowers_part`): the bud search keeps contact
    within each flower (as apart), and the bloom from those buds has contact between
    them too, starting at one frame: the earliest start among them. Kept where it
    leaves fewer frames crossing among them and their neighbours (``whole``: the frames
    the file crosses in, :func:`~pipeline.chain.crossing.seen`) and ends as near the model
    (:data:`TOGETHER_OFF`); ``runs``
    and ``positions`` updated in place, the choice logged. Where the flowers of a cluster,
    bloomed apart but started together, cross nothing, that is kept without a solve (and
    where together they cross more, or find no bloom, it is kept if it crosses less than
    staggered). Returns ``(K,)`` each flower's cluster (its first flower: those of one
    start together), or None where each blooms apart, staggered."""
    if job.cfg["effects.collisions.enabled"] is False or not whole.any():
        return None
    count = len(parts)
    at = np.flatnonzero(whole)
    boxes = crossing.boxes(positions, parts)
    pairs = [(k, int(j)) for k in sorted(runs) for j in crossing.near(k, boxes)
             if j > k and j in runs
             and crossing.seen([k, int(j)], positions, parts, prep, starts, frames=at,
                               first=True).any()]
    if not pairs:
        return None
    label_of = components(np.asarray(pairs, dtype=np.int64), count)
    crossed = sorted({q for pair in pairs for q in pair})
    clusters = {}
    for k in crossed:
        clusters.setdefault(int(label_of[k]), []).append(k)
    cluster = np.arange(count)
    names = job.names if "collisions" in job.names else [*job.names, "collisions"]
    together = dataclasses.replace(job, names=names)
    # each cluster judged where it can change anything: its flowers and those whose boxes
    # meet theirs (by the whole file's frames, one cluster of a branch's many could never
    # leave fewer: the others cross in the same frames)
    regions = [sorted({*members, *(int(j) for k in members for j in crossing.near(k, boxes))})
               for members in clusters.values()]

    def joining(members):  # (the clusters so far, and these flowers as one)
        joined = cluster.copy()
        joined[members] = members[0]
        return joined

    # the clusters that need a solve (bloomed apart but started together, they still
    # cross) solved first, side by side: each problem is its own, so the same bits as
    # one after another; judged below in order, as neighbours change
    unsynced = [(c, members) for c, members in enumerate(clusters.values())
                if crossing.seen(regions[c], positions, parts, prep,
                                 stagger.together(starts, joining(members)), first=True).any()]
    # buds found apart that pass through each other: the bloom together cannot start from
    # them, so those clusters' buds are searched together at once
    buds = np.asarray(prep.vertices, dtype=np.float64)[None].copy()
    for k in runs:
        buds[0, runs[k][1]] = runs[k][0].bud
    tangled = {c for c, members in unsynced if crossing.seen(members, buds, parts, prep, None)[0]}
    solved = _solved_together(prep, unsynced, together, ckpt, tangled)
    for c, members in enumerate(clusters.values()):
        label = "flowers " + ", ".join(map(str, members))
        region, joined = regions[c], joining(members)
        before = crossing.seen(region, positions, parts, prep,
                               stagger.together(starts, cluster)).sum()
        # first, bloomed apart but started together (no solve: each ends on its model,
        # and in step they may keep apart where staggered they crossed)
        synced = crossing.seen(region, positions, parts, prep,
                               stagger.together(starts, joined)).sum()
        if synced == 0:
            log.info("%s pass through each other blooming apart, staggered (%d frame(s) with "
                     "their neighbours): started together, they cross in none", label,
                     int(before))
            cluster = joined
            continue
        log.info("%s pass through each other in %d of %d frames, blooming apart: they "
                 "bloom together, as one problem with contact between them (their buds "
                 "searched with contact within each), from frame %d", label,
                 int(whole.sum()), len(whole), int(np.asarray(starts)[members].min()))
        if c not in solved:  # (synced, it crossed nothing before a neighbour changed)
            solved.update(_solved_together(prep, [(c, members)], together, ckpt))
        run, why, searched = solved.pop(c)
        if searched is not None:
            log.info("%s: %s; their buds are searched together, with contact between them",
                     label, searched)
        idx = np.flatnonzero(np.isin(np.asarray(prep.flower), members))
        apart = [runs[k][0].distance for k in members]
        if run is not None and run.distance is not None and None not in apart and \
                run.distance > max(TOGETHER_OFF * report.OFF_MODEL, TOGETHER_APART * max(apart)):
            why = (f"together they end {run.distance:.3g} petal lengths from the model, apart "
                   f"{max(apart):.3g} at most")
            run = None
        if run is not None:
            kept = positions[:, idx].copy()
            positions[:, idx] = np.asarray(run.rec.positions)
            after = crossing.seen(region, positions, parts, prep,
                                  stagger.together(starts, joined)).sum()
            if after < min(before, synced):
                log.info("%s bloom together: they and their neighbours cross in %d frame(s), "
                         "%d apart", label, int(after), int(before))
                for k in members:
                    runs.pop(k, None)
                runs[members[0]] = (run, idx)
                cluster = joined
                continue
            positions[:, idx] = kept
            why = f"together they and their neighbours cross in {int(after)} frame(s)"
        if synced < before:
            log.info("%s bloom apart, started together: they and their neighbours cross in %d "
                     "frame(s), %d staggered (%s)", label, int(synced), int(before), why)
            cluster = joined
        else:
            log.info("%s bloom apart: %s; %d frame(s) apart", label, why, int(before))
    return cluster if np.any(cluster != np.arange(count)) else None


def _solved_together(prep: Prepared, clusters: list, job: Job, ckpt: Path,
                     tangled=frozenset()) -> dict:
    """``{c: (bloom or None, why refused, why its buds were searched together or None)}``:
    each cluster ``(c, members)`` of flowers as one problem (:func:`_bloom_all`, side by
    side), its buds searched within each flower; a cluster refused so (those buds can
    pass through each other, and the bloom cannot start from them), or one of
    ``tangled`` (its buds found apart do), is solved with its buds searched together,
    contact between its flowers too."""
    if not clusters:
        return {}
    parts = [prep.flowers_part(members) for _, members in clusters]
    labels = [("flowers " + ", ".join(map(str, members)), f"-together{c}")
              for c, members in clusters]
    plain = [k for k, (c, _) in enumerate(clusters) if c not in tangled]
    first = {k: (None, "their buds found apart pass through each other") for k in
             range(len(clusters)) if k not in plain}
    first.update({k: (run, f"together they find no bloom ({why})") for k, run, why in
                  _bloom_all(parts, job, ckpt, plain, labels)})
    again = [k for k in range(len(clusters)) if first[k][0] is None]
    second = {}
    if again:
        searched = [(dataclasses.replace(parts[k][0], searched_together=True), parts[k][1])
                    for k in again]
        relabel = [(labels[k][0], labels[k][1] + "-searched") for k in again]
        second = {again[j]: (run, why) for j, run, why in
                  _bloom_all(searched, job, ckpt, list(range(len(again))), relabel)}
    out = {}
    for k, (c, _) in enumerate(clusters):
        run, why = first[k]
        if run is not None:
            out[c] = (run, "", None)
            continue
        run, why_again = second[k]
        out[c] = (run, "" if run is not None else f"together they find no bloom "
                  f"({why_again}), their buds searched together too", why)
    return out


def _shared_budget(job: Job, problems: int) -> Job:
    """``job`` with each of a file's ``problems`` flowers held to its share of
    ``simulate.file_vertices`` for a solve cut finer (or ``simulate.max_vertices``, the
    fewer): a branch of a thousand blossoms of 10-vertex petals was cut to 1,800 vertices
    a blossom, 30 s of solve each."""
    cfg = job.cfg
    most, budget = cfg["simulate.max_vertices"], cfg["simulate.file_vertices"]
    if budget <= 0 or problems <= 1:
        return job
    share = budget // problems
    if share >= most:
        return job
    log.info("simulate.file_vertices = %d: each of the %d flowers to solve keeps to %d "
             "vertices cut finer (simulate.max_vertices: %d)", budget, problems, share, most)
    return dataclasses.replace(job, max_vertices=share)


def flowers_apart(prep: Prepared, job: Job, ckpt: Path, starts) -> Result:
    """Each flower of a file of many as a problem of its own
    (:func:`~pipeline.chain.problem.problem`), put together. A flower whose bloom is
    refused is kept as modelled (its frames the model; its petals opened 0 deg), with a
    warning naming it and why; the run is refused only if every flower is. A copy of
    another flower blooms as it does, moved, unless that passes through a neighbour in a
    frame the user sees (staggered by ``starts``, each flower's start frame): then it
    blooms on its own (:func:`_own_where_copies_cross`); flowers that pass through each
    other bloom together (:func:`_together_where_flowers_cross`)."""
    flower = np.asarray(prep.flower)
    count = int(flower.max()) + 1
    petal = np.asarray(prep.petal)
    petals = len(prep.tip)
    shapes = copies.seen()  # (flowers that are copies of another bloom as it does, moved)
    parts = [prep.flower_part(k) for k in range(count)]  # (part, its vertices here)
    source = {k: copies.copy_of(k, part, shapes) for k, (part, _) in enumerate(parts)}
    own = [k for k in range(count) if source[k] is None]
    job = _shared_budget(job, len(own))
    blooms, refusals = {}, []
    for k, run, why in _bloom_all(parts, job, ckpt, own):
        if run is None:
            log.warning("flower %d could not bloom; it is kept as modelled: %s", k, why)
            refusals.append(why)
        else:
            blooms[k] = run
    copied = count - len(own)
    if copied:
        log.info("%d of %d flowers are copies of others (moved, turned or scaled, their petals "
                 "remeshed alike): each blooms as its original does, moved", copied, count)
    if not blooms:
        raise BloomError(refusals[0], where=job.where)
    runs, held = {}, []
    for k in range(count):
        j = k if source[k] is None else source[k][0]
        if j not in blooms:
            held.append(k)
        elif j == k:
            runs[k] = (blooms[k], parts[k][1])
        else:
            runs[k] = (copies.moved(blooms[j], *source[k][1:]), parts[k][1])
    some = next(iter(runs.values()))[0]
    times = np.asarray(some.rec.time)
    frames = len(times)
    positions = np.repeat(np.asarray(prep.vertices, dtype=np.float64)[None], frames, axis=0)
    for run_, idx in runs.values():
        positions[:, idx] = np.asarray(run_.rec.positions)
    # what the user sees: flowers through each other, staggered
    whole = crossing.seen(list(range(count)), positions, parts, prep, starts,
                          workers=workers(job.cfg["simulate.workers"]))
    whole = _own_where_copies_cross(runs, source, parts, prep, job, ckpt, positions, starts,
                                    whole)
    together = _together_where_flowers_cross(runs, parts, prep, job, ckpt, positions, starts,
                                             whole)
    bud = np.array(prep.vertices, dtype=np.float64)
    per_petal = np.zeros((frames, petals))
    diag: dict = {}
    names, pairs, broken = set(), [], []
    info: dict = {}
    wall, resumed, resumed_step = 0.0, None, 0
    stopped = []
    s, x, solved = np.array(prep.s, dtype=np.float64), np.array(prep.x, dtype=np.float64), False
    for run_, idx in runs.values():
        bud[idx] = run_.bud
        if run_.axes is not None:  # (a flower solved on its mesh cut finer)
            s[idx], x[idx], solved = run_.axes[0], run_.axes[1], True
        mine = np.unique(petal[idx])
        if run_.stopped:
            stopped.append((run_.stopped[0], int(mine[run_.stopped[1]])))
        arrays = run_.rec.arrays()
        if "opening_angle_per_petal" in arrays:
            per_petal[:, mine] = arrays["opening_angle_per_petal"]
        for name, values in arrays.items():
            if name in ("opening_angle", "opening_angle_per_petal"):
                continue
            values = np.asarray(values, dtype=np.float64)
            if name not in diag:
                diag[name] = values.copy()
            elif name in _LARGEST:
                diag[name] = np.maximum(diag[name], values)
            elif name not in _SAME:
                diag[name] = diag[name] + values
        names.update(run_.effects.names)
        c = run_.effects.connections
        if c is not None:
            pairs.append(idx[np.asarray(c.pairs, dtype=np.int64)])
            broken.append(np.asarray(c.broken_step))
        for key, value in run_.bud_info.items():
            info.setdefault(key, []).append(value)
        wall += run_.wall
        if run_.resumed is not None:
            resumed, resumed_step = run_.resumed, max(resumed_step, run_.resumed_step)
    diag["opening_angle_per_petal"] = per_petal
    diag["opening_angle"] = per_petal.mean(axis=1)
    bud_info = {}
    for key, values in info.items():  # the flowers' figures of their bud searches
        if isinstance(values[0], str):
            bud_info[key] = ",".join(sorted(set(values)))
        elif key in ("bud_seconds", "bud_newton_iterations"):
            bud_info[key] = sum(values)
        elif key == "bud_close":
            bud_info[key] = min(values)
        elif key in ("recurve_share", "bud_growth"):  # (the path back stopped highest)
            bud_info[key] = max(values)
    start_open = job.start.start == "open"
    distance = None
    if start_open:
        model = np.asarray(prep.vertices)
        bud_info["bud_distance"] = distance_to_model(bud, model, petal, prep.base)
        distance = distance_to_model(positions[-1], model, petal, prep.base)
    connections = None
    if pairs:
        connections = SimpleNamespace(pairs=np.concatenate(pairs),
                                      broken_step=np.concatenate(broken))
    return Result(bud, bud_info, sorted(names, key=lambda n: ORDER.index(n)
                                         if n in ORDER else len(ORDER)),
                   connections, times, positions, diag, wall, resumed, resumed_step, distance,
                   held, stopped, together, axes=(s, x) if solved else None)


