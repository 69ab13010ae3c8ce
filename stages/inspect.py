"""bloom inspect: what an artifact holds and how it was made."""

from __future__ import annotations

import json
from pathlib import Path

import click

from pipeline.artifact import describe

PROVENANCE = ("stage", "version", "command", "inputs", "config")


@click.command("inspect")
@click.argument("artifact", type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def command(artifact: str, as_json: bool) -> None:
    """Show the datasets of ARTIFACT and its provenance (stage, command, inputs, config)."""
    info = describe(Path(artifact))
    if as_json:
        click.echo(json.dumps(info, indent=2, sort_keys=True))
        return
    attrs = info["attributes"]
    click.echo(f"{artifact}: written by `bloom {attrs.get('stage', '?')}` "
               f"(bloom {attrs.get('version', '?')})")
    click.echo(f"  command: {attrs.get('command', '?')}")
    for path, digest in (attrs.get("inputs") or {}).items():
        click.echo(f"  input:   {path}  sha256 {digest[:16]}...")
    timings = attrs.get("timings") or {}
    if timings:
        total = sum(timings.values())
        click.echo("  stage times: " + ", ".join(f"{k} {v:.2f} s" for k, v in timings.items())
                   + f"; total {total:.2f} s")
    others = {k: v for k, v in attrs.items() if k not in PROVENANCE + ("timings",)}
    for key, value in others.items():
        text = json.dumps(value) if not isinstance(value, str) else value
        click.echo(f"  {key}: {text if len(text) < 100 else text[:97] + '...'}")
    click.echo("datasets:")
    for name, d in info["datasets"].items():
        shape = "x".join(map(str, d["shape"])) or "scalar"
        rng = ""
        if "min" in d:
            rng = f"  [{d['min']:.6g}, {d['max']:.6g}]" if isinstance(d["min"], float) \
                else f"  [{d['min']}, {d['max']}]"
        doc = f"  {d['doc']}" if "doc" in d else ""
        click.echo(f"  {name:32s} {d['dtype']:8s} {shape:14s}{rng}{doc}")
    config = attrs.get("config")
    if isinstance(config, dict):
        click.echo("config:")
        for section, values in config.items():
            click.echo(f"  [{section}] " + json.dumps(values, sort_keys=True))
