"""Fuzz: hundreds of generated bad meshes, configs and artifacts through the stages.
Each must end with one line on stderr naming the file (and key), a non-zero exit code,
no traceback, and no output file (nor a temporary one) left behind."""

import numpy as np
import pytest

from stages.cli import main


class _Ran:
    """What a real `bloom ...` run shows: exit code and stderr (main() as the console
    script calls it: Click's own errors become one line too)."""

    def __init__(self, args):
        import contextlib
        import io

        err = io.StringIO()
        self.exception = None
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                main([str(a) for a in args])
                self.exit_code = 0
            except SystemExit as exc:
                self.exit_code = exc.code if isinstance(exc.code, int) else 1
                self.exception = exc
            except BaseException as exc:  # a traceback: what must never happen
                self.exit_code, self.exception = 1, exc
        self.output = err.getvalue()

GOOD_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0.1\nf 1 2 3\nf 2 4 3\n"


def _petal_obj(rng) -> str:
    """A small valid open petal (a fan of triangles), to break in various ways."""
    n = 12
    ang = np.linspace(-0.6, 0.6, n)
    rim = np.stack([np.sin(ang), np.cos(ang), 0.1 * ang ** 2], axis=1) * 3
    v = np.concatenate([[[0, 0, 0]], rim])
    f = [[0, i, i + 1] for i in range(1, n)]
    lines = [f"v {a:.6f} {b:.6f} {c:.6f}" for a, b, c in v]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]
    return "\n".join(lines) + "\n"


def bad_meshes(rng):
    """(name, suffix, bytes) of broken mesh files."""
    good = _petal_obj(rng).encode()
    yield "empty", ".obj", b""
    yield "whitespace", ".obj", b"   \n\n"
    for k in range(12):
        cut = int(rng.integers(1, len(good) - 1))
        yield f"truncated{k}", ".obj", good[:cut].rsplit(b"\n", 1)[0][:max(cut // 3, 1)]
    for suffix in (".obj", ".ply", ".stl", ".off", ".glb", ".gltf"):
        for k in range(7):
            yield f"junk{suffix}{k}", suffix, rng.bytes(int(rng.integers(1, 3000)))
    yield "png-as-obj", ".obj", b"\x89PNG\r\n\x1a\n" + rng.bytes(200)
    yield "toml-as-ply", ".ply", b"[scene]\nmesh = 'x'\n"
    yield "text-as-stl", ".stl", b"hello world\n"
    yield "json-as-gltf", ".gltf", b'{"asset": {"version": "2.0"}, "meshes": []}'
    for token in ("nan", "inf", "-inf", "1e400"):
        yield f"{token}-coords", ".obj", good.replace(b"v 0.000000 0.000000 0.000000",
                                                      f"v {token} 0 0".encode())
    yield "index-out-of-range", ".obj", GOOD_OBJ.encode() + b"f 1 2 99\n"
    yield "no-faces", ".obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n"
    yield "no-vertices", ".obj", b"f 1 2 3\n"
    yield "all-one-point", ".obj", b"v 1 1 1\nv 1 1 1\nv 1 1 1\nf 1 2 3\n"
    yield "collinear", ".obj", b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n"
    yield "tetrahedron", ".obj", (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
                                  b"f 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n")
    # (a fin on a sheet is repaired now: tests/test_real_input.py) three faces on one
    # edge, all flat: nothing is left after dropping degenerate faces
    yield "non-manifold-flat", ".obj", (b"v 0 0 0\nv 1 0 0\nv 0.5 0 0\nv 2 0 0\nv -1 0 0\n"
                                        b"f 1 2 3\nf 2 1 4\nf 1 2 5\n")
    yield "unknown-suffix", ".xyz", good
    yield "no-suffix", "", good
    for k in range(10):  # a random vertex made non-finite, or a face past the vertices
        lines = good.split(b"\n")
        vertex_lines = [i for i, line in enumerate(lines) if line.startswith(b"v ")]
        i = int(rng.choice(vertex_lines))
        lines[i] = [b"v nan 0 0", b"v 0 inf 0", b"v 1e309 1 1", b"v 0 0 -inf"][k % 4]
        if k >= 6:
            lines = good.split(b"\n") + [f"f 1 2 {len(vertex_lines) + 1 + k}".encode()]
        yield f"edit{k}", ".obj", b"\n".join(lines)


def bad_configs(rng):
    """(name, TOML text) of broken configs."""
    yield "not-toml", "[scene\nmesh = 1"
    yield "binary", rng.bytes(300).decode("latin-1")
    yield "unknown-section", "[nonsense]\nx = 1\n"
    words = ["steps", "stepz", "h", "eta", "frames", "curve", "ramp", "beta", "enabled", "foo"]
    sections = ["simulate", "growth", "remesh", "axis", "effects.curl", "render", "scene"]
    for k in range(25):
        yield f"unknown{k}", f"[{rng.choice(sections)}]\n{rng.choice(words)}_{k} = 1\n"
    typed = {"simulate.steps": ['"ten"', "1.5", "true", "[1, 2]", "{a = 1}"],
             "simulate.h": ['"one"', "true", "[1.0]"],
             "simulate.eta": ['"0.1"', "false"],
             "growth.curve": ["2", "true", "[1]"],
             "effects.curl.enabled": ["1", '"yes"'],
             "remesh.symmetrize": ['"no"', "0"],
             "simulate.integrator": ["1", '"verlet"', '"quasi"']}
    ranged = {"simulate.steps": ["0", "-3", "-1000000"],
              "simulate.frames": ["1", "0", "-2"],
              "simulate.h": ["0", "-1.0", "0.0", "nan", "inf", "-inf"],
              "simulate.eta": ["-0.1", "0.51", "1.0", "nan"],
              "simulate.stretch_stiffness": ["0", "-0.1", "inf"],
              "simulate.bending_stiffness": ["-0.001", "nan"],
              "simulate.mass": ["0", "-1"],
              "effects.curl.beta": ["-0.5", "1.5"],
              "growth.ramp": ["0", "1.5", "-0.2"],
              "remesh.target_edge": ["-1"],
              "simulate.stages": ["0", "-5"],
              "simulate.tolerance": ["0", "-1e-6"]}
    for table in (typed, ranged):
        for dotted, values in table.items():
            section, key = dotted.rsplit(".", 1)
            for value in values:
                yield f"{dotted}={value}", f"[{section}]\n{key} = {value}\n"
    for curve in ("x**", "import os", "__import__('os')", "x.real", "open('f')", "x(1)",
                  "lambda: 1", "[x]", "1/x", "1/(x-x)", "y**2", "-1.5", "-1", "-1 - x**2",
                  "-2*x**2", "log(x)", "sqrt(-1-x**2)", "x if x else 1", "1e400*x", "",
                  "x" * 600, "0.2*x**2 +", "exp(1000*x)"):
        yield f"curve={curve[:20]}", f'[growth]\ncurve = "{curve}"\n'
    yield "frames>steps", "[simulate]\nsteps = 10\nframes = 50\n"
    yield "both-targets", "[remesh]\ntarget_edge = 0.1\npetal_vertices = 100\n"
    yield "odd-render", "[render]\nwidth = 321\n"
    yield "no-gap", "[effects.collisions]\nenabled = true\nthickness = 0\n"


def _one_clean_line(r, stage: str, where: str) -> str:
    text = r.output.strip()
    assert r.exit_code != 0, text
    assert isinstance(r.exception, SystemExit), repr(r.exception)
    assert "Traceback" not in text
    lines = text.splitlines()
    assert len(lines) == 1, text
    assert lines[0].startswith((f"bloom {stage}: error: ", "bloom: error: ")), lines[0]
    assert where in lines[0], lines[0]
    return lines[0]


def _nothing_left(folder, before: set) -> None:
    after = {p.name for p in folder.iterdir()}
    assert after == before, after - before


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """Valid artifacts of every stage, for the wrong-stage and broken-artifact cases."""
    d = tmp_path_factory.mktemp("fuzzchain")
    mesh = d / "p.obj"
    assert _Ran(["asset", "petal", "--vertices", 80, "--out", mesh]).exit_code == 0
    paths = {"mesh": mesh}
    short = ["--set", "simulate.steps=50", "--set", "simulate.frames=2"]
    r = _Ran(["remesh", "--set", f"scene.mesh={mesh}", "--out", d / "remesh.h5"])
    assert r.exit_code == 0, r.output
    paths["remesh"] = prev = d / "remesh.h5"
    for stage in ("axis", "growth", "simulate"):
        out = d / f"{stage}.h5"
        r = _Ran([stage, prev, "--out", out, *short])
        assert r.exit_code == 0, r.output
        paths[stage] = prev = out
    return paths


def test_fuzz_meshes(tmp_path):
    rng = np.random.default_rng(20261121)
    count = 0
    for name, suffix, data in bad_meshes(rng):
        mesh = tmp_path / f"m{count}{suffix}"
        mesh.write_bytes(data)
        out = tmp_path / f"out{count}.h5"
        before = {p.name for p in tmp_path.iterdir()}
        r = _Ran(["-q", "remesh", "--set", f"scene.mesh={mesh}", "--out", out])
        try:
            _one_clean_line(r, "remesh", mesh.name)
        except AssertionError as exc:
            raise AssertionError(f"mesh case {name}: {exc}") from None
        _nothing_left(tmp_path, before)
        count += 1
    assert count >= 80


def test_fuzz_configs(tmp_path, chain):
    rng = np.random.default_rng(7)
    count = 0
    for name, text in bad_configs(rng):
        cfg = tmp_path / f"c{count}.toml"
        cfg.write_bytes(text.encode("utf-8", "surrogateescape"))
        for stage, src in (("remesh", None), ("simulate", chain["growth"])):
            out = tmp_path / f"out{count}.h5"
            before = {p.name for p in tmp_path.iterdir()}
            args = ["-q", stage] + ([str(src)] if src else ["--set", f"scene.mesh={chain['mesh']}"])
            r = _Ran([*args, "--config", cfg, "--out", out])
            try:
                _one_clean_line(r, stage, cfg.name)
            except AssertionError as exc:
                raise AssertionError(f"config case {name} ({stage}): {exc}") from None
            _nothing_left(tmp_path, before)
        count += 1
    assert count >= 100


RUNTIME = [  # valid configs that fail while simulating (the first three: the guards of
    # the dynamic scheme, so they ask for it; quasi-static is the default)
    ("diverges", ["simulate.integrator=semi-implicit", "simulate.h=3.0", "simulate.substeps=1"]),
    ("diverges, checkpointing", ["simulate.integrator=semi-implicit", "simulate.h=3.0",
                                 "simulate.substeps=1", "simulate.checkpoint_seconds=0.0001"]),
    ("speed guard", ["simulate.integrator=semi-implicit", "simulate.speed_limit=1e-9"]),
    ("quasi-static without bending", ["simulate.integrator=quasi-static",
                                      "simulate.bending_stiffness=0"]),
]


@pytest.mark.parametrize("name,sets", RUNTIME, ids=[n for n, _ in RUNTIME])
def test_fuzz_runtime_failures(tmp_path, chain, name, sets):
    """Failures found while simulating: one line naming the key, no sim.h5, and no
    checkpoint or temporary file left behind."""
    out = tmp_path / "sim.h5"
    args = ["-q", "simulate", chain["growth"], "--out", out, "--set", "simulate.steps=3000",
            "--set", "simulate.frames=31"]
    for kv in sets:
        args += ["--set", kv]
    r = _Ran(args)
    line = _one_clean_line(r, "simulate", "simulate.")
    assert "diverged" in line or "quasi-static" in line or "bending" in line, line
    assert list(tmp_path.iterdir()) == []


def test_fuzz_artifacts(tmp_path, chain):
    """Every stage given every other stage's artifact, a truncated one, junk, a folder."""
    import h5py

    rng = np.random.default_rng(3)
    inputs = {"axis": "remesh", "growth": "axis", "simulate": "growth",
              "render": "simulate", "report": "simulate", "inspect": None}
    order = ["remesh", "axis", "growth", "simulate"]
    cases = []
    for stage, right in inputs.items():  # an artifact of an earlier stage than it needs
        if right is not None and stage != "render":
            cases += [(stage, chain[o], f"{o}.h5") for o in order[:order.index(right)]]
    data = chain["growth"].read_bytes()
    for k in range(8):
        p = tmp_path / f"trunc{k}.h5"
        p.write_bytes(data[: int(rng.integers(10, len(data) - 10))])
        cases += [(s, p, p.name) for s in ("simulate", "inspect", "report")]
    for k in range(4):
        p = tmp_path / f"junk{k}.h5"
        p.write_bytes(rng.bytes(5000))
        cases += [(s, p, p.name) for s in ("axis", "growth", "simulate")]
    for name in ("growth/edges", "growth/alpha", "mesh/vertices", "axis/base"):
        p = tmp_path / f"missing-{name.replace('/', '-')}.h5"
        p.write_bytes(data)
        with h5py.File(p, "a") as f:
            del f[name]
        cases.append(("simulate", p, p.name))
    folder = tmp_path / "a-folder.h5"
    folder.mkdir()
    cases += [(s, folder, folder.name) for s in ("axis", "simulate")]
    cases += [(s, tmp_path / "missing.h5", "missing.h5") for s in inputs]
    for i, (stage, src, where) in enumerate(cases):
        suffix = {"render": "", "report": ".json"}.get(stage, ".h5")
        out = tmp_path / f"out{i}{suffix}"
        before = {p.name for p in tmp_path.iterdir()}
        args = ["-q", stage, str(src)] + ([] if stage == "inspect" else ["--out", str(out)])
        r = _Ran(args)
        try:
            _one_clean_line(r, stage, where)
        except AssertionError as exc:
            raise AssertionError(f"artifact case {stage} <- {src.name}: {exc}") from None
        _nothing_left(tmp_path, before)
    assert len(cases) >= 40
