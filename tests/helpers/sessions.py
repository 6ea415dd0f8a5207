"""Small, valid sessions written from scratch, for tests of ingestion and of the CLI."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

G = 9.80665


def write_minimal_session(path: Path, *, fmt: str = "csv", seconds: float = 10.0, rate_hz: float = 100.0,
                          with_gps: bool = True, with_ranges: bool = False, with_anchors: bool = False, with_odometry: bool = False,
                          t0: float = 1000.0, seed: int = 0) -> Path:
    """A static FRD IMU (gravity on -z, Earth-rate-sized gyro noise), 1 Hz GPS, optional ranges/anchors/odometry."""
    rng = np.random.default_rng(seed)
    path.mkdir(parents=True, exist_ok=True)
    n = int(seconds * rate_hz)
    t = t0 + np.arange(n) / rate_hz
    imu = pd.DataFrame({
        "t": t,
        "gyro_x": 1e-4 * rng.standard_normal(n), "gyro_y": 1e-4 * rng.standard_normal(n), "gyro_z": 1e-4 * rng.standard_normal(n),
        "acc_x": 0.01 * rng.standard_normal(n), "acc_y": 0.01 * rng.standard_normal(n), "acc_z": -G + 0.01 * rng.standard_normal(n),
    })
    toml = [
        "[session]", 'name = "minimal"', f'kind = "{"ranging" if with_anchors else "drive"}"', "",
        "[imu]", 'axes = "FRD"', f"rate_hz = {rate_hz}", "",
    ]
    _write(imu, path / "imu", fmt)
    if with_gps:
        tg = t0 + np.arange(int(seconds))
        gps = pd.DataFrame({"t": tg, "lat": 45.0 + 1e-7 * rng.standard_normal(tg.size), "lon": -73.0 + np.zeros(tg.size),
                            "h": 50.0 + np.zeros(tg.size), "fix": np.full(tg.size, 2)})
        _write(gps, path / "gps", fmt)
    if with_ranges:
        tr = t0 + np.arange(int(seconds * 10)) / 10.0
        rng_df = pd.DataFrame({"t": tr, "d1": 12.0 + np.zeros(tr.size), "d2": 12.0 + np.zeros(tr.size), "d3": 12.0 + np.zeros(tr.size)})
        _write(rng_df, path / "ranges", fmt)
        toml += ["[rangefinders]", "baseline_12_m = 0.2", "baseline_13_m = 0.2", "sigma_m = 0.0015", ""]
    if with_odometry:
        to = t0 + np.arange(int(seconds * 50)) / 50.0
        _write(pd.DataFrame({"t": to, "speed_mps": np.zeros(to.size)}), path / "odometry", fmt)
    if with_anchors:
        pd.DataFrame({"id": ["A1", "A2", "A3", "A4"], "e": [0.0, 10.0, 10.0, 0.0], "n": [0.0, 0.0, 5.0, 5.0],
                      "u": [2.0, 2.0, 2.0, 2.0]}).to_csv(path / "anchors.csv", index=False)
        ta = np.repeat(t0 + np.arange(int(seconds * 10)) / 10.0, 4)
        ids = np.tile(["A1", "A2", "A3", "A4"], ta.size // 4)
        pd.DataFrame({"t": ta, "id": ids, "range": 5.0 + np.zeros(ta.size)}).to_csv(path / "anchor_ranges.csv", index=False)
        toml += ["[local]", "lat = 45.0", "lon = -73.0", "h = 50.0", ""]
    (path / "session.toml").write_text("\n".join(toml) + "\n")
    return path


def _write(df: pd.DataFrame, stem: Path, fmt: str) -> None:
    if fmt == "csv":
        df.to_csv(stem.with_suffix(".csv"), index=False)
    else:
        df.to_parquet(stem.with_suffix(".parquet"), index=False)
