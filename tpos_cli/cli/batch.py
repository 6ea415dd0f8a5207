"""`tpos batch`: reprocess many sessions, resumable, in parallel or on a Dask cluster."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from tpos_cli.cli._common import run_to_exit
from tpos_cli.errors import InvalidInputError, TposError


def batch(
    sessions: Annotated[list[str], typer.Argument(help="Session directories, globs ('logs/*') or list files (one session per line).", show_default=False)],
    out: Annotated[Path, typer.Option("--out", "-o", help="Root directory: each session goes to OUT/<session-name>/.")],
    pipeline: Annotated[str | None, typer.Option("--pipeline", "-p", help="Pipeline name or TOML file; default: the pipeline for each session's kind.")] = None,
    jobs: Annotated[int | None, typer.Option("--jobs", "-j", help="Worker processes (default: all cores; 1 runs in this process).")] = None,
    report: Annotated[bool, typer.Option("--report", help="Run `tpos report` on each finished run (accuracy files and report.pdf in it) and add its errors against truth, with the run's own figures, to the table and batch files.")] = False,
    force: Annotated[bool, typer.Option("--force", help="Redo sessions whose finished run is current.")] = False,
    timeout: Annotated[float, typer.Option("--timeout", help="Time limit per session in seconds (0: none); a session over it fails with exit code 1, the others go on.")] = 7200.0,
    scheduler: Annotated[str | None, typer.Option("--scheduler", help="Dask scheduler address (tcp://host:8786): run the sessions on that cluster.")] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Process every session into OUT/<session-name>/; skip finished ones; exit 1 if any failed.

    Prints one line per session (status, verdict, errors against truth with --report, warnings,
    time) and writes OUT/batch.json and OUT/batch.parquet: every row with its warnings, verdict and
    figures, merged with earlier batches into OUT (an unchanged run keeps its earlier report).

    Example: tpos batch 'field/2024-*' more_sessions.txt -o runs/all --jobs 2 --report
    """
    run_to_exit(pause_collector=False)  # a one-shot process: no interpreter teardown at the end
    from tpos_cli import batch as b

    try:
        tasks = b.plan_batch(b.expand_sessions(sessions), out, pipeline, force=force, report=report, timeout_s=timeout)
        b.check_jobs(jobs)  # a usage error leaves nothing behind: checked before OUT is created
        _check_writable(out)  # before the sessions run: a read-only OUT failed each of them, then the record
        result = _run_with_progress(tasks, jobs, scheduler, quiet)
        json_path, _ = b.write_batch_record(result, pipeline=pipeline)
    except KeyboardInterrupt:  # typer would end with exit 130 and not a word
        _err(f"interrupted; the sessions finished so far are in {out}, the others were not written; "
             "the same command resumes (finished runs are skipped)")
        raise typer.Exit(130) from None
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


def _check_writable(out: Path) -> None:
    """OUT exists (created now if need be) and can be written, else a one-line TposError (exit 1)."""
    import os

    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise TposError(f"-o {out}: cannot create the directory ({exc.strerror or exc})") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise TposError(f"-o {out}: the directory cannot be written (read-only file system or no permission)")


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
    from tpos_cli.batch import TABLE_LEGEND, format_table
    from tpos_cli.report.solutions import rank_solutions

    for line in format_table(result.results, rank_solutions):
        typer.echo(line)
    typer.echo(TABLE_LEGEND)
    for r in result.results:  # whole lines, not folded into a cell: easy to read and to grep
        if r.error:
            typer.echo(f"{r.name}: {r.error}")
