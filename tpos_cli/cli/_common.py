"""Shared bits of the CLI: error mapping to exit codes, progress policy, console output."""

from __future__ import annotations

import contextlib
import sys

import typer

from tpos_cli.errors import TposError


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
