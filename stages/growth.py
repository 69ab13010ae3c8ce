"""bloom growth: growth ratio per edge from growth.curve, hinges, rest angles."""

from __future__ import annotations

import click

from .common import config_options, load, output_options


@click.command("growth")
@click.argument("axis_h5", type=click.Path(dir_okay=False))
@config_options
@output_options
def command(axis_h5: str, config_path, overrides, out, overwrite) -> None:
    """Assign each edge its growth ratio alpha = growth.curve(x) and list the hinges."""
    from pipeline.chain import growth

    growth.run(axis_h5, out, load(config_path, overrides), overwrite=overwrite)
