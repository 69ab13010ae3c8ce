"""bloom bench: what each effect costs, as ratios to the bare simulation, in one run."""

from __future__ import annotations

import json
from pathlib import Path

import click


def _sizes(ctx, param, value: str) -> tuple[int, ...]:
    try:
        sizes = tuple(int(x) for x in value.split(","))
    except ValueError:
        raise click.BadParameter(f"{value!r} is not a comma-separated list of integers") from None
    if any(n < 120 for n in sizes):
        raise click.BadParameter("every size must be at least 120 vertices")
    return sizes


@click.command("bench")
@click.option("--vertices", default=2000, show_default=True, type=click.IntRange(min=120),
              help="Vertices of the bud.")
@click.option("--steps", default=3000, show_default=True, type=click.IntRange(min=10),
              help="Steps timed per variant.")
@click.option("--sizes", default="2000,8000,32000", show_default=True, callback=_sizes,
              help="Vertex counts for the collision scaling (comma-separated, each >= 120).")
@click.option("--converge/--no-converge", default=True, show_default=True,
              help="Also time a converged bloom of the Fig. 12-size bud with each integrator.")
@click.option("--scenes", default="lily", show_default=True,
              help="Default scenes with contact (configs/<name>.toml, comma-separated; "
                   "'none' for none) run through remesh, axis, growth and simulate as make "
                   "runs them: simulate's seconds, Newton iterations, frames with an "
                   "intersection (ipctk's exact test).")
@click.option("--remesh-faces", default=100_000, show_default=True, type=click.IntRange(min=0),
              help="Time `bloom remesh`'s work (default config) on a synthetic flower of about "
                   "this many faces: 12 solidified petals pushed into a closed receptacle, in "
                   "one mesh (0: skip).")
@click.option("--model", "models", multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="A real flower model (repeatable), with a scene of scene.mesh only, through "
                   "remesh, axis, growth and simulate: simulate's seconds with the bud search "
                   "of an open model included, and the study's verdict (bloom study models).")
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of tables.")
@click.option("--quick", is_flag=True,
              help="Every part end to end on small buds (about a minute; for tests): at most "
                   "600 vertices and 300 steps, sizes 600,1200, a 6-petal bud of 600 vertices "
                   "for the converged bloom.")
def command(vertices: int, steps: int, sizes: tuple[int, ...], converge: bool, scenes: str,
            remesh_faces: int, models: tuple[str, ...], as_json: bool, quick: bool) -> None:
    """Time the simulator on a procedural 6-petal bud: no effect, each effect alone and
    all together (ratios to no effect, best of 3 interleaved runs); then the step cost
    and collisions at several sizes (cost per edge and per vertex should stay flat:
    linear in the vertex count); then, with --converge, the wall time each integrator
    needs for a bloom within 1% of the petal length of a converged reference, on a
    6-petal bud of 2133 vertices (the paper's Fig. 12 lily: 44 s); then the default
    scenes with contact named by --scenes (--quick: none); last, the remesh stage on a
    studio-sized model of --remesh-faces faces (--quick: at most 20,000); and each real
    flower model given by --model."""
    from pipeline.errors import BloomError
    from pipeline.studies import accuracy, bench

    names = () if scenes.strip() in ("", "none") else tuple(
        n.strip() for n in scenes.split(","))
    unknown = [n for n in names if n not in bench.CONTACT_SCENES]
    if unknown:
        raise click.BadParameter(f"no such scene {unknown[0]!r} (one of "
                                 f"{', '.join(bench.CONTACT_SCENES)})", param_hint="--scenes")
    if quick:
        vertices, steps, sizes, names = min(vertices, 600), min(steps, 300), (600, 1200), ()
        remesh_faces = min(remesh_faces, 20_000)
    try:
        costs = bench.effect_costs(vertices, steps)
        scaling = bench.collision_scaling(sizes)
        converged = None
        if converge:
            scene = accuracy.Scene.bud(6, 600 if quick else 2133)
            ref, change = accuracy.reference(scene)
            converged = {"vertices": scene.model.vertex_count, "reference_seconds": ref.wall,
                         "reference_refinement_change": change,
                         "runs": accuracy.time_to_converge(
                             scene, ref.positions, echo=None if as_json else click.echo,
                             quick=quick)}
        contact = bench.contact_scenes(names) if names else []
        remesh = bench.remesh_cost(remesh_faces) if remesh_faces else None
        real = bench.real_models([Path(m) for m in models])
    except RuntimeError as exc:  # a run that diverged or did not converge
        raise BloomError(f"a benchmark run failed: {exc}", where="bloom bench") from None
    if as_json:
        steps = [{"vertices": r["vertices"], "edges": r["edges"], "ms_per_step": r["bare_ms"],
                  "ns_per_edge": r["bare_ns_per_edge"]} for r in scaling]
        click.echo(json.dumps({"step_cost": steps, "effects": costs,
                               "collision_scaling": scaling, "converged_bloom": converged,
                              "contact_scenes": contact, "remesh": remesh,
                               "models": real},
                              indent=1))
        return
    click.echo(f"effects on a 6-petal bud of about {vertices} vertices, {steps} steps")
    click.echo(f"{'effects':58s} {'ms/step':>8s} {'ratio':>6s}")
    for row in costs:
        click.echo(f"{row['effects']:58s} {row['ms_per_step']:8.4f} {row['ratio']:6.2f}")
    click.echo("\nstep cost and collisions by size")
    click.echo(f"{'vertices':>8s} {'edges':>7s} {'bare ms':>8s} {'ns/edge':>8s} {'coll ms':>8s} "
               f"{'coll ns/vertex':>14s}")
    for row in scaling:
        click.echo(f"{row['vertices']:8d} {row['edges']:7d} {row['bare_ms']:8.4f} "
                   f"{row['bare_ns_per_edge']:8.1f} {row['collisions_ms']:8.4f} "
                   f"{row['collisions_ns_per_vertex']:14.1f}")
    if converged:
        click.echo(f"\nconverged bloom (within 1% of the petal length), 6-petal bud of "
                   f"{converged['vertices']} vertices; the paper: "
                   f"{accuracy.PAPER_LILY_SECONDS:.0f} s for its 2133-vertex lily")
        for row in converged["runs"]:
            mark = "" if row["converged"] else "  (not within 1% even so)"
            click.echo(f"{row['integrator']:26s} {row['wall_seconds']:8.2f} s  "
                       f"{row['params']}{mark}")
    if contact:
        click.echo("\nscenes with contact (configs/<scene>.toml, as make runs them)")
        click.echo(f"{'scene':14s} {'vertices':>8s} {'integrator':>13s} {'simulate s':>10s} "
                   f"{'Newton its':>10s} {'intersecting':>12s} {'opening':>8s}")
        for row in contact:
            click.echo(f"{row['scene']:14s} {row['vertices']:8d} {row['integrator']:>13s} "
                       f"{row['simulate_seconds']:10.2f} {row['newton_iterations']:10d} "
                       f"{row['intersecting_frames']:5d} of {row['frames']:<4d} "
                       f"{row['opening_deg']:7.1f}")
    if remesh:
        click.echo(f"\nremesh (default config) of a studio-sized flower: {remesh['faces_in']} faces, "
                   f"{remesh['vertices_in']} vertices in one mesh -> {remesh['petals']} petals, "
                   f"{remesh['vertices_out']} vertices")
        click.echo(f"{remesh['wall_seconds']:.1f} s wall, {remesh['cpu_seconds']:.1f} s CPU, "
                   f"peak resident memory {remesh['peak_rss_mb']:.0f} MB (largest worker "
                   f"{remesh['worker_peak_rss_mb']:.0f} MB)")
    if real:
        click.echo("\nreal flowers, scene.mesh only (simulate: the bud search included)")
        click.echo(f"{'model':26s} {'vertices':>8s} {'start':>5s} {'effects':>10s} "
                   f"{'simulate s':>10s}  verdict")
        for row in real:
            click.echo(f"{row['model']:26s} {row['vertices']:8d} {row['start']:>5s} "
                       f"{row['effects']:>10s} {row['seconds']:10.1f}  {row['verdict']}")
