"""How late a receiver's logged velocity is against its own positions (issue 11), from the GPS alone.

Kept apart from `fusion.insgps` (numba kernels through `fusion.engine`) so that `tpos import`,
whose velocity-timing note runs the same test (`importers.velocity_timing`), does not import numba
(0.5 s) for it. Needs only numpy and `frames.geodetic`; `fixes` is any object with `t_s`, `lla`
and `vel_ned_mps` (`fusion.insgps.GpsFixes`).
"""

from __future__ import annotations

import numpy as np

from tpos_cli.frames.geodetic import lla_to_ned

LAG_GRID_S = np.arange(0.0, 0.5001, 0.025)  # velocity lags tried (s)


def velocity_latency_s(fixes, grid_s=LAG_GRID_S, min_gain: float = 0.3) -> tuple[float, dict]:
    """How late the logged GPS velocity is against the fixes' own positions (s, >= 0), from the GPS
    alone: many receivers log the backward difference of positions, the velocity of half an
    interval earlier (issue 11: 0.125 s at 4 Hz). The lag that best matches the logged horizontal
    velocity to the central differences of the positions, if it cuts their RMS difference by at
    least `min_gain` against no lag; else 0. Returns (lag_s, figures)."""
    v = np.asarray(fixes.vel_ned_mps, dtype=float)
    ok = np.isfinite(v[:, 0]) & np.isfinite(v[:, 1])
    if ok.sum() < 20:
        return 0.0, {"fixes": int(ok.sum())}
    t = np.asarray(fixes.t_s, dtype=float)
    ned = lla_to_ned(fixes.lla, fixes.lla[0])
    n_m, e_m = ned[:, 0], ned[:, 1]
    dt = np.diff(t)
    good = (dt > 0) & (dt < 1.5 * np.median(dt))
    tm = 0.5 * (t[1:] + t[:-1])[good]
    vc = np.column_stack([np.diff(n_m)[good] / dt[good], np.diff(e_m)[good] / dt[good]])
    rms = []
    for tau in grid_s:
        m = ok & (t - tau > tm[0]) & (t - tau < tm[-1])
        vi = np.column_stack([np.interp(t[m] - tau, tm, vc[:, i]) for i in range(2)])
        rms.append(float(np.sqrt(np.mean((v[m, :2] - vi) ** 2))))
    rms = np.array(rms)
    best = int(np.argmin(rms))
    lag = float(grid_s[best]) if rms[best] < (1.0 - min_gain) * rms[0] else 0.0
    return lag, {"lag_s": lag, "rms_mps_at_lag": round(float(rms[best]), 4), "rms_mps_at_0": round(float(rms[0]), 4)}
