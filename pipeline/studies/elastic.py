"""``bloom study elastic``: every default scene with the paper's springs and with the shell,
side by side (issue 31): the final opening, the cross-section curvature, the rim's
wrinkles, the simulate time, and a picture of each bloom's bud and last frame.

Each scene runs through remesh, axis, growth and simulate as ``make`` runs it
(:func:`pipeline.chain.run_scene`), once with ``simulate.model = paper`` and once with
``shell``; the figures are the report's (:func:`pipeline.review.report.compute`).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from pipeline import artifact
from pipeline.chain import run_scene
from pipeline.review import render, report

MODELS = ("paper", "shell")


def compare(configs: list[Path], out: Path, *, echo=print, width: int = 320,
            height: int = 240) -> list[dict]:
    """Run each scene of ``configs`` with both models; write ``out/elastic.png`` (one row
    per scene: the paper's bud and bloom, the shell's) and return one row per run."""
    rows, sheets = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for config in configs:
            pair = []
            for model in MODELS:
                folder = Path(tmp) / f"{config.stem}-{model}"
                made = run_scene(config, folder, overrides=(f"simulate.model={model}",))
                with artifact.Artifact(made["simulate"], "simulate", "study elastic") as sim:
                    rep = report.compute(sim)
                    X = sim["frames/positions"]
                    row = {"scene": config.stem, "model": model,
                           "vertices": int(X.shape[1]),
                           "opening_deg": float(rep["opening_angle_final_mean"]),
                           "curvature": float(rep["cross_section_curvature"][-1]),
                           "wrinkles": int(rep["boundary_wrinkles"][-1]),
                           "simulate_seconds": float(sim.attrs["wall_seconds"]),
                           "intersecting_frames": int(rep["intersecting_frames"])}
                    layer = render.sheet_layer(X[[0, -1]], sim["mesh/faces"], None,
                                               color="#f4a6c1", palette="color")
                    up = render.flower_up(sim.attrs.get("flower_axis"))
                labels = [f"{config.stem}, {model}: bud",
                          f"{model}: {row['opening_deg']:.1f} deg, {row['wrinkles']} wrinkles"]
                render.render_frames([layer], folder / "render", width=width, height=height,
                                     fps=2, contact_frames=2, up=up, labels=labels)
                pair.append(folder / "render" / "contact_sheet.png")
                rows.append(row)
                echo(f"{row['scene']:>14} {model:>5}: opening {row['opening_deg']:6.1f} deg, "
                     f"curvature {row['curvature']:.4f}, wrinkles {row['wrinkles']:3d}, "
                     f"simulate {row['simulate_seconds']:6.1f} s")
            sheets.append(pair)
        _figure(sheets, out / "elastic.png")
    return rows


def _figure(sheets: list[list[Path]], path: Path) -> None:
    """The contact sheets, one row per scene, the paper's left and the shell's right."""
    import imageio.v2 as imageio

    rows = [np.concatenate([imageio.imread(p)[..., :3] for p in pair], axis=1)
            for pair in sheets]
    imageio.imwrite(path, np.concatenate(rows, axis=0))


def table(rows: list[dict]) -> str:
    """The runs as a markdown table, a scene's two models side by side."""
    by = {(r["scene"], r["model"]): r for r in rows}
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    lines = ["| scene | opening paper / shell | curvature paper / shell | wrinkles paper / shell "
             "| simulate paper / shell |",
             "|---|---|---|---|---|"]
    for s in scenes:
        p, q = by[(s, "paper")], by[(s, "shell")]
        lines.append(f"| {s} | {p['opening_deg']:.1f} / {q['opening_deg']:.1f} deg | "
                     f"{p['curvature']:.4f} / {q['curvature']:.4f} | "
                     f"{p['wrinkles']} / {q['wrinkles']} | "
                     f"{p['simulate_seconds']:.1f} / {q['simulate_seconds']:.1f} s |")
    return "\n".join(lines)
