"""Clock handling: duplicate stamps, IMU gaps, GPS outages as explicit intervals.

All times here are float64 seconds on one clock (the caller decides which).
"""

from __future__ import annotations

import numpy as np


def first_decrease(t: np.ndarray) -> int | None:
    """Index of the first sample whose stamp is earlier than its predecessor's, or None."""
    bad = np.flatnonzero(np.diff(t) < 0)
    return int(bad[0]) + 1 if bad.size else None


def duplicate_mask(t: np.ndarray) -> np.ndarray:
    """True for every sample whose stamp equals its predecessor's (the first of a run is kept)."""
    mask = np.zeros(t.shape, dtype=bool)
    mask[1:] = np.diff(t) == 0
    return mask


def find_gaps(t: np.ndarray, nominal_dt_s: float, factor: float = 2.5) -> np.ndarray:
    """Intervals (G, 2) between consecutive samples more than `factor` nominal periods apart."""
    dt = np.diff(t)
    idx = np.flatnonzero(dt > factor * nominal_dt_s)
    return np.column_stack([t[idx], t[idx + 1]]) if idx.size else np.empty((0, 2))


def gps_outages(t_fix: np.ndarray, t_begin: float, t_end: float, min_gap_s: float | None = None) -> np.ndarray:
    """GPS outages (K, 2) within [t_begin, t_end] from the times of valid fixes.

    An outage is a stretch longer than `min_gap_s` without a valid fix (default: the larger of
    1.5 s and three median fix intervals), including before the first and after the last fix.
    """
    t_fix = np.asarray(t_fix, dtype=float)
    if t_fix.size == 0:
        return np.array([[t_begin, t_end]]) if t_end > t_begin else np.empty((0, 2))
    if min_gap_s is None:
        med = float(np.median(np.diff(t_fix))) if t_fix.size > 1 else 1.0
        min_gap_s = max(1.5, 3.0 * med)
    edges = np.concatenate([[t_begin], t_fix, [t_end]])
    gap = np.diff(edges)
    idx = np.flatnonzero(gap > min_gap_s)
    out = np.column_stack([edges[idx], edges[idx + 1]]) if idx.size else np.empty((0, 2))
    return out


def in_intervals(t: np.ndarray, intervals: np.ndarray | None, *, closed: bool = False) -> np.ndarray:
    """Boolean mask of the times inside any of the intervals (K, 2): half-open [start, end) (outages,
    report windows), or closed [start, end] with `closed` (stops, RTK float stretches: a stretch's
    last fix is in it); None or (0, 2): none. Intervals may overlap and come in any order; an empty
    or NaN one holds nothing.

    O((N + K) log K): a time is inside when more intervals have started at or before it than have
    ended before it (at or before it, half-open), counted by binary search over the sorted ends."""
    t = np.asarray(t, dtype=float)
    if intervals is None:
        return np.zeros(t.shape, dtype=bool)
    iv = np.asarray(intervals, dtype=float).reshape(-1, 2)
    iv = iv[(iv[:, 0] <= iv[:, 1]) if closed else (iv[:, 0] < iv[:, 1])]  # NaN rows fail both
    started = np.searchsorted(np.sort(iv[:, 0]), t, side="right")  # start <= t
    ended = np.searchsorted(np.sort(iv[:, 1]), t, side="left" if closed else "right")  # end < t (closed), end <= t
    return started > ended


def true_runs(mask) -> tuple[np.ndarray, np.ndarray]:
    """Runs of consecutive True in a boolean array: (starts, ends) index arrays, each run [start, end)."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], np.asarray(mask, dtype=bool).astype(np.int8), [0]))))
    return edges[::2], edges[1::2]
