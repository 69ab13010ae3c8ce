"""bloom study: accuracy (what accuracy costs in time), resolution, stability, models and
elastic (the paper's springs against the shell on every default scene)."""

from __future__ import annotations

from pathlib import Path

import click

from pipeline.errors import BloomError

#: the scene of the accuracy study's resolution axis (the project's own)
PETAL = Path(__file__).resolve().parents[1] / "configs" / "petal.toml"


def _counts(text: str, option: str) -> tuple[int, ...]:
    """Vertex counts given as ``a,b,c`` (each at least 50), or a one-line error naming
    ``option``."""
    try:
        numbers = tuple(int(c) for c in text.split(","))
    except ValueError:
        numbers = ()
    if not numbers or min(numbers) < 50:
        raise BloomError(f"not a list of vertex counts (each at least 50): {text!r}",
                         where=option)
    return numbers


@click.group("study")
def command() -> None:
    """Studies of the simulator (slow; not part of a scene's build)."""


@command.command("accuracy")
@click.option("--out", "out", required=True, type=click.Path(file_okay=False),
              help="Folder for accuracy.csv and accuracy.png (created if missing).")
@click.option("--petals", default=6, show_default=True, type=click.IntRange(1, 24),
              help="Petals of the procedural bud.")
@click.option("--vertices", default=2133, show_default=True, type=click.IntRange(min=120),
              help="Vertices of the bud (the paper's Fig. 12 lily: 2133).")
@click.option("--quick", is_flag=True, help="Shorter dynamic runs (for tests).")
@click.option("--resolution", "scene", default=str(PETAL), show_default=True,
              type=click.Path(exists=True, dir_okay=False),
              help="The resolution axis: this scene at --resolution-counts vertices per petal, "
                   "regular and irregular, with each elastic model (as `bloom study "
                   "resolution`, into OUT/resolution), drawn beside the cost curves.")
@click.option("--resolution-counts", "counts", default="150,300,600,1200", show_default=True,
              help="Vertices per petal of the resolution axis, comma-separated.")
@click.option("--no-resolution", is_flag=True, help="Leave the resolution axis out.")
def accuracy(out: str, petals: int, vertices: int, quick: bool, scene: str, counts: str,
             no_resolution: bool) -> None:
    """Run one bud with every integrator over a range of cost (growth duration, eta,
    increments) and measure each final bloom against a converged reference: RMS vertex
    distance over petal length, and the opening angle difference. Then the resolution
    axis: one scene at several mesh densities with the paper's springs and the shell."""
    from pipeline.studies import accuracy

    numbers = _counts(counts, "--resolution-counts")
    folder = Path(out)
    if folder.exists() and not folder.is_dir():
        raise BloomError("exists and is not a folder", where=str(folder))
    folder.mkdir(parents=True, exist_ok=True)
    axis = None if no_resolution else dict(config=scene, counts=numbers,
                                           models=("paper", "shell"))
    try:
        accuracy.accuracy(folder, petals=petals, vertices=vertices, quick=quick,
                          resolution=axis, echo=click.echo)
    except RuntimeError as exc:  # a run that diverged or did not converge
        raise BloomError(f"a run of the study failed: {exc}", where=str(folder)) from None
    click.echo(f"wrote {folder / 'accuracy.csv'} and {folder / 'accuracy.png'}")


@command.command("resolution")
@click.option("--out", "out", required=True, type=click.Path(file_okay=False),
              help="Folder for the runs, resolution.csv and resolution.png (created if missing).")
@click.option("--config", "config", required=True, type=click.Path(exists=True, dir_okay=False),
              help="The scene (its mesh a procedural asset, `bloom asset`).")
@click.option("--counts", default="300,1200,4800", show_default=True,
              help="Vertices per petal, comma-separated (the finest regular run is the reference).")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Config overrides for every run, e.g. simulate.model=shell.")
@click.option("--regular-only", is_flag=True, help="Only the scene's own remesh (no irregular meshes).")
@click.option("--models", default="", metavar="NAME,...",
              help="Elastic models to run, each against its own finest regular run "
                   "(e.g. paper,shell); default: the scene's simulate.model.")
def resolution(out: str, config: str, counts: str, overrides, regular_only: bool,
               models: str) -> None:
    """Run one scene at several mesh densities, on regular and irregular triangulations of
    the same surface, and measure each bloom against the finest regular one: the largest
    opening difference over the frames and the RMS shape difference (points matched by
    (s, x)) over the petal length."""
    from pipeline.studies import resolution as study

    numbers = _counts(counts, "--counts")
    from pipeline.config import KEYS

    names = tuple(m.strip() for m in models.split(",") if m.strip())
    allowed = KEYS["simulate.model"].choices
    for name in names:  # (before any run writes a file)
        if name not in allowed:
            raise BloomError(f"not an elastic model: {name!r} (one of {', '.join(allowed)})",
                             where="--models")
    try:
        rows = study.resolution(Path(out), config, counts=numbers, overrides=overrides,
                                kinds=("regular",) if regular_only else ("regular", "irregular"),
                                models=names or (None,), echo=click.echo)
    except ValueError as exc:
        raise BloomError(str(exc), where=config) from None
    click.echo("\n".join(study.table(rows)))
    click.echo(f"wrote {Path(out) / 'resolution.csv'} and {Path(out) / 'resolution.png'}")


@command.command("stability")
def stability() -> None:
    """The hard cases (dense buds, extreme growth, contact, snaps), slow ones included:
    each run through remesh -> simulate; prints a table and exits 1 if a case is not as
    expected (a bloom that finishes, or a clean one-line stop)."""
    from pipeline.studies import stability as cases

    if cases.main():
        raise BloomError("a stability case did not end as expected (see the table)",
                         where="bloom study stability")


@command.command("models")
@click.argument("models", nargs=-1, type=click.Path(exists=True, dir_okay=False))
@click.option("--dir", "folder", type=click.Path(exists=True, file_okay=False),
              help="Run every mesh file in this folder (e.g. ../shared/external-meshes).")
@click.option("--out", "out", default="outputs/models", show_default=True,
              type=click.Path(file_okay=False), help="Folder for each model's artifacts and models.csv.")
@click.option("--timeout", default=900.0, show_default=True, type=click.FloatRange(min=1),
              help="Seconds each model may take through the four stages.")
@click.option("--into", "into", type=click.Path(dir_okay=False),
              help="Also write the table into this Markdown file, between <!-- models --> "
                   "and <!-- /models --> (e.g. docs/performance.md).")
def models(models: tuple[str, ...], folder: str | None, out: str, timeout: float,
           into: str | None) -> None:
    """Real flower models, each with a scene of scene.mesh only, through remesh, axis,
    growth and simulate; a table of what was decided and whether the bloom is one an
    artist would keep (no frame with an intersection; an open model ends on itself from
    a bud at least 20 deg more closed; a lone petal opens 10 deg; a bud opens forward).
    Exits 1 if a model fails."""
    from pipeline.studies import models as study

    meshes = [Path(m) for m in models] + (study.models_in(Path(folder)) if folder else [])
    if not meshes:
        raise BloomError("no models given (MODELS... or --dir)", where="bloom study models")
    root = Path(out)
    root.mkdir(parents=True, exist_ok=True)
    rows = study.study(meshes, root, timeout=timeout, echo=click.echo)
    text = study.table(rows)
    click.echo(text)
    if into:
        study.into(Path(into), text)
        click.echo(f"wrote the table into {into}")
    if any(r.verdict != "ok" for r in rows):
        raise BloomError(f"{sum(r.verdict != 'ok' for r in rows)} of {len(rows)} models failed "
                         "(see the table)", where="bloom study models")


@command.command("elastic")
@click.option("--out", "out", required=True, type=click.Path(file_okay=False),
              help="Folder for elastic.png and elastic.md (created if missing).")
@click.option("--scenes", default="", help="Scene names of configs/, comma-separated "
              "(default: every default scene).")
def elastic(out: str, scenes: str) -> None:
    """Every default scene with the paper's springs and with the shell, side by side: the
    final opening, curvature, wrinkles and simulate time (a table), and each bloom's bud
    and last frame (elastic.png)."""
    from pipeline.studies import elastic as study

    root = Path(__file__).resolve().parents[1] / "configs"
    names = [s for s in scenes.split(",") if s] or sorted(p.stem for p in root.glob("*.toml"))
    missing = [n for n in names if not (root / f"{n}.toml").exists()]
    if missing:
        raise BloomError(f"no such scene: {', '.join(missing)}", where="bloom study elastic --scenes")
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    rows = study.compare([root / f"{n}.toml" for n in names], folder, echo=click.echo)
    text = study.table(rows)
    (folder / "elastic.md").write_text(text + "\n")
    click.echo(text)
    click.echo(f"wrote {folder / 'elastic.png'} and {folder / 'elastic.md'}")
