"""Scene files are checked on load; errors name the file and the key."""

import numpy as np
import pytest

from pipeline.config import KEYS, load_config
from pipeline.errors import BloomError
from pipeline.expr import evaluate_curve, parse_curve
from tests.conftest import ROOT


def write(tmp_path, text, name="scene.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_defaults_load_and_cover_the_contract_keys():
    cfg = load_config(None)
    for key in ("scene.mesh", "remesh.target_edge", "remesh.symmetrize", "growth.curve",
                "simulate.steps", "simulate.frames", "simulate.h", "simulate.eta",
                "simulate.integrator", "simulate.stretch_stiffness",
                "simulate.bending_stiffness", "effects.curl.beta", "effects.wrinkles.alpha_add"):
        assert key in KEYS
    for effect in ("curl", "wrinkles", "connections", "center_plane"):
        assert cfg[f"effects.{effect}.enabled"] is False
    # contact is decided from the model (on where two petals can meet), as is the start
    assert cfg["effects.collisions.enabled"] == "auto"
    assert cfg["growth.start"] == "auto"
    assert cfg["simulate.stretch_stiffness"] == 0.1 and cfg["simulate.bending_stiffness"] == 0.0005


@pytest.mark.parametrize("name", sorted(p.name for p in (ROOT / "configs").glob("*.toml")))
def test_shipped_scenes_are_valid(name):
    cfg = load_config(ROOT / "configs" / name)
    assert cfg.mesh_path().exists()


@pytest.mark.parametrize("text, key, words", [
    ("[simulate]\nstepz = 3\n", "simulate.stepz", "unknown key (did you mean simulate.steps?)"),
    ("[simulat]\nsteps = 3\n", "simulat", "unknown section"),
    ("[simulate]\nsteps = 'many'\n", "simulate.steps", "expected an integer"),
    ("[simulate]\nsteps = 2.5\n", "simulate.steps", "expected an integer"),
    ("[simulate]\nsteps = -4\n", "simulate.steps", "must be >= 1"),
    ("[simulate]\nh = 0\n", "simulate.h", "must be > 0"),
    ("[simulate]\neta = 0.7\n", "simulate.eta", "must be <= 0.5"),
    ("[simulate]\neta = -0.1\n", "simulate.eta", "must be >= 0"),
    ("[remesh]\nsymmetrize = 1\n", "remesh.symmetrize", "expected true or false"),
    ("[growth]\ncurve = 'x +* 2'\n", "growth.curve", "not an expression of x"),
    ("[growth]\ncurve = '__import__(\"os\")'\n", "growth.curve", "may be called"),
    ("[growth]\ncurve = 'y**2'\n", "growth.curve", "unknown name 'y'"),
    ("[growth]\ncurve = '1/x'\n", "growth.curve", "not finite"),
    ("[growth]\nschedule = 'cubic'\n", "growth.schedule", "must be one of"),
    ("[effects.curl]\nenabled = 'yes'\n", "effects.curl.enabled", "expected true or false"),
    ("[simulate]\nsteps = 10\nframes = 50\n", "simulate.frames", "need at least"),
    ("[render]\ncolor = 'pinkish'\n", "render.color", "is not a colour"),
    ("[simulate\n", None, "not valid TOML"),
])
def test_bad_scene_files_name_the_file_and_key(tmp_path, text, key, words):
    path = write(tmp_path, text)
    with pytest.raises(BloomError) as err:
        load_config(path)
    msg = str(err.value)
    assert msg.startswith(str(path) + ": ")
    if key:
        assert key in msg
    assert words in msg
    assert "\n" not in msg


def test_missing_config_file(tmp_path):
    with pytest.raises(BloomError, match="config file not found"):
        load_config(tmp_path / "nope.toml")


def test_overrides_are_typed_and_checked(tmp_path):
    path = write(tmp_path, "[simulate]\nsteps = 100\n")
    cfg = load_config(path, ["simulate.steps=250", "growth.curve=0.1*x**2",
                             "effects.curl.enabled=true", "simulate.eta=0"])
    assert cfg["simulate.steps"] == 250
    assert cfg["growth.curve"] == "0.1*x**2"
    assert cfg["effects.curl.enabled"] is True
    assert cfg["simulate.eta"] == 0.0
    with pytest.raises(BloomError, match=r"^--set: simulate.eta: must be <= 0.5"):
        load_config(path, ["simulate.eta=2"])
    with pytest.raises(BloomError, match="unknown key"):
        load_config(path, ["simulate.nope=2"])
    with pytest.raises(BloomError, match="expected section.key=value"):
        load_config(path, ["simulate.steps"])


def test_mesh_path_is_relative_to_the_config_file(tmp_path):
    sub = tmp_path / "scenes"
    sub.mkdir()
    path = write(sub, "[scene]\nmesh = '../assets/a.obj'\n")
    assert load_config(path).mesh_path() == sub / "../assets/a.obj"


def test_a_mesh_given_by_set_is_relative_to_the_working_folder(tmp_path, monkeypatch):
    """``--set scene.mesh=x.obj`` beside ``--config scenes/s.toml``: the path typed on the
    command line is from where it was typed (``make accuracy`` wrote its meshes under
    outputs/ and looked for them under configs/outputs/)."""
    sub = tmp_path / "scenes"
    sub.mkdir()
    path = write(sub, "[scene]\nmesh = '../assets/a.obj'\n")
    monkeypatch.chdir(tmp_path)
    cfg = load_config(path, ["scene.mesh=out/b.obj"])
    assert cfg.mesh_path() == tmp_path / "out" / "b.obj"
    assert load_config(None, ["scene.mesh=b.obj"]).mesh_path() == tmp_path / "b.obj"


def test_growth_curves_evaluate_without_eval():
    x = np.linspace(-1, 1, 5)
    np.testing.assert_allclose(evaluate_curve("0.2*x**2", x), 0.2 * x ** 2)
    np.testing.assert_allclose(evaluate_curve("0.2*x**6", x), 0.2 * x ** 6)
    np.testing.assert_allclose(evaluate_curve("0.1", x), 0.1)
    np.testing.assert_allclose(evaluate_curve("0.15*abs(x)**1.5 - 0.01", x), 0.15 * np.abs(x) ** 1.5 - 0.01)
    for bad in ("x.real", "[x]", "(lambda: 1)()", "x if x else 1", "open('f')", "x[0]", "x == 1"):
        with pytest.raises(ValueError):
            parse_curve(bad)
