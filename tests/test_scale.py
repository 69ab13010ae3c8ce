"""Studio-sized input: memory and work that grow about linearly with the input (no
(n, n) array, no pass over all pairs), and the array-level helpers the speed-ups rest on
giving what the slower code gave. Memory is measured (tracemalloc: numpy's arrays), time
never asserted."""

from __future__ import annotations

import logging
import tracemalloc

import numpy as np
import pytest

from pipeline.flower.classify import _measure, _measure_pieces, _piece_labels
from pipeline.io.meshfile import MeshFile, Part
from pipeline.mesh import clean, procedural, topology
from pipeline.mesh.lobes import lobes, plane_frame
from pipeline.studies.bench import solidified, studio_flower
from tests.test_lobes import star


def _peak(fn, *args, **kwargs):
    """``fn``'s result and the peak memory numpy allocated while it ran, in bytes."""
    tracemalloc.start()
    try:
        out = fn(*args, **kwargs)
        return out, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_lobes_of_a_100k_face_sheet_take_memory_linear_in_its_faces():
    """The lotus's failure: plane_frame took a full SVD of the (F, 3) face centroids,
    whose U is (F, F): 74 GiB at 99,576 faces. Now a few arrays of F rows."""
    v, f = star(k=6, rings=160, around=320)
    assert len(f) > 100_000
    result, peak = _peak(lobes, v, f)
    assert result.count == 6
    assert peak < 2_000 * len(f)  # measured 630 bytes a face; an (F, F) array is 800 kB a face


def test_plane_frame_of_a_few_faces_still_has_three_axes():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.1]])
    for f in (np.array([[0, 1, 2]]), np.array([[0, 1, 2], [1, 3, 2]])):
        _, axes, _, _ = plane_frame(v, f)
        assert axes.shape == (3, 3)
        assert np.allclose(axes @ axes.T, np.eye(3), atol=1e-12)


@pytest.mark.slow
@pytest.mark.studio  # (a minute and a half: make test-studio; bloom bench times the same)
def test_remesh_of_a_100k_face_flower_takes_memory_linear_in_its_faces():
    """The remesh stage's work (default config) on a 100,000-face flower in one mesh
    (12 solidified petals pushed into a receptacle): every petal found, and numpy's peak
    memory a few kilobytes a face (4 GB would be 40 kB a face)."""
    from pipeline.flower.petals import prepare_parts

    v, f = studio_flower(100_000)
    assert 95_000 < len(f) < 105_000
    result, peak = _peak(prepare_parts, MeshFile([Part("flower", v, f)], None, None),
                         where="studio_flower")
    assert len(result.plane) == 12 and len(result.flower_centre) == 1
    assert result.found["flower"]["area_kept"] > 0.9
    logging.getLogger("bloom").info("studio flower: peak traced %.0f MB", peak / 2 ** 20)
    assert peak < 10_000 * len(f)


def test_unique_edges_are_those_of_sorting_rows():
    """unique_edges on one int64 key per edge gives what np.unique over rows gives."""
    v, f, _ = procedural.bud(4, 900, 1)
    rng = np.random.default_rng(0)
    f = f[rng.permutation(len(f))]
    edges, he_edge, count = topology.unique_edges(f)
    he, _ = topology.half_edges(f)
    ref, ref_inverse, ref_count = np.unique(np.sort(he, axis=1), axis=0, return_inverse=True,
                                            return_counts=True)
    assert np.array_equal(edges, ref) and np.array_equal(count, ref_count)
    assert np.array_equal(he_edge, ref_inverse.reshape(-1))


def test_orient_consistently_by_tree_and_pointer_jumping():
    """Faces flipped at random and shuffled, several components: one orientation per
    component, the first face of each keeps its winding, and the flips counted are the
    faces turned."""
    v, f, petal = procedural.bud(5, 1500, 2)
    rng = np.random.default_rng(4)
    f = f[rng.permutation(len(f))]
    flipped = rng.random(len(f)) < 0.4
    f[flipped] = f[flipped][:, [0, 2, 1]]
    out, count = clean.orient_consistently(f, len(v))
    topology.hinges(out)  # raises if two faces run an edge the same way
    face_comp = petal[f[:, 0]]
    for c in np.unique(face_comp):
        first = np.flatnonzero(face_comp == c)[0]
        assert np.array_equal(out[first], f[first])
    assert count == int(np.sum(np.any(out != f, axis=1)))


def test_pieces_measured_in_one_pass_are_measured_as_alone():
    """_measure_pieces (one ray cast for every piece, through the others) gives each
    piece's form and measures as _measure of the piece alone: here solidified petals
    pushed through one another and an open one."""
    v, f, petal = procedural.open_flower(5, 1500, seed=1)
    pieces = []
    for p in range(5):
        idx = np.flatnonzero(petal == p)
        pv, pf = v[idx], np.searchsorted(idx, f[np.isin(f[:, 0], idx)])
        pieces.append(solidified(pv, pf, 0.02) if p < 4 else (pv, pf))
    offsets = np.cumsum([0] + [len(pv) for pv, _ in pieces])
    allv = np.vstack([pv for pv, _ in pieces])
    allf = np.vstack([pf + o for (_, pf), o in zip(pieces, offsets, strict=False)])
    welded, label, count = _piece_labels(allv, allf)
    assert count == 5
    together = _measure_pieces(allv, welded, label, count)
    for (pv, pf), shape in zip(pieces, together, strict=True):
        alone = _measure(pv, pf)
        assert shape.form == alone.form
        assert shape.area == pytest.approx(alone.area, rel=1e-9)
        assert shape.length == pytest.approx(alone.length, rel=1e-9)
        assert shape.layered == pytest.approx(alone.layered, abs=0.02)
    assert [s.form for s in together] == ["shell"] * 4 + ["sheet"]


@pytest.mark.slow
def test_layered_fraction_takes_memory_linear_in_its_faces():
    """A solidified petal of 6,000 faces: its neighbour pairs (millions within the search
    radius on a fine mesh) are looked at a block of faces at a time (measured: 5 kB a
    face; all at once it was 30 kB a face at 24,000 faces, and grows with the density)."""
    v, f, _ = procedural.bud(1, 1500, 0)
    sv, sf = solidified(v, f, 0.02)
    (fraction, gap), peak = _peak(clean.layered_fraction, sv, sf)
    assert fraction > 0.9 and gap == pytest.approx(0.02, rel=0.1)
    assert peak < 10_000 * len(sf)


def test_progress_lines_under_make(caplog):
    """Not on a terminal: a line when a step starts and then at most every few seconds,
    naming the stage, the input, the step, how far and the part."""
    from pipeline.progress import Steps

    progress = Steps("remesh", "bush.glb", every=3600.0, quiet=0.0, show=False)
    with caplog.at_level(logging.INFO, logger="bloom"):
        progress("cleaning petal parts", 0, 30, "part 'Object_8'")
        progress("cleaning petal parts", 1, 30, "part 'Object_12'")  # within `every`: quiet
        progress("remeshing petals", 3, 160, "petal 3 (Object_8)")
    lines = [r.getMessage() for r in caplog.records]
    assert lines == ["remesh: bush.glb: cleaning petal parts: 0 of 30 (0%), part 'Object_8'",
                     "remesh: bush.glb: remeshing petals: 3 of 160 (2%), petal 3 (Object_8)"]
    quiet = Steps("remesh", "petal.obj", show=False)  # a quick run says nothing
    with caplog.at_level(logging.INFO, logger="bloom"):
        caplog.clear()
        quiet("remeshing petals", 0, 1)
    assert caplog.records == []


def test_workers_progress_is_shown_by_the_parent(caplog):
    """A file's flowers bloom in forked workers: each worker's bars post to a board shared
    at the fork, and the parent's bar, read from it, logs under make at least every
    heartbeat, however little is done, naming what each flower is doing and how far."""
    import multiprocessing

    from pipeline import progress as module
    from pipeline.progress import Board, Progress

    board = Board(3)

    def worker():
        board.serve(2)
        with Progress(10, "simulate flower 2 (the path back)", show=False) as bar:
            bar.update(4)
        module.doing("simulate flower 2: checking its frames")  # (no share: not counted)
        board.serve(0)
        module.doing("simulate flower 0: finding the bud (own)")

    child = multiprocessing.get_context("fork").Process(target=worker)
    child.start()
    child.join(30)
    assert child.exitcode == 0
    assert module._POST is None  # (the parent's own bars are its own)
    share, doing = board.read([0, 1, 2])
    assert share == 0.0  # (neither says a share; flower 1 has not started)
    both = "simulate flower 0: finding the bud (own); simulate flower 2: checking its frames"
    assert doing == both
    with caplog.at_level(logging.INFO, logger="bloom"):
        bar = Progress(3, "simulate flowers", show=False, heartbeat=0.0)
        bar.reach(0.4, doing)
        bar.reach(0.2, "later")  # (never less than before)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2 and lines[0].startswith("simulate flowers: 13% done after")
    assert lines[0].endswith(f"({both})")
    assert lines[1].startswith("simulate flowers: 13% done") and lines[1].endswith("(later)")
    quiet = Progress(3, "simulate flowers", show=False)  # no heartbeat: a tenth more, 10 s
    with caplog.at_level(logging.INFO, logger="bloom"):
        caplog.clear()
        quiet.reach(0.1, "x")
    assert caplog.records == []


def test_many_coarse_petals_are_held_to_a_budget_of_vertices(monkeypatch):
    """A coarse petal (under MIN_PETAL_VERTICES) is remeshed up to about that many; a file
    of many coarse petals (a branch of blossoms) is held to COARSE_BUDGET vertices in
    all, each petal about its share, and says so in a note."""
    from pipeline.flower import petals as module
    from pipeline.flower.petals import prepare_parts

    v, f, p = procedural.bud(4, 4 * 40, 0)  # (coarse petals: about 40 vertices each)
    coarse = []
    for k in range(4):
        idx = np.flatnonzero(p == k)
        coarse.append(Part(f"Petal.{k}", v[idx], np.searchsorted(idx, f[np.isin(f[:, 0], idx)])))
    counts = []
    for budget in (10_000, 4 * 50):
        monkeypatch.setattr(module, "COARSE_BUDGET", budget)
        result = prepare_parts(MeshFile(coarse, None, None), where="coarse")
        counts.append(np.bincount(result.petal))
        assert ("a coarse petal is remeshed to about 50 vertices" in "\n".join(result.notes)) \
            == (budget == 200)
    assert np.all(counts[0] > 80) and np.all(counts[1] < 70)  # about 100, then about 50


def test_a_dense_petal_is_remeshed_down_to_the_ceiling():
    """A petal of more than remesh.max_petal_vertices (a studio's dense mesh: the tulip's
    3,500 a petal; 1,500 by default) is remeshed to about that many, with a note; one
    under it is kept as it is; remesh.petal_vertices still wins over the ceiling, and
    remesh.max_petal_vertices = 0 is none."""
    from pipeline.flower.petals import MAX_PETAL_VERTICES, prepare_parts

    v, f, p = procedural.bud(3, 3 * 400, 0)
    parts = MeshFile([Part("Bud", v, f)], None, None)
    kept = np.bincount(prepare_parts(parts, where="bud").petal)
    result = prepare_parts(parts, where="bud", max_petal_vertices=150)
    capped = np.bincount(result.petal)
    assert MAX_PETAL_VERTICES == 1500
    assert np.all(kept > 300), kept  # under the ceiling: as modelled (about 400)
    assert np.all((capped > 110) & (capped < 200)), capped  # about 150
    assert sum("remeshed to about 150" in n for n in result.notes) == 3
    chosen = np.bincount(prepare_parts(parts, where="bud", petal_vertices=300).petal)
    assert np.all((chosen > 240) & (chosen < 360)), chosen
    unbound = np.bincount(prepare_parts(parts, where="bud", max_petal_vertices=0).petal)
    assert np.array_equal(unbound, kept)  # 0: no ceiling
