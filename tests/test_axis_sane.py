"""Every petal's axis is sane, or `bloom axis` says why: x spans [-1, 1], the on-axis
vertices are a line (each next to a vertex off the axis, about one per edge of the
axis's length), and the axis runs the petal's length from the end nearest the flower's
axis. A flat sheet's own plane and a plane across an elongated petal are no center
planes (dimontel's flat petal had 68 of 103 vertices on its axis, x over [0, 1])."""

from __future__ import annotations

import re

import h5py
import numpy as np
import pytest
from click.testing import CliRunner
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import Delaunay

from pipeline import artifact
from pipeline.flower.axis import BadPetal, axis_depth, find_axes
from pipeline.mesh import clean, symmetry, topology
from pipeline.review import report
from stages.cli import cli
from tests.conftest import SHARED

EXTERNAL = SHARED / "external-meshes"
needs_shared = pytest.mark.skipif(not EXTERNAL.exists(), reason="../shared/external-meshes absent")


def flat_petal(length=24.0, width=8.0, widen=1.0, roll=0.0, widest=0.65):
    """A petal outline along x (base at x = 0, widest at ``widest`` of its length; 0.5: an
    oval, the same both ways) filled with triangles of about unit edge, lying in z = 0;
    the side y > 0 stretched by ``widen`` (1: mirror-symmetric about y = 0); with
    ``roll``, the sheet bent around the x axis (a tube-like petal whose cross section is
    an arc of ``roll`` radians). Returns ``(vertices, faces, petal)``."""
    pts = []
    power = np.log(0.5) / np.log(widest)
    for x in np.arange(0.0, length + 1e-9, 1.0):
        t = min(max(x / length, 0.02), 0.98)
        half = 0.5 * width * np.sin(np.pi * t ** power) ** 0.7
        count = max(int(np.ceil(2 * half)), 1)
        ys = np.linspace(-half, half, count + 1)
        pts += [(x, y) for y in ys]
    p2 = np.unique(np.round(np.array(pts), 9), axis=0)
    faces = Delaunay(p2).simplices
    a, b, c = (p2[faces[:, k]] for k in range(3))
    area = 0.5 * np.abs((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])
    longest = np.max([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1),
                      np.linalg.norm(a - c, axis=1)], axis=0)
    faces = faces[(area > 1e-3) & (longest < 1.8)]  # not the hull's bridges over the outline
    v = np.c_[p2, np.zeros(len(p2))]
    v[:, 1] = np.where(v[:, 1] > 0, v[:, 1] * widen, v[:, 1])
    if roll:
        r = width / roll
        angle = v[:, 1] / r
        v[:, 1], v[:, 2] = r * np.sin(angle), r * (1 - np.cos(angle))
    v, f, _ = clean.clean_mesh(v, faces)
    return v / clean.mean_edge_length(v, f), f, np.zeros(len(v), dtype=np.int64)


def line_figures(v, f, petal, axes, p=0):
    """(x min, x max, depth in hops, on-axis count per mean edge of the axis, reach: the
    axis's length along the mesh over the petal's extent along its principal axis)."""
    idx = np.flatnonzero(petal == p)
    local = np.searchsorted(idx, f[np.isin(f[:, 0], idx)])
    edges, _, _ = topology.unique_edges(local)
    graph = topology.edge_graph(v[idx], edges)
    hops = graph.copy()
    hops.data[:] = 1.0
    on = axes.on_axis[idx]
    off = dijkstra(hops, indices=np.flatnonzero(~on), min_only=True)
    mean_edge = np.linalg.norm(v[idx][edges[:, 0]] - v[idx][edges[:, 1]], axis=1).mean()
    from_base = dijkstra(graph, indices=np.flatnonzero(axes.base[idx]), min_only=True)
    tip = int(np.searchsorted(idx, axes.tip[p]))
    x = axes.x[idx]
    centred = v[idx] - v[idx].mean(axis=0)
    extent = np.ptp(centred @ np.linalg.svd(centred, full_matrices=False)[2][0])
    return (x.min(), x.max(), off[on].max(), on.sum() / (from_base[tip] / mean_edge),
            from_base[tip] / extent)


def test_a_flat_sheet_is_not_mirrored_about_the_plane_it_lies_in():
    v, f, _ = flat_petal(widest=0.5)  # an oval: two mirror planes across the sheet
    plane, err = symmetry.mirror_plane(v)  # was (0, 0, 1, 0): the sheet's own, err 0
    assert abs(plane[2]) < 1e-6 and err < 1e-9
    assert symmetry.center_plane_fault(v, np.array([0.0, 0.0, 1.0, 0.0])).startswith(
        "the sheet lies in it")


def test_a_rolled_petal_mirrored_only_across_its_length_is_refused_not_grown_crosswise():
    """A rolled oval petal, one side wider: mirror-symmetric across its length (about
    x = 12), not along it. The most symmetric plane cuts it crosswise, so its axis would
    run across it (half as long as the petal): refused, naming the key."""
    v, f, petal = flat_petal(widen=1.3, roll=2.0, widest=0.5)
    across = np.array([1.0, 0.0, 0.0, 0.5 * v[:, 0].max()])
    assert symmetry.asymmetry(v, across) < 1e-9
    with pytest.raises(BadPetal, match="petal 0: its axis is .* as long as the petal") as err:
        find_axes(v, f, petal)
    assert err.value.key == "scene.exclude"


def test_in_a_file_of_many_flowers_a_petal_with_no_sound_axis_is_held_as_modelled():
    """Two flowers apart (lone petals of their own flower each, in one file): the rolled
    oval petal above, whose axis would run across it, is held as modelled (every vertex
    fixed, s and x 0, named with why) with ``hold_bad``; the other petal's axes are what
    they are without it. Without ``hold_bad`` it is refused as before."""
    good = flat_petal()
    bad = flat_petal(widen=1.3, roll=2.0, widest=0.5)
    shift = np.array([0.0, 40.0, 0.0])
    v = np.vstack([good[0], bad[0] + shift])
    f = np.vstack([good[1], bad[1] + len(good[0])])
    petal = np.concatenate([good[2], bad[2] + 1])
    flower = np.array([0, 1])
    with pytest.raises(BadPetal, match="petal 1: its axis is"):
        find_axes(v, f, petal, flower=flower)
    axes = find_axes(v, f, petal, flower=flower, hold_bad=True)
    assert [p for p, _ in axes.held] == [1] and "as long as the petal" in axes.held[0][1]
    mine = petal == 1
    assert axes.base[mine].all() and not axes.on_axis[mine].any()
    assert np.all(axes.s[mine] == 0.0) and np.all(axes.x[mine] == 0.0)
    alone = find_axes(*good)
    other = petal == 0
    for name in ("base", "on_axis", "s", "x"):
        assert np.array_equal(getattr(axes, name)[other], getattr(alone, name)), name
    assert axes.tip[0] == alone.tip[0]


@pytest.mark.parametrize("widen, roll", [(1.0, 0.0), (1.15, 0.0), (1.15, 0.5)])
def test_a_flat_or_rolled_petal_has_a_line_for_its_axis_and_x_on_both_sides(widen, roll):
    """The flat ones were dimontel's failure (all on the axis, x in [0, 1]). An
    unsymmetrized petal's axis is the end nearer the plane of each edge crossing it: one
    vertex wide, not a band of two."""
    v, f, petal = flat_petal(widen=widen, roll=roll)
    axes = find_axes(v, f, petal)
    xmin, xmax, depth, per_edge, reach = line_figures(v, f, petal, axes)
    assert xmin == -1.0 and xmax == 1.0
    assert depth <= 2.0 and per_edge <= 2.5, (depth, per_edge)  # measured 1-2 and 1.0-2.1
    assert reach > 0.9


def test_axis_depth_tells_a_line_from_a_region():
    v, f, petal = flat_petal()
    edges, _, _ = topology.unique_edges(f)
    graph = topology.edge_graph(v, edges)
    graph.data[:] = 1.0
    line = np.abs(v[:, 1]) < 1e-9
    band = np.abs(v[:, 1]) < 2.6
    assert axis_depth(graph, line) == 1.0
    assert axis_depth(graph, band) >= 2.0
    assert axis_depth(graph, np.ones(len(v), bool)) == np.inf
    assert axis_depth(graph, np.zeros(len(v), bool)) == 0.0


def write_remesh(path, v, f, p, part_name):
    with artifact.writing(path, stage="remesh", config_json="{}", inputs={},
                          attrs={"scale": 1.0}) as h5:
        artifact.put(h5, "mesh/vertices", v)
        artifact.put(h5, "mesh/faces", f.astype(np.int64))
        artifact.put(h5, "mesh/petal", p)
        h5.create_dataset("mesh/part_names", data=[part_name], dtype=h5py.string_dtype("utf-8"))
        artifact.put(h5, "mesh/part", np.zeros(len(v), dtype=np.int64))
    return path


def test_a_petal_whose_plane_lies_in_it_is_refused_naming_the_part_and_the_key(tmp_path,
                                                                               monkeypatch):
    """Where no center plane can be found (here: forced to the sheet's own), the stage
    refuses the petal in one line naming it, its part and scene.exclude, and writes
    nothing; the library raises BadPetal with that key."""
    v, f, petal = flat_petal(widen=1.3)
    monkeypatch.setattr(symmetry, "mirror_plane",
                        lambda points, refine=True: (np.array([0.0, 0.0, 1.0, 0.0]), 0.0))
    with pytest.raises(BadPetal, match="petal 0: its axis is a region, not a line") as err:
        find_axes(v, f, petal)
    assert err.value.key == "scene.exclude"
    remesh = write_remesh(tmp_path / "remesh.h5", v, f, petal, "petal.2")
    r = CliRunner().invoke(cli, ["-q", "axis", str(remesh), "--out", str(tmp_path / "axis.h5")])
    assert r.exit_code != 0
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.output, r.output
    assert "petal 0 (petal.2): its axis is a region" in lines[0]
    assert 'scene.exclude = ["petal.2"]' in lines[0] and str(remesh) in lines[0]
    assert not (tmp_path / "axis.h5").exists()


MODELS = ["chianti_petal1.obj", "chianti_flower5.obj", "souki202_petal.obj",
          "pchinyun_petal.obj", "ericrius1_petal.obj", "dimontel_petal.obj",
          "clach_flower.obj", "bulat66_lily.glb", "hallgeirl_petals.obj", "ssajeev_daisy.obj"]


@needs_shared
@pytest.mark.parametrize("name", MODELS)
def test_every_petal_of_the_external_models_has_a_sane_axis(tmp_path, name):
    """Default config (scene.mesh only). Measured on the 50 petals: x [-1, 1], depth 1,
    1.0-1.24 on-axis vertices per mean edge of the axis, reach 0.87-1.05 (0.96-1.0 before
    the shell's band reached 8% of the length along the surface: ericrius1 0.87), every base
    nearer the flower's axis than its tip. Before: dimontel's 68 of 103 vertices on its
    axis (depth 3, 5.3 per edge, x [0, 1]); five of hallgeirl's tubes cut across
    (reach 0.42-0.69, axes 6-7 vertices long)."""
    config = tmp_path / "scene.toml"
    config.write_text(f'[scene]\nmesh = "{EXTERNAL / name}"\n')
    for stage, src, dst in (("remesh", None, "r.h5"), ("axis", "r.h5", "a.h5")):
        args = ["-q", stage] + ([str(tmp_path / src)] if src else [])
        r = CliRunner().invoke(cli, args + ["--config", str(config), "--out", str(tmp_path / dst)])
        assert r.exit_code == 0, r.output
    with h5py.File(tmp_path / "a.h5") as h:
        v, f, petal = h["mesh/vertices"][()], h["mesh/faces"][()], h["mesh/petal"][()]
        line = h.attrs["flower_axis"]

        class Axes:
            base, on_axis, tip, x = (h["axis/base"][()], h["axis/on_axis"][()],
                                     h["axis/tip"][()], h["axis/x"][()])
    for p in range(int(petal.max()) + 1):
        xmin, xmax, depth, per_edge, reach = line_figures(v, f, petal, Axes, p)
        assert (xmin, xmax) == (-1.0, 1.0), (p, xmin, xmax)
        assert depth == 1.0 and per_edge <= 1.5, (p, depth, per_edge)
        assert reach > 0.8, (p, reach)
        if np.all(np.isfinite(line)):
            def off_axis(points):
                r = points - line[:3]
                return np.linalg.norm(r - np.outer(r @ line[3:], line[3:]), axis=1)
            mine = petal == p
            assert off_axis(v[Axes.base & mine]).mean() < off_axis(v[[Axes.tip[p]]])[0], p


@needs_shared
def test_dimontels_petal_opens_with_the_default_config(tmp_path):
    """Remeshed, unsymmetrized (its mirrored remesh keeps a needle): it opened -1.0 deg
    with its axis a region. Now (a flat petal: an open start): with the model's own
    curvature kept in the bud, its bud at growth.close 1 was only 8.7 deg more closed
    than the model (its rim's growth undone curls it across) and the search closed twice
    as far (53.2 deg); with the bud cupped and not rolled back (growth.cup,
    growth.recurve: 83% of its squared curvature is recurve), growth.close 1 finds a bud
    0.53 petal lengths away that opens 27.3 deg back onto the model."""
    out = {}
    src = str(EXTERNAL / "dimontel_petal.obj")
    for stage, dst in (("remesh", "r.h5"), ("axis", "a.h5"), ("growth", "g.h5"),
                       ("simulate", "s.h5")):
        r = CliRunner().invoke(cli, ["-q", stage, src, "--out", str(tmp_path / dst)])
        assert r.exit_code == 0, r.output
        out[stage] = r.output
        src = str(tmp_path / dst)
    with h5py.File(tmp_path / "s.h5") as h:
        assert h["diagnostics/opening_angle_per_petal"][-1, 0] > 20.0  # (reverse.CLOSED)
        assert h.attrs["bud_close"] == 1.0 and h.attrs["bud_distance"] > 0.3
        assert h.attrs["recurve_share"] > 0.5
        assert h.attrs["distance_to_model"] < 1e-3


@needs_shared
def test_an_open_petal_whose_lifted_bud_blooms_elsewhere_is_searched_again(tmp_path,
                                                                           monkeypatch):
    """ericrius1's petal, default config: the bud the closing lift picked once bloomed
    forward onto another equilibrium, 0.27 petal lengths from the model, and the run
    called that sound. A bloom off its model (over report.OFF_MODEL) searches again
    along the model's own path (no lift) and keeps the bloom that ends nearer the model
    (then, still over the bound, along it with the lift faded: reverse.lift_faded).
    (Since the band is clamped to the nearest row, this petal's lifted bud blooms back
    onto its model, 5.6e-9 petal lengths away: the bound is lowered under that here so
    that the second search runs; and the petal, of 159 vertices, is solved as it is, as
    when this was found: cut finer, its bud is found along its own path from the start,
    with no lift to search again without.)"""
    monkeypatch.setattr(report, "OFF_MODEL", 1e-12)
    src = str(EXTERNAL / "ericrius1_petal.obj")
    for stage, dst in (("remesh", "r.h5"), ("axis", "a.h5"), ("growth", "g.h5"),
                       ("simulate", "s.h5")):
        more = ["--set", "simulate.petal_vertices=0"] if stage == "simulate" else []
        r = CliRunner().invoke(cli, [stage, src, "--out", str(tmp_path / dst), *more])
        assert r.exit_code == 0, r.output
        src = str(tmp_path / dst)
    assert "searching again along the model's own path" in r.output
    kept = re.search(r"without the lift the bloom ends (\S+) petal lengths from the model: "
                     r"(kept|the first one kept)", r.output)
    assert kept, r.output
    faded = re.search(r"with the lift faded the bloom ends \S+ petal lengths from the model"
                      r"[^:]*: kept", r.output)  # (the third search, still over the bound)
    with h5py.File(tmp_path / "s.h5") as h:
        assert h.attrs["bud_path"] == ("faded" if faded else
                                       "own" if kept[2] == "kept" else "lifted")
        assert h.attrs["distance_to_model"] < 1e-3
        assert h.attrs["bud_distance"] > 0.5
        assert h["diagnostics/opening_angle_per_petal"][-1, 0] > 20.0
    assert not list(tmp_path.glob(".*checkpoint*"))


@needs_shared
@pytest.mark.studio
def test_a_daisy_whose_blooms_end_off_it_both_ways_keeps_the_nearest_and_says_so(tmp_path):
    """The first daisy of the daisy bush, picked (scene.flower = 0), default config: its
    lifted bud's rays jam edge on and bloom forward onto another equilibrium (0.107 to
    0.148 petal lengths off), its own path's bud hangs open the other way, and it is
    searched for again along its own path with the lift faded into the rest state
    (reverse.lift_faded). Which bloom comes out is decided by rounding at the forks of
    the path: on one CPU the faded path's bloom ended on the model (under 1e-6), on two
    others 0.092 off, or the own path's was kept. What holds on any: every search runs,
    the bloom kept is the nearest of those from a bud more closed than the model, and
    the summary says whether it is back on the model, with its figure."""
    scene = tmp_path / "scene.toml"
    scene.write_text(f'[scene]\nmesh = "{EXTERNAL / "mitagki_daisybush.glb"}"\nflower = "0"\n')
    src: list = []
    for stage, dst in (("remesh", "r.h5"), ("axis", "a.h5"), ("growth", "g.h5"),
                       ("simulate", "s.h5")):
        r = CliRunner().invoke(cli, [stage, *src, "--config", str(scene), "--out",
                                     str(tmp_path / dst)])
        assert r.exit_code == 0, r.output
        src = [str(tmp_path / dst)]
    assert "searching again along the model's own path with the closing lift" in r.output
    first = re.search(r"the bloom ends (\S+) petal lengths \(RMS\) from the model \(over", r.output)
    faded = re.search(r"with the lift faded the bloom ends (\S+) petal lengths from the model"
                      r"[^:]*: (kept|the one)", r.output)
    assert first and faded, r.output
    with h5py.File(tmp_path / "s.h5") as h:
        distance = h.attrs["distance_to_model"]
        assert (h.attrs["bud_path"] == "faded") == (faded[2] == "kept")
        assert distance <= float(first[1]) * 1.001 and distance <= float(faded[1]) * 1.001
        assert h.attrs["bud_closed"] > 0.0
        summary = h.attrs["summary"]
        if distance > report.OFF_MODEL:
            assert summary.startswith("unsound") and f"{distance:.2g}" in summary, summary
        assert summary.startswith("sound") or "from the model" in summary, summary
