"""bloom remesh: read a mesh, clean it, split petals, scale to mean edge 1, symmetrize."""

from __future__ import annotations

import click

from .common import config_options, load, output_options


@click.command("remesh")
@click.argument("mesh", required=False, type=click.Path(dir_okay=False))
@config_options
@output_options
def command(mesh: str | None, config_path, overrides, out, overwrite) -> None:
    """Clean MESH (default: the config's scene.mesh) and write remesh.h5.

    Reads the file's named parts and classifies each (petal, thick petal, stem, leaf,
    sepal, stamen, pistil, receptacle, other; scene.petals and scene.exclude override),
    logging one line per part. Per petal part: welds duplicate vertices, drops degenerate
    and duplicate faces and dust, orients faces consistently, takes a thick petal's
    mid-surface, and labels each connected piece as a petal; every part that cannot be
    simulated is named in one error line. Other parts are stored untouched under
    input/parts. Remeshes each petal to remesh.target_edge or
    remesh.petal_vertices (boundary included), with remesh.symmetrize makes each petal
    mirror-symmetric about its center plane, and scales the mesh so its mean edge is 1
    (the scale is recorded; the mesh is never rotated). A petal whose triangles have an
    angle under 20 deg (pipeline.mesh.remesh.MIN_ANGLE; sharp rim corners excepted) is remeshed
    at its own mean edge; a petal that cannot be mirrored is kept as it is and listed in
    the attribute unsymmetrized. A part holding a whole flower (petals, receptacle, stem in
    one mesh) gives its petal pieces; petals are grouped into flowers (mesh/flower,
    flower/petal_flower, flower/centre) and scene.flower keeps one. The log gives the
    petals found and the share of the input's petal area kept; a part that loses petals is
    a warning naming it. Petals are remeshed in remesh.workers processes; a run of more
    than a few seconds shows how far it has got. Petals that pass through or touch each other are moved
    apart (remesh.separate; at least effects.collisions.thickness apart; the attribute
    separation says how far), or refused in one line naming their parts.
    """
    from pipeline.chain import remesh

    remesh.run(mesh, out, load(config_path, overrides), overwrite=overwrite)
