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
from pipeline.expr import evaluate_curve
from pipeline.progress import Progress
from pipeline.review import render

log = logging.getLogger("bloom")

MARKER = "render.json"  #: the file that says `bloom render` wrote a folder


def run(artifact_h5: str | Path, out: str | Path, cfg: Config, *, overwrite: bool = False) -> None:
    """Render ``artifact_h5`` off-screen into the folder ``out``.

    sim.h5 gives OUT/frames/NNNN.png, OUT/bloom.mp4 and OUT/contact_sheet.png; remesh.h5,
    axis.h5 and growth.h5 give OUT/<stage>.png, a still for debugging that stage.
    """
    rc = cfg.section("render")
    out = Path(out)
    with artifact.Artifact(artifact_h5, needs="remesh" if _stage(artifact_h5) != "simulate"
                           else "simulate", reader="render") as src:
        stage = src.stage
        with artifact.writing_folder(out, overwrite, MARKER, "render") as tmp:
            up = up_direction(src)
            if stage == "simulate":
                pos = src["frames/positions"]
                times = src["frames/time"]
                labels = [f"t = {t:,.0f}" for t in times]
                if "diagnostics/opening_angle" in src:
                    angle = src["diagnostics/opening_angle"]
                    labels = [f"{lab}   opening {a:+.1f} deg" for lab, a in zip(labels, angle, strict=True)]
                palette = rc["palette"]
                growth = None
                if palette == "growth":
                    curve = json.loads(src.attrs["config"])["growth"]["curve"]
                    growth = evaluate_curve(curve, src["axis/x"])
                total = len(pos) + rc["turntable_frames"]
                with Progress(total, "render") as bar:
                    render.render_frames(
                        pos, src["mesh/faces"], tmp, width=rc["width"], height=rc["height"],
                        fps=rc["fps"], color=rc["color"], contact_frames=rc["contact_frames"],
                        up=up, labels=labels,
                        petal=src["mesh/petal"] if palette == "petals" else None,
                        growth=growth, turntable_frames=rc["turntable_frames"],
                        progress=bar.update)
                written = {"frames": len(pos), "mp4": "bloom.mp4",
                           "contact_sheet": "contact_sheet.png"}
                if rc["turntable_frames"]:
                    written["turntable"] = "turntable.mp4"
            else:
                name = f"{stage}.png"
                _debug_view(src, stage, tmp / name, rc, up)
                written = {"still": name}
            (tmp / MARKER).write_text(json.dumps({"source": str(artifact_h5), "stage": stage,
                                                  "render": rc, **written}, indent=2))
    log.info("wrote %s", out)




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
