"""`tpos import rtklib-pos`: RTKLIB solution files (rnx2rtkp / rtkpost / rtknavi `.pos`).

Reads the lat/lon/height form (`%  GPST latitude(deg) longitude(deg) height(m) Q ns sdn(m) ...`),
with time as `yyyy/mm/dd hh:mm:ss.sss` (GPST, UTC or JST, from the header) or `week tow`, and the
optional velocity columns `vn(m/s) ve(m/s) vu(m/s)`. Heights are what the header's option line says
(`% (lat/lon/height=WGS84/ellipsoidal,...)` or `.../geodetic`, i.e. above the geoid); without that
line RTKLIB's default, ellipsoidal, is assumed and a note says so. Geodetic heights are converted with
`geoid_sep_m` (the geoid undulation at the site), else the import is refused: they are never written as
ellipsoidal. A row that is not a solution (wrong number of fields, text, month 13, hour 99, latitude
95.5) refuses the file, naming its line. The solution quality Q maps to the
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
    leap_table_note,
    utc_calendar_to_clock,
)
from tpos_cli.importers.result import ImportResult, gps_result, read_source
from tpos_cli.io.plausibility import H_MAX_M, H_MIN_M

Q_TO_FIX = {0: 0, 1: 2, 2: 2, 3: 2, 4: 2, 5: 1, 6: 2}
_DATE = re.compile(r"^(\d{4})/(\d{1,2})/(\d{1,2})$")
_OPTIONS = re.compile(r"lat/lon/height=(\w+)/(ellipsoidal|geodetic)", re.IGNORECASE)


def _header(lines: list[str]) -> tuple[list[str], str, str | None, str | None, int]:
    """Column labels of the column-header line, time system, height kind ('ellipsoidal', 'geodetic'
    or None when the file does not say), datum (or None), and the number of header lines."""
    labels: list[str] = []
    time_sys = "GPST"
    height = datum = None
    n = 0
    for line in lines:
        if not line.startswith("%"):
            break
        n += 1
        m = _OPTIONS.search(line)
        if m:
            datum, height = m.group(1), m.group(2).lower()
        toks = line[1:].split()
        if toks and toks[0] in ("GPST", "UTC", "JST"):
            time_sys = toks[0]
            labels = toks
    return labels, time_sys, height, datum, n


HEIGHT_KINDS = ("ellipsoidal", "geodetic")


def import_rtklib_pos(path: Path, *, clock: str = "gps_tow", geoid_sep_m: float | None = None,
                      heights: str | None = None) -> ImportResult:
    """Read one .pos file into a contract `gps` table on `clock` ("gps_tow", "gps" or "unix").

    `heights` ('ellipsoidal' or 'geodetic') says what the heights are when the file does not (it
    must agree when the file does); `geoid_sep_m` is the geoid undulation at the site (m), needed
    when they are geodetic (above the geoid)."""
    path = Path(path)
    text = read_source(path, clock).decode("utf-8", errors="replace")
    lines = text.splitlines()
    labels, time_sys, height_kind, datum, n_head = _header(lines)
    if heights is not None and heights not in HEIGHT_KINDS:
        raise InvalidInputError(f"--heights must be one of {', '.join(HEIGHT_KINDS)}, got {heights!r}")
    if height_kind is not None and heights is not None and heights != height_kind:
        raise InvalidInputError(f"{path}: --heights {heights} contradicts the file's header, which says {height_kind}")
    stated = height_kind is not None
    height_kind = height_kind or heights
    if height_kind is None:
        raise InvalidInputError(
            f"{path}: the file does not say whether its heights are ellipsoidal or geodetic (above the geoid, about "
            "mean sea level): it has no '% (lat/lon/height=WGS84/...)' line. Pass --heights ellipsoidal, or "
            "--heights geodetic --geoid-sep-m N (the geoid undulation at the site), or re-run RTKLIB with "
            "'Output Header: ON'")
    if not labels:
        raise InvalidInputError(f"{path}: no RTKLIB column header ('%  GPST  latitude(deg) ...'); is this a .pos file?")
    if datum is not None and datum.upper() != "WGS84":
        raise InvalidInputError(f"{path}: positions are on the {datum} datum; the session needs WGS84 (RTKLIB 'Datum: WGS84')")
    if height_kind == "geodetic" and geoid_sep_m is None:
        raise InvalidInputError(
            f"{path}: the header says the heights are geodetic (above the geoid, about mean sea level), not "
            "ellipsoidal as the session needs; re-run RTKLIB with 'Height: Ellipsoidal', or pass --geoid-sep-m N "
            "(the geoid undulation at the site) to convert")
    lab = [x.lower() for x in labels]
    if "latitude(deg)" not in lab:
        raise InvalidInputError(
            f"{path}: only the lat/lon/height solution form is supported (header has {' '.join(labels[:5])} ...); "
            "set RTKLIB 'Solution Format' to Lat/Lon/Height in degrees"
        )
    numbered = [(i + 1, ln.split()) for i, ln in enumerate(lines) if ln.strip() and not ln.startswith("%")]
    if not numbered:
        raise InvalidInputError(f"{path}: no solution rows")
    # the time takes two tokens (date + time, or week + tow); labels have one token for it
    ncol = len(labels) + 1
    for line_no, r in numbered:
        if len(r) != ncol:
            raise InvalidInputError(f"{path}: line {line_no}: {len(r)} fields where the header has {ncol}; "
                                    "the file is damaged (nothing written)")
    line_nos = np.array([ln for ln, _ in numbered])
    df = pd.DataFrame([r for _, r in numbered], columns=["_d", "_t"] + labels[1:])
    num = {}
    for c in df.columns[2:]:
        v = pd.to_numeric(df[c], errors="coerce").to_numpy(float)
        bad = np.flatnonzero(np.isnan(v))
        if bad.size:
            raise InvalidInputError(f"{path}: line {line_nos[bad[0]]}: {c} {df[c].iloc[bad[0]]!r} is not a number; "
                                    "the file is damaged (nothing written)")
        num[c] = v

    def check(name, v, lo, hi, what):
        bad = np.flatnonzero(~((v >= lo) & (v <= hi)))
        if bad.size:
            raise InvalidInputError(f"{path}: line {line_nos[bad[0]]}: {name} {v[bad[0]]:g} is not {what}; "
                                    "the file is damaged (nothing written)")

    if _DATE.match(str(df["_d"].iloc[0])):
        parts = df["_d"].str.extract(r"^(\d{4})/(\d{1,2})/(\d{1,2})$").astype(float)
        hms = df["_t"].str.extract(r"^(\d{1,2}):(\d{1,2}):(\d{1,2}(?:\.\d*)?)$").astype(float)
        for frame in (parts, hms):
            bad = np.flatnonzero(frame.isna().any(axis=1).to_numpy())
            if bad.size:
                raise InvalidInputError(f"{path}: line {line_nos[bad[0]]}: time {df['_d'].iloc[bad[0]]} {df['_t'].iloc[bad[0]]} "
                                        "is not yyyy/mm/dd hh:mm:ss.sss; the file is damaged (nothing written)")
        y, mo, d = (parts[k].to_numpy() for k in range(3))
        h, mi, sec = (hms[k].to_numpy() for k in range(3))
        check("month", mo, 1, 12, "a month (1-12)")
        check("day", d, 1, 31, "a day of the month (1-31)")
        check("hour", h, 0, 23, "an hour (0-23)")
        check("minute", mi, 0, 59, "a minute (0-59)")
        check("second", sec, 0, 60.999999, "a second (0-60)")
        y, mo, d, h, mi = (a.astype(int) for a in (y, mo, d, h, mi))
        days_in = pd.to_datetime(pd.DataFrame({"year": y, "month": mo, "day": 1})).dt.days_in_month.to_numpy()
        bad = np.flatnonzero(d > days_in)
        if bad.size:
            raise InvalidInputError(f"{path}: line {line_nos[bad[0]]}: day {d[bad[0]]} is not a day of its month "
                                    f"({y[bad[0]]}/{mo[bad[0]]:02d}); the file is damaged (nothing written)")
        if time_sys == "GPST":
            t = gpst_calendar_to_clock(y, mo, d, h, mi, sec, clock)
        else:
            h = h - (9 if time_sys == "JST" else 0)  # JST = UTC + 9 h; negative hours roll back via day arithmetic
            t = utc_calendar_to_clock(y, mo, d, h, mi, sec, clock)
    else:
        week = pd.to_numeric(df["_d"], errors="coerce").to_numpy(float)
        tow = pd.to_numeric(df["_t"], errors="coerce").to_numpy(float)
        bad = np.flatnonzero(~(np.isfinite(week) & np.isfinite(tow)))
        if bad.size:
            raise InvalidInputError(f"{path}: line {line_nos[bad[0]]}: time is neither 'yyyy/mm/dd hh:mm:ss' nor 'week tow'")
        check("GPS week", week, 0, 1e5, "a GPS week")
        check("time of week", tow, 0, WEEK_S, "seconds of a week (0-604800)")
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
    check("latitude", col("latitude(deg)"), -90.0, 90.0, "a latitude (±90 deg)")
    check("longitude", col("longitude(deg)"), -180.0, 180.0, "a longitude (±180 deg)")
    if col("height(m)") is not None:
        check("height", col("height(m)"), H_MIN_M, H_MAX_M, f"a height on Earth ({H_MIN_M:g} to {H_MAX_M:g} m)")
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
    if height_kind == "geodetic":
        out["h"] = out["h"] + geoid_sep_m
    g = pd.DataFrame(out)
    nopos = g["fix"] == 0
    g.loc[nopos, ["lat", "lon", "h"]] = np.nan
    if "nsat" in g:
        g["nsat"] = g["nsat"].round().astype("Int64")
    notes = [f"{path.name}: {len(g)} solutions, Q counts {dict(sorted((int(k), int(v)) for k, v in pd.Series(q).value_counts().items()))} -> fix {dict(sorted(g['fix'].value_counts().items()))}"]
    said = "as the header says" if stated else "as --heights says (the file does not say)"
    if height_kind == "ellipsoidal":
        notes.append(f"{path.name}: heights ellipsoidal, {said}")
    else:
        notes.append(f"{path.name}: heights geodetic (above the geoid), {said}; + --geoid-sep-m {geoid_sep_m:g} m = ellipsoidal")
    leap = None
    if time_sys != "GPST" or clock == "unix":
        leap = leap_table_note(np.asarray(t, float) if clock == "unix" else np.array([]))
    return gps_result(g, path.name, notes, leap)
