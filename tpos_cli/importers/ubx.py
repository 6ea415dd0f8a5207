"""`tpos import ubx`: u-blox binary logs, NAV-PVT messages, decoded with pyubx2.

pyubx2 finds the UBX frames in the stream, verifies each frame's checksum and decodes UBX-NAV-PVT
(u-blox 8 / M8, F9); frames with a bad checksum are skipped and counted, other messages (raw
measurements, NMEA text interleaved in the stream) are ignored. Time: GPS time from iTOW (GPS time
of week of the epoch), the week from the UTC date when `valid` says it is resolved; height: `height`
above the ellipsoid (`hMSL`, above mean sea level, is not used; their difference is the geoid
separation, printed in a note); fix: fixType 2/3/4 with gnssFixOK -> 1, or 2 when a differential
solution was applied (diffSoln, or carrSoln float/fixed); fixType 0/1/5 (no fix, dead reckoning
only, time only) -> 0. A message with a good checksum and an impossible value (latitude beyond 90 deg,
month 13, hour 99) refuses the file: it is damaged or not what it claims.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pandas as pd
from pyubx2 import ERR_LOG, UBX_PROTOCOL, VALCKSUM, UBXReader

from tpos_cli.errors import InvalidInputError
from tpos_cli.importers.gpstime import WEEK_S, gps_s_to_clock, leap_table_note, utc_calendar_to_clock
from tpos_cli.importers.result import ImportResult, gps_result, read_source
from tpos_cli.io.plausibility import H_MAX_M, H_MIN_M

# (field, lowest, highest, what it must be) of the NAV-PVT values used (u-blox interface description)
_RANGES = (("lat", -90.0, 90.0, "a latitude (±90 deg)"), ("lon", -180.0, 180.0, "a longitude (±180 deg)"),
           ("month", 1, 12, "a month (1-12)"), ("day", 1, 31, "a day (1-31)"), ("hour", 0, 23, "an hour (0-23)"),
           ("min", 0, 59, "a minute (0-59)"), ("second", 0, 60, "a second (0-60)"),
           ("iTOW", 0, WEEK_S * 1e3, "milliseconds of a GPS week"),
           ("height", H_MIN_M * 1e3, H_MAX_M * 1e3, f"a height on Earth in mm ({H_MIN_M:g} to {H_MAX_M:g} m)"))


def read_nav_pvt(data: bytes, name: str = "UBX") -> tuple[pd.DataFrame, int]:
    """NAV-PVT fields of every checksum-valid frame (contract units: deg, m, m/s) and the number of
    frames skipped for a bad checksum or a damaged header."""
    bad = [0]

    def count(_err) -> None:
        bad[0] += 1

    stream = io.BytesIO(data)
    reader = UBXReader(stream, protfilter=UBX_PROTOCOL, validate=VALCKSUM, quitonerror=ERR_LOG, errorhandler=count)
    recs = []
    while True:
        at = stream.tell()
        try:
            raw, msg = reader.read()
        except UnicodeDecodeError:  # pyubx2 decodes a '$' it meets as NMEA text even when filtered out
            bad[0] += 1
            if stream.tell() == at:  # nothing consumed: never loop on the same bytes
                break
            continue
        if raw is None:
            break
        if msg is None or msg.identity != "NAV-PVT":
            continue
        rec = {k: getattr(msg, k) for k in ("iTOW", "year", "month", "day", "hour", "min", "second", "nano",
                                             "validDate", "validTime", "fullyResolved", "fixType", "gnssFixOk",
                                             "diffSoln", "carrSoln", "numSV", "lat", "lon", "height", "hMSL",
                                             "hAcc", "vAcc", "velN", "velE", "velD")}
        resolved = rec["validDate"] and rec["validTime"] and rec["fullyResolved"]
        for field, lo, hi, what in _RANGES:
            if field in ("lat", "lon", "height") and not rec["gnssFixOk"]:
                continue  # no position: the receiver may leave anything there
            if field in ("month", "day", "hour", "min", "second") and not resolved:
                continue
            if not lo <= rec[field] <= hi:
                raise InvalidInputError(f"{name}: NAV-PVT message {len(recs) + 1} (iTOW {rec['iTOW']} ms): {field} "
                                        f"{rec[field]} is not {what}; the file is damaged (nothing written)")
        recs.append(rec)
    return pd.DataFrame(recs), bad[0]


def import_ubx(path: Path, *, clock: str = "gps_tow") -> ImportResult:
    """Read the NAV-PVT messages of a u-blox log into a contract `gps` table."""
    path = Path(path)
    data = read_source(path, clock, text=False)
    r, bad = read_nav_pvt(data, str(path))
    if r.empty:
        raise InvalidInputError(f"{path}: no UBX NAV-PVT messages (enable UBX-NAV-PVT output on the receiver)")
    n_all = len(r)
    resolved = (r["validDate"] == 1) & (r["validTime"] == 1) & (r["fullyResolved"] == 1)
    r = r[resolved].reset_index(drop=True)
    if r.empty:
        raise InvalidInputError(f"{path}: NAV-PVT present but no message has a resolved UTC date and time")
    # iTOW is the epoch's GPS time of week (ms); the UTC fields only pick the week
    tow_s = r["iTOW"].to_numpy(float) * 1e-3
    utc_second = r["second"].to_numpy(float) + r["nano"].to_numpy(float) * 1e-9
    gps_from_utc = utc_calendar_to_clock(r["year"], r["month"], r["day"], r["hour"], r["min"], utc_second, "gps")
    week = np.round((gps_from_utc - tow_s) / WEEK_S)
    t = tow_s if clock == "gps_tow" else gps_s_to_clock(week * WEEK_S + tow_s, clock)
    gnss_ok = r["gnssFixOk"].to_numpy() == 1
    diff = (r["diffSoln"].to_numpy() == 1) | (r["carrSoln"].to_numpy() > 0)
    fix = np.where(gnss_ok & r["fixType"].isin([2, 3, 4]).to_numpy(), np.where(diff, 2, 1), 0)
    h_m, h_msl_m = r["height"].to_numpy(float) * 1e-3, r["hMSL"].to_numpy(float) * 1e-3
    hacc_m = r["hAcc"].to_numpy(float) * 1e-3
    g = pd.DataFrame({
        "t": t, "lat": r["lat"].astype(float), "lon": r["lon"].astype(float), "h": h_m, "fix": fix.astype(np.int64),
        "nsat": r["numSV"].astype("Int64"),
        "vn": r["velN"] * 1e-3, "ve": r["velE"] * 1e-3, "vd": r["velD"] * 1e-3,
        # hAcc/vAcc are the receiver's accuracy estimates (about 1 sigma); split hAcc evenly over n/e
        "sigma_n": hacc_m / np.sqrt(2.0), "sigma_e": hacc_m / np.sqrt(2.0), "sigma_u": r["vAcc"] * 1e-3,
    })
    g.loc[g["fix"] == 0, ["lat", "lon", "h"]] = np.nan
    notes = [f"{path.name}: heights: NAV-PVT 'height' above the ellipsoid (geoid separation in this log, "
             f"height - hMSL: {float(np.median(h_m - h_msl_m)):.3f} m)"]
    notes += [f"{path.name}: {n_all} NAV-PVT messages ({int((~resolved).sum())} without resolved time dropped), "
              f"{bad} bad frame(s) skipped; fix {dict(sorted((int(k), int(v)) for k, v in g['fix'].value_counts().items()))}"]
    return gps_result(g, path.name, notes, leap_table_note(gps_s_to_clock(week * WEEK_S + tow_s, "unix")))
