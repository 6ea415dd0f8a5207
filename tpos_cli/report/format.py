"""Numbers for people: lengths in mm or m with fixed decimals, durations, percentages."""

from __future__ import annotations

import numpy as np


def length_unit(values) -> tuple[str, float, int]:
    """(unit, scale, decimals) for a set of lengths in metres: mm below 10 cm, else m."""
    v = np.abs(np.asarray(values, dtype=float))
    v = v[np.isfinite(v)]
    big = float(np.percentile(v, 95)) if v.size else 1.0
    if big < 0.1:
        return "mm", 1000.0, 1
    return "m", 1.0, 3 if big < 10 else 2


def fmt_len(v) -> str:
    if v is None or not np.isfinite(v):
        return "n/a"
    if abs(v) < 0.1:
        return f"{v * 1000:.1f} mm"
    if abs(v) < 10:
        return f"{v:.2f} m"
    if abs(v) < 1000:
        return f"{v:.1f} m"
    return f"{v / 1000:.2f} km"


def fmt_duration(s) -> str:
    if s is None or not np.isfinite(s):
        return "n/a"
    if s < 120:
        return f"{s:.0f} s"
    if s < 7200:
        return f"{s / 60:.1f} min"
    return f"{int(s // 3600)} h {int(s % 3600 // 60):02d} min"


def pct(x) -> str:
    return "n/a" if x is None or not np.isfinite(x) else f"{100 * x:.1f} %"
