"""Errors of each solution of a run against the chosen truth, and the accuracy table.

The accuracy table (`accuracy.parquet`) is long: one row per (solution, target, segment, quantity)
with the statistics of `metrics.error_stats`. Segments: `all`; `outage` / `gps` (inside / outside
the GPS outages and `--mask-gps` windows); `outage_k` per window (paper 003's outage errors);
`movement` (truth's movement phase, BROAD); `withheld` (GPS truth: only the fixes withheld from the
run, the independent ones). Quantities: `pos_3d_m`, `pos_h_m`, `pos_v_m` (up), `pos_n_m`, `pos_e_m`,
and with attitude truth `roll_deg`, `pitch_deg`, `yaw_deg` (wrap-aware), `att_deg` (total angle).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from tpos_cli.frames.geodetic import ecef_to_ned_dcm, lla_to_ecef
from tpos_cli.frames.rotation import euler_to_dcm
from tpos_cli.io.columns import Columns, from_records
from tpos_cli.report import metrics
from tpos_cli.report.qc import Series, solution_series
from tpos_cli.report.rundir import RunData, ordered_solutions
from tpos_cli.report.truth import (
    ReportTruth,
    interpolate_attitude,
    interpolate_flag,
    interpolate_positions,
)
from tpos_cli.timebase import in_intervals

if TYPE_CHECKING:
    import pandas as pd

ROW_KEYS = ("solution", "target", "segment", "quantity")
COLUMNS = ROW_KEYS + metrics.STAT_FIELDS + ("cep", "ce90")
POS_QUANTITIES = ("pos_3d_m", "pos_h_m", "pos_v_m", "pos_n_m", "pos_e_m")
ATT_QUANTITIES = ("roll_deg", "pitch_deg", "yaw_deg", "att_deg")


@dataclass(frozen=True)
class SolutionErrors:
    """Per-epoch errors of one trajectory solution (NaN where truth does not cover the epoch)."""

    solution: str
    t: np.ndarray
    lla: np.ndarray
    rpy_deg: np.ndarray
    truth_lla: np.ndarray
    truth_rpy_deg: np.ndarray | None
    err_ned_m: np.ndarray
    att_err_deg: dict[str, np.ndarray] | None
    outage_index: np.ndarray  # -1 outside windows, else index into RunData.outage_windows
    in_outage: np.ndarray
    movement: np.ndarray | None
    independent: np.ndarray


@dataclass(frozen=True)
class Accuracy:
    table: Columns  # `COLUMNS`, one row per statistic (accuracy.parquet); `.to_pandas()` for a DataFrame
    solutions: tuple[SolutionErrors, ...]
    targets: pd.DataFrame | None  # one row per (solution, target shot) with errors and sigmas
    paper_tables: dict[str, Columns]
    # the trajectory segment whose truth is independent of the run: `all`, `withheld` (a truth that holds
    # the GPS fixes the run used: only the fixes withheld by --mask-gps), or None (none is independent)
    independent_segment: str | None = "all"


def _stat_row(solution, target, segment, quantity, err) -> dict:
    """One accuracy-table row: the statistics of `err`, or `err` itself when it holds them (a dict)."""
    s = err if isinstance(err, dict) else metrics.error_stats(err).as_dict()
    horiz = quantity == "pos_h_m"
    return {
        "solution": solution,
        "target": target,
        "segment": segment,
        "quantity": quantity,
        **s,
        "cep": s["p50"] if horiz else np.nan,  # empirical CEP: median horizontal error
        "ce90": s["p90"] if horiz else np.nan,
    }


@dataclass(frozen=True)
class TruthAt:
    """The truth at one set of epochs, with what every solution's errors need, computed once for
    all the solutions that share those epochs (the target chain's six solutions do)."""

    t: np.ndarray
    lla: np.ndarray
    rpy_deg: np.ndarray | None
    r_e: np.ndarray
    C_ne: np.ndarray
    quat: np.ndarray | None  # (4, N) scalar-first quaternions of the truth attitude
    movement: np.ndarray | None  # truth's movement phase at the epochs (BROAD)
    independent: np.ndarray  # truth independent of the run at the epochs (withheld GPS fixes)

    @classmethod
    def at(cls, tt, t: np.ndarray) -> TruthAt:
        lla = interpolate_positions(tt.t, tt.lla, t, tt.max_gap_s)
        rpy = interpolate_attitude(tt.t, tt.rpy_deg, t, tt.max_gap_s) if tt.rpy_deg is not None else None
        quat = metrics.euler_to_quat(rpy) if rpy is not None else None
        movement = interpolate_flag(tt.t, tt.movement, t, tt.max_gap_s) if tt.movement is not None else None
        indep = interpolate_flag(tt.t, tt.independent.astype(float), t, tt.max_gap_s)
        return cls(t, lla, rpy, lla_to_ecef(lla), ecef_to_ned_dcm(lla[:, 0], lla[:, 1]), quat, movement, indep)


def solution_errors(
    run: RunData, truth: ReportTruth, series: Series, truth_at: TruthAt | None = None, previous: SolutionErrors | None = None
) -> SolutionErrors:
    """Errors of one trajectory solution against `truth.trajectory` at its own epochs (`truth_at`
    when it was built for exactly these epochs). The position errors of `previous`, a solution at
    the same epochs, are shared when the positions are the same (a tripod log's attitude solutions
    all hold the one surveyed point) and no lever arm makes them depend on the attitude."""
    t, lla, rpy = series.t, series.lla, series.rpy_deg
    tt = truth.trajectory
    if truth_at is None or not np.array_equal(truth_at.t, t):
        truth_at = TruthAt.at(tt, t)
    truth_lla, truth_rpy = truth_at.lla, truth_at.rpy_deg
    offset = None
    lever = bool(np.any(tt.lever_arm_b_m != 0.0))
    if lever:
        # truth is the GPS antenna: move the solution from the IMU point to it, r_a = r + C_nb l_b
        C_nb = euler_to_dcm(*np.radians(rpy).T)
        offset = C_nb @ tt.lever_arm_b_m
    same_epochs = previous is not None and (previous.t is t or np.array_equal(previous.t, t))
    if not lever and same_epochs and np.array_equal(previous.lla, lla, equal_nan=True):
        err = previous.err_ned_m
    else:
        err = metrics.position_errors_ned(lla, truth_lla, offset, truth_r_e=truth_at.r_e, truth_C_ne=truth_at.C_ne)
    att = metrics.attitude_errors_deg(rpy, truth_rpy, truth_quat=truth_at.quat) if truth_rpy is not None else None
    idx = np.full(t.size, -1)
    for k, w in enumerate(run.outage_windows):
        idx[in_intervals(t, w[None, :])] = k  # [start, end), as timebase defines outages
    in_out = (idx >= 0) | series.outage  # and the chain's own outage flag, when it wrote one
    return SolutionErrors(series.name, t, lla, rpy, truth_lla, truth_rpy, err, att, idx, in_out, truth_at.movement, truth_at.independent)


class _StatsMemo:
    """Statistics of position errors already computed, for solutions that share them (the same
    error array and segment mask give the same statistics)."""

    def __init__(self) -> None:
        self._by_err: dict[int, tuple[np.ndarray, dict, list]] = {}

    def split(self, err_ned_m: np.ndarray) -> dict[str, np.ndarray]:
        hit = self._by_err.get(id(err_ned_m))
        if hit is None:
            hit = self._by_err[id(err_ned_m)] = (err_ned_m, metrics.split_position_errors(err_ned_m), [])
        return dict(hit[1])

    def stats(self, err_ned_m: np.ndarray, segment: np.ndarray, quantity: str, e: np.ndarray) -> dict:
        done = self._by_err[id(err_ned_m)][2] if quantity in POS_QUANTITIES else None
        if done is not None:
            for mask, q, st in done:
                if q == quantity and (mask is segment or np.array_equal(mask, segment)):
                    return st
        st = metrics.error_stats(np.where(segment, e, np.nan)).as_dict()
        if done is not None:
            done.append((segment, quantity, st))
        return st


def _trajectory_rows(run: RunData, se: SolutionErrors, gps_truth: bool, memo: _StatsMemo | None = None) -> list[dict]:
    memo = memo if memo is not None else _StatsMemo()
    series = memo.split(se.err_ned_m)
    if se.att_err_deg is not None:
        series.update(se.att_err_deg)
    segments = {"all": np.ones(se.t.size, dtype=bool)}
    if len(run.outage_windows) or se.in_outage.any():
        segments["outage"] = se.in_outage
        segments["gps"] = ~se.in_outage
    for k in range(len(run.outage_windows)):
        segments[f"outage_{k + 1}"] = se.outage_index == k
    if se.movement is not None:
        segments["movement"] = se.movement
    if gps_truth and len(run.mask_windows):
        segments["withheld"] = se.independent
    rows = []
    for seg, m in segments.items():
        for q, e in series.items():
            rows.append(_stat_row(se.solution, "", seg, q, memo.stats(se.err_ned_m, m, q, e)))
    return rows


def target_errors(run: RunData, truth: ReportTruth) -> pd.DataFrame | None:
    """One row per targets.parquet row whose id has surveyed truth: NEU errors, sigmas, predicted CEP."""
    if run.targets is None or truth.targets is None:
        return None
    import pandas as pd  # here: only a run with targets has them (targets.parquet is read with pandas)

    lut = {i: k for k, i in enumerate(truth.targets.ids)}
    df = run.targets[run.targets["id"].isin(lut.keys())].reset_index(drop=True)
    if df.empty:
        return None
    tl = truth.targets.lla[[lut[i] for i in df["id"]]]
    err = metrics.position_errors_ned(df[["lat", "lon", "h"]].to_numpy(float), tl)
    out = pd.DataFrame(
        {
            "solution": df["solution"].astype(str),
            "id": df["id"].astype(str),
            "t_start": df["t_start"].to_numpy(float) if "t_start" in df else np.nan,
            "range_m": df["range_m"].to_numpy(float) if "range_m" in df else np.nan,
            "err_n_m": err[:, 0],
            "err_e_m": err[:, 1],
            "err_u_m": -err[:, 2],
            "err_h_m": np.hypot(err[:, 0], err[:, 1]),
            "err_3d_m": np.linalg.norm(err, axis=1),
        }
    )
    for c in ("sigma_n", "sigma_e", "sigma_u"):
        out[c + "_m"] = df[c].to_numpy(float) if c in df else np.nan
    out["cep_pred_m"] = metrics.cep_from_sigmas(out["sigma_n_m"].to_numpy(float), out["sigma_e_m"].to_numpy(float))
    return out


def _target_rows(te: pd.DataFrame) -> list[dict]:
    rows = []
    series = {
        "pos_3d_m": "err_3d_m",
        "pos_h_m": "err_h_m",
        "pos_v_m": "err_u_m",
        "pos_n_m": "err_n_m",
        "pos_e_m": "err_e_m",
    }
    for sol in ordered_solutions(te["solution"]):
        d = te[te["solution"] == sol]
        for tid in ["all"] + list(dict.fromkeys(d["id"])):
            dd = d if tid == "all" else d[d["id"] == tid]
            for q, c in series.items():
                rows.append(_stat_row(sol, tid, "all", q, dd[c].to_numpy(float)))
    return rows


class _Lookup:
    """Cells of the accuracy table by (solution, target, segment, quantity): one pass to index it,
    then dictionary look-ups (the paper tables read a few hundred cells)."""

    def __init__(self, table: Columns) -> None:
        keys = zip(*([str(v) for v in table[k].tolist()] for k in ROW_KEYS))
        self._row = {k: i for i, k in reversed(list(enumerate(keys)))}  # the first row of a key wins
        self._table = table

    def __call__(self, solution, target, segment, quantity, stat) -> float:
        i = self._row.get((solution, target, segment, quantity))
        return float("nan") if i is None else float(self._table[stat][i])


def _table(columns: dict[str, list]) -> Columns:
    """A table of equally long lists by name, dtypes as pandas infers them (`io.columns.from_records`)."""
    names = list(columns)
    return from_records([dict(zip(names, row)) for row in zip(*columns.values())], names)


def paper_tables(run: RunData, table: Columns, kind: str) -> dict[str, Columns]:
    """The accuracy table reshaped like the papers' tables, where the run reproduces one."""
    out: dict[str, Columns] = {}
    _get = _Lookup(table)
    tgt = table.take(table["target"] == "all")
    if len(tgt):
        sols = ordered_solutions(tgt["solution"])
        out["paper000_table4"] = _table(
            {
                "solution": sols,
                "mean_m": [_get(s, "all", "all", "pos_3d_m", "mean") for s in sols],
                "sd_m": [_get(s, "all", "all", "pos_3d_m", "sd") for s in sols],
                "n": [_get(s, "all", "all", "pos_3d_m", "n") for s in sols],
            }
        )
    traj = table.take(table["target"] == "")
    if len(traj) and kind == "ranging":
        sols = ordered_solutions(traj["solution"])
        g = lambda s, q, st: _get(s, "", "all", q, st)  # noqa: E731
        out["paper002_table1"] = _table(
            {
                "solution": sols,
                "x_min_m": [g(s, "pos_e_m", "min") for s in sols],
                "x_max_m": [g(s, "pos_e_m", "max") for s in sols],
                "y_min_m": [g(s, "pos_n_m", "min") for s in sols],
                "y_max_m": [g(s, "pos_n_m", "max") for s in sols],
                "x_var_m2": [g(s, "pos_e_m", "sd") ** 2 for s in sols],
                "y_var_m2": [g(s, "pos_n_m", "sd") ** 2 for s in sols],
                "max_m": [g(s, "pos_h_m", "max") for s in sols],
                "average_m": [g(s, "pos_h_m", "mean") for s in sols],
            }
        )
    if len(traj) and len(run.outage_windows):
        rows = []
        for k, (a, b) in enumerate(run.outage_windows):
            for s in ordered_solutions(traj["solution"]):
                seg = f"outage_{k + 1}"
                n = _get(s, "", seg, "pos_h_m", "n")
                if not n:
                    continue
                rows.append(
                    {
                        "outage": k + 1,
                        "t0": float(a),
                        "t1": float(b),
                        "duration_s": float(b - a),
                        "solution": s,
                        "rms_h_m": _get(s, "", seg, "pos_h_m", "rms"),
                        "max_h_m": _get(s, "", seg, "pos_h_m", "max"),
                        "rms_v_m": _get(s, "", seg, "pos_v_m", "rms"),
                        "max_3d_m": _get(s, "", seg, "pos_3d_m", "max"),
                    }
                )
        if rows:
            out["paper003_outages"] = from_records(rows, list(rows[0]))
    return out


def compute_accuracy(run: RunData, truth: ReportTruth | None, kind: str = "", series: dict[str, Series] | None = None) -> Accuracy:
    """All error statistics of a run against `truth` (see module docstring); empty without truth."""
    rows: list[dict] = []
    sols: list[SolutionErrors] = []
    independent_segment: str | None = "all"
    if truth is not None and run.trajectory is not None and truth.trajectory is not None:
        series = series if series is not None else solution_series(run.trajectory)
        gps_truth = not truth.trajectory.independent.all()  # GPS fixes, or a truth that holds the fixes the run used
        if gps_truth:
            independent_segment = "withheld" if len(run.mask_windows) and truth.trajectory.independent.any() else None
        truth_at = None
        memo = _StatsMemo()
        for s in ordered_solutions(series):
            if truth_at is None or not np.array_equal(truth_at.t, series[s].t):
                truth_at = TruthAt.at(truth.trajectory, series[s].t)
            previous = sols[-1] if sols else None
            se = solution_errors(run, truth, series[s], truth_at, previous)
            sols.append(se)
            rows += _trajectory_rows(run, se, gps_truth, memo)
    te = target_errors(run, truth) if truth is not None else None
    if te is not None:
        rows += _target_rows(te)
    table = from_records(rows, COLUMNS)
    table = Columns({c: table[c].astype(np.int64) if c == "n" else table[c] for c in COLUMNS}, len(table))
    return Accuracy(table, tuple(sols), te, paper_tables(run, table, kind), independent_segment)
