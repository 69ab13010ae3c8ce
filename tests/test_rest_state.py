"""The growth stage refuses a rest state that is not a sound equilibrium (degenerate
triangles), naming the petal, before any time is spent simulating it."""

import shutil

import h5py
import numpy as np
from click.testing import CliRunner

from pipeline.sim.build import REST_STIFFNESS, rest_stiffness
from stages.cli import cli
from tests.conftest import prepared


def _collapse_one_triangle(v, f, petal_of_vertices, which: int = 0):
    """Move the third vertex of an interior face of petal ``which`` to 1e-9 mean edges
    off the midpoint of the face's first edge: that face becomes a sliver."""
    from pipeline.mesh import topology

    boundary = topology.boundary_vertices(f, len(v))
    faces = [t for t in f if not boundary[t].any() and petal_of_vertices[t[0]] == which]
    a, b, c = faces[len(faces) // 2]
    v = v.copy()
    normal = np.cross(v[b] - v[a], v[c] - v[a])
    v[c] = 0.5 * (v[a] + v[b]) + 1e-9 * normal / np.linalg.norm(normal)
    return v


def test_a_sound_mesh_is_a_stiff_rest_state_of_a_few_k_s():
    v, f, petal, axes, growth = prepared(3, 450)
    stiff = rest_stiffness(v, growth, petal, axes.base, 0.1, 0.0005)
    assert stiff.shape == (3,)
    assert np.all(stiff > 1.0) and np.all(stiff < 10.0)  # measured 5.0-7.3


def test_a_sliver_makes_the_rest_state_unsound_in_its_own_petal_only():
    v, f, petal, axes, growth = prepared(3, 450)
    bad = _collapse_one_triangle(v, f, petal, which=1)
    stiff = rest_stiffness(bad, growth, petal, axes.base, 0.1, 0.0005)
    assert stiff[1] > 1e3 * REST_STIFFNESS
    assert stiff[0] < 10.0 and stiff[2] < 10.0


def test_growth_refuses_an_unsound_rest_state_in_one_line(tmp_path):
    mesh, scene = tmp_path / "bud.obj", tmp_path / "scene.toml"
    scene.write_text('[scene]\nmesh = "bud.obj"\n')
    run = CliRunner().invoke
    assert run(cli, ["asset", "bud", "--petals", "3", "--vertices", "360", "--out", str(mesh)]).exit_code == 0
    assert run(cli, ["remesh", "--config", str(scene), "--out", str(tmp_path / "r.h5")]).exit_code == 0
    assert run(cli, ["axis", str(tmp_path / "r.h5"), "--out", str(tmp_path / "a.h5")]).exit_code == 0
    good = run(cli, ["growth", str(tmp_path / "a.h5"), "--out", str(tmp_path / "g.h5")])
    assert good.exit_code == 0, good.output
    broken = tmp_path / "broken.h5"
    shutil.copy(tmp_path / "a.h5", broken)
    with h5py.File(broken, "a") as h5:
        v, f, petal = h5["mesh/vertices"][()], h5["mesh/faces"][()], h5["mesh/petal"][()]
        h5["mesh/vertices"][...] = _collapse_one_triangle(v, f, petal, which=2)
    r = run(cli, ["growth", str(broken), "--out", str(tmp_path / "g2.h5")])
    assert r.exit_code == 1
    assert len(r.output.strip().splitlines()) == 1 and "Traceback" not in r.output
    assert "petal 2 " in r.output and str(broken) in r.output
    assert not (tmp_path / "g2.h5").exists()
