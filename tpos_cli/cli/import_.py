"""`tpos import`: write a contract session from logs in other formats."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from tpos_cli.cli._common import exit_on_error, working


def import_(
    fmt: Annotated[str, typer.Argument(metavar="FORMAT", help="csv | nmea | rtklib-pos | ubx")],
    srcs: Annotated[list[Path], typer.Argument(metavar="SRC...", help="Source file(s), read only.")],
    out: Annotated[Path, typer.Option("-o", "--out", help="Session directory to write or add to.")],
    mapping: Annotated[Path | None, typer.Option("--map", help="csv: mapping TOML (columns, units, axes, time).")] = None,
    clock: Annotated[str, typer.Option("--clock", help="nmea/rtklib-pos/ubx: clock of `t`: gps_tow | gps | unix.")] = "gps_tow",
    force: Annotated[bool, typer.Option("--force", help="Replace a table the session already has.")] = False,
    geoid_sep_m: Annotated[float | None, typer.Option(
        "--geoid-sep-m",
        help="nmea/rtklib-pos: geoid undulation at the site (m) for heights the source gives above the geoid (mean sea level).",
    )] = None,
    heights: Annotated[str | None, typer.Option(
        "--heights", help="rtklib-pos: ellipsoidal | geodetic, for a .pos file whose header does not say.")] = None,
) -> None:
    """Import SRC files of FORMAT into the session OUT (created, or added to: import the IMU CSV,
    then the GPS solution, into one session). Sources are never modified.

    Heights: the session needs ellipsoidal heights; an importer converts heights given above the geoid
    only with the separation (from the source, or --geoid-sep-m), and refuses otherwise.

    Example: tpos import csv imu_1730.csv --map docs/mappings/rtklibexplorer_walk_0827_imu.toml -o walk
    """
    from tpos_cli.importers import import_into_session

    with exit_on_error(), working(f"tpos import {fmt}"):
        written, notes = import_into_session(fmt, list(srcs), out, mapping=mapping, clock=clock, force=force,
                                             geoid_sep_m=geoid_sep_m, heights=heights)
    for n in notes:
        typer.echo(f"  {n}")
    typer.echo(f"wrote {', '.join(p.name for p in written)} in {out}")
