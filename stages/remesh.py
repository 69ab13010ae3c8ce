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
    consistently, labels each connected component as a petal, scales the mesh so its
    mean edge is 1 (the scale is recorded; the mesh is never rotated), and with
    remesh.symmetrize makes each petal mirror-symmetric about its center plane.
    """
    from pipeline import artifact, clean, symmetry, topology
    from pipeline.meshfile import read_mesh

    cfg = load(config_path, overrides)
    where = str(cfg.path) if cfg.path else "defaults"
    mesh_path = mesh or cfg.mesh_path()
    if mesh_path is None:
        raise BloomError("scene.mesh: no input mesh (give MESH or set scene.mesh)", where=where)
    if cfg["remesh.target_edge"] > 0:
        raise BloomError("remesh.target_edge: resampling to a target edge length is not "
                         "available in this version; use 0 (keep the input's triangles)",
                         where=where)
    out = artifact.check_output(out, "remesh", overwrite)
    v_in, f_in = read_mesh(mesh_path)
    v, f, report = clean.clean_mesh(v_in, f_in)
    if len(f) == 0:
        raise BloomError("no triangles left after removing degenerate faces", where=str(mesh_path))
    _, _, count = topology.unique_edges(f)
    if np.any(count > 2):
        raise BloomError(f"{int(np.sum(count > 2))} non-manifold edges (an edge shared by 3+ "
                         "faces); repair the mesh (e.g. merge by distance, delete loose "
                         "duplicate faces) and export again", where=str(mesh_path))
    petal = topology.components(f, len(v))
    petal_count = int(petal.max()) + 1
    boundary = topology.boundary_vertices(f, len(v))
    for p in range(petal_count):
        if not boundary[petal == p].any():
            raise BloomError(f"petal {p} is a closed surface (a thick or solidified petal), "
                             "not a sheet; export the petal as a single open surface",
                             where=str(mesh_path))
    mean_edge = clean.mean_edge_length(v, f)
    scale = 1.0 / mean_edge
    v = v * scale

    asym_before, asym_after = [], []
    symmetric = []
    for p in range(petal_count):
        idx = np.flatnonzero(petal == p)
        plane, err = symmetry.mirror_plane(v[idx])
        asym_before.append(err)
        if cfg["remesh.symmetrize"]:
            local_faces = np.searchsorted(idx, f[np.isin(f[:, 0], idx)])
            partner = symmetry.mirror_pairs(v[idx], plane, local_faces)
            if partner is None:
                log.warning("petal %d: topology is not mirror-symmetric; left as it is "
                            "(asymmetry %.3g)", p, err)
            else:
                v[idx] = symmetry.symmetrize(v[idx], plane, partner)
                err = symmetry.asymmetry(v[idx], plane)
        symmetric.append(bool(err < 1e-9))
        asym_after.append(err)
    log.info("%s: %d vertices, %d faces, %d petal(s); welded %d, dropped %d degenerate and "
             "%d duplicate faces, flipped %d; scale %.6g; asymmetry %s -> %s",
             mesh_path, len(v), len(f), petal_count, report.welded, report.degenerate_faces,
             report.duplicate_faces, report.flipped_faces, scale,
             np.round(asym_before, 4).tolist(), np.round(asym_after, 9).tolist())

    attrs = {
        "scale": scale,
        "petal_count": petal_count,
        "clean": json.dumps(vars(report)),
        "asymmetry_before": np.asarray(asym_before),
        "asymmetry_after": np.asarray(asym_after),
    }
    with artifact.writing(out, stage="remesh", config_json=cfg.to_json(),
                          inputs=input_hashes(cfg, mesh_path), attrs=attrs) as h5:
        artifact.put(h5, "mesh/vertices", v, "(V, 3) positions, mean edge 1")
        artifact.put(h5, "mesh/faces", f.astype(np.int64), "(F, 3) vertex indices, consistently oriented")
        artifact.put(h5, "mesh/petal", petal.astype(np.int64), "(V,) petal id (connected component)")
    log.info("wrote %s", out)
