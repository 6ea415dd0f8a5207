"""`tpos batch`: reprocess many sessions, resumable, in parallel or on a Dask cluster."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from tpos_cli.errors import InvalidInputError, TposError


def batch(
    sessions: Annotated[list[str], typer.Argument(help="Session directories, globs ('logs/*') or list files (one session per line).", show_default=False)],
    out: Annotated[Path, typer.Option("--out", "-o", help="Root directory: each session goes to OUT/<session-name>/.")],
    pipeline: Annotated[str | None, typer.Option("--pipeline", "-p", help="Pipeline name or TOML file; default: the pipeline for each session's kind.")] = None,
    jobs: Annotated[int | None, typer.Option("--jobs", "-j", help="Worker processes (default: all cores; 1 runs in this process).")] = None,
    report: Annotated[bool, typer.Option("--report", help="Run `tpos report` on each finished run (accuracy files and report.pdf in it) and add its errors against truth, with the run's own figures, to the table and batch files.")] = False,
    force: Annotated[bool, typer.Option("--force", help="Redo sessions whose finished run is current.")] = False,
    scheduler: Annotated[str | None, typer.Option("--scheduler", help="Dask scheduler address (tcp://host:8786): run the sessions on that cluster.")] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Process every session into OUT/<session-name>/; skip finished ones; exit 1 if any failed."""
    from tpos_cli import batch as b

    try:
        tasks = b.plan_batch(b.expand_sessions(sessions), out, pipeline, force=force, report=report)
        result = _run_with_progress(tasks, jobs, scheduler, quiet)
        json_path, _ = b.write_batch_record(result, pipeline=pipeline)
    except InvalidInputError as exc:
        _err(str(exc))
        raise typer.Exit(2) from None
    except TposError as exc:
        _err(str(exc))
        raise typer.Exit(1) from None
    _print_table(result)
    typer.echo(
        f"{result.count(b.STATUS_OK)} ok, {result.count(b.STATUS_SKIPPED)} skipped, "
        f"{result.count(b.STATUS_FAILED)} failed in {result.wall_time_s:.1f} s; record: {json_path}"
    )
    raise typer.Exit(result.exit_code)


def _err(msg: str) -> None:
    typer.secho(f"error: {msg}", fg=typer.colors.RED, err=True)


def _run_with_progress(tasks, jobs, scheduler, quiet):
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from tpos_cli.batch import run_batch

    console = Console(stderr=True)
    if quiet or not console.is_terminal:
        return run_batch(tasks, jobs=jobs, scheduler=scheduler)
    columns = (TextColumn("[bold]batch"), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[last]}"),
               TimeElapsedColumn(), TimeRemainingColumn())
    with Progress(*columns, console=console, transient=True) as progress:
        bar = progress.add_task("batch", total=len(tasks), last="")
        def advance(r):
            progress.update(bar, advance=1, last=f"{r.name}: {r.status}")
        return run_batch(tasks, jobs=jobs, scheduler=scheduler, on_result=advance)


def _print_table(result) -> None:
    from rich.console import Console
    from rich.table import Table

    from tpos_cli.batch import key_accuracy_figures

    keys = key_accuracy_figures(result.results)
    table = Table(show_edge=False)
    for col in ("session", "status", "time s", *keys):
        table.add_column(col, overflow="fold")
    style = {"ok": "green", "skipped": "cyan", "failed": "red"}
    for r in result.results:
        acc = [f"{r.accuracy[k]:.4g}" if k in r.accuracy else "" for k in keys]
        time_s = "" if r.time_s != r.time_s else f"{r.time_s:.1f}"  # NaN: the worker was lost
        table.add_row(r.name, f"[{style[r.status]}]{r.status}[/]", time_s, *acc)
    console = Console()
    if not console.is_terminal:  # piped or logged: do not fold names at 80 columns
        console = Console(width=200)
    console.print(table)
    for r in result.results:  # whole lines, not folded into a cell: easy to read and to grep
        if r.error:
            typer.echo(f"{r.name}: {r.error}")
