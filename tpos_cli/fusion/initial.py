"""Initial state of the INS/GPS filter for a land vehicle (paper 003 Sec. 5: a car).

Levelling over the static start (`alignment.detect_static_window`, `alignment.level_rad`),
heading from GPS velocity once moving (`alignment.gps_velocity_heading`) carried back to the
first sample through the gyros, or the magnetometer when GPS never shows motion.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from tpos_cli import alignment
from tpos_cli.errors import ProcessingError
from tpos_cli.filters.gating import chi2_threshold
from tpos_cli.frames import earth
from tpos_cli.frames.rotation import dcm_to_euler, euler_to_dcm, wrap_angle_rad
from tpos_cli.fusion.engine import ENDS_ONLY, FilterConfig, InitialState
from tpos_cli.fusion.insgps import GpsFixes, run_insgps
from tpos_cli.ins.mechanization import decimate_to_rate, integrate


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
        vel_sigma = sig.vel_mps
    f_b = np.mean(acc_b_mps2[sl], axis=0)
    level_sigma = sig.level_rad
    if not static:
        # a moving vehicle's specific force holds its acceleration (2 m/s^2 is 11 deg of false
        # tilt): remove the longitudinal acceleration (GPS speed slope) and the centripetal one
        # (speed x yaw rate) along the body axes of a car (no side slip), and widen the SD
        a_b = _start_acceleration_b(t[sl], gyro_b_rps[sl], fixes)
        f_b = f_b - a_b
        level_sigma = max(level_sigma, np.radians(3.0))
        info["levelling"] = (f"moving start: specific force of the first second less the GPS acceleration "
                             f"({a_b[0]:.2f}, {a_b[1]:.2f}) m/s^2 along body x, y")
    roll, pitch = alignment.level_rad(f_b)
    roll, pitch = float(roll), float(pitch)
    lat0 = np.radians(fixes.lla[0, 0])
    yaw_sigma = sig.yaw_rad
    hd = _gps_heading(fixes, min_speed_mps)
    if hd is not None:
        i_h = int(np.clip(np.searchsorted(t, hd.t_s), 1, t.size - 1))
        # attitude from t0 to the heading epoch with yaw 0: C(t_h) = Rz(yaw0) C_mech(t_h) exactly
        # when the nav-frame rotation over that span is negligible (15 deg/h Earth rate)
        tr = integrate(t[: i_h + 1], gyro_b_rps[: i_h + 1], acc_b_mps2[: i_h + 1], fixes.lla[0], [0.0, 0.0, 0.0],
                       np.degrees([roll, pitch, 0.0]))
        _, _, yaw_mech = dcm_to_euler(tr.C_nb[-1])
        yaw = float(wrap_angle_rad(hd.yaw_rad - yaw_mech))
        yaw_sigma = max(yaw_sigma, hd.sigma_yaw_rad)
        info["heading"] = f"gps velocity at t_s = {hd.t_s:.1f} s ({hd.how})"
    elif mag_b_ut is not None:
        m = np.nanmean(mag_b_ut[sl], axis=0)
        yaw = float(alignment.magnetic_yaw_rad(m, roll, pitch, declination_rad))
        yaw_sigma = max(yaw_sigma, np.radians(5.0))
        info["heading"] = "magnetometer (GPS never shows motion)"
    else:
        # no course and no magnetometer: yaw unknown; `search_yaw` (the chain runs it) decides
        yaw, yaw_sigma = 0.0, np.pi
        info["heading"] = "unknown (GPS never shows motion, no magnetometer)"
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
    s = InitialSigmas(max(sig.pos_m, 1.0 + abs(dt0) * (0.0 if static else 2.0)), vel_sigma, level_sigma, yaw_sigma,
                      sig.acc_bias_mps2, sig.gyro_bias_rps)
    info["static_start"] = bool(static)
    return InitialState(nav, C, bias, initial_covariance(s)), info


def _start_acceleration_b(t_s, gyro_b_rps, fixes: GpsFixes) -> np.ndarray:
    """Mean acceleration (3,) along FRD body x, y over the samples `t_s` of a moving car: speed
    slope from the fixes within 1 s of that span (logged velocity, else positions), speed x
    mean yaw rate sideways. Zero when fewer than two fixes are near."""
    m = (fixes.t_s >= t_s[0] - 1.0) & (fixes.t_s <= t_s[-1] + 1.0)
    tf = fixes.t_s[m]
    if tf.size < 2:
        return np.zeros(3)
    v = fixes.vel_ned_mps[m]
    if np.isfinite(v[:, :2]).all():
        speed = np.hypot(v[:, 0], v[:, 1])
    else:
        lat = np.radians(fixes.lla[m, 0])
        n_m = lat * earth.meridian_radius_m(lat)
        e_m = np.radians(fixes.lla[m, 1]) * earth.transverse_radius_m(lat) * np.cos(lat)
        if tf.size < 3:
            return np.zeros(3)
        speed = np.hypot(np.gradient(n_m, tf), np.gradient(e_m, tf))
    a_long = float(np.polyfit(tf - tf[0], speed, 1)[0])
    a_lat = float(np.mean(speed) * np.mean(gyro_b_rps[:, 2]))  # right turn (w_z > 0): centripetal to the right
    return np.array([a_long, a_lat, 0.0])


@dataclass(frozen=True)
class _Heading:
    t_s: float
    yaw_rad: float
    sigma_yaw_rad: float
    how: str


def _gps_heading(fixes: GpsFixes, min_speed_mps: float) -> _Heading | None:
    """Course over ground once moving, or None when GPS never shows motion.

    With logged velocity: the first fix at `min_speed_mps`, or, for a slow platform (a rover, a
    pedestrian) that never reaches a car's threshold, at half the speed the log reaches (95th
    percentile, at least 0.3 m/s); SD from the velocity SD over the speed. Without logged
    velocity: positions differenced over 10 s (single 1-2 s differences of correlated metre-level
    fixes invent speeds a slow platform never had), same thresholds, SD from a 1 m position
    error over the baseline. `search_yaw` then checks the course against other yaws.
    """
    t = fixes.t_s
    v = fixes.vel_ned_mps
    baseline_s = 10.0
    if np.isfinite(v[:, :2]).any():
        speed = np.hypot(v[:, 0], v[:, 1])
        vel, how = v, "logged velocity"
    else:
        if t.size < 3 or t[-1] - t[0] < 2 * baseline_s:
            return None
        lat = np.radians(fixes.lla[:, 0])
        n_m = lat * (earth.meridian_radius_m(lat) + fixes.lla[:, 2])
        e_m = np.radians(fixes.lla[:, 1]) * (earth.transverse_radius_m(lat) + fixes.lla[:, 2]) * np.cos(lat)
        j = np.searchsorted(t, t + baseline_s)
        i = np.flatnonzero(j < t.size)
        j = j[i]
        speed = np.hypot(n_m[j] - n_m[i], e_m[j] - e_m[i]) / (t[j] - t[i])
        vel, how = None, f"positions over {baseline_s:g} s"
    if not np.isfinite(speed).any():
        return None
    thr = min(min_speed_mps, max(0.3, 0.5 * float(np.nanpercentile(speed, 95))))
    try:
        if vel is not None:
            hd = alignment.gps_velocity_heading(t, fixes.lla, vel, min_speed_mps=thr)
            sigma = hd.sigma_yaw_rad
        else:
            hd = alignment.gps_velocity_heading(t, fixes.lla, None, min_speed_mps=thr, baseline_s=baseline_s)
            sigma = float(np.clip(1.0 / (thr * baseline_s), np.radians(2.0), np.radians(30.0)))
    except ProcessingError:
        return None
    return _Heading(hd.t_s, hd.yaw_rad, sigma, f"{how} at {thr:.2f} m/s")


@dataclass(frozen=True)
class YawSearch:
    """Outcome of `search_yaw`: chosen initial yaw and SD (rad), every hypothesis and its score."""

    yaw_rad: float
    sigma_yaw_rad: float
    hypotheses_rad: np.ndarray
    scores: np.ndarray
    window_s: tuple[float, float]
    chose_prior: bool


def search_yaw(t_s, gyro_b_rps, acc_b_mps2, fixes: GpsFixes, init: InitialState, cfg: FilterConfig, *,
               n_hypotheses: int = 12, motion_s: float = 30.0, moved_m: float = 5.0,
               min_likelihood_ratio: float = 100.0, rate_hz: float = 25.0) -> YawSearch:
    """Coarse-to-fine initial yaw: the filter run from `n_hypotheses` yaws over the start of the log.

    A linearized error-state filter converges only from a yaw error of some 15-20 deg; a course
    from GPS at walking speed or a magnetometer near a car can be off by far more. So the forward
    filter is run, gated as `cfg`, over the log until `motion_s` after the platform has first moved
    `moved_m` from its first fix, from yaws spaced 360/n deg apart (SD half the spacing) plus
    the prior yaw of `init` (its own SD); the hypothesis whose GPS innovations have the smallest
    summed NIS, each capped at the gate (`robust_nis_score`; rejected rows included), wins (a
    wrong yaw makes the INS velocity point the wrong way as soon as the platform accelerates, so
    its innovations grow). Returns the winner's yaw and SD.
    The runs take the IMU decimated to about `rate_hz` (`ins.mechanization.decimate_to_rate`) and 1 s
    covariance steps, as the other tuning passes: a score only ranks yaws tens of degrees apart.
    """
    t = np.asarray(t_s, dtype=float)
    lat = np.radians(fixes.lla[:, 0])
    dn = (lat - lat[0]) * earth.meridian_radius_m(lat[0])
    de = np.radians(fixes.lla[:, 1] - fixes.lla[0, 1]) * earth.transverse_radius_m(lat[0]) * np.cos(lat[0])
    far = np.flatnonzero(np.hypot(dn, de) > moved_m)
    t_move = fixes.t_s[far[0]] if far.size else fixes.t_s[-1]
    i_end = int(min(t.size, np.searchsorted(t, t_move + motion_s) + 1))
    _, _, yaw0 = dcm_to_euler(init.C_nb)
    yaw0 = float(yaw0)
    sig0 = float(np.sqrt(init.P0[8, 8]))
    spacing = 2.0 * np.pi / n_hypotheses
    # the prior (k = 0, its own SD, at most half the spacing) and the grid around it
    hyps = np.asarray(wrap_angle_rad(yaw0 + spacing * np.arange(n_hypotheses)))
    sigmas = np.full(hyps.size, spacing / 2.0)
    sigmas[0] = min(sig0, spacing / 2.0)
    # gated as `cfg` (a row beyond the gate leaves the state alone: RTK float fixes decimetres off under a
    # centimetre SD at a standstill no longer pull each run's state, which then decided the score) and
    # scored with each NIS capped at the gate (`robust_nis_score`): a rejected row still counts, at the
    # gate's edge, so a wrong yaw whose rows the gate rejects pays for each; no nominal history kept
    td, gd, ad, rate_d = decimate_to_rate(t[:i_end], gyro_b_rps[:i_end], acc_b_mps2[:i_end], rate_hz)
    scfg = dataclasses.replace(cfg, nominal_idx=ENDS_ONLY,
                               cov_step=max(1, int(round(rate_d))))
    sub = fixes_before(fixes, t[i_end - 1])
    scores = np.full(hyps.size, np.inf)
    for h, (yaw, sy) in enumerate(zip(hyps, sigmas)):
        try:
            run = run_insgps(td, gd, ad, sub, with_yaw(init, yaw, sy), scfg, store_rts=False)
        except ProcessingError:
            continue  # diverged: not this one
        scores[h] = robust_nis_score(run.ev_nis, run.measurements.dim, cfg.gate_probability)
    best = int(np.argmin(scores))
    # the score is -2 log-likelihood up to terms alike for every hypothesis: the prior yields
    # only to a yaw at least `min_likelihood_ratio` times more likely (weak yaw observability,
    # e.g. a slow rover, gives near-equal scores: then the course is the better information)
    if np.isfinite(scores[0]) and scores[0] - scores[best] < 2.0 * np.log(min_likelihood_ratio):
        best = 0
    return YawSearch(float(hyps[best]), float(sigmas[best]), hyps, scores, (float(t[0]), float(t[i_end - 1])), best == 0)


def robust_nis_score(nis, dim, gate_probability: float) -> float:
    """Sum over the events of each NIS capped at the gate's chi-square threshold for its dimension.

    The truncated quadratic (the loss of a redescending M-estimator: -2 log of a Gaussian with a
    flat outlier floor; `gps_error.innovation_loglik` caps its rows alike) counts a row the gate
    rejects as the gate's edge, however far off. Uncapped, a few fixes far outside
    their stated SD (RTK float fixes 10-25 cm off under a 1 cm SD at a standstill: NIS in the
    hundreds) outweigh the hundreds of rows that tell a wrong yaw from the course.
    `nis` (E,) with NaN where not processed, `dim` (E,) the rows' dimensions."""
    nis = np.asarray(nis, dtype=float)
    dim = np.asarray(dim, dtype=np.int64)
    ok = np.isfinite(nis) & (dim > 0)
    gate = chi2_threshold(gate_probability, int(dim.max(initial=1)))
    return float(np.sum(np.minimum(nis[ok], gate[dim[ok]])))


def fixes_before(fixes: GpsFixes, t_end_s: float) -> GpsFixes:
    """The fixes at or before `t_end_s`."""
    m = fixes.t_s <= t_end_s
    return GpsFixes(fixes.t_s[m], fixes.lla[m], fixes.vel_ned_mps[m], fixes.sigma_pos_ned_m[m], fixes.sigma_vel_mps[m],
                    fixes.from_receiver, fixes.vel_latency_s)


def with_yaw(init: InitialState, yaw_rad: float, sigma_yaw_rad: float) -> InitialState:
    """`init` turned about the vertical to `yaw_rad`, yaw SD `sigma_yaw_rad`."""
    _, _, yaw0 = dcm_to_euler(init.C_nb)
    C = euler_to_dcm(0.0, 0.0, yaw_rad - float(yaw0)) @ init.C_nb
    bias = init.bias.copy()
    if np.any(bias[3:] != 0.0):  # a gyro bias from the static start had Earth rate removed at yaw0
        w_ie = earth.earth_rate_ned_rps(float(init.nav[0]))
        bias[3:] += init.C_nb.T @ w_ie - C.T @ w_ie
    P0 = init.P0.copy()
    P0[8, 8] = sigma_yaw_rad**2
    return InitialState(init.nav.copy(), C, bias, P0)
