"""bloom render: PNG frames, an MP4 and a contact sheet of sim.h5; a debug view of any
earlier artifact (petals, axis and base, growth map)."""

from __future__ import annotations

import click

from .common import config_options, load


@click.command("render")
@click.argument("artifact_h5", type=click.Path(dir_okay=False))
@config_options
@click.option("--out", required=True, type=click.Path(file_okay=False), help="Folder to write.")
@click.option("--overwrite", is_flag=True,
              help="Replace --out even if `bloom render` did not write it.")
def command(artifact_h5: str, config_path, overrides, out, overwrite) -> None:
    """Render ARTIFACT_H5 off-screen into the folder --out.

    sim.h5 gives OUT/frames/NNNN.png, OUT/bloom.mp4 and OUT/contact_sheet.png; remesh.h5,
    axis.h5 and growth.h5 give OUT/<stage>.png, a still for debugging that stage.
    """
    from pipeline.chain import render

    render.run(artifact_h5, out, load(config_path, overrides), overwrite=overwrite)
