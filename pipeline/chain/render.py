"""The render stage: PNG frames, an MP4 and a contact sheet of sim.h5; a still of any
earlier artifact for checking that stage (petals; axis and base; growth map)."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import h5py
import numpy as np

from pipeline import artifact
from pipeline.chain import up_direction
from pipeline.config import Config
from pipeline.directions import DIRECTIONS
from pipeline.expr import evaluate_curve
from pipeline.flower import stagger
from pipeline.io import binding, export, userasset
from pipeline.progress import Progress
from pipeline.review import render

log = logging.getLogger("bloom")

MARKER = "render.json"  #: the file that says `bloom render` wrote a folder


def run(artifact_h5: str | Path, out: str | Path, cfg: Config, *, overwrite: bool = False) -> None:
    """Render ``artifact_h5`` off-screen into the folder ``out``.

    sim.h5 gives OUT/frames/NNNN.png, OUT/bloom.mp4, OUT/contact_sheet.png and
    OUT/turntable.mp4: with export.mesh = "input" (the default) the user's own parts, the
    petals deformed through their binding as `bloom export` gives them and the other
    parts in place; with "sheet", the simulated sheet. The flower stands upright along its
    own axis, seen from three-quarters above, framed on its petals. remesh.h5, axis.h5 and
    growth.h5 give OUT/<stage>.png, a still for debugging that stage.
    """
    rc = cfg.section("render")
    out = Path(out)
    with artifact.Artifact(artifact_h5, needs="remesh" if _stage(artifact_h5) != "simulate"
                           else "simulate", reader="render") as src:
        stage = src.stage
        with artifact.writing_folder(out, overwrite, MARKER, "render") as tmp:
            if stage == "simulate":
                pos = src["frames/positions"]
                times = src["frames/time"]
                labels = [f"t = {t:,.0f}" for t in times]
                starts = stagger.of_run(src, cfg)
                if starts is not None:  # many flowers, each from its own start frame
                    pos = stagger.staggered(pos, stagger.vertex_flowers(src), starts)
                    labels = [f"frame {j}" for j in range(len(pos))]
                elif "diagnostics/opening_angle" in src:
                    angle = src["diagnostics/opening_angle"]
                    labels = [f"{lab}   opening {a:+.1f} deg" for lab, a in zip(labels, angle, strict=True)]
                layers, up = _bloom_layers(src, cfg, rc, pos)
                total = len(pos) + rc["turntable_frames"]
                with Progress(total, "render") as bar:
                    render.render_frames(
                        layers, tmp, width=rc["width"], height=rc["height"], fps=rc["fps"],
                        contact_frames=rc["contact_frames"], up=up, labels=labels,
                        turntable_frames=rc["turntable_frames"], progress=bar.update)
                written = {"frames": len(pos), "mp4": "bloom.mp4",
                           "contact_sheet": "contact_sheet.png"}
                if rc["turntable_frames"]:
                    written["turntable"] = "turntable.mp4"
            else:
                name = f"{stage}.png"
                _debug_view(src, stage, tmp / name, rc, up_direction(src))
                written = {"still": name}
            (tmp / MARKER).write_text(json.dumps({"source": str(artifact_h5), "stage": stage,
                                                  "render": rc, **written}, indent=2))
    log.info("wrote %s", out)




def _bloom_layers(src, cfg, rc: dict, pos):
    """The layers of a bloom (:class:`pipeline.review.render.Layer`) and the picture's up:
    the user's parts through their binding where sim.h5 holds them and export.mesh is
    "input", else the simulated sheet."""
    faces, petal = src["mesh/faces"], src["mesh/petal"]
    palette = rc["palette"]
    growth = None
    if palette == "growth":
        curve = json.loads(src.attrs["config"])["growth"]["curve"]
        growth = evaluate_curve(curve, src["axis/x"])
    asset = userasset.read(src) if cfg["export.mesh"] == "input" else None
    bindings = binding.read_bindings(src) if asset is not None else {}
    up = render.flower_up(src.attrs.get("flower_axis"), _declared_up(src, asset, cfg),
                          _rise(src, pos[0]))
    if asset is None or not bindings:
        return [render.sheet_layer(pos, faces, petal, color=rc["color"], palette=palette,
                                   growth=growth)], up
    scale = float(src.attrs["scale"])
    frames = export.asset_frames(pos, faces, asset, bindings, scale, cfg["export.keep_thickness"])
    layers = render.asset_layers(frames, asset, bindings, faces, petal, color=rc["color"],
                                 palette=palette, growth=growth, kinds=_kinds(src, asset, bindings))
    return layers, up


def _declared_up(src, asset, cfg):
    """The up the scene or the file says, as a unit vector, or None: sim.h5's ``up``
    attribute, scene.up, the input asset's (glTF: +y)."""
    for said in (src.attrs.get("up"), cfg["scene.up"], asset.up if asset is not None else None):
        said = str(said or "").strip().lower()
        if said in DIRECTIONS:
            return np.array(DIRECTIONS[said])
    return None


def _rise(src, first):
    """The petals' mean base-to-tip chord in the first frame, or None."""
    if "axis/tip" not in src or "axis/base" not in src:
        return None
    return first[src["axis/tip"]].mean(axis=0) - first[src["axis/base"]].mean(axis=0)


def _kinds(src, asset, bindings) -> list[str]:
    """What each part is (stem, stamen, ...), as remesh classified it (the ``parts``
    attribute it records and the later stages carry), for its colour; "other" where an
    artifact does not say."""
    if all(i in bindings for i in range(len(asset.parts))):
        return ["petal"] * len(asset.parts)
    parts = json.loads(src.attrs.get("parts", "[]"))
    if len(parts) != len(asset.parts):
        return ["other"] * len(asset.parts)
    return [p["kind"] for p in parts]


def _stage(path: str) -> str | None:

    try:
        with h5py.File(path, "r") as f:
            return f.attrs.get("stage")
    except Exception:
        return None


def _debug_view(src, stage: str, path: Path, rc: dict, up) -> None:
    v, f = src["mesh/vertices"], src["mesh/faces"]
    kw = dict(width=rc["width"], height=rc["height"], up=up)
    if stage == "remesh":
        render.render_debug(v, f, path, scalars=src["mesh/petal"].astype(float),
                            scalar_name="petal", cmap="tab10", title="remesh: petals", **kw)
        return
    base, on_axis, tip = src["axis/base"], src["axis/on_axis"], src["axis/tip"]
    points = {"base": (v[base], "#d62728"), "axis": (v[on_axis], "#222222"),
              "tip": (v[tip], "#ffbf00")}
    if stage == "axis":
        render.render_debug(v, f, path, scalars=src["axis/x"], scalar_name="x", cmap="coolwarm",
                            clim=(-1, 1), points=points, title="axis: x, base, tip", **kw)
        return
    edges, alpha = src["growth/edges"], src["growth/alpha"]
    total = np.zeros(len(v))
    count = np.zeros(len(v))
    for c in range(2):
        np.add.at(total, edges[:, c], alpha)
        np.add.at(count, edges[:, c], 1.0)
    render.render_debug(v, f, path, scalars=total / np.maximum(count, 1), scalar_name="alpha",
                        cmap="viridis", points=points, title="growth: alpha per vertex", **kw)
