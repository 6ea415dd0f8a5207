"""IMU-GPS time offset from the log itself: GPS course rate against the gyro's vertical rate.

The heading rate seen by GPS (course of the velocity, unwrapped, central difference over
consecutive fixes) must equal the mean of the body rotation rate about the vertical over the same
interval. With the IMU vertical rate r(t) = ω_b · d_b (d_b: down direction from the low-passed
specific force), the central difference of course at fix k compares to
(R(t_{k+1} + δ) - R(t_{k-1} + δ)) / (t_{k+1} - t_{k-1}), R = ∫ r dt. The offset δ is found by a
grid search plus parabolic refinement of the least-squares misfit (with a fitted gain, which also
exposes a flipped or mis-scaled gyro), and its SD from the Gauss-Newton curvature
σ_δ² = s² / Σ (∂m/∂δ)², s² the residual variance (Bard 1974, Nonlinear Parameter Estimation).
δ is what to ADD to `[time] gps_offset_s`: GPS times plus δ land on the IMU clock.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli.errors import ProcessingError


@dataclass(frozen=True)
class TimeOffset:
    offset_s: float  # add to the GPS times (i.e. to `[time] gps_offset_s`)
    sigma_s: float
    gain: float  # fitted IMU-to-GPS rate ratio; 1 for a consistent log
    n_used: int  # GPS course-rate samples used
    rms_resid_rps: float


def _lowpass(x: np.ndarray, n: int) -> np.ndarray:
    c = np.cumsum(np.concatenate([np.zeros((1,) + x.shape[1:]), x]), axis=0)
    i = np.arange(x.shape[0])
    lo = np.clip(i - n // 2, 0, x.shape[0])
    hi = np.clip(i - n // 2 + n, 0, x.shape[0])
    return (c[hi] - c[lo]) / (hi - lo).reshape((-1,) + (1,) * (x.ndim - 1))


def vertical_rate_rps(t_s, gyro_b_rps, acc_b_mps2, smooth_s: float = 1.0) -> np.ndarray:
    """Rotation rate about the local down axis (≈ yaw rate), from gyro and low-passed gravity."""
    t = np.asarray(t_s, float)
    dt = float(np.median(np.diff(t)))
    f = _lowpass(np.asarray(acc_b_mps2, float), max(1, int(round(smooth_s / dt))))
    d_b = -f / np.linalg.norm(f, axis=1, keepdims=True)  # specific force points up at rest
    return np.einsum("ij,ij->i", np.asarray(gyro_b_rps, float), d_b)


def gps_course_rate(t_gps_s, vel_ned_mps, min_speed_mps: float):
    """(time, course rate rad/s, half-interval start, end) by central differences over fixes fast enough."""
    v = np.asarray(vel_ned_mps, float)
    t = np.asarray(t_gps_s, float)
    speed = np.hypot(v[:, 0], v[:, 1])
    course = np.unwrap(np.arctan2(v[:, 1], v[:, 0]))
    ok = (speed[:-2] > min_speed_mps) & (speed[1:-1] > min_speed_mps) & (speed[2:] > min_speed_mps)
    ok &= np.isfinite(course[:-2]) & np.isfinite(course[2:]) & (t[2:] - t[:-2] < 5.0)
    rate = (course[2:] - course[:-2]) / (t[2:] - t[:-2])
    return t[1:-1][ok], rate[ok], t[:-2][ok], t[2:][ok]


def gps_velocity(t_gps_s, lla, vel_ned_mps=None) -> np.ndarray:
    """GPS velocity NED: the logged one where present, else central differences of positions."""
    from tpos_cli.frames.geodetic import lla_to_ned

    if vel_ned_mps is not None and np.isfinite(vel_ned_mps[:, :2]).all():
        return np.asarray(vel_ned_mps, float)
    ned = lla_to_ned(lla, lla[0])
    return np.gradient(ned, np.asarray(t_gps_s, float), axis=0)


def estimate_gps_time_offset(t_imu_s, gyro_b_rps, acc_b_mps2, t_gps_s, vel_ned_mps, *,
                             max_offset_s: float = 1.0, min_speed_mps: float = 2.0,
                             min_samples: int = 20) -> TimeOffset:
    """Offset δ (s) to add to GPS times so the GPS course rate lines up with the gyro.

    Needs turns while moving faster than `min_speed_mps`; raises ProcessingError otherwise.
    """
    t = np.asarray(t_imu_s, float)
    r = vertical_rate_rps(t, gyro_b_rps, acc_b_mps2)
    # a sample holds the mean rate over (t_{k-1}, t_k] (architecture.md), so the rectangle sum is
    # the exact integral at the sample times; a trapezoid would shift it by half a sample
    R = np.concatenate([[0.0], np.cumsum(r[1:] * np.diff(t))])
    tk, rate, ta, tb = gps_course_rate(t_gps_s, vel_ned_mps, min_speed_mps)
    inside = (ta - max_offset_s > t[0]) & (tb + max_offset_s < t[-1])
    tk, rate, ta, tb = tk[inside], rate[inside], ta[inside], tb[inside]
    if rate.size < min_samples or np.std(rate) < 0.01:
        raise ProcessingError(
            f"time offset: only {rate.size} GPS course-rate samples above {min_speed_mps:g} m/s "
            f"(turn-rate SD {np.std(rate) if rate.size else 0:.3f} rad/s); the log needs turns while moving"
        )

    def model(delta):
        return (np.interp(tb + delta, t, R) - np.interp(ta + delta, t, R)) / (tb - ta)

    def misfit(delta):
        m = model(delta)
        gain = float(m @ rate / (m @ m)) if m @ m > 0 else 0.0
        res = rate - gain * m
        return float(res @ res), gain

    dt_imu = float(np.median(np.diff(t)))
    step = max(dt_imu, 0.002)
    grid = np.arange(-max_offset_s, max_offset_s + step / 2, step)
    sse = np.array([misfit(d)[0] for d in grid])
    i = int(np.argmin(sse))
    if 0 < i < grid.size - 1:  # parabola through the three best grid points
        denom = sse[i - 1] - 2 * sse[i] + sse[i + 1]
        best = grid[i] + (0.5 * step * (sse[i - 1] - sse[i + 1]) / denom if denom > 0 else 0.0)
    else:
        best = grid[i]
    sse_b, gain = misfit(best)
    h = 1e-3
    J = gain * (model(best + h) - model(best - h)) / (2 * h)
    s2 = sse_b / max(rate.size - 2, 1)
    sigma = float(np.sqrt(s2 / (J @ J))) if J @ J > 0 else float("inf")
    return TimeOffset(float(best), sigma, gain, int(rate.size), float(np.sqrt(sse_b / rate.size)))


def estimate_session_offset(session, **kw) -> TimeOffset:
    """`estimate_gps_time_offset` on a loaded Session (GPS times already include `[time]` offsets)."""
    g = session.gps
    if g is None:
        raise ProcessingError("time offset: the session has no GPS")
    ok = g.valid
    vel = gps_velocity(g.t_s[ok], g.lla[ok], g.vel_ned_mps[ok])
    return estimate_gps_time_offset(session.imu.t_s, session.imu.gyro_b_rps, session.imu.acc_b_mps2, g.t_s[ok], vel, **kw)
