"""Column names of the contract tables (docs/log-format.md), in one place."""

from __future__ import annotations

IMU_REQUIRED = ("t", "gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z")
IMU_MAG = ("mag_x", "mag_y", "mag_z")
RANGES_REQUIRED = ("t", "d1", "d2", "d3")
GPS_REQUIRED = ("t", "lat", "lon", "h", "fix")
GPS_OPTIONAL = ("nsat", "hdop", "vn", "ve", "vd", "sigma_n", "sigma_e", "sigma_u")
ANCHOR_RANGES_REQUIRED = ("t", "id", "range")
RANGE_CALIBRATION_REQUIRED = ("id", "true_m", "measured_m")
TARGETS_REQUIRED = ("id", "lat", "lon", "h")
SHOTS_REQUIRED = ("id", "t_start", "t_end")
ODOMETRY_REQUIRED = ("t", "speed_mps")
TRUTH_REQUIRED = ("t", "lat", "lon", "h")
TRUTH_OPTIONAL = ("vn", "ve", "vd", "roll", "pitch", "yaw")

# Tables that may be CSV or Parquet, and those the contract gives as CSV only.
TABLES_ANY_FORMAT = ("imu", "ranges", "gps", "anchor_ranges", "odometry", "truth")
TABLES_CSV_ONLY = ("anchors", "range_calibration", "targets", "shots")

# session.toml: its sections and the keys tpos reads in each (the contract's and tpos's extensions),
# for the parser (`session.load_session`) and its unknown-key warnings. Each section is optional
# except [session] and [imu]; [time] holds one `<table>_offset_s` per table.
IMU_NOISE_KEYS = ("gyro_noise_dps", "gyro_bias_dph", "acc_noise_mg", "acc_bias_mg", "mag_noise_ut")
_LLA_KEYS = ("lat", "lon", "h")
SESSION_TOML_KEYS = {
    "session": ("name", "kind", "start_utc"),
    "imu": ("axes", "rate_hz", "mounting_rpy_deg", *IMU_NOISE_KEYS),
    "rangefinders": ("baseline_12_m", "baseline_13_m", "sigma_m"),
    "magnetic": ("declination_deg", "hard_iron_ut", "soft_iron"),
    "gps": ("lever_arm_m",),
    "observer": _LLA_KEYS,
    "local": _LLA_KEYS,
    "time": tuple(f"{t}_offset_s" for t in (*TABLES_ANY_FORMAT, *TABLES_CSV_ONLY)),
}

SESSION_KINDS = ("target", "drive", "ranging")
TARGET_ROLES = ("reference", "truth", "")
GPS_FIX_VALUES = (0, 1, 2)

# Output tables.
TRAJECTORY_COLUMNS = ("t", "lat", "lon", "h", "vn", "ve", "vd", "roll", "pitch", "yaw", "solution")
TARGET_COLUMNS = ("id", "t_start", "t_end", "range_m", "lat", "lon", "h", "solution")
