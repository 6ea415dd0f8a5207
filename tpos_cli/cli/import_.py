"""`tpos import`: write a contract session from logs in other formats."""

from __future__ import annotations

from pathlib import Path

import typer

from tpos_cli.cli._common import exit_on_error, working


def import_(
    fmt: str = typer.Argument(..., metavar="FORMAT", help="csv | nmea | rtklib-pos | ubx"),
    srcs: list[Path] = typer.Argument(..., metavar="SRC...", help="Source file(s), read only."),
    out: Path = typer.Option(..., "-o", "--out", help="Session directory to write or add to."),
    mapping: Path = typer.Option(None, "--map", help="csv: mapping TOML (columns, units, axes, time)."),
    clock: str = typer.Option("gps_tow", "--clock", help="nmea/rtklib-pos/ubx: clock of `t`: gps_tow | gps | unix."),
    force: bool = typer.Option(False, "--force", help="Replace a table the session already has."),
) -> None:
    """Import SRC files of FORMAT into the session OUT (created, or added to: import the IMU CSV,
    then the GPS solution, into one session). Sources are never modified.

    Example: tpos import csv imu_1730.csv --map docs/mappings/rtklibexplorer_walk_0827_imu.toml -o walk
    """
    from tpos_cli.importers import import_into_session

    with exit_on_error(), working(f"tpos import {fmt}"):
        written, notes = import_into_session(fmt, list(srcs), out, mapping=mapping, clock=clock, force=force)
    for n in notes:
        typer.echo(f"  {n}")
    typer.echo(f"wrote {', '.join(p.name for p in written)} in {out}")
