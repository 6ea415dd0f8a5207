"""Frozen results of a simulation: exact truth, sensor outputs with and without errors."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tpos_cli.frames.geodetic import lla_to_ned
from tpos_cli.frames.rotation import dcm_to_rotvec, euler_to_dcm
from tpos_cli.sim.rtk import RtkErrors
from tpos_cli.sim.sensor_errors import ImuErrors, ImuGrade
from tpos_cli.sim.writer import write_session


@dataclass(frozen=True)
class SimTruth:
    """Truth of the body (IMU) point at the IMU sample times."""

    t_s: np.ndarray  # (N,) relative to the first IMU sample
    lla: np.ndarray  # (N, 3) lat deg, lon deg, h m
    vel_ned_mps: np.ndarray  # (N, 3)
    rpy_rad: np.ndarray  # (N, 3) roll, pitch, yaw (yaw in (-pi, pi])

    @property
    def C_nb(self) -> np.ndarray:
        """(N, 3, 3) body FRD -> NED."""
        return euler_to_dcm(self.rpy_rad[:, 0], self.rpy_rad[:, 1], self.rpy_rad[:, 2])

    def navigation_errors(self, idx: np.ndarray, nav: np.ndarray, C_nb: np.ndarray) -> np.ndarray:
        """(K, 9) errors of an estimate at truth samples `idx`: NED position (m, about the first truth
        point), NED velocity (m/s), and attitude phi (rad) with C_est = (I - [phi x]) C_true.
        `nav` (K, 6) is lat, lon (rad), h (m), vn, ve, vd (m/s); `C_nb` (K, 3, 3)."""
        lla = np.column_stack([np.degrees(nav[:, 0]), np.degrees(nav[:, 1]), nav[:, 2]])
        e_p = lla_to_ned(lla, self.lla[0]) - lla_to_ned(self.lla[idx], self.lla[0])
        e_v = nav[:, 3:] - self.vel_ned_mps[idx]
        phi = -dcm_to_rotvec(C_nb @ np.transpose(self.C_nb[idx], (0, 2, 1)))
        return np.column_stack([e_p, e_v, phi])

    @property
    def rpy_deg(self) -> np.ndarray:
        return np.degrees(self.rpy_rad)


@dataclass(frozen=True)
class SimImu:
    """IMU samples in body FRD (the writer rotates them into the logged `axes`)."""

    t_s: np.ndarray  # (N,)
    gyro_b_rps: np.ndarray  # (N, 3) with errors
    acc_b_mps2: np.ndarray
    mag_b_ut: np.ndarray | None
    gyro_true_b_rps: np.ndarray  # (N, 3) exact mean rates over (t_{k-1}, t_k]
    acc_true_b_mps2: np.ndarray
    mag_true_b_ut: np.ndarray | None  # Earth field only (no disturbance, no noise)
    errors: ImuErrors
    grade: ImuGrade
    axes: str
    rate_hz: float


@dataclass(frozen=True)
class SimGps:
    t_s: np.ndarray  # (M,)
    lla: np.ndarray  # (M, 3) with noise
    vel_ned_mps: np.ndarray  # (M, 3) with noise
    sigma_neu_m: np.ndarray  # (M, 3) the stated SDs: those the white noise was drawn with (raised in RTK float stretches)
    fix: np.ndarray  # (M,) int64
    nsat: np.ndarray  # (M,) int64
    hdop: np.ndarray  # (M,)
    lla_true: np.ndarray
    vel_true_ned_mps: np.ndarray
    sigma_vel_mps: float
    rtk: RtkErrors | None = None  # the RTK regimes and offsets at these rows (rtk.py), when simulated


@dataclass(frozen=True)
class SimRanges:
    """The three laser rangefinders (d1, d2, d3)."""

    t_s: np.ndarray  # (K,)
    range_m: np.ndarray  # (K, 3) with noise, NaN = no return
    range_true_m: np.ndarray  # (K, 3) exact ray-plane distances
    baseline_12_m: float
    baseline_13_m: float
    sigma_m: float


@dataclass(frozen=True)
class SimTargets:
    ids: tuple[str, ...]
    lla: np.ndarray  # (T, 3)
    role: tuple[str, ...]  # "reference" | "truth"


@dataclass(frozen=True)
class SimOdometry:
    """Vehicle speed as an odometer logs it: forward speed times (1 + scale_error) plus noise."""

    t_s: np.ndarray  # (M,)
    speed_mps: np.ndarray  # (M,)
    scale_error: float
    sigma_mps: float


@dataclass(frozen=True)
class SimShots:
    ids: tuple[str, ...]
    t_start_s: np.ndarray
    t_end_s: np.ndarray


@dataclass(frozen=True)
class SimAnchors:
    ids: tuple[str, ...]
    enu_m: np.ndarray  # (A, 3) in the [local] frame
    lla: np.ndarray  # (A, 3)
    origin_lla: np.ndarray  # (3,)


@dataclass(frozen=True)
class SimAnchorRanges:
    t_s: np.ndarray  # (R,)
    anchor: np.ndarray  # (R,) int64 index into SimAnchors.ids
    range_m: np.ndarray  # (R,) measured (Eq. 13)
    range_true_m: np.ndarray
    nlos_m: np.ndarray  # (R,) the NLOS error added (0 for LOS)


@dataclass(frozen=True)
class SimRangeCalibration:
    anchor: np.ndarray  # (C,) int64
    true_m: np.ndarray
    measured_m: np.ndarray
    scale: float  # f of Eq. 13
    bias_m: np.ndarray  # (A,) c_i of Eq. 13


@dataclass(frozen=True)
class SimResult:
    """Everything a scenario produced; `write(path)` makes a contract session directory."""

    kind: str  # "drive" | "target" | "ranging"
    name: str
    t0_s: float  # logger-clock time of the first IMU sample
    truth: SimTruth
    imu: SimImu
    gps: SimGps | None = None
    gps_outages_s: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # relative [start, end)
    ranges: SimRanges | None = None
    targets: SimTargets | None = None
    shots: SimShots | None = None
    anchors: SimAnchors | None = None
    anchor_ranges: SimAnchorRanges | None = None
    range_calibration: SimRangeCalibration | None = None
    odometry: SimOdometry | None = None
    toml: dict = field(default_factory=dict)  # extra session.toml sections ([magnetic], [observer], ...)
    params: dict = field(default_factory=dict)  # the scenario's parameters, recorded in session.toml

    def write(self, path: str | Path, *, overwrite: bool = False) -> Path:
        """Write the session directory (see `tpos_cli.sim.writer.write_session`)."""
        return write_session(self, path, overwrite=overwrite)
