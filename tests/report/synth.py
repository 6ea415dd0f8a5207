"""Small synthetic sessions and run directories with errors chosen so the statistics are known by hand.

Truth: the body moves north at 1 m/s from ORIGIN for 20 s, sampled at 1 Hz (t = T0 + 0..20 on the
logger clock). A solution is the truth displaced by a chosen NED offset per epoch, placed exactly with
`ned_to_lla` about each truth point, so `position_errors_ned` must give the offsets back.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd

from tpos_cli.frames.geodetic import ned_to_lla
from tpos_cli.session import session_file_hashes

ORIGIN = np.array([45.5, -73.6, 50.0])
T0 = 1000.0  # logger clock of the first IMU sample
DURATION_S = 20.0


def truth_ned(t_rel):
    """Truth NED about ORIGIN at relative times: 1 m/s north."""
    t_rel = np.asarray(t_rel, dtype=float)
    return np.column_stack([t_rel, np.zeros_like(t_rel), np.zeros_like(t_rel)])


def truth_lla(t_rel):
    return ned_to_lla(truth_ned(t_rel), ORIGIN)


def truth_rpy_deg(t_rel):
    """Yaw sweeps through north (358 -> 2 deg and beyond): wrap-aware errors and SLERP are tested."""
    t_rel = np.asarray(t_rel, dtype=float)
    yaw = (350.0 + 1.0 * t_rel) % 360.0
    return np.column_stack([2.0 + 0.0 * t_rel, -1.0 + 0.0 * t_rel, yaw])


def displaced(lla_points, offsets_ned_m):
    """Points moved by NED offsets resolved at each point (exact inverse of the error definition)."""
    return np.array([ned_to_lla(o[None, :], p)[0] for p, o in zip(lla_points, np.asarray(offsets_ned_m, float))])


def write_session(
    d: Path,
    *,
    kind: str = "drive",
    truth: bool = True,
    truth_nan_rows=(),
    attitude: bool = True,
    movement: bool = False,
    gps: bool = False,
    gps_lever_m=None,
    gps_error_ned_m=(0.0, 0.0, 0.0),
    targets: list[tuple[str, np.ndarray, str]] | None = None,
) -> Path:
    """A valid session directory (IMU at 10 Hz, static, FRD). With `gps`, fixes at the truth's
    rows displaced by `gps_error_ned_m` (zero: the truth is the receiver's own solution)."""
    d.mkdir(parents=True, exist_ok=True)
    toml = [
        "[session]",
        'name = "synthetic_report"',
        f'kind = "{kind}"',
        "[imu]",
        'axes = "FRD"',
        "rate_hz = 10.0",
    ]
    if gps_lever_m is not None:
        toml += ["[gps]", f"lever_arm_m = [{', '.join(str(float(v)) for v in gps_lever_m)}]"]
    (d / "session.toml").write_text("\n".join(toml) + "\n")
    t = T0 + np.arange(0.0, DURATION_S + 1e-9, 0.1)
    imu = pd.DataFrame({"t": t, "gyro_x": 0.0, "gyro_y": 0.0, "gyro_z": 0.0, "acc_x": 0.0, "acc_y": 0.0, "acc_z": -9.8})
    imu.to_csv(d / "imu.csv", index=False)
    tr = np.arange(0.0, DURATION_S + 1e-9, 1.0)
    if truth:
        lla = truth_lla(tr)
        df = pd.DataFrame({"t": T0 + tr, "lat": lla[:, 0], "lon": lla[:, 1], "h": lla[:, 2]})
        if attitude:
            rpy = truth_rpy_deg(tr)
            df["roll"], df["pitch"], df["yaw"] = rpy[:, 0], rpy[:, 1], rpy[:, 2]
        if movement:
            df["movement"] = (tr >= 5.0).astype(float)
        for i in truth_nan_rows:
            df.loc[i, ["lat", "lon", "h"] + (["roll", "pitch", "yaw"] if attitude else [])] = np.nan
        df.to_csv(d / "truth.csv", index=False)
    if gps:
        lla = displaced(truth_lla(tr), np.tile(np.asarray(gps_error_ned_m, dtype=float), (tr.size, 1)))
        pd.DataFrame(
            {"t": T0 + tr, "lat": lla[:, 0], "lon": lla[:, 1], "h": lla[:, 2], "fix": 2, "sigma_n": 1.0, "sigma_e": 1.0, "sigma_u": 2.0}
        ).to_csv(d / "gps.csv", index=False)
    if targets:
        pd.DataFrame(
            {
                "id": [n for n, _, _ in targets],
                "lat": [p[0] for _, p, _ in targets],
                "lon": [p[1] for _, p, _ in targets],
                "h": [p[2] for _, p, _ in targets],
                "role": [r for _, _, r in targets],
            }
        ).to_csv(d / "targets.csv", index=False)
    return d


def trajectory_rows(solution: str, t_rel, offsets_ned_m, rpy_err_deg=(0.0, 0.0, 0.0), sigma=None) -> pd.DataFrame:
    """Trajectory rows of one solution: truth displaced by `offsets_ned_m`, attitude truth + error."""
    t_rel = np.asarray(t_rel, dtype=float)
    lla = displaced(truth_lla(t_rel), np.broadcast_to(np.asarray(offsets_ned_m, float), (t_rel.size, 3)))
    rpy = truth_rpy_deg(t_rel) + np.asarray(rpy_err_deg, float)
    rpy[:, 2] = rpy[:, 2] % 360.0
    df = pd.DataFrame(
        {
            "t": T0 + t_rel,
            "lat": lla[:, 0],
            "lon": lla[:, 1],
            "h": lla[:, 2],
            "vn": 1.0,
            "ve": 0.0,
            "vd": 0.0,
            "roll": rpy[:, 0],
            "pitch": rpy[:, 1],
            "yaw": rpy[:, 2],
            "solution": solution,
        }
    )
    if sigma is not None:
        for c, v in zip(("sigma_n", "sigma_e", "sigma_d"), sigma):
            df[c] = float(v)
    return df


def _session_kind(session_dir: Path) -> str:
    """`[session] kind` of a session directory this module wrote."""
    return tomllib.loads((Path(session_dir) / "session.toml").read_text())["session"]["kind"]


def write_run(
    d: Path,
    session_dir: Path,
    trajectory: pd.DataFrame | None = None,
    targets: pd.DataFrame | None = None,
    *,
    gps_outages=(),
    mask_gps=(),
    withheld: pd.DataFrame | None = None,
    innovations: pd.DataFrame | None = None,
    pipeline: str = "synthetic",
) -> Path:
    """A run directory as `tpos process` writes it (docs/architecture.md)."""
    d.mkdir(parents=True, exist_ok=True)
    outputs = []
    for name, df in (("trajectory", trajectory), ("targets", targets), ("withheld_gps", withheld), ("innovations", innovations)):
        if df is not None:
            df.to_parquet(d / f"{name}.parquet", index=False)
            outputs.append(f"{name}.parquet")
    summary = {
        "tpos_version": "0.1.0",
        "pipeline": pipeline,
        "config": {},
        "config_sha256": "ab" * 32,
        # the session's kind, as tpos process records it (the report is titled and scored by the run's kind)
        "session": {"path": str(session_dir), "name": "synthetic_report", "kind": _session_kind(session_dir)},
        "inputs": session_file_hashes(session_dir),  # as tpos process records them
        "timings_s": {"total": 0.1},
        "counts": {},
        "warnings": ["a warning from the chain"],
        "gps_outages": [list(map(float, w)) for w in gps_outages],
        "mask_gps": [list(map(float, w)) for w in mask_gps],
        "results": {},
        "outputs": outputs,
        "created_utc": "2024-01-01T00:00:00Z",
    }
    (d / "summary.json").write_text(json.dumps(summary))
    return d
