"""Initial alignment of a static IMU: stationary-window detection, levelling, magnetic yaw.

Levelling is paper 000 Eq. 6 (pitch/roll from the mean specific force); magnetic yaw is
Eq. 7-9 (field levelled into the horizontal h-frame, azimuth plus declination D), of which the
paper's Eq. 13 is the zero-pitch/roll case. Written for the package's FRD body / NED frames:
f_b = C_nb^T (0, 0, -g) at rest, so pitch = atan2(f_x, hypot(f_y, f_z)), roll = atan2(-f_y, -f_z).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli.errors import ProcessingError
from tpos_cli.frames import earth
from tpos_cli.frames.rotation import euler_to_dcm


@dataclass(frozen=True)
class StaticWindow:
    """Sample indices [i0, i1) of the initial stationary window, and why it ended."""

    i0: int
    i1: int
    end_reason: str  # "motion" | "magnetic" | "max_duration" | "end_of_log"


@dataclass(frozen=True)
class Alignment:
    """Coarse initial attitude and the reference quantities measured while static.

    Angles in rad; C_nb (3,3) FRD->NED; gyro_bias_rps (3,) mean rate minus Earth rate;
    mag_norm_ut, mag_dip_rad: the undisturbed field seen during the window (NaN without a
    magnetometer); sigma_rpy_rad (3,) SD of the alignment from the sensor noise figures.
    """

    window: StaticWindow
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    C_nb: np.ndarray
    gyro_bias_rps: np.ndarray
    mag_norm_ut: float
    mag_dip_rad: float
    sigma_rpy_rad: np.ndarray


def _moving(x, n):
    """Centered moving mean of x (N, ...) over n samples (edges use the partial window).

    Mean over samples [lo, hi) = (c[hi] - c[lo]) / (hi - lo) with c the cumulative sum from 0,
    lo = clip(i - n//2, 0, N), hi = clip(i - n//2 + n, 0, N). The clipped indices are read as two
    slices of c padded with its first value (n//2 times) and its last (n times): no gathers.
    """
    x = np.asarray(x)
    N = x.shape[0]
    h = n // 2
    c = np.empty((N + 1 + h + n,) + x.shape[1:])
    c[: h + 1] = 0.0
    np.cumsum(x, axis=0, out=c[h + 1 : h + 1 + N])
    c[h + 1 + N :] = c[h + N]
    i = np.arange(N)
    cnt = (np.minimum(i - h + n, N) - np.maximum(i - h, 0)).reshape((-1,) + (1,) * (x.ndim - 1))
    return (c[n : n + N] - c[:N]) / cnt


def static_mask(t_s, gyro_b_rps, acc_b_mps2, *, window_s=0.5, gyro_tol_rps=0.03, acc_sd_tol_mps2=0.15):
    """True where the IMU is still: moving-window mean rate and specific-force SD below tolerance.

    The mean-rate test catches slow rotations that a pure SD test misses; the specific-force SD
    catches shaking. Tolerances are above MEMS noise (0.01 rad/s, 0.02 m/s^2 per sample).
    """
    dt = float(np.median(np.diff(t_s))) if t_s.size > 1 else 0.01
    n = max(3, int(round(window_s / dt)))
    w_mean = _moving(gyro_b_rps, n)
    a_mean = _moving(acc_b_mps2, n)
    a_var = _moving(acc_b_mps2**2, n) - a_mean**2
    a_sd = np.sqrt(np.clip(a_var, 0.0, None).sum(axis=1))
    return (np.linalg.norm(w_mean, axis=1) < gyro_tol_rps) & (a_sd < acc_sd_tol_mps2)


def detect_static_window(t_s, gyro_b_rps, acc_b_mps2, mag_b_ut=None, *, min_duration_s=1.0,
                         max_duration_s=60.0, window_s=0.5, gyro_tol_rps=0.03,
                         acc_sd_tol_mps2=0.15, mag_step_tol_ut=3.0) -> StaticWindow:
    """Find the initial stationary window: the first still stretch of at least `min_duration_s`.

    The window also ends where the field magnitude leaves its first-second median by more than
    `mag_step_tol_ut` (a disturbance that starts while still must not enter the magnetic yaw).
    Raises ProcessingError when no such window exists in the log.
    """
    t = np.asarray(t_s, dtype=float)
    still = static_mask(t, gyro_b_rps, acc_b_mps2, window_s=window_s, gyro_tol_rps=gyro_tol_rps,
                        acc_sd_tol_mps2=acc_sd_tol_mps2)
    # runs of consecutive still samples
    d = np.diff(np.concatenate([[0], still.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.01
    half = max(3, int(round(window_s / dt))) // 2
    for i0, i1 in zip(starts, ends):
        if i1 < t.size:
            i1 = max(i0 + 1, i1 - half)  # the centered test window sees motion half a window early
        if t[i1 - 1] - t[i0] < min_duration_s:
            continue
        reason = "motion" if i1 < t.size else "end_of_log"
        if t[i1 - 1] - t[i0] > max_duration_s:
            i1 = int(np.searchsorted(t, t[i0] + max_duration_s))
            reason = "max_duration"
        if mag_b_ut is not None and mag_step_tol_ut > 0:
            m = np.linalg.norm(np.asarray(mag_b_ut[i0:i1], dtype=float), axis=1)
            n1 = max(1, int(np.searchsorted(t[i0:i1], t[i0] + min(1.0, min_duration_s))))
            ref = np.nanmedian(m[:n1])
            dt = float(np.median(np.diff(t))) if t.size > 1 else 0.01
            m_s = _moving(np.nan_to_num(m, nan=ref), max(3, int(round(0.2 / dt))))  # 0.2 s smoothing vs noise
            bad = np.flatnonzero(np.abs(m_s - ref) > mag_step_tol_ut)
            if bad.size:
                cut = i0 + int(bad[0])
                if t[cut - 1] - t[i0] < min_duration_s:
                    continue
                i1, reason = cut, "magnetic"
        return StaticWindow(int(i0), int(i1), reason)
    raise ProcessingError(
        f"imu: no stationary window of at least {min_duration_s:g} s found (mean rate below "
        f"{gyro_tol_rps:g} rad/s and specific-force SD below {acc_sd_tol_mps2:g} m/s^2); the "
        "initial alignment needs the device held still at the start"
    )


def level_rad(acc_b_mps2):
    """Roll and pitch (rad) from specific force (..., 3) FRD (paper 000 Eq. 6)."""
    f = np.asarray(acc_b_mps2, dtype=float)
    pitch = np.arctan2(f[..., 0], np.hypot(f[..., 1], f[..., 2]))
    roll = np.arctan2(-f[..., 1], -f[..., 2])
    return roll, pitch


def magnetic_yaw_rad(mag_b_ut, roll_rad, pitch_rad, declination_rad=0.0):
    """Yaw from true north (rad) from the field (..., 3) FRD and the attitude's roll/pitch.

    Eq. 7: level the field, m_h = Ry(pitch) Rx(roll) m_b; Eq. 8: psi = D - azimuth(m_h)
    (the horizontal field points to magnetic north, at azimuth D from true north).
    """
    m = np.asarray(mag_b_ut, dtype=float)
    cr, sr = np.cos(roll_rad), np.sin(roll_rad)
    cp, sp = np.cos(pitch_rad), np.sin(pitch_rad)
    my = cr * m[..., 1] - sr * m[..., 2]
    mz = sr * m[..., 1] + cr * m[..., 2]
    mx = cp * m[..., 0] + sp * mz
    return declination_rad - np.arctan2(my, mx)


def coarse_alignment(t_s, gyro_b_rps, acc_b_mps2, mag_b_ut, window: StaticWindow, *,
                     declination_rad=0.0, lat_rad=0.0, acc_noise_mps2=0.01, mag_noise_ut=0.5,
                     yaw_rad=None) -> Alignment:
    """Average the window and apply Eq. 6 and Eq. 8 (yaw_rad overrides the magnetic yaw).

    Without a magnetometer and without `yaw_rad`, yaw is 0 and its SD is pi.
    """
    sl = slice(window.i0, window.i1)
    n = window.i1 - window.i0
    f = np.mean(np.asarray(acc_b_mps2, dtype=float)[sl], axis=0)
    roll, pitch = level_rad(f)
    roll, pitch = float(roll), float(pitch)
    g = float(np.linalg.norm(f))
    s_tilt = acc_noise_mps2 / g / np.sqrt(n)
    mag_norm, dip = np.nan, np.nan
    if yaw_rad is not None:
        yaw, s_yaw = float(yaw_rad), 0.0
    elif mag_b_ut is not None:
        m = np.nanmean(np.asarray(mag_b_ut, dtype=float)[sl], axis=0)
        yaw = float(magnetic_yaw_rad(m, roll, pitch, declination_rad))
        C = euler_to_dcm(roll, pitch, yaw)
        m_n = C @ m
        mag_norm = float(np.linalg.norm(m))
        h = float(np.hypot(m_n[0], m_n[1]))
        dip = float(np.arctan2(m_n[2], h))
        # yaw error: horizontal-field noise plus tilt error coupled through the dip
        s_yaw = float(np.hypot(mag_noise_ut / max(h, 1e-9) / np.sqrt(n), s_tilt * abs(np.tan(dip))))
    else:
        yaw, s_yaw = 0.0, np.pi
    C = euler_to_dcm(roll, pitch, yaw)
    w_ie_b = C.T @ earth.earth_rate_ned_rps(lat_rad)
    bias = np.mean(np.asarray(gyro_b_rps, dtype=float)[sl], axis=0) - w_ie_b
    return Alignment(window=window, roll_rad=roll, pitch_rad=pitch, yaw_rad=yaw, C_nb=C,
                     gyro_bias_rps=bias, mag_norm_ut=mag_norm, mag_dip_rad=dip,
                     sigma_rpy_rad=np.array([s_tilt, s_tilt, s_yaw]))


@dataclass(frozen=True)
class GpsHeading:
    """Heading from GPS velocity at the first fix where the vehicle moves: index into the
    fixes, its time t_s, yaw_rad (course over ground, clockwise from true north), sigma_yaw_rad."""

    index: int
    t_s: float
    yaw_rad: float
    sigma_yaw_rad: float


def gps_velocity_heading(t_s, lla, vel_ned_mps=None, *, min_speed_mps=3.0, sigma_vel_mps=0.1,
                         baseline_s=2.0) -> GpsHeading:
    """Course over ground at the first fix with horizontal speed >= `min_speed_mps`.

    Uses the logged NED velocity where present, else central differences of the positions
    over `baseline_s`.
    A land vehicle moves along its body forward axis (no side slip), so course = yaw; its SD
    is sigma_vel / speed. Raises ProcessingError when the vehicle never reaches the speed.
    """
    t = np.asarray(t_s, dtype=float)
    lla = np.asarray(lla, dtype=float)
    v = np.full((t.size, 3), np.nan) if vel_ned_mps is None else np.array(vel_ned_mps, dtype=float)
    missing = ~np.isfinite(v[:, :2]).all(axis=1)
    if missing.any() and t.size >= 3:
        # positions differenced over a baseline of about 2 s (not adjacent fixes: at 10-20 Hz the
        # position noise over 0.1 s swamps a slow vehicle's displacement)
        lat = np.radians(lla[:, 0])
        rn = earth.meridian_radius_m(lat) + lla[:, 2]
        re = (earth.transverse_radius_m(lat) + lla[:, 2]) * np.cos(lat)
        n_m = lat * rn
        e_m = np.radians(lla[:, 1]) * re
        lo = np.clip(np.searchsorted(t, t - baseline_s / 2.0), 0, t.size - 1)
        hi = np.clip(np.searchsorted(t, t + baseline_s / 2.0), 0, t.size - 1)
        dt = t[hi] - t[lo]
        vd = np.full((t.size, 2), np.nan)
        with np.errstate(invalid="ignore", divide="ignore"):
            vd[:, 0] = (n_m[hi] - n_m[lo]) / dt
            vd[:, 1] = (e_m[hi] - e_m[lo]) / dt
        # no velocity across an outage, nor from a too short baseline
        med = float(np.median(np.diff(t)))
        span_gap = np.array([np.diff(t[a:b + 1]).max(initial=0.0) if b > a else np.inf for a, b in zip(lo, hi)])
        bad = (dt < 0.5 * baseline_s) | (span_gap > max(3.0 * med, 1.5))
        vd[bad] = np.nan
        v[missing, :2] = vd[missing]
    speed = np.hypot(v[:, 0], v[:, 1])
    ok = np.flatnonzero(np.nan_to_num(speed, nan=0.0) >= min_speed_mps)
    if ok.size == 0:
        raise ProcessingError(
            f"gps: the vehicle never reaches {min_speed_mps:g} m/s, so the heading cannot be aligned from GPS velocity"
        )
    i = int(ok[0])
    return GpsHeading(i, float(t[i]), float(np.arctan2(v[i, 1], v[i, 0])), float(sigma_vel_mps / speed[i]))
