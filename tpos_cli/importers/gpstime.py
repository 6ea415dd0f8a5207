"""GPS time scales: GPS week/seconds, seconds since the GPS epoch, UNIX (UTC) time, and leap seconds.

GPS time runs without leap seconds from 1980-01-06T00:00:00 UTC; UNIX time counts UTC seconds from
1970-01-01 without leap seconds, so GPS - UTC jumps by one second at each leap second (IS-GPS-200
§20.3.3.5.2.4). GPS - UTC = (TAI - UTC) - 19 s.

The leap seconds come from ERFA's table (pyerfa, `erfa.leap_seconds`): the IAU SOFA-derived library
that astropy uses, updated with each IERS Bulletin C announcement, so `pip install -U pyerfa` brings a
new leap second without a change here. (pynmeagps, which pyubx2 pulls in, also has a table, but only
as a per-date scalar lookup without a validity check.) `leap_table_note` says when a log's date lies
past the years the installed table vouches for.
"""

from __future__ import annotations

import calendar
import warnings

import erfa
import numpy as np

GPS_EPOCH_UNIX_S = 315964800.0  # 1980-01-06T00:00:00Z in UNIX seconds
WEEK_S = 604800.0
TAI_MINUS_GPS_S = 19.0


def _leap_table() -> tuple[np.ndarray, np.ndarray]:
    """(UNIX time at which each GPS - UTC offset starts, the offset in s) from ERFA's table."""
    table = erfa.leap_seconds.get()
    start = np.array([calendar.timegm((int(y), int(m), 1, 0, 0, 0)) for y, m in zip(table["year"], table["month"])], float)
    gps_utc = np.asarray(table["tai_utc"], float) - TAI_MINUS_GPS_S
    keep = start > GPS_EPOCH_UNIX_S  # GPS - UTC is 0 at the GPS epoch; earlier rows do not apply
    return start[keep], gps_utc[keep]


_LEAP_UNIX_S, _LEAP_S = _leap_table()


def leap_table_note(unix_s) -> str | None:
    """A warning when the latest of `unix_s` is past the years ERFA's table vouches for, else None."""
    u = np.asarray(unix_s, float)
    u = u[np.isfinite(u)]
    if u.size == 0:
        return None
    y, mo, d = (int(x) for x in np.datetime64(int(u.max()), "s").astype(object).timetuple()[:3])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        erfa.dat(y, mo, d, 0.0)
    if any("dubious" in str(w.message) for w in caught):
        return (f"the leap-second table of the installed pyerfa {erfa.__version__} may be out of date for "
                f"{y:04d}-{mo:02d}-{d:02d} (`pip install -U pyerfa`); GPS - UTC taken as {int(_LEAP_S[-1])} s")
    return None

CLOCKS = ("gps_tow", "gps", "unix")  # clocks an importer may write into a session's `t`


def leap_seconds_at_unix(unix_s):
    """GPS - UTC (s) at UNIX times `unix_s` (array-like)."""
    i = np.searchsorted(_LEAP_UNIX_S, np.asarray(unix_s, float), side="right")
    return np.where(i > 0, _LEAP_S[np.maximum(i - 1, 0)], 0.0)


def unix_to_gps_s(unix_s):
    """Seconds since the GPS epoch (GPS time scale) from UNIX (UTC) seconds."""
    u = np.asarray(unix_s, float)
    return u - GPS_EPOCH_UNIX_S + leap_seconds_at_unix(u)


def gps_s_to_unix(gps_s):
    """UNIX (UTC) seconds from seconds since the GPS epoch (exact except within a leap second)."""
    g = np.asarray(gps_s, float)
    approx = g + GPS_EPOCH_UNIX_S
    return approx - leap_seconds_at_unix(approx - leap_seconds_at_unix(approx))


def gps_s_to_clock(gps_s, clock: str):
    """Express GPS-scale seconds since the GPS epoch on `clock` ("gps_tow", "gps" or "unix")."""
    g = np.asarray(gps_s, float)
    day = np.floor(g / 86400.0)
    return gps_day_sod_to_clock(day.astype("int64"), g - day * 86400.0, clock)


def gps_day_sod_to_clock(gps_day, sod_s, clock: str):
    """GPS time given as whole days since the GPS epoch plus seconds of day, on `clock`.

    Keeping days and seconds apart keeps `gps_tow` exact to the input's decimals (a float64 of
    seconds since 1980 only resolves about 0.2 µs).
    """
    day = np.asarray(gps_day, dtype="int64")
    sod = np.asarray(sod_s, float)
    if clock == "gps":
        return day * 86400.0 + sod
    if clock == "gps_tow":
        # one log never spans a week boundary in practice; stay continuous if it does
        week0 = day.min() // 7 if day.size else 0
        return (day - 7 * week0) * 86400.0 + sod
    if clock == "unix":
        g = day * 86400.0 + sod
        return g + GPS_EPOCH_UNIX_S - leap_seconds_at_unix(gps_s_to_unix(g))
    raise ValueError(f"`clock` must be one of {CLOCKS}, got {clock!r}")


def calendar_to_days_sod(year, month, day, hour, minute, second):
    """(days since 1970-01-01, seconds of day) of calendar fields, vectorized."""
    y, mo, d = (np.atleast_1d(np.asarray(a, dtype="int64")) for a in (year, month, day))
    dates = (y - 1970).astype("datetime64[Y]") + (mo - 1).astype("timedelta64[M]")
    days = (dates.astype("datetime64[D]") + (d - 1).astype("timedelta64[D]")).astype("int64")
    sod = np.asarray(hour, float) * 3600.0 + np.asarray(minute, float) * 60.0 + np.asarray(second, float)
    return days, sod


GPS_EPOCH_UNIX_DAYS = 3657  # 1980-01-06 is day 3657 after 1970-01-01


def gpst_calendar_to_clock(year, month, day, hour, minute, second, clock: str):
    """A GPST calendar time (as RTKLIB prints it) on `clock`."""
    days, sod = calendar_to_days_sod(year, month, day, hour, minute, second)
    return gps_day_sod_to_clock(days - GPS_EPOCH_UNIX_DAYS, sod, clock)


def utc_calendar_to_clock(year, month, day, hour, minute, second, clock: str):
    """A UTC calendar time on `clock` (adds GPS - UTC leap seconds for the GPS clocks)."""
    days, sod = calendar_to_days_sod(year, month, day, hour, minute, second)
    if clock == "unix":
        return days * 86400.0 + sod
    leap = leap_seconds_at_unix(days * 86400.0 + sod)
    sod = sod + leap
    carry = np.floor(sod / 86400.0).astype("int64")
    return gps_day_sod_to_clock(days - GPS_EPOCH_UNIX_DAYS + carry, sod - carry * 86400.0, clock)


def unix_to_clock(unix_s, clock: str):
    """UNIX (UTC) seconds on `clock`."""
    u = np.asarray(unix_s, float)
    if clock == "unix":
        return u
    return gps_s_to_clock(unix_to_gps_s(u), clock)
