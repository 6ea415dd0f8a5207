"""`tpos calibrate-mag`: hard/soft-iron calibration of the magnetometer by ellipsoid fitting."""

from __future__ import annotations

from pathlib import Path

import typer

from tpos_cli.cli._common import exit_on_error, parse_window, working


def calibrate_mag(
    session: Path = typer.Argument(..., help="Session directory with a magnetometer."),
    window: str = typer.Option(None, "--window", help="T0:T1 (logger clock) of the rotation sequence; default: whole log."),
    out: Path = typer.Option(None, "-o", "--out", help="Write a calibrated COPY of the session here (the input is never modified)."),
    force: bool = typer.Option(False, "--force", help="Replace OUT if it exists."),
) -> None:
    """Fit an ellipsoid to the magnetometer samples and print `[magnetic] hard_iron_ut` and
    `soft_iron` (m_cal = soft_iron (m_raw - hard_iron_ut), logged sensor axes). With -o, copy the
    session to OUT with these keys in its session.toml; loading OUT applies them.

    Example: tpos calibrate-mag broad_02 --window 10:90 -o broad_02_cal
    """
    from tpos_cli.importers.session_out import dumps_toml
    from tpos_cli.magcal import calibrate_session, write_calibrated_copy

    with exit_on_error(), working("tpos calibrate-mag"):
        if out is not None:
            from tpos_cli.io.run_dir import check_session_out

            check_session_out(out, force=force, src=session)  # before the fit: --force replaces a session, nothing else
        cal, note = calibrate_session(session, parse_window(window, "--window") if window else None)
        if out is not None:
            write_calibrated_copy(session, out, cal, force=force)
    typer.echo(dumps_toml({"magnetic": cal.toml_keys()}).rstrip())
    typer.echo(f"# {note}")
    if out is not None:
        typer.echo(f"# wrote calibrated session {out}")
