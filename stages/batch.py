"""bloom batch: the stage graph of many scenes on a Dask distributed cluster."""

from __future__ import annotations

from pathlib import Path

import click

from pipeline.errors import BloomError

from .common import log


@click.command("batch")
@click.argument("configs", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--scheduler", default="local", show_default=True,
              help="Address of a Dask scheduler (tcp://host:8786), or `local` for a local "
                   "cluster on this machine.")
@click.option("--workers", default=2, show_default=True, type=click.IntRange(1, 256),
              help="Worker processes of the local cluster (one thread each).")
@click.option("--out-root", default="outputs", show_default=True,
              type=click.Path(file_okay=False), help="Scenes go to OUT_ROOT/<scene>/.")
@click.option("--retries", default=2, show_default=True, type=click.IntRange(0, 10),
              help="How often a task lost with its worker is run again (the local "
                   "cluster's allowed-failures; a remote scheduler has its own). A stage "
                   "that fails is not retried: it would fail again.")
@click.option("--force", is_flag=True,
              help="Run every stage, even where the output is newer than its inputs.")
def command(configs, scheduler: str, workers: int, out_root: str, retries: int,
            force: bool) -> None:
    """Build CONFIGS (scene TOML files) as the Makefile does, each stage a Dask task
    whose input artifact is its dependency. Prints one line per scene; exits 1 if any
    stage failed (its log under OUT_ROOT/<scene>/logs/ says why)."""
    from pipeline.studies import batch

    paths = [Path(c) for c in configs]
    for p in paths:
        if not p.is_file():
            raise BloomError("config file not found", where=str(p))
    stems = [p.stem for p in paths]
    if len(set(stems)) != len(stems):
        raise BloomError("two configs have the same scene name (file stem)", where=str(paths[0]))
    tasks = batch.plan(paths, Path(out_root))
    import logging

    from distributed import Client, LocalCluster

    for name in ("distributed", "tornado"):  # their INFO chatter is not this command's
        logging.getLogger(name).setLevel(logging.ERROR)

    import dask

    dask.config.set({"distributed.scheduler.allowed-failures": retries})
    if scheduler == "local":
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        client = Client(cluster)
    else:
        cluster = None
        try:
            client = Client(scheduler, timeout="20s")
        except OSError as exc:
            raise BloomError(f"cannot reach the Dask scheduler ({exc})", where=scheduler) from None
    try:
        log.info("%d scenes, %d tasks on %s", len(paths), len(tasks), scheduler)
        errors = batch.run(tasks, client, force)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    failed = 0
    for scene in stems:
        mine = {k: v for k, v in errors.items() if k.startswith(f"{scene}/")}
        bad = [(k, v) for k, v in mine.items() if v is not None and "not run" not in v]
        if bad:
            failed += 1
            click.echo(f"{scene}: FAILED at {bad[0][0].split('/')[1]}: {bad[0][1]}", err=True)
        else:
            click.echo(f"{scene}: done ({len(mine)} stages)", err=True)
    if failed:
        raise BloomError(f"{failed} of {len(stems)} scenes failed", where="batch")
