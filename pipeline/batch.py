"""The Makefile's stage graph on a Dask distributed cluster (``bloom batch``).

Each stage of each scene is one task, running the same ``bloom`` command the Makefile
runs, in a subprocess on a worker; a stage's task depends on the task that writes its
input artifact, so Dask runs the scenes side by side and each scene's stages in order.
A task lost with its worker is retried (``retries``); `bloom simulate --resume` picks
up the checkpoint a lost simulation left. Workers must see the same files (one machine,
or a shared file system) and the same project.

Every stage's stderr goes to ``<out_root>/<scene>/logs/<stage>.log``, as under make.
Like make, a stage whose output is newer than its input and config is not run again
(``force`` runs everything); unlike make, changes to Bloom's own code are not tracked.
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

#: the stages of a scene: (name, input artifact or None, output, extra arguments)
STAGES = (
    ("remesh", None, "remesh.h5", ()),
    ("axis", "remesh.h5", "axis.h5", ()),
    ("growth", "axis.h5", "growth.h5", ()),
    ("simulate", "growth.h5", "sim.h5", ("--resume",)),
    ("render", "sim.h5", "render", ()),
    ("report", "sim.h5", "report.json", ()),
    ("export", "sim.h5", "bloom.usdc", ()),
)
NO_CONFIG = ("report",)  #: stages the Makefile runs without --config


@dataclass(frozen=True)
class Task:
    scene: str
    stage: str
    argv: tuple[str, ...]
    log: str
    needs: str | None  #: the stage whose output this one reads
    output: str  #: what it writes (a file, or a folder for render)
    sources: tuple[str, ...]  #: the files it reads (input artifact, config)

    @property
    def key(self) -> str:
        return f"{self.scene}/{self.stage}"


def plan(configs: list[Path], out_root: Path) -> list[Task]:
    """The tasks of every scene, in dependency order."""
    tasks = []
    out_root = Path(out_root).resolve()  # workers may run elsewhere: absolute paths
    for config in configs:
        config = Path(config).resolve()
        scene = config.stem
        folder = out_root / scene
        made = {}
        for stage, src, out, extra in STAGES:
            argv = [stage]
            if src is not None:
                argv.append(str(folder / src))
            if stage not in NO_CONFIG:
                argv += ["--config", str(config)]
            argv += ["--out", str(folder / out), *extra]
            sources = ((str(folder / src),) if src else ()) + (str(config),)
            tasks.append(Task(scene, stage, tuple(argv), str(folder / "logs" / f"{stage}.log"),
                              made.get(src), str(folder / out), sources))
            made[out] = stage
    return tasks


def up_to_date(output: str, sources: tuple[str, ...]) -> bool:
    """Like make: the output exists and is newer than everything it is made from (for
    a folder, the marker file its stage writes last)."""
    out = Path(output)
    if out.is_dir():
        out = out / "render.json"
    if not out.exists():
        return False
    return all(out.stat().st_mtime >= Path(s).stat().st_mtime for s in sources)


def run_stage(argv: tuple[str, ...], log: str, output: str, sources: tuple[str, ...],
              force: bool, *upstream) -> str:
    """Run one ``bloom`` command in a subprocess (on a worker); its stderr goes to ``log``.
    ``upstream`` are the results of the tasks it depends on (Dask waits for them). An
    up-to-date output is kept, as make keeps it (unless ``force``): a task run again
    after a lost worker does not rebuild what is already there, so a simulation's
    checkpoint still matches its input. Raises RuntimeError with the command's one-line
    error when it fails."""
    if not force and up_to_date(output, sources):
        return output
    Path(log).parent.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-c", "from stages.cli import main; main()", *argv]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    Path(log).write_text(proc.stderr)
    if proc.returncode != 0:
        lines = proc.stderr.strip().splitlines()
        raise RuntimeError(lines[-1] if lines else f"exit code {proc.returncode}")
    return output


def run(tasks: list[Task], client, retries: int = 2, force: bool = False
        ) -> dict[str, str | None]:
    """Submit the tasks to a ``distributed.Client``; wait for all. Returns each task's
    error (None when it succeeded; tasks after a failed one are not run)."""
    from distributed import wait

    futures = {}
    for t in tasks:
        deps = [futures[f"{t.scene}/{t.needs}"]] if t.needs else []
        futures[t.key] = client.submit(run_stage, t.argv, t.log, t.output, t.sources,
                                       force, *deps, key=t.key.replace("/", "-"), pure=False,
                                       retries=retries)
    wait(list(futures.values()))
    errors = {}
    for key, fut in futures.items():
        if fut.status == "finished":
            errors[key] = None
        else:
            try:
                exc = fut.exception()
                errors[key] = str(exc) if exc is not None else fut.status
            except Exception as exc:  # cancelled, or its input failed
                errors[key] = f"{type(exc).__name__}: not run ({exc})"
    return errors
