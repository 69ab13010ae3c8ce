"""``bloom study models``: real flower models, each with a scene of ``scene.mesh`` only,
through remesh, axis, growth and simulate as ``make`` runs them, judged as an artist
would judge the bloom:

- no frame with an edge through a triangle (ipctk's exact test, every frame);
- an open model (``growth.start = auto`` decided "open") ends on itself within
  :data:`ON_MODEL` of a petal length (RMS), from a bud at least :data:`MORE_CLOSED`
  degrees more closed than the model;
- a lone petal opens by at least :data:`LONE_OPENS` degrees;
- a closed bud opens forward (its opening grows) with no petal through another;
- every petal opens (at least :data:`~pipeline.review.report.NOT_OPEN` degrees);
- the flower does not close first (its mean opening never more than
  :data:`~pipeline.review.report.CLOSES_FIRST` degrees below its start).

Each model runs in a subprocess per stage (the ``bloom`` commands), with a time limit, so
one that hangs or crashes is a row of the table, not the end of the study. The table
goes to the terminal, to ``models.csv``, and (``--into``) into a Markdown file between
the markers ``<!-- models -->`` and ``<!-- /models -->`` (docs/performance.md).
"""

from __future__ import annotations

import csv
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import h5py
import numpy as np

from pipeline.chain import SIMULATION, argv
from pipeline.review.report import CLOSES_FIRST, NOT_OPEN, closing_dip

#: an open model's last frame is within this fraction of a petal length of the model (RMS)
ON_MODEL = 0.01
#: ... and its bud at least this many degrees more closed than the model
MORE_CLOSED = 20.0
#: a lone petal opens by at least this many degrees
LONE_OPENS = 10.0
#: the mesh files a folder of models is read for
SUFFIXES = (".obj", ".glb", ".gltf", ".ply", ".stl", ".off")
BEGIN, END = "<!-- models -->", "<!-- /models -->"


@dataclass
class Row:
    """One model's run and verdict."""

    model: str
    petals: int = 0
    vertices: int = 0
    start: str = ""  #: growth.start as decided (bud / open)
    effects: str = ""
    #: simulate's wall: the ``bloom simulate`` command's, every try included
    #: (:func:`run_model`); from a sim.h5 alone (:func:`judge`), the kept bloom's and its
    #: bud search's (a file of many flowers' blooms and searches summed)
    seconds: float = 0.0
    geometry_seconds: float = 0.0  #: remesh + axis + growth
    intersecting: str = ""  #: "k of n" frames
    opened: float = float("nan")  #: the flower's opening at the end minus at the start (deg)
    least: float = float("nan")  #: the least-opened petal at the end (deg)
    distance: float = float("nan")  #: open start: last frame to the model, petal lengths
    verdict: str = ""  #: ok, or what failed


def models_in(folder: Path) -> list[Path]:
    """The mesh files in ``folder``, by name."""
    return sorted(p for p in Path(folder).iterdir() if p.suffix.lower() in SUFFIXES)


def run_model(mesh: Path, work: Path, *, timeout: float) -> Row:
    """``mesh`` through the simulation stages in ``work`` with a scene of ``scene.mesh``
    only; the row of the table."""
    row = Row(mesh.stem)
    work.mkdir(parents=True, exist_ok=True)
    config = work / "scene.toml"
    config.write_text(f'[scene]\nmesh = "{mesh.resolve()}"\n')
    deadline = time.monotonic() + timeout
    for s in SIMULATION:
        clock = time.monotonic()
        cmd = [sys.executable, "-m", "stages", "-q", *argv(s, work, config), "--overwrite"]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True,
                                  timeout=max(1.0, deadline - clock))
        except subprocess.TimeoutExpired:
            row.verdict = f"{s.name}: over the time limit ({timeout:g} s)"
            return row
        if proc.returncode != 0:
            lines = (proc.stderr or proc.stdout).strip().splitlines()
            row.verdict = f"{s.name}: {lines[-1] if lines else 'exit ' + str(proc.returncode)}"
            return row
        if s.name != "simulate":
            row.geometry_seconds += time.monotonic() - clock
        else:
            command = time.monotonic() - clock
    with h5py.File(work / "sim.h5", "r") as h:
        judge(row, h)
    # (the command's: the tries the sim.h5 does not keep count too: the daisy bush's
    # kept blooms took 98 s of its 711)
    row.seconds = command
    return row


def judge(row: Row, h) -> None:
    """Fill ``row`` from a sim.h5 and give the verdict."""
    positions = h["frames/positions"]
    petal = h["mesh/petal"][()]
    row.petals = int(petal.max()) + 1
    row.vertices = int(positions.shape[1])
    row.start = str(h.attrs.get("growth_start", ""))
    row.effects = str(h.attrs.get("effects", "")) or "none"
    row.seconds = float(h.attrs.get("wall_seconds", np.nan)) + float(h.attrs.get("bud_seconds", 0.0))
    crossed = h["diagnostics/intersecting"][()]
    row.intersecting = f"{int(crossed.sum())} of {len(crossed)}"
    opening = h["diagnostics/opening_angle"][()]
    row.opened = float(opening[-1] - opening[0])
    if "diagnostics/opening_angle_per_petal" in h:
        row.least = float(h["diagnostics/opening_angle_per_petal"][-1].min())
    row.distance = float(h.attrs.get("distance_to_model", np.nan))
    failed = []
    if crossed.any():
        failed.append("petals through each other")
    if "mesh/left" in h:  # (pairs remesh could not part: left through each other)
        left = len(h["mesh/left"])
        if left:
            failed.append(f"{left} pair(s) of petals left through each other as modelled")
    if row.start == "open":
        if not row.distance <= ON_MODEL:
            failed.append(f"ends {row.distance:.3g} petal lengths from the model")
        if not row.opened >= MORE_CLOSED:
            failed.append(f"bud only {row.opened:.1f} deg more closed")
        lean = h.attrs.get("bud_closed")
        if lean is not None and not float(lean) > 0.0:
            failed.append(f"bud hangs open the other way ({float(lean):.1f} deg)")
    elif row.petals == 1:
        if not row.opened >= LONE_OPENS:
            failed.append(f"opens {row.opened:.1f} deg")
    elif not row.opened > 0.0:
        failed.append(f"opens backward ({row.opened:.1f} deg)")
    if row.least < NOT_OPEN:
        failed.append(f"a petal did not open ({row.least:.1f} deg)")
    dip = closing_dip(h["diagnostics/opening_angle_per_petal"][()]
                      if "diagnostics/opening_angle_per_petal" in h else opening)
    if dip > CLOSES_FIRST:
        failed.append(f"closes {dip:.1f} deg before it opens")
    row.verdict = "; ".join(failed) or "ok"


def table(rows: list[Row]) -> str:
    """The Markdown table of the rows."""
    head = ("| model | petals | vertices | start | effects | geometry | simulate | frames "
            "intersecting | opened | least petal | to the model | verdict |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|---|\n")

    def f(x, fmt):
        return "-" if not np.isfinite(x) else format(x, fmt)

    lines = [f"| {r.model} | {r.petals or '-'} | {r.vertices or '-'} | {r.start or '-'} | "
             f"{r.effects or '-'} | {f(r.geometry_seconds, '.1f')} s | "
             f"{f(r.seconds, '.1f') if r.vertices else '-'} s | {r.intersecting or '-'} | "
             f"{f(r.opened, '+.1f')} deg | {f(r.least, '.1f')} deg | {f(r.distance, '.2g')} | "
             f"{r.verdict} |" for r in rows]
    return head + "\n".join(lines) + "\n"


def into(path: Path, text: str) -> None:
    """Put ``text`` between the markers of the Markdown file ``path`` (appended with
    them if it has none)."""
    doc = path.read_text() if path.exists() else ""
    block = f"{BEGIN}\n{text}{END}"
    if BEGIN in doc and END in doc:
        doc = doc[:doc.index(BEGIN)] + block + doc[doc.index(END) + len(END):]
    else:
        doc = doc.rstrip("\n") + "\n\n" + block + "\n"
    path.write_text(doc)


def study(meshes: list[Path], out: Path, *, timeout: float, echo=print) -> list[Row]:
    """Run every mesh; write ``out/models.csv``; return the rows."""
    rows = []
    for mesh in meshes:
        echo(f"{mesh.name} ...")
        row = run_model(mesh, out / mesh.stem, timeout=timeout)
        echo(f"  {row.verdict} (geometry {row.geometry_seconds:.1f} s, simulate "
             f"{row.seconds:.1f} s)")
        rows.append(row)
    with open(out / "models.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(asdict(rows[0])) if rows else ["model"])
        writer.writeheader()
        for r in rows:
            writer.writerow(asdict(r))
    return rows
