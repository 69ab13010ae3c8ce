"""The report stage: what the bloom and its effects did, measured -> report.json and
report.png (:mod:`pipeline.review.report`)."""

from __future__ import annotations

import json
import logging
from pathlib import Path

from pipeline import artifact
from pipeline.errors import BloomError
from pipeline.review import report

log = logging.getLogger("bloom")


def run(sim_h5: str | Path, out: str | Path, cfg=None, *, overwrite: bool = False) -> None:
    """Measure ``sim_h5``: opening per petal, cross-section curvature, boundary wrinkles,
    crossings between petals, connection breaks, Gaussian curvature sign; and whether the
    bloom is sound: frames with an intersection, the last frame's distance to the model
    (an open start), petals that did not open (under 5 deg: a warning naming each) -> ``out``
    (report.json; the plot beside it, report.png). It takes no config (``cfg`` unused)."""
    out_path = Path(out)
    if out_path.suffix.lower() != ".json":
        raise BloomError("--out must name a .json file (the plot goes beside it as .png)",
                         where=str(out_path))
    png = out_path.with_suffix(".png")
    for path in (out_path, png):
        if path.is_dir():
            raise BloomError("is a folder; --out needs a file path", where=str(path))
    if out_path.exists() and not overwrite and not _is_report(out_path):
        raise BloomError("exists and is not a Bloom report; not overwriting it (pass "
                         "--overwrite to replace it)", where=str(out_path))
    if png.exists() and not overwrite and not _is_report(out_path):
        raise BloomError("exists and was not written by `bloom report`; not overwriting it "
                         "(pass --overwrite to replace it)", where=str(png))
    with artifact.Artifact(sim_h5, needs="simulate", reader="report") as sim:
        missing = [name for name in report.NEEDS if name not in sim]
        if missing:
            raise BloomError(f"made by an older `bloom simulate` ({missing[0]} missing); "
                             "rerun `bloom simulate` to report on it", where=str(sim_h5))
        data = {"stage": "report", "input": str(sim_h5), **report.compute(sim)}
    out_path.parent.mkdir(parents=True, exist_ok=True)
    with artifact.atomic_path(out_path) as tmp_json, artifact.atomic_path(png) as tmp_png:
        tmp_json.write_text(json.dumps(data, indent=1) + "\n")
        report.plot(data, tmp_png)
    log.info("opening %.1f deg; wrinkles %d; crossings %d at the end; %d of %d frames with "
             "an intersection", data["opening_angle_final_mean"], data["boundary_wrinkles"][-1],
             data["crossings"][-1], data["intersecting_frames"], len(data["intersecting"]))
    report.warn_not_opened(data["not_opened"], lambda m: log.warning("warning: %s", m))
    report.warn_lagging(data, lambda m: log.warning("warning: %s", m))
    log.info("%s", data["summary"])
    log.info("wrote %s and %s", out_path, png)


def _is_report(path: Path) -> bool:
    try:
        return json.loads(path.read_text()).get("stage") == "report"
    except Exception:
        return False
