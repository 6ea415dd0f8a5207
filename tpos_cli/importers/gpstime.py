"""GPS time scales: GPS week/seconds, seconds since the GPS epoch, UNIX (UTC) time, and leap seconds.

GPS time runs without leap seconds from 1980-01-06T00:00:00 UTC; UNIX time counts UTC seconds from
1970-01-01 without leap seconds, so GPS - UTC jumps by one second at each leap second (IS-GPS-200
§20.3.3.5.2.4; table from IERS Bulletin C).
"""

from __future__ import annotations

import calendar

import numpy as np

GPS_EPOCH_UNIX_S = 315964800.0  # 1980-01-06T00:00:00Z in UNIX seconds
WEEK_S = 604800.0

# (UNIX time at which the new offset starts, GPS - UTC in seconds after it)
_LEAPS = [
    ("1981-07-01", 1), ("1982-07-01", 2), ("1983-07-01", 3), ("1985-07-01", 4), ("1988-01-01", 5),
    ("1990-01-01", 6), ("1991-01-01", 7), ("1992-07-01", 8), ("1993-07-01", 9), ("1994-07-01", 10),
    ("1996-01-01", 11), ("1997-07-01", 12), ("1999-01-01", 13), ("2006-01-01", 14), ("2009-01-01", 15),
    ("2012-07-01", 16), ("2015-07-01", 17), ("2017-01-01", 18),
]
_LEAP_UNIX_S = np.array([calendar.timegm(tuple(int(x) for x in d.split("-")) + (0, 0, 0)) for d, _ in _LEAPS], float)
_LEAP_S = np.array([n for _, n in _LEAPS], float)

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
