"""bloom remesh: read a mesh, clean it, split petals, scale to mean edge 1, symmetrize."""

from __future__ import annotations

import json

import click
import numpy as np

from pipeline.errors import BloomError

from .common import config_options, input_hashes, load, log, output_options


@click.command("remesh")
@click.argument("mesh", required=False, type=click.Path(dir_okay=False))
@config_options
@output_options
def command(mesh: str | None, config_path, overrides, out, overwrite) -> None:
    """Clean MESH (default: the config's scene.mesh) and write remesh.h5.

    Welds duplicate vertices, drops degenerate and duplicate faces, orients faces
    consistently, labels each connected component as a petal, refuses closed and
    two-layer petals, remeshes each petal to remesh.target_edge or
    remesh.petal_vertices (boundary included), with remesh.symmetrize makes each petal
    mirror-symmetric about its center plane, and scales the mesh so its mean edge is 1
    (the scale is recorded; the mesh is never rotated). A petal whose triangles have an
    angle under 20 deg (pipeline.remesh.MIN_ANGLE; sharp rim corners excepted) is remeshed
    at its own mean edge; a petal that cannot be mirrored is kept as it is and listed in
    the attribute unsymmetrized.
    """
    from pipeline import artifact
    from pipeline.meshfile import read_mesh
    from pipeline.petals import prepare

    cfg = load(config_path, overrides)
    where = str(cfg.path) if cfg.path else "defaults"
    mesh_path = mesh or cfg.mesh_path()
    if mesh_path is None:
        raise BloomError("scene.mesh: no input mesh (give MESH or set scene.mesh)", where=where)
    out = artifact.check_output(out, "remesh", overwrite)
    v_in, f_in = read_mesh(mesh_path)
    result = prepare(v_in, f_in, where=str(mesh_path), target_edge=cfg["remesh.target_edge"],
                     petal_vertices=cfg["remesh.petal_vertices"],
                     symmetrize=cfg["remesh.symmetrize"], closed_parts=cfg["remesh.closed_parts"])
    report = result.report
    for line in result.dropped:
        log.warning("%s: left out %s (remesh.closed_parts = \"drop\")", mesh_path, line)
    for line in result.notes:
        if ": warning: " in line:
            log.warning("%s: %s", mesh_path, line.replace(": warning: ", ": ", 1))
        else:
            log.info("%s", line)
    log.info("%s: %d vertices, %d faces, %d petal(s); welded %d, dropped %d degenerate and "
             "%d duplicate faces, flipped %d; scale %.6g; asymmetry %s -> %s",
             mesh_path, len(result.vertices), len(result.faces), len(result.plane),
             report.welded, report.degenerate_faces, report.duplicate_faces,
             report.flipped_faces, result.scale, np.round(result.asymmetry_before, 4).tolist(),
             np.round(result.asymmetry_after, 9).tolist())

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
    }
    with artifact.writing(out, stage="remesh", config_json=cfg.to_json(),
                          inputs=input_hashes(cfg, mesh_path), attrs=attrs) as h5:
        artifact.put(h5, "mesh/vertices", result.vertices, "(V, 3) positions, mean edge 1")
        artifact.put(h5, "mesh/faces", result.faces.astype(np.int64),
                     "(F, 3) vertex indices, consistently oriented")
        artifact.put(h5, "mesh/petal", result.petal, "(V,) petal id (connected component)")
        artifact.put(h5, "mesh/plane", result.plane,
                     "(P, 4) center plane of each petal: unit normal, offset")
    log.info("wrote %s", out)
