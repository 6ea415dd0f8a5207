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
from tpos_cli.frames.rotation import euler_to_dcm, rotvec_to_dcm
from tpos_cli.timebase import true_runs


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
    starts, ends = true_runs(still)  # runs of consecutive still samples
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


#: 95 % quantile of chi-square with 2 dof (-2 ln 0.05): the still-window test of `held_at`
CHI2_2DOF_95 = 5.991464547107979


def _turned_to(t_s, gyro_b_rps, window: StaticWindow, ref: int, bias_rps) -> np.ndarray:
    """(n, 3, 3) R(ref <- k) for the window's samples k: the body frame at k turned into the body frame at `ref`
    by the gyro less `bias_rps` (the product of exp((omega - bias) dt); row k's rate covers (t_{k-1}, t_k])."""
    t = np.asarray(t_s, dtype=float)
    i0, i1 = window.i0, window.i1
    w = np.asarray(gyro_b_rps, dtype=float)[i0:i1] - np.asarray(bias_rps, dtype=float)
    inc = rotvec_to_dcm(w[1:] * np.diff(t[i0:i1])[:, None])  # inc[k-1] = R(k-1 <- k)
    R = np.empty((i1 - i0, 3, 3))
    j = ref - i0
    R[j] = np.eye(3)
    for k in range(j + 1, i1 - i0):
        R[k] = R[k - 1] @ inc[k - 1]
    for k in range(j - 1, -1, -1):
        R[k] = R[k + 1] @ inc[k].T
    return R


def held_at(t_s, gyro_b_rps, vectors, window: StaticWindow, ref: int, gyro_noise_rps: float, acc_noise_mps2: float,
            acc_bias_rw_mps2_rts: float = 0.0):
    """Body-frame vectors of a hand-held "still" window as they were at sample `ref`, and the variance (rad^2
    per axis) that turning them by the gyro adds.

    A hand never holds a device quite still: a sway of a few tenths of a degree makes the window's mean
    specific force the gravity at the window's MEAN attitude, not at `ref` (a sim with a 0.5 deg, 7 s roll
    sway: levelling 0.11-0.39 deg off at the window's edge against a stated 0.002 deg). Each sample is turned
    into the body frame at `ref` by the gyro, v_ref(k) = R(ref <- k) v(k), and averaged. The window-mean rate,
    the usual bias estimate, also holds the sway's net turn over the window (bias error e): the turned vectors
    then rotate as v0 + (v0 x e)(t - t_ref) (first order), so a line fitted to the turned specific force
    (vectors[0]) gives its slope s = f0 x e, and the part of e that tilts, e_perp = -(f0 x s) / |f0|^2, is
    removed before the vectors are turned again (their mean is then the line's value at ref).
    On a device that does not sway (a table) the turned mean differs from the plain one by noise only, of
    variance v per tilt axis: the gyro's white noise (`gyro_noise_rps` per sample, dt apart) turns as a
    random walk from ref, whose line value at ref over T has variance (2/15) sigma_g^2 dt T (the integral of
    ((1 - u)(1 - 3u))^2 over [0, 1]), and the specific force's white noise (`acc_noise_mps2`) enters the
    line's value at ref with 4/n against the mean's 1/n: 3 (sigma_a / g)^2 / n; the accelerometer bias's
    drift (random walk q = `acc_bias_rw_mps2_rts`, the filters' model of it) tilts the turned specific force
    like a gyro bias error, the fitted slope s T/2 taking (3/10) (q / g)^2 T. So the turned vectors (and
    the corrected bias) are taken only where the turn's tilt d (2 dof, the turned mean against the plain one)
    is more than that noise explains at 95 %, |d|^2 > chi2_2(0.95) v = 5.99 v (k = 1), else the plain means
    and the window-mean rate (k = 0); k v is the variance per axis the turn adds. (Chosen after the smooth
    empirical-Bayes share k = max(0, 1 - 2 v / |d|^2) was measured: it also turns a third of truly still
    windows a little, target_nees mems fkf .2056 -> .2080 m; notes marg12.md.)
    Returns ((k, 3) vectors for the (N, 3) `vectors`, NaN samples left out per series; k v rad^2; the gyro
    bias (3,) rad/s, Earth rate included)."""
    t = np.asarray(t_s, dtype=float)
    i0, i1 = window.i0, window.i1
    bias = np.mean(np.asarray(gyro_b_rps, dtype=float)[i0:i1], axis=0)
    f = np.einsum("kij,kj->ki", _turned_to(t, gyro_b_rps, window, ref, bias), np.asarray(vectors[0], dtype=float)[i0:i1])
    X = np.stack([np.ones(i1 - i0), t[i0:i1] - t[ref]], axis=1)
    f0, s = np.linalg.lstsq(X, f, rcond=None)[0]
    e_perp = -np.cross(f0, s) / float(f0 @ f0)
    R = _turned_to(t, gyro_b_rps, window, ref, bias - e_perp)
    turned = np.stack([np.nanmean(np.einsum("kij,kj->ki", R, np.asarray(v, dtype=float)[i0:i1]), axis=0)
                       for v in vectors])
    plain = np.stack([np.nanmean(np.asarray(v, dtype=float)[i0:i1], axis=0) for v in vectors])
    dt = float(np.median(np.diff(t[i0:i1]))) if i1 - i0 > 1 else 0.0
    T, g2 = float(t[i1 - 1] - t[i0]), float(plain[0] @ plain[0])
    v = (2.0 / 15.0 * float(gyro_noise_rps) ** 2 * dt * T + 3.0 * float(acc_noise_mps2) ** 2 / g2 / (i1 - i0)
         + 0.3 * float(acc_bias_rw_mps2_rts) ** 2 / g2 * T)
    c = np.cross(plain[0], turned[0])
    d2 = float(c @ c) / g2 / float(turned[0] @ turned[0])
    k = 1.0 if d2 > CHI2_2DOF_95 * v else 0.0
    return plain + k * (turned - plain), k * v, bias - k * e_perp


def coarse_alignment(t_s, gyro_b_rps, acc_b_mps2, mag_b_ut, window: StaticWindow, *,
                     declination_rad=0.0, lat_rad=0.0, acc_noise_mps2=0.01, mag_noise_ut=0.5,
                     yaw_rad=None, ref: int | None = None, gyro_noise_rps: float = 0.0,
                     acc_bias_rw_mps2_rts: float = 0.0) -> Alignment:
    """Average the window and apply Eq. 6 and Eq. 8 (yaw_rad overrides the magnetic yaw); with `ref`, the
    attitude at that sample of the window from the gyro-referenced specific force and field (`held_at`, with
    the gyro's white noise `gyro_noise_rps` per sample and the accelerometer bias's random walk
    `acc_bias_rw_mps2_rts`) instead of the window's mean attitude, and the gyro
    bias `held_at` turned them with. The sigmas stay the mean's: the turn's own variance (`held_at`'s k v)
    is not added. Measured with an earlier, smooth share of the turn, 0.003-0.011 deg of it added to BROAD's
    alignments made the filters worse through their tilt prior (tpos/VQF 02 .552 -> .575, 26 .718 -> .741;
    notes marg12.md); on the sims that turn (stated gyro noise) it is below 0.001 deg. Said, not hidden.

    Without a magnetometer and without `yaw_rad`, yaw is 0 and its SD is pi.
    """
    sl = slice(window.i0, window.i1)
    n = window.i1 - window.i0
    if ref is not None:
        vecs = [acc_b_mps2] + ([mag_b_ut] if (yaw_rad is None and mag_b_ut is not None) else [])
        held, _, bias_m = held_at(t_s, gyro_b_rps, vecs, window, ref, gyro_noise_rps, acc_noise_mps2,
                                  acc_bias_rw_mps2_rts)
        f = held[0]
    else:
        f = np.mean(np.asarray(acc_b_mps2, dtype=float)[sl], axis=0)
        bias_m = np.mean(np.asarray(gyro_b_rps, dtype=float)[sl], axis=0)
    roll, pitch = level_rad(f)
    roll, pitch = float(roll), float(pitch)
    g = float(np.linalg.norm(f))
    s_tilt = acc_noise_mps2 / g / np.sqrt(n)
    mag_norm, dip = np.nan, np.nan
    if yaw_rad is not None:
        yaw, s_yaw = float(yaw_rad), 0.0
    elif mag_b_ut is not None:
        m = held[1] if ref is not None else np.nanmean(np.asarray(mag_b_ut, dtype=float)[sl], axis=0)
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
    bias = bias_m - w_ie_b
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
