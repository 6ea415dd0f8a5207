"""`tpos report`: accuracy of a run against GPS-referenced truth (accuracy.parquet/.json, report.pdf)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from tpos_cli.cli._common import exit_on_error, working


def report(
    run: Path = typer.Argument(..., help="Run directory written by `tpos process`."),
    truth: Path = typer.Option(None, "--truth", help="Session holding the truth; default: the run's own session (summary.json)."),
    json_: bool = typer.Option(False, "--json", help="Print the accuracy summary (accuracy.json) to stdout for scripts."),
) -> None:
    """Compare RUN's solutions with truth and write accuracy.parquet, accuracy.json and report.pdf into RUN.

    Truth, in order: the session's truth.*; surveyed targets (role = truth); else the GPS fixes
    (independent only inside --mask-gps windows). The report says which was used.
    Exit code 2 when the run has nothing to compare with.

    Example: tpos report runs/drive --json
    """
    from tpos_cli.report.build import make_report

    with exit_on_error(), working(f"tpos report {run}"):
        res = make_report(run, truth)
    if json_:
        typer.echo(json.dumps(res.summary, indent=1))
        return
    tt = res.truth.trajectory
    typer.echo(f"truth: {tt.description if tt is not None else res.truth.targets.description}")
    def f(v):
        return "n/a" if v is None else f"{v:.3g}"

    for h in res.summary["headline"]:
        yaw = f", yaw {f(h['rms_yaw_deg'])} deg" if "rms_yaw_deg" in h else ""
        typer.echo(f"{h['solution']:>10} ({h['of']}, n={h['n']}): RMS 3-D {f(h['rms_pos_3d_m'])} m, "
                   f"horizontal {f(h['rms_pos_h_m'])} m, vertical {f(h['rms_pos_v_m'])} m{yaw}")
    typer.echo(f"-> {res.run_dir} ({', '.join(res.outputs)}, {len(res.pages)} PDF pages)")
