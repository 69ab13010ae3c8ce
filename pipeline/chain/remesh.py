"""The remesh stage: read a mesh, take its petals to clean, isotropic, symmetric sheets at
mean edge 1 (:func:`pipeline.flower.petals.prepare_parts`), bind the user's own parts to
them (:mod:`pipeline.io.binding`) -> remesh.h5."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import h5py
import numpy as np

from pipeline import artifact
from pipeline.config import Config
from pipeline.errors import BloomError
from pipeline.flower.petals import prepare_parts
from pipeline.forks import workers
from pipeline.io import binding, userasset
from pipeline.io.meshfile import read_parts
from pipeline.progress import Steps

log = logging.getLogger("bloom")

#: more parts (or notes) than this: a summary line instead of one line each
LINES = 50


def run(mesh: str | Path | None, out: str | Path, cfg: Config, *, overwrite: bool = False) -> None:
    """Clean ``mesh`` (default: the config's scene.mesh) and write remesh.h5 at ``out``.

    Reads the file's named parts and classifies each (petal, thick petal, stem, leaf,
    sepal, stamen, pistil, receptacle, other; scene.petals and scene.exclude override),
    logging one line per part. Per petal part: welds duplicate vertices, drops degenerate
    and duplicate faces and dust, orients faces consistently, takes a thick petal's
    mid-surface, and labels each connected piece as a petal; every part that cannot be
    simulated is named in one error line. Other parts are stored untouched under
    input/parts. Remeshes each petal to remesh.target_edge or remesh.petal_vertices
    (boundary included), with remesh.symmetrize makes each petal mirror-symmetric about
    its center plane, and scales the mesh so its mean edge is 1 (the scale is recorded;
    the mesh is never rotated). A part holding a whole flower (petals, receptacle, stem in
    one mesh) gives its petal pieces; petals are grouped into flowers (mesh/flower,
    flower/petal_flower, flower/centre) and scene.flower keeps one. The log gives the
    petals found and the share of the input's petal area kept; a part that loses petals is
    a warning naming it. Petals are remeshed in remesh.workers processes; a run of more
    than a few seconds shows how far it has got (:class:`pipeline.progress.Steps`). Moves
    petal sheets that pass through or touch each other apart (remesh.separate,
    :mod:`pipeline.flower.separation`) before the user's parts are bound to them.
    """
    where = str(cfg.path) if cfg.path else "defaults"
    mesh_path = mesh or cfg.mesh_path()
    if mesh_path is None:
        raise BloomError("scene.mesh: no input mesh (give MESH or set scene.mesh)", where=where)
    out = artifact.check_output(out, "remesh", overwrite)
    mesh_file = read_parts(mesh_path)
    with Steps("remesh", str(mesh_path)) as progress:
        result = prepare_parts(mesh_file, where=str(mesh_path),
                               target_edge=cfg["remesh.target_edge"],
                               petal_vertices=cfg["remesh.petal_vertices"],
                               max_petal_vertices=cfg["remesh.max_petal_vertices"],
                               symmetrize=cfg["remesh.symmetrize"],
                               closed_parts=cfg["remesh.closed_parts"],
                               petals_globs=cfg["scene.petals"], exclude_globs=cfg["scene.exclude"],
                               flower=cfg["scene.flower"], progress=progress,
                               workers=workers(cfg["remesh.workers"]))
    report = result.report
    with Steps("remesh", str(mesh_path)) as progress:
        separation = _separated(result, cfg, mesh_path, mesh_file, progress)
    left = np.asarray(separation.get("left", []), dtype=np.int64).reshape(-1, 2)
    asset, bindings = _bound_asset(mesh_path, mesh_file, result)
    _log_parts(result, mesh_path)
    log.info("%s: %d vertices, %d faces, %d petal(s); welded %d, dropped %d degenerate and "
             "%d duplicate faces, flipped %d; scale %.6g; asymmetry %s -> %s",
             mesh_path, len(result.vertices), len(result.faces), len(result.plane),
             report.welded, report.degenerate_faces, report.duplicate_faces,
             report.flipped_faces, result.scale, _listed(result.asymmetry_before, 4),
             _listed(result.asymmetry_after, 9))

    attrs = {
        "scale": result.scale,
        "petal_count": len(result.plane),
        "clean": json.dumps(vars(report)),
        "asymmetry_before": result.asymmetry_before,
        "asymmetry_after": result.asymmetry_after,
        "edge_target": result.edge_target,
        "dropped_parts": json.dumps(result.dropped),
        "notes": json.dumps(result.notes),
        # petals remesh.symmetrize could not mirror (a later stage may constrain them instead)
        "unsymmetrized": np.asarray(result.unsymmetrized, dtype=np.int64),
        "min_angle": result.min_angle,
        "parts": json.dumps(result.parts),
        "file_up": mesh_file.up or "",
        "separation": json.dumps(separation),
        "flower_count": len(result.flower_centre),
        "flower_picked": result.flower_picked,
        "petals_found": json.dumps(result.found),
    }
    if mesh_file.meters_per_unit is not None:
        attrs["meters_per_unit"] = float(mesh_file.meters_per_unit)
    with artifact.writing(out, stage="remesh", config_json=cfg.to_json(),
                          inputs=artifact.input_hashes(cfg, mesh_path), attrs=attrs) as h5:
        artifact.put(h5, "mesh/vertices", result.vertices, "(V, 3) positions, mean edge 1")
        artifact.put(h5, "mesh/faces", result.faces.astype(np.int64),
                     "(F, 3) vertex indices, consistently oriented")
        artifact.put(h5, "mesh/petal", result.petal, "(V,) petal id (connected component)")
        artifact.put(h5, "mesh/left", left,
                     "(K, 2) petal pairs left through each other as modelled (remesh.separate "
                     "could not move them apart): no contact between the two of a pair")
        if result.cut_rim is not None:
            artifact.put(h5, "mesh/cut_rim", result.cut_rim.astype(bool),
                         "(V,) the rims a cut made (remesh.separate cut away the parts of "
                         "petals buried in others): where such a petal leaves the centre, the "
                         "base bloom axis holds")
        artifact.put(h5, "mesh/plane", result.plane,
                     "(P, 4) center plane of each petal: unit normal, offset")
        names = np.array([p.name for p in mesh_file.parts], dtype=object)
        h5.create_dataset("mesh/part_names", data=names, dtype=h5py.string_dtype("utf-8"))
        h5["mesh/part_names"].attrs["doc"] = "(N,) the input's part names, in file order"
        artifact.put(h5, "mesh/part", result.part.astype(np.int64),
                     "(V,) the input part (index into mesh/part_names) each vertex came from")
        artifact.put(h5, "mesh/thickness", result.thickness,
                     "(V,) thickness of a thick petal (its mid-surface's), output units; 0 for sheets")
        artifact.put(h5, "mesh/flower", result.flower.astype(np.int64),
                     "(V,) the flower each vertex's petal belongs to (petals gathered by their bases)")
        artifact.put(h5, "flower/petal_flower", result.petal_flower.astype(np.int64),
                     "(P,) the flower of each petal")
        artifact.put(h5, "flower/centre", result.flower_centre,
                     "(K, 3) where each flower's petal bases gather, output units")
        for i, (pv, pf) in sorted(result.kept_parts.items()):
            what = (f"the pieces of part {mesh_file.parts[i].name!r} that are not petals (a whole "
                    "flower in one mesh)" if result.parts[i]["role"] == "petal" else
                    f"part {mesh_file.parts[i].name!r} as read")
            artifact.put(h5, f"input/parts/{i}/vertices", pv.astype(np.float64),
                         f"(n, 3) {what}, input units (not scaled)")
            artifact.put(h5, f"input/parts/{i}/faces", pf.astype(np.int64), "(m, 3) its triangles")
        if asset is not None:
            userasset.write(h5, asset)
            binding.write_bindings(h5, bindings)
    log.info("wrote %s", out)


def _log_parts(result, mesh_path) -> None:
    """The log of what became of each part (a summary line when there are more than
    :data:`LINES`), the notes, the petals found and the share of the input's petal area
    kept, and the flowers."""
    # sheets per part, in one pass (a mask per part costs parts x vertices)
    pairs = np.unique(np.stack([result.part, result.petal], axis=1), axis=0)
    per_part = np.bincount(pairs[:, 0], minlength=len(result.parts))
    lines = len(result.parts) <= LINES
    kinds: dict = {}
    for i, part in enumerate(result.parts):
        done = {"petal": "simulated", "kept": "kept as it is (carried forward)",
                "excluded": "excluded by scene.exclude (carried forward)"}[part["role"]]
        if part["role"] == "petal":
            done = f"simulated as {per_part[i]} petal sheet(s)" if per_part[i] else "left out"
        if lines:
            log.info("%s: part %r: %s (%s): %s", mesh_path, part["name"], part["kind"],
                     part["reason"], done)
        kinds.setdefault((part["kind"], part["role"]), []).append(part["name"])
    if not lines:
        log.info("%s: %d parts: %s", mesh_path, len(result.parts), "; ".join(
            f"{len(names)} {kind} ({role}: {', '.join(repr(n) for n in names[:3])}"
            f"{', ...' if len(names) > 3 else ''})" for (kind, role), names in sorted(kinds.items())))
    for line in result.dropped:
        log.warning("%s: left out %s (remesh.closed_parts = \"drop\")", mesh_path, line)
    shown = {"warning": 0, "info": 0}
    for line in result.notes:
        level = "warning" if ": warning: " in line else "info"
        shown[level] += 1
        if shown[level] > LINES:
            continue
        if level == "warning":
            log.warning("%s: %s", mesh_path, line.replace(": warning: ", ": ", 1))
        else:
            log.info("%s", line)
    for level, count in shown.items():
        if count > LINES:
            getattr(log, level)("%s: %d more %s line(s) (in remesh.h5's attribute notes)",
                                mesh_path, count - LINES, level)
    area_in = sum(r["area_in"] for r in result.found.values())
    area_out = sum(r["area_in"] * r["area_kept"] for r in result.found.values())
    found = [f"{name!r}: {r['petals']} from {r['pieces']} piece(s), {r['area_kept']:.0%} of its area"
             for name, r in result.found.items()]
    log.info("%s: %d petal(s) found in %d part(s)%s, %.0f%% of the input's petal area kept",
             mesh_path, len(result.plane), len(result.found),
             f" ({', '.join(found)})" if len(found) <= LINES else "",
             100.0 * area_out / area_in if area_in > 0 else 0.0)
    counts = np.bincount(result.petal_flower, minlength=len(result.flower_centre))
    sizes = ", ".join(f"{k}: {n} petal(s)" for k, n in enumerate(counts.tolist()[:LINES]))
    log.info("%s: %d flower(s)%s: %s%s", mesh_path, len(result.flower_centre),
             "" if result.flower_picked < 0 else f" (scene.flower picked flower {result.flower_picked})",
             sizes, ", ..." if len(counts) > LINES else "")


def _listed(values: np.ndarray, digits: int) -> str:
    """Per-petal values for the log: all of them, or their range when there are many."""
    if len(values) <= LINES:
        return str(np.round(values, digits).tolist())
    return f"{len(values)} petals from {values.min():.{digits}g} to {values.max():.{digits}g}"


def _separated(result, cfg, mesh_path, mesh_file, progress=None) -> dict:
    """The sheets moved apart where they pass through or touch each other (remesh.separate,
    before the user's parts are bound to them: those come back as they were, and follow
    the separated sheet); logged, and returned for the artifact."""
    if not cfg["remesh.separate"]:
        return {"enabled": False}
    from pipeline.flower.separation import separate_sheets

    gap = cfg["effects.collisions.thickness"]
    done = separate_sheets(result, gap=gap, names=[p.name for p in mesh_file.parts],
                           where=str(mesh_path), progress=progress)
    if done["crossed"] or done["close"]:
        log.info("%s: separated petals: %s; moved %d of %d vertices, the largest move %.2f%% "
                 "of a petal's length, RMS %.3f%%, in %d round(s); the nearest petals are now "
                 "%.3g apart (remesh.separate)", mesh_path,
                 "; ".join([f"through each other {done['crossed_parts']}"] * bool(done["crossed"])
                           + [f"nearer than effects.collisions.thickness = {gap:g} "
                              f"{done['close_parts']}"] * bool(done["close"])),
                 done["moved"], len(result.vertices), 100 * done["largest"], 100 * done["rms"],
                 done["rounds"], done["distance"] or float("inf"))
    return {"enabled": True, **done}


def _bound_asset(mesh_path, mesh_file, result):
    """The input's parts as the file gives them (for the export) and their petals' binding
    to the sheet; ``(None, {})`` when the file's own parts cannot be matched to the parts
    read for simulating (the export can then give back the sheet only)."""
    from pipeline.io import binding, userasset

    asset = userasset.read_asset(mesh_path)
    names = [p.name for p in mesh_file.parts]
    if asset.names != names:
        log.warning("%s: the file's own parts (%d) do not match the parts read (%d); the "
                    "export can give back the simulated sheet only (export.mesh = \"sheet\")",
                    mesh_path, len(asset.parts), len(names))
        return None, {}
    bindings = binding.bind_parts(asset, result.scale, result.vertices, result.faces, result.part,
                                  result.kept_parts, result.unpicked)
    for i, b in sorted(bindings.items())[:LINES]:
        bound = b.face >= 0
        stay = int((~bound).sum())
        log.info("%s: part %r: %d points bound to its sheet (offset up to %.3g along the "
                 "normal, %.3g across)%s", mesh_path, names[i], int(bound.sum()),
                 float(np.abs(b.offset[bound, 2]).max(initial=0.0)) / result.scale,
                 float(np.linalg.norm(b.offset[bound, :2], axis=1).max(initial=0.0)) / result.scale,
                 f"; {stay} points of its pieces that are no petal stay where they are"
                 if stay else "")
    return asset, bindings
