"""Stationary intervals for zero-velocity updates (beyond paper 002): the IMU, confirmed by the fixes.

An IMU cannot tell rest from uniform straight motion (a simulated cart on a leg is as still, to
its sensors, as a parked one), so IMU stillness alone must not trigger a ZUPT. The intervals are
built in three steps:

1. `alignment.static_mask`: no rotation and no shaking (mean rate, specific-force SD);
2. each still run is cut where the moving-mean specific force leaves the value at the start of
   the current piece by more than `acc_step_mps2`: at constant attitude a change of specific force
   is an acceleration, so inside a piece the velocity is nearly constant;
3. a piece of at least `min_duration_s` is stationary when, for every anchor heard in it, the
   range rate (robust Theil-Sen line through that anchor's ranges: NLOS spikes are one-sided
   outliers) is below `max_speed_mps`, and at least two anchors resolve it (3-SD half-width of
   the rate below the limit; far anchors have noisier ranges); a moving node changes the range
   to an anchor ahead or behind at nearly its speed. Ranges beat position fixes here: with the
   anchors on the corridor walls a fix's cross-corridor SD is several times the range SD.
   Pieces with fewer than `_MIN_RANGES` ranges from every anchor are not used.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.special import ndtri  # not scipy.stats (theilslopes): its import costs 0.5 s of every ranging run

from tpos_cli.alignment import static_mask
from tpos_cli.timebase import true_runs

_MIN_RANGES = 5  # a line through fewer ranges gives no usable rate
_MAX_POINTS = 200  # Theil-Sen is O(n^2): thin longer pieces (the rate SD still shrinks with span)


def theil_sen(x, y, confidence: float) -> tuple[float, float, float]:
    """Theil-Sen line y = a + b x: (slope b, low, high) with the two-sided `confidence` interval
    of the slope (Sen 1968, Eq. 2.6, ties in x and y corrected), as `scipy.stats.theilslopes`.

    b is the median of the slopes (y_j - y_i) / (x_j - x_i) over the pairs with x_j > x_i; the
    interval is the pair of sorted slopes at ranks (N -+ z sigma) / 2, z the normal quantile of
    (1 - confidence) / 2 and sigma^2 = [n (n-1) (2n+5) - sum over tied groups of t (t-1) (2t+5)] / 18.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    dx = x[:, None] - x
    pos = dx > 0
    slopes = (y[:, None] - y)[pos] / dx[pos]
    if slopes.size == 0:  # all x equal
        return np.nan, np.nan, np.nan
    slopes.sort()
    slope = float(np.median(slopes))
    z = ndtri((1.0 - confidence) / 2.0)

    def ties(v):
        _, c = np.unique(v, return_counts=True)
        c = c[c > 1].astype(float)
        return float(np.sum(c * (c - 1) * (2 * c + 5)))

    n, nt = y.size, slopes.size
    sigma = np.sqrt((n * (n - 1) * (2 * n + 5) - ties(x) - ties(y)) / 18.0)
    hi = min(int(np.round((nt - z * sigma) / 2.0)), nt - 1)
    lo = max(int(np.round((nt + z * sigma) / 2.0)) - 1, 0)
    return slope, float(slopes[lo]), float(slopes[hi])


def stationary_intervals(t_s, gyro_b_rps, acc_b_mps2, range_t_s, anchor, range_m, *, min_duration_s=1.0,
                         acc_step_mps2=0.05, max_speed_mps=0.05, window_s=0.5, **static_kw) -> list[tuple[float, float]]:
    """Intervals [t0, t1] (s) where the node stands still.

    t_s, gyro_b_rps, acc_b_mps2 : IMU; range_t_s, anchor, range_m (R,) : anchor ranges (any order;
    an anchor's ranges in a piece are thinned in time order).
    """
    t = np.asarray(t_s, dtype=float)
    if t.size < 3:
        return []
    still = static_mask(t, gyro_b_rps, acc_b_mps2, window_s=window_s, **static_kw)
    dt = float(np.median(np.diff(t)))
    nw = max(3, int(round(window_s / dt)))
    a_mean = uniform_filter1d(np.asarray(acc_b_mps2, dtype=float), nw, axis=0, mode="nearest")
    half = nw // 2  # the centred window sees a change half a window early: trim both ends
    pieces = []
    for i0, i1 in zip(*true_runs(still)):
        start = i0
        while start < i1:
            dev = np.linalg.norm(a_mean[start:i1] - a_mean[start], axis=1)
            out = np.flatnonzero(dev > acc_step_mps2)
            end = start + int(out[0]) if out.size else i1
            pieces.append((start, end))  # while accelerating, pieces are short and dropped below
            start = end
    order = np.argsort(np.asarray(range_t_s, dtype=float), kind="stable")  # time order: a piece's ranges are a slice
    rt = np.asarray(range_t_s, dtype=float)[order]
    ra = np.asarray(anchor, dtype=np.int64)[order]
    rr = np.asarray(range_m, dtype=float)[order]
    out_iv = []
    for s, e in pieces:
        a = s + (half if s > 0 else 0)
        b = e - (half if e < t.size else 0)
        if b - a < 2 or t[b - 1] - t[a] < min_duration_s:
            continue
        t0, t1 = t[a], t[b - 1]
        inside = slice(np.searchsorted(rt, t0, side="left"), np.searchsorted(rt, t1, side="right"))  # t0 <= rt <= t1
        p_t, p_a, p_r = rt[inside], ra[inside], rr[inside]
        ok, n_resolved = True, 0
        for i in np.unique(p_a):
            m = np.flatnonzero(p_a == i)
            if m.size < _MIN_RANGES:
                continue
            m = m[:: max(1, m.size // _MAX_POINTS)]
            slope, lo, hi = theil_sen(p_t[m], p_r[m], 0.997)  # (lo, hi): 3-sigma interval
            if abs(slope) >= max_speed_mps:
                ok = False
                break
            n_resolved += 0.5 * (hi - lo) < max_speed_mps
        if ok and n_resolved >= 2:
            out_iv.append((float(t0), float(t1)))
    return out_iv
