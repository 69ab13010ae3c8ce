"""bloom simulate: grow the petals and integrate (Eq. 6-8) -> sim.h5."""

from __future__ import annotations

import click

from .common import config_options, load, output_options


@click.command("simulate")
@click.argument("growth_h5", type=click.Path(dir_okay=False))
@config_options
@output_options
@click.option("--progress/--no-progress", default=None,
              help="Progress bar [default: on when stderr is a terminal].")
@click.option("--resume", is_flag=True,
              help="Continue from the checkpoint an interrupted run of the same inputs and "
                   "config left next to --out (same result as an uninterrupted run).")
def command(growth_h5: str, config_path, overrides, out, overwrite, progress, resume) -> None:
    """Simulate the bloom of the petals in GROWTH_H5 and write the frames to sim.h5."""
    from pipeline.chain import simulate

    simulate.run(growth_h5, out, load(config_path, overrides), overwrite=overwrite,
                 resume=resume, progress=progress)
