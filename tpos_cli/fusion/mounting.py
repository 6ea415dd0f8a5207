"""Mounting check for land vehicles: does the IMU's forward axis point along the direction of travel?

A car hardly slips sideways, so while it moves its course over ground (atan2(ve, vn)) and the
yaw of its forward axis agree within a few degrees. An INS/GPS filter converges on the yaw of the
IMU's x axis whatever the mounting (positions stay right), so a course-minus-yaw offset that is
steady and large says the IMU is not mounted (or its `[imu] axes` not declared) as the session
claims: the attitude output then describes the IMU, not the vehicle, and laser targeting along
"body forward" points the wrong way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli.frames.rotation import dcm_to_euler, rotvec_to_dcm


@dataclass(frozen=True)
class CourseYawCheck:
    """Course over ground minus yaw while moving: median_deg in (-180, 180], spread_deg (half the
    16-84 percentile range), moving_s (time above min_speed_mps), n rows used."""

    median_deg: float
    spread_deg: float
    moving_s: float
    min_speed_mps: float
    n: int

    def summary(self) -> dict:
        return {"course_minus_yaw_median_deg": round(self.median_deg, 2), "spread_deg": round(self.spread_deg, 2),
                "moving_s": round(self.moving_s, 1), "min_speed_mps": self.min_speed_mps, "rows": self.n}


def course_minus_yaw(t_s, vel_ned_mps, yaw_rad, min_speed_mps: float) -> CourseYawCheck | None:
    """Statistics of course - yaw over the rows faster than `min_speed_mps` (None if fewer than 2).

    The median is taken about the circular mean, so offsets near 180 deg (an IMU mounted
    backwards) do not split across the wrap.
    """
    t = np.asarray(t_s, dtype=float)
    v = np.asarray(vel_ned_mps, dtype=float)
    speed = np.hypot(v[:, 0], v[:, 1])
    m = speed > min_speed_mps
    if m.sum() < 2:
        return None
    d = np.arctan2(v[m, 1], v[m, 0]) - np.asarray(yaw_rad, dtype=float)[m]
    c = np.arctan2(np.mean(np.sin(d)), np.mean(np.cos(d)))
    r = np.angle(np.exp(1j * (d - c)))  # about the circular mean, in (-pi, pi]
    med = float(np.angle(np.exp(1j * (c + np.median(r)))))
    p16, p84 = np.percentile(r, [16.0, 84.0])
    dt = np.diff(t, prepend=t[0])
    return CourseYawCheck(float(np.degrees(med)), float(np.degrees(0.5 * (p84 - p16))), float(dt[m].sum()),
                          float(min_speed_mps), int(m.sum()))


def mounting_off(check: CourseYawCheck | None, threshold_deg: float, min_moving_s: float = 10.0) -> bool:
    """Whether course over ground minus yaw says the IMU's forward axis is off the direction of
    travel: its median beyond `threshold_deg` over at least `min_moving_s` of motion (the sentence
    for the user: `quality.mounting_text`)."""
    return check is not None and check.moving_s >= min_moving_s and abs(check.median_deg) > threshold_deg


def vehicle_attitude(C_nb, P_att_rad2, C_vb, misalign_py_rad=None, misalign_sd_rad=None, roll_sd_rad: float = 0.0):
    """The vehicle's attitude from the IMU's: C_nv = C_nb C_vb^T (C_vb: IMU body to vehicle
    axes, v_vehicle = C_vb v_body), with the filter's residual misalignment [pitch, yaw] (rad,
    (K, 2), `fusion.layout.mounting_block`) turning the vehicle axes by (I - [(0, m_p, m_y) x]) as
    the NHC rows model it. C_nb (K, 3, 3), P_att_rad2 (K, 3, 3) the NED attitude-error covariance;
    returns (C_nv (K, 3, 3), P (K, 3, 3)): the misalignment's variance (vehicle axes) is added,
    rotated into NED (the cross-covariance is left out: the two come from different rows), and
    roll_sd_rad^2 about the vehicle's forward axis: no measurement sees how the IMU is rolled on
    the vehicle (NHC and the travel direction fix its pitch and yaw only), so the vehicle's roll
    carries the mounting's roll uncertainty (`constraints.vehicle_axes` takes the IMU as unrolled).
    P_att_rad2 None: the attitude only, (C_nv, None) (checks that read no covariance)."""
    C_nb = np.asarray(C_nb, dtype=float)
    K = C_nb.shape[0]
    # C_nv = C_nb (M C_vb)^T = (C_nb C_vb^T) M^T, M = I - [m x]: one (3K, 3) product with the constant
    # C_vb^T, then M^T = I + [m x] for m = (0, m_p, m_y) as three column updates (no (K, 3, 3) products)
    C_nv = (C_nb.reshape(-1, 3) @ np.asarray(C_vb, dtype=float).T).reshape(K, 3, 3)
    if misalign_py_rad is not None:
        m = np.asarray(misalign_py_rad, dtype=float)
        mp, my = m[:, 0, None], m[:, 1, None]
        X = C_nv.copy()
        C_nv[:, :, 0] += X[:, :, 1] * my - X[:, :, 2] * mp
        C_nv[:, :, 1] -= X[:, :, 0] * my
        C_nv[:, :, 2] += X[:, :, 0] * mp
    if P_att_rad2 is None:
        return C_nv, None
    if misalign_sd_rad is None and not roll_sd_rad > 0.0:
        return C_nv, np.array(P_att_rad2, dtype=float, copy=True)
    d = np.zeros((K, 3))  # the diagonal of the vehicle-axes covariance [roll, pitch, yaw]
    d[:, 0] = float(roll_sd_rad) ** 2
    if misalign_sd_rad is not None:
        d[:, 1:] = np.broadcast_to(np.asarray(misalign_sd_rad, dtype=float), (K, 2)) ** 2
    P = (C_nv * d[:, None, :]) @ np.swapaxes(C_nv, 1, 2)  # C_nv diag(d) C_nv^T
    P += P_att_rad2
    return C_nv, P


def refined_mounting(C_vb, misalign_py_rad, sd_py_rad) -> tuple[np.ndarray, dict]:
    """The mounting C_vb (IMU body to vehicle axes) turned by a run's residual misalignment
    [pitch, yaw] (rad; `fusion.layout.mounting_block`: the vehicle axes are (I - [(0, m_p, m_y) x])
    C_vb, here the exact rotation by -m), and its summary: mounting_rpy_deg, sigma_py_deg (the
    misalignment's SDs, deg), residual_py_deg."""
    m = np.array([0.0, *np.asarray(misalign_py_rad, dtype=float)[:2]])
    C = rotvec_to_dcm(-m) @ np.asarray(C_vb, dtype=float)
    sd = np.degrees(np.asarray(sd_py_rad, dtype=float)[:2])
    return C, {"mounting_rpy_deg": [round(float(v), 2) for v in np.degrees(dcm_to_euler(C))],
               "sigma_py_deg": [round(float(v), 3) for v in sd], "residual_py_deg": [round(float(v), 3) for v in np.degrees(m[1:])]}
