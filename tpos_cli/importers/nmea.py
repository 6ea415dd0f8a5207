"""`tpos import nmea`: NMEA 0183 GGA/RMC/VTG/GSA sentences of a GPS(-WAAS) receiver, read with pynmea2.

Sentences are found anywhere in the input (a plain log, or NMEA interleaved in a binary u-blox
stream), any talker (GP, GN, GL, ...), and parsed by pynmea2; a sentence whose checksum is wrong is
skipped and counted. A sentence with a good checksum but an impossible value (latitude beyond 90 deg,
hour 99, month 13) is refused: the file is damaged or not what it claims, and no session is written.
One row per GGA epoch: position, fix quality (0 -> 0; 1 GPS, 3 PPS -> 1; 2 DGPS/SBAS, 4 RTK fixed,
5 RTK float -> 2; 6 dead reckoning, 7 manual, 8 simulator -> 0), satellites, HDOP. Heights: GGA gives
the altitude above mean sea level (the geoid) and the geoid separation (fields 9 and 11; NMEA 0183
v4.10); the ellipsoidal height the contract wants is their sum. Without a separation the height is not
called ellipsoidal: `geoid_sep_m` (the undulation at the site) converts it, else the import is refused.
Speed and course over ground from RMC (or VTG) give vn = s cos(course), ve = s sin(course); vd is not
in NMEA. The date comes from RMC; GGA times roll over midnight onto the next day.
"""

from __future__ import annotations

import datetime as dt
import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pynmea2

from tpos_cli.errors import InvalidInputError
from tpos_cli.importers.gpstime import leap_table_note, utc_calendar_to_clock
from tpos_cli.importers.result import ImportResult, read_source
from tpos_cli.io.plausibility import H_MAX_M, H_MIN_M

KNOT_MPS = 1852.0 / 3600.0
GGA_QUALITY_TO_FIX = {0: 0, 1: 1, 2: 2, 3: 1, 4: 2, 5: 2, 6: 0, 7: 0, 8: 0}
# A candidate sentence anywhere in a byte stream: talker, type, fields, checksum (pynmea2 parses it).
_SENTENCE = re.compile(rb"\$([A-Z]{2})([A-Z]{3}),([^\r\n$*]*)\*([0-9A-Fa-f]{2})")
_KINDS = ("GGA", "RMC", "VTG", "GSA")


class _BadField(ValueError):
    """A checksum-valid sentence with an impossible value (named in the message)."""


def _f(x) -> float:
    try:
        return float(x) if x not in (None, "") else math.nan
    except (TypeError, ValueError):
        return math.nan


def _sod(msg) -> float:
    """UTC seconds of day of a GGA/RMC sentence; an impossible time is a _BadField."""
    raw = msg.data[0]
    try:
        t = msg.timestamp
    except ValueError:
        raise _BadField(f"time {raw!r} is not hhmmss.ss (hour 0-23, minutes and seconds 0-59)") from None
    if not isinstance(t, dt.time):
        raise _BadField(f"time {raw!r} is not hhmmss.ss")
    return t.hour * 3600.0 + t.minute * 60.0 + t.second + t.microsecond * 1e-6


def _position(msg) -> tuple[float, float]:
    """Signed degrees of a GGA position (NaN when empty); latitude beyond 90 or longitude beyond 180,
    or minutes of 60 or more, are _BadField."""
    out = []
    for raw, hemi, lim, name in ((msg.lat, msg.lat_dir, 90.0, "latitude"), (msg.lon, msg.lon_dir, 180.0, "longitude")):
        if not raw:
            out.append(math.nan)
            continue
        try:
            v = float(raw)
        except ValueError:
            raise _BadField(f"{name} {raw!r} is not a number") from None
        deg, minutes = math.floor(v / 100.0), v - 100.0 * math.floor(v / 100.0)
        if minutes >= 60.0 or hemi not in (("N", "S") if name == "latitude" else ("E", "W")):
            raise _BadField(f"{name} {raw!r} {hemi!r} is not (d)ddmm.mmm with a {'N/S' if name == 'latitude' else 'E/W'} hemisphere")
        val = deg + minutes / 60.0
        if val > lim:
            raise _BadField(f"{name} {val:g} deg is outside ±{lim:g}")
        out.append(-val if hemi in ("S", "W") else val)
    return out[0], out[1]


def _date(msg) -> tuple[int, int, int] | None:
    raw = msg.data[8] if len(msg.data) > 8 else ""
    if not raw:
        return None
    try:
        d = msg.datestamp
    except ValueError:
        d = None
    if not isinstance(d, dt.date):  # pynmea2 hands back the text it could not read as a date
        raise _BadField(f"date {raw!r} is not ddmmyy (day 1-31, month 1-12)")
    return (d.year, d.month, d.day)


def parse_nmea(data: bytes, name: str = "NMEA") -> tuple[pd.DataFrame, dict]:
    """Epoch table (UTC seconds of day, date, position, quality, velocity) and sentence counts.

    Raises InvalidInputError naming the line and the field of the first checksum-valid sentence
    with an impossible value."""
    counts = {"GGA": 0, "RMC": 0, "VTG": 0, "GSA": 0, "bad_checksum": 0}
    epochs: list[dict] = []
    cur: dict | None = None
    date: tuple[int, int, int] | None = None
    last_rmc: tuple[float, float, float] | None = None  # (sod, speed, course): RMC may precede its GGA
    for m in _SENTENCE.finditer(data):
        kind = m.group(2).decode()
        if kind not in _KINDS:
            continue
        try:
            msg = pynmea2.parse(m.group(0).decode("ascii"), check=True)
        except (pynmea2.ChecksumError, UnicodeDecodeError):
            counts["bad_checksum"] += 1
            continue
        except pynmea2.ParseError:
            counts["bad_checksum"] += 1
            continue
        counts[kind] += 1
        try:
            if kind == "GGA" and msg.data[0]:
                lat, lon = _position(msg)
                alt = _f(msg.altitude)
                if math.isfinite(alt) and not H_MIN_M <= alt <= H_MAX_M:
                    raise _BadField(f"altitude {alt:g} m is not a height on Earth ({H_MIN_M:g} to {H_MAX_M:g} m)")
                cur = {
                    "sod": _sod(msg), "date": date, "lat": lat, "lon": lon,
                    "quality": int(_f(msg.gps_qual)) if math.isfinite(_f(msg.gps_qual)) else 0,
                    "nsat": _f(msg.num_sats), "hdop": _f(msg.horizontal_dil), "alt_msl": _f(msg.altitude),
                    "geoid_sep": _f(msg.geo_sep), "speed": math.nan, "course": math.nan,
                }
                if last_rmc is not None and abs(last_rmc[0] - cur["sod"]) < 1e-6:
                    cur["speed"], cur["course"] = last_rmc[1], last_rmc[2]
                epochs.append(cur)
            elif kind == "RMC" and msg.data[0]:
                date = _date(msg) or date
                sod = _sod(msg)
                last_rmc = (sod, _f(msg.spd_over_grnd) * KNOT_MPS, _f(msg.true_course))
                if cur is not None and abs(cur["sod"] - sod) < 1e-6:
                    cur["date"] = cur["date"] or date
                    cur["speed"], cur["course"] = last_rmc[1], last_rmc[2]
            elif kind == "VTG" and cur is not None:
                # VTG has no time: it belongs to the epoch of the last GGA
                cur["speed"], cur["course"] = _f(msg.spd_over_grnd_kts) * KNOT_MPS, _f(msg.true_track)
        except _BadField as exc:
            line = data.count(b"\n", 0, m.start()) + 1
            raise InvalidInputError(f"{name}: line {line}: {kind} sentence: {exc}; the file is damaged (nothing written)") from None
    return pd.DataFrame(epochs), counts


def import_nmea(path: Path, *, clock: str = "gps_tow", geoid_sep_m: float | None = None) -> ImportResult:
    """Read GGA epochs (with RMC/VTG velocity) of one NMEA log into a contract `gps` table.

    `geoid_sep_m`: the geoid undulation at the site (m), used for GGA sentences without a geoid
    separation; without it such sentences make the import fail (their heights are above sea level)."""
    path = Path(path)
    data = read_source(path, clock)
    ep, counts = parse_nmea(data, path.name)
    if ep.empty:
        raise InvalidInputError(f"{path}: no valid NMEA GGA sentences ({counts['bad_checksum']} with a bad checksum)")
    # GGA epochs before the first RMC take the first known date; then roll over at midnight
    dates = ep["date"].ffill().bfill()
    if dates.isna().all():
        raise InvalidInputError(f"{path}: no RMC sentence with a date; the GGA times cannot be placed on a clock")
    y = np.array([d[0] for d in dates]); mo = np.array([d[1] for d in dates]); dd = np.array([d[2] for d in dates])
    sod = ep["sod"].to_numpy(float)
    day_carry = np.concatenate([[0], np.cumsum(np.diff(sod) < -43200.0)])  # midnight rollovers
    t = utc_calendar_to_clock(y, mo, dd, 0, 0, sod + 86400.0 * day_carry, clock)
    fix = np.array([GGA_QUALITY_TO_FIX.get(int(q), 0) for q in ep["quality"]], np.int64)
    sep = ep["geoid_sep"].to_numpy(float)
    no_sep = np.isnan(sep) & np.isfinite(ep["alt_msl"].to_numpy(float)) & (fix > 0)
    if no_sep.any() and geoid_sep_m is None:
        raise InvalidInputError(
            f"{path}: {int(no_sep.sum())} GGA sentence(s) give the altitude above mean sea level without the geoid "
            "separation, so the ellipsoidal height the session needs is unknown; pass --geoid-sep-m N (the geoid "
            "undulation at the site, e.g. from EGM96/EGM2008) or configure the receiver to output it")
    sep_used = np.where(np.isnan(sep), np.nan if geoid_sep_m is None else geoid_sep_m, sep)
    h = ep["alt_msl"].to_numpy(float) + sep_used
    course = np.deg2rad(ep["course"].to_numpy(float))
    speed = ep["speed"].to_numpy(float)
    g = pd.DataFrame({
        "t": t, "lat": ep["lat"], "lon": ep["lon"], "h": h, "fix": fix,
        "nsat": ep["nsat"].round().astype("Int64"), "hdop": ep["hdop"],
        "vn": speed * np.cos(course), "ve": speed * np.sin(course), "vd": np.nan,
    })
    g.loc[g["fix"] == 0, ["lat", "lon", "h"]] = np.nan
    notes = [f"{path.name}: sentences {counts}; {len(g)} epochs, fix {dict(sorted((int(k), int(v)) for k, v in g['fix'].value_counts().items()))}"]
    n_gga_sep = int(np.isfinite(sep).sum())
    if n_gga_sep:
        notes.append(f"{path.name}: heights: GGA altitude above mean sea level + the GGA geoid separation "
                     f"(median {float(np.nanmedian(sep)):.3f} m) = ellipsoidal, in {n_gga_sep} epoch(s)")
    if no_sep.any():
        notes.append(f"{path.name}: heights: GGA altitude above mean sea level + --geoid-sep-m {geoid_sep_m:g} m = "
                     f"ellipsoidal, in {int(no_sep.sum())} epoch(s) without a separation in the log")
    leap = leap_table_note(utc_calendar_to_clock(y, mo, dd, 0, 0, sod, "unix"))
    if leap:
        notes.append(f"{path.name}: {leap}")
    if np.isnan(course).any() and np.isfinite(speed).any():
        notes.append(f"{path.name}: {int(np.isnan(course).sum())} epoch(s) with speed but no course: no velocity written there")
    if g[["vn", "ve"]].isna().all().all():
        g = g.drop(columns=["vn", "ve", "vd"])
    return ImportResult({"gps": g}, {}, tuple(notes))
