"""`tpos inspect`: what a session holds."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from tpos_cli.cli._common import exit_on_error, working


def inspect(
    session: Path = typer.Argument(..., help="Session directory."),
    as_json: bool = typer.Option(False, "--json", help="Print a JSON document for scripts."),
) -> None:
    """Summarise SESSION: files, rows, time span, measured rates, gaps, GPS outages, NaN counts,
    fix types, anchors, and warnings. Exit code 2 if the session is not valid.

    Example: tpos inspect sample_logs/drive_outage --json
    """
    from tpos_cli.inspection import describe_session
    from tpos_cli.session import load_session

    with exit_on_error(), working(f"tpos inspect {session}"):
        loaded = load_session(session)
        info = describe_session(loaded)
        from tpos_cli.conventions import check_conventions

        info["warnings"] = list(info["warnings"]) + check_conventions(loaded)
    if as_json:
        typer.echo(json.dumps(info, indent=2))
        return
    typer.echo(f"session {info['name']} ({info['kind']}) at {info['path']}")
    typer.echo(f"  clock: t0 = {info['t0']:.6f} s, duration {info['duration_s']:.2f} s")
    typer.echo(f"  {'table':<18}{'rows':>8}{'span s':>9}{'rate Hz':>9}{'jitter ms':>10}  notes")
    for name, t in info["tables"].items():
        rate = f"{t['rate_hz']:.2f}" if t.get("rate_hz") else "-"
        jitter = f"{t['jitter_ms']:.2f}" if t.get("jitter_ms") is not None else "-"
        span = f"{t['span_s']:.1f}" if t.get("span_s") is not None else "-"
        typer.echo(f"  {name:<18}{t['rows']:>8}{span:>9}{rate:>9}{jitter:>10}  {t.get('notes', '')}")
    typer.echo("  (rate: mean over the sample intervals; jitter: their SD; gaps left out and listed below)")
    if info["gps_outages"]:
        typer.echo("  GPS outages (logger clock): " + ", ".join(f"{a:.2f}-{b:.2f} ({b - a:.1f} s)" for a, b in info["gps_outages"]))
    if info["imu_gaps"]:
        typer.echo(f"  IMU gaps: {len(info['imu_gaps'])}, longest {max(b - a for a, b in info['imu_gaps']):.3f} s")
    if info["counts"]:
        typer.echo("  counts: " + ", ".join(f"{k}={v}" for k, v in info["counts"].items()))
    for w in info["warnings"]:
        typer.echo(f"  warning: {w}")
