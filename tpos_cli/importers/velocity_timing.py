"""When a receiver's velocities are differences of its own fixes, not instantaneous: a note.

A receiver (or RTKLIB) may write as the velocity of epoch k the position difference with the epoch
before, v_k = (p_k - p_{k-1}) / (t_k - t_{k-1}): the mean velocity over the interval before its
stamp, whose centre is half an interval (0.125 s at 4 Hz) earlier than the position stamped with
it. The contract has one `t` per GPS row, so the session cannot say so; `tpos process` then finds a
velocity clock apart from the position clock by about half an interval (its verdict: "one [time]
gps_offset_s cannot put both right"). This module tells the user at import time.

Test: over moving epochs (horizontal speed above `MIN_SPEED_MPS`) with regular intervals on both
sides, the RMS of the horizontal velocity minus each of the backward, central and forward
differences of the positions (north-east, m). An instantaneous (Doppler) velocity is closest to
the central difference (its error is O(jerk dt^2) against O(acceleration dt) for the one-sided
ones); the note is given when a one-sided difference fits `CLEARLY` times better than both others.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from tpos_cli.frames.geodetic import lla_to_ned

MIN_SPEED_MPS = 0.5  # moving: the differences carry the motion, not only the position noise
MIN_EPOCHS = 20  # fewer moving epochs say nothing either way
CLEARLY = 1.5  # how much better the one-sided fit must be (chosen after seeing the walk and part 1, ratios 2.6 and 2.3)
REGULAR = 0.1  # an interval within 10 % of the median one is regular


def velocity_timing_note(gps: pd.DataFrame, name: str) -> str | None:
    """A note when `gps`'s velocities (vn, ve) are one-sided differences of its positions (lat, lon, h,
    t in seconds); None when they look instantaneous or the data cannot tell."""
    need = ("t", "lat", "lon", "h", "vn", "ve")
    if not all(c in gps.columns for c in need):
        return None
    g = gps.loc[:, list(need)].astype(float).sort_values("t", kind="stable")
    g = g[np.isfinite(g.to_numpy()).all(axis=1)]
    if len(g) < MIN_EPOCHS + 2:
        return None
    t = g["t"].to_numpy()
    lla = g[["lat", "lon", "h"]].to_numpy()
    ne = lla_to_ned(lla, lla[0])[:, :2]
    v = g[["vn", "ve"]].to_numpy()
    dt = np.diff(t)
    step = float(np.median(dt))
    if not step > 0:
        return None
    regular = np.abs(dt - step) <= REGULAR * step
    k = np.flatnonzero(regular[:-1] & regular[1:]) + 1  # epochs with a regular interval on both sides
    k = k[np.hypot(v[k, 0], v[k, 1]) > MIN_SPEED_MPS]
    if k.size < MIN_EPOCHS:
        return None
    back = (ne[k] - ne[k - 1]) / dt[k - 1, None]
    fwd = (ne[k + 1] - ne[k]) / dt[k, None]
    cen = (ne[k + 1] - ne[k - 1]) / (t[k + 1] - t[k - 1])[:, None]

    def rms(d):
        return float(np.sqrt(np.mean(np.sum((v[k] - d) ** 2, axis=1))))

    rb, rc, rf = rms(back), rms(cen), rms(fwd)
    figures = f"RMS {{}} m/s over {k.size} moving epochs; central difference {rc:.3f}, the other side {{}}"
    if CLEARLY * rb < min(rc, rf):
        return (f"{name}: the velocities are the position differences with the fix before ("
                + figures.format(f"{rb:.3f}", f"{rf:.3f}") + f"): each is the mean over the {step:g} s before its "
                f"stamp, centred {step / 2:g} s earlier than the position stamped with it; `tpos process` will see a GPS "
                "velocity clock apart from the position clock by about that")
    if CLEARLY * rf < min(rc, rb):
        return (f"{name}: the velocities are the position differences with the fix after ("
                + figures.format(f"{rf:.3f}", f"{rb:.3f}") + f"): each is the mean over the {step:g} s after its "
                f"stamp, centred {step / 2:g} s later than the position stamped with it; `tpos process` will see a GPS "
                "velocity clock apart from the position clock by about that")
    return None
