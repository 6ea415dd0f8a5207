"""The `tpos` command line: thin Typer commands over the library; exit codes 0 / 1 / 2.

Each command lives in its own module and is registered below with one line.
"""

from __future__ import annotations

import os
import sys
from typing import Annotated

import typer

from tpos_cli.cli import _common
from tpos_cli.cli import batch as _batch
from tpos_cli.cli import calibrate_mag as _calibrate_mag
from tpos_cli.cli import export as _export
from tpos_cli.cli import import_ as _import
from tpos_cli.cli import inspect as _inspect
from tpos_cli.cli import noise as _noise
from tpos_cli.cli import pipelines as _pipelines
from tpos_cli.cli import process as _process
from tpos_cli.cli import report as _report
from tpos_cli.cli import simulate as _simulate
from tpos_cli.cli import validate as _validate

app = typer.Typer(
    name="tpos",
    help="Post-process navigation logs from low-cost sensors (MEMS IMU, laser rangefinders, GPS-WAAS, "
    "ranging anchors) into attitude, trajectory and target positions with an honest accuracy report.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)



def _print_version(value: bool) -> None:
    if value:
        from tpos_cli import __version__

        typer.echo(f"tpos {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[bool, typer.Option("--version", callback=_print_version, is_eager=True,
                                          help="Print the tpos version and exit.")] = False,
) -> None:
    # Options of `tpos` itself; the help text is the app's (above).
    return None


app.command("validate")(_validate.validate)
app.command("inspect")(_inspect.inspect)
app.command("process")(_process.process)
app.command("report")(_report.report)
app.command("export")(_export.export)
app.command("pipelines")(_pipelines.pipelines)
app.command("simulate")(_simulate.simulate)
app.command("batch")(_batch.batch)
app.command("import")(_import.import_)
app.command("noise")(_noise.noise)
app.command("calibrate-mag")(_calibrate_mag.calibrate_mag)


def main() -> None:
    """Console-script entry point: a one-line message and exit code 1 for an unexpected failure."""
    _common.mark_one_shot()
    try:
        app()
    except SystemExit as exc:
        _common.end_process(exc.code)  # `tpos process`/`report`/`batch`: ends here, no teardown
        raise
    except KeyboardInterrupt:
        print("tpos: interrupted", file=sys.stderr)
        sys.exit(130)
    except Exception as exc:  # a bug, not bad input: keep the traceback behind an opt-in
        if os.environ.get("TPOS_DEBUG"):
            raise
        print(f"tpos: internal error: {type(exc).__name__}: {exc} (set TPOS_DEBUG=1 for the traceback)", file=sys.stderr)
        sys.exit(1)
