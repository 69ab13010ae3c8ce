"""bloom export: the bloom as a cache DCC tools read (USD; OBJ or PLY sequences)."""

from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np

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
    """Export the frames of SIM_H5 at the input mesh's scale. With export.mesh = "input"
    (the default): the user's own parts, under their names, with their polygons, UVs,
    normals and materials, the petals deformed by the simulated sheet through their
    binding and the other parts in place; with "sheet": the simulated sheet, one mesh
    per petal. USD: one stage file, time codes the frame numbers, played at render.fps;
    OBJ or PLY: one file per frame; XDMF: a ParaView time series."""
    from pipeline import artifact, binding, export, userasset

    cfg = load(config_path, overrides)
    out = Path(out)
    with artifact.Artifact(sim_h5, needs="simulate", reader="export") as src:
        scale = float(src.attrs["scale"])
        sheet = src["frames/positions"]
        positions = sheet / scale
        faces, petal = src["mesh/faces"], src["mesh/petal"]
        numbers = src["frames/frame"] if "frames/frame" in src else np.arange(len(positions))
        fps = cfg["render.fps"]  # the scene's, as simulated, unless given here
        if config_path is None and not any(o.startswith("render.fps=") for o in overrides):
            fps = src.config().get("render", {}).get("fps", fps)
        asset = userasset.read(src)
        if cfg["export.mesh"] == "input" and asset is None:
            raise BloomError("export.mesh: this artifact holds no input asset (input/asset: the "
                             "remesh stage could not match the file's own parts); set "
                             "export.mesh = \"sheet\"", where=sim_h5)
        use_input = cfg["export.mesh"] == "input"
        meters = (asset.meters_per_unit if asset is not None and asset.meters_per_unit
                  else cfg["export.meters_per_unit"])
        if use_input:
            bindings = binding.read_bindings(src)
            sides = export.part_sides(asset, bindings, sheet[0], faces, scale)
            frames = export.asset_frames(sheet, faces, asset, bindings, scale,
                                         cfg["export.keep_thickness"], sides)
            _report(asset, bindings, frames, sheet / scale, sides)
        if fmt == "usd":
            if out.suffix.lower() not in USD_SUFFIXES:
                raise BloomError("--out: a USD file must end in .usd, .usdc or .usda",
                                 where=str(out))
            _check_usd_output(out, overwrite)
            out.parent.mkdir(parents=True, exist_ok=True)
            up = _up_axis(src, asset, cfg)
            source = {"source": str(sim_h5), "sha256": artifact.sha256_file(sim_h5)}
            with artifact.atomic_path(out) as tmp:
                if use_input:
                    turns = _turns(sheet, faces, asset, bindings)
                    export.write_usd_asset(tmp, frames, asset, fps, numbers, turns=turns,
                                           source=source, up=up, meters_per_unit=meters)
                else:
                    export.write_usd(tmp, positions, faces, petal, fps, source=source, up=up,
                                     meters_per_unit=meters, frame_numbers=numbers)
        else:
            with writing_folder(out, overwrite, MARKER, "export") as tmp:
                if use_input and fmt == "obj":
                    export.write_obj_asset(tmp, frames, asset, numbers)
                else:
                    pos, tris, labels = positions, faces, petal
                    if use_input:
                        pos, tris = export.joined_asset(frames, asset)
                        labels = np.concatenate([np.full(len(p.points), i) for i, p in
                                                 enumerate(asset.parts)])
                    if fmt == "xdmf":
                        export.write_xdmf(tmp, pos, tris, labels, fps)
                    else:
                        export.write_sequence(tmp, pos, tris, fmt)
                (tmp / MARKER).write_text(json.dumps(
                    {"source": str(sim_h5), "format": fmt, "frames": len(positions),
                     "mesh": cfg["export.mesh"],
                     "scale": "input units (positions / artifact scale)"}, indent=2))
    what = (f"{len(asset.parts)} parts" if use_input else f"{int(petal.max()) + 1} petals")
    log.info("wrote %s (%d frames, %s)", out, len(positions), what)


def _up_axis(src, asset, cfg) -> str:
    """"Y" or "Z": the input file's (glTF: +Y), else scene.up's, else whichever the
    flower's axis is nearer."""
    said = (asset.up if asset is not None and asset.up else
            cfg["scene.up"] if cfg["scene.up"] != "auto" else None)
    if said is not None:
        return "Y" if said[-1] == "y" else "Z"
    up = up_direction(src)
    return "Y" if up is not None and abs(up[1]) > abs(up[2]) else "Z"


def _turns(sheet, faces, asset, bindings) -> dict:
    """Per deformed part with normals of its own: each frame's rotation of each point's
    local frame from rest (the normals turn with it)."""
    from pipeline import binding
    from pipeline.topology import vertex_normals

    out = {}
    for i, b in bindings.items():
        if asset.parts[i].normals is None:
            continue
        rest = binding.local_frames(sheet[0], faces, b.face, b.bary)
        out[i] = np.stack([binding.rotations(X, faces, b, rest, vertex_normals(X, faces))
                           for X in sheet])
    return out


def _report(asset, bindings, frames, sheet, sides: dict) -> None:
    """Log what the binding did: the largest frame-to-frame jump of a bound point against
    the sheet's own, and how far a thick part's thickness strayed from the input's in any
    frame (``sides``: :func:`pipeline.export.part_sides`)."""
    from pipeline import binding

    if not bindings:
        return
    sheet_jump = float(np.linalg.norm(np.diff(sheet, axis=0), axis=2).max()) if len(sheet) > 1 else 0.0
    jump = max(float(np.linalg.norm(np.diff(frames[i], axis=0), axis=2).max())
               for i in bindings) if len(sheet) > 1 else 0.0
    log.info("bound parts: largest frame-to-frame jump %.4g (the sheet's own: %.4g), input units",
             jump, sheet_jump)
    for i, b in sorted(bindings.items()):
        part = asset.parts[i]
        tris = part.triangles()
        s = sides[i]
        which, rest = s.point[s.positive], s.rest[s.positive]
        if len(which) == 0:  # (a one-sided part: no thickness to keep)
            continue
        change = [float(np.abs(binding.thickness(X, tris, b.offset[:, 2], which) / rest - 1).max())
                  for X in frames[i]]
        worst = int(np.argmax(change))
        log.info("part %r: thickness (median %.4g, %d points) within %.2f%% of the input's in "
                 "every frame (the most at frame %d)", part.name, float(np.median(rest)),
                 len(which), 100 * change[worst], worst)


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
