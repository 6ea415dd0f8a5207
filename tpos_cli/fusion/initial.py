"""Initial state of the INS/GPS filter for a land vehicle (paper 003 Sec. 5: a car).

Levelling over the static start (`alignment.detect_static_window`, `alignment.level_rad`),
heading from GPS velocity once moving (`alignment.gps_velocity_heading`) carried back to the
first sample through the gyros, or the magnetometer when GPS never shows motion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli import alignment
from tpos_cli.errors import ProcessingError
from tpos_cli.frames import earth
from tpos_cli.frames.rotation import dcm_to_euler, euler_to_dcm, wrap_angle_rad
from tpos_cli.fusion.insgps import GpsFixes, InitialState
from tpos_cli.ins.mechanization import integrate


@dataclass(frozen=True)
class InitialSigmas:
    """Initial SDs (SI): position m, velocity m/s, level and yaw rad, acc bias m/s^2, gyro bias rad/s."""

    pos_m: float
    vel_mps: float
    level_rad: float
    yaw_rad: float
    acc_bias_mps2: float
    gyro_bias_rps: float


def initial_covariance(s: InitialSigmas) -> np.ndarray:
    """Diagonal P0 (15, 15) from the SDs."""
    d = np.array([s.pos_m] * 3 + [s.vel_mps] * 3 + [s.level_rad, s.level_rad, s.yaw_rad]
                 + [s.acc_bias_mps2] * 3 + [s.gyro_bias_rps] * 3)
    return np.diag(d**2)


def align_vehicle(t_s, gyro_b_rps, acc_b_mps2, mag_b_ut, fixes: GpsFixes, lever_b_m, sig: InitialSigmas,
                  *, min_speed_mps=3.0, declination_rad=0.0) -> tuple[InitialState, dict]:
    """Initial state at t_s[0] and a dict saying how it was obtained (for the summary)."""
    t = np.asarray(t_s, dtype=float)
    info: dict = {}
    if fixes.t_s.size == 0:
        raise ProcessingError("gps: no valid fix; the drive pipeline needs GPS for its position and heading")
    try:
        # only the start of the log can hold the static start: do not scan an hour of IMU
        n_head = int(np.searchsorted(t, t[0] + 120.0)) + 1
        win = alignment.detect_static_window(t[:n_head], gyro_b_rps[:n_head], acc_b_mps2[:n_head],
                                             min_duration_s=1.0, max_duration_s=60.0)
        static = win.i0 == 0 or t[win.i0] - t[0] < 0.5
    except ProcessingError:
        static = False
    if static:
        # a car pulling away smoothly passes the IMU stillness test: end the window before the
        # first fix that shows motion
        speed = np.hypot(fixes.vel_ned_mps[:, 0], fixes.vel_ned_mps[:, 1])
        moving = np.flatnonzero(np.nan_to_num(speed, nan=0.0) > 0.3)
        if moving.size:
            i_move = int(np.searchsorted(t, fixes.t_s[moving[0]] - 1.0))
            win = alignment.StaticWindow(win.i0, max(win.i0 + 2, min(win.i1, i_move)), win.end_reason)
        sl = slice(win.i0, win.i1)
        info["levelling"] = f"static start, {t[win.i1 - 1] - t[win.i0]:.1f} s"
        vel_sigma = 0.05
    else:
        sl = slice(0, max(2, int(np.searchsorted(t, t[0] + 1.0))))
        info["levelling"] = "moving start: mean specific force of the first second (vehicle acceleration biases it)"
        vel_sigma = sig.vel_mps
    roll, pitch = alignment.level_rad(np.mean(acc_b_mps2[sl], axis=0))
    roll, pitch = float(roll), float(pitch)
    lat0 = np.radians(fixes.lla[0, 0])
    yaw_sigma = sig.yaw_rad
    try:
        hd = alignment.gps_velocity_heading(fixes.t_s, fixes.lla, fixes.vel_ned_mps, min_speed_mps=min_speed_mps)
        i_h = int(np.clip(np.searchsorted(t, hd.t_s), 1, t.size - 1))
        # attitude from t0 to the heading epoch with yaw 0: C(t_h) = Rz(yaw0) C_mech(t_h) exactly
        # when the nav-frame rotation over that span is negligible (15 deg/h Earth rate)
        tr = integrate(t[: i_h + 1], gyro_b_rps[: i_h + 1], acc_b_mps2[: i_h + 1], fixes.lla[0], [0.0, 0.0, 0.0],
                       np.degrees([roll, pitch, 0.0]))
        _, _, yaw_mech = dcm_to_euler(tr.C_nb[-1])
        yaw = float(wrap_angle_rad(hd.yaw_rad - yaw_mech))
        yaw_sigma = max(yaw_sigma, hd.sigma_yaw_rad)
        info["heading"] = f"gps velocity at t_s = {hd.t_s:.1f} s"
    except ProcessingError:
        if mag_b_ut is None:
            raise
        m = np.nanmean(mag_b_ut[sl], axis=0)
        yaw = float(alignment.magnetic_yaw_rad(m, roll, pitch, declination_rad))
        yaw_sigma = max(yaw_sigma, np.radians(5.0))
        info["heading"] = "magnetometer (GPS never shows motion)"
    C = euler_to_dcm(roll, pitch, yaw)
    bias = np.zeros(6)
    if static:
        bias[3:] = np.mean(gyro_b_rps[sl], axis=0) - C.T @ earth.earth_rate_ned_rps(lat0)
        info["gyro_bias_from_static_rps"] = bias[3:].tolist()
    # position from the first fix, antenna to IMU
    i0 = 0
    lla = fixes.lla[i0]
    lat = np.radians(lla[0])
    rn = earth.meridian_radius_m(lat) + lla[2]
    re = earth.transverse_radius_m(lat) + lla[2]
    Cl = C @ np.asarray(lever_b_m, dtype=float)
    vel = np.zeros(3) if static else np.nan_to_num(fixes.vel_ned_mps[i0])
    dt0 = fixes.t_s[i0] - t[0]  # move the fix back to t0 along its velocity
    nav = np.array([lat - (Cl[0] + vel[0] * dt0) / rn, np.radians(lla[1]) - (Cl[1] + vel[1] * dt0) / (re * np.cos(lat)),
                    lla[2] + Cl[2] + vel[2] * dt0, *vel])
    s = InitialSigmas(max(sig.pos_m, 1.0 + abs(dt0) * (0.0 if static else 2.0)), vel_sigma, sig.level_rad, yaw_sigma,
                      sig.acc_bias_mps2, sig.gyro_bias_rps)
    info["static_start"] = bool(static)
    return InitialState(nav, C, bias, initial_covariance(s)), info


def measured_white_noise(x) -> float:
    """Per-sample white-noise SD of a sensor series (N, 3), from its first differences.

    For white noise of SD s, x[k+1] - x[k] has SD s sqrt(2); the motion of a vehicle at IMU rates
    adds little to a difference. Robust scale (1.4826 MAD) so that bumps do not dominate;
    averaged over the three axes.
    """
    d = np.diff(np.asarray(x, dtype=float), axis=0)
    mad = np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    return float(np.mean(1.4826 * mad / np.sqrt(2.0)))
