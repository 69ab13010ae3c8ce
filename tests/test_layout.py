"""The structure, read from the code's own imports: the library never imports the
command line, and its packages form floors, each importing only its own floor and those
below it (so there is no cycle between packages); no module is longer than about 500
lines unless its docstring says why."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: the library's floors, lowest first: a module may import its own floor and those below
FLOORS = ("core", "mesh", "io", "flower", "sim", "review", "chain", "studies")
LONG = 500  #: lines; a longer module says why in its docstring ("long because ...")


def _floor(module: str) -> str:
    parts = module.split(".")
    if parts[0] != "pipeline":
        return parts[0]
    return parts[1] if len(parts) > 2 and parts[1] in FLOORS else "core"


def _imports(path: Path) -> set[str]:
    """Every module ``path`` imports, at any depth (function-level imports included)."""
    tree = ast.parse(path.read_text())
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
    return out


def _modules(folder: str):
    for path in sorted((ROOT / folder).rglob("*.py")):
        yield ".".join(path.relative_to(ROOT).with_suffix("").parts), path


def test_the_library_never_imports_the_command_line():
    bad = [(m, i) for m, path in _modules("pipeline") for i in _imports(path)
           if i == "stages" or i.startswith("stages.")]
    assert not bad, bad


def test_each_package_imports_only_its_floor_and_those_below():
    bad = []
    for module, path in _modules("pipeline"):
        mine = FLOORS.index(_floor(module))
        for imported in _imports(path):
            if imported.startswith("pipeline.") and _floor(imported) in FLOORS:
                if FLOORS.index(_floor(imported)) > mine:
                    bad.append(f"{module} imports {imported}")
    assert not bad, "\n".join(sorted(set(bad)))


def test_no_cycle_between_the_modules_of_the_simulator():
    """Within the library, module-level imports form no cycle (a cycle is what
    function-level imports were once used to dodge)."""
    graph = {}
    for module, path in _modules("pipeline"):
        tree = ast.parse(path.read_text())
        deps = set()
        for node in tree.body:  # module level only
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("pipeline"):
                deps.add(node.module)
                deps.update(f"{node.module}.{a.name}" for a in node.names)
        graph[module] = {d for d in deps if d in dict(_modules("pipeline")) and d != module}
    state: dict[str, int] = {}

    def visit(m, trail):
        if state.get(m) == 1:
            raise AssertionError("import cycle: " + " -> ".join(trail + [m]))
        if state.get(m) == 2:
            return
        state[m] = 1
        for d in sorted(graph.get(m, ())):
            visit(d, trail + [m])
        state[m] = 2

    for m in sorted(graph):
        visit(m, [])


def test_long_modules_say_why():
    long = []
    for folder in ("pipeline", "stages"):
        for module, path in _modules(folder):
            lines = path.read_text().count("\n")
            doc = ast.get_docstring(ast.parse(path.read_text())) or ""
            if lines > LONG and "long because" not in doc:
                long.append(f"{module}: {lines} lines")
    assert not long, long


def test_the_makefile_runs_the_one_stage_list():
    """Each stage of pipeline.chain.STAGES is a Makefile rule from its input artifact to
    its output, with the command line the chain gives."""
    from pipeline.chain import STAGES

    text = (ROOT / "Makefile").read_text()
    for s in STAGES:
        target = f"$(OUT)/%/{s.writes if s.name != 'render' else 'render/bloom.mp4'}:"
        assert target in text, s
        rule = text[text.index(target):].split("\n\n")[0]
        if s.reads:
            assert f"$(OUT)/%/{s.reads}" in rule, s
        assert f"$(BLOOM) {s.name} " in rule, s
        assert ("--config" in rule) == s.config, s
        assert ("--resume" in rule) == s.resume, s


def test_every_package_is_in_the_distribution():
    """A wheel (``pip install .``, not ``-e``) carries every package of the library and
    the command line: pyproject.toml finds them by pattern, and each one matches."""
    import fnmatch
    import tomllib

    setup = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    patterns = setup["packages"]["find"]["include"]
    packages = [".".join(p.parent.relative_to(ROOT).parts)
                for top in ("pipeline", "stages") for p in (ROOT / top).rglob("__init__.py")]
    assert len(packages) > 8
    missing = [p for p in packages if not any(fnmatch.fnmatch(p, pat) for pat in patterns)]
    assert not missing, f"packages a wheel would leave out: {missing}"
