"""The `tpos` command line: thin Typer commands over the library; exit codes 0 / 1 / 2.

Each command lives in its own module and is registered below with one line.
"""

from __future__ import annotations

import functools
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


def _print_version(value: bool) -> None:
    if value:
        from tpos_cli import __version__

        typer.echo(f"tpos {__version__}")
        raise typer.Exit()


def _root(
    version: Annotated[bool, typer.Option("--version", callback=_print_version, is_eager=True,
                                          help="Print the tpos version and exit.")] = False,
) -> None:
    # Options of `tpos` itself; the help text is the app's (above).
    return None


# What Ctrl-C leaves, per command: typer turns KeyboardInterrupt into a silent exit 130 before main()
# sees it, so each command says it (process, report and batch say more in their own handlers).
_INTERRUPTED = {
    "export": "the output file, if it existed, is unchanged",
    "import": "the tables written so far are whole; session.toml, written last, may not name them yet (the same "
              "command with --force writes them again)",
}


def _interruptible(name: str, fn):
    """`fn` saying one line and exiting 130 on Ctrl-C or `kill PID` (SIGTERM, which would otherwise end
    the process where it stands, its temporaries and run-directory lock left behind) (signature kept for typer)."""
    from tpos_cli.report.files import terminate_as_interrupt

    @functools.wraps(fn)
    def command(*args, **kwargs):
        try:
            with terminate_as_interrupt():
                return fn(*args, **kwargs)
        except KeyboardInterrupt:
            kept = _INTERRUPTED.get(name)
            typer.echo(f"tpos {name}: interrupted" + (f"; {kept}" if kept else ""), err=True)
            raise typer.Exit(130) from None

    return command


COMMANDS = {"validate": _validate.validate, "inspect": _inspect.inspect, "process": _process.process,
            "report": _report.report, "export": _export.export, "pipelines": _pipelines.pipelines,
            "simulate": _simulate.simulate, "batch": _batch.batch, "import": _import.import_,
            "noise": _noise.noise, "calibrate-mag": _calibrate_mag.calibrate_mag}


def make_app(names=None) -> typer.Typer:
    """The `tpos` app with the commands `names` (default: every command of COMMANDS, in its order).
    One command parses, validates and helps as in the whole app: `main()` builds only the command it
    runs (typer builds every registered command's parameters when the app starts: 0.02 s CPU of each
    `tpos process` for the ten others)."""
    app = typer.Typer(
        name="tpos",
        help="Post-process navigation logs from low-cost sensors (MEMS IMU, laser rangefinders, GPS-WAAS, "
        "ranging anchors) into attitude, trajectory and target positions with an honest accuracy report.",
        no_args_is_help=True,
        add_completion=False,
        pretty_exceptions_enable=False,
        rich_markup_mode=None,
    )
    app.callback()(_root)  # `tpos --version`; with it the app stays a group of commands even with one command
    for name, fn in COMMANDS.items():
        if names is None or name in names:
            app.command(name)(_interruptible(name, fn))
    return app


app = make_app()


def main() -> None:
    """Console-script entry point: a one-line message and exit code 1 for an unexpected failure."""
    _common.mark_one_shot()
    # One BLAS thread unless the user says otherwise (read when numpy and scipy load their OpenBLAS, after this:
    # no command module imports numpy at import time). tpos's BLAS calls are dots and small products a second
    # thread does not speed up, and OpenBLAS threads spin-wait after each call: on a busy machine they took the
    # CPU from the run (drive hour, 2 cores at load 5: conventions stage 3.2 s instead of 0.33 s, process CPU
    # 4.3 s instead of 1.8 s). One thread also gives the same sums on every machine, as the benchmarks run.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    # No pydantic plugins unless the user says otherwise: tpos's models are its own pipeline tables, which no
    # plugin observes, and looking for plugins reads the entry points of every installed distribution when the
    # first model's validator is built (typer turns them off for its own adapters the same way).
    os.environ.setdefault("PYDANTIC_DISABLE_PLUGINS", "1")
    # `tpos COMMAND ...`: the app of that command alone; anything else (`tpos --help`, a mistyped command) the whole app
    name = sys.argv[1] if len(sys.argv) > 1 else None
    try:
        (make_app((name,)) if name in COMMANDS else app)()
    except SystemExit as exc:
        _common.end_process(exc.code)  # `tpos process`/`report`/`batch`: ends here, no teardown
        raise
    except KeyboardInterrupt:  # outside a command (typer's parsing, or the exit itself); a command says its own
        print("tpos: interrupted", file=sys.stderr)
        sys.exit(130)
    except Exception as exc:  # a bug, not bad input: keep the traceback behind an opt-in
        if os.environ.get("TPOS_DEBUG"):
            raise
        print(f"tpos: internal error: {type(exc).__name__}: {exc} (set TPOS_DEBUG=1 for the traceback)", file=sys.stderr)
        sys.exit(1)
