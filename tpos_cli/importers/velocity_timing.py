"""When a receiver's velocities are differences of its own fixes, not instantaneous: a note.

A receiver (or RTKLIB) may write as the velocity of epoch k the position difference with the epoch
before, v_k = (p_k - p_{k-1}) / (t_k - t_{k-1}): the mean velocity over the interval before its
stamp, whose centre is half an interval (0.125 s at 4 Hz) earlier than the position stamped with
it. The contract has one `t` per GPS row, so the session cannot say so; `tpos process` then finds a
velocity clock apart from the position clock by about half an interval. This module tells the user
at import time.

The test is the filter's own (`fusion.velocity_lag.velocity_latency_s`: the lag, 0-0.5 s, that best matches
the horizontal velocities to the central differences of the positions, kept when it cuts their RMS
difference by 30 %), run once as logged and once on the log reversed in time, where a difference
with the fix after becomes one with the fix before (t -> -t, v -> -v). The note is given when the
lag found is half an interval, within a quarter of one.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd

from tpos_cli.fusion.velocity_lag import velocity_latency_s

HALF_INTERVAL_TOLERANCE = 0.25  # of one fix interval: a lag this close to half an interval is a one-sided difference


def _fixes(t_s, lla, vel_ne_mps) -> SimpleNamespace:
    """The fields `velocity_latency_s` reads (t_s, lla, vel_ned_mps)."""
    return SimpleNamespace(t_s=t_s, lla=lla, vel_ned_mps=np.column_stack([vel_ne_mps, np.zeros(t_s.size)]))


def velocity_timing_note(gps: pd.DataFrame, name: str) -> str | None:
    """A note when `gps`'s velocities (vn, ve) are one-sided differences of its positions (lat, lon, h,
    t in seconds); None when they look instantaneous or the data cannot tell."""
    need = ("t", "lat", "lon", "h", "vn", "ve")
    if not all(c in gps.columns for c in need):
        return None
    g = gps.loc[:, list(need)].astype(float).sort_values("t", kind="stable")
    g = g[np.isfinite(g.to_numpy()).all(axis=1)]
    t = g["t"].to_numpy()
    if t.size < 3 or not np.all(np.diff(t) > 0):
        return None
    step = float(np.median(np.diff(t)))
    lla, v = g[["lat", "lon", "h"]].to_numpy(), g[["vn", "ve"]].to_numpy()
    for side, sign, fixes in (("before", "earlier", _fixes(t, lla, v)),
                              ("after", "later", _fixes(-t[::-1], lla[::-1], -v[::-1]))):
        lag, fig = velocity_latency_s(fixes)
        if lag > 0 and abs(lag - step / 2) <= HALF_INTERVAL_TOLERANCE * step:
            return (f"{name}: the velocities are the position differences with the fix {side} (they match the "
                    f"positions' central differences {lag:g} s {sign}: RMS {fig['rms_mps_at_lag']:.3f} m/s, against "
                    f"{fig['rms_mps_at_0']:.3f} at their stamps): each is the mean over the {step:g} s {side} its stamp, "
                    f"centred {step / 2:g} s {sign} than the position stamped with it; `tpos process` will see a GPS "
                    "velocity clock apart from the position clock by about that")
    return None
