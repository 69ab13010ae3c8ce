"""bloom export: the bloom as a cache DCC tools read (USD; OBJ or PLY sequences)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from pipeline.errors import BloomError

from .common import config_options, load, log, up_direction, writing_folder

MARKER = "export.json"
USD_SUFFIXES = (".usd", ".usdc", ".usda")


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
    """Export the frames of SIM_H5 at the input mesh's scale: a USD stage with one mesh
    per petal and time-sampled points and normals (played at render.fps), or one OBJ or
    PLY file per frame."""
    from pipeline import artifact, export

    cfg = load(config_path, overrides)
    out = Path(out)
    with artifact.Artifact(sim_h5, needs="simulate", reader="export") as src:
        scale = float(src.attrs["scale"])
        positions = src["frames/positions"] / scale
        faces, petal = src["mesh/faces"], src["mesh/petal"]
        fps = cfg["render.fps"]  # the scene's, as simulated, unless given here
        if config_path is None and not any(o.startswith("render.fps=") for o in overrides):
            fps = src.config().get("render", {}).get("fps", fps)
        if fmt == "usd":
            if out.suffix.lower() not in USD_SUFFIXES:
                raise BloomError("--out: a USD file must end in .usd, .usdc or .usda",
                                 where=str(out))
            _check_usd_output(out, overwrite)
            out.parent.mkdir(parents=True, exist_ok=True)
            up = up_direction(src)
            with artifact.atomic_path(out) as tmp:
                export.write_usd(tmp, positions, faces, petal, fps,
                                 source={"source": str(sim_h5),
                                         "sha256": artifact.sha256_file(sim_h5)},
                                 up="Y" if up is not None and abs(up[1]) > abs(up[2]) else "Z",
                                 meters_per_unit=cfg["export.meters_per_unit"])
        else:
            with writing_folder(out, overwrite, MARKER, "export") as tmp:
                if fmt == "xdmf":
                    export.write_xdmf(tmp, positions, faces, petal, fps)
                else:
                    export.write_sequence(tmp, positions, faces, fmt)
                (tmp / MARKER).write_text(json.dumps(
                    {"source": str(sim_h5), "format": fmt, "frames": len(positions),
                     "scale": "input units (positions / artifact scale)"}, indent=2))
    log.info("wrote %s (%d frames, %d petals)", out, len(positions), int(petal.max()) + 1)


def _check_usd_output(out: Path, overwrite: bool) -> None:
    """Never replace a USD file `bloom export` did not write (unless --overwrite)."""
    if out.is_dir():
        raise BloomError("is a folder; --out needs a .usd/.usdc/.usda file", where=str(out))
    if not out.exists() or overwrite:
        return
    from pxr import Sdf, Tf

    try:
        layer = Sdf.Layer.FindOrOpen(str(out))
    except Tf.ErrorException:
        layer = None  # not a USD file at all
    if layer is None or "bloom" not in dict(layer.customLayerData):
        raise BloomError("exists and was not written by `bloom export`; not overwriting it "
                         "(pass --overwrite)", where=str(out))
