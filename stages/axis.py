"""bloom axis: base, tip, center plane, axis vertices, s and x of every petal."""

from __future__ import annotations

import click

from .common import config_options, load, output_options


@click.command("axis")
@click.argument("remesh_h5", type=click.Path(dir_okay=False))
@config_options
@output_options
def command(remesh_h5: str, config_path, overrides, out, overwrite) -> None:
    """Find each petal's base, tip, center plane and cross-section coordinates."""
    from pipeline.chain import axis

    axis.run(remesh_h5, out, load(config_path, overrides), overwrite=overwrite)
