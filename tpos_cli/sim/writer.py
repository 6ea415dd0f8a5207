"""Write a `SimResult` as a session directory in the contract format (docs/log-format.md).

Time-stamped tables go to Parquet (`fmt="parquet"`) or CSV; anchors, range calibration, targets
and shots are CSV as the contract requires. IMU vectors are rotated from body FRD into the logged
`[imu] axes` (sensor = C_bs^T body). Times are written on the logger clock, t = t_s + t0_s.
The scenario parameters are recorded as comments at the top of session.toml.
"""

from __future__ import annotations

import json
import math
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from tpos_cli.errors import InvalidInputError
from tpos_cli.frames.rotation import axes_to_dcm
from tpos_cli.io.run_dir import check_session_out

if TYPE_CHECKING:  # annotations only: sim.result imports this module for SimResult.write
    from tpos_cli.sim.result import SimResult

FORMATS = ("parquet", "csv")


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        if not math.isfinite(v):
            raise ValueError(f"cannot write non-finite {v!r} to TOML")
        return repr(float(v))
    if isinstance(v, str):
        return json.dumps(v)  # a JSON string of printable text is a valid TOML basic string
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def session_toml(sim: SimResult) -> str:
    """Text of session.toml for `sim`."""
    lines = ["# Written by `tpos simulate`: synthetic session with exact truth (truth.*)."]
    for k, v in sim.params.items():
        lines.append(f"# {k} = {json.dumps(v) if not isinstance(v, str) else v}")
    sections: dict[str, dict] = {
        "session": {"name": sim.name, "kind": sim.kind},
        "imu": {"axes": sim.imu.axes, "rate_hz": float(sim.imu.rate_hz), **sim.imu.grade.toml_figures(sim.imu.mag_b_ut is not None)},
    }
    if "start_utc" in sim.toml:
        sections["session"]["start_utc"] = sim.toml["start_utc"]
    if sim.ranges is not None:
        sections["rangefinders"] = {
            "baseline_12_m": sim.ranges.baseline_12_m,
            "baseline_13_m": sim.ranges.baseline_13_m,
            "sigma_m": sim.ranges.sigma_m,
        }
    for name, body in sim.toml.items():
        if isinstance(body, dict):
            sections[name] = body
    for name, body in sections.items():
        lines.append("")
        lines.append(f"[{name}]")
        for k, v in body.items():
            lines.append(f"{k} = {_toml_value(v)}")
    return "\n".join(lines) + "\n"


def session_tables(sim: SimResult) -> dict[str, pd.DataFrame]:
    """The contract tables of `sim` by name (imu, gps, truth, ranges, anchors, ...)."""
    t0 = sim.t0_s
    C_sb = axes_to_dcm(sim.imu.axes).T  # body FRD -> logged sensor axes
    out: dict[str, pd.DataFrame] = {}
    imu = {"t": sim.imu.t_s + t0}
    for name, arr in (("gyro", sim.imu.gyro_b_rps), ("acc", sim.imu.acc_b_mps2), ("mag", sim.imu.mag_b_ut)):
        if arr is None:
            continue
        s = arr @ C_sb.T
        for i, ax in enumerate("xyz"):
            imu[f"{name}_{ax}"] = s[:, i]
    out["imu"] = pd.DataFrame(imu)

    tr = sim.truth
    rpy = np.degrees(tr.rpy_rad)
    out["truth"] = pd.DataFrame(
        {
            "t": tr.t_s + t0,
            "lat": tr.lla[:, 0],
            "lon": tr.lla[:, 1],
            "h": tr.lla[:, 2],
            "vn": tr.vel_ned_mps[:, 0],
            "ve": tr.vel_ned_mps[:, 1],
            "vd": tr.vel_ned_mps[:, 2],
            "roll": rpy[:, 0],
            "pitch": rpy[:, 1],
            "yaw": rpy[:, 2],
        }
    )
    if sim.gps is not None:
        g = sim.gps
        out["gps"] = pd.DataFrame(
            {
                "t": g.t_s + t0,
                "lat": g.lla[:, 0],
                "lon": g.lla[:, 1],
                "h": g.lla[:, 2],
                "fix": g.fix.astype(np.int64),
                "nsat": g.nsat.astype(np.int64),
                "hdop": g.hdop,
                "vn": g.vel_ned_mps[:, 0],
                "ve": g.vel_ned_mps[:, 1],
                "vd": g.vel_ned_mps[:, 2],
                "sigma_n": g.sigma_neu_m[:, 0],
                "sigma_e": g.sigma_neu_m[:, 1],
                "sigma_u": g.sigma_neu_m[:, 2],
            }
        )
    if sim.odometry is not None:
        out["odometry"] = pd.DataFrame({"t": sim.odometry.t_s + t0, "speed_mps": sim.odometry.speed_mps})
    if sim.ranges is not None:
        r = sim.ranges
        out["ranges"] = pd.DataFrame({"t": r.t_s + t0, "d1": r.range_m[:, 0], "d2": r.range_m[:, 1], "d3": r.range_m[:, 2]})
    if sim.targets is not None:
        tg = sim.targets
        out["targets"] = pd.DataFrame(
            {"id": list(tg.ids), "lat": tg.lla[:, 0], "lon": tg.lla[:, 1], "h": tg.lla[:, 2], "role": list(tg.role)}
        )
    if sim.shots is not None:
        sh = sim.shots
        out["shots"] = pd.DataFrame({"id": list(sh.ids), "t_start": sh.t_start_s + t0, "t_end": sh.t_end_s + t0})
    if sim.anchors is not None:
        a = sim.anchors
        out["anchors"] = pd.DataFrame({"id": list(a.ids), "e": a.enu_m[:, 0], "n": a.enu_m[:, 1], "u": a.enu_m[:, 2]})
    if sim.anchor_ranges is not None:
        ar = sim.anchor_ranges
        ids = np.asarray(sim.anchors.ids, dtype=object)
        out["anchor_ranges"] = pd.DataFrame({"t": ar.t_s + t0, "id": ids[ar.anchor], "range": ar.range_m})
    if sim.range_calibration is not None:
        rc = sim.range_calibration
        ids = np.asarray(sim.anchors.ids, dtype=object)
        out["range_calibration"] = pd.DataFrame({"id": ids[rc.anchor], "true_m": rc.true_m, "measured_m": rc.measured_m})
    return out


CSV_ONLY = ("anchors", "range_calibration", "targets", "shots")


def write_session(sim: SimResult, path: str | Path, *, fmt: str = "parquet", overwrite: bool = False) -> Path:
    """Write `sim` to the directory `path` (created; replaced only if `overwrite`).

    The files are written into a temporary sibling directory that is renamed into place when
    complete, so an interrupted run never leaves a half-written session. Returns the path.
    """
    if fmt not in FORMATS:
        raise InvalidInputError(f"format: {fmt!r} is not one of {', '.join(FORMATS)}")
    out = Path(path)
    # absent or empty; with `overwrite` an existing session only (never a directory of other files,
    # nor one holding the current directory): the guard `tpos simulate --force` applies, for library callers too
    check_session_out(out, force=overwrite)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    tmp.chmod(0o755)  # mkdtemp makes it private; a session is an ordinary shared directory
    try:
        (tmp / "session.toml").write_text(session_toml(sim), encoding="utf-8")
        for name, df in session_tables(sim).items():
            if name in CSV_ONLY or fmt == "csv":
                df.to_csv(tmp / f"{name}.csv", index=False)  # pandas writes the shortest exact repr
            else:
                df.to_parquet(tmp / f"{name}.parquet", index=False, engine="pyarrow", compression="zstd")
        if out.exists():
            shutil.rmtree(out)
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out
