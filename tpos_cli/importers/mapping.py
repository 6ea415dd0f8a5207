"""Mapping files for `tpos import csv`: which source column is which contract column, in what unit.

A mapping is TOML (see docs/mappings/README.md for every key); it is data only. Parsing checks
every key and value and raises InvalidInputError naming `file: [section] key`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tpos_cli.errors import InvalidInputError
from tpos_cli.frames.rotation import axes_to_dcm, euler_to_dcm
from tpos_cli.importers import units
from tpos_cli.importers.gpstime import CLOCKS
from tpos_cli.io.bounded import read_toml
from tpos_cli.session import mounting_problem

TABLE_COLUMNS = {
    "imu": ("gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z", "mag_x", "mag_y", "mag_z"),
    "gps": ("lat", "lon", "h", "fix", "nsat", "hdop", "vn", "ve", "vd", "sigma_n", "sigma_e", "sigma_u"),
    "truth": ("lat", "lon", "h", "vn", "ve", "vd", "roll", "pitch", "yaw"),
    "ranges": ("d1", "d2", "d3"),
}
REQUIRED = {
    "imu": ("gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z"),
    "gps": ("lat", "lon", "h"),
    "truth": ("lat", "lon", "h"),
    "ranges": ("d1", "d2", "d3"),
}
TIME_UNITS = tuple(units.TIME_S) + ("unix", "unix_ms", "gps_s", "gps_tow", "gps_week_seconds")
_VECTORS = {"gyro": ("gyro_x", "gyro_y", "gyro_z"), "acc": ("acc_x", "acc_y", "acc_z"), "mag": ("mag_x", "mag_y", "mag_z")}


@dataclass(frozen=True)
class ColumnSpec:
    """One contract column: taken from a source column (times `factor`), or a constant `value`."""

    name: str
    source: str | None
    factor: float = 1.0
    increment: bool = False  # dθ / dv samples: divide by the sample interval
    value: float | None = None
    code_map: dict[str, float] | None = None  # e.g. RTKLIB Q -> contract fix


@dataclass(frozen=True)
class CsvMapping:
    table: str
    delimiter: str | None  # None = runs of whitespace
    header: bool
    names: tuple[str, ...] | None
    comment: str | None
    skip_rows: int
    time_column: str
    time_unit: str
    week_column: str | None
    tag_file: str | None
    tag_line_ending: str
    clock: str
    offset_s: float
    columns: dict[str, ColumnSpec]
    rotation: np.ndarray  # (3,3) maps the logged sensor axes to the written axes
    axes: str | None  # `[imu] axes` to write into session.toml
    session_toml: dict = field(default_factory=dict)


def _err(path, where, msg):
    return InvalidInputError(f"{path}: {where}: {msg}")


def _check_keys(path, where, table, allowed):
    if not isinstance(table, dict):
        raise _err(path, where, "must be a table")
    extra = sorted(set(table) - set(allowed))
    if extra:
        raise _err(path, where, f"unknown key(s) {', '.join(extra)}; allowed: {', '.join(allowed)}")


def _get(path, where, table, key, typ, default=...):
    if key not in table:
        if default is ...:
            raise _err(path, where, f"missing key '{key}'")
        return default
    v = table[key]
    if typ is float and isinstance(v, int) and not isinstance(v, bool):
        v = float(v)
    if not isinstance(v, typ) or (typ is int and isinstance(v, bool)):
        raise _err(path, f"{where} {key}", f"must be {typ.__name__}, got {v!r}")
    return v


def _unit_factor(path, name, unit, table):
    """(factor, increment) of a column's unit for table `table`."""
    try:
        if name.startswith("gyro_"):
            if unit in units.GYRO_INCREMENT:
                return units.factor(units.GYRO_INCREMENT, unit, name), True
            return units.factor(units.GYRO_RATE, unit, name), False
        if name.startswith("acc_"):
            if unit in units.ACC_INCREMENT:
                return units.factor(units.ACC_INCREMENT, unit, name), True
            return units.factor(units.ACC_RATE, unit, name), False
        if name.startswith("mag_"):
            return units.factor(units.MAG, unit, name), False
        if name in ("lat", "lon", "roll", "pitch", "yaw"):
            return units.factor(units.ANGLE_DEG, unit, name), False
        if name in ("h", "d1", "d2", "d3", "sigma_n", "sigma_e", "sigma_u"):
            return units.factor(units.LENGTH_M, unit, name), False
        if name in ("vn", "ve", "vd"):
            return units.factor(units.SPEED_MPS, unit, name), False
    except KeyError as exc:
        raise _err(path, f"[columns] {name} unit", exc.args[0]) from None
    if unit not in ("", "1", "count"):
        raise _err(path, f"[columns] {name} unit", f"'{name}' has no unit; got {unit!r}")
    return 1.0, False


def load_mapping(path: Path) -> CsvMapping:
    """Parse and check a CSV mapping TOML."""
    path = Path(path)
    if not path.exists():
        raise InvalidInputError(f"{path}: mapping file not found")
    doc = read_toml(path)  # regular file, size and depth bounded
    _check_keys(path, "top level", doc, ("table", "source", "time", "columns", "axes", "session_toml"))
    table = _get(path, "top level", doc, "table", str)
    if table not in TABLE_COLUMNS:
        raise _err(path, "table", f"must be one of {', '.join(TABLE_COLUMNS)}, got {table!r}")

    src = doc.get("source", {})
    _check_keys(path, "[source]", src, ("delimiter", "header", "names", "comment", "skip_rows"))
    delim = _get(path, "[source]", src, "delimiter", str, ",")
    names = _get(path, "[source]", src, "names", list, None)
    if names is not None and not all(isinstance(n, str) for n in names):
        raise _err(path, "[source] names", "must be a list of strings")

    tm = doc.get("time")
    if tm is None:
        raise _err(path, "[time]", "missing section")
    _check_keys(path, "[time]", tm, ("column", "unit", "week_column", "tag_file", "tag_line_ending", "clock", "offset_s"))
    time_unit = _get(path, "[time]", tm, "unit", str)
    if time_unit not in TIME_UNITS:
        raise _err(path, "[time] unit", f"must be one of {', '.join(TIME_UNITS)}, got {time_unit!r}")
    week_column = _get(path, "[time]", tm, "week_column", str, None)
    if time_unit == "gps_week_seconds" and week_column is None:
        raise _err(path, "[time]", "unit 'gps_week_seconds' needs 'week_column'")
    clock = _get(path, "[time]", tm, "clock", str, "gps_tow")
    if clock not in CLOCKS:
        raise _err(path, "[time] clock", f"must be one of {', '.join(CLOCKS)}, got {clock!r}")
    tag_line_ending = _get(path, "[time]", tm, "tag_line_ending", str, "auto")
    if tag_line_ending not in ("auto", "lf", "crlf"):
        raise _err(path, "[time] tag_line_ending", f"must be auto, lf or crlf, got {tag_line_ending!r}")

    cols_doc = doc.get("columns")
    if not cols_doc:
        raise _err(path, "[columns]", "missing section")
    allowed = TABLE_COLUMNS[table]
    columns: dict[str, ColumnSpec] = {}
    for name, spec in cols_doc.items():
        where = f"[columns] {name}"
        if name not in allowed:
            raise _err(path, where, f"not a column of table '{table}'; allowed: {', '.join(allowed)}")
        _check_keys(path, where, spec, ("from", "unit", "scale", "value", "map"))
        if ("from" in spec) == ("value" in spec):
            raise _err(path, where, "give exactly one of 'from' (a source column) or 'value' (a constant)")
        unit = _get(path, where, spec, "unit", str, "")
        fac, inc = _unit_factor(path, name, unit, table)
        if unit == "" and (name.startswith(("gyro_", "acc_", "mag_")) or name in ("lat", "lon", "h", "vn", "ve", "vd")):
            raise _err(path, where, "needs a 'unit'")
        fac *= _get(path, where, spec, "scale", float, 1.0)
        code_map = spec.get("map")
        if code_map is not None:
            _check_keys(path, f"{where} map", code_map, tuple(code_map))
            code_map = {str(k): float(v) for k, v in code_map.items()}
        value = _get(path, where, spec, "value", float, None) if "value" in spec else None
        columns[name] = ColumnSpec(name, spec.get("from"), fac, inc, value, code_map)
    missing = [c for c in REQUIRED[table] if c not in columns]
    if missing:
        raise _err(path, "[columns]", f"table '{table}' needs {', '.join(missing)}")
    for vec, names3 in _VECTORS.items():
        present = [c in columns for c in names3]
        if any(present) and not all(present):
            raise _err(path, "[columns]", f"give all three of {', '.join(names3)} or none")
        if all(present) and len({columns[c].increment for c in names3}) != 1:
            raise _err(path, "[columns]", f"{vec} columns mix rate and increment units")

    ax = doc.get("axes", {})
    _check_keys(path, "[axes]", ax, ("sensor", "mounting_rpy_deg", "write"))
    sensor = _get(path, "[axes]", ax, "sensor", str, None)
    rpy = _get(path, "[axes]", ax, "mounting_rpy_deg", list, None)
    write = _get(path, "[axes]", ax, "write", str, None)
    if sensor is not None and rpy is not None:
        raise _err(path, "[axes]", "give 'sensor' letters or 'mounting_rpy_deg', not both")
    try:
        if rpy is not None:
            problem = mounting_problem(rpy)  # the session's rule: NaN, true, [[0], [1], [2]] or pitch 100 wrote a broken imu table
            if problem is not None:
                raise _err(path, "[axes] mounting_rpy_deg", problem)
            # Groves' Euler-to-DCM: f_body(FRD) = C f_sensor with C = Rz(yaw) Ry(pitch) Rx(roll)
            C_bs = euler_to_dcm(*np.deg2rad(np.asarray(rpy, float)))
            write = write or "FRD"
        elif sensor is not None:
            C_bs = axes_to_dcm(sensor)
        else:
            C_bs = None
        if C_bs is None:
            rotation, axes_out = np.eye(3), write
        elif write is None:
            rotation, axes_out = np.eye(3), sensor
        else:
            rotation, axes_out = axes_to_dcm(write).T @ C_bs, write
    except ValueError as exc:
        raise _err(path, "[axes]", str(exc)) from None
    if table == "imu" and axes_out is None:
        raise _err(path, "[axes]", "an imu mapping must say the sensor axes ('sensor' letters or 'mounting_rpy_deg')")

    session_toml = doc.get("session_toml", {})
    if not isinstance(session_toml, dict):
        raise _err(path, "[session_toml]", "must be a table")
    return CsvMapping(
        table=table,
        delimiter=None if delim in ("whitespace", " ") else delim,
        header=_get(path, "[source]", src, "header", bool, names is None),
        names=tuple(names) if names else None,
        comment=_get(path, "[source]", src, "comment", str, None),
        skip_rows=_get(path, "[source]", src, "skip_rows", int, 0),
        time_column=_get(path, "[time]", tm, "column", str),
        time_unit=time_unit,
        week_column=week_column,
        tag_file=_get(path, "[time]", tm, "tag_file", str, None),
        tag_line_ending=tag_line_ending,
        clock=clock,
        offset_s=_get(path, "[time]", tm, "offset_s", float, 0.0),
        columns=columns,
        rotation=rotation,
        axes=axes_out,
        session_toml=session_toml,
    )
