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
def command(scene, config_path, overrides, get, mesh_path, keys) -> None:
    """Check SCENE (a TOML file) and print its values, defaults filled in, as JSON."""
    from pipeline.config import KEYS, describe_keys, load_config
    from pipeline.errors import BloomError

    if keys:
        click.echo(describe_keys())
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
