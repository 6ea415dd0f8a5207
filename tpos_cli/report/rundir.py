"""Reading a run directory (`tpos process` output) for the report: summary, tables, outage windows."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from tpos_cli.errors import InvalidInputError
from tpos_cli.io.bounded import read_json_bounded
from tpos_cli.io.columns import Columns, as_text, first_appearance_codes, from_arrow, no_value
from tpos_cli.io.run_dir import check_summary_shape

if TYPE_CHECKING:
    import pandas as pd

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
    trajectory: Columns | pd.DataFrame | None  # Columns from `load_run(..., frames=False)` (the report), else DataFrames
    targets: pd.DataFrame | None
    withheld_gps: Columns | pd.DataFrame | None
    innovations: Columns | pd.DataFrame | None
    outage_windows: np.ndarray  # (K, 2) logger clock: GPS outages of the session and --mask-gps windows, merged
    mask_windows: np.ndarray  # (M, 2) logger clock: the --mask-gps windows alone


def _read(run_dir: Path, name: str, required: tuple[str, ...], columns: tuple[str, ...] | None = None, frame: bool = True):
    """A run table (only `columns` of it when given): a DataFrame whose label columns (`solution`,
    `kind`) are pandas categoricals, so splitting an hour-long 100 Hz table by solution costs one
    pass; or, with `frame` False, `Columns` read without pandas (labels: object arrays of str, each
    distinct value decoded once). The same checks either way (`_check_run_table`)."""
    path = run_dir / name
    if not path.exists():
        return None
    if columns is not None:
        required = tuple(c for c in required if c in columns)
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq

        if frame:
            import pandas as pd
            import pyarrow.compute as pc

            schema = pq.read_schema(path)
            labels = [f.name for f in schema
                      if f.name in ("solution", "kind") and (pa.types.is_string(f.type) or pa.types.is_large_string(f.type))]
            names = None if columns is None else [f.name for f in schema if f.name in columns]
            # labels decoded once per row group, not once per row
            table = pq.read_table(path, columns=names, read_dictionary=[c for c in labels if names is None or c in names])
            for col in ("solution", "kind"):
                i = table.schema.get_field_index(col)
                if i >= 0 and (pa.types.is_string(table.schema.field(i).type) or pa.types.is_large_string(table.schema.field(i).type)):
                    table = table.set_column(i, col, pc.dictionary_encode(table.column(col)))
            df = table.to_pandas()
            cols = {c: df[c].to_numpy() for c in df.columns}
        else:
            # not pq.read_table: its dataset reader imports pandas; text read as dictionaries: each label decoded once
            # per row group, and no pyarrow.compute (~0.06 s of imports) to encode them
            schema = pq.read_schema(path)
            text = [f.name for f in schema if pa.types.is_string(f.type) or pa.types.is_large_string(f.type)]
            with pq.ParquetFile(path, read_dictionary=text) as pf:
                names = None if columns is None else [c for c in pf.schema_arrow.names if c in columns]
                df = from_arrow(pf.read(columns=names))
            cols = {c: df[c] for c in df.columns}
    except Exception as exc:  # pyarrow raises several unrelated types for a damaged file
        raise InvalidInputError(f"{run_dir.name}/{name}: not a readable Parquet file ({str(exc).splitlines()[0][:160]})") from exc
    _check_run_table(run_dir, name, required, cols)
    if frame and "solution" in df.columns and not isinstance(df["solution"].dtype, pd.CategoricalDtype):
        df["solution"] = df["solution"].astype(str).astype("category")
    return df


def _check_run_table(run_dir: Path, name: str, required: tuple[str, ...], cols: dict[str, np.ndarray]) -> None:
    """What tpos writes: the required columns, numbers in them and labels in every row; no value a
    square of overflows (InvalidInputError naming column and row otherwise: an altered file)."""
    missing = [c for c in required if c not in cols]
    if missing:
        raise InvalidInputError(f"{run_dir.name}/{name}: column '{missing[0]}': required column is missing")
    for col in required:  # what tpos writes: numbers, labels in every row (an altered file otherwise)
        v = cols[col]
        if col in LABELS:
            missing_label = np.flatnonzero(no_value(v))
            if missing_label.size:
                raise InvalidInputError(f"{run_dir.name}/{name}: column '{col}', row {int(missing_label[0]) + 1}: empty; "
                                        "not a file tpos wrote (reprocess the session)")
            continue
        if v.dtype.kind not in "fiub":
            raise InvalidInputError(f"{run_dir.name}/{name}: column '{col}': {v.dtype} where tpos writes numbers; "
                                    "not a file tpos wrote (reprocess the session)")
    # numbers: NaN where absent, never inf or a value whose square overflows; in the required columns, and in every
    # float column of the tables the report and export take squares of (positions, sigmas), not the innovations
    for col in cols if name != "innovations.parquet" else required:
        v = cols[col]
        if v.dtype.kind != "f":
            continue
        with np.errstate(invalid="ignore"):
            bad = np.flatnonzero(np.abs(v) >= MAX_RUN_VALUE)
        if bad.size:
            raise InvalidInputError(f"{run_dir.name}/{name}: column '{col}', row {int(bad[0]) + 1}: {v[bad[0]]} is not a "
                                    "value tpos writes; not a file tpos wrote (reprocess the session)")


def _solution_codes(t) -> tuple[np.ndarray, list[str]]:
    """(code of each row's solution, the solution names in order of first appearance)."""
    if isinstance(t, Columns):
        codes, names = first_appearance_codes(t["solution"])
        return codes, [str(s) for s in names]
    codes = t["solution"].cat.codes.to_numpy()
    return codes, [str(s) for s in t["solution"].cat.categories]


def _sorted_by_solution_time(df):
    """Rows grouped by solution (first-appearance order) with time increasing in each group; the
    chains write them that way, so this is one check and usually no sort."""
    codes, _ = _solution_codes(df)
    t = np.asarray(df["t"], dtype=float)
    same = codes[1:] == codes[:-1]
    if np.count_nonzero(~same) == len(np.unique(codes)) - 1 and np.all(t[1:][same] >= t[:-1][same]):
        return df if isinstance(df, Columns) else df.reset_index(drop=True)
    _, at = np.unique(codes, return_index=True)
    first = codes[np.sort(at)]  # codes in order of first appearance
    rank = np.empty(codes.max() + 1, dtype=np.int64)
    rank[first] = np.arange(first.size)
    order = np.lexsort((t, rank[codes]))
    return df.take(order) if isinstance(df, Columns) else df.iloc[order].reset_index(drop=True)


def _require_positions(run_dir: Path, traj) -> None:
    """Every solution tpos writes has epochs with a position: one without is an altered file, which
    the report cannot place (InvalidInputError, one line)."""
    finite = np.isfinite(np.column_stack([np.asarray(traj[c], dtype=float) for c in ("lat", "lon", "h")])).all(axis=1)
    codes, names = _solution_codes(traj)
    has = np.bincount(codes[finite], minlength=len(names)) > 0
    present = np.bincount(codes, minlength=has.size) > 0
    for k in np.flatnonzero(present & ~has):
        raise InvalidInputError(f"{run_dir.name}/trajectory.parquet: column 'lat': solution '{names[k]}' has no epoch with a "
                                "position (lat, lon, h not all numbers in any of its rows); not a file tpos wrote "
                                "(reprocess the session)")


def _complete_innovations(df):
    """Fill the optional innovation columns: `solution` and `kind` "unspecified", and `dof` as the
    number of finite `nu_*` components of each row, else the size of the measurement kind
    (`KIND_DOF`), else NaN (no chi-square bounds)."""
    if df is None:
        return None
    if isinstance(df, Columns):
        cols = {c: df[c] for c in df.columns}
        for c in ("solution", "kind"):
            if c not in cols:
                cols[c] = np.full(len(df), "unspecified", dtype=object)
            else:
                cols[c] = as_text(cols[c])
        get = cols.__getitem__
    else:
        import pandas as pd

        df = df.copy()
        for c in ("solution", "kind"):
            df[c] = df[c].astype(str).astype("category") if c in df.columns else pd.Categorical(["unspecified"] * len(df))
        get = df.__getitem__
    names = df.columns
    if "dof" not in names:
        nu = [c for c in names if c.startswith("nu_")]
        if nu:
            dof = np.isfinite(np.column_stack([np.asarray(get(c), dtype=float) for c in nu])).sum(axis=1).astype(float)
        else:  # the measurement's own size, where its kind says it
            dof = np.array([KIND_DOF.get(str(k), np.nan) for k in np.asarray(get("kind")).tolist()], dtype=float)
        dof = np.where(dof > 0, dof, np.nan)
        if isinstance(df, Columns):
            cols["dof"] = dof
        else:
            df["dof"] = dof
    return Columns(cols, len(df)) if isinstance(df, Columns) else df


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


def load_run(run_dir: Path, *, trajectory_columns_if_targets: tuple[str, ...] | None = None, frames: bool = True) -> RunData:
    """Read a run directory; raises InvalidInputError when it is not one. `trajectory_columns_if_targets`:
    when targets.parquet holds a target, read only these of trajectory.parquet (a target export needs
    its times and positions, not an hour of attitudes and sigmas); otherwise the whole table.
    `frames` False: trajectory, withheld fixes and innovations as `Columns`, read without pandas (the
    report; targets.parquet, which only target and ranging runs write, stays a DataFrame)."""
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
    traj = _read(run_dir, "trajectory.parquet", TRAJECTORY_REQUIRED, columns, frames)
    if isinstance(traj, Columns) and traj["solution"].dtype != object:  # an altered file's numbers: labels as pandas makes them
        traj = Columns({c: as_text(traj[c]) if c == "solution" else traj[c] for c in traj.columns}, len(traj))
    withheld = _read(run_dir, "withheld_gps.parquet", GPS_REQUIRED, frame=frames)
    innov = _complete_innovations(_read(run_dir, "innovations.parquet", INNOVATIONS_REQUIRED, frame=frames))
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
