"""`tpos report`: a report someone hands in (report.pdf), with accuracy.parquet and accuracy.json."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from tpos_cli.cli._common import defer_unused_imports, exit_on_error, keep_until_exit, run_to_exit, working


def report(
    run: Path = typer.Argument(..., help="Run directory written by `tpos process`."),
    truth: Path = typer.Option(None, "--truth", help="Session holding the truth; default: the run's own session (summary.json)."),
    full: bool = typer.Option(False, "--full", help="Add the appendix: every segment, innovation stream and shot."),
    json_: bool = typer.Option(False, "--json", help="Print the accuracy summary (accuracy.json) to stdout for scripts."),
) -> None:
    """Write report.pdf, accuracy.parquet and accuracy.json into RUN.

    Page 1 is the summary (verdict, headline figures, plan view, provenance). Without truth the
    report is a quality-control report (estimated accuracy, forward/backward separation, GPS
    quality, innovations); with truth (the session's truth.*, surveyed targets, or GPS fixes
    withheld by --mask-gps) it adds the errors against it. A run whose session inputs changed since
    it was processed is refused (exit 2): reprocess it first.

    Example: tpos report runs/drive --json
    """
    run_to_exit()  # a one-shot process: no interpreter teardown at the end
    # numpy's f2py, testing, and fontTools.subset (matplotlib's PDF backend imports it at its own import,
    # ~0.13 s CPU, and uses it only to embed a font; the standard PDF fonts the pages mostly use are not
    # embedded): each imported only if something uses it (one-shot only)
    defer_unused_imports("fontTools.subset")
    from tpos_cli.report.collector import cyclic_gc_paused

    try:
        with exit_on_error(), cyclic_gc_paused(), working(f"tpos report {run}"):  # the report's imports too
            from tpos_cli.report.build import make_report

            res = make_report(run, truth, full=full)  # SIGTERM is an interrupt here too (cli._interruptible)
            keep_until_exit()  # before the collector resumes (a one-shot `tpos report`)
    except KeyboardInterrupt:
        typer.echo("tpos report: interrupted; the run's earlier report files, if any, are unchanged", err=True)
        raise typer.Exit(130) from None
    for n in res.notes:
        typer.echo(f"note: {n}", err=True)
    if json_:
        typer.echo(json.dumps(res.summary, indent=1))
        return
    q = res.summary.get("quality")
    n_reasons = len(q.get("reasons") or []) if q else 0
    where = " in report.pdf, in full under \"The verdict's checks\""  # page 1 holds six lines of them
    typer.echo(
        f"verdict: {q['verdict']}" + (f" ({n_reasons} reason(s){where})" if n_reasons else "")
        if q
        else "verdict: no verdict recorded"
    )
    tt = res.truth.trajectory if res.truth is not None else None
    tg = res.truth.targets if res.truth is not None else None
    typer.echo(f"truth: {tt.description if tt is not None else tg.description if tg is not None else 'none (quality-control report)'}")

    def f(v):
        return "n/a" if v is None else f"{v:.3g}"

    static = res.summary["session"]["kind"] == "target"
    for h in res.summary["headline"]:
        if static and h["of"] == "trajectory":  # a fixed observer: its solutions are attitudes
            if "rms_yaw_deg" in h:
                # the total angle first: near pitch +-90 deg roll and yaw errors are large and cancel
                typer.echo(
                    f"{h['solution']:>10} (attitude, n={h['n']}): RMS total angle {f(h.get('rms_att_deg'))} deg (roll "
                    f"{f(h.get('rms_roll_deg'))}, pitch {f(h.get('rms_pitch_deg'))}, yaw {f(h['rms_yaw_deg'])})"
                )
            continue
        # all three angles: the comma drive's yaw alone (0.9 deg) hid its pitch error (3.7 deg), which `tpos batch`
        # shows in its total attitude error
        att = (f"; attitude RMS roll {f(h.get('rms_roll_deg'))}, pitch {f(h.get('rms_pitch_deg'))}, yaw "
               f"{f(h['rms_yaw_deg'])} deg" if "rms_yaw_deg" in h else "")
        typer.echo(
            f"{h['solution']:>10} ({h['of']}, n={h['n']}): RMS 3-D {f(h['rms_pos_3d_m'])} m, "
            f"horizontal {f(h['rms_pos_h_m'])} m, vertical {f(h['rms_pos_v_m'])} m{att}"
        )
    typer.echo(f"-> {res.run_dir} ({', '.join(res.outputs)}, {len(res.pages)} PDF pages)")
