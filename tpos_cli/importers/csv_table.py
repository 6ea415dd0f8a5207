"""`tpos import csv`: any delimited text log, described by a mapping file (`mapping.py`).

Lines that do not parse (truncated first/last lines of a serial log, garbage) are dropped and
counted. Time comes from one column in a counter unit (s, ms, µs, ns: the logger clock, written as
seconds), an absolute scale (UNIX, GPS seconds, GPS week + seconds of week), or a counter fitted to
an RTKLIB time-tag file (`timetag.py`). Rates are converted to the contract units; increments (dθ,
dv) are divided by the sample interval; vectors are rotated from the sensor axes to the written axes.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pandas as pd

from tpos_cli.errors import InvalidInputError
from tpos_cli.importers import timetag
from tpos_cli.importers.gpstime import WEEK_S, gps_s_to_clock, unix_to_clock
from tpos_cli.importers.mapping import CsvMapping
from tpos_cli.importers.result import ImportResult
from tpos_cli.importers.units import TIME_S
from tpos_cli.io.bounded import MAX_LINE_BYTES, read_source_bytes
from tpos_cli.io.plausibility import H_MAX_M, H_MIN_M


def _data_lines(raw: bytes, m: CsvMapping, path: Path):
    """(header names or None, data lines, their end byte offsets) with comments and blanks removed."""
    lines = raw.split(b"\n")
    if lines and lines[-1] == b"":
        lines = lines[:-1]
    lengths = np.array([len(x) for x in lines], np.int64)
    long = np.flatnonzero(lengths > MAX_LINE_BYTES)
    if long.size:  # not a damaged log line to drop: a file that is not a delimited log (pandas would take GBs)
        raise InvalidInputError(f"{path}: line {int(long[0]) + 1}: longer than {MAX_LINE_BYTES // 1024} KiB: not a line "
                                "of a delimited log; nothing written")
    keep = np.ones(len(lines), bool)
    keep[: m.skip_rows] = False
    cm = m.comment.encode() if m.comment else None
    for i, line in enumerate(lines):
        s = line.strip()
        if not s or (cm and s.startswith(cm)):
            keep[i] = False
    idx = np.flatnonzero(keep)
    header = None
    if m.header:
        if idx.size == 0:
            raise InvalidInputError(f"{path}: no header line")
        header = [h.strip() for h in lines[idx[0]].decode("utf-8", "replace").strip().split(m.delimiter)]
        idx = idx[1:]
    return header, [lines[i] for i in idx], idx, lengths


def _parse(data: list[bytes], names: list[str], m: CsvMapping, path: Path) -> pd.DataFrame:
    buf = io.BytesIO(b"\n".join(data))
    try:
        df = pd.read_csv(
            buf,
            sep=m.delimiter if m.delimiter is not None else r"\s+",
            header=None,
            names=names,
            dtype=str,
            skip_blank_lines=False,
            engine="python" if m.delimiter is None else "c",
            index_col=False,
            on_bad_lines="error",
        )
    except (pd.errors.ParserError, ValueError) as exc:
        raise InvalidInputError(f"{path}: cannot split into columns ({exc})") from None
    if len(df) != len(data):
        raise InvalidInputError(f"{path}: parsed {len(df)} rows from {len(data)} data lines (quoted newlines?)")
    return df


# (contract column, lowest, highest, what it must be) of positions, after the unit conversion
_POSITION_RANGES = (("lat", -90.0, 90.0, "a latitude (±90 deg)"), ("lon", -180.0, 180.0, "a longitude (±180 deg)"),
                    ("h", H_MIN_M, H_MAX_M, f"a height on Earth ({H_MIN_M:g} to {H_MAX_M:g} m)"))


def _check_positions(path: Path, cols: dict, line_idx: np.ndarray) -> None:
    """An impossible latitude, longitude or height (wrong column or unit in the mapping, a damaged
    line) is refused naming its line: nothing is written."""
    for name, lo, hi, what in _POSITION_RANGES:
        if name not in cols:
            continue
        v = np.asarray(cols[name], float)
        bad = np.flatnonzero(np.isfinite(v) & ~((v >= lo) & (v <= hi)))
        if bad.size:
            raise InvalidInputError(f"{path}: line {int(line_idx[bad[0]]) + 1}: {name} {v[bad[0]]:g} is not {what} "
                                    "(the mapping's column or unit, or a damaged line?); nothing written")


def import_csv(path: Path, m: CsvMapping) -> ImportResult:
    """Read one delimited file with mapping `m` into a contract table."""
    path = Path(path)
    raw = read_source_bytes(path, text=True)
    header, data, line_idx, lengths = _data_lines(raw, m, path)
    names = list(m.names) if m.names else header
    if names is None:
        raise InvalidInputError(f"{path}: the mapping gives no column names and the file has no header")
    # lines with more fields than names would shift columns: count them as bad
    sep = m.delimiter.encode() if m.delimiter else None
    nfields = np.array([len(x.split(sep)) for x in data])
    df = _parse([x if n <= len(names) else b"" for x, n in zip(data, nfields)], names, m, path)
    needed = [m.time_column] + ([m.week_column] if m.week_column else [])
    needed += [c.source for c in m.columns.values() if c.source is not None]
    unknown = [c for c in needed if c not in df.columns]
    if unknown:
        raise InvalidInputError(f"{path}: column(s) {', '.join(repr(u) for u in unknown)} not in the file; it has {', '.join(df.columns)}")
    numeric = {}
    for c in dict.fromkeys(needed):
        numeric[c] = pd.to_numeric(df[c].str.strip(), errors="coerce").to_numpy(float)
    # a row is usable when its time and every required numeric field parsed
    ok = (nfields <= len(names)) & np.isfinite(numeric[m.time_column])
    for spec in m.columns.values():
        if spec.source is not None and spec.code_map is None and (spec.name in ("lat", "lon", "h") or spec.name[:3] in ("gyr", "acc", "mag")):
            ok &= np.isfinite(numeric[spec.source])
    notes = []
    if (~ok).sum():
        bad = line_idx[~ok] + 1
        notes.append(f"{path.name}: dropped {(~ok).sum()} unparsable or incomplete line(s) (e.g. line {bad[0]})")

    t_raw = numeric[m.time_column]
    if m.tag_file is not None:
        tag_path = (path.parent / m.tag_file) if not Path(m.tag_file).is_absolute() else Path(m.tag_file)
        if not tag_path.exists():
            raise InvalidInputError(f"{path}: time-tag file {tag_path} not found")
        tags = timetag.read_time_tags(tag_path)
        if m.time_unit not in TIME_S:
            raise InvalidInputError(f"{path}: a time-tag file needs a counter time unit (s, ms, us, ns), got {m.time_unit!r}")
        term = {"lf": 1, "crlf": 2}.get(m.tag_line_ending) or timetag.guess_terminator_bytes(raw, len(lengths), tags)
        ends = timetag.line_end_offsets(lengths, term)[line_idx]
        counter_s = t_raw * TIME_S[m.time_unit]
        arrival = timetag.line_arrival_gps_s(tags, ends)
        fit = timetag.fit_counter_to_arrival(np.where(ok, counter_s, np.nan), arrival)
        t = np.full(counter_s.shape, np.nan)
        t[ok] = gps_s_to_clock(fit(counter_s[ok]), m.clock)
        notes.append(
            f"{path.name}: counter fitted to the time tags over {fit.n_used} lines: "
            f"clock rate {fit.slope:.8f}, arrival-time residual SD {fit.residual_sd_s * 1e3:.1f} ms"
            + (" (tags count CRLF line ends: the file was converted to LF)" if term == 2 and b"\r" not in raw[:4096] else "")
        )
    elif m.time_unit in TIME_S:
        t = t_raw * TIME_S[m.time_unit]
    elif m.time_unit in ("unix", "unix_ms"):
        t = np.full(t_raw.shape, np.nan)
        t[ok] = unix_to_clock(t_raw[ok] * (1e-3 if m.time_unit == "unix_ms" else 1.0), m.clock)
    elif m.time_unit == "gps_s":
        t = np.full(t_raw.shape, np.nan)
        t[ok] = gps_s_to_clock(t_raw[ok], m.clock)
    elif m.time_unit == "gps_tow":
        t = t_raw  # already seconds of the GPS week: written as given
    else:  # gps_week_seconds
        ok &= np.isfinite(numeric[m.week_column])
        t = np.full(t_raw.shape, np.nan)
        t[ok] = gps_s_to_clock(numeric[m.week_column][ok] * WEEK_S + t_raw[ok], m.clock)
    t = t + m.offset_s

    keep = ok.copy()
    out = {"t": t[keep]}
    for spec in m.columns.values():
        if spec.value is not None:
            col = np.full(keep.sum(), spec.value)
        elif spec.code_map is not None:
            codes = df[spec.source].str.strip().to_numpy()[keep]
            # numeric codes are matched on their integer form ("1.0000000" is code "1")
            num = pd.to_numeric(pd.Series(codes), errors="coerce").to_numpy()
            keys = np.where(np.isfinite(num) & (num == np.round(num)), np.char.mod("%d", np.nan_to_num(num).astype(np.int64)), codes)
            col = np.array([spec.code_map.get(str(k), np.nan) for k in keys], float)
            if np.isnan(col).any():
                unmapped = sorted({str(k) for k, v in zip(keys, col) if np.isnan(v)})
                raise InvalidInputError(f"{path}: column '{spec.source}' has code(s) {', '.join(unmapped)} missing from the mapping's 'map'")
        else:
            col = numeric[spec.source][keep] * spec.factor
        out[spec.name] = col
    _check_positions(path, out, line_idx[keep])
    tables_cols = out
    if m.table == "imu":
        t_k = tables_cols["t"]
        if t_k.size < 2:
            raise InvalidInputError(f"{path}: fewer than two usable IMU rows")
        dt = np.diff(t_k)
        if (dt < 0).any():
            raise InvalidInputError(f"{path}: time goes backwards at data row {int(np.argmax(dt < 0)) + 2}")
        dt_nominal = float(np.median(dt))
        dt_full = np.concatenate([[dt_nominal], dt])
        for vec in ("gyro", "acc", "mag"):
            cols = [f"{vec}_{a}" for a in "xyz"]
            if cols[0] not in m.columns:
                continue
            v = np.column_stack([tables_cols[c] for c in cols])
            if m.columns[cols[0]].increment:
                with np.errstate(divide="ignore", invalid="ignore"):
                    v = v / np.where(dt_full > 0, dt_full, np.nan)[:, None]  # mean rate over (t_{k-1}, t_k]
                notes.append(f"{path.name}: {vec} increments divided by the sample interval")
            v = v @ m.rotation.T  # v_written = R v_sensor
            for i, c in enumerate(cols):
                tables_cols[c] = v[:, i]
        rate_hz = round(1.0 / dt_nominal, 3)
        toml = {"imu": {"axes": m.axes, "rate_hz": rate_hz}}
    else:
        toml = {}
        if m.table == "gps" and "fix" not in tables_cols:
            tables_cols["fix"] = np.ones(len(tables_cols["t"]))
            notes.append(f"{path.name}: no fix column: every row written with fix = 1 (autonomous)")
    df_out = pd.DataFrame(tables_cols)
    for c in ("fix", "nsat"):
        if c in df_out:
            df_out[c] = df_out[c].round().astype("Int64")
    from tpos_cli.importers.session_out import merge_toml

    return ImportResult({m.table: df_out}, merge_toml(m.session_toml, toml), tuple(notes))
