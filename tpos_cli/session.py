"""Session loading and validation: a session directory (docs/log-format.md) into one `Session`.

`load_session` checks everything the contract requires, collects every problem it finds, and raises
one `InvalidInputError` listing them (each a one-line `file: column 'c', row r: what`). Oddities the
contract allows (duplicate stamps, isolated NaN samples, IMU gaps, rows without a fix) are handled,
counted in `Session.counts` and described in `Session.warnings`.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from tpos_cli import schema, timebase
from tpos_cli.errors import InvalidInputError
from tpos_cli.frames import geodetic
from tpos_cli.frames.rotation import axes_to_dcm
from tpos_cli.io import plausibility
from tpos_cli.io.bounded import MAX_TABLE_BYTES, read_toml, regular_file_size
from tpos_cli.io.columns import Columns
from tpos_cli.io.tables import Problem, find_table, read_table, shown

# Rates above this cannot be rad/s from a MEMS gyro: 2000 deg/s is the largest full scale of
# consumer MEMS gyros. Checked on the 99.9th percentile so that a few glitch samples do not trip it.
GYRO_MAX_PLAUSIBLE_RPS = 34.9
# One sample beyond these is no sensor's reading (corrupted, or another unit), and would overflow the
# filters' arithmetic: ten times the largest full scales of MEMS gyros (4000 deg/s = 70 rad/s) and
# accelerometers (400 g), and 0.1 T against magnetometers' few mT (from datasheets, not from any log).
GYRO_MAX_SAMPLE_RPS = 700.0
ACC_MAX_SAMPLE_MPS2 = 40_000.0
MAG_MAX_SAMPLE_UT = 100_000.0
# An odometry speed beyond this is no wheeled vehicle's (the fastest road cars reach about 140 m/s).
ODOMETER_MAX_MPS = 200.0
# Median spacing of a table's rows once its times are read in seconds: a GPS receiver's rate
# (100 Hz to one fix per 10 s) and an odometer's or CAN bus's (up to 1 kHz).
GPS_STEP_S = (0.01, 10.0)
ODOMETRY_STEP_S = (0.001, 10.0)
# A median specific-force magnitude in this band is g units, not m/s^2 (the median of any log,
# static or moving, sits near 1 g).
ACC_G_BAND = (0.5, 2.0)
ACC_MPS2_BAND = (5.0, 15.0)
ACC_SWITCH_MIN_S = 10.0  # a stretch of the log in g units within one in m/s² (`_acc_unit_switch`)
# The Earth's field at the surface is 22-67 µT (the extremes of the IGRF's total intensity). A median
# magnetometer magnitude above the upper bound (150 times the strongest field, twice the widest MEMS
# full scale, 4900 µT) is no reading in µT: nT; below the lower one (a tenth of the weakest field,
# which no body-fixed hard iron cancels in every orientation) it is gauss or tesla, or no sensor.
MAG_MEDIAN_UT = (2.0, 10_000.0)
# A declination beyond ±180 deg is not an angle of the contract's convention.
DECLINATION_LIMIT_DEG = 180.0
# A soft-iron matrix this ill-conditioned (or singular) destroys the magnetometer's direction.
SOFT_IRON_MAX_COND = 1e3
# Median ranges beyond this are not a handheld laser rangefinder's or a ranging anchor's metres
# (they are millimetres: a wall at 12 m logged as 12000).
RANGE_MAX_PLAUSIBLE_M = 3000.0
# session.toml figures beyond these are not the quantity in the contract's units (a 1e308 baseline
# overflowed the target chain; a negative SD is no SD): (section, key) -> (lowest, highest).
PLAUSIBLE_SESSION_VALUES = {
    ("imu", "rate_hz"): (0.0, 100_000.0),
    ("imu", "gyro_noise_dps"): (0.0, 10.0),  # per-sample SD; consumer MEMS: 0.005-0.1 deg/s
    ("imu", "gyro_bias_dph"): (0.0, 36_000.0),  # 10 deg/s
    ("imu", "acc_noise_mg"): (0.0, 1_000.0),
    ("imu", "acc_bias_mg"): (0.0, 1_000.0),
    ("imu", "mag_noise_ut"): (0.0, 100.0),  # the Earth's field is 25-65 µT
    ("rangefinders", "baseline_12_m"): (0.0, 10.0),  # rangefinders on one rig
    ("rangefinders", "baseline_13_m"): (0.0, 10.0),
    ("rangefinders", "sigma_m"): (0.0, 100.0),
}
# A GPS antenna more than this from the IMU is not on the same vehicle.
LEVER_ARM_MAX_M = 100.0
# A clock offset beyond 1e10 s (about 300 years) is no clock's: and t + offset in float64 keeps
# milliseconds only up to about 1e12 s.
TIME_OFFSET_MAX_S = 1e10
# A log's start: not before the GPS epoch, not in the 22nd century.
START_UTC_RANGE = (datetime(1980, 1, 6, tzinfo=UTC), datetime(2100, 1, 1, tzinfo=UTC))


@dataclass(frozen=True)
class ImuNoise:
    """Optional `[imu]` noise figures, in the contract's units (None where absent)."""

    gyro_noise_dps: float | None = None
    gyro_bias_dph: float | None = None
    acc_noise_mg: float | None = None
    acc_bias_mg: float | None = None
    mag_noise_ut: float | None = None


@dataclass(frozen=True)
class Rangefinders:
    """`[rangefinders]`: LR2 is `baseline_12_m` left of LR1, LR3 `baseline_13_m` below LR1."""

    baseline_12_m: float
    baseline_13_m: float
    sigma_m: float | None = None


@dataclass(frozen=True)
class SessionMeta:
    name: str
    kind: str
    start_utc: datetime | None
    axes: str
    rate_hz: float
    imu_noise: ImuNoise
    rangefinders: Rangefinders | None
    declination_deg: float | None
    lever_arm_b_m: np.ndarray  # FRD
    observer_lla: np.ndarray | None
    local_origin_lla: np.ndarray | None
    time_offsets_s: dict
    hard_iron_ut: np.ndarray | None
    soft_iron: np.ndarray | None
    raw: dict
    # `[imu] mounting_rpy_deg`: the sensor's roll, pitch, yaw on the vehicle body after `axes`
    # (v_body = Rz(yaw) Ry(pitch) Rx(roll) v_sensor), degrees; None when absent, which means
    # unknown (not zero): a vehicle chain may estimate it from the log.
    mounting_rpy_deg: np.ndarray | None = None


@dataclass(frozen=True)
class ImuData:
    t_s: np.ndarray
    gyro_b_rps: np.ndarray
    acc_b_mps2: np.ndarray
    mag_b_ut: np.ndarray | None


@dataclass(frozen=True)
class GpsData:
    t_s: np.ndarray
    lla: np.ndarray
    fix: np.ndarray
    nsat: np.ndarray
    hdop: np.ndarray
    vel_ned_mps: np.ndarray
    sigma_neu_m: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """Rows that carry a usable position fix."""
        return (self.fix > 0) & np.isfinite(self.lla).all(axis=1)


@dataclass(frozen=True)
class RangeData:
    t_s: np.ndarray
    range_m: np.ndarray


@dataclass(frozen=True)
class OdometryData:
    """The contract's `odometry` table: forward speed of the vehicle body (>= 0), on the IMU clock."""

    t_s: np.ndarray
    speed_mps: np.ndarray


@dataclass(frozen=True)
class Anchors:
    ids: tuple
    lla: np.ndarray
    ned_m: np.ndarray
    origin_lla: np.ndarray


@dataclass(frozen=True)
class AnchorRanges:
    t_s: np.ndarray
    anchor: np.ndarray
    range_m: np.ndarray


@dataclass(frozen=True)
class RangeCalibration:
    anchor: np.ndarray
    true_m: np.ndarray
    measured_m: np.ndarray


@dataclass(frozen=True)
class Targets:
    ids: tuple
    lla: np.ndarray
    role: tuple


@dataclass(frozen=True)
class Shots:
    ids: tuple
    t_start_s: np.ndarray
    t_end_s: np.ndarray


@dataclass(frozen=True)
class Truth:
    t_s: np.ndarray
    lla: np.ndarray
    vel_ned_mps: np.ndarray
    rpy_deg: np.ndarray
    extra: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Session:
    path: Path
    meta: SessionMeta
    t0_s: float
    imu: ImuData | None  # None only from load_session(..., with_imu=False): see load_imu
    gps: GpsData | None
    ranges: RangeData | None
    anchors: Anchors | None
    anchor_ranges: AnchorRanges | None
    range_calibration: RangeCalibration | None
    targets: Targets | None
    shots: Shots | None
    truth: Truth | None
    gps_outages_s: np.ndarray
    imu_gaps_s: np.ndarray
    counts: dict
    warnings: tuple
    file_hashes: dict
    odometry: OdometryData | None = None

    @property
    def t_end_s(self) -> float:
        return float(self.imu.t_s[-1])


def sha256_file(path: Path) -> str:
    with open(path, "rb") as fh:  # file_digest reads into one reused buffer (no bytes object per chunk)
        return hashlib.file_digest(fh, "sha256").hexdigest()


class _Collector:
    """Gathers problems, counts and warnings while a session loads."""

    def __init__(self, session_dir: Path):
        self.dir = session_dir
        self.problems: list[Problem] = []
        self.counts: dict[str, int] = {}
        self.warnings: list[str] = []

    def problem(self, file: str, message: str, column: str | None = None, row: int | None = None):
        self.problems.append(Problem(file, message, column, row))

    def count(self, key: str, n: int):
        if n:
            self.counts[key] = self.counts.get(key, 0) + int(n)

    def table(self, name: str, numeric, text=(), required=(), csv_only=False) -> tuple[Columns | None, str]:
        try:
            path = find_table(self.dir, name, csv_only=csv_only)
            if path is None:
                return None, name
            df = read_table(path, tuple(numeric), tuple(text), tuple(required))
        except InvalidInputError as exc:
            self.problems.extend(exc.problems or [Problem(f"{name}.*", str(exc))])
            return None, name
        for col in numeric:  # t has its own check (`_check_time`)
            v = df[col] if col != "t" and col in df else None
            bad = None if v is None or v.dtype.kind != "f" else np.flatnonzero(np.isinf(v))
            if bad is not None and bad.size:
                self.problem(path.name, f"{_v(v[bad[0]])} is not a measurement (a missing value is an empty cell or NaN)",
                             col, int(bad[0]) + 1)
                return None, path.name
        return df, path.name


def _number(c: _Collector, section: dict, key: str, where: str, required=False, positive=False):
    if key not in section:
        if required:
            c.problem("session.toml", f"[{where}] {key} is required")
        return None
    v = section[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        c.problem("session.toml", f"[{where}] {key} must be a finite number, got {_v(v)}")
        return None
    if positive and v <= 0:
        c.problem("session.toml", f"[{where}] {key} must be positive, got {_v(v)}")
        return None
    lo, hi = PLAUSIBLE_SESSION_VALUES.get((where, key), (-math.inf, math.inf))
    if not lo <= v <= hi:
        c.problem("session.toml", f"[{where}] {key} = {_v(v)} is outside {lo:g} to {hi:g}: not this quantity in the "
                  "contract's units (docs/log-format.md)")
        return None
    return float(v)


def _lla_section(c: _Collector, raw: dict, name: str) -> np.ndarray | None:
    sec = raw.get(name)
    if sec is None:
        return None
    if not isinstance(sec, dict):
        c.problem("session.toml", f"[{name}] must be a table with lat, lon, h")
        return None
    vals = [_number(c, sec, k, name, required=True) for k in ("lat", "lon", "h")]
    if any(v is None for v in vals):
        return None
    if abs(vals[0]) > 90 or abs(vals[1]) > 180:
        c.problem("session.toml", f"[{name}] lat/lon out of range ({vals[0]}, {vals[1]})")
        return None
    if plausibility.first_bad_height(np.array([vals[2]])) is not None:
        c.problem("session.toml", f"[{name}] h {vals[2]:g} m is not an ellipsoidal height on Earth "
                  f"({plausibility.H_MIN_M:g} to {plausibility.H_MAX_M:g} m): feet, or a wrong column?")
        return None
    return np.array(vals)


def _unknown_keys(raw: dict) -> list[str]:
    """One warning per section or key of session.toml that tpos does not read: the contract ignores
    them, but a misspelt key (`gyro_noise_dsp`) would silently lose its setting."""
    import difflib

    known = schema.SESSION_TOML_KEYS
    out = []
    for sec, val in raw.items():
        if sec not in known:
            near = difflib.get_close_matches(sec, list(known), n=1)
            out.append(f"session.toml: [{sec}]: unknown section, ignored" + (f" (did you mean [{near[0]}]?)" if near else ""))
            continue
        for key in val if isinstance(val, dict) else ():
            if key not in known[sec]:
                near = difflib.get_close_matches(key, known[sec], n=1)
                out.append(f"session.toml: [{sec}] {key}: unknown key, ignored" + (f" (did you mean {near[0]}?)" if near else ""))
    return out


def _parse_meta(c: _Collector) -> SessionMeta | None:
    path = c.dir / "session.toml"
    if not path.exists():
        c.problem("session.toml", "missing: every session needs a session.toml")
        return None
    try:
        raw = read_toml(path, "session.toml")
    except InvalidInputError as exc:
        c.problem("session.toml", str(exc).split(": ", 1)[1])
        return None
    n0 = len(c.problems)
    for sec in ("session", "imu"):
        if sec not in raw:  # present but not a table: said once, below
            c.problem("session.toml", f"[{sec}] section is required (a table, e.g. [{sec}] on its own line)")
    for sec in SECTIONS:
        if sec in raw and not isinstance(raw[sec], dict):
            c.problem("session.toml", f"{sec} must be a table ([{sec}] with keys), got {type(raw[sec]).__name__} {raw[sec]!r:.40}")
    if len(c.problems) > n0:
        return None
    c.warnings.extend(_unknown_keys(raw))
    s, imu = raw["session"], raw["imu"]
    name = str(s.get("name", c.dir.name))
    kind = s.get("kind")
    if kind not in schema.SESSION_KINDS:
        c.problem("session.toml", f"[session] kind must be one of {', '.join(schema.SESSION_KINDS)}, got {_v(kind)}")
    start_utc = None
    if "start_utc" in s:
        v = s["start_utc"]
        try:
            start_utc = v if isinstance(v, datetime) else datetime.fromisoformat(str(v).replace("Z", "+00:00"))
        except ValueError:
            c.problem("session.toml", f"[session] start_utc is not an ISO-8601 time: {_v(v)}")
        aware = None if start_utc is None else start_utc.replace(tzinfo=UTC) if start_utc.tzinfo is None else start_utc
        if aware is not None:
            if not START_UTC_RANGE[0] <= aware <= START_UTC_RANGE[1]:
                c.problem("session.toml", f"[session] start_utc {start_utc.isoformat()} is outside "
                          f"{START_UTC_RANGE[0]:%Y-%m-%d} (the GPS epoch) to {START_UTC_RANGE[1]:%Y-%m-%d}: not a log's start")
                start_utc = None
    axes = imu.get("axes")
    if not isinstance(axes, str):
        c.problem("session.toml", f"[imu] axes must be three letters such as \"FRD\", got {_v(axes)}")
        axes = "FRD"
    try:
        axes_to_dcm(axes)
    except ValueError as exc:
        c.problem("session.toml", f"[imu] {exc}")
    rate = _number(c, imu, "rate_hz", "imu", required=True, positive=True)
    mounting = _mounting(c, imu)
    noise = ImuNoise(**{k: _number(c, imu, k, "imu", positive=False) for k in schema.IMU_NOISE_KEYS})
    rf = None
    if "rangefinders" in raw:
        sec = raw["rangefinders"]
        b12 = _number(c, sec, "baseline_12_m", "rangefinders", required=True, positive=True)
        b13 = _number(c, sec, "baseline_13_m", "rangefinders", required=True, positive=True)
        sig = _number(c, sec, "sigma_m", "rangefinders", positive=True)
        if b12 is not None and b13 is not None:
            rf = Rangefinders(b12, b13, sig)
    mag = raw.get("magnetic", {})
    decl = _number(c, mag, "declination_deg", "magnetic")
    if decl is not None and abs(decl) > DECLINATION_LIMIT_DEG:
        c.problem("session.toml", f"[magnetic] declination_deg {decl:g} is outside ±{DECLINATION_LIMIT_DEG:g} degrees")
        decl = None
    hard_iron = soft_iron = None
    if "hard_iron_ut" in mag:
        hard_iron = np.asarray(mag["hard_iron_ut"], dtype=float) if _is_matrix(mag["hard_iron_ut"], (3,)) else None
        if hard_iron is None:
            c.problem("session.toml", "[magnetic] hard_iron_ut must be three numbers (µT)")
    if "soft_iron" in mag:
        soft_iron = np.asarray(mag["soft_iron"], dtype=float) if _is_matrix(mag["soft_iron"], (3, 3)) else None
        if soft_iron is None:
            c.problem("session.toml", "[magnetic] soft_iron must be a 3x3 array of numbers")
        elif not np.linalg.cond(soft_iron) < SOFT_IRON_MAX_COND:
            c.problem("session.toml", "[magnetic] soft_iron is singular or nearly so (condition number "
                      f"{np.linalg.cond(soft_iron):.3g}): it would erase the magnetometer's direction")
            soft_iron = None
    lever = np.zeros(3)
    gps = raw.get("gps", {})
    if "lever_arm_m" in gps:
        if _is_matrix(gps["lever_arm_m"], (3,)) and np.abs(gps["lever_arm_m"]).max() > LEVER_ARM_MAX_M:
            c.problem("session.toml", f"[gps] lever_arm_m {gps['lever_arm_m']!r:.80} has a component beyond "
                      f"{LEVER_ARM_MAX_M:g} m: not an antenna on the vehicle (millimetres?)")
        elif _is_matrix(gps["lever_arm_m"], (3,)):
            lever = np.asarray(gps["lever_arm_m"], dtype=float)
        else:
            c.problem("session.toml", "[gps] lever_arm_m must be three numbers (m, in the IMU's logged axes)")
    offsets = {}
    for k in raw.get("time", {}):
        val = _number(c, raw["time"], k, "time")
        if val is not None and abs(val) > TIME_OFFSET_MAX_S:
            c.problem("session.toml", f"[time] {k} {val:g} s is not a clock offset (at most {TIME_OFFSET_MAX_S:g} s, "
                      "about 300 years; beyond it float64 times lose their milliseconds)")
        elif val is not None:
            offsets[k] = val
    observer = _lla_section(c, raw, "observer")
    local = _lla_section(c, raw, "local")
    if len(c.problems) > n0:
        return None
    C_bs = axes_to_dcm(axes)
    return SessionMeta(
        name=name, kind=kind, start_utc=start_utc, axes=axes.upper(), rate_hz=rate, imu_noise=noise,
        rangefinders=rf, declination_deg=decl, lever_arm_b_m=C_bs @ lever, observer_lla=observer,
        local_origin_lla=local, time_offsets_s=offsets, hard_iron_ut=hard_iron, soft_iron=soft_iron, raw=raw,
        mounting_rpy_deg=mounting,
    )


# The sections of the contract (and the tpos extensions): each must be a table when present.
SECTIONS = tuple(schema.SESSION_TOML_KEYS)


# Bounds of the Euler angles of `[imu] mounting_rpy_deg` (same convention as attitude: pitch within
# +-90 deg); a value outside is not an angle of this convention (e.g. radians, or a typo).
MOUNTING_LIMITS_DEG = (180.0, 90.0, 360.0)


def mounting_problem(v) -> str | None:
    """What is wrong with a `mounting_rpy_deg` value (three finite TOML numbers, degrees, within
    MOUNTING_LIMITS_DEG), or None: the session's `[imu]` key and an import mapping's `[axes]` key."""
    if not _is_matrix(v, (3,)):
        return f"must be three finite numbers (roll, pitch, yaw in degrees), got {_v(v)}"
    for name, val, lim in zip(("roll", "pitch", "yaw"), np.asarray(v, dtype=float), MOUNTING_LIMITS_DEG):
        if abs(val) > lim:
            return f"{name} {val:g} is outside ±{lim:g} degrees"
    return None


def _mounting(c: _Collector, imu: dict) -> np.ndarray | None:
    """`[imu] mounting_rpy_deg` as (3,) degrees, or None when the key is absent (unknown)."""
    if "mounting_rpy_deg" not in imu:
        return None
    problem = mounting_problem(imu["mounting_rpy_deg"])
    if problem is not None:
        c.problem("session.toml", f"[imu] mounting_rpy_deg {problem}")
        return None
    return np.asarray(imu["mounting_rpy_deg"], dtype=float)


def _v(x) -> str:
    """A cell value for a message: plain Python repr, never numpy's, cut to a line (`io.tables.shown`)."""
    return shown(x)


def _is_matrix(v, shape) -> bool:
    """`v` is an array of `shape` of finite TOML numbers (not booleans, not text that reads as a number)."""
    def numbers(x) -> bool:
        if isinstance(x, list):
            return all(numbers(e) for e in x)
        return isinstance(x, (int, float)) and not isinstance(x, bool)

    if not numbers(v):
        return False
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        return False
    return a.shape == shape and bool(np.isfinite(a).all())


# Duplicate IMU time stamps beyond this share of the rows, with the rest off the stated rate, are a time column that
# cannot resolve the samples, not a logger's repeated rows (kept first, counted).
DUPLICATE_SHARE_MAX = 0.1


def _check_time(c: _Collector, fname: str, t: np.ndarray, key: str) -> np.ndarray | None:
    """Time column checks; returns the mask of rows to keep (duplicates dropped), None if invalid."""
    nan = np.flatnonzero(~np.isfinite(t))
    if nan.size:
        c.problem(fname, "time is empty or not finite", "t", int(nan[0]) + 1)
        return None
    i = timebase.first_decrease(t)
    if i is not None:
        c.problem(fname, f"time goes backwards ({_v(t[i])} after {_v(t[i - 1])}); t must be non-decreasing", "t", i + 1)
        return None
    dup = timebase.duplicate_mask(t)
    if dup.any():
        c.count(f"duplicate_stamps_{key}", int(dup.sum()))
        c.warnings.append(f"{fname}: {int(dup.sum())} duplicate time stamps (the first at row {int(np.argmax(dup)) + 1}); "
                          "the first sample of each kept")
    return ~dup


def _swap_hint(col: str, lat: np.ndarray, lon: np.ndarray) -> str:
    """For a latitude out of range: the exchange of lat and lon, when every latitude is out of range (a
    longitude column, not one glitch) and every value would be in range exchanged."""
    lat, lon = lat[np.isfinite(lat)], lon[np.isfinite(lon)]
    exchanged = (col == "lat" and bool(np.all((np.abs(lat) > 90.0) & (np.abs(lat) <= 180.0)))
                 and bool(np.all(np.abs(lon) <= 90.0)))
    return "; lat and lon look exchanged (every lon is within ±90): swap the two columns" if exchanged else ""


def _check_latlon(c: _Collector, fname: str, lat: np.ndarray, lon: np.ndarray, h: np.ndarray | None = None):
    for col, v, lim in (("lat", lat, 90.0), ("lon", lon, 180.0)):
        bad = np.flatnonzero(np.abs(v) > lim)
        if bad.size:
            c.problem(fname, f"{_v(v[bad[0]])} is outside ±{lim:g} degrees{_swap_hint(col, lat, lon)}", col, int(bad[0]) + 1)
    i = None if h is None else plausibility.first_bad_height(h)
    if i is not None:
        c.problem(fname, f"{_v(h[i])} m is not an ellipsoidal height on Earth ({plausibility.H_MIN_M:g} to "
                  f"{plausibility.H_MAX_M:g} m): feet, millimetres or a wrong column?", "h", i + 1)


def _timed_table(c: _Collector, name: str, numeric, required):
    """A table with a `t` column and its checked times: (df, file name, t, rows kept), or None when it
    is absent or invalid (the problems recorded)."""
    df, fname = c.table(name, numeric, required=required)
    if df is None:
        return None
    t = df["t"]
    keep = _check_time(c, fname, t, name)
    return None if keep is None else (df, fname, t, keep)


def _imu_table(c: _Collector, cols, required):
    """The IMU table's columns `cols` and its checked times: (df, file name, t, rows kept), or None
    (the problems recorded)."""
    got = _timed_table(c, "imu", cols, required)
    if got is None and not any(p.file.startswith("imu") for p in c.problems):
        c.problem("imu.*", "missing: every session needs imu.csv or imu.parquet")
    return got


def _load_imu(c: _Collector, meta: SessionMeta):
    got = _imu_table(c, schema.IMU_REQUIRED + schema.IMU_MAG, schema.IMU_REQUIRED)
    if got is None:
        return None
    df, fname, t, keep = got
    has_mag = [m in df.columns for m in schema.IMU_MAG]
    if any(has_mag) and not all(has_mag):
        missing = [m for m, h in zip(schema.IMU_MAG, has_mag) if not h][0]
        c.problem(fname, "magnetometer columns come as mag_x, mag_y, mag_z together", missing)
        return None
    gyro = df.matrix(["gyro_x", "gyro_y", "gyro_z"])
    acc = df.matrix(["acc_x", "acc_y", "acc_z"])
    mag = df.matrix(list(schema.IMU_MAG)) if all(has_mag) else None
    finite = np.isfinite(gyro).all(axis=1) & np.isfinite(acc).all(axis=1)
    if finite.sum() < 2:
        c.problem(fname, "fewer than two complete samples (gyro and acc all present)")
        return None
    nan_rows = ~finite & keep
    if nan_rows.any():
        c.count("imu_nan_samples", int(nan_rows.sum()))
        n = int(nan_rows.sum())
        c.warnings.append(f"{fname}: {n} sample{'s' if n != 1 else ''} with empty/NaN gyro or acc values dropped "
                          f"(the first at row {int(np.argmax(nan_rows)) + 1})")
    keep = keep & finite
    every_row = bool(keep.all())  # the usual log: no row dropped, so no copies of the kept rows
    gyro_k = gyro if every_row else gyro[keep]
    acc_k = acc if every_row else acc[keep]
    for name, sensor, block, limit, unit in (("gyro", "gyro", gyro, GYRO_MAX_SAMPLE_RPS, "rad/s"),
                                             ("acc", "accelerometer", acc, ACC_MAX_SAMPLE_MPS2, "m/s²"),
                                             ("mag", "magnetometer", mag, MAG_MAX_SAMPLE_UT, "µT")):
        over = None if block is None else np.flatnonzero((np.abs(block) > limit).any(axis=1) & keep)
        if over is not None and over.size:
            i = int(over[0])
            j = int(np.argmax(np.abs(block[i]) > limit))
            c.problem(fname, f"{_v(block[i, j])} {unit} is beyond any {sensor}'s range (at most {limit:g} {unit}): "
                      "a corrupted sample or another unit", f"{name}_{'xyz'[j]}", i + 1)
            return None
    gyro_norm = np.linalg.norm(gyro_k, axis=1)
    p999 = float(np.quantile(gyro_norm, 0.999))
    if p999 > GYRO_MAX_PLAUSIBLE_RPS:
        i = int(np.flatnonzero(keep)[np.argmax(gyro_norm > GYRO_MAX_PLAUSIBLE_RPS)])
        axis = "xyz"[int(np.argmax(np.abs(gyro[i])))]  # the column that reads deg/s there (often one axis only)
        c.problem(fname, f"angular rates up to {p999:.1f} (99.9th percentile of |gyro|) only make sense in deg/s; "
                  "the contract requires rad/s", f"gyro_{axis}", i + 1)
    acc_norms = np.linalg.norm(acc_k, axis=1)
    acc_norm = float(np.median(acc_norms))
    if ACC_G_BAND[0] <= acc_norm <= ACC_G_BAND[1]:
        c.problem(fname, f"median |acc| is {acc_norm:.3f}: that is g units; the contract requires m/s² "
                  "(multiply by 9.80665)", "acc_x", 1)
    elif not ACC_MPS2_BAND[0] <= acc_norm <= ACC_MPS2_BAND[1]:
        c.problem(fname, f"median |acc| is {acc_norm:.3g}, which is not gravity in m/s² (about 9.8)", "acc_x", 1)
    else:
        switch = _acc_unit_switch(t[keep], acc_norms)
        if switch is not None:
            row = int(np.flatnonzero(keep)[switch[0]]) + 1
            c.problem(fname, f"|acc| is {switch[1]:.3g} from t = {t[keep][switch[0]]:.6g} s on (and about 9.8 elsewhere) for "
                      f"at least {ACC_SWITCH_MIN_S:g} s: that part is in g units; the contract requires m/s² throughout",
                      "acc_x", row)
    if mag is not None:
        mag_nan = keep & ~np.isfinite(mag).all(axis=1)
        if mag_nan.any():
            c.count("imu_mag_nan_samples", int(mag_nan.sum()))
            c.warnings.append(f"{fname}: {int(mag_nan.sum())} samples without a magnetometer value (kept; magnetometer treated as missing there)")
        unit = _mag_unit_problem(mag if every_row else mag[keep])
        if unit is not None:
            c.problem(fname, unit, "mag_x")
    if any(p.file == fname for p in c.problems):
        return None
    C_bs = axes_to_dcm(meta.axes)
    t = t[keep]  # a copy even of every row: a view would keep the whole decoded table alive while the other tables load
    gyro_b = gyro_k @ C_bs.T
    acc_b = acc_k @ C_bs.T
    mag_b = None
    if mag is not None:
        m = mag if every_row else mag[keep]
        if meta.hard_iron_ut is not None or meta.soft_iron is not None:
            hi = meta.hard_iron_ut if meta.hard_iron_ut is not None else np.zeros(3)
            si = meta.soft_iron if meta.soft_iron is not None else np.eye(3)
            # Calibration is defined in the logged sensor axes: m_cal = S (m_raw - b).
            m = (m - hi) @ si.T
        mag_b = m @ C_bs.T
    nominal = 1.0 / meta.rate_hz
    gaps = timebase.find_gaps(t, nominal)
    if len(gaps):
        c.count("imu_gaps", len(gaps))
        c.warnings.append(f"{fname}: {len(gaps)} gaps longer than 2.5 sample periods (longest {np.max(gaps[:, 1] - gaps[:, 0]):.3f} s)")
    measured = (t[-1] - t[0]) / max(len(t) - 1, 1)
    for factor, unit in ((1e3, "milliseconds"), (1e6, "microseconds"), (1e9, "nanoseconds")):
        if abs(measured / factor * meta.rate_hz - 1.0) < 0.5:
            c.problem(fname, f"samples are {measured:.6g} apart with [imu] rate_hz = {meta.rate_hz:g}: t is in {unit}; "
                      "the contract requires seconds", "t", 2)
            return None
    if abs(measured * meta.rate_hz - 1.0) > 0.1:
        dup = c.counts.get("duplicate_stamps_imu", 0)
        if dup > DUPLICATE_SHARE_MAX * (dup + len(t)):
            # most samples share a stamp and the rest run at another rate: the time column cannot resolve the samples
            # (t written with too few decimals, or float32 far from zero); keeping the first of each stamp kept 601 of
            # 6000 samples of a 100 Hz log with t rounded to 0.1 s, verdict ok (audit, session 10)
            c.problem(fname, f"{dup} of {dup + len(t)} samples repeat the time stamp before them and the others are "
                      f"{measured:.6g} s apart, where [imu] rate_hz = {meta.rate_hz:g}: t cannot resolve the samples "
                      "(too few decimals, or float32); write t in seconds with enough digits", "t")
            return None
        c.warnings.append(f"{fname}: measured rate {1.0 / measured:.2f} Hz differs from [imu] rate_hz = {meta.rate_hz:g} by more than 10%")
    return t, gyro_b, acc_b, mag_b, gaps


def _mag_unit_problem(mag: np.ndarray) -> str | None:
    """What is wrong with a magnetometer block (N, 3) as logged whose median |m| is outside
    MAG_MEDIAN_UT (its unit, by the Earth's field of 22-67 µT), or None. Milligauss (220-670) is left
    to `conventions.magnetometer_findings`: a µT log with a few hundred µT of hard iron reads the same."""
    n = np.linalg.norm(mag[np.isfinite(mag).all(axis=1)], axis=1)
    if n.size == 0:
        return None
    med = float(np.median(n))
    if med > MAG_MEDIAN_UT[1]:
        return (f"median |mag| is {med:.3g}, where the Earth's field is 22-67 µT and no magnetometer reads "
                f"{MAG_MEDIAN_UT[1]:g} µT: it is nT; the contract requires µT (multiply by 0.001)")
    if not n.any():
        return "mag_x, mag_y and mag_z are zero in every sample: no magnetometer reading; leave the mag columns out"
    if med < MAG_MEDIAN_UT[0]:
        unit = ("it looks like gauss (multiply by 100)" if med >= 0.02 else
                "it looks like tesla (multiply by 1e6)" if med <= 2e-4 else "another unit")
        return f"median |mag| is {med:.3g}, where the Earth's field is 22-67 µT: {unit}; the contract requires µT"
    return None


def _acc_unit_switch(t_s, acc_norm_mps2) -> tuple[int, float] | None:
    """(first sample, its block mean of |acc|) of a stretch logged in g within a log in m/s²
    (two logs joined, a logger reconfigured): 1 s blocks whose mean |acc| lies in ACC_G_BAND for at
    least ACC_SWITCH_MIN_S seconds in a log whose |acc| is gravity in m/s² (ACC_MPS2_BAND) overall. A
    vehicle's |acc| stays near 9.8 m/s²; only a fall keeps it low, and then below 0.5 m/s²."""
    if t_s.size < 2 or t_s[-1] - t_s[0] < 2 * ACC_SWITCH_MIN_S:
        return None
    block = np.floor(t_s - t_s[0]).astype(np.int64)  # 1 s blocks
    norm = acc_norm_mps2
    starts = np.flatnonzero(np.r_[True, block[1:] != block[:-1]])
    med = np.add.reduceat(norm, starts) / np.diff(np.r_[starts, norm.size])  # block means: ms for an hour
    in_g = (med >= ACC_G_BAND[0]) & (med <= ACC_G_BAND[1])
    if in_g.sum() < ACC_SWITCH_MIN_S:
        return None
    # the longest run of consecutive g blocks
    runs = np.column_stack(timebase.true_runs(in_g))
    first, end = runs[np.argmax(runs[:, 1] - runs[:, 0])]
    if end - first < ACC_SWITCH_MIN_S:
        return None
    return int(starts[first]), float(med[first])


def _say_conflicting_duplicates(c: _Collector, fname: str, keep: np.ndarray, fix: np.ndarray, lla: np.ndarray) -> None:
    """GPS rows dropped as duplicate stamps (`_check_time`: the first of each kept) whose fix or position
    differs from the kept row's: counted (`gps_duplicate_conflicts`) and said with the largest distance and
    its row, since which of two fixes of one epoch is right, the log cannot tell."""
    dropped = np.flatnonzero(~keep)
    if not dropped.size:
        return
    kept = np.maximum.accumulate(np.where(keep, np.arange(keep.size), 0))[dropped]  # each one's kept twin
    a, b = lla[dropped], lla[kept]
    m_per_deg = 6_371_000.0 * np.pi / 180.0  # a sphere: a figure for a message
    dist = np.sqrt(((a[:, 0] - b[:, 0]) * m_per_deg) ** 2 + ((a[:, 1] - b[:, 1]) * m_per_deg * np.cos(np.radians(b[:, 0]))) ** 2
                   + (a[:, 2] - b[:, 2]) ** 2)
    same = (fix[dropped] == fix[kept]) & ((a == b) | (np.isnan(a) & np.isnan(b))).all(axis=1)
    if same.all():
        return
    far = np.where(np.isfinite(dist) & ~same, dist, -1.0)
    i = int(np.argmax(far))
    c.count("gps_duplicate_conflicts", int((~same).sum()))
    where = f"up to {far[i]:.3g} m from the kept fix (row {int(dropped[i]) + 1})" if far[i] >= 0 else \
        f"a different fix type or a missing position (row {int(dropped[np.argmax(~same)]) + 1})"
    c.warnings.append(f"{fname}: {int((~same).sum())} rows share a time stamp with an earlier row but not its fix: {where}; "
                      "the first row of each time stamp is used")


def _offset(meta: SessionMeta, name: str) -> float:
    return float(meta.time_offsets_s.get(f"{name}_offset_s", 0.0))


def _load_gps(c: _Collector, meta: SessionMeta, t0: float, imu_span_s: tuple[float, float] | None = None):
    got = _timed_table(c, "gps", schema.GPS_REQUIRED + schema.GPS_OPTIONAL, schema.GPS_REQUIRED)
    if got is None:
        return None
    df, fname, t, keep = got
    fix = df["fix"]
    bad = np.flatnonzero(~np.isin(fix, schema.GPS_FIX_VALUES))
    if bad.size:
        c.problem(fname, f"fix must be 0, 1 or 2, got {_v(fix[bad[0]])}", "fix", int(bad[0]) + 1)
        return None
    fix = fix.astype(np.int64)
    lla = df.matrix(["lat", "lon", "h"])
    _check_latlon(c, fname, lla[:, 0], lla[:, 1], lla[:, 2])
    _say_conflicting_duplicates(c, fname, keep, fix, lla)
    if "vn" in df.columns and "ve" in df.columns and not any(p.file == fname for p in c.problems):
        moving = keep & (fix > 0)
        spans = plausibility.velocity_spans(t[moving], lla[moving, 0], lla[moving, 1], df["vn"][moving], df["ve"][moving])
        ev = plausibility.latlon_swap_evidence(spans)
        if ev is not None:
            c.problem(fname, f"lat and lon look exchanged: the fixes' steps match vn/ve to {ev[1]:.1f} m (median) read "
                      f"the other way round, {ev[0]:.1f} m as given; swap the lat and lon columns", "lat", 1)
            return None
        ev = plausibility.latlon_radians_evidence(spans)
        if ev is not None:
            c.problem(fname, f"lat and lon look like radians: the fixes' steps match vn/ve to {ev[1]:.1f} m (median) "
                      f"read as radians, {ev[0]:.1f} m as degrees; the contract requires degrees (multiply by 180/pi)",
                      "lat", 1)
            return None
    if "vd" in df.columns and not any(p.file == fname for p in c.problems):
        moving = keep & (fix > 0)
        ev = plausibility.height_feet_evidence(t[moving], lla[moving, 2], df["vd"][moving])
        if ev is not None:
            c.problem(fname, f"h looks like feet: the fixes' height changes are {ev[0]:.2f} ± {ev[1]:.2f} times what vd "
                      f"integrates to ({plausibility.FEET_PER_M:.2f} in feet); the contract requires metres (multiply by 0.3048)",
                      "h")
            return None
    no_pos = (fix > 0) & ~np.isfinite(lla).all(axis=1)
    if no_pos.any():
        c.count("gps_fix_without_position", int(no_pos.sum()))
        c.warnings.append(f"{fname}: {int(no_pos.sum())} rows with fix > 0 but no position, treated as fix = 0")
        fix = np.where(no_pos, 0, fix)
    c.count("gps_no_fix_rows", int(((fix == 0) & keep).sum()))
    for col in ("sigma_n", "sigma_e", "sigma_u", "hdop", "nsat"):
        if col in df.columns:
            v = df[col]
            neg = np.flatnonzero(v < 0)
            if neg.size:
                c.problem(fname, f"{_v(v[neg[0]])} is negative", col, int(neg[0]) + 1)
    if any(p.file == fname for p in c.problems):
        return None

    def opt(cols):
        return np.column_stack([df[k] if k in df.columns else np.full(len(df), np.nan) for k in cols])

    lla = np.where((fix > 0)[:, None], lla, np.nan)
    t_rel = t[keep] + _offset(meta, "gps") - t0
    if _refuse_time_unit(c, fname, "fixes", t_rel, t[keep], t0 - _offset(meta, "gps"), imu_span_s, t0):
        return None
    fixes = fix[keep] > 0
    if imu_span_s is not None and meta.kind == "drive" and fixes.any() and \
            not ((t_rel >= imu_span_s[0]) & (t_rel <= imu_span_s[1]) & fixes).any():
        # a drive's chain needs the fixes: refused here as `tpos process` refuses it (chains.drive_smooth.
        # fixes_from_session), not a warning that validate passes and process then refuses
        c.problem(fname, gps_outside_imu_span_message(t_rel[fixes][[0, -1]] + t0, np.asarray(imu_span_s) + t0),
                  "t", int(np.flatnonzero(keep & (fix > 0))[0]) + 1)
        return None
    if imu_span_s is not None and not ((t_rel >= imu_span_s[0]) & (t_rel <= imu_span_s[1]) & fixes).any():
        # a chain that may run without GPS (target, ranging): counted and said; the run's verdict names
        # the clock mistake and its fix (tpos_cli.quality)
        c.count("gps_outside_imu_span", 1)
        c.warnings.append(f"{fname}: no GPS fix falls within the IMU's time span (GPS {t_rel[0] + t0:.3f}-{t_rel[-1] + t0:.3f} s, "
                          f"IMU {imu_span_s[0] + t0:.3f}-{imu_span_s[1] + t0:.3f} s on the logger clock): wrong clock or "
                          "[time] gps_offset_s; the GPS cannot be used as it is")
    return GpsData(
        t_s=t_rel, lla=lla[keep], fix=fix[keep],
        nsat=opt(["nsat"])[keep, 0], hdop=opt(["hdop"])[keep, 0],
        vel_ned_mps=opt(["vn", "ve", "vd"])[keep], sigma_neu_m=opt(["sigma_n", "sigma_e", "sigma_u"])[keep],
    )


def _refuse_time_unit(c: _Collector, fname: str, what: str, t_rel, t_raw, origin, imu_span_s, t0: float,
                      step_s=GPS_STEP_S) -> bool:
    """Record the problem (column t, row 2) and return True when `_time_unit` finds the table's times
    in milli-, micro- or nanoseconds; `what` names its rows ("fixes", "rows")."""
    unit = _time_unit(t_rel, t_raw, origin, imu_span_s, step_s)
    if unit is None:
        return False
    c.problem(fname, f"the {what} span {t_rel[0] + t0:.6g}-{t_rel[-1] + t0:.6g} where the IMU spans "
              f"{imu_span_s[0] + t0:.6g}-{imu_span_s[1] + t0:.6g} s; divided by {unit[1]:g} they fall within it: t is in {unit[0]}; "
              "the contract requires seconds", "t", 2)
    return True


def gps_outside_imu_span_message(fix_span_s, imu_span_s) -> str:
    """What `tpos validate` and the drive chain say of position fixes none of which falls within the
    IMU's span (first and last fix, first and last IMU sample: logger-clock seconds)."""
    return (f"no position fix falls within the IMU's time span (fixes {fix_span_s[0]:.3f}-{fix_span_s[-1]:.3f} s, IMU "
            f"{imu_span_s[0]:.3f}-{imu_span_s[-1]:.3f} s on the logger clock, after [time] gps_offset_s): the GPS rows "
            "are stamped on another clock (the GPS clock, not the logger's) or [time] gps_offset_s is wrong; the drive "
            "pipeline needs GPS fixes")


def _time_unit(t_rel, t_raw, origin, imu_span_s, step_s=GPS_STEP_S) -> tuple[str, float] | None:
    """(unit, factor) when a table's times are in milliseconds, microseconds or nanoseconds of the
    logger's clock: fewer than half the rows fall within the IMU's span as given, at least 90 % do once
    divided by the factor, and the rows are then `step_s` apart (the sensor's rate). `t_rel` relative
    to the logger's t0, `t_raw` as logged, `origin` what `t_raw` less gives `t_rel`; None otherwise."""
    if imu_span_s is None or t_rel.size < 3:
        return None
    a, b = imu_span_s
    if np.mean((t_rel >= a) & (t_rel <= b)) >= 0.5:
        return None
    for factor, unit in ((1e3, "milliseconds"), (1e6, "microseconds"), (1e9, "nanoseconds")):
        scaled = t_raw / factor - origin
        step = float(np.median(np.diff(scaled)))
        if np.mean((scaled >= a) & (scaled <= b)) >= 0.9 and step_s[0] <= step <= step_s[1]:
            return unit, factor
    return None


def _load_ranges(c: _Collector, meta: SessionMeta, t0: float):
    df, fname = c.table("ranges", schema.RANGES_REQUIRED, required=schema.RANGES_REQUIRED)
    if df is None:
        return None
    if meta.rangefinders is None:
        c.problem("session.toml", "[rangefinders] is required when ranges.* exists (baseline_12_m, baseline_13_m)")
    t = df["t"]
    keep = _check_time(c, fname, t, "ranges")
    if keep is None:
        return None
    d = df.matrix(["d1", "d2", "d3"])
    for j, col in enumerate(("d1", "d2", "d3")):
        neg = np.flatnonzero(d[:, j] < 0)
        if neg.size:
            c.problem(fname, f"negative range {_v(d[neg[0], j])} m", col, int(neg[0]) + 1)
    if any(p.file == fname for p in c.problems):
        return None
    _check_range_unit(c, fname, d[keep], "d1")
    if any(p.file == fname for p in c.problems):
        return None
    c.count("ranges_no_return", int((~np.isfinite(d[keep])).sum()))
    return RangeData(t_s=t[keep] + _offset(meta, "ranges") - t0, range_m=d[keep])


ODOMETRY_DUPLICATE_SHARE_MAX = 0.5  # set before looking at logs (no real log repeats an odometry stamp)


def _load_odometry(c: _Collector, meta: SessionMeta, t0: float, imu_span_s: tuple[float, float] | None):
    """The optional `odometry` table: time checks, NaN speeds dropped and counted, speed >= 0."""
    got = _timed_table(c, "odometry", schema.ODOMETRY_REQUIRED, schema.ODOMETRY_REQUIRED)
    if got is None:
        return None
    df, fname, t, keep = got
    dup = int((~keep).sum())
    if dup > ODOMETRY_DUPLICATE_SHARE_MAX * t.size:
        # a logger repeats a row now and then; most rows sharing a stamp is a time column that cannot tell the samples apart
        # (all rows 10.0 kept one of 2401 and ran with exit 0, audit session 13)
        c.problem(fname, f"{dup} of {t.size} rows repeat the time stamp before them: t cannot resolve the samples (too few "
                  "decimals, or one value); write t in seconds with enough digits", "t")
        return None
    v = df["speed_mps"]
    neg = np.flatnonzero(v < 0)
    if neg.size:
        c.problem(fname, f"speed {_v(v[neg[0]])} m/s is negative; the contract's speed_mps is the forward speed, >= 0",
                  "speed_mps", int(neg[0]) + 1)
        return None
    fast = np.flatnonzero(v > ODOMETER_MAX_MPS)
    if fast.size:
        c.problem(fname, f"speed {_v(v[fast[0]])} m/s is beyond any wheeled vehicle's ({ODOMETER_MAX_MPS:g} m/s): "
                  "a corrupted row or another unit (km/h, mm/s?); the contract's speed_mps is m/s", "speed_mps", int(fast[0]) + 1)
        return None
    nan = keep & ~np.isfinite(v)
    if nan.any():
        c.count("odometry_nan_samples", int(nan.sum()))
        c.warnings.append(f"{fname}: {int(nan.sum())} rows without a speed value dropped")
    keep = keep & np.isfinite(v)
    if not keep.any():
        c.problem(fname, "no row carries a speed value", "speed_mps")
        return None
    t_rel = t[keep] + _offset(meta, "odometry") - t0
    if _refuse_time_unit(c, fname, "rows", t_rel, t[keep], t0 - _offset(meta, "odometry"), imu_span_s, t0, ODOMETRY_STEP_S):
        return None
    if imu_span_s is not None:
        inside = (t_rel >= imu_span_s[0]) & (t_rel <= imu_span_s[1])
        if not inside.any():
            c.problem(fname, f"no odometry row falls within the IMU's time span (odometry {t_rel[0] + t0:.3f}-{t_rel[-1] + t0:.3f} s, "
                      f"IMU {imu_span_s[0] + t0:.3f}-{imu_span_s[1] + t0:.3f} s on the logger clock): wrong clock or [time] odometry_offset_s", "t")
            return None
    return OdometryData(t_s=t_rel, speed_mps=v[keep])


def _check_range_unit(c: _Collector, fname: str, r: np.ndarray, column: str) -> None:
    """Ranges whose median is beyond RANGE_MAX_PLAUSIBLE_M are millimetres, not metres."""
    r = r[np.isfinite(r)]
    if r.size and np.median(r) > RANGE_MAX_PLAUSIBLE_M:
        c.problem(fname, f"median range {np.median(r):.6g} m is beyond any rangefinder here: millimetres? "
                  "the contract requires metres", column)


def _load_anchors(c: _Collector, meta: SessionMeta):
    df, fname = c.table("anchors", ("lat", "lon", "h", "e", "n", "u"), text=("id",), required=("id",), csv_only=True)
    if df is None:
        return None
    ids = tuple(df["id"])
    has_lla = all(k in df.columns for k in ("lat", "lon", "h"))
    has_enu = all(k in df.columns for k in ("e", "n", "u"))
    if not (has_lla or has_enu):
        c.problem(fname, "anchors need either lat, lon, h or e, n, u columns", "lat" if "lat" not in df.columns else "e")
        return None
    empty = [i for i, v in enumerate(ids) if v == ""]
    if empty:
        c.problem(fname, "anchor id is empty", "id", empty[0] + 1)
    import pandas as pd  # here: a drive session is read without pandas

    dup = pd.Series(ids).duplicated().to_numpy()
    if dup.any():
        c.problem(fname, f"anchor id {_v(ids[int(np.argmax(dup))])} appears twice", "id", int(np.argmax(dup)) + 1)
    origin = meta.local_origin_lla
    if has_lla:
        lla = df.matrix(["lat", "lon", "h"])
        _check_latlon(c, fname, lla[:, 0], lla[:, 1], lla[:, 2])
        nan = np.flatnonzero(~np.isfinite(lla).all(axis=1))
        if nan.size:
            c.problem(fname, "anchor position is incomplete", "lat", int(nan[0]) + 1)
        if origin is None:
            origin = lla[0].copy()
    else:
        enu = df.matrix(["e", "n", "u"])
        nan = np.flatnonzero(~np.isfinite(enu).all(axis=1))
        if nan.size:
            c.problem(fname, "anchor position is incomplete", "e", int(nan[0]) + 1)
        if origin is None:
            c.problem("session.toml", "[local] origin (lat, lon, h) is required when anchors.csv gives e, n, u")
            return None
    if any(p.file == fname for p in c.problems):
        return None
    if has_lla:
        ned = geodetic.lla_to_ned(lla, origin)
    else:
        lla = geodetic.enu_to_lla(enu, origin)
        ned = np.column_stack([enu[:, 1], enu[:, 0], -enu[:, 2]])
    return Anchors(ids=ids, lla=lla, ned_m=ned, origin_lla=np.asarray(origin, dtype=float))


def _anchor_index(c: _Collector, fname: str, ids: np.ndarray, anchors: Anchors | None) -> np.ndarray | None:
    if anchors is None:
        if not (c.dir / "anchors.csv").exists():  # else its own problem is already reported
            c.problem(fname, "ranges to anchors need anchors.csv with the anchors' positions")
        return None
    lookup = {a: i for i, a in enumerate(anchors.ids)}
    import pandas as pd  # here: a drive session is read without pandas

    codes, uniques = pd.factorize(np.asarray(ids, dtype=object))  # ids: str (read_table), never missing
    idx = np.array([lookup.get(a, -1) for a in uniques] + [-1], dtype=np.int64)[codes]
    bad = np.flatnonzero(idx < 0)
    if bad.size:
        c.problem(fname, f"anchor id {_v(ids[bad[0]])} is not in anchors.csv", "id", int(bad[0]) + 1)
        return None
    return idx


def _load_anchor_ranges(c: _Collector, meta: SessionMeta, t0: float, anchors: Anchors | None):
    df, fname = c.table("anchor_ranges", ("t", "range"), text=("id",), required=schema.ANCHOR_RANGES_REQUIRED)
    if df is None:
        return None
    t = df["t"]
    nan = np.flatnonzero(~np.isfinite(t))
    if nan.size:
        c.problem(fname, "time is empty or not finite", "t", int(nan[0]) + 1)
        return None
    i = timebase.first_decrease(t)
    if i is not None:  # long format: several rows share one epoch, so only decreases are errors
        c.problem(fname, f"time goes backwards ({_v(t[i])} after {_v(t[i - 1])})", "t", i + 1)
        return None
    r = df["range"]
    neg = np.flatnonzero(r < 0)
    if neg.size:
        c.problem(fname, f"negative range {_v(r[neg[0]])} m", "range", int(neg[0]) + 1)
        return None
    idx = _anchor_index(c, fname, df["id"], anchors)
    if idx is None:
        return None
    _check_range_unit(c, fname, r, "range")
    if any(p.file == fname for p in c.problems):
        return None
    import pandas as pd  # here: a drive session is read without pandas

    pair = pd.DataFrame({"t": t, "a": idx}).duplicated().to_numpy()
    ok = np.isfinite(r) & ~pair
    c.count("anchor_ranges_missing", int((~np.isfinite(r)).sum()))
    c.count("duplicate_stamps_anchor_ranges", int(pair.sum()))
    return AnchorRanges(t_s=t[ok] + _offset(meta, "anchor_ranges") - t0, anchor=idx[ok], range_m=r[ok])


def _load_range_calibration(c: _Collector, anchors: Anchors | None):
    df, fname = c.table("range_calibration", ("true_m", "measured_m"), text=("id",),
                        required=schema.RANGE_CALIBRATION_REQUIRED, csv_only=True)
    if df is None:
        return None
    tm, mm = df["true_m"], df["measured_m"]
    for col, v in (("true_m", tm), ("measured_m", mm)):
        bad = np.flatnonzero(~np.isfinite(v) | (v < 0))
        if bad.size:
            c.problem(fname, f"{_v(v[bad[0]])} is not a non-negative distance", col, int(bad[0]) + 1)
            return None
    idx = _anchor_index(c, fname, df["id"], anchors)
    if idx is None:
        return None
    return RangeCalibration(anchor=idx, true_m=tm, measured_m=mm)


def _load_targets(c: _Collector):
    df, fname = c.table("targets", ("lat", "lon", "h"), text=("id", "role"), required=schema.TARGETS_REQUIRED, csv_only=True)
    if df is None:
        return None
    ids = tuple(df["id"])
    roles = tuple(df["role"]) if "role" in df.columns else ("",) * len(ids)
    bad = [i for i, r in enumerate(roles) if r not in schema.TARGET_ROLES]
    if bad:
        c.problem(fname, f"role must be 'reference' or 'truth' (or empty), got {_v(roles[bad[0]])}", "role", bad[0] + 1)
    import pandas as pd  # here: a drive session is read without pandas

    dup = pd.Series(ids).duplicated().to_numpy()
    if dup.any():
        i = int(np.argmax(dup))
        c.problem(fname, f"target id {_v(ids[i])} appears twice (rows {ids.index(ids[i]) + 1} and {i + 1}); "
                  "a surveyed point has one position", "id", i + 1)
    lla = df.matrix(["lat", "lon", "h"])
    _check_latlon(c, fname, lla[:, 0], lla[:, 1], lla[:, 2])
    nan = np.flatnonzero(~np.isfinite(lla).all(axis=1))
    if nan.size:
        c.problem(fname, "target position is incomplete", "lat", int(nan[0]) + 1)
    if any(p.file == fname for p in c.problems):
        return None
    return Targets(ids=ids, lla=lla, role=roles)


def _check_targets_near_observer(c: _Collector, targets: Targets, observer_lla: np.ndarray) -> None:
    """A surveyed target is within a rangefinder's reach of [observer]; one thousands of km away is a
    lat/lon swap (in targets.csv or in [observer]) or another site's file."""
    d = plausibility.distances_from_m(targets.lla, observer_lla)
    far = np.flatnonzero(d > plausibility.TARGET_MAX_DISTANCE_M)
    if not far.size:
        return
    i = int(far[0])
    hint = "a target file of another site?"
    # exchanging lat and lon in either place brings the two together: geometry cannot say which one
    if min(plausibility.distances_from_m(targets.lla[i, [1, 0, 2]], observer_lla)[0],
           plausibility.distances_from_m(targets.lla[i], observer_lla[[1, 0, 2]])[0]) <= plausibility.TARGET_MAX_DISTANCE_M:
        hint = "lat and lon are exchanged, in targets.csv or in [observer] of session.toml (the one not at the site)"
    c.problem("targets.csv", f"target {_v(targets.ids[i])} is {d[i] / 1000:.0f} km from [observer] ({observer_lla[0]:g}, "
              f"{observer_lla[1]:g}), beyond any rangefinder's {plausibility.TARGET_MAX_DISTANCE_M / 1000:g} km: {hint}",
              "lat", i + 1)


def _load_shots(c: _Collector, t0: float):
    df, fname = c.table("shots", ("t_start", "t_end"), text=("id",), required=schema.SHOTS_REQUIRED, csv_only=True)
    if df is None:
        return None
    a, b = df["t_start"], df["t_end"]
    for col, v in (("t_start", a), ("t_end", b)):
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            c.problem(fname, "time is empty or not finite", col, int(bad[0]) + 1)
            return None
    bad = np.flatnonzero(b <= a)
    if bad.size:
        c.problem(fname, f"t_end {_v(b[bad[0]])} is not after t_start {_v(a[bad[0]])}", "t_end", int(bad[0]) + 1)
        return None
    order = np.argsort(a, kind="stable")
    over = np.flatnonzero(a[order][1:] < b[order][:-1])
    if over.size:
        i, j = int(order[over[0]]), int(order[over[0] + 1])
        c.problem(fname, f"shot windows overlap: row {i + 1} ({df['id'][i]}, {_v(a[i])}-{_v(b[i])}) and row {j + 1} "
                  f"({df['id'][j]}, {_v(a[j])}-{_v(b[j])}); LR1 is held on one point at a time", "t_start", j + 1)
        return None
    return Shots(ids=tuple(df["id"]), t_start_s=a - t0, t_end_s=b - t0)


def _load_truth(c: _Collector, t0: float):
    path = None
    try:
        path = find_table(c.dir, "truth")
    except InvalidInputError as exc:
        c.problems.extend(exc.problems)
        return None
    if path is None:
        return None
    df_all = None
    try:
        regular_file_size(path, path.name, MAX_TABLE_BYTES)
    except InvalidInputError as exc:
        c.problems.append(Problem(path.name, str(exc).split(": ", 1)[1]))
        return None
    try:
        # Truth may carry extra columns (e.g. BROAD's `movement`): keep the numeric ones.
        if path.suffix == ".parquet":
            import pyarrow.parquet as pq

            names = pq.read_schema(path).names
        else:
            import pandas as pd  # here, for a CSV truth only: a Parquet session is read (and reported) without pandas

            names = pd.read_csv(path, nrows=0).columns.tolist()
    except Exception:
        names = []
    extra_cols = tuple(n for n in names if n not in schema.TRUTH_REQUIRED + schema.TRUTH_OPTIONAL)
    got = _timed_table(c, "truth", schema.TRUTH_REQUIRED + schema.TRUTH_OPTIONAL + extra_cols, ("t",))
    if got is None:
        return None
    df, fname, t, keep = got

    def opt(cols):
        return np.column_stack([df[k] if k in df.columns else np.full(len(df), np.nan) for k in cols])

    lla = opt(["lat", "lon", "h"])
    _check_latlon(c, fname, lla[:, 0], lla[:, 1], lla[:, 2])
    if any(p.file == fname for p in c.problems):
        return None
    del df_all
    return Truth(t_s=t[keep] - t0, lla=lla[keep], vel_ned_mps=opt(["vn", "ve", "vd"])[keep],
                 rpy_deg=opt(["roll", "pitch", "yaw"])[keep],
                 extra={k: df[k][keep] for k in extra_cols if k in df.columns})


def _load_imu_times(c: _Collector, meta: SessionMeta):
    """The IMU's time column alone, with its checks (t0, span and gaps for the other tables)."""
    got = _imu_table(c, ("t",), ("t",))
    if got is None:
        return None
    t = got[2][got[3]]
    return t, None, None, None, timebase.find_gaps(t, 1.0 / meta.rate_hz)


def load_imu(session: Session) -> ImuData:
    """The IMU of a session loaded with `with_imu=False`, read and checked as `load_session` does."""
    if session.imu is not None:
        return session.imu
    c = _Collector(session.path)
    imu = _load_imu(c, session.meta)
    if c.problems or imu is None:
        _raise(c)
    t, gyro_b, acc_b, mag_b, _ = imu
    return _imu_data(t - session.t0_s, gyro_b, acc_b, mag_b)


def _imu_data(t_rel_s, gyro_b, acc_b, mag_b) -> ImuData:
    """`ImuData` of `_load_imu`'s columns (contiguous, as the kernels read them), t relative to t0."""
    return ImuData(t_s=t_rel_s, gyro_b_rps=np.ascontiguousarray(gyro_b), acc_b_mps2=np.ascontiguousarray(acc_b),
                   mag_b_ut=None if mag_b is None else np.ascontiguousarray(mag_b))


def load_session(path: str | Path, *, with_truth: bool = True, with_imu: bool = True) -> Session:
    """Load and validate a session directory; raises InvalidInputError listing every problem.
    with_truth=False leaves the truth table unread (`Session.truth` None): it is for reports only, never
    an input to processing (the contract), and on a simulated hour it is a tenth of `tpos process`.
    with_imu=False reads only the IMU's time column (t0 and the span the other tables are checked
    against): `Session.imu` None, `load_imu` reads it when needed. For reports on a run whose recorded
    input hashes match the session (its IMU was checked when it was processed)."""
    session_dir = Path(path)
    if not session_dir.is_dir():
        p = Problem(str(session_dir), "not a session directory (it must hold session.toml and imu.*)")
        raise InvalidInputError(str(p), [p])
    c = _Collector(session_dir)
    meta = _parse_meta(c)
    if meta is None:
        _raise(c)
    imu = _load_imu(c, meta) if with_imu else _load_imu_times(c, meta)
    t0 = float(imu[0][0]) if imu is not None else 0.0
    imu_span = (0.0, float(imu[0][-1] - t0)) if imu is not None else None
    gps = _load_gps(c, meta, t0, imu_span)
    ranges = _load_ranges(c, meta, t0)
    odometry = _load_odometry(c, meta, t0, imu_span)
    anchors = _load_anchors(c, meta)
    anchor_ranges = _load_anchor_ranges(c, meta, t0, anchors)
    range_cal = _load_range_calibration(c, anchors)
    targets = _load_targets(c)
    shots = _load_shots(c, t0)
    truth = _load_truth(c, t0) if with_truth else None
    if shots is not None and targets is not None:
        pass  # a shot on a new name is an unknown point: allowed by the contract
    if targets is not None and meta.observer_lla is not None:
        _check_targets_near_observer(c, targets, meta.observer_lla)
    if c.problems or imu is None:
        _raise(c)
    t, gyro_b, acc_b, mag_b, gaps = imu
    t_rel = t - t0
    outages = np.empty((0, 2))
    if gps is not None:
        outages = timebase.gps_outages(gps.t_s[gps.valid], 0.0, float(t_rel[-1]))
        if len(outages):
            c.count("gps_outages", len(outages))
    hashes = session_file_hashes(session_dir)
    return Session(
        path=session_dir.resolve(), meta=meta, t0_s=t0,
        imu=None if gyro_b is None else _imu_data(t_rel, gyro_b, acc_b, mag_b),
        gps=gps, ranges=ranges, anchors=anchors, anchor_ranges=anchor_ranges, range_calibration=range_cal,
        targets=targets, shots=shots, truth=truth, gps_outages_s=outages, imu_gaps_s=gaps - t0,
        counts=dict(c.counts), warnings=tuple(c.warnings), file_hashes=hashes, odometry=odometry,
    )


def session_file_hashes(session_dir: Path) -> dict[str, str]:
    """sha256 of every contract file of a session (what `summary.json` records as its inputs)."""
    return {p.name: sha256_file(p) for p in sorted(Path(session_dir).iterdir()) if p.is_file() and _is_session_file(p.name)}


def _is_session_file(name: str) -> bool:
    stem, _, ext = name.partition(".")
    return name == "session.toml" or (ext in ("csv", "parquet") and stem in schema.TABLES_ANY_FORMAT + schema.TABLES_CSV_ONLY)


def _raise(c: _Collector):
    problems = c.problems or [Problem("session", "invalid")]
    first = str(problems[0])
    more = f" (and {len(problems) - 1} more problem{'s' if len(problems) > 2 else ''})" if len(problems) > 1 else ""
    raise InvalidInputError(f"{c.dir.name}/{first}{more}", problems)
