"""Checkpoints of a running simulation, so that a killed ``bloom simulate`` resumes where
it stopped and ends with the arrays an uninterrupted run gives, bit for bit.

A checkpoint holds everything the run carries from one step to the next: the state
(positions, velocities, forces, step, energy), every array of the effects' bundle
(collision sides, near pairs and their reference positions, grid, counters; connection
springs' alive flags and break steps; curl's work arrays), and the frames recorded so
far. It is keyed by a fingerprint of the inputs and the config, and resuming refuses a
checkpoint whose fingerprint differs. It is written atomically next to the output
(``.sim.h5.checkpoint``) and removed once the output is complete.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from pathlib import Path

import h5py
import numpy as np

from pipeline import __version__
from pipeline.artifact import atomic_path
from pipeline.sim.effects import Effects
from pipeline.sim.model import State
from pipeline.sim.run import Recording

VERSION = 1


def path_for(out: str | Path) -> Path:
    out = Path(out)
    return out.with_name(f".{out.name}.checkpoint")


def fingerprint(config_json: str, inputs: dict[str, str]) -> str:
    """What a checkpoint must match to be resumed: the inputs, the config (but not how
    often checkpoints are written), and the code that steps (Bloom's version, the
    simulator's sources, numpy's and numba's versions): a checkpoint from other code
    would splice two different runs into one artifact."""
    import numba


    config = json.loads(config_json)
    config.get("simulate", {}).pop("checkpoint_seconds", None)
    sources = hashlib.sha256()
    for src in sorted(Path(__file__).parent.rglob("*.py")):
        sources.update(src.read_bytes())
    text = json.dumps({"config": config, "inputs": inputs, "v": VERSION,
                       "code": [__version__, sources.hexdigest(), np.__version__,
                                numba.__version__]}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def _bundle_arrays(effects: Effects) -> list[tuple[str, np.ndarray]]:
    """The arrays of the effects' bundle, by field name (sorted)."""
    return sorted((name, a) for name, a in effects.bundle()._asdict().items()
                  if isinstance(a, np.ndarray))


def _alive(pid: str) -> bool:
    try:
        os.kill(int(pid), 0)
    except (ValueError, ProcessLookupError):
        return False
    except PermissionError:
        return True
    return True


def _write_tree(group, name: str, value) -> None:
    """Write a tree of dicts, lists, arrays, numbers, strings and None under ``group``."""
    if isinstance(value, dict):
        node = group.create_group(name)
        node.attrs["kind"] = "dict"
        for k, v in value.items():
            _write_tree(node, str(k), v)
    elif isinstance(value, (list, tuple)):
        node = group.create_group(name)
        node.attrs["kind"] = "list"
        node.attrs["length"] = len(value)
        for k, v in enumerate(value):
            _write_tree(node, str(k), v)
    elif value is None:
        group.create_group(name).attrs["kind"] = "none"
    else:
        group[name] = value
        if isinstance(value, (bool, np.bool_)):
            group[name].attrs["kind"] = "bool"


def _read_tree(node):
    """What :func:`_write_tree` wrote."""
    if isinstance(node, h5py.Group):
        kind = node.attrs.get("kind")
        if kind == "none":
            return None
        if kind == "list":
            return [_read_tree(node[str(k)]) for k in range(int(node.attrs["length"]))]
        return {k: _read_tree(node[k]) for k in node}
    value = node[()]
    if node.attrs.get("kind") == "bool":
        return bool(value)
    if isinstance(value, bytes):
        return value.decode()
    return value


def save(path: Path, key: str, state: State, effects: Effects, rec: Recording,
         integrator=None) -> None:
    """Write the checkpoint (atomically: a kill while writing leaves the previous one;
    the half-written file of such a kill is removed by the next save)."""
    for stale in path.parent.glob(f".{path.stem}.tmp-*{path.suffix}"):
        pid = stale.name[len(f".{path.stem}.tmp-"):-len(path.suffix) or None]
        if not _alive(pid):  # never another live writer's
            stale.unlink(missing_ok=True)
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        f.attrs["fingerprint"] = key
        f.attrs["step"] = state.step
        f.attrs["potential_energy"] = state.potential_energy
        for name in ("positions", "velocities", "forces"):
            f[f"state/{name}"] = getattr(state, name)
        for name, a in _bundle_arrays(effects):
            f[f"effects/{name}"] = a
        f["frames/time"] = np.asarray(rec.time)
        f["frames/positions"] = np.asarray(rec.positions)
        for name, values in rec.diagnostics.items():
            f[f"diagnostics/{name}"] = np.asarray(values)
        if hasattr(integrator, "state"):  # (the quasi-static solver's: its path, its groups)
            _write_tree(f, "integrator", integrator.state())


def load(path: Path, key: str, state: State, effects: Effects, integrator=None,
         model=None) -> Recording | None:
    """Restore ``state``, ``effects`` and ``integrator`` (of ``model``; one with a
    ``restore``) in place from the checkpoint and return the frames recorded so far;
    None if there is no checkpoint, or it is for other inputs or config (or unreadable:
    a checkpoint is only ever a shortcut)."""

    log = logging.getLogger("bloom")
    if not path.exists():
        return None
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("fingerprint") != key:
                log.info("%s: not resumed: made from other inputs, config or code", path)
                return None
            saved_state = {n: f[f"state/{n}"][()] for n in ("positions", "velocities", "forces")}
            saved_fx = {name: f[f"effects/{name}"][()] for name in f["effects"]}
            step, energy = int(f.attrs["step"]), float(f.attrs["potential_energy"])
            rec = Recording()
            rec.time = list(f["frames/time"][()])
            rec.positions = list(f["frames/positions"][()])
            for name in f["diagnostics"]:
                rec.diagnostics[name] = list(f[f"diagnostics/{name}"][()])
            solver = _read_tree(f["integrator"]) if "integrator" in f else None
        arrays = _bundle_arrays(effects)
        if (sorted(saved_fx) != [name for name, _ in arrays]
                or any(saved_fx[name].shape != a.shape for name, a in arrays)
                or any(saved_state[n].shape != getattr(state, n).shape for n in saved_state)):
            log.info("%s: not resumed: its arrays do not fit this run", path)
            return None
        if hasattr(integrator, "restore") and solver is None:
            log.info("%s: not resumed: it holds no state of the integrator", path)
            return None
        for name, value in saved_state.items():
            getattr(state, name)[...] = value
        for name, a in arrays:
            a[...] = saved_fx[name]
        state.step, state.potential_energy = step, energy
        if hasattr(integrator, "restore"):
            integrator.restore(model, state, effects, solver)
        return rec
    except (OSError, KeyError, ValueError) as exc:
        log.info("%s: not resumed: unreadable (%s)", path, exc)
        return None
