"""bloom export: the bloom as a cache DCC tools read (USD; OBJ or PLY sequences)."""

from __future__ import annotations

import click

from .common import config_options, load


@click.command("export")
@click.argument("sim_h5", type=click.Path(dir_okay=False))
@config_options
@click.option("--format", "fmt", type=click.Choice(["usd", "obj", "ply", "xdmf"]),
              default="usd", show_default=True,
              help="usd: one stage file; obj, ply: a numbered sequence; xdmf: a ParaView "
                   "time series (bloom.xdmf + bloom.h5).")
@click.option("--out", required=True, type=click.Path(),
              help="bloom.usdc (or .usd, .usda) for usd; a folder for obj, ply and xdmf.")
@click.option("--overwrite", is_flag=True,
              help="Replace --out even if `bloom export` did not write it.")
def command(sim_h5: str, config_path, overrides, fmt: str, out: str, overwrite: bool) -> None:
    """Export the frames of SIM_H5 at the input mesh's scale. With export.mesh = "input"
    (the default): the user's own parts, under their names, with their polygons, UVs,
    normals and materials, the petals deformed by the simulated sheet through their
    binding and the other parts in place; with "sheet": the simulated sheet, one mesh
    per petal. USD: one stage file, time codes the frame numbers, played at render.fps;
    OBJ or PLY: one file per frame; XDMF: a ParaView time series."""
    from pipeline.chain import export

    export.run(sim_h5, out, load(config_path, overrides), overwrite=overwrite, fmt=fmt)
