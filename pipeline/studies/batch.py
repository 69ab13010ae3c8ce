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

import ctypes
import json
import signal
import subprocess
import sys
import uuid
from dataclasses import dataclass
from pathlib import Path

from pipeline.chain import STAGES
from pipeline.chain import argv as chain_argv


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
        for s in STAGES:
            argv = tuple(chain_argv(s, folder, config))
            sources = ((str(folder / s.reads),) if s.reads else ()) + (str(config),)
            tasks.append(Task(scene, s.name, argv, str(folder / "logs" / f"{s.name}.log"),
                              made.get(s.reads), str(folder / s.writes), sources))
            made[s.writes] = s.name
    return tasks


def up_to_date(output: str, sources: tuple[str, ...]) -> bool:
    """Whether ``output`` need not be made again.

    An HDF5 artifact records the sha256 of every file it was made from (its input
    artifact, its config, for remesh its mesh): it is up to date when every one of
    those still has that hash and the task's own sources are among them, whatever the
    files' dates (a config restored with an old date, a mesh edited in place). A folder
    (render) or another file (report, export) is up to date when it and every file its
    stage lists exist and are newer than the sources, as make judges."""

    out = Path(output)
    if out.suffix == ".h5":
        if not out.exists():
            return False
        try:
            import h5py

            with h5py.File(out, "r") as f:
                recorded = json.loads(f.attrs["inputs"])
        except (OSError, KeyError, ValueError):
            return False
        from pipeline.artifact import sha256_file

        if not {str(Path(s).resolve()) for s in sources} <= {
                str(Path(p).resolve()) for p in recorded}:
            return False
        return all(Path(p).exists() and sha256_file(p) == digest for p, digest in recorded.items())
    files = [out / "render.json", out / "bloom.mp4", out / "contact_sheet.png"] \
        if out.suffix == "" else [out]
    if not all(f.exists() for f in files):
        return False
    newest = max(Path(s).stat().st_mtime for s in sources)
    return all(f.stat().st_mtime >= newest for f in files)


FAILED = "FAILED: "  #: a task's result that says its stage failed (not an exception:
#: a deterministic failure is not worth retrying, and its dependents skip)


def _die_with_parent() -> None:  # pragma: no cover - runs in the child, before exec
    """Linux: the stage's process is killed when its worker dies, so a retried task
    never runs beside an orphan of the first attempt."""

    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def run_stage(argv: tuple[str, ...], log: str, output: str, sources: tuple[str, ...],
              force: bool, *upstream) -> str:
    """Run one ``bloom`` command in a subprocess (on a worker); its stderr goes to ``log``.
    ``upstream`` are the results of the tasks it depends on (Dask waits for them); if
    one failed, this one is not run. An up-to-date output is kept, as make keeps it
    (unless ``force``): a task run again after a lost worker does not rebuild what is
    already there, so a simulation's checkpoint still matches its input. Returns the
    output, or :data:`FAILED` and the command's one-line error."""
    for result in upstream:
        if str(result).startswith(FAILED):
            return FAILED + "not run (an earlier stage failed)"
    if not force and up_to_date(output, sources):
        return output
    Path(log).parent.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "stages", *argv]  # the `bloom` command, in this Python
    proc = subprocess.run(cmd, capture_output=True, text=True,
                          preexec_fn=_die_with_parent if sys.platform == "linux" else None)
    Path(log).write_text(proc.stderr)
    if proc.returncode != 0:
        lines = proc.stderr.strip().splitlines()
        return FAILED + (lines[-1] if lines else f"exit code {proc.returncode}")
    return output


def run(tasks: list[Task], client, force: bool = False) -> dict[str, str | None]:
    """Submit the tasks to a ``distributed.Client``; wait for all. Returns each task's
    error (None when it succeeded). A task lost with its worker is run again by the
    scheduler (up to its ``distributed.scheduler.allowed-failures``)."""

    from distributed import wait

    run_id = uuid.uuid4().hex[:8]  # keys of this run only, on a shared scheduler
    futures = {}
    for t in tasks:
        deps = [futures[f"{t.scene}/{t.needs}"]] if t.needs else []
        futures[t.key] = client.submit(run_stage, t.argv, t.log, t.output, t.sources,
                                       force, *deps, pure=False,
                                       key=f"{t.scene}-{t.stage}-{run_id}")
    wait(list(futures.values()))
    errors = {}
    for key, fut in futures.items():
        if fut.status != "finished":
            errors[key] = f"lost ({fut.status})"
            continue
        result = fut.result()
        errors[key] = result[len(FAILED):] if str(result).startswith(FAILED) else None
    return errors
