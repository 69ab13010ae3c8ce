"""Options every stage shares, and the small steps every stage takes."""

from __future__ import annotations

import logging
from contextlib import contextmanager
from pathlib import Path

import click

from pipeline.artifact import sha256_file
from pipeline.config import Config, load_config

log = logging.getLogger("bloom")


def config_options(f):
    """--config FILE and --set section.key=value (repeatable)."""
    f = click.option("--set", "overrides", multiple=True, metavar="SECTION.KEY=VALUE",
                     help="Override one config value (repeatable), e.g. --set simulate.steps=1000.")(f)
    f = click.option("--config", "config_path", type=click.Path(dir_okay=False),
                     help="Scene file (TOML). Without it, the defaults.")(f)
    return f


def output_options(f):
    """--out PATH and --overwrite."""
    f = click.option("--overwrite", is_flag=True,
                     help="Replace an existing --out even if this stage did not write it.")(f)
    f = click.option("--out", "out", required=True, type=click.Path(),
                     help="Where to write the result.")(f)
    return f


def load(config_path: str | None, overrides: tuple[str, ...]) -> Config:
    return load_config(config_path, overrides)


def input_hashes(cfg: Config, *paths: str | Path) -> dict[str, str]:
    """Provenance of a stage's inputs: path -> sha256, the config file included."""
    files = [Path(p) for p in paths]
    if cfg.path is not None:
        files.append(cfg.path)
    return {str(p): sha256_file(p) for p in files}


@contextmanager
def writing_folder(out: Path, overwrite: bool, marker: str, stage: str):
    """A temporary folder to write the folder output ``out`` into: swapped into place if
    the block succeeds, removed if it fails (the previous ``out`` is left as it was).
    A folder that exists, is not empty and has no ``marker`` file (so this stage did not
    write it) is refused unless ``overwrite``."""
    import shutil

    tmp = _prepare_folder(out, overwrite, marker, stage)
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    _commit_folder(tmp, out)


def _prepare_folder(out: Path, overwrite: bool, marker: str, stage: str) -> Path:
    import os
    import shutil

    from pipeline.errors import BloomError

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
    return tmp


def _commit_folder(tmp: Path, out: Path) -> None:
    """Swap the finished folder into place; the old one is removed only after."""
    import os
    import shutil

    old = out.with_name(f".{out.name}.old-{os.getpid()}")
    if out.exists():
        os.replace(out, old)
    os.replace(tmp, out)
    if old.exists():
        shutil.rmtree(old)


class _NoBar:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def update(self, n):
        pass


def progress_bar(length: int, label: str, show: bool | None = None):
    """A progress bar on stderr when it is a terminal (or when ``show``); otherwise a
    bar that shows nothing, so logs and pipes stay clean."""
    import sys

    if show is None:
        show = sys.stderr.isatty()
    if not show:
        return _NoBar()
    return click.progressbar(length=length, label=label, file=sys.stderr, show_eta=True,
                             show_percent=True)


def up_direction(src):
    """The flower's axis, pointing from the petals' bases toward their tips."""
    import numpy as np

    axis = src.attrs.get("flower_axis")
    if axis is None or not np.all(np.isfinite(axis)):
        return None
    d = np.asarray(axis[3:], dtype=np.float64)
    if "axis/tip" in src and "axis/base" in src:
        v = src["mesh/vertices"] if "mesh/vertices" in src else src["frames/positions"][0]
        if (v[src["axis/tip"]].mean(axis=0) - v[src["axis/base"]].mean(axis=0)) @ d < 0:
            d = -d
    return d
