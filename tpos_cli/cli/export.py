"""`tpos export`: targets or a trajectory of a run as CSV, KML, GeoJSON or GPX."""

from __future__ import annotations

from pathlib import Path

import typer

from tpos_cli.cli._common import exit_on_error


def export(
    run: Path = typer.Argument(..., help="Run directory written by `tpos process`."),
    format_: str = typer.Option(None, "--format", "-f", help="csv | kml | geojson | gpx; default: from the -o file's extension, else csv."),
    solution: str = typer.Option(
        None, "--solution", "-s", help="Solution to export; default the best the run has (smoothed, fkf_cal, fkf, fatci, forward, ...)."
    ),
    rate: float = typer.Option(
        None,
        "--rate",
        help="Trajectory epochs per second (the epoch nearest each tick is kept); default all epochs for csv, 1 Hz for the map formats.",
    ),
    trajectory: bool = typer.Option(
        False, "--trajectory", help="Export the trajectory of a run that also has targets (a drive with roadside shots)."
    ),
    out: str = typer.Option(
        None, "--out", "-o", help="Output file or directory; '-' for stdout; default RUN/<targets|trajectory>_<solution>.<format>."
    ),
) -> None:
    """Export RUN's targets (one row per target, repeat shots combined) or its trajectory.

    Target runs: id, lat, lon, h, sigma_n/e/u, the 95 % horizontal ellipse, number of shots and UTM
    coordinates. Other runs: the chosen solution's track with sigmas. WGS-84, ellipsoidal heights.

    Example (CSV into the run): tpos export runs/wall

    Example: tpos export runs/drive -o drive.kml
    """
    from tpos_cli.export.build import FORMATS, export_run

    suffix = Path(out).suffix.lower().lstrip(".") if out not in (None, "-") else ""
    named = {"json": "geojson"}.get(suffix, suffix) if suffix in FORMATS + ("json",) else None  # the format -o names
    fmt = (format_ or named or "csv").lower()
    if fmt not in FORMATS:
        raise typer.BadParameter(f"expected one of {', '.join(FORMATS)}, got {format_!r}", param_hint="--format")
    if named is not None and named != fmt:  # KML written into drive.csv: a file no tool opens as what it is named
        raise typer.BadParameter(f"{format_!r} contradicts -o {out} (a .{suffix} file): drop --format or name the file "
                                 f"*.{fmt}", param_hint="--format")
    with exit_on_error():
        res = export_run(run, fmt, solution=solution, rate_hz=rate, out=out, trajectory=trajectory)
    for n in res.notes:
        typer.echo(f"note: {n}", err=True)
    if res.path is None:
        return
    what = (
        f"{res.n_rows} target{'s' if res.n_rows != 1 else ''}"
        if res.kind == "targets"
        else f"{res.n_rows} epochs" + (f" at {res.rate_hz:g} Hz" if res.rate_hz else "")
    )
    typer.echo(f"{res.kind} ({res.solution}, {what}, UTM {res.zone}) -> {res.path}")
