"""bloom config: a scene's full configuration, one value, or every key documented."""

from __future__ import annotations

import json

import click

from .common import config_options


@click.command("config")
@click.argument("scene", required=False, type=click.Path(dir_okay=False))
@config_options
@click.option("--get", "get", metavar="SECTION.KEY", help="Print one value only.")
@click.option("--mesh-path", is_flag=True, help="Print scene.mesh resolved to a path.")
@click.option("--keys", is_flag=True, help="List every key with its type, default and meaning.")
@click.option("--markdown", is_flag=True, help="With --keys: as the Markdown table of docs/guide.md.")
@click.option("--into", type=click.Path(dir_okay=False, exists=True),
              help="With --keys --markdown: write the table into this Markdown file, between "
                   "its keys markers (make docs does docs/guide.md).")
def command(scene, config_path, overrides, get, mesh_path, keys, markdown, into) -> None:
    """Check SCENE (a TOML file) and print its values, defaults filled in, as JSON."""
    from pathlib import Path

    from pipeline.artifact import atomic_path
    from pipeline.config import KEYS, describe_keys, keys_markdown, load_config, with_keys_table
    from pipeline.errors import BloomError

    if keys and into:
        try:
            text = with_keys_table(Path(into).read_text())
        except ValueError as exc:
            raise BloomError(f"--into: {exc}", where=into) from None
        with atomic_path(into) as tmp:
            tmp.write_text(text)
        return
    if keys:
        click.echo(keys_markdown() if markdown else describe_keys())
        return
    cfg = load_config(scene or config_path, overrides)
    if mesh_path:
        p = cfg.mesh_path()
        if p is None:
            raise BloomError("scene.mesh: not set", where=str(cfg.path or "defaults"))
        click.echo(str(p))
    elif get:
        if get not in KEYS:
            raise BloomError(f"--get {get}: unknown key")
        value = cfg[get]
        click.echo(value if isinstance(value, str) else json.dumps(value))
    else:
        click.echo(json.dumps(cfg.nested(), indent=2, sort_keys=True))
