"""HDF5 artifacts: written whole or not at all, each with its provenance.

Every artifact carries the root attributes ``stage``, ``command``, ``config`` (JSON of
the values used), ``inputs`` (JSON: path -> sha256) and ``version``. It is written to a
temporary file beside the target and renamed when complete, so an interrupted stage
never leaves a half-written file that make would take as done.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from pipeline import __version__
from pipeline.errors import BloomError

#: The stages in pipeline order, and the datasets each one adds.
STAGE_DATASETS = {
    "remesh": ("mesh/vertices", "mesh/faces", "mesh/petal"),
    "axis": ("axis/base", "axis/on_axis", "axis/tip", "axis/plane", "axis/x", "axis/s"),
    "growth": ("growth/edges", "growth/alpha", "growth/stiffness", "growth/hinges",
               "growth/rest_angle", "growth/connections"),
    "simulate": ("frames/time", "frames/positions", "mesh/faces"),
}
STAGES = tuple(STAGE_DATASETS)


def sha256_file(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def input_hashes(cfg, *paths: str | Path) -> dict[str, str]:
    """Provenance of a stage's inputs: path -> sha256, the config file included."""
    files = [Path(p) for p in paths]
    if cfg.path is not None:
        files.append(cfg.path)
    return {str(p): sha256_file(p) for p in files}


def command_line() -> str:
    return " ".join([Path(sys.argv[0]).name, *sys.argv[1:]])


def is_artifact_of(path: Path, stages: tuple[str, ...]) -> bool:
    """True if ``path`` is an HDF5 file written by one of ``stages``."""
    try:
        with h5py.File(path, "r") as f:
            return f.attrs.get("stage") in stages
    except Exception:
        return False


def check_output(path: str | Path, stage: str, overwrite: bool) -> Path:
    """Refuse an output path that holds something this stage did not write.

    A stage replaces its own artifact (that is what make asks of it when an input has
    changed); anything else at that path is the user's and stays, unless ``--overwrite``.
    """
    path = Path(path)
    if path.is_dir():
        raise BloomError("is a folder; --out needs a file path", where=str(path))
    if path.exists() and not overwrite and not is_artifact_of(path, (stage,)):
        raise BloomError(f"exists and is not a {stage} artifact; not overwriting it "
                         "(pass --overwrite to replace it)", where=str(path))
    parent = path.parent
    if not parent.exists():
        missing = [p for p in (parent, *parent.parents) if not p.exists()]
        parent.mkdir(parents=True, exist_ok=True)
        CREATED.extend(missing)  # (deepest first)
    return path


#: when the running stage began (set by the command line for each command)
STARTED = [time.monotonic()]
#: the folders this command made for its output (:func:`check_output`), deepest first
CREATED: list[Path] = []


def remove_created() -> None:
    """Remove the folders :func:`check_output` made for a command that then failed,
    those still empty (nothing half-made is left behind, not even a folder)."""
    for folder in CREATED:
        try:
            folder.rmdir()
        except OSError:  # (not empty, or gone: left as it is)
            pass
    CREATED.clear()


@contextmanager
def writing(path: str | Path, *, stage: str, config_json: str, inputs: dict[str, str],
            attrs: dict[str, Any] | None = None,
            previous: Artifact | None = None) -> Iterator[h5py.File]:
    """Open a temporary HDF5 file for ``path``; rename it into place if the block succeeds.

    On any exception (including KeyboardInterrupt) the temporary file is removed and the
    previous artifact at ``path``, if any, is left as it was. The artifact records the
    wall seconds of every stage so far in ``timings`` (JSON: stage -> seconds), the
    ``previous`` artifact's carried forward and this stage's (from its start to here).
    """
    timings = json.loads(previous.attrs.get("timings", "{}")) if previous is not None else {}
    timings[stage] = round(time.monotonic() - STARTED[0], 3)
    with atomic_path(path) as tmp, h5py.File(tmp, "w", track_order=True) as f:
        f.attrs["stage"] = stage
        f.attrs["command"] = command_line()
        f.attrs["config"] = config_json
        f.attrs["inputs"] = json.dumps(inputs, sort_keys=True)
        f.attrs["version"] = __version__
        f.attrs["timings"] = json.dumps(timings)
        for key, value in (attrs or {}).items():
            f.attrs[key] = value
        yield f


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path next to ``path`` to write any file to; renamed into place if the
    block succeeds, removed if it fails (the previous file is left as it was). The one
    way every file Bloom writes reaches its name: artifacts, reports, USD, meshes,
    checkpoints."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.tmp-{os.getpid()}{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


@contextmanager
def writing_folder(out: str | Path, overwrite: bool, marker: str, stage: str) -> Iterator[Path]:
    """A temporary folder to write the folder output ``out`` into: swapped into place if
    the block succeeds, removed if it fails (the previous ``out`` is left as it was).
    A folder that exists, is not empty and has no ``marker`` file (so ``bloom stage``
    did not write it) is refused unless ``overwrite``."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise BloomError("exists and is not a folder; --out needs a folder", where=str(out))
    if out.is_dir() and any(out.iterdir()) and not (out / marker).exists() and not overwrite:
        raise BloomError(f"folder exists and was not written by `bloom {stage}`; not "
                         "overwriting it (pass --overwrite)", where=str(out))
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp-{os.getpid()}")
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    old = out.with_name(f".{out.name}.old-{os.getpid()}")  # the old one goes only after
    if out.exists():
        os.replace(out, old)
    os.replace(tmp, out)
    if old.exists():
        shutil.rmtree(old)


def put(f: h5py.File, name: str, data: Any, doc: str | None = None) -> None:
    """Write one dataset (compressed when large), with an optional one-line description."""
    arr = np.asarray(data)
    kwargs = {}
    if arr.size > 4096:
        kwargs = {"compression": "gzip", "compression_opts": 4, "shuffle": True}
    ds = f.create_dataset(name, data=arr, **kwargs)
    if doc:
        ds.attrs["doc"] = doc


class Artifact:
    """A read-only view of an artifact, checked to hold what a stage needs."""

    def __init__(self, path: str | Path, needs: str, reader: str):
        self.path = Path(path)
        where = str(self.path)
        if not self.path.exists():
            raise BloomError("file not found", where=where)
        if self.path.is_dir():
            raise BloomError("is a folder, not an HDF5 artifact", where=where)
        try:
            self.file = h5py.File(self.path, "r")
        except OSError:
            raise BloomError("not an HDF5 artifact (unreadable or truncated)", where=where) from None
        stage = self.file.attrs.get("stage")
        if stage not in STAGES:
            self.file.close()
            raise BloomError("not a Bloom artifact (no 'stage' attribute)", where=where)
        for name in STAGE_DATASETS[needs]:
            if name not in self.file:
                self.file.close()
                got = f"written by `bloom {stage}`" if stage else "unknown"
                raise BloomError(f"`bloom {reader}` needs the output of `bloom {needs}` "
                                 f"({name} missing; this file was {got})", where=where)
        self.stage = stage

    def __enter__(self) -> Artifact:
        return self

    def __exit__(self, *exc) -> None:
        self.file.close()

    def __contains__(self, name: str) -> bool:
        return name in self.file

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self.file:
            raise BloomError(f"dataset {name} is missing (a damaged or hand-edited artifact?); "
                             f"rebuild it with `bloom {self.stage}`", where=str(self.path))
        try:
            return self.file[name][()]
        except OSError:
            raise BloomError(f"dataset {name} is unreadable (a damaged artifact?); rebuild it "
                             f"with `bloom {self.stage}`", where=str(self.path)) from None

    @property
    def attrs(self) -> h5py.AttributeManager:
        return self.file.attrs

    def config(self) -> dict:
        return json.loads(self.file.attrs["config"])

    def copy_to(self, out: h5py.File, names: tuple[str, ...]) -> None:
        """Carry datasets forward unchanged, so later stages need not open earlier files."""
        for name in names:
            if name in self.file:
                self.file.copy(self.file[name], out, name=name)


def describe(path: str | Path) -> dict:
    """What the HDF5 file at ``path`` holds: its attributes (JSON ones decoded) and each
    dataset's shape, dtype, range and one-line description."""
    path = Path(path)
    where = str(path)
    if not path.exists():
        raise BloomError("file not found", where=where)
    try:
        f = h5py.File(path, "r")
    except OSError:
        raise BloomError("not an HDF5 file (unreadable or truncated)", where=where) from None
    with f:
        def plain(value):
            if isinstance(value, bytes):
                value = value.decode()
            if isinstance(value, str) and value[:1] in "{[":
                try:
                    return json.loads(value)
                except json.JSONDecodeError:
                    return value
            if isinstance(value, np.ndarray):
                return value.tolist()
            if isinstance(value, np.generic):
                return value.item()
            return value

        attrs = {k: plain(v) for k, v in f.attrs.items()}
        datasets = {}

        def visit(name, obj):
            if isinstance(obj, h5py.Dataset):
                entry = {"shape": list(obj.shape), "dtype": str(obj.dtype)}
                if obj.dtype.kind in "fiub" and obj.size and obj.size <= 50_000_000:
                    data = obj[()]
                    entry["min"] = plain(np.min(data))
                    entry["max"] = plain(np.max(data))
                if "doc" in obj.attrs:
                    entry["doc"] = plain(obj.attrs["doc"])
                datasets[name] = entry

        f.visititems(visit)
    return {"file": where, "attributes": attrs, "datasets": datasets}
