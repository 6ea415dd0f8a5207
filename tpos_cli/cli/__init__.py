"""The `tpos` command line: thin Typer commands over the library; exit codes 0 / 1 / 2.

Each command lives in its own module and is registered below with one line of `COMMANDS`. A command's
module is imported, and its Click command built, only when that command runs or a help page lists it:
`tpos report RUN` neither imports nor builds the other ten.
"""

from __future__ import annotations

import importlib
import os
import sys
from collections.abc import Iterator, MutableMapping
from typing import Annotated

import typer
from typer.core import TyperGroup
from typer.main import get_command_from_info

from tpos_cli.cli import _common

# name: (module in tpos_cli.cli, function), in the order `tpos --help` lists them
COMMANDS = {
    "validate": ("validate", "validate"),
    "inspect": ("inspect", "inspect"),
    "process": ("process", "process"),
    "report": ("report", "report"),
    "export": ("export", "export"),
    "pipelines": ("pipelines", "pipelines"),
    "simulate": ("simulate", "simulate"),
    "batch": ("batch", "batch"),
    "import": ("import_", "import_"),
    "noise": ("noise", "noise"),
    "calibrate-mag": ("calibrate_mag", "calibrate_mag"),
}


class _Commands(MutableMapping):
    """The group's commands by name, each imported and built on first access (as `app.command(name)`
    registers it, then as Typer builds it): Click and Typer look commands up by name, list them
    (help, completion) and suggest near names from the keys, which are all known without imports."""

    def __init__(self, built: dict):
        self._built = dict(built)

    def __getitem__(self, name: str):
        cmd = self._built.get(name)
        if cmd is None:
            module, func = COMMANDS[name]  # KeyError: no such command
            registrar = typer.Typer()
            registrar.command(name)(getattr(importlib.import_module(f"tpos_cli.cli.{module}"), func))
            cmd = self._built[name] = get_command_from_info(
                registrar.registered_commands[0],
                pretty_exceptions_short=app.pretty_exceptions_short,
                rich_markup_mode=app.rich_markup_mode,
            )
        return cmd

    def __contains__(self, name) -> bool:
        return name in COMMANDS or name in self._built

    def __setitem__(self, name: str, cmd) -> None:
        self._built[name] = cmd

    def __delitem__(self, name: str) -> None:
        raise TypeError("tpos commands cannot be removed")

    def __iter__(self) -> Iterator[str]:
        return iter(dict.fromkeys([*COMMANDS, *self._built]))

    def __len__(self) -> int:
        return len(set(COMMANDS) | set(self._built))


class _LazyGroup(TyperGroup):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.commands = _Commands(self.commands)


app = typer.Typer(
    cls=_LazyGroup,
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


def main() -> None:
    """Console-script entry point: a one-line message and exit code 1 for an unexpected failure."""
    _common.mark_one_shot()
    try:
        app()
    except SystemExit:
        raise
    except KeyboardInterrupt:
        print("tpos: interrupted", file=sys.stderr)
        sys.exit(130)
    except Exception as exc:  # a bug, not bad input: keep the traceback behind an opt-in
        if os.environ.get("TPOS_DEBUG"):
            raise
        print(f"tpos: internal error: {type(exc).__name__}: {exc} (set TPOS_DEBUG=1 for the traceback)", file=sys.stderr)
        sys.exit(1)
