"""The export stage: the bloom as a cache other tools read: USD (the user's own parts,
deformed through their binding, or the simulated sheet), OBJ or PLY sequences, XDMF."""

from __future__ import annotations

import contextlib
import json
import logging
from pathlib import Path

import numpy as np
from pxr import Sdf, Tf

from pipeline import artifact
from pipeline.chain import up_direction
from pipeline.config import Config
from pipeline.errors import BloomError
from pipeline.flower import stagger
from pipeline.io import binding, export, userasset
from pipeline.mesh.topology import vertex_normals
from pipeline.progress import Progress

log = logging.getLogger("bloom")

MARKER = "export.json"  #: the file that says `bloom export` wrote a folder
USD_SUFFIXES = (".usd", ".usdc", ".usda")


def run(sim_h5: str | Path, out: str | Path, cfg: Config, *, overwrite: bool = False,
        fmt: str = "usd") -> None:
    """Export the frames of ``sim_h5`` at the input mesh's scale to ``out`` in ``fmt``
    (usd, obj, ply, xdmf). With export.mesh = "input" (the default): the user's own
    parts, under their names, with their polygons, UVs, normals and materials, the
    petals deformed by the simulated sheet through their binding and the other parts in
    place; with "sheet": the simulated sheet, one mesh per petal. USD: one stage file,
    time codes the frame numbers, played at render.fps; OBJ or PLY: one file per frame;
    XDMF: a ParaView time series."""
    out = Path(out)
    with contextlib.ExitStack() as stack:
        src = stack.enter_context(artifact.Artifact(sim_h5, needs="simulate", reader="export"))
        scale = float(src.attrs["scale"])
        sheet = src["frames/positions"]
        numbers = src["frames/frame"][()] if "frames/frame" in src else np.arange(len(sheet))
        starts = stagger.of_run(src, cfg)
        if starts is not None:  # many flowers, each from its own start frame
            sheet = stagger.staggered(sheet, stagger.vertex_flowers(src), starts)
            numbers = np.r_[numbers, numbers[-1] + 1 + np.arange(len(sheet) - len(numbers))]
            log.info("scene.stagger = %s: %d flowers start at frames %s", cfg["scene.stagger"],
                     len(starts), ", ".join(map(str, starts)))
        positions = sheet / scale
        faces, petal = src["mesh/faces"], src["mesh/petal"]
        fps = cfg["render.fps"]  # the scene's, as simulated, unless given here
        if "render.fps" not in cfg.given:
            fps = src.config().get("render", {}).get("fps", fps)
        asset = userasset.read(src)
        if cfg["export.mesh"] == "input" and asset is None:
            raise BloomError("export.mesh: this artifact holds no input asset (input/asset: the "
                             "remesh stage could not match the file's own parts); set "
                             "export.mesh = \"sheet\"", where=sim_h5)
        use_input = cfg["export.mesh"] == "input"
        meters = (asset.meters_per_unit if asset is not None and asset.meters_per_unit
                  else cfg["export.meters_per_unit"])
        # (a bar on a terminal, log lines under make: a branch of blossoms took minutes)
        bar = stack.enter_context(Progress(3 * len(asset.parts) if use_input else 1, "export"))

        def done(name):
            bar.reach(bar.done + 1, f"part {name!r}")

        if use_input:
            bindings = binding.read_bindings(src)
            sides = export.part_sides(asset, bindings, sheet[0], faces, scale)
            frames = export.asset_frames(sheet, faces, asset, bindings, scale,
                                         cfg["export.keep_thickness"], sides, progress=done)
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
                    turns = _turns(sheet, faces, asset, bindings, progress=done)
                    export.write_usd_asset(tmp, frames, asset, fps, numbers, turns=turns,
                                           source=source, up=up, meters_per_unit=meters,
                                           progress=done)
                else:
                    export.write_usd(tmp, positions, faces, petal, fps, source=source, up=up,
                                     meters_per_unit=meters, frame_numbers=numbers)
        else:
            with artifact.writing_folder(out, overwrite, MARKER, "export") as tmp:
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


def _turns(sheet, faces, asset, bindings, progress=None) -> dict:
    """Per deformed part with normals of its own: each frame's rotation of each point's
    local frame from rest (the normals turn with it). ``progress(name)``: called as each
    part is done (a part with none to turn too)."""
    out = {}
    normals = None  # (each frame's sheet normals, once for all parts)
    for i, part in enumerate(asset.parts):
        b = bindings.get(i)
        if b is not None and part.normals is not None:
            if normals is None:
                normals = [vertex_normals(X, faces) for X in sheet]
            rest = binding.local_frames(sheet[0], faces, b.face, b.bary)
            out[i] = np.stack([binding.rotations(X, faces, b, rest, N)
                               for X, N in zip(sheet, normals, strict=True)])
        if progress is not None:
            progress(part.name)
    return out


def _report(asset, bindings, frames, sheet, sides: dict) -> None:
    """Log what the binding did: the largest frame-to-frame jump of a bound point against
    the sheet's own, and how far a thick part's thickness strayed from the input's in any
    frame (``sides``: :func:`pipeline.io.export.part_sides`)."""
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
        normal = np.where(b.face >= 0, b.offset[:, 2], np.nan)  # (a piece that stays: neither)
        change = [float(np.abs(binding.thickness(X, tris, normal, which) / rest - 1).max())
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
    try:
        layer = Sdf.Layer.FindOrOpen(str(out))
    except Tf.ErrorException:
        layer = None  # not a USD file at all
    if layer is None or "bloom" not in dict(layer.customLayerData):
        raise BloomError("exists and was not written by `bloom export`; not overwriting it "
                         "(pass --overwrite)", where=str(out))
