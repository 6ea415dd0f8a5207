"""A plain-data description of a loaded session, for `tpos inspect` (table and --json)."""

from __future__ import annotations

import numpy as np

from tpos_cli.session import Session

# Sample intervals longer than this many median intervals are gaps (reported apart), not jitter;
# the same factor as the loader's IMU gap detection (timebase.find_gaps).
GAP_FACTOR = 2.5


def sample_timing(t: np.ndarray) -> dict:
    """Mean rate and timing jitter of a stamped stream, gaps left out.

    `rate_hz` is 1 / mean interval (a 152 Hz logger whose stamps are mostly 6 ms apart is 152 Hz,
    not the 166.67 Hz its median interval suggests); `jitter_ms` is the SD of the intervals and
    `dt_min_ms`/`dt_max_ms` their range. Intervals over GAP_FACTOR median intervals are gaps.
    """
    dt = np.diff(np.unique(np.asarray(t, dtype=float)))
    if dt.size == 0:
        return {"rate_hz": None, "jitter_ms": None, "dt_min_ms": None, "dt_max_ms": None}
    dt = dt[dt <= GAP_FACTOR * np.median(dt)]
    return {"rate_hz": float(1.0 / dt.mean()), "jitter_ms": float(dt.std() * 1e3),
            "dt_min_ms": float(dt.min() * 1e3), "dt_max_ms": float(dt.max() * 1e3)}


def describe_session(s: Session) -> dict:
    """Files, rows, spans, measured rates, gaps, outages, counts and warnings of a session."""
    t0 = s.t0_s
    tables: dict[str, dict] = {}
    imu = s.imu
    mounting = s.meta.mounting_rpy_deg
    timing = sample_timing(imu.t_s)
    tables["imu"] = {"rows": int(imu.t_s.size), "span_s": float(imu.t_s[-1] - imu.t_s[0]), **timing,
                     "mounting_rpy_deg": None if mounting is None else [float(x) for x in mounting],
                     "notes": f"axes {s.meta.axes}, nominal {s.meta.rate_hz:g} Hz, dt {timing['dt_min_ms']:.1f}-{timing['dt_max_ms']:.1f} ms" + (", magnetometer" if imu.mag_b_ut is not None else "")
                     + (", mounting " + "/".join(f"{x:g}" for x in mounting) + " deg" if mounting is not None else ", mounting unknown")}
    if s.gps is not None:
        g = s.gps
        fixes = {str(k): int(v) for k, v in zip(*np.unique(g.fix, return_counts=True))}
        tables["gps"] = {"rows": int(g.t_s.size), "span_s": float(g.t_s[-1] - g.t_s[0]) if g.t_s.size else 0.0,
                         **sample_timing(g.t_s), "fix_counts": fixes,
                         "has_velocity": bool(np.isfinite(g.vel_ned_mps).any()),
                         "notes": "fix " + ", ".join(f"{k}: {v}" for k, v in fixes.items())}
    if s.ranges is not None:
        nan = (~np.isfinite(s.ranges.range_m)).sum(axis=0)
        tables["ranges"] = {"rows": int(s.ranges.t_s.size), "span_s": float(np.ptp(s.ranges.t_s)), **sample_timing(s.ranges.t_s),
                            "no_return": {f"d{i + 1}": int(n) for i, n in enumerate(nan)},
                            "notes": "no return: " + ", ".join(f"d{i + 1} {int(n)}" for i, n in enumerate(nan))}
    if s.odometry is not None:
        o = s.odometry
        tables["odometry"] = {"rows": int(o.t_s.size), "span_s": float(np.ptp(o.t_s)), **sample_timing(o.t_s),
                              "speed_max_mps": float(o.speed_mps.max()),
                              "notes": f"speed {float(np.median(o.speed_mps)):.2f} m/s median, {float(o.speed_mps.max()):.2f} max"}
    if s.anchors is not None:
        tables["anchors"] = {"rows": len(s.anchors.ids), "ids": list(s.anchors.ids),
                             "notes": "ids " + ", ".join(s.anchors.ids)}
    if s.anchor_ranges is not None:
        ar = s.anchor_ranges
        per = {s.anchors.ids[i]: int(n) for i, n in zip(*np.unique(ar.anchor, return_counts=True))}
        tables["anchor_ranges"] = {"rows": int(ar.t_s.size), "span_s": float(np.ptp(ar.t_s)), **sample_timing(ar.t_s),
                                   "per_anchor": per, "notes": ", ".join(f"{k}: {v}" for k, v in per.items())}
    if s.range_calibration is not None:
        tables["range_calibration"] = {"rows": int(s.range_calibration.true_m.size)}
    if s.targets is not None:
        roles = {r or "(none)": s.targets.role.count(r) for r in set(s.targets.role)}
        tables["targets"] = {"rows": len(s.targets.ids), "roles": roles, "notes": ", ".join(f"{k}: {v}" for k, v in roles.items())}
    if s.shots is not None:
        tables["shots"] = {"rows": len(s.shots.ids), "notes": f"{np.sum(s.shots.t_end_s - s.shots.t_start_s):.1f} s on points"}
    if s.truth is not None:
        tr = s.truth
        has_att = bool(np.isfinite(tr.rpy_deg).any())
        tables["truth"] = {"rows": int(tr.t_s.size), "span_s": float(np.ptp(tr.t_s)), **sample_timing(tr.t_s),
                           "has_attitude": has_att, "nan_rows": int((~np.isfinite(tr.lla).all(axis=1)).sum()),
                           "notes": ("attitude, " if has_att else "") + f"{int((~np.isfinite(tr.lla).all(axis=1)).sum())} rows without position"}
    return {
        "name": s.meta.name, "kind": s.meta.kind, "path": str(s.path), "t0": t0, "duration_s": s.t_end_s,
        "start_utc": s.meta.start_utc.isoformat() if s.meta.start_utc else None,
        "tables": tables,
        "gps_outages": (s.gps_outages_s + t0).tolist(),
        "imu_gaps": (s.imu_gaps_s + t0).tolist(),
        "counts": dict(s.counts),
        "warnings": list(s.warnings),
        "file_hashes": dict(s.file_hashes),
    }
