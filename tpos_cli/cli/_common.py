"""Shared bits of the CLI: error mapping to exit codes, progress policy, console output."""

from __future__ import annotations

import atexit
import contextlib
import gc
import os
import sys
import threading

import typer

from tpos_cli.errors import TposError

# True once `main()` runs: this process executes one command and exits (the console script,
# `python -m tpos_cli`), so memory held only by reference cycles may be left to the operating
# system at exit. False under CliRunner, tests and `tpos batch`, which call the commands in a
# process that goes on.
_one_shot = False
# True once a command that may end the process itself (`run_to_exit`) has started in a one-shot process.
_end_with_os_exit = False


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
        gc.freeze()


# numpy submodules no command uses that numpy imports on first attribute access, and scipy's array-API
# layer touches every public attribute of numpy at scipy's first import (array_api_compat's
# `clone_module`: `hasattr(numpy, name)` for each; numba's first dispatch imports scipy.linalg): about
# 0.05 s CPU of every `tpos process` (numpy.f2py's crackfortran compiles some hundred regexes).
_UNUSED_NUMPY_MODULES = ("numpy.f2py", "numpy.testing")


def defer_unused_imports(*more: str) -> None:
    """In a one-shot process, register `_UNUSED_NUMPY_MODULES` and the submodules `more` as lazy
    modules (the standard library's `importlib.util.LazyLoader`): the attribute their parent package
    hands out is the module, whose code runs at the first access to one of ITS attributes, so only a
    caller that uses it pays for its import. Modules already imported are left as they are; nothing
    changes in a process that goes on."""
    if not _one_shot:
        return
    import importlib
    import importlib.util

    for name in _UNUSED_NUMPY_MODULES + more:
        if name in sys.modules:
            continue
        parent = importlib.import_module(name.rpartition(".")[0])
        spec = importlib.util.find_spec(name)
        if spec is None or spec.loader is None:
            continue
        spec.loader = importlib.util.LazyLoader(spec.loader)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
        setattr(parent, name.rpartition(".")[2], module)


def run_to_exit(pause_collector: bool = True) -> None:
    """Called first by `tpos process`, `report` and `batch`. In a one-shot process only (never under
    CliRunner, tests or a library caller): with `pause_collector` the cyclic collector stays off for
    the rest of the command (its imports' ~10^5 objects are not rescanned; one run of a session
    leaves few garbage cycles; `tpos batch`, which may run many sessions in this process, keeps it),
    and `main()` ends the process with `end_process` once the command has returned, instead of the
    interpreter's teardown, which frees every object and module one by one (0.08-0.10 s CPU of a
    drive-hour process) only for the operating system to drop them anyway."""
    global _end_with_os_exit
    if _one_shot:
        if pause_collector:
            gc.disable()
        _end_with_os_exit = True


def end_process(code: object) -> None:
    """End a `run_to_exit` command's process now with exit status `code` (a SystemExit code: None
    or an int), skipping the interpreter's teardown; returns (and the normal exit follows) when the
    command did not ask for it, for any other code (a message), when another thread is alive or when
    stdout/stderr cannot be flushed (a closed pipe: Python's own exit reports it). What the teardown
    would still do is done first: stdout/stderr flushed, atexit handlers (and `weakref.finalize`
    clean-ups) run; every output file is already closed by the command (written with `with`)."""
    if not _end_with_os_exit or threading.active_count() > 1:
        return
    if code is None:
        code = 0
    if not isinstance(code, int) or isinstance(code, bool):
        return
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):
        return
    atexit._run_exitfuncs()
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):
        pass
    os._exit(code)


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
