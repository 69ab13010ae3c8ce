"""bloom bench: what each effect costs, as ratios to the bare simulation, in one run."""

from __future__ import annotations

import json

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
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of tables.")
def command(vertices: int, steps: int, sizes: tuple[int, ...], as_json: bool) -> None:
    """Time the simulator on a procedural 6-petal bud: no effect, each effect alone and
    all together (ratios to no effect, best of 3 interleaved runs); then collisions at
    several sizes (cost per vertex should stay flat: linear in the vertex count)."""
    from pipeline import bench

    costs = bench.effect_costs(vertices, steps)
    scaling = bench.collision_scaling(sizes)
    if as_json:
        click.echo(json.dumps({"effects": costs, "collision_scaling": scaling}, indent=1))
        return
    click.echo(f"effects on a 6-petal bud of about {vertices} vertices, {steps} steps")
    click.echo(f"{'effects':58s} {'ms/step':>8s} {'ratio':>6s}")
    for row in costs:
        click.echo(f"{row['effects']:58s} {row['ms_per_step']:8.4f} {row['ratio']:6.2f}")
    click.echo("\ncollisions by size")
    click.echo(f"{'vertices':>8s} {'bare ms':>8s} {'coll ms':>8s} {'ns/vertex':>10s}")
    for row in scaling:
        click.echo(f"{row['vertices']:8d} {row['bare_ms']:8.4f} {row['collisions_ms']:8.4f} "
                   f"{row['collisions_ns_per_vertex']:10.1f}")
