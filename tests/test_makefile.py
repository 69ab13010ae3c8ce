"""The Makefile's contract, on two tiny scenes in a scratch tree: `make` builds every
artifact, a second `make` has nothing to do, touching one scene's config reruns that
scene's stages only, and `make -j2` builds scenes side by side."""

import os
import shutil
import subprocess

import numpy as np
import pytest

from tests.conftest import ROOT

STAGES = ("remesh", "axis", "growth", "simulate", "render", "report", "export")
TINY = """[scene]
mesh = "../assets/{mesh}"
[simulate]
model = "paper"
steps = 300
frames = 3
[render]
width = 128
height = 96
"""


def _tree(path):
    """A scratch tree of the Makefile, the code (linked) and two tiny scenes at ``path``."""
    if not (ROOT / ".venv" / ".installed").exists():
        pytest.skip("needs the project's .venv (run through `make test`)")
    stamp = (ROOT / ".venv" / ".installed").stat().st_mtime
    for name in ("Makefile", "pyproject.toml", "constraints.txt"):
        shutil.copy2(ROOT / name, path / name)
        # older than the stamp, so make never reinstalls into the project's own .venv
        os.utime(path / name, (stamp - 1, stamp - 1))
    for name in ("pipeline", "stages", ".venv"):
        (path / name).symlink_to(ROOT / name)
    (path / "configs").mkdir()
    (path / "assets").mkdir()
    shutil.copy2(ROOT / "assets" / "petal.obj", path / "assets" / "petal.obj")
    for scene, mesh in (("one", "petal.obj"), ("two", "petal.obj")):
        (path / "configs" / f"{scene}.toml").write_text(TINY.format(mesh=mesh))
    return path


@pytest.fixture
def tree(tmp_path):
    return _tree(tmp_path)


@pytest.fixture(scope="module")
def _built(tmp_path_factory):
    """A tree built once with `make -j2` (and what that make printed)."""
    path = _tree(tmp_path_factory.mktemp("built"))
    return path, make(path, "-j2")


@pytest.fixture
def built(_built, tmp_path):
    """A copy of the built tree of its own (files keep their times: make sees it built)
    and the first make's output."""
    path, first = _built
    assert first.returncode == 0, first.stderr[-2000:]
    copy = tmp_path / "tree"
    shutil.copytree(path, copy, symlinks=True)
    return copy, first


def make(tree, *args):
    return subprocess.run(["make", *args], cwd=tree, capture_output=True, text=True)


def stage_commands(output: str) -> list[str]:
    """The bloom commands make ran (each line is wrapped in the log redirection)."""
    return [line[line.index(".venv/bin/bloom "):] for line in output.splitlines()
            if ".venv/bin/bloom " in line]


def test_make_builds_then_does_nothing_then_rebuilds_one_scene(built):
    tree, first = built
    for scene in ("one", "two"):
        for artifact in ("remesh.h5", "axis.h5", "growth.h5", "sim.h5", "render/bloom.mp4",
                         "report.json", "report.png", "bloom.usdc"):
            assert (tree / "outputs" / scene / artifact).exists(), (scene, artifact)
        for stage in STAGES:  # each stage's log, with what the stage said
            log = (tree / "outputs" / scene / "logs" / f"{stage}.log").read_text()
            assert stage != "simulate" or "steps of h" in log, log
    assert len(stage_commands(first.stdout)) == 14
    again = make(tree)
    assert again.returncode == 0 and stage_commands(again.stdout) == []
    assert "Nothing to be done" in again.stdout
    (tree / "configs" / "two.toml").touch()
    plan = stage_commands(make(tree, "-n").stdout)
    assert [cmd.split()[1] for cmd in plan] == list(STAGES)
    assert all("two" in cmd and "one" not in cmd for cmd in plan)


def _positions_hash(path) -> str:
    import hashlib

    import h5py

    with h5py.File(path) as f:
        return hashlib.sha256(f["frames/positions"][()].tobytes()).hexdigest()


def test_make_j_gives_the_same_arrays_as_a_serial_build(built):
    """Scenes `one` and `two` are the same inputs: built side by side with -j2 they give
    the same frames, and a serial rebuild from scratch (-j1) gives them again, bit for
    bit. (Not `make -B`: that would remake the venv stamp too, through the symlink.)"""
    tree, _ = built
    sims = [tree / "outputs" / s / "sim.h5" for s in ("one", "two")]
    parallel = [_positions_hash(p) for p in sims]
    assert parallel[0] == parallel[1]
    shutil.rmtree(tree / "outputs" / "one")
    r = make(tree, "-j1", "SCENES=one")
    assert r.returncode == 0, r.stderr[-2000:]
    assert _positions_hash(sims[0]) == parallel[0]


@pytest.mark.extended
def test_killed_make_then_make_gives_the_uninterrupted_arrays(tree):
    """SIGKILL the whole `make` (and its bloom simulate) mid-simulation, then `make`
    again: it resumes from the checkpoint, and the frames hash as an uninterrupted build
    of the same scene does."""
    import signal
    import time

    long = TINY.replace("steps = 300\nframes = 3", "steps = 60000\nframes = 31\n"
                        "checkpoint_seconds = 0.2\nintegrator = \"semi-implicit\"")  # (checkpoints)
    for scene in ("one", "two"):
        (tree / "configs" / f"{scene}.toml").write_text(long.format(mesh="petal.obj"))
    proc = subprocess.Popen(["make", "SCENES=one"], cwd=tree, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    ckpt = tree / "outputs" / "one" / ".sim.h5.checkpoint"
    deadline = time.monotonic() + 240
    while not ckpt.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert ckpt.exists() and not (tree / "outputs" / "one" / "sim.h5").exists()
    r = make(tree)  # both scenes: `one` resumes, `two` runs uninterrupted
    assert r.returncode == 0, r.stderr[-2000:]
    assert "resuming from step" in (tree / "outputs" / "one" / "logs" / "simulate.log").read_text()
    assert not ckpt.exists()
    one, two = (tree / "outputs" / s / "sim.h5" for s in ("one", "two"))
    assert _positions_hash(one) == _positions_hash(two)


def _datasets(f) -> list[str]:
    import h5py

    names = []
    f.visititems(lambda n, o: names.append(n) if isinstance(o, h5py.Dataset) else None)
    return names


def test_bloom_batch_on_a_local_dask_cluster_matches_make(built):
    """The same scenes through `make -j2` and through `bloom batch` on a local Dask
    cluster (2 workers): every artifact's arrays bit for bit, per-stage logs, and the
    USD export."""
    import h5py

    tree, _ = built
    r = subprocess.run([str(tree / ".venv" / "bin" / "bloom"), "batch", "configs/one.toml",
                        "configs/two.toml", "--out-root", "batch", "--workers", "2"],
                       cwd=tree, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "one: done (7 stages)" in r.stderr and "two: done (7 stages)" in r.stderr
    for scene in ("one", "two"):
        for name in ("remesh.h5", "axis.h5", "growth.h5", "sim.h5"):
            with h5py.File(tree / "outputs" / scene / name) as a, \
                    h5py.File(tree / "batch" / scene / name) as b:
                names = _datasets(a)
                assert names
                for n in names:
                    x, y = a[n][()], b[n][()]
                    # NaN where a value is unknown (a lone petal's flower axis) equals itself here
                    same = np.array_equal(x, y, equal_nan=np.asarray(x).dtype.kind == "f")
                    assert same, (scene, name, n)
        assert (tree / "batch" / scene / "bloom.usdc").stat().st_size > 0
        assert "steps of h" in (tree / "batch" / scene / "logs" / "simulate.log").read_text()
        mine = (tree / "batch" / scene / "render" / "bloom.mp4")
        assert mine.stat().st_size > 0


@pytest.mark.extended
def test_bloom_batch_survives_a_lost_worker(tree):
    """Kill the Dask worker running a scene's simulation (and the simulation) mid-run:
    the task is retried on another worker, resumes from the checkpoint (its inputs are
    up to date, so not rebuilt), and the frames equal an uninterrupted make build's."""
    import signal
    import time

    import psutil

    long = TINY.replace("steps = 300\nframes = 3", "steps = 400000\nframes = 21\n"
                        "checkpoint_seconds = 0.3\nintegrator = \"semi-implicit\"")  # (checkpoints)
    for scene in ("one", "two"):
        (tree / "configs" / f"{scene}.toml").write_text(long.format(mesh="petal.obj"))
    assert make(tree, "SCENES=two").returncode == 0  # the uninterrupted reference
    proc = subprocess.Popen([str(tree / ".venv" / "bin" / "bloom"), "batch", "configs/one.toml",
                             "--out-root", "batch", "--workers", "2"], cwd=tree,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ckpt = tree / "batch" / "one" / ".sim.h5.checkpoint"
    deadline = time.monotonic() + 240
    while not ckpt.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    sims = [p for p in psutil.process_iter(["cmdline"])
            if "simulate" in (p.info["cmdline"] or []) and str(tree) in " ".join(p.info["cmdline"])]
    assert len(sims) == 1, "the simulation finished before its worker could be killed?"
    worker = sims[0].parent()
    for p in (worker, sims[0]):
        p.send_signal(signal.SIGKILL)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err[-2000:]
    assert "one: done (7 stages)" in err
    log = (tree / "batch" / "one" / "logs" / "simulate.log").read_text()
    assert "resuming from step" in log, log
    assert _positions_hash(tree / "batch" / "one" / "sim.h5") == \
        _positions_hash(tree / "outputs" / "two" / "sim.h5")


def test_bloom_batch_reports_failures_and_sees_changed_inputs(tree):
    """A scene whose simulation diverges: one line naming it and the stage, no
    traceback, exit 1, nothing after the failed stage. A config changed in content but
    restored with an old date is still seen as changed (hashes, not dates)."""
    import h5py

    bloom = str(tree / ".venv" / "bin" / "bloom")
    bad = TINY.format(mesh="petal.obj").replace("steps = 300", "steps = 300\nh = 3.0\nsubsteps = 1\n"
                                                    "integrator = \"semi-implicit\"")
    (tree / "configs" / "bad.toml").write_text(bad)
    r = subprocess.run([bloom, "batch", "configs/one.toml", "configs/bad.toml", "--out-root", "b"],
                       cwd=tree, capture_output=True, text=True)
    assert r.returncode != 0
    assert "one: done (7 stages)" in r.stderr and "Traceback" not in r.stderr
    assert "bad: FAILED at simulate: " in r.stderr and "diverged" in r.stderr
    assert not (tree / "b" / "bad" / "sim.h5").exists()
    assert not (tree / "b" / "bad" / "render").exists()
    one = tree / "configs" / "one.toml"
    stamp = os.stat(one).st_mtime
    one.write_text(one.read_text().replace("frames = 3", "frames = 5"))
    os.utime(one, (stamp - 10**7, stamp - 10**7))  # restored with an old date
    r = subprocess.run([bloom, "batch", "configs/one.toml", "--out-root", "b"], cwd=tree,
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    with h5py.File(tree / "b" / "one" / "sim.h5") as f:
        assert f["frames/positions"].shape[0] == 5


def test_a_failing_stage_under_make_says_so_on_stderr(tree):
    bad = TINY.format(mesh="petal.obj").replace("steps = 300", "steps = 300\nh = 3.0\nsubsteps = 1\n"
                                                    "integrator = \"semi-implicit\"")
    (tree / "configs" / "bad.toml").write_text(bad)
    r = make(tree, "SCENES=bad")
    assert r.returncode != 0
    assert "bloom simulate: error: " in r.stderr and "diverged" in r.stderr
    assert "bloom simulate: error: " not in r.stdout
    assert "diverged" in (tree / "outputs" / "bad" / "logs" / "simulate.log").read_text()
    assert not (tree / "outputs" / "bad" / "sim.h5").exists()
