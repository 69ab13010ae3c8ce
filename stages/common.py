"""Options every stage shares, and the small steps every stage takes."""

from __future__ import annotations

import logging

import click

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
