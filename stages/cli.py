"""The `bloom` command group: logging, verbosity and one-line errors. Nothing else.

Subcommands are imported only when called, so `bloom --help` is instant and a stage
does not pay for another's imports (pyvista, numba kernels).
"""

from __future__ import annotations

import importlib
import logging
import signal
import sys

import click

from pipeline import __version__
from pipeline.errors import BloomError

COMMANDS = {
    "asset": ("stages.asset", "Generate a procedural petal or closed bud (OBJ)."),
    "remesh": ("stages.remesh", "Clean, scale and symmetrize an input mesh -> remesh.h5."),
    "axis": ("stages.axis", "Find base, tip, center plane and cross-section x -> axis.h5."),
    "growth": ("stages.growth", "Assign growth ratios, hinges and rest angles -> growth.h5."),
    "simulate": ("stages.simulate", "Simulate the bloom -> sim.h5."),
    "report": ("stages.report", "Measure a bloom and its effects -> report.json + report.png."),
    "render": ("stages.render", "Render an artifact off-screen: PNG frames, MP4, contact sheet."),
    "export": ("stages.export", "Export sim.h5 as a USD stage or an OBJ/PLY sequence."),
    "batch": ("stages.batch", "Build many scenes on a Dask cluster (local or an address)."),
    "bench": ("stages.bench", "Time the simulator: each effect's cost, collisions by size."),
    "study": ("stages.study", "Studies: what accuracy costs in time (accuracy.csv, .png)."),
    "inspect": ("stages.inspect", "Show what an artifact holds and how it was made."),
    "config": ("stages.config", "Show a scene's configuration with defaults, or all keys."),
}


class StageError(click.ClickException):
    """A BloomError as Click shows it: one line on stderr, exit code 1."""

    def __init__(self, command: str, error: BloomError):
        super().__init__(str(error))
        self.command = command

    def show(self, file=None) -> None:
        click.echo(f"bloom {self.command}: error: {self.format_message()}", err=True)


class LazyGroup(click.Group):
    def list_commands(self, ctx):
        return list(COMMANDS)

    def get_command(self, ctx, name):
        if name not in COMMANDS:
            return None
        module = importlib.import_module(COMMANDS[name][0])
        return module.command

    def format_commands(self, ctx, formatter):
        # list commands without importing them
        rows = [(name, help_) for name, (_, help_) in COMMANDS.items()]
        with formatter.section("Commands"):
            formatter.write_dl(rows)

    def invoke(self, ctx):
        import time

        from pipeline import artifact

        artifact.STARTED[0] = time.monotonic()  # this command's stage timing starts here
        artifact.CREATED.clear()
        try:
            return super().invoke(ctx)
        except BloomError as exc:
            artifact.remove_created()
            name = ctx.invoked_subcommand or ""
            raise StageError(name, exc) from None
        except BaseException:
            artifact.remove_created()
            raise


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="bloom")
@click.option("-v", "--verbose", count=True, help="More log output (repeatable).")
@click.option("-q", "--quiet", is_flag=True, help="Only errors.")
def cli(verbose: int, quiet: bool) -> None:
    """Bloom: physically based flower blooming as a batch pipeline.

    Stages, in order: remesh -> axis -> growth -> simulate -> render. Each reads one
    file and writes one HDF5 artifact (or, for render, a folder). A stage replaces
    an artifact it wrote before, but never a file it did not write (use --overwrite).
    """
    level = logging.ERROR if quiet else (logging.DEBUG if verbose > 1 else logging.INFO)
    logging.basicConfig(level=level, format="%(message)s", stream=sys.stderr, force=True)
    logging.getLogger("trimesh").setLevel(max(level, logging.WARNING))


def _terminate(signum, frame):
    raise KeyboardInterrupt  # unwinds like Ctrl-C: temporary outputs are removed


def main(argv: list[str] | None = None) -> None:
    """Console entry point: Click's own errors also become one line; SIGTERM (a farm's
    kill) cleans up like Ctrl-C, leaving any previous artifact as it was."""
    signal.signal(signal.SIGTERM, _terminate)
    try:
        code = cli.main(args=argv, prog_name="bloom", standalone_mode=False)
    except StageError as exc:
        exc.show()
        sys.exit(exc.exit_code)
    except click.ClickException as exc:
        click.echo(f"bloom: error: {exc.format_message()}", err=True)
        sys.exit(exc.exit_code)
    except (click.Abort, KeyboardInterrupt):
        click.echo("bloom: interrupted; no output written", err=True)
        sys.exit(130)
    sys.exit(code if isinstance(code, int) else 0)
