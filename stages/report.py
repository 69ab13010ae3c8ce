"""bloom report: what the bloom and its effects did, measured -> report.json + report.png."""

from __future__ import annotations

import click


@click.command("report")
@click.argument("sim_h5", type=click.Path(dir_okay=False))
@click.option("--out", required=True, type=click.Path(dir_okay=False),
              help="report.json to write; the plot goes beside it (same name, .png).")
@click.option("--overwrite", is_flag=True, help="Replace --out even if `bloom report` did not write it.")
def command(sim_h5: str, out: str, overwrite: bool) -> None:
    """Measure SIM_H5: opening per petal, cross-section curvature, boundary wrinkles,
    crossings between petals, connection breaks, Gaussian curvature sign."""
    from pipeline.chain import report

    report.run(sim_h5, out, overwrite=overwrite)
