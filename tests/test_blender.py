"""Blender reads Bloom's USD: where the optional `bpy` wheel is installed
(`pip install '.[blender]'`), Blender imports bloom.usdc headless and its evaluated
vertex positions match sim.h5 (at the input's scale) at several frames."""

import json
import subprocess
import sys

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from stages.cli import cli
from tests.conftest import ROOT


def _has_bpy() -> bool:
    probe = subprocess.run([sys.executable, "-c", "import bpy"], capture_output=True)
    return probe.returncode == 0


@pytest.mark.skipif(not _has_bpy(), reason="bpy (Blender as a module) is not installed")
def test_blender_imports_the_usd_and_sees_the_same_points(tmp_path):
    from pxr import Usd, UsdGeom

    runner = CliRunner()
    mesh, prev = tmp_path / "bud.obj", None
    assert runner.invoke(cli, ["asset", "bud", "--petals", "2", "--vertices", "200",
                               "--out", str(mesh)]).exit_code == 0
    short = ["--set", "simulate.steps=3000", "--set", "simulate.frames=7"]
    for stage in ("remesh", "axis", "growth", "simulate"):
        out = tmp_path / f"{stage}.h5"
        args = [stage, "--set", f"scene.mesh={mesh}"] if prev is None else [stage, str(prev)]
        r = runner.invoke(cli, [*args, "--out", str(out), *short])
        assert r.exit_code == 0, r.output
        prev = out
    usd = tmp_path / "bloom.usdc"
    # the simulation sheet itself (export.mesh = "sheet"); the user's parts are the next test
    assert runner.invoke(cli, ["export", str(prev), "--out", str(usd),
                               "--set", "export.mesh=sheet"]).exit_code == 0
    frames = [0, 3, 6]
    r = subprocess.run([sys.executable, str(ROOT / "tests" / "blender" / "evaluated_points.py"),
                        str(usd), ",".join(map(str, frames))], capture_output=True, text=True,
                       timeout=300)
    line = next(x for x in r.stdout.splitlines() if x.startswith("JSON"))
    got = json.loads(line[4:])
    assert got["names"] == ["petal_00", "petal_01"]
    # metersPerUnit 1 (export.meters_per_unit): Blender's points are the USD's, unscaled
    assert UsdGeom.GetStageMetersPerUnit(Usd.Stage.Open(str(usd))) == 1.0
    with h5py.File(prev) as f:
        pos = f["frames/positions"][()] / f.attrs["scale"]
        petal = f["mesh/petal"][()]
    order = np.concatenate([np.flatnonzero(petal == p) for p in range(petal.max() + 1)])
    for t in frames:
        blender = np.asarray(got["points"][str(t)])
        np.testing.assert_allclose(blender, pos[t][order], atol=1e-5 * np.abs(pos).max())
    assert not np.allclose(pos[0], pos[-1])  # the frames differ: time samples were read


@pytest.mark.skipif(not _has_bpy(), reason="bpy (Blender as a module) is not installed")
def test_blender_imports_the_users_parts(tmp_path):
    """export.mesh = "input": Blender sees the input's parts under their (prim) names,
    with the input's vertex counts, UVs per face corner and material names, and the last
    frame's positions are the input deformed by sim.h5 through the binding."""
    from tests.test_asset_back import maya_obj, run_chain

    mesh = tmp_path / "flower.obj"
    maya_obj(mesh)
    sim = run_chain(mesh, tmp_path, "--set", 'scene.petals=["petal"]')
    _blender_sees_the_asset(mesh, sim, tmp_path / "bloom.usdc", 8)


@pytest.mark.skipif(not _has_bpy(), reason="bpy (Blender as a module) is not installed")
def test_blender_imports_the_lily_as_its_18_meshes(tmp_path):
    """The Blender glTF lily (bulat66_lily.glb) back into Blender: its 18 meshes under
    their names, vertex counts, UVs and materials, the tepals deformed as sim.h5 says."""
    from tests.test_asset_back import SHARED, run_chain

    lily = SHARED / "bulat66_lily.glb"
    if not lily.exists():
        pytest.skip("../shared/external-meshes is not here")
    sim = run_chain(lily, tmp_path, "--set", "remesh.petal_vertices=300")
    got = _blender_sees_the_asset(lily, sim, tmp_path / "bloom.usdc", 8)
    assert len(got) == 18


def _blender_sees_the_asset(mesh, sim, usd, frame):
    """Export sim.h5 to USD, import it in Blender headless and compare every part with the
    input (names, counts, polygon corners, UVs, materials) and with its frame through the
    binding. Returns what Blender saw."""
    from pipeline.io import binding, export, userasset

    assert CliRunner().invoke(cli, ["export", str(sim), "--out", str(usd)]).exit_code == 0
    r = subprocess.run([sys.executable, str(ROOT / "tests" / "blender" / "asset_report.py"),
                        str(usd), str(frame)], capture_output=True, text=True, timeout=300)
    got = json.loads(next(x for x in r.stdout.splitlines() if x.startswith("JSON"))[4:])
    asset = userasset.read_asset(mesh)
    with h5py.File(sim) as f:
        frames = export.asset_frames(f["frames/positions"][()], f["mesh/faces"][()], asset,
                                     binding.read_bindings(f), f.attrs["scale"])
    assert sorted(got) == sorted(export.prim_names(asset.names))
    for name, part, pts in zip(export.prim_names(asset.names), asset.parts, frames, strict=True):
        seen = got[name]
        assert seen["vertices"] == len(part.points) and seen["faces"] == len(part.face_counts)
        assert seen["loops"] == part.face_indices.tolist()  # Blender keeps the polygons' order
        assert sorted(seen["materials"]) == sorted(export.prim_names(part.materials))
        if part.uv is not None:
            # glTF's UVs are per vertex: the corners index them through the faces
            corners = part.uv_indices if part.uv_indices is not None else part.face_indices
            np.testing.assert_allclose(seen["uv"], part.uv[corners], atol=1e-6)
        last = pts[frame] if pts.ndim == 3 else pts
        # metersPerUnit 0.01: Blender scales the objects, not their local points
        np.testing.assert_allclose(seen["points"], last, atol=1e-5 * np.abs(last).max())
    return got


@pytest.mark.skipif(not _has_bpy(), reason="bpy (Blender as a module) is not installed")
def test_blender_imports_a_bush_of_staggered_flowers(tmp_path):
    """Three flowers of one file, each from its own bud and staggered (issue 29), in one
    USD: Blender sees a mesh per petal, and at the first frame, at the latest flower's
    start and at the end, the points the run and the stagger say."""
    from tests.test_flowers import staggered_bush_frames, staggered_bush_usd

    usd, sim, starts = staggered_bush_usd(tmp_path)
    want = staggered_bush_frames(sim, starts)
    frames = [0, int(starts.max()), 4 + int(starts.max())]
    r = subprocess.run([sys.executable, str(ROOT / "tests" / "blender" / "evaluated_points.py"),
                        str(usd), ",".join(map(str, frames))], capture_output=True, text=True,
                       timeout=300)
    got = json.loads(next(x for x in r.stdout.splitlines() if x.startswith("JSON"))[4:])
    assert len(got["names"]) == 15
    assert not np.allclose(want[frames[0]], want[frames[-1]])
    for t in frames:
        np.testing.assert_allclose(np.asarray(got["points"][str(t)]), want[t],
                                   atol=1e-5 * np.abs(want).max())
