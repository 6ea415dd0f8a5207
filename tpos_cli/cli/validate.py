"""`tpos validate`: check sessions against the contract."""

from __future__ import annotations

from pathlib import Path

import typer

from tpos_cli.cli._common import working
from tpos_cli.errors import InvalidInputError


def validate(
    sessions: list[Path] = typer.Argument(..., help="Session directories to check."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print problems only, not the 'ok' lines."),
) -> None:
    """Check each SESSION against the session contract (docs/log-format.md).

    Prints one line per problem (session/file: column, row: what is wrong), and the warnings of
    valid sessions, including convention checks (axes, signs, units, clocks) with the likely fix. Exit code 0 when every session is valid, 2 otherwise.

    Example: tpos validate sample_logs/*/
    """
    from tpos_cli.conventions import check_gps_clock, contract_errors, session_findings
    from tpos_cli.session import load_session

    bad = 0
    for s in sessions:
        try:
            with working(f"validating {s}"):
                session = load_session(s)
                findings = session_findings(session)
                errors = contract_errors(session, findings)  # a unit the contract forbids: invalid, not a warning
                if errors:
                    raise InvalidInputError(errors[0], errors)
                warnings = [*session.warnings, *(f.reason for f in findings if f.reason)]
                if session.gps is not None:
                    warnings += check_gps_clock(session)
        except InvalidInputError as exc:
            bad += 1
            problems = exc.problems or [str(exc)]
            for p in problems:
                typer.echo(f"{s}/{p}" if not str(p).startswith(str(s)) else str(p), err=True)
            continue
        if not quiet:
            typer.echo(f"ok {s}: {session.meta.kind}, {len(session.imu.t_s)} IMU samples, {session.t_end_s:.1f} s")
        for w in warnings:
            typer.echo(f"warning {s}: {w}")
    if bad:
        raise typer.Exit(2)
