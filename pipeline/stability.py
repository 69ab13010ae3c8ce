"""Hard cases, each taken through the real stages (remesh, axis, growth, simulate), that
must either finish with finite, bounded results or stop early with a clear one-line
message (``make stability``; the fast ones also run in the tests).

For each case: the outcome, the largest vertex speed over the run, the energy drift
during the hold after growth stops (the largest rise of kinetic + potential energy over
its value when growth stopped, relative to it; Eq. 8 with eta < 1/2 only removes energy
then, so a rise means energy is being created), how far any vertex got from the bud
(largest distance from the origin over the initial one), and the wall time.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from . import asset

#: a finished case passes when these hold
MAX_ESCAPE = 3.0  #: no vertex further from the receptacle than 3x the bud's initial reach
MAX_DRIFT = 0.1  #: total energy may not rise by more than 10% during the hold (measured
#: energy of a vibrating mesh fluctuates a little; a steady rise is an instability)


@dataclass
class Case:
    name: str
    what: str
    mesh: str  #: a key of MESHES
    settings: dict = field(default_factory=dict)  #: dotted config keys
    expect: str = "finish"  #: finish, or stop (a clean early stop is the right outcome)
    slow: bool = False


def _petal_points(vertices: int = 320, seed: int = 0):
    v, f, p = asset.bud(1, vertices, seed)
    return v, f, p


def _skinny(seed: int = 0):
    """A petal with 120 edges split 1/40 of the way along: triangles of aspect ~40."""
    v, f, p = _petal_points(320, seed)
    v, f = list(v), [list(t) for t in f]
    rng = np.random.default_rng(seed)
    from .topology import unique_edges

    edges = unique_edges(np.asarray(f))[0]
    done = set()
    for e in rng.permutation(len(edges))[:400]:
        a, b = (int(x) for x in edges[e])
        if a in done or b in done:
            continue
        touching = [t for t in f if a in t and b in t]
        if len(touching) != 2:
            continue
        m = len(v)
        v.append(np.asarray(v[a]) + (np.asarray(v[b]) - np.asarray(v[a])) / 40.0)
        for t in touching:
            f.remove(t)
            i, j = t.index(a), t.index(b)
            ta, tb = list(t), list(t)
            ta[j] = m
            tb[i] = m
            f += [ta, tb]
        done.update((a, b))
        if len(done) >= 240:
            break
    v = np.asarray(v)
    return v, np.asarray(f), np.zeros(len(v), dtype=np.int64)


def _duplicates(seed: int = 0):
    """A petal whose every 5th vertex has an unwelded twin 1e-9 away used by some of its
    faces, plus sliver faces (three collinear vertices)."""
    v, f, p = _petal_points(320, seed)
    twins = np.arange(0, len(v), 5)
    extra = v[twins] + 1e-9
    index = {int(t): len(v) + k for k, t in enumerate(twins)}
    f = f.copy()
    for row in range(0, len(f), 3):
        f[row] = [index.get(int(x), int(x)) for x in f[row]]
    v = np.concatenate([v, extra])
    a, b = f[0, 0], f[0, 1]
    mid = len(v)
    v = np.concatenate([v, [(v[a] + v[b]) / 2]])
    f = np.concatenate([f, [[a, b, mid]]])
    return v, f, np.zeros(len(v), dtype=np.int64)


def _folded(seed: int = 0, angle_deg: float = 179.0):
    """A flat petal whose tip (past 85% of its length) is folded back by ``angle_deg``:
    the fold's hinges sit near the +-pi branch cut of the dihedral angle."""
    rng = np.random.default_rng(seed)
    pts, f = asset.flat_petal(asset.Outline(), 0.06, rng)
    u, s = pts[:, 0], pts[:, 1]
    s0, phi = 0.85, np.radians(angle_deg)
    beyond = np.maximum(s - s0, 0.0)
    y = np.where(s > s0, s0 + beyond * np.cos(phi), s)
    z = np.where(s > s0, beyond * np.sin(phi), 0.0)
    v = np.stack([u, y, z], axis=1)
    return v, f, np.zeros(len(v), dtype=np.int64)


def _crossing_bud(seed: int = 0):
    """A 6-petal bud whose layers are pushed into each other: petals start interpenetrating."""
    return asset.bud(6, 1200, seed, asset.BudShape(layer_gap=-0.04))


MESHES = {
    "petal": lambda: _petal_points(320),
    "skinny": _skinny,
    "duplicates": _duplicates,
    "folded": _folded,
    "bud6": lambda: asset.bud(6, 1200, 0),
    "crossing": _crossing_bud,
    "bud12": lambda: asset.bud(12, 2400, 0),
}

STEPS = {"simulate.steps": 30_000, "simulate.frames": 31}

CASES = [
    Case("buckling x^6", "severe buckling: growth 0.2 x^6", "petal",
         {"growth.curve": "0.2*x**6"}),
    Case("buckling 0.6 x^6", "stronger: growth 0.6 x^6", "petal", {"growth.curve": "0.6*x**6"}),
    Case("alpha 1.0", "very large growth: alpha = 1.0 x^2 (rims double)", "petal",
         {"growth.curve": "1.0*x**2"}),
    Case("uniform alpha 1.0", "the whole petal doubles: alpha = 1.0", "petal",
         {"growth.curve": "1.0"}),
    Case("skinny triangles", "240 triangles of aspect ~40 (kept: no remesh, no symmetrize)",
         "skinny", {"remesh.symmetrize": False}, expect="stop"),
    Case("skinny, remeshed", "the same mesh remeshed (remesh.petal_vertices = 320)",
         "skinny", {"remesh.symmetrize": False, "remesh.petal_vertices": 320}),
    Case("near-duplicates, slivers", "twins 1e-9 apart and a collinear face (welded and "
         "dropped by remesh)", "duplicates", {"remesh.symmetrize": False}),
    Case("folded near pi", "tip folded back 179 deg: hinges near the +-pi branch cut", "folded",
         {"remesh.symmetrize": False, "axis.base": "-y"}),
    Case("interpenetrating bud", "petals start through each other; collisions on", "crossing",
         {"effects.collisions.enabled": True}),
    Case("12-petal bud", "dense 12-petal bud, 2400 vertices; collisions on", "bud12",
         {"effects.collisions.enabled": True}, slow=True),
    Case("mass breaking", "connection springs 100x stiffer than plum_locked's, breaking at "
         "1% stretch", "bud6",
         {"effects.connections.enabled": True, "effects.connections.critical_stretch": 1.01,
          "effects.connections.stiffness": 0.01, "effects.connections.max_distance": 3.0,
          "effects.connections.min_s": 0.3}),
    Case("h 1.5", "time step 1.5, inside the explicit limit", "petal", {"simulate.h": 1.5}),
    Case("h 1.9", "time step 1.9, at the explicit limit (about 2 / omega_max)", "petal",
         {"simulate.h": 1.9}, expect="stop"),
    Case("h 2.5", "time step 2.5, past the explicit limit", "petal", {"simulate.h": 2.5},
         expect="stop"),
]


def _toml(settings: dict) -> str:
    sections: dict[str, list[str]] = {}
    for dotted, value in settings.items():
        section, key = dotted.rsplit(".", 1)
        if isinstance(value, bool):
            text = "true" if value else "false"
        elif isinstance(value, str):
            text = f'"{value}"'
        else:
            text = repr(value)
        sections.setdefault(section, []).append(f"{key} = {text}")
    return "\n".join(f"[{s}]\n" + "\n".join(lines) for s, lines in sections.items()) + "\n"


@dataclass
class Result:
    case: Case
    outcome: str  #: finished, stopped, FAILED
    message: str = ""
    max_speed: float = float("nan")
    drift: float = float("nan")
    escape: float = float("nan")
    wall: float = 0.0
    ok: bool = False
    notes: str = ""  #: what the case's artifacts show it exercised


def run_case(case: Case, workdir: Path, steps: dict | None = None) -> Result:
    """Write the case's mesh and config, run remesh -> simulate through the CLI, judge."""
    from click.testing import CliRunner

    from stages.cli import cli

    workdir.mkdir(parents=True, exist_ok=True)
    v, f, p = MESHES[case.mesh]()
    mesh = workdir / "input.obj"
    asset.write_obj(mesh, v, f, p, f"stability case: {case.name}")
    settings = {**STEPS, **(steps or {}), **case.settings}
    cfg = workdir / "scene.toml"
    cfg.write_text('[scene]\nmesh = "input.obj"\n' + _toml(settings))
    runner = CliRunner()
    paths = {k: workdir / f"{k}.h5" for k in ("remesh", "axis", "growth", "sim")}
    chain = [("remesh", None), ("axis", "remesh"), ("growth", "axis"), ("simulate", "growth")]
    t0 = time.perf_counter()
    for stage, src in chain:
        out = paths["sim" if stage == "simulate" else stage]
        args = ["-q", stage] + ([str(paths[src])] if src else []) + ["--config", str(cfg),
                                                                 "--out", str(out)]
        r = runner.invoke(cli, args)
        if r.exit_code != 0:
            wall = time.perf_counter() - t0
            text = r.output.strip()
            clean = (r.exception is None or isinstance(r.exception, SystemExit)) and \
                "Traceback" not in text and len(text.splitlines()) == 1 and not out.exists()
            outcome = "stopped" if clean else "FAILED"
            ok = clean and case.expect in ("stop", "either")
            return Result(case, outcome, text.splitlines()[-1] if text else repr(r.exception),
                          wall=wall, ok=ok)
    wall = time.perf_counter() - t0
    notes = []
    with h5py.File(paths["growth"]) as h5:
        folded = int(np.sum(np.abs(h5["growth/rest_angle"][()]) > np.radians(170)))
        if folded:
            notes.append(f"{folded} hinges folded past 170 deg")
    with h5py.File(paths["sim"]) as h5:
        pos = h5["frames/positions"][()]
        speed = h5["diagnostics/max_speed"][()]
        total = h5["diagnostics/total_energy"][()]
        growth = h5["diagnostics/growth"][()]
        if "diagnostics/contacts" in h5:
            notes.append(f"{int(h5['diagnostics/contacts'][()].sum())} contacts pushed back")
        if "diagnostics/connections_intact" in h5:
            intact = h5["diagnostics/connections_intact"][()]
            notes.append(f"connection springs {intact[0]} -> {intact[-1]} intact")
    finite = bool(np.all(np.isfinite(pos)) and np.all(np.isfinite(total)))
    reach0 = np.linalg.norm(pos[0], axis=1).max()
    escape = float(np.linalg.norm(pos, axis=2).max() / reach0)
    hold = np.flatnonzero(growth >= 1.0)
    drift = 0.0
    if len(hold) > 1:
        e0 = total[hold[0]]
        drift = float((total[hold].max() - e0) / max(abs(e0), 1e-12))
    ok = (finite and escape < MAX_ESCAPE and drift < MAX_DRIFT
          and case.expect in ("finish", "either"))
    return Result(case, "finished" if finite else "FAILED", "", float(speed.max()), drift,
                  escape, wall, ok, "; ".join(notes))


def table(results: list[Result]) -> str:
    rows = ["| case | what | outcome | max speed | energy drift (hold) | escape | wall |",
            "|---|---|---|---|---|---|---|"]
    for r in results:
        outcome = r.outcome
        if r.message:  # the stage's one line, without the case's path and remedy
            outcome += ": " + r.message.split(": ", 3)[-1].split("; likely cause")[0]
        if r.notes:
            outcome += f" ({r.notes})"
        rows.append(f"| {r.case.name} | {r.case.what} | {outcome} | {r.max_speed:.3g} | "
                    f"{r.drift:.2g} | {r.escape:.2f} | {r.wall:.1f} s |")
    return "\n".join(rows)


def main() -> int:
    """``make stability``: every case, the table, exit 1 if any case is not as expected."""
    import sys
    import tempfile

    results = []
    with tempfile.TemporaryDirectory(prefix="bloom-stability-") as tmp:
        for i, case in enumerate(CASES):
            r = run_case(case, Path(tmp) / f"case{i}")
            print(f"{'ok  ' if r.ok else 'BAD '} {case.name}: {r.outcome} {r.message}",
                  file=sys.stderr, flush=True)
            results.append(r)
    print(table(results))
    return 0 if all(r.ok for r in results) else 1


if __name__ == "__main__":
    raise SystemExit(main())
