"""Numbers for people: lengths in mm or m with fixed decimals, durations, percentages, UTC stamps."""

from __future__ import annotations

from datetime import UTC, datetime

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


def utc_strings(t_s, start_utc: datetime | None, decimals: int = 3) -> np.ndarray | None:
    """ISO-8601 UTC stamps ("...Z") of logger-clock times, millisecond resolution; None without start_utc."""
    if start_utc is None:
        return None
    t = np.asarray(t_s, dtype=float)
    base = np.datetime64(start_utc.replace(tzinfo=None), "ns")
    stamps = base + np.round(t * 1e9).astype("int64").astype("timedelta64[ns]")
    unit = {0: "s", 3: "ms", 6: "us"}[decimals]
    return np.char.add(np.datetime_as_string(stamps, unit=unit), "Z")


def checked_start_utc(start_utc: datetime | None, t_s, now: datetime | None = None) -> tuple[datetime | None, str]:
    """`start_utc` (the contract's UTC of t = 0) if the logger times `t_s` it dates end no later than
    `now` (default: the present), else (None, why). A session stamped in Unix seconds or GPS time
    whose start_utc names its first sample (t = 1.5e9 s) would otherwise date its epochs decades
    ahead (navego_canada_enav: 2067): no UTC at all beats a wrong one in a deliverable."""
    if start_utc is None:
        return None, ""
    t = np.asarray(t_s, dtype=float)
    t = t[np.isfinite(t)]
    if not t.size:
        return start_utc, ""
    now = now or datetime.now(UTC)
    last = utc_strings([float(t.max())], start_utc, 0)[0]
    if np.datetime64(last.rstrip("Z")) <= np.datetime64(now.replace(tzinfo=None), "s"):
        return start_utc, ""
    return None, (
        f"session start_utc {start_utc.strftime('%Y-%m-%dT%H:%M:%SZ')} + t (up to {float(t.max()):.0f} s) dates epochs "
        f"to {last}, after today: start_utc is not the UTC of t = 0 (docs/log-format.md); no UTC times written"
    )
