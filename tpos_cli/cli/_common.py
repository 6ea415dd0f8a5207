"""Shared bits of the CLI: error mapping to exit codes, progress policy, console output."""

from __future__ import annotations

import contextlib
import sys

import typer

from tpos_cli.errors import TposError

# True once `main()` runs: this process executes one command and exits (the console script,
# `python -m tpos_cli`), so memory held only by reference cycles may be left to the operating
# system at exit. False under CliRunner, tests and `tpos batch`, which call the commands in a
# process that goes on.
_one_shot = False


def mark_one_shot() -> None:
    """Called by `main()` only."""
    global _one_shot
    _one_shot = True


def keep_until_exit() -> None:
    """In a one-shot process, move every object now alive (and cycles already unreachable) out of the
    cyclic collector's reach (`gc.freeze`); they are released by the process's exit. `tpos process`
    calls it after its imports: later collections no longer rescan their ~10^5 objects (collector time
    of a drive-hour process 0.19 -> 0.08 s); `tpos report` after the report is written: its ~10^5
    matplotlib artists are not freed by a collection (0.09 s) nor rescanned at exit. Nothing else
    changes: files are closed by then, `weakref.finalize`/atexit clean-ups still run, objects created
    later are collected as before. Does nothing in a process that goes on (CliRunner, tests, batch)."""
    if _one_shot:
        import gc

        gc.freeze()


@contextlib.contextmanager
def exit_on_error():
    """Map library errors to a one-line message on stderr and the error's exit code."""
    try:
        yield
    except TposError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(exc.exit_code) from None


def show_progress(quiet: bool) -> bool:
    """Progress bars only for a person watching: never with --quiet or when stdout is not a terminal."""
    return not quiet and sys.stdout.isatty()


def parse_window(text: str, option: str) -> tuple[float, float]:
    """`T0:T1` into two floats; a bad value is a usage error (exit 2)."""
    try:
        a, b = text.split(":")
        return float(a), float(b)
    except ValueError:
        raise typer.BadParameter(f"expected T0:T1 in seconds, got {text!r}", param_hint=option) from None


@contextlib.contextmanager
def working(label: str, quiet: bool = False):
    """A spinner with `label` on stderr while a long step runs, for a person at a terminal only."""
    if not show_progress(quiet):
        yield
        return
    from rich.console import Console

    with Console(stderr=True).status(label):
        yield
