"""`tpos import ubx`: u-blox binary logs, NAV-PVT messages (class 0x01, id 0x07, 92-byte payload).

Decoded directly with `struct` from the u-blox interface description (u-blox 8 / M8 and F9
"UBX-NAV-PVT"); every frame's Fletcher checksum is verified and bad frames are skipped. Other
messages (raw measurements, NMEA text interleaved in the stream) are ignored. Time: GPS time from
iTOW (GPS time of week of the epoch), the week from the UTC date when `valid` says it is
resolved; height: `height` above the ellipsoid (`hMSL` is not used); fix:
fixType 2/3 with gnssFixOK -> 1, or 2 when a differential solution was applied (diffSoln, or
carrSoln float/fixed); fixType 0/1/5 (no fix, dead reckoning only, time only) -> 0.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pandas as pd

from tpos_cli.errors import InvalidInputError
from tpos_cli.importers.gpstime import WEEK_S, gps_s_to_clock, utc_calendar_to_clock
from tpos_cli.importers.result import ImportResult, read_source

SYNC = b"\xb5\x62"
NAV_PVT = (0x01, 0x07)
_PVT = struct.Struct("<IHBBBBBBIiBBBBiiiiIIiiiiiIIHBBi")  # first 84 bytes of the payload (to headMot..)


def _frames(data: bytes):
    """Yield (class, id, payload) of every checksum-valid UBX frame; count the bad ones."""
    i, bad = 0, 0
    n = len(data)
    while True:
        i = data.find(SYNC, i)
        if i < 0 or i + 8 > n:
            break
        length = data[i + 4] | (data[i + 5] << 8)
        end = i + 6 + length
        if end + 2 > n:
            break
        ck_a = ck_b = 0
        for byte in data[i + 2 : end]:
            ck_a = (ck_a + byte) & 0xFF
            ck_b = (ck_b + ck_a) & 0xFF
        if data[end] == ck_a and data[end + 1] == ck_b:
            yield data[i + 2], data[i + 3], data[i + 6 : end]
            i = end + 2
        else:
            bad += 1
            i += 2  # a false sync inside other data: resynchronise on the next one
    _frames.bad = bad  # type: ignore[attr-defined]


def decode_nav_pvt(payload: bytes) -> dict:
    """Fields of one NAV-PVT payload in contract units (deg, m, m/s)."""
    (itow, year, month, day, hour, minute, sec, valid, tacc, nano, fixtype, flags, _flags2, numsv,
     lon, lat, height, hmsl, hacc, vacc, veln, vele, veld, _gspeed, _headmot, sacc, _headacc, pdop,
     _flags3, _r1, _r2) = _PVT.unpack_from(payload, 0)
    return {
        "itow_ms": itow, "year": year, "month": month, "day": day, "hour": hour, "minute": minute,
        "second": sec + nano * 1e-9, "valid": valid, "fix_type": fixtype, "flags": flags, "nsat": numsv,
        "lat": lat * 1e-7, "lon": lon * 1e-7, "h": height * 1e-3, "h_msl": hmsl * 1e-3,
        "hacc_m": hacc * 1e-3, "vacc_m": vacc * 1e-3, "vn": veln * 1e-3, "ve": vele * 1e-3, "vd": veld * 1e-3,
        "sacc_mps": sacc * 1e-3, "pdop": pdop * 0.01,
    }


def import_ubx(path: Path, *, clock: str = "gps_tow") -> ImportResult:
    """Read the NAV-PVT messages of a u-blox log into a contract `gps` table."""
    path = Path(path)
    data = read_source(path, clock)
    recs = [decode_nav_pvt(p) for c, i, p in _frames(data) if (c, i) == NAV_PVT and len(p) == 92]
    bad = getattr(_frames, "bad", 0)
    if not recs:
        raise InvalidInputError(f"{path}: no UBX NAV-PVT messages (enable UBX-NAV-PVT output on the receiver)")
    r = pd.DataFrame(recs)
    # valid bit 0 validDate, bit 1 validTime, bit 2 fullyResolved
    resolved = (r["valid"] & 0x7) == 0x7
    r = r[resolved].reset_index(drop=True)
    if r.empty:
        raise InvalidInputError(f"{path}: NAV-PVT present but no message has a resolved UTC date and time")
    # iTOW is the epoch's GPS time of week (ms); the UTC fields only pick the week
    tow_s = r["itow_ms"].to_numpy(float) * 1e-3
    gps_from_utc = utc_calendar_to_clock(r["year"], r["month"], r["day"], r["hour"], r["minute"], r["second"], "gps")
    week = np.round((gps_from_utc - tow_s) / WEEK_S)
    t = tow_s if clock == "gps_tow" else gps_s_to_clock(week * WEEK_S + tow_s, clock)
    flags = r["flags"].to_numpy(np.int64)
    gnss_ok = (flags & 0x01) == 0x01
    diff = ((flags & 0x02) == 0x02) | (((flags >> 6) & 0x3) > 0)  # diffSoln, carrSoln
    fix = np.where(gnss_ok & r["fix_type"].isin([2, 3, 4]).to_numpy(), np.where(diff, 2, 1), 0)
    g = pd.DataFrame({
        "t": t, "lat": r["lat"], "lon": r["lon"], "h": r["h"], "fix": fix.astype(np.int64),
        "nsat": r["nsat"].astype("Int64"), "vn": r["vn"], "ve": r["ve"], "vd": r["vd"],
        # hAcc/vAcc are the receiver's accuracy estimates (about 1 sigma); split hAcc evenly over n/e
        "sigma_n": r["hacc_m"] / np.sqrt(2.0), "sigma_e": r["hacc_m"] / np.sqrt(2.0), "sigma_u": r["vacc_m"],
    })
    g.loc[g["fix"] == 0, ["lat", "lon", "h"]] = np.nan
    notes = [f"{path.name}: heights written above the ellipsoid (geoid separation in this log: "
             f"{float((r['h'] - r['h_msl']).median()):.3f} m)"]
    notes += [f"{path.name}: {len(recs)} NAV-PVT messages ({int((~resolved).sum())} without resolved time dropped), "
             f"{bad} bad-checksum frame(s) skipped; fix {dict(sorted((int(k), int(v)) for k, v in g['fix'].value_counts().items()))}"]
    return ImportResult({"gps": g}, {}, tuple(notes))
