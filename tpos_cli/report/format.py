"""Numbers for people: lengths in mm or m with fixed decimals, durations, percentages, UTC stamps."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

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


UNIX_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
# start_utc within this of the Unix reading of the first epoch: the logger's clock is Unix time. An export's
# first epoch may follow the log's start by an alignment (seconds to minutes); a clock of another origin
# whose stamps land within an hour of the stated start by chance is one in ~1e5 over 1980-2100.
UNIX_MATCH_S = 3600.0


def checked_start_utc(start_utc: datetime | None, t_s, now: datetime | None = None) -> tuple[datetime | None, str]:
    """The UTC of t = 0 to date the logger times `t_s` with, and a note (empty when start_utc is used as the
    contract says). docs/log-format.md: t is the logger's clock, of any origin, and start_utc the UTC of
    t = 0. A log stamped in Unix seconds whose start_utc names its first sample (navego_canada_enav: t =
    1.5e9 s, start_utc 2018) would date its epochs to 2067: when 1970-01-01 + t puts the first epoch within
    UNIX_MATCH_S of start_utc, t is Unix time and 1970-01-01 is the UTC of t = 0 (noted). Epochs after `now`
    (default: the present) any other way: (None, why), as no UTC at all beats a wrong one in a deliverable."""
    if start_utc is None:
        return None, ""
    t = np.asarray(t_s, dtype=float)
    t = t[np.isfinite(t)]
    if not t.size:
        return start_utc, ""
    now = now or datetime.now(UTC)

    def until_now(origin: datetime) -> bool:
        last = utc_strings([float(t.max())], origin, 0)[0]
        return bool(np.datetime64(last.rstrip("Z")) <= np.datetime64(now.replace(tzinfo=None), "s"))

    if until_now(start_utc):
        return start_utc, ""
    stated = start_utc.strftime("%Y-%m-%dT%H:%M:%SZ")
    if float(t.min()) < 1e11:  # timedelta's range; no Unix second of 1980-2100 is near it
        unix_first = UNIX_EPOCH + timedelta(seconds=float(t.min()))
        if abs((unix_first - start_utc).total_seconds()) <= UNIX_MATCH_S and until_now(UNIX_EPOCH):
            return UNIX_EPOCH, (
                f"t counts Unix seconds: session start_utc {stated} is the UTC of the first epoch (1970-01-01 + "
                f"{float(t.min()):.1f} s = {unix_first.strftime('%Y-%m-%dT%H:%M:%S.%f')[:-5]}Z), not of t = 0 as "
                "docs/log-format.md says; UTC times are 1970-01-01 + t"
            )
    return None, (
        f"session start_utc {stated} + t (up to {float(t.max()):.0f} s) dates epochs "
        f"to {utc_strings([float(t.max())], start_utc, 0)[0]}, after today: start_utc is not the UTC of t = 0 "
        "(docs/log-format.md); no UTC times written"
    )
