"""The pipeline's stages as library calls, and the one list of them.

Each stage reads one file and writes one artifact (:mod:`pipeline.artifact`); its work
is one function, ``run``, in a module of this package named after it
(:mod:`.remesh`, :mod:`.axis`, :mod:`.growth`, :mod:`.simulate`, :mod:`.render`,
:mod:`.report`, :mod:`.export`). The ``bloom`` commands (``stages/``) parse their
options and call these; the Makefile, ``bloom batch``, the stability cases and the
bench run the same chain (:data:`STAGES`; the Makefile is checked against it by
``tests/test_makefile.py``).
"""

from __future__ import annotations

import importlib
import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline import artifact
from pipeline.config import load_config


@dataclass(frozen=True)
class Stage:
    """One stage of a scene's chain, as the Makefile writes it."""

    name: str  #: the command, ``bloom <name>``, and the module ``pipeline.chain.<name>``
    reads: str | None  #: the artifact it reads in the scene's folder (None: the scene's mesh)
    writes: str  #: what it writes in the scene's folder (a file, or a folder for render)
    config: bool = True  #: whether it takes the scene's ``--config``
    resume: bool = False  #: whether make runs it with ``--resume``


#: a scene's stages, in order: outputs/<scene>/<writes> from outputs/<scene>/<reads>
STAGES = (
    Stage("remesh", None, "remesh.h5"),
    Stage("axis", "remesh.h5", "axis.h5"),
    Stage("growth", "axis.h5", "growth.h5"),
    Stage("simulate", "growth.h5", "sim.h5", resume=True),
    Stage("render", "sim.h5", "render"),
    Stage("report", "sim.h5", "report.json", config=False),
    Stage("export", "sim.h5", "bloom.usdc"),
)
#: the stages that make the artifacts a bloom is simulated from, and the bloom
SIMULATION = tuple(s for s in STAGES if s.name in ("remesh", "axis", "growth", "simulate"))


#: root attributes every stage after remesh carries forward from its input artifact
CARRIED_ATTRS = ("scale", "parts", "file_up", "meters_per_unit", "flower_axis", "up")


def carried_attrs(src) -> dict:
    """The root attributes of ``src`` (an input artifact) a stage carries forward."""
    return {k: src.attrs[k] for k in CARRIED_ATTRS if k in src.attrs}


def stage(name: str) -> Stage:
    """The stage called ``name``."""
    for s in STAGES:
        if s.name == name:
            return s
    raise KeyError(name)


def argv(s: Stage, folder: Path, config: Path | None, overrides=()) -> list[str]:
    """The command line of stage ``s`` for the scene in ``folder`` (``bloom`` omitted)."""
    args = [s.name]
    if s.reads is not None:
        args.append(str(Path(folder) / s.reads))
    if s.config and config is not None:
        args += ["--config", str(config)]
    if s.config:
        for o in overrides:
            args += ["--set", o]
    args += ["--out", str(Path(folder) / s.writes)]
    if s.resume:
        args.append("--resume")
    return args


def run_scene(config: Path | str, folder: Path | str, *, stages=SIMULATION, overrides=(),
              overwrite: bool = True, quiet: bool = True) -> dict[str, Path]:
    """Run ``stages`` of the scene ``config`` into ``folder``, in process, as the
    commands run them (``quiet``: their log shows errors only, as ``bloom -q``). Returns
    each stage's output path. A stage that refuses its input raises
    :class:`~pipeline.errors.BloomError` (one line, naming the file and key), with
    nothing written for it."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cfg = load_config(config, tuple(overrides))
    made = {}
    logger = logging.getLogger("bloom")
    level = logger.level
    if quiet:
        logger.setLevel(logging.ERROR)
    try:
        for s in stages:
            module = importlib.import_module(f"pipeline.chain.{s.name}")
            artifact.STARTED[0] = time.monotonic()  # the stage's own timing
            source = None if s.reads is None else folder / s.reads
            out = folder / s.writes
            module.run(source, out, cfg, overwrite=overwrite)
            made[s.name] = out
    finally:
        logger.setLevel(level)
    return made


def up_direction(src):
    """The flower's axis, pointing from the petals' bases toward their tips."""
    axis = src.attrs.get("flower_axis")
    if axis is None or not np.all(np.isfinite(axis)):
        return None
    d = np.asarray(axis[3:], dtype=np.float64)
    if "axis/tip" in src and "axis/base" in src:
        v = src["mesh/vertices"] if "mesh/vertices" in src else src["frames/positions"][0]
        if (v[src["axis/tip"]].mean(axis=0) - v[src["axis/base"]].mean(axis=0)) @ d < 0:
            d = -d
    return d
