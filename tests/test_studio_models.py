"""Flowers as studios export them (issue 29): a whole flower in one mesh, many flowers in
one file, 50,000 to 100,000 faces. The five models in ../shared/external-meshes (skipped
when absent) through remesh, axis and growth with the default config; petals found,
flowers found, the share of petal area kept. Slow: each is one to two minutes here, so
these are marked ``studio`` and left out of the default run (``make test-studio``)."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from pipeline.review import report
from tests.test_real_input import EXTERNAL, needs_shared, run, run_stages

#: model -> (least petals found, flowers, least share of the input's petal area kept)
MODELS = {
    "fabrication123_waterlily.glb": (40, 1, 0.9),
    "resonate_lotus.glb": (16, 1, 0.9),
    "manmeet_tulip.glb": (6, 1, 0.9),
    "mitagki_daisybush.glb": (160, 10, 0.85),
    "mitagki_roses.glb": (250, 5, 0.9),
}


def _scene(tmp_path, name):
    """A config file holding only the mesh: the default config."""
    scene = tmp_path / "scene.toml"
    scene.write_text(f'[scene]\nmesh = "{EXTERNAL / name}"\n')
    return scene


@pytest.mark.slow
@pytest.mark.studio
@needs_shared
@pytest.mark.parametrize("name", sorted(MODELS))
def test_studio_model_through_remesh_axis_growth(tmp_path, name):
    least, flowers, area = MODELS[name]
    scene = _scene(tmp_path, name)
    code, out = run("remesh", "--config", scene, "--out", tmp_path / "r.h5")
    assert code == 0 and "Traceback" not in out, out
    assert "petal(s) found" in out and "of the input's petal area kept" in out
    with h5py.File(tmp_path / "r.h5") as h:
        petals = int(h.attrs["petal_count"])
        assert least <= petals
        assert h.attrs["flower_count"] == flowers
        per_petal = h["flower/petal_flower"][()]
        assert np.array_equal(np.bincount(per_petal), np.full(flowers, petals // flowers))
        assert np.array_equal(h["mesh/flower"][()], per_petal[h["mesh/petal"][()]])
        found = json.loads(h.attrs["petals_found"])
        kept = sum(r["area_in"] * r["area_kept"] for r in found.values()) / sum(
            r["area_in"] for r in found.values())
        assert kept >= area, found
        # (pairs too far into each other to part are left as modelled, recorded)
        left = json.loads(h.attrs["separation"])["left"]
        assert h["mesh/left"][()].tolist() == left
    for stage, src, dst in (("axis", "r.h5", "a.h5"), ("growth", "a.h5", "g.h5")):
        code, out = run(stage, tmp_path / src, "--config", scene, "--out", tmp_path / dst)
        assert code == 0 and "Traceback" not in out, out
    with h5py.File(tmp_path / "g.h5") as h:
        axis = h["flower/axis"][()]
        assert axis.shape == (flowers, 6) and np.all(np.isfinite(axis))
        assert np.isfinite(h["growth/alpha"][()]).all()


@pytest.mark.slow
@pytest.mark.studio
@needs_shared
def test_the_water_lily_keeps_its_petals_and_its_receptacle_is_kept_apart(tmp_path):
    """One mesh of 47 pieces: 44 petals in whorls, a receptacle, a centre piece and a
    stem. The petals are simulated, the other pieces are kept under input/parts."""
    code, out = run("remesh", EXTERNAL / "fabrication123_waterlily.glb", "--out", tmp_path / "r.h5")
    assert code == 0, out
    assert "a whole flower in one mesh (47 pieces): 44 petals" in out
    with h5py.File(tmp_path / "r.h5") as h:
        assert h.attrs["petal_count"] == 44
        kept = h["input/parts/0/faces"][()]
        assert 0 < len(kept) < 4616 - 44 * 64 + 1  # the receptacle, centre and stem: not petals
        assert json.loads(h.attrs["petals_found"])["node_id33"]["area_kept"] > 0.9


@pytest.mark.slow
@pytest.mark.studio
@needs_shared
def test_one_daisy_of_the_bush_by_index_and_by_part(tmp_path):
    """scene.flower picks one flower of the ten: by its index, or by a petal part's name."""
    mesh = EXTERNAL / "mitagki_daisybush.glb"
    for pick in ("3", "Object_20"):
        code, out = run("remesh", mesh, "--out", tmp_path / "r.h5", "--set", f"scene.flower={pick}",
                        "--overwrite")
        assert code == 0, out
        with h5py.File(tmp_path / "r.h5") as h:
            assert h.attrs["petal_count"] == 16 and h.attrs["flower_picked"] == 3
            names = list(h["mesh/part_names"].asstr()[()])
            assert {names[i] for i in np.unique(h["mesh/part"][()])} == {"Object_20"}


@pytest.mark.slow
@pytest.mark.studio
@needs_shared
def test_a_daisy_of_the_bush_blooms_forward_from_a_closed_bud(tmp_path):
    """The daisy bush's first daisy alone (``scene.flower = 0``), default config. Its
    lifted bud blooms to 0.07 petal lengths off the flat model, so the bud is searched
    again along the model's own path; that bud's petals hang 40 deg further open than the
    model's, and its "bloom" lifted them up to flat (the bush's every daisy did, before).
    The bud that hangs open the other way is not kept over a closed one: the bloom is
    forward, from a bud more closed than the model. With the bud's shape (growth.cup,
    growth.recurve) that bud is 22.4 deg more closed than the model (5.9 before), but the
    bloom still ends 0.107 petal lengths off it and two of its sixteen petals open only
    2 deg (pressed under their neighbours; every petal opened before, from the less
    closed bud): measured, not fixed. With x from the signed distance from the midrib
    the bud is 17.1 deg more closed, not 22.4: under the 20 deg issue 28 asks of an open
    model's bud (the bound below keeps it from falling further; not met), and four of its
    petals open under 5 deg (12 of 16 over it, not 14; median 24.9 deg, over 30 before):
    a regression of this daisy, taken for the lotus's sound bloom and x's accuracy
    (docs/performance.md). Both blooms (from the lifted bud and from the own path's)
    close first (25.6 and 33.1 deg), and each path back's bud hangs open the other way
    (half its petals curl in over the disc, half hang straight down under it: -71.6 deg,
    the lower median), so each starts from its most closed frame (A = 0.23, 0.40): the
    own path's then ends nearer the model (0.129 petal lengths, the lifted 0.148) from a
    bud 17.2 deg more closed, every petal opening (least 7.2 deg): still off the model."""
    scene = tmp_path / "scene.toml"
    scene.write_text(f'[scene]\nmesh = "{EXTERNAL / "mitagki_daisybush.glb"}"\nflower = "0"\n')
    out = run_stages(tmp_path, scene)
    assert "its bud hangs open the other way" in out and "most closed frame" in out, out
    with h5py.File(tmp_path / "s.h5") as h:
        assert "bloom_path" not in h.attrs  # (not the path back)
        assert h.attrs["bud_closed"] > 10.0 and h.attrs["bud_growth"] > 0.0
        opening = h["diagnostics/opening_angle_per_petal"][()]
        assert report.closing_dip(opening) <= report.CLOSES_FIRST
        assert opening[-1].min() > 5.0 and np.median(opening[-1]) > 40.0, opening[-1]


@pytest.mark.slow
@pytest.mark.studio
@needs_shared
def test_the_lotus_petals_buried_in_its_centre_are_cut_and_then_apart(tmp_path):
    """The lotus's sixteen petals are stuck into its centre, every pair through each
    other: the buried parts are cut (each petal within 40% of its area), no pair is left
    as modelled, and no petal passes through another (ipctk's exact test)."""
    from pipeline.mesh import topology
    from pipeline.mesh.separate import crossed_pairs

    code, out = run("remesh", EXTERNAL / "resonate_lotus.glb", "--out", tmp_path / "r.h5")
    assert code == 0 and "cut away the parts of petals buried" in out, out
    with h5py.File(tmp_path / "r.h5") as h:
        record = json.loads(h.attrs["separation"])
        X, F, P = h["mesh/vertices"][()], h["mesh/faces"][()], h["mesh/petal"][()]
        left = h["mesh/left"][()]
        rim = h["mesh/cut_rim"][()]
    cut = np.asarray(record["cut"])
    # the rims the cut made, where `bloom axis` holds each cut petal: on every cut petal
    assert np.array_equal(np.flatnonzero(np.bincount(P[rim], minlength=len(cut))),
                          np.flatnonzero(cut))
    assert record["left"] == [] and left.shape == (0, 2)
    assert np.count_nonzero(cut) >= 10 and 0.0 < cut.max() <= 0.4
    assert crossed_pairs(X, F, P) == []
    # every petal one sheet joined across edges (petal 11 kept a two-face flap hanging by a
    # vertex, 0.002 edges from it, which folded through it in frames 68-69 of its bloom)
    face_petal = P[F[:, 0]]
    assert all(topology.face_components(F[face_petal == p]).max() == 0
               for p in range(P.max() + 1))
