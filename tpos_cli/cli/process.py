"""`tpos process`: run a pipeline on a session into a run directory."""

from __future__ import annotations

import tomllib
from pathlib import Path

import typer

from tpos_cli.cli._common import defer_unused_imports, exit_on_error, keep_until_exit, parse_window, run_to_exit, show_progress
from tpos_cli.io.bounded import MAX_TOML_DEPTH, toml_depth


def _parse_set(items: list[str]) -> dict:
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise typer.BadParameter(f"expected section.key=value, got {item!r}", param_hint="--set")
        try:
            out[key.strip()] = tomllib.loads(f"v = {value.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            out[key.strip()] = value.strip()  # a bare word is a string
        except RecursionError:
            raise typer.BadParameter(f"{key.strip()}: value nested too deeply", param_hint="--set") from None
        if toml_depth(out[key.strip()]) > MAX_TOML_DEPTH:
            raise typer.BadParameter(f"{key.strip()}: value nested more than {MAX_TOML_DEPTH} levels", param_hint="--set")
    return out


def process(
    session: Path = typer.Argument(..., help="Session directory (docs/log-format.md)."),
    pipeline: str = typer.Option(None, "--pipeline", "-p", help="Pipeline name (see `tpos pipelines`) or a TOML file; default: the one for the session's kind."),
    out: Path = typer.Option(None, "--out", "-o", help="Run directory; default runs/<session>-<pipeline>."),
    mask_gps: list[str] = typer.Option([], "--mask-gps", help="Withhold GPS in T0:T1 (logger-clock seconds); repeatable. The withheld fixes go to RUN/withheld_gps.parquet for `tpos report`."),
    set_: list[str] = typer.Option([], "--set", help="Override a pipeline parameter: section.key=value (TOML value); repeatable."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bars, only the final line (and the verdict when it is not ok)."),
    strict: bool = typer.Option(False, "--strict", help="Exit 1 when the verdict is \"unreliable\" (the run directory is still written)."),
) -> None:
    """Process SESSION with a pipeline and write trajectory.parquet, targets.parquet (when aimed shots exist)
    and summary.json into the run directory.

    Outputs appear only when the run completes (written to a temporary directory, then renamed).
    Every run gets a verdict, `quality` in summary.json: "ok", "suspect" or "unreliable", with a
    reason per finding (likely cause and fix) and the figures behind it; it is printed when not ok.
    A fix is suggested only after re-processing part of the log with it fitted the data better.
    Exit code 0 means processing completed; it is NOT a claim of accuracy (with --strict an
    "unreliable" verdict exits 1, and the run directory is still written). Use `tpos report`
    against truth.

    Example: tpos process sample_logs/drive_outage -o runs/drive --mask-gps 50:80
    """
    run_to_exit()  # a one-shot process: no cyclic collections, no interpreter teardown at the end
    defer_unused_imports()  # numpy's f2py, testing: imported only if something uses them (one-shot only)
    windows = [parse_window(w, "--mask-gps") for w in mask_gps]
    overrides = _parse_set(set_)
    try:
        from tpos_cli.pipeline import process_session

        keep_until_exit()  # the ~10^5 objects of the imports above: out of every later collection (one-shot only)
        with exit_on_error():
            res = process_session(session, pipeline, out, mask_gps_windows=windows, overrides=overrides,
                                  progress=show_progress(quiet))
    except KeyboardInterrupt:  # typer would end with exit 130 and not a word
        typer.echo("tpos process: interrupted; no run was written (an earlier run in that directory, if any, is unchanged)", err=True)
        raise typer.Exit(130) from None
    s = res.summary
    q = s.get("quality") or {}
    verdict = q.get("verdict", "ok")
    said_below = set(q.get("reasons", [])) if verdict != "ok" else set()  # a finding the chain also warned of: once
    if not quiet:
        for w in s["warnings"]:
            if w not in said_below:
                typer.echo(f"warning: {w}")
    typer.echo(f"{s['session']['name']}: {s['pipeline']} -> {res.run_dir} ({', '.join(s['outputs'])}) "
               f"in {s['timings_s'].get('total', 0):.2f} s")
    if verdict != "ok":
        typer.echo(f"verdict: {verdict}", err=True)
        for r in q.get("reasons", []):
            typer.echo(f"  - {r}", err=True)
    if strict and verdict == "unreliable":
        raise typer.Exit(1)
