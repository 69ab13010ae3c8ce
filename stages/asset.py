"""bloom asset petal|bud|open: procedural meshes for tests and default scenes."""

from __future__ import annotations

from pathlib import Path

import click

from pipeline.artifact import atomic_path
from pipeline.errors import BloomError

HEADER = "bloom asset"


@click.command("asset")
@click.argument("kind", type=click.Choice(["petal", "bud", "open"]))
@click.option("--petals", type=click.IntRange(1, 64), default=6, show_default=True,
              help="Petals in a bud.")
@click.option("--vertices", type=click.IntRange(30, 2_000_000), default=None,
              help="About how many vertices in all [petal: 320, bud: 300 per petal].")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="OBJ file to write.")
@click.option("--overwrite", is_flag=True, help="Replace --out even if `bloom asset` did not write it.")
def command(kind: str, petals: int, vertices: int | None, seed: int, out: str, overwrite: bool) -> None:
    """Generate a procedural cupped petal, a closed bud of overlapping petals, or an open
    lily (open: outer and inner tepals, recurved; bloom it with growth.start = "open").

    The same options give the same file, byte for byte.
    """
    from pipeline.mesh import procedural

    path = Path(out)
    if path.suffix.lower() != ".obj":
        raise BloomError("--out: asset meshes are written as OBJ (.obj)", where=str(path))
    if path.exists() and not overwrite:
        with open(path, "rb") as f:
            first = f.readline()
        if not first.startswith(f"# {HEADER}".encode()):
            raise BloomError("exists and was not written by `bloom asset`; not overwriting it "
                             "(pass --overwrite)", where=str(path))
    if kind == "petal":
        petals = 1
    n = vertices or (320 if kind == "petal" else 300 * petals)
    v, f, p = (procedural.open_flower if kind == "open" else procedural.bud)(petals, n, seed)
    header = (f"{HEADER} {kind} --petals {petals} --vertices {n} --seed {seed}\n"
              f"{len(v)} vertices, {len(f)} faces, {petals} petals; flower axis +z")
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        procedural.write_obj(tmp, v, f, p, header)
    click.echo(f"wrote {path}: {len(v)} vertices, {len(f)} faces, {petals} petal(s)", err=True)
