"""Reading a run directory (`tpos process` output) for the report: summary, tables, outage windows."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from tpos_cli.errors import InvalidInputError
from tpos_cli.io.bounded import read_json_bounded
from tpos_cli.io.run_dir import check_summary_shape

TRAJECTORY_REQUIRED = ("t", "lat", "lon", "h", "roll", "pitch", "yaw", "solution")
TARGETS_REQUIRED = ("id", "lat", "lon", "h", "solution")
INNOVATIONS_REQUIRED = ("t", "nis", "accepted")  # plus solution, kind, dof (filled in when absent, see _complete_innovations)
GPS_REQUIRED = ("t", "lat", "lon", "h")

LABELS = ("solution", "kind", "id")
# No quantity tpos writes comes near this; the squares the report and export take of larger values overflow float64.
MAX_RUN_VALUE = 1e150

# size of a measurement of each innovation kind, for tables without `dof` or `nu_*` columns (the
# ranging chain: one scalar range, a north-east fix)
KIND_DOF = {"range": 1.0, "fix": 2.0}
# paper 000 Tables 4-5 list the attitude sources in this order; other solutions follow as found
SOLUTION_ORDER = ("gyro", "lf1", "lf2", "fkf", "forward", "backward", "smoothed")


@dataclass(frozen=True)
class RunData:
    path: Path
    summary: dict
    trajectory: pd.DataFrame | None
    targets: pd.DataFrame | None
    withheld_gps: pd.DataFrame | None
    innovations: pd.DataFrame | None
    outage_windows: np.ndarray  # (K, 2) logger clock: GPS outages of the session and --mask-gps windows, merged
    mask_windows: np.ndarray  # (M, 2) logger clock: the --mask-gps windows alone


def _read(run_dir: Path, name: str, required: tuple[str, ...], columns: tuple[str, ...] | None = None) -> pd.DataFrame | None:
    """A run table (only `columns` of it when given); its label columns (`solution`, `kind`) as
    pandas categoricals, so splitting an hour-long 100 Hz table by solution costs one pass."""
    path = run_dir / name
    if not path.exists():
        return None
    if columns is not None:
        required = tuple(c for c in required if c in columns)
    try:
        import pyarrow as pa
        import pyarrow.compute as pc
        import pyarrow.parquet as pq

        schema = pq.read_schema(path)
        labels = [
            f.name for f in schema if f.name in ("solution", "kind") and (pa.types.is_string(f.type) or pa.types.is_large_string(f.type))
        ]
        names = None if columns is None else [f.name for f in schema if f.name in columns]
        # labels decoded once per row group, not once per row
        table = pq.read_table(path, columns=names, read_dictionary=[c for c in labels if names is None or c in names])
        for col in ("solution", "kind"):
            i = table.schema.get_field_index(col)
            if i >= 0 and (pa.types.is_string(table.schema.field(i).type) or pa.types.is_large_string(table.schema.field(i).type)):
                table = table.set_column(i, col, pc.dictionary_encode(table.column(col)))
        df = table.to_pandas()
    except Exception as exc:  # pyarrow raises several unrelated types for a damaged file
        raise InvalidInputError(f"{run_dir.name}/{name}: not a readable Parquet file ({str(exc).splitlines()[0][:160]})") from exc
    missing = [c for c in required if c not in df.columns]
    if missing:
        raise InvalidInputError(f"{run_dir.name}/{name}: column '{missing[0]}': required column is missing")
    for col in required:  # what tpos writes: numbers, labels in every row (an altered file otherwise)
        if col in LABELS:
            missing_label = np.flatnonzero(df[col].isna().to_numpy())
            if missing_label.size:
                raise InvalidInputError(f"{run_dir.name}/{name}: column '{col}', row {int(missing_label[0]) + 1}: empty; "
                                        "not a file tpos wrote (reprocess the session)")
            continue
        v = df[col].to_numpy()
        if v.dtype.kind not in "fiub":
            raise InvalidInputError(f"{run_dir.name}/{name}: column '{col}': {v.dtype} where tpos writes numbers; "
                                    "not a file tpos wrote (reprocess the session)")
    # numbers: NaN where absent, never inf or a value whose square overflows; in the required columns, and in every
    # float column of the tables the report and export take squares of (positions, sigmas), not the innovations
    for col in df.columns if name != "innovations.parquet" else required:
        v = df[col].to_numpy()
        if v.dtype.kind != "f":
            continue
        with np.errstate(invalid="ignore"):
            bad = np.flatnonzero(np.abs(v) >= MAX_RUN_VALUE)
        if bad.size:
            raise InvalidInputError(f"{run_dir.name}/{name}: column '{col}', row {int(bad[0]) + 1}: {v[bad[0]]} is not a "
                                    "value tpos writes; not a file tpos wrote (reprocess the session)")
    if "solution" in df.columns and not isinstance(df["solution"].dtype, pd.CategoricalDtype):
        df["solution"] = df["solution"].astype(str).astype("category")
    return df


def _sorted_by_solution_time(df: pd.DataFrame) -> pd.DataFrame:
    """Rows grouped by solution (first-appearance order) with time increasing in each group; the
    chains write them that way, so this is one check and usually no sort."""
    codes = df["solution"].cat.codes.to_numpy()
    t = df["t"].to_numpy(float)
    same = codes[1:] == codes[:-1]
    if np.count_nonzero(~same) == len(np.unique(codes)) - 1 and np.all(t[1:][same] >= t[:-1][same]):
        return df.reset_index(drop=True)
    first = pd.unique(codes)
    rank = np.empty(codes.max() + 1, dtype=np.int64)
    rank[first] = np.arange(first.size)
    return df.iloc[np.lexsort((t, rank[codes]))].reset_index(drop=True)


def _require_positions(run_dir: Path, traj: pd.DataFrame) -> None:
    """Every solution tpos writes has epochs with a position: one without is an altered file, which
    the report cannot place (InvalidInputError, one line)."""
    finite = np.isfinite(traj[["lat", "lon", "h"]].to_numpy(float)).all(axis=1)
    codes = traj["solution"].cat.codes.to_numpy()
    has = np.bincount(codes[finite], minlength=len(traj["solution"].cat.categories)) > 0
    present = np.bincount(codes, minlength=has.size) > 0
    for k in np.flatnonzero(present & ~has):
        name = traj["solution"].cat.categories[k]
        raise InvalidInputError(f"{run_dir.name}/trajectory.parquet: column 'lat': solution '{name}' has no epoch with a "
                                "position (lat, lon, h not all numbers in any of its rows); not a file tpos wrote "
                                "(reprocess the session)")


def _complete_innovations(df: pd.DataFrame | None) -> pd.DataFrame | None:
    """Fill the optional innovation columns: `solution` and `kind` "unspecified", and `dof` as the
    number of finite `nu_*` components of each row, else the size of the measurement kind
    (`KIND_DOF`), else NaN (no chi-square bounds)."""
    if df is None:
        return None
    df = df.copy()
    for c in ("solution", "kind"):
        df[c] = df[c].astype(str).astype("category") if c in df.columns else pd.Categorical(["unspecified"] * len(df))
    if "dof" not in df.columns:
        nu = [c for c in df.columns if c.startswith("nu_")]
        if nu:
            dof = np.isfinite(df[nu].to_numpy(float)).sum(axis=1).astype(float)
        else:  # the measurement's own size, where its kind says it
            dof = df["kind"].astype(str).map(KIND_DOF).to_numpy(float)
        df["dof"] = np.where(dof > 0, dof, np.nan)
    return df


def windows(value, where: str) -> np.ndarray:
    """[[t0, t1], ...] from summary.json (lists of pairs); (K, 2) float, sorted by start."""
    if value is None:
        return np.empty((0, 2))
    try:
        a = np.asarray(value, dtype=float).reshape(-1, 2)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"summary.json: {where}: expected a list of [t0, t1] pairs, got {value!r}"[:300]) from exc
    return a[np.argsort(a[:, 0], kind="stable")] if a.size else np.empty((0, 2))


def merge_windows(*arrays: np.ndarray) -> np.ndarray:
    """Union of intervals, (K, 2) sorted and non-overlapping."""
    a = np.concatenate([np.asarray(x, dtype=float).reshape(-1, 2) for x in arrays])
    if a.size == 0:
        return np.empty((0, 2))
    a = a[np.argsort(a[:, 0], kind="stable")]
    out = [list(a[0])]
    for s, e in a[1:]:
        if s <= out[-1][1]:
            out[-1][1] = max(out[-1][1], e)
        else:
            out.append([s, e])
    return np.asarray(out)


def load_run(run_dir: Path, *, trajectory_columns_if_targets: tuple[str, ...] | None = None) -> RunData:
    """Read a run directory; raises InvalidInputError when it is not one. `trajectory_columns_if_targets`:
    when targets.parquet holds a target, read only these of trajectory.parquet (a target export needs
    its times and positions, not an hour of attitudes and sigmas); otherwise the whole table."""
    run_dir = Path(run_dir)
    sp = run_dir / "summary.json"
    if not run_dir.is_dir() or not sp.exists():
        raise InvalidInputError(f"{run_dir}: not a run directory (no summary.json); run `tpos process` first")
    # read once, as untrusted (bounded: a FIFO or a deeply nested file must not block or crash a report),
    # and of the shape tpos writes before any code reads into it
    summary = read_json_bounded(sp, f"{run_dir.name}/summary.json")
    check_summary_shape(summary, f"{run_dir.name}/summary.json")
    tgts = _read(run_dir, "targets.parquet", TARGETS_REQUIRED)
    if tgts is not None:
        tgts["id"] = tgts["id"].astype(str)
    columns = trajectory_columns_if_targets if tgts is not None and len(tgts) else None
    traj = _read(run_dir, "trajectory.parquet", TRAJECTORY_REQUIRED, columns)
    withheld = _read(run_dir, "withheld_gps.parquet", GPS_REQUIRED)
    innov = _complete_innovations(_read(run_dir, "innovations.parquet", INNOVATIONS_REQUIRED))
    if traj is not None and len(traj):
        traj = _sorted_by_solution_time(traj)
        _require_positions(run_dir, traj)
    outages = windows(summary.get("gps_outages"), "gps_outages")
    mask = windows(summary.get("mask_gps"), "mask_gps")
    return RunData(run_dir, summary, traj, tgts, withheld, innov, merge_windows(outages, mask), mask)


def session_dir_of(summary: dict, run_dir: Path) -> Path | None:
    """The run's session directory from summary.json `session.path` (absolute, or relative to the
    current directory, the run directory's parent or the run directory), or None if not found."""
    raw = (summary.get("session") or {}).get("path")
    if not raw:
        return None
    p = Path(raw)
    for cand in [p] if p.is_absolute() else [Path.cwd() / p, Path(run_dir).parent / p, Path(run_dir) / p]:
        if cand.is_dir():
            return cand
    return None


def ordered_solutions(names) -> list[str]:
    """Solution names, known ones in paper order first, the rest in order of appearance."""
    seen = list(dict.fromkeys(str(n) for n in names))
    known = [s for s in SOLUTION_ORDER if s in seen]
    return known + [s for s in seen if s not in known]
