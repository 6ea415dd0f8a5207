"""`export_run`: the one call behind `tpos export` (run directory in, one CSV/KML/GeoJSON/GPX file out).

A run with `targets.parquet` exports its targets (one row or placemark per target id, repeat shots
combined, see `export.targets`) unless the trajectory is asked for; any other run its trajectory
(one solution at a chosen rate).
"""

from __future__ import annotations

import re
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from tpos_cli.errors import InvalidInputError
from tpos_cli.export import geojson, gpx, kml
from tpos_cli.export.meta import ExportMeta, decimals, read_start_utc
from tpos_cli.export.trajectory import trajectory_table
from tpos_cli.report.files import write_atomic
from tpos_cli.report.format import checked_start_utc, utc_strings
from tpos_cli.report.solutions import choose_solution
from tpos_cli.report.targets import combined_targets

FORMATS = ("csv", "kml", "geojson", "gpx")
TARGET_EXPORT_TRAJECTORY = ("t", "lat", "lon", "h", "solution")  # what a target export reads of a run's trajectory
MAP_RATE_HZ = 1.0  # default rate of the map formats: a track a viewer draws smoothly, a file a person opens


@dataclass(frozen=True)
class ExportResult:
    path: Path | None  # None when written to stdout
    kind: str  # "targets" | "trajectory"
    solution: str
    n_rows: int
    zone: str
    rate_hz: float | None
    notes: tuple[str, ...] = ()  # one line each, for the terminal


def format_csv(df: pd.DataFrame) -> bytes:
    """CSV with fixed decimals per column (no scientific notation), empty cells for NaN."""
    out = pd.DataFrame(index=df.index)
    for c in df.columns:
        v = df[c]
        if pd.api.types.is_float_dtype(v):
            a = v.to_numpy(float)
            s = np.char.mod(f"%.{decimals(c)}f", a)
            out[c] = np.where(np.isfinite(a), s, "")
        else:
            out[c] = v.astype(str).replace({"None": "", "nan": ""})
    return out.to_csv(index=False, lineterminator="\n").encode("utf-8")


def _observer(run, solution: str) -> pd.DataFrame | None:
    """The observer's position for a target export: the chosen solution's (fixed) trajectory point;
    None for a moving platform (a drive with roadside shots has no one observer point)."""
    if run.trajectory is None or (run.summary.get("session") or {}).get("kind") != "target":
        return None
    d = run.trajectory[run.trajectory["solution"] == solution]
    if d.empty:
        d = run.trajectory
    p = d[["lat", "lon", "h"]].to_numpy(float)
    p = p[np.isfinite(p).all(axis=1)]
    if not len(p):
        return None
    return pd.DataFrame({"id": ["observer"], "lat": [p[0, 0]], "lon": [p[0, 1]], "h": [p[0, 2]]})


def _logger_times(run) -> np.ndarray:
    """Every logger-clock time an export may date: trajectory epochs and shot windows."""
    parts = [np.empty(0)]
    if run.trajectory is not None:
        parts.append(run.trajectory["t"].to_numpy(float))
    if run.targets is not None:
        parts += [run.targets[c].to_numpy(float) for c in ("t_start", "t_end") if c in run.targets.columns]
    return np.concatenate(parts)


def _default_path(run_dir: Path, kind: str, solution: str, fmt: str) -> Path:
    """`run_dir`/KIND_SOLUTION.FMT. The solution name comes from the run's own tables: anything but
    letters, digits, "_", "-" and inner "." becomes "_", so that no name ("../../x", "a/b") leads
    the file out of `run_dir`."""
    safe = re.sub(r"[^A-Za-z0-9_.-]", "_", solution).strip(".") or "_"
    return run_dir / f"{kind}_{safe.replace('..', '__')}.{fmt}"


# What an export may write into a tpos run directory (a directory holding summary.json): a file of an
# export format's suffix (GeoJSON also as .json) that is not one of the run's or its report's JSON files.
EXPORT_SUFFIXES = (".csv", ".kml", ".geojson", ".gpx", ".json")
RUN_JSON_FILES = ("summary.json", "accuracy.json")


def check_export_path(path: Path, out, session_dir: Path | None = None) -> None:
    """InvalidInputError when `path` (followed through links) would replace a session's input or a
    run's own file: a file in a directory holding session.toml (a session) or in the run's own
    `session_dir`, or in a run directory a file that is not an export (trajectory.parquet,
    summary.json, report.pdf ...). A run's and a session's files are only ever written by the
    commands that own them. A device or FIFO is refused by the writer (`report.files.check_replaceable`)."""
    real = Path(path).resolve()
    where = real.parent
    if (where / "session.toml").is_file() or (session_dir is not None and real.is_relative_to(Path(session_dir).resolve())):
        raise InvalidInputError(f"-o {out}: {real} is inside a session directory; exports never go among a session's "
                                "input files: choose a file elsewhere")
    if (where / "summary.json").is_file() and (real.suffix.lower() not in EXPORT_SUFFIXES or real.name in RUN_JSON_FILES):
        raise InvalidInputError(f"-o {out}: {real.name} in the run directory {where} is the run's own file, not an export: "
                                f"choose a name ending in {', '.join(EXPORT_SUFFIXES[:4])}")


def export_run(
    run_dir: Path,
    fmt: str,
    *,
    solution: str | None = None,
    rate_hz: float | None = None,
    out: Path | str | None = None,
    trajectory: bool = False,
) -> ExportResult:
    """Write one export of a run (see module docstring); `out` "-" writes to stdout; `trajectory`
    exports the trajectory of a run that also has targets (a drive with roadside shots).

    Raises InvalidInputError (exit 2) for an unknown format or solution, a run without solutions,
    or a rate that is not positive.
    """
    from tpos_cli import __version__
    from tpos_cli.report.rundir import load_run, session_dir_of

    if fmt not in FORMATS:
        raise InvalidInputError(f"--format {fmt}: expected one of {', '.join(FORMATS)}")
    if rate_hz is not None and not (np.isfinite(rate_hz) and rate_hz > 0):
        raise InvalidInputError(f"--rate {rate_hz:g}: must be a positive number of Hz")
    # a target export reads of the trajectory what it dates and places (times, the observer's position);
    # a run without targets (or with an empty targets.parquet) exports its whole trajectory
    run = load_run(Path(run_dir), trajectory_columns_if_targets=None if trajectory else TARGET_EXPORT_TRAJECTORY)
    start_utc, why = checked_start_utc(read_start_utc(session_dir_of(run.summary, run.path)), _logger_times(run))
    notes = (why,) if why else ()
    s = run.summary
    sess = s.get("session") or {}

    def meta(kind, sol, zone):
        return ExportMeta(
            session=str(sess.get("name") or run.path.name),
            kind=kind,
            solution=sol,
            run_dir=str(run.path),
            pipeline=str(s.get("pipeline")),
            config_sha256=str(s.get("config_sha256") or ""),
            tpos_version=__version__,
            zone=zone,
            start_utc=start_utc,
        )

    if trajectory and (run.trajectory is None or not len(run.trajectory)):
        raise InvalidInputError(f"{run.path.name}: the run has no trajectory.parquet to export")
    if not trajectory and run.targets is not None and len(run.targets):
        kind = "targets"
        sol = choose_solution(run.targets["solution"], solution, f"{run.path.name}/targets.parquet")
        table, zone = combined_targets(run, sol, start_utc)
        m = meta(kind, sol, zone)
        obs = _observer(run, sol)
        writers = {
            "csv": lambda: format_csv(table),
            "geojson": lambda: geojson.targets(table, m, obs),
            "kml": lambda: kml.targets(table, m, obs),
            "gpx": lambda: gpx.targets(table, m, obs),
        }
        rate = None
    elif run.trajectory is not None and len(run.trajectory):
        kind = "trajectory"
        sol = choose_solution(run.trajectory["solution"], solution, f"{run.path.name}/trajectory.parquet")
        rate = rate_hz if rate_hz is not None else (None if fmt == "csv" else MAP_RATE_HZ)
        table, zone = trajectory_table(run.trajectory, sol, rate)
        if rate is not None and len(table) > 1:
            own_hz = 1.0 / float(np.median(np.diff(table["t"].to_numpy(float))))
            if rate > 1.5 * own_hz:  # no epochs to pick between: every one is exported, at the run's own rate
                notes += (f"--rate {rate:g} Hz is above the solution's own rate (about {own_hz:.3g} Hz): every epoch is "
                          "exported",)
                rate = None
        utc = utc_strings(table["t"].to_numpy(float), start_utc, 6)  # to 1 us, as t
        if utc is not None:
            table.insert(1, "time_utc", utc)
        table["solution"] = sol
        m = meta(kind, sol, zone)
        writers = {
            "csv": lambda: format_csv(table),
            "geojson": lambda: geojson.track(table, m),
            "kml": lambda: kml.track(table, m),
            "gpx": lambda: gpx.track(table, m),
        }
    else:
        raise InvalidInputError(
            f"{run.path.name}: the run has no targets and no trajectory to export (run a pipeline that writes solutions)"
        )
    data = writers[fmt]()
    if out is not None and str(out) == "-":
        sys.stdout.buffer.write(data)
        sys.stdout.flush()
        return ExportResult(None, kind, sol, len(table), zone.label, rate, notes)
    path = Path(out) if out is not None else _default_path(run.path, kind, sol, fmt)
    if path.is_dir():
        path = _default_path(path, kind, sol, fmt)
    if not path.parent.is_dir():
        raise InvalidInputError(f"-o {out}: directory {path.parent} does not exist" if out is not None
                                else f"{run.path.name}: the run directory is gone ({path.parent})")
    check_export_path(path, out if out is not None else path, session_dir_of(run.summary, run.path))
    write_atomic(path, lambda p: p.write_bytes(data))
    return ExportResult(path, kind, sol, len(table), zone.label, rate, notes)
