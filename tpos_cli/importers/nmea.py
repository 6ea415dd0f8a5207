"""`tpos import nmea`: NMEA 0183 GGA/RMC/VTG/GSA sentences of a GPS(-WAAS) receiver.

Sentences are found anywhere in the input (a plain log, or NMEA interleaved in a binary u-blox
stream), any talker (GP, GN, GL, ...); a sentence whose checksum is wrong is skipped and counted.
One row per GGA epoch: position, fix quality (0 -> 0; 1 GPS, 3 PPS -> 1; 2 DGPS/SBAS, 4 RTK fixed,
5 RTK float -> 2; 6 dead reckoning, 7 manual, 8 simulator -> 0), satellites, HDOP; ellipsoidal
height = altitude above the geoid + geoid separation (GGA fields 9 and 11; NMEA 0183 v4.10). Speed
and course over ground from RMC (or VTG) give vn = s cos(course), ve = s sin(course); vd is not in
NMEA. The date comes from RMC; GGA times roll over midnight onto the next day.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pandas as pd

from tpos_cli.errors import InvalidInputError
from tpos_cli.importers.gpstime import utc_calendar_to_clock
from tpos_cli.importers.result import ImportResult, read_source

KNOT_MPS = 1852.0 / 3600.0
GGA_QUALITY_TO_FIX = {0: 0, 1: 1, 2: 2, 3: 1, 4: 2, 5: 2, 6: 0, 7: 0, 8: 0}
_SENTENCE = re.compile(rb"\$([A-Z]{2})([A-Z]{3}),([^\r\n$*]*)\*([0-9A-Fa-f]{2})")


def checksum_ok(body: bytes, checksum: bytes) -> bool:
    """XOR of the bytes between '$' and '*' equals the two hex digits."""
    x = 0
    for b in body:
        x ^= b
    return x == int(checksum, 16)


def _deg(value: str, hemi: str) -> float:
    """NMEA (d)ddmm.mmmm and hemisphere to signed degrees; NaN if empty."""
    if not value:
        return math.nan
    v = float(value)
    d = math.floor(v / 100.0)
    out = d + (v - 100.0 * d) / 60.0
    return -out if hemi in ("S", "W") else out


def _f(s: str) -> float:
    try:
        return float(s) if s else math.nan
    except ValueError:
        return math.nan


def _sod(hhmmss: str) -> float:
    return int(hhmmss[0:2]) * 3600.0 + int(hhmmss[2:4]) * 60.0 + float(hhmmss[4:])


def parse_nmea(data: bytes) -> tuple[pd.DataFrame, dict]:
    """Epoch table (UTC seconds of day, date, position, quality, velocity) and sentence counts."""
    counts = {"GGA": 0, "RMC": 0, "VTG": 0, "GSA": 0, "bad_checksum": 0}
    epochs: list[dict] = []
    cur: dict | None = None
    date: tuple[int, int, int] | None = None
    last_rmc: tuple[float, float, float] | None = None  # (sod, speed, course): RMC may precede its GGA
    for m in _SENTENCE.finditer(data):
        talker, kind, fields_b, ck = m.groups()
        if not checksum_ok(talker + kind + b"," + fields_b, ck):
            counts["bad_checksum"] += 1
            continue
        k = kind.decode()
        if k not in counts:
            continue
        counts[k] += 1
        f = fields_b.decode("ascii", "replace").split(",")
        try:
            if k == "GGA" and len(f) >= 11 and f[0]:
                alt, sep = _f(f[8]), _f(f[10])
                cur = {
                    "sod": _sod(f[0]), "date": date, "lat": _deg(f[1], f[2]), "lon": _deg(f[3], f[4]),
                    "quality": int(f[5] or 0), "nsat": _f(f[6]), "hdop": _f(f[7]), "alt_msl": alt,
                    "geoid_sep": sep, "speed": math.nan, "course": math.nan,
                }
                if last_rmc is not None and abs(last_rmc[0] - cur["sod"]) < 1e-6:
                    cur["speed"], cur["course"] = last_rmc[1], last_rmc[2]
                epochs.append(cur)
            elif k == "RMC" and len(f) >= 9 and f[0]:
                if len(f[8]) == 6:
                    dd, mm, yy = int(f[8][0:2]), int(f[8][2:4]), int(f[8][4:6])
                    date = (2000 + yy if yy < 80 else 1900 + yy, mm, dd)
                last_rmc = (_sod(f[0]), _f(f[6]) * KNOT_MPS, _f(f[7]))
                if cur is not None and abs(cur["sod"] - _sod(f[0])) < 1e-6:
                    cur["date"] = cur["date"] or date
                    cur["speed"], cur["course"] = _f(f[6]) * KNOT_MPS, _f(f[7])
            elif k == "VTG" and len(f) >= 7 and cur is not None:
                # VTG has no time: it belongs to the epoch of the last GGA
                cur["speed"], cur["course"] = _f(f[4]) * KNOT_MPS, _f(f[0])
        except ValueError:
            counts["bad_checksum"] += 0  # malformed field: skip the sentence
    return pd.DataFrame(epochs), counts


def import_nmea(path: Path, *, clock: str = "gps_tow") -> ImportResult:
    """Read GGA epochs (with RMC/VTG velocity) of one NMEA log into a contract `gps` table."""
    path = Path(path)
    data = read_source(path, clock)
    ep, counts = parse_nmea(data)
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
    no_sep = np.isnan(sep)
    h = ep["alt_msl"].to_numpy(float) + np.where(no_sep, 0.0, sep)
    course = np.deg2rad(ep["course"].to_numpy(float))
    speed = ep["speed"].to_numpy(float)
    g = pd.DataFrame({
        "t": t, "lat": ep["lat"], "lon": ep["lon"], "h": h, "fix": fix,
        "nsat": ep["nsat"].round().astype("Int64"), "hdop": ep["hdop"],
        "vn": speed * np.cos(course), "ve": speed * np.sin(course), "vd": np.nan,
    })
    g.loc[g["fix"] == 0, ["lat", "lon", "h"]] = np.nan
    notes = [f"{path.name}: sentences {counts}; {len(g)} epochs, fix {dict(sorted((int(k), int(v)) for k, v in g['fix'].value_counts().items()))}"]
    if no_sep.any():
        notes.append(
            f"{path.name}: {int(no_sep.sum())} GGA sentence(s) without geoid separation: their heights are above "
            "sea level, not the ellipsoid; add the geoid undulation or expect a height bias"
        )
    if np.isnan(course).any() and np.isfinite(speed).any():
        notes.append(f"{path.name}: {int(np.isnan(course).sum())} epoch(s) with speed but no course: no velocity written there")
    if g[["vn", "ve"]].isna().all().all():
        g = g.drop(columns=["vn", "ve", "vd"])
    return ImportResult({"gps": g}, {}, tuple(notes))
