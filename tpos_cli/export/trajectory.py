"""A trajectory solution as a table people and GIS tools read: chosen rate, sigmas, UTM.

Lowering the rate keeps real epochs (the one nearest each tick of a `rate_hz` grid), so every
exported point and its sigmas are what the run estimated, never an interpolation. A rate at or above
the solution's own keeps every epoch.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from tpos_cli.errors import InvalidInputError
from tpos_cli.report.projection import UtmZone, to_utm, zone_for
from tpos_cli.report.targets import horizontal_ellipse

BASE = ("t", "lat", "lon", "h", "vn", "ve", "vd", "roll", "pitch", "yaw")
SIGMAS = ("sigma_n", "sigma_e", "sigma_u", "sigma_vn", "sigma_ve", "sigma_vd", "sigma_roll", "sigma_pitch", "sigma_yaw",
          "sigma_tilt_n", "sigma_tilt_e", "sigma_heading", "att95_deg")


MAX_TICKS_PER_EPOCH = 4  # above this the tick grid is not built (see `epochs_at_rate`)


def epochs_at_rate(t_s, rate_hz: float | None) -> np.ndarray:
    """Indices of the epochs nearest each tick k / `rate_hz` (k integer) between the first and the
    last epoch (sorted `t_s`; a tick half-way goes to the earlier epoch), with the first and the last;
    all when None.

    The grid of ticks is span x rate long (`--rate 1e9` on an hour would be 3.6e12 ticks), so above
    `MAX_TICKS_PER_EPOCH` ticks per epoch it is not built: epoch i is the nearest to the ticks in its
    cell (m_{i-1}, m_i], m_i = (t_i + t_{i+1}) / 2, and is kept when an integer k lies in
    (m_{i-1} rate, m_i rate] (the same epochs up to rounding of ticks exactly half-way; a rate past
    float range keeps every epoch)."""
    t = np.asarray(t_s, dtype=float)
    if rate_hz is None or t.size < 2:
        return np.arange(t.size)
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise InvalidInputError(f"--rate {rate_hz}: must be a positive number of Hz")
    with np.errstate(over="ignore"):
        k0, k1 = np.ceil(t[0] * rate_hz), np.floor(t[-1] * rate_hz)
        scaled = t * rate_hz
    if not np.isfinite(scaled).all():
        return np.arange(t.size)  # ticks closer than any float spacing of t: every epoch is the nearest to one
    if k1 - k0 + 1.0 <= MAX_TICKS_PER_EPOCH * t.size:
        ticks = np.arange(k0, k1 + 1.0) / rate_hz
        j = np.clip(np.searchsorted(t, ticks), 1, t.size - 1)
        nearest = np.where(ticks - t[j - 1] <= t[j] - ticks, j - 1, j)
        return np.unique(np.concatenate([[0], nearest, [t.size - 1]]))
    mid = (scaled[:-1] + scaled[1:]) / 2.0
    first = np.maximum(np.floor(np.r_[k0 - 1.0, mid]) + 1.0, k0)  # smallest k above the cell's start
    last = np.minimum(np.floor(np.r_[mid, k1]), k1)  # largest k at or below its end
    keep = last >= first
    keep[0] = keep[-1] = True
    return np.flatnonzero(keep)


def trajectory_table(traj: pd.DataFrame, solution: str, rate_hz: float | None = None) -> tuple[pd.DataFrame, UtmZone]:
    """Rows of `solution` at `rate_hz`: BASE columns, the sigma columns the run wrote (sigma_u from
    sigma_d where needed), `cov_ne_m2` when written, the 95 % horizontal ellipse of each epoch, NaN
    rows dropped, UTM zone/easting/northing appended."""
    d = traj[traj["solution"].astype(str) == solution].sort_values("t", kind="stable")
    d = d[np.isfinite(d[["t", "lat", "lon", "h"]].to_numpy(float)).all(axis=1)]
    out = pd.DataFrame({c: d[c].to_numpy(float) if c in d.columns else np.nan for c in BASE})
    if "sigma_u" not in d.columns and "sigma_d" in d.columns:
        d = d.assign(sigma_u=d["sigma_d"])
    for c in SIGMAS:
        if c in d.columns:
            out[c] = d[c].to_numpy(float)
    if "sigma_n" in out and "sigma_e" in out:
        c_ne = d["cov_ne_m2"].to_numpy(float) if "cov_ne_m2" in d.columns else np.zeros(len(out))
        if "cov_ne_m2" in d.columns:
            out["cov_ne_m2"] = c_ne
        sn2, se2 = out["sigma_n"].to_numpy() ** 2, out["sigma_e"].to_numpy() ** 2
        ell = horizontal_ellipse(np.stack([np.column_stack([sn2, c_ne]), np.column_stack([c_ne, se2])], axis=1))
        out["ell95_major_m"], out["ell95_minor_m"], out["ell95_azimuth_deg"] = ell.semi_major_m, ell.semi_minor_m, ell.azimuth_deg
    if "yaw" in out:
        out["yaw"] = np.mod(out["yaw"], 360.0)  # heading convention of GPS tools: [0, 360) from north
    out = out.iloc[epochs_at_rate(out["t"].to_numpy(), rate_hz)].reset_index(drop=True)
    if out.empty:
        raise InvalidInputError(f"solution '{solution}' has no epoch with a position")
    zone = zone_for(out["lat"], out["lon"])
    out["utm_zone"] = zone.label
    out["utm_e_m"], out["utm_n_m"] = to_utm(out["lat"], out["lon"], zone)
    return out, zone
