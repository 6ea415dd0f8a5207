"""IMU-GPS time offset from the log itself: GPS velocity changes against the integrated IMU.

Two observables compare a change of the GPS velocity over a window [t_a, t_b] (fix times on the
GPS clock) with the IMU integral over the same window shifted by δ onto the IMU clock:
- course:  s̄ Δψ  = k_ψ s̄ ∫ r dt          (r: rotation rate about the local down axis, s̄ the mean
  speed; weighting by s̄ makes the course noise σ_v/s homogeneous, and s̄ ψ̇ is the lateral acceleration);
- along-track: Δs = k_x ∫ f_x dt + k_y ∫ f_y dt  (forward/right specific force; the gains absorb a
  yaw misalignment of the mounting).
Both sides are high-passed alike (a centred moving mean over `highpass_s` removed), which removes
gyro and accelerometer biases and the slowly varying g·sin(pitch) of road grades (f_x = a_x + g sin θ,
Groves Eq. 2.138-like kinematics). The offset minimises Σ_c SSE_c(δ)/σ_c² (each channel's gains
solved by least squares at each δ, σ_c² its residual variance at the best δ), with Huber weights
(IRLS) against outliers such as GPS jumps. Its SD is a delete-one-block jackknife over time blocks
(Efron & Stein 1981; blocks of many seconds, so the overlap of windows and slow misfits are honest).
δ is what to ADD to `[time] gps_offset_s`: GPS times plus δ land on the IMU clock.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli.errors import ProcessingError

HUBER_K = 1.345  # 95 % efficiency on Gaussian residuals (Huber 1981)
MIN_R2 = 0.3  # a channel explaining less of its own variance carries no timing information
GAIN_RANGE = (0.5, 2.0)  # |gain| of a channel that measures what it should (1 for a consistent log)


@dataclass(frozen=True)
class TimeOffset:
    offset_s: float  # add to the GPS times (i.e. to `[time] gps_offset_s`)
    sigma_s: float  # jackknife SD (inf when it could not be formed)
    gain: float  # course channel: IMU-to-GPS rate ratio, 1 for a consistent log (NaN if unused)
    n_used: int  # GPS windows used over all channels
    rms_resid_rps: float  # course channel RMS residual as a rate (NaN if unused)
    gain_along: float = float("nan")  # along-track channel: forward specific-force gain (NaN if unused)
    channels: tuple[str, ...] = ()  # "course", "along" that carried the estimate
    r2: tuple[float, ...] = ()  # share of each tried channel's variance explained at its best offset


@dataclass(frozen=True)
class NoOffset:
    """Why a set of channels gives no offset (`estimate_gps_time_offsets`): the one-line reason a
    ProcessingError carries when a single set is asked for (`estimate_gps_time_offset`)."""

    reason: str


def _lowpass(x: np.ndarray, n: int, step: int = 1) -> np.ndarray:
    """Centred moving mean of x (N, ...) along axis 0 over n samples (fewer at the ends), from
    cumulative sums c: row i is (c[hi] - c[lo]) / (hi - lo) with lo = max(i - n // 2, 0) and
    hi = min(i - n // 2 + n, N). With `step`, only rows 0, step, 2 step, ... (the same values as
    `_lowpass(x, n)[::step]`, without the rows between). The rows whose window lies inside are
    slices of c, only the ends gather."""
    N = x.shape[0]
    c = np.empty((N + 1,) + x.shape[1:])
    c[0] = 0.0
    np.cumsum(x, axis=0, dtype=float, out=c[1:])  # (the sums of [0, x]: no concatenated copy of x)

    def means(i):  # the window means at rows i, gathered
        lo = np.clip(i - n // 2, 0, N)
        hi = np.clip(i - n // 2 + n, 0, N)
        return (c[hi] - c[lo]) / (hi - lo).reshape((-1,) + (1,) * (x.ndim - 1))

    if step > 1:
        return means(np.arange(0, N, step))
    out = np.empty(c.shape)[:N]
    a, b = n // 2, N - n + n // 2 + 1  # rows a..b-1: the whole window inside
    if b > a:
        np.subtract(c[n:], c[: N - n + 1], out=out[a:b])
        out[a:b] /= n
    i = np.concatenate([np.arange(min(a, N)), np.arange(max(a, b), N)])
    out[i] = means(i)
    return out


def vertical_rate_rps(t_s, gyro_b_rps, acc_b_mps2, smooth_s: float = 1.0) -> np.ndarray:
    """Rotation rate about the local down axis (≈ yaw rate), from gyro and low-passed gravity."""
    t = np.asarray(t_s, float)
    dt = float(np.median(np.diff(t)))
    f = _lowpass(np.asarray(acc_b_mps2, float), max(1, int(round(smooth_s / dt))))
    # the down direction (specific force points up at rest), in place; |f| as np.linalg.norm(f, axis=1) sums
    # the squares (in order: the same numbers), without its slow reduction along a row of three (4 ms per hour)
    norm = f[:, 0] * f[:, 0]
    norm += f[:, 1] * f[:, 1]
    norm += f[:, 2] * f[:, 2]
    f /= -np.sqrt(norm)[:, None]
    return np.einsum("ij,ij->i", np.asarray(gyro_b_rps, float), f)


def gps_velocity(t_gps_s, lla, vel_ned_mps=None, half_window_s: float = 0.5) -> np.ndarray:
    """GPS velocity NED: the logged one where present, else central differences of positions
    over ±`half_window_s` (a 20 Hz position log differenced sample to sample is mostly noise)."""
    from tpos_cli.frames.geodetic import lla_to_ned

    if vel_ned_mps is not None and np.isfinite(vel_ned_mps[:, :2]).all():
        return np.asarray(vel_ned_mps, float)
    t = np.asarray(t_gps_s, float)
    ned = lla_to_ned(lla, lla[0])
    h = max(half_window_s, float(np.median(np.diff(t)))) if t.size > 1 else half_window_s
    return np.stack([(np.interp(t + h, t, ned[:, j]) - np.interp(t - h, t, ned[:, j])) / (2 * h) for j in range(3)], axis=1)


def _masked_mean(x: np.ndarray, w: np.ndarray, n: int) -> np.ndarray:
    """Centred moving mean of x over n samples counting only where w > 0 (x (N,) or (N, p))."""
    ww = w.reshape((-1,) + (1,) * (x.ndim - 1))
    num = _lowpass(x * ww, n)
    den = _lowpass(np.broadcast_to(ww, x.shape).astype(float), n)
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)


@dataclass(frozen=True)
class _Windows:
    """GPS windows [t_a, t_b] on a uniform grid and the GPS-side changes over them."""

    ta: np.ndarray
    tb: np.ndarray
    s_mean: np.ndarray
    d_course: np.ndarray
    d_speed: np.ndarray
    ok: np.ndarray
    dt_s: float  # grid step


def _gps_windows(t_gps, vel, window_s, min_speed_mps) -> _Windows:
    t_gps = np.asarray(t_gps, float)
    dtg = max(float(np.median(np.diff(t_gps))), 0.02)
    grid = np.arange(t_gps[0], t_gps[-1] + dtg / 2, dtg)
    # a grid point is usable only between fixes less than 2.5 intervals apart (no interpolation over gaps)
    j = np.clip(np.searchsorted(t_gps, grid), 1, t_gps.size - 1)
    near = (t_gps[j] - t_gps[j - 1]) < 2.5 * dtg
    vn, ve = (np.interp(grid, t_gps, vel[:, k]) for k in (0, 1))
    speed = np.hypot(vn, ve)
    course = np.unwrap(np.arctan2(ve, vn))
    m = max(1, int(round(window_s / dtg)))
    fast = near & (speed > min_speed_mps)
    # every grid point inside the window must be usable: count the unusable ones by cumulative sum
    c = np.concatenate([[0], np.cumsum(~fast)])
    ok = (c[m + 1 :] - c[: -m - 1]) == 0
    return _Windows(grid[:-m], grid[m:], 0.5 * (speed[:-m] + speed[m:]), course[m:] - course[:-m], speed[m:] - speed[:-m], ok, dtg)


def estimate_gps_time_offset(t_imu_s, gyro_b_rps, acc_b_mps2, t_gps_s, vel_ned_mps, *,
                             channels: tuple[str, ...] = ("course", "along"), **kw) -> TimeOffset:
    """Offset δ (s) to add to GPS times so GPS velocity changes line up with the IMU, from `channels`
    (`estimate_gps_time_offsets`, whose keywords it takes).

    Needs turns or speed changes while moving faster than `min_speed_mps`; raises ProcessingError otherwise.
    """
    (res,) = estimate_gps_time_offsets(t_imu_s, gyro_b_rps, acc_b_mps2, t_gps_s, vel_ned_mps, channel_sets=(channels,), **kw)
    if isinstance(res, NoOffset):
        raise ProcessingError(res.reason)
    return res


def estimate_gps_time_offsets(t_imu_s, gyro_b_rps, acc_b_mps2, t_gps_s, vel_ned_mps, *,
                              channel_sets: tuple[tuple[str, ...], ...],
                              max_offset_s: float = 1.0, min_speed_mps: float = 0.5,
                              window_s: float = 0.5, highpass_s: float = 30.0,
                              min_samples: int = 20, n_blocks: int = 10) -> list[TimeOffset | NoOffset]:
    """`estimate_gps_time_offset` from each set of channels in `channel_sets`, on one set of windows
    and integrals (the regressors at each offset tried are formed once for all sets): per set its
    TimeOffset, or a NoOffset saying why it cannot tell. Raises ProcessingError when the log has too
    few GPS windows for any set.
    """
    t = np.asarray(t_imu_s, float)
    acc = np.asarray(acc_b_mps2, float)
    r = vertical_rate_rps(t, gyro_b_rps, acc)
    dt = np.diff(t)
    # a sample holds the mean over (t_{k-1}, t_k] (architecture.md): rectangle sums are the exact
    # integrals at the sample times; a trapezoid would shift them by half a sample
    integ = np.concatenate([np.zeros((1, 3)), np.cumsum(np.column_stack([r[1:], acc[1:, 0], acc[1:, 1]]) * dt[:, None], axis=0)])
    # one contiguous row per integral: np.interp copies a strided column of the log (N values) to
    # read it, at each of the ~200 offsets the scans try (0.9 of 1.2 s CPU of an hour's estimate)
    integ = np.ascontiguousarray(integ.T)
    vel = np.asarray(vel_ned_mps, float)
    w = _gps_windows(t_gps_s, vel, window_s, min_speed_mps)
    inside = (w.ta - max_offset_s > t[0]) & (w.tb + max_offset_s < t[-1]) & w.ok
    inside &= np.isfinite(w.d_course) & np.isfinite(w.d_speed)
    nhp = max(3, int(round(highpass_s / w.dt_s)))
    if inside.sum() < min_samples:
        raise ProcessingError(f"time offset: only {int(inside.sum())} GPS windows above {min_speed_mps:g} m/s "
                              "inside the IMU span; the log needs turns or speed changes while moving")

    def hp(x, wt):
        return (x - _masked_mean(x, wt, nhp)) * (wt > 0).reshape((-1,) + (1,) * (x.ndim - 1))

    mask = inside.astype(float)
    y = {"course": hp(w.s_mean * w.d_course, mask), "along": hp(w.d_speed, mask)}
    wrap = np.abs(w.d_course) > np.pi / 2  # a course jump (reversing, noise at low speed)
    base_w = {"course": mask * ~wrap, "along": mask}

    cache: dict = {}  # the jackknife re-scans the same offsets with other weights

    def regressors(delta):
        key = round(float(delta), 9)
        if key not in cache:
            d = np.stack([np.interp(w.tb + delta, t, integ[k]) - np.interp(w.ta + delta, t, integ[k]) for k in range(3)], axis=1)
            cache[key] = {"course": hp((w.s_mean * d[:, 0])[:, None], mask), "along": hp(d[:, 1:], mask)}
        return cache[key]

    def fit(delta, wts, channels):
        X = regressors(delta)
        out = {}
        for c in channels:
            sw = np.sqrt(wts[c])
            A, b = X[c] * sw[:, None], y[c] * sw
            k, *_ = np.linalg.lstsq(A, b, rcond=None)
            res = y[c] - X[c] @ k
            out[c] = (float((wts[c] * res) @ res), k, res)
        return out

    def scan(grid, wts, scale, channels):
        sse = np.array([[fit(d, wts, channels)[c][0] for c in channels] for d in grid])
        J = (sse / scale).sum(axis=1)
        i = int(np.argmin(J))
        if 0 < i < grid.size - 1:  # parabola through the three best grid points
            den = J[i - 1] - 2 * J[i] + J[i + 1]
            return grid[i] + (0.5 * (grid[1] - grid[0]) * (J[i - 1] - J[i + 1]) / den if den > 0 else 0.0), sse
        return grid[i], sse

    def solve(channels) -> TimeOffset | NoOffset:
        # coarse to fine: the cost varies over the window length (0.5 s), so a 0.05 s grid finds its
        # basin, and 0.01 s grids (with a parabola through the best three) refine it
        step = 0.01
        grid = np.arange(-max_offset_s, max_offset_s + 0.025, 0.05)
        wts = dict(base_w)
        scale = np.ones(len(channels))
        best, sse = scan(grid, wts, scale, channels)

        def near(x, half_s):
            return x + np.arange(-half_s, half_s + step / 2, step)

        # channel noise levels at their own best; channels that explain too little are dropped
        ss_y = np.array([float((wts[c] * y[c]) @ y[c]) for c in channels])
        r2 = 1 - sse.min(axis=0) / np.maximum(ss_y, 1e-300)
        i_best = np.argmin(sse, axis=0)
        gains = [float(np.linalg.norm(fit(grid[i], wts, channels)[c][1])) for c, i in zip(channels, i_best)]
        use = tuple(c for c, q, k in zip(channels, r2, gains) if q >= MIN_R2 and GAIN_RANGE[0] < k < GAIN_RANGE[1])
        if not use:
            return NoOffset(f"time offset: GPS velocity changes do not follow the IMU (R² {np.array2string(r2, precision=2)}, "
                                   f"gains {np.array2string(np.array(gains), precision=2)}); "
                                   "too little motion, or the GPS velocity is too noisy")
        r2_all = tuple(float(q) for q in r2)
        channels = use
        for _ in range(2):  # IRLS with Huber weights on each channel's residuals at the current best
            f = fit(best, wts, channels)
            for c in channels:
                res = f[c][2][base_w[c] > 0]
                s = 1.4826 * np.median(np.abs(res)) or 1.0
                u = np.abs(f[c][2]) / (HUBER_K * s)
                wts[c] = base_w[c] * np.minimum(1.0, 1.0 / np.maximum(u, 1e-12))
            f = fit(best, wts, channels)
            scale = np.array([f[c][0] / max(wts[c].sum() - f[c][1].size, 1.0) for c in channels])
            best, _ = scan(near(best, 0.1), wts, scale, channels)

        f = fit(best, wts, channels)
        # delete-one-block jackknife over contiguous blocks of the usable windows
        idx = np.flatnonzero(inside)
        blocks = [b for b in np.array_split(idx, n_blocks) if b.size]
        local = near(best, 0.1)
        reps = []
        for b in blocks:
            wb = {c: wts[c].copy() for c in channels}
            for c in channels:
                wb[c][b] = 0.0
            reps.append(scan(local, wb, scale, channels)[0])
        reps = np.array(reps)
        sigma = float(np.sqrt((len(reps) - 1) / len(reps) * np.sum((reps - reps.mean()) ** 2))) if len(reps) > 2 else float("inf")
        gain = float(f["course"][1][0]) if "course" in channels else float("nan")
        gain_x = float(f["along"][1][0]) if "along" in channels else float("nan")
        rms = float("nan")
        if "course" in channels:
            rms = float(np.sqrt(f["course"][0] / wts["course"].sum()) / window_s / max(np.median(w.s_mean[inside]), 1e-9))
        return TimeOffset(float(best), sigma, gain, int(sum(wts[c].astype(bool).sum() for c in channels)), rms, gain_x, channels, r2_all)

    return [solve(tuple(c)) for c in channel_sets]


def estimate_session_offset(session, *, max_span_s: float | None = None, **kw) -> TimeOffset:
    """`estimate_gps_time_offset` on a loaded Session (GPS times already include `[time]` offsets);
    with `max_span_s`, on the span of the log where GPS course and speed change most (`busiest_span`)."""
    (res,) = estimate_session_offsets(session, channel_sets=(kw.pop("channels", ("course", "along")),),
                                      max_span_s=max_span_s, **kw)
    if isinstance(res, NoOffset):
        raise ProcessingError(res.reason)
    return res


def estimate_session_offsets(session, *, channel_sets: tuple[tuple[str, ...], ...], max_span_s: float | None = None,
                             **kw) -> list[TimeOffset | NoOffset]:
    """`estimate_gps_time_offsets` on a loaded Session (`estimate_session_offset`): one TimeOffset or
    NoOffset per set of channels; raises ProcessingError when the log cannot tell for any."""
    g = session.gps
    if g is None:
        raise ProcessingError("time offset: the session has no GPS")
    ok = g.valid
    if ok.sum() < 3:
        raise ProcessingError("time offset: fewer than 3 GPS fixes")
    t_g, vel = g.t_s[ok], gps_velocity(g.t_s[ok], g.lla[ok], g.vel_ned_mps[ok])
    t, gyro, acc = session.imu.t_s, session.imu.gyro_b_rps, session.imu.acc_b_mps2
    if max_span_s is not None and t[-1] - t[0] > max_span_s:
        a, b = busiest_span(t_g, vel, max_span_s)
        pad = kw.get("max_offset_s", 1.0) + 1.0
        mi = (t >= a - pad) & (t <= b + pad)
        mg = (t_g >= a) & (t_g <= b)
        t, gyro, acc, t_g, vel = t[mi], gyro[mi], acc[mi], t_g[mg], vel[mg]
    return estimate_gps_time_offsets(t, gyro, acc, t_g, vel, channel_sets=channel_sets, **kw)


def busiest_span(t_gps_s, vel_ned_mps, span_s: float, min_speed_mps: float = 0.5) -> tuple[float, float]:
    """[a, b] of length `span_s` holding the largest sum of squared GPS horizontal velocity changes
    while moving (turns and speed changes: what times the clock)."""
    t = np.asarray(t_gps_s, float)
    v = np.asarray(vel_ned_mps, float)[:, :2]
    dv = np.diff(v, axis=0)
    e = np.where(np.isfinite(dv).all(axis=1) & (np.linalg.norm(v[1:], axis=1) > min_speed_mps), np.sum(dv * dv, axis=1), 0.0)
    c = np.concatenate([[0.0], np.cumsum(e)])
    j = np.searchsorted(t, t[:-1] + span_s, side="right") - 1  # last fix inside [t_i, t_i + span]
    j = np.clip(j, 0, t.size - 1)
    gain = c[j] - c[np.arange(t.size - 1)]
    i = int(np.argmax(gain)) if gain.size else 0
    a = float(t[i])
    return a, a + span_s


@dataclass(frozen=True)
class CourseGain:
    """GPS course change against the gyro's rotation about the local vertical, over the same windows."""

    gain: float  # 1 for a consistent log; pi/180 for deg/s logged as rad/s; -1 for a flipped vertical axis
    sigma: float  # block-jackknife SD
    r2: float  # share of the course-change variance explained
    n_windows: int


def course_gain(t_imu_s, gyro_b_rps, acc_b_mps2, t_gps_s, vel_ned_mps, *, min_speed_mps: float = 1.0,
                window_s: float = 1.0, n_blocks: int = 10) -> CourseGain | None:
    """Gain k of  s̄ Δψ_gps = k s̄ ∫ r dt  at zero time offset (module docstring, course channel, not
    high-passed: a gyro bias of a few deg/h adds far less than a turn); None without turns while moving.

    Cheap (one fit): it tells deg/s from rad/s and a flipped vertical axis on logs without rest.
    """
    t = np.asarray(t_imu_s, float)
    r = vertical_rate_rps(t, gyro_b_rps, acc_b_mps2)
    integ = np.concatenate([[0.0], np.cumsum(r[1:] * np.diff(t))])
    vel = np.asarray(vel_ned_mps, float)
    ok = np.isfinite(vel[:, :2]).all(axis=1)
    if ok.sum() < 10:
        return None
    w = _gps_windows(np.asarray(t_gps_s, float)[ok], vel[ok], window_s, min_speed_mps)
    use = w.ok & (w.ta > t[0]) & (w.tb < t[-1]) & (np.abs(w.d_course) < np.pi / 2)
    if use.sum() < 20:
        return None
    x = w.s_mean[use] * (np.interp(w.tb[use], t, integ) - np.interp(w.ta[use], t, integ))
    y = w.s_mean[use] * w.d_course[use]
    if float(x @ x) <= 0 or float(y @ y) <= 0:
        return None
    k = float(x @ y / (x @ x))
    res = y - k * x
    r2 = 1.0 - float(res @ res) / float(y @ y)
    blocks = [b for b in np.array_split(np.arange(x.size), n_blocks) if b.size]
    reps = []
    for b in blocks:
        m = np.ones(x.size, bool)
        m[b] = False
        if float(x[m] @ x[m]) > 0:
            reps.append(float(x[m] @ y[m] / (x[m] @ x[m])))
    reps = np.asarray(reps)
    sd = float(np.sqrt((reps.size - 1) / reps.size * np.sum((reps - reps.mean()) ** 2))) if reps.size > 2 else float("inf")
    return CourseGain(k, sd, r2, int(use.sum()))


def session_course_gain(session, **kw) -> CourseGain | None:
    """`course_gain` on a loaded Session (None without GPS)."""
    g = session.gps
    if g is None or g.valid.sum() < 10:
        return None
    ok = g.valid
    vel = gps_velocity(g.t_s[ok], g.lla[ok], g.vel_ned_mps[ok])
    return course_gain(session.imu.t_s, session.imu.gyro_b_rps, session.imu.acc_b_mps2, g.t_s[ok], vel, **kw)
