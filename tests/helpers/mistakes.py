"""User mistakes planted into a copy of a session directory, as a user would make them.

Each planter edits the files of a session (never the original: `plant` copies it first) the way a
wrong export or a typo in `session.toml` would: units, axes letters, clock offsets, the GPS lever
arm, anchor coordinates, rangefinder baselines, a magnetic disturbance, the odometry's clock, the
IMU's stated mounting. Shared by `tests/test_quality.py` and `benchmarks/verdict.py`.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd

from tpos_cli.frames.earth import G0_MPS2
from tpos_cli.frames.geodetic import lla_to_ned, ned_to_lla
from tpos_cli.frames.rotation import axes_to_dcm, euler_to_dcm


def _table(d: Path, stem: str) -> Path:
    for ext in (".parquet", ".csv"):
        if (d / f"{stem}{ext}").exists():
            return d / f"{stem}{ext}"
    raise FileNotFoundError(f"{d}/{stem}.*")


def read(d: Path, stem: str) -> pd.DataFrame:
    p = _table(d, stem)
    return pd.read_parquet(p) if p.suffix == ".parquet" else pd.read_csv(p, dtype={"t": float})


def write(d: Path, stem: str, df: pd.DataFrame) -> None:
    p = _table(d, stem)
    if p.suffix == ".parquet":
        df.to_parquet(p, index=False)
    else:
        df.to_csv(p, index=False, float_format="%.10g")


def set_toml(d: Path, section: str, key: str, value: str) -> None:
    """Set `key = value` (a TOML literal) in `[section]` of session.toml, adding it if absent."""
    p = d / "session.toml"
    lines = p.read_text().splitlines()
    sec, out, done = None, [], False
    for line in lines:
        m = re.match(r"\s*\[([^\]]+)\]", line)
        if m:
            if sec == section and not done:
                out.append(f"{key} = {value}")
                done = True
            sec = m.group(1).strip()
        if sec == section and re.match(rf"\s*{re.escape(key)}\s*=", line) and not done:
            out.append(f"{key} = {value}")
            done = True
            continue
        out.append(line)
    if not done:
        if sec != section:
            out += ["", f"[{section}]"]
        out.append(f"{key} = {value}")
    p.write_text("\n".join(out) + "\n")


def gyro_degps(d: Path) -> None:
    imu = read(d, "imu")
    imu[["gyro_x", "gyro_y", "gyro_z"]] = np.degrees(imu[["gyro_x", "gyro_y", "gyro_z"]].to_numpy())
    write(d, "imu", imu)


def acc_g(d: Path) -> None:
    imu = read(d, "imu")
    imu[["acc_x", "acc_y", "acc_z"]] = imu[["acc_x", "acc_y", "acc_z"]].to_numpy() / G0_MPS2
    write(d, "imu", imu)


def axes(letters: str):
    def plant(d: Path) -> None:
        set_toml(d, "imu", "axes", f'"{letters}"')
    plant.__name__ = f"axes_{letters}"
    return plant


def _stamped_late(stem: str, seconds: float):
    """The `stem` table's rows stamped `seconds` late on the logger clock."""
    def plant(d: Path) -> None:
        x = read(d, stem)
        x["t"] = x["t"] + seconds
        write(d, stem, x)
    plant.__name__ = f"{stem}_late_{seconds:g}"
    return plant


def odometry_late(seconds: float):
    """Odometry rows stamped `seconds` late on the logger clock."""
    return _stamped_late("odometry", seconds)


def mounting_stated(rpy_deg_text: str, name: str = "mounting_stated"):
    """`[imu] mounting_rpy_deg = rpy_deg_text` (a TOML array, e.g. radians written for degrees)."""
    def plant(d: Path) -> None:
        set_toml(d, "imu", "mounting_rpy_deg", rpy_deg_text)
    plant.__name__ = name
    return plant


def gps_late(seconds: float):
    """GPS rows stamped `seconds` late on the logger clock."""
    return _stamped_late("gps", seconds)


def antenna_offset(lever_b_m, declared_b_m):
    """Move the GPS antenna to `lever_b_m` (body FRD = the sim's logged axes) using the truth
    attitude and rates, and declare `declared_b_m` as `[gps] lever_arm_m`."""
    lever = np.asarray(lever_b_m, dtype=float)

    def plant(d: Path) -> None:
        g, tr, imu = read(d, "gps"), read(d, "truth"), read(d, "imu")
        C_bs = axes_to_dcm(_axes(d))
        t = g["t"].to_numpy()
        ang = {c: np.radians(tr[c].to_numpy(float)) for c in ("roll", "pitch", "yaw")}
        ang["yaw"] = np.unwrap(ang["yaw"])
        r, p_, y = (np.interp(t, tr["t"], ang[c]) for c in ("roll", "pitch", "yaw"))
        C = euler_to_dcm(r, p_, y)
        w_s = np.column_stack([np.interp(t, imu["t"], imu[c]) for c in ("gyro_x", "gyro_y", "gyro_z")])
        lb = C_bs @ lever
        off = np.einsum("nij,j->ni", C, lb)
        dv = np.einsum("nij,nj->ni", C, np.cross(w_s @ C_bs.T, lb))
        lla = g[["lat", "lon", "h"]].to_numpy(float)
        ned = lla_to_ned(lla, lla[0]) + off
        g[["lat", "lon", "h"]] = ned_to_lla(ned, lla[0])
        for j, c in enumerate(("vn", "ve", "vd")):
            if c in g:
                g[c] = g[c] + dv[:, j]
        write(d, "gps", g)
        set_toml(d, "gps", "lever_arm_m", "[" + ", ".join(f"{v:g}" for v in declared_b_m) + "]")
    plant.__name__ = "lever_arm_" + ("ok" if np.allclose(lever, declared_b_m) else "wrong")
    return plant


def _axes(d: Path) -> str:
    m = re.search(r'axes\s*=\s*"([A-Za-z]{3})"', (d / "session.toml").read_text())
    return m.group(1) if m else "FRD"


def anchor_moved(anchor: str = "A2", dn_m: float = 0.0, de_m: float = 1.0):
    def plant(d: Path) -> None:
        a = pd.read_csv(d / "anchors.csv")
        a.loc[a["id"] == anchor, "e"] += de_m
        a.loc[a["id"] == anchor, "n"] += dn_m
        a.to_csv(d / "anchors.csv", index=False)
    plant.__name__ = f"anchor_{anchor}_moved"
    return plant


def baseline(key: str, value_m: float):
    def plant(d: Path) -> None:
        set_toml(d, "rangefinders", key, f"{value_m:g}")
    plant.__name__ = f"{key}_{value_m:g}"
    return plant


def mag_disturbance(ut: float = 50.0, start_frac: float = 0.5):
    """Add `ut` along sensor x from `start_frac` of the log to its end (a magnet brought close)."""
    def plant(d: Path) -> None:
        imu = read(d, "imu")
        t = imu["t"].to_numpy()
        on = t >= t[0] + start_frac * (t[-1] - t[0])
        imu.loc[on, "mag_x"] = imu.loc[on, "mag_x"] + ut
        write(d, "imu", imu)
    plant.__name__ = f"mag_disturbance_{ut:g}uT"
    return plant


def mag_noise_stated(ut: float):
    """`[imu] mag_noise_ut = ut` in session.toml: the magnetometer's white-noise SD as the user states it (a
    figure below the sensor's own understates it; the session's figure wins over the still window's)."""
    def plant(d: Path) -> None:
        set_toml(d, "imu", "mag_noise_ut", f"{ut:g}")
    plant.__name__ = f"mag_noise_stated_{ut:g}uT"
    return plant


def plant(src: Path, dst: Path, *planters) -> Path:
    """Copy session `src` to `dst` (replacing it) and apply the planters in order."""
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst)
    for p in planters:
        p(dst)
    return dst
