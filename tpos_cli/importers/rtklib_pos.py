"""`tpos import rtklib-pos`: RTKLIB solution files (rnx2rtkp / rtkpost / rtknavi `.pos`).

Reads the lat/lon/height form (`%  GPST latitude(deg) longitude(deg) height(m) Q ns sdn(m) ...`),
with time as `yyyy/mm/dd hh:mm:ss.sss` (GPST, UTC or JST, from the header) or `week tow`, and the
optional velocity columns `vn(m/s) ve(m/s) vu(m/s)`. Heights are ellipsoidal unless the header says
"geodetic" (then they are above the geoid and a note says so). The solution quality Q maps to the
contract's `fix`: 1 fix, 2 float, 3 SBAS, 4 DGPS, 6 PPP -> 2 (differential); 5 single -> 1;
0 -> 0 (RTKLIB manual, Table "Solution status").
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from tpos_cli.errors import InvalidInputError
from tpos_cli.importers.gpstime import (
    WEEK_S,
    gps_s_to_clock,
    gpst_calendar_to_clock,
    utc_calendar_to_clock,
)
from tpos_cli.importers.result import ImportResult, read_source

Q_TO_FIX = {0: 0, 1: 2, 2: 2, 3: 2, 4: 2, 5: 1, 6: 2}
_DATE = re.compile(r"^(\d{4})/(\d{1,2})/(\d{1,2})$")


def _header(lines: list[str]) -> tuple[list[str], str, bool]:
    """Column labels of the last '%' line, time system, and whether heights are geodetic (geoid)."""
    labels: list[str] = []
    time_sys = "GPST"
    geoid = False
    for line in lines:
        if not line.startswith("%"):
            break
        low = line.lower()
        if "height" in low and ("geodetic" in low or "msl" in low) and "ellipsoidal" not in low:
            geoid = True
        toks = line[1:].split()
        if toks and toks[0] in ("GPST", "UTC", "JST"):
            time_sys = toks[0]
            labels = toks
    return labels, time_sys, geoid


def import_rtklib_pos(path: Path, *, clock: str = "gps_tow") -> ImportResult:
    """Read one .pos file into a contract `gps` table on `clock` ("gps_tow", "gps" or "unix")."""
    path = Path(path)
    text = read_source(path, clock).decode("utf-8", errors="replace")
    lines = text.splitlines()
    labels, time_sys, geoid = _header(lines)
    if not labels:
        raise InvalidInputError(f"{path}: no RTKLIB column header ('%  GPST  latitude(deg) ...'); is this a .pos file?")
    lab = [x.lower() for x in labels]
    if "latitude(deg)" not in lab:
        raise InvalidInputError(
            f"{path}: only the lat/lon/height solution form is supported (header has {' '.join(labels[:5])} ...); "
            "set RTKLIB 'Solution Format' to Lat/Lon/Height in degrees"
        )
    rows = [ln.split() for ln in lines if ln.strip() and not ln.startswith("%")]
    if not rows:
        raise InvalidInputError(f"{path}: no solution rows")
    # the time takes two tokens (date + time, or week + tow); labels have one token for it
    ncol = len(labels) + 1
    bad = [i for i, r in enumerate(rows) if len(r) < ncol - 0 and len(r) < 7]
    if bad:
        raise InvalidInputError(f"{path}: solution row {bad[0] + 1} has {len(rows[bad[0]])} fields")
    width = min(len(r) for r in rows)
    arr = [r[:width] for r in rows]
    df = pd.DataFrame(arr, columns=["_d", "_t"] + labels[1 : width - 1])
    num = {c: pd.to_numeric(df[c], errors="coerce").to_numpy(float) for c in df.columns[2:]}

    if _DATE.match(str(df["_d"].iloc[0])):
        ymd = df["_d"].str.split("/", expand=True).astype(int)
        hms = df["_t"].str.split(":", expand=True)
        h, mi, s = hms[0].astype(int), hms[1].astype(int), hms[2].astype(float)
        y, mo, d = ymd[0], ymd[1], ymd[2]
        if time_sys == "GPST":
            t = gpst_calendar_to_clock(y, mo, d, h, mi, s, clock)
        else:
            h = h - (9 if time_sys == "JST" else 0)  # JST = UTC + 9 h; negative hours roll back via day arithmetic
            t = utc_calendar_to_clock(y, mo, d, h, mi, s, clock)
    else:
        week = pd.to_numeric(df["_d"], errors="coerce").to_numpy(float)
        tow = pd.to_numeric(df["_t"], errors="coerce").to_numpy(float)
        if not np.isfinite(week).all() or not np.isfinite(tow).all():
            raise InvalidInputError(f"{path}: time is neither 'yyyy/mm/dd hh:mm:ss' nor 'week tow'")
        t = tow if clock == "gps_tow" else gps_s_to_clock(week * WEEK_S + tow, clock)
        if time_sys != "GPST":
            raise InvalidInputError(f"{path}: week/tow times in {time_sys} are not supported")

    def col(label):
        for k in num:
            if k.lower() == label:
                return num[k]
        return None

    q = col("q")
    if q is None:
        raise InvalidInputError(f"{path}: no Q column")
    fix = np.array([Q_TO_FIX.get(int(v), 0) if np.isfinite(v) else 0 for v in q], np.int64)
    out = {
        "t": np.asarray(t, float),
        "lat": col("latitude(deg)"),
        "lon": col("longitude(deg)"),
        "h": col("height(m)"),
        "fix": fix,
    }
    ns = col("ns")
    if ns is not None:
        out["nsat"] = ns
    vn, ve, vu = col("vn(m/s)"), col("ve(m/s)"), col("vu(m/s)")
    if vn is not None and ve is not None and vu is not None:
        out.update(vn=vn, ve=ve, vd=-vu)  # RTKLIB prints up; the contract wants down
    for c, lab_ in (("sigma_n", "sdn(m)"), ("sigma_e", "sde(m)"), ("sigma_u", "sdu(m)")):
        v = col(lab_)
        if v is not None:
            out[c] = v
    g = pd.DataFrame(out)
    nopos = g["fix"] == 0
    g.loc[nopos, ["lat", "lon", "h"]] = np.nan
    if "nsat" in g:
        g["nsat"] = g["nsat"].round().astype("Int64")
    notes = [f"{path.name}: {len(g)} solutions, Q counts {dict(sorted((int(k), int(v)) for k, v in pd.Series(q).value_counts().items()))} -> fix {dict(sorted(g['fix'].value_counts().items()))}"]
    if geoid:
        notes.append(f"{path.name}: heights are geodetic (above the geoid), not ellipsoidal as the contract wants: "
                     "re-run RTKLIB with 'Height: Ellipsoidal'")
    return ImportResult({"gps": g}, {}, tuple(notes))
