"""Vehicle motion constraints as measurements of the error-state filter (issue 11).

- Stops (`detect_stops`): intervals where the GPS speed or the odometer says the vehicle stands
  (an engine's vibration fails a raw-IMU stillness test, so the IMU alone does not decide).
- ZUPT (`Kind.ZUPT`, the block's mean NED velocity 0) and ZARU (`Kind.ZARU`, mean raw gyro = gyro bias + Earth rate)
  rows on the stops (`stop_measurements`).
- Non-holonomic constraints (`Kind.NHC`: the vehicle's lateral and vertical velocity are 0,
  Groves 2013 Sec. 15.4.3) while it is not stopped (`nhc_measurements`), in the vehicle axes given
  by the mounting rotation C_vb.
- The mounting (`travel_direction`): the IMU-to-vehicle rotation from a first run's body-frame
  velocity (a wheeled vehicle moves along its own x axis), with its sigma and the steadiness of
  that direction, which decides the platform when the pipeline says `auto` (a car's travel
  direction is fixed in its body axes, a walker's or a hand-held unit's is not).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli.frames.rotation import dcm_to_euler, euler_to_dcm
from tpos_cli.fusion.engine import Measurements
from tpos_cli.fusion.measurements import Kind

# constraints are gated without a counter of consecutive rejections (slot -1): when they keep
# failing it is the state that is wrong (e.g. a wrong initial yaw), and only the GPS may force it back
_SLOT_NHC = _SLOT_ZUPT = _SLOT_ZARU = -1


@dataclass(frozen=True)
class Stops:
    """Stop intervals (K, 2) session seconds, and where they were found (`gps`, `odometry` counts)."""

    intervals_s: np.ndarray
    sources: dict

    def contains(self, t_s) -> np.ndarray:
        t = np.asarray(t_s, dtype=float)
        inside = np.zeros(t.shape, dtype=bool)
        for a, b in self.intervals_s:
            inside |= (t >= a) & (t <= b)
        return inside

    @property
    def total_s(self) -> float:
        return float(np.sum(self.intervals_s[:, 1] - self.intervals_s[:, 0])) if self.intervals_s.size else 0.0


def _runs(t_s, still, max_step_s: float, min_len_s: float) -> list[tuple[float, float]]:
    """Intervals [first, last] of consecutive `still` samples no more than max_step_s apart."""
    out = []
    t = np.asarray(t_s, dtype=float)
    i = 0
    n = t.size
    while i < n:
        if not still[i]:
            i += 1
            continue
        j = i
        while j + 1 < n and still[j + 1] and t[j + 1] - t[j] <= max_step_s:
            j += 1
        if t[j] - t[i] >= min_len_s:
            out.append((float(t[i]), float(t[j])))
        i = j + 1
    return out


def detect_stops(gps_t_s, gps_vel_ned_mps, odo_t_s=None, odo_speed_mps=None, *, max_speed_mps: float = 0.1,
                 min_duration_s: float = 2.0) -> Stops:
    """Stops where consecutive GPS velocities (horizontal speed) or odometer speeds stay below
    max_speed_mps for at least min_duration_s. Each interval is shrunk by 0.5 s at both ends (the
    vehicle may be starting or finishing a stop between samples)."""
    found = []
    src = {"gps": 0, "odometry": 0}
    t = np.asarray(gps_t_s, dtype=float)
    v = np.asarray(gps_vel_ned_mps, dtype=float).reshape(-1, 3)
    ok = np.isfinite(v[:, 0]) & np.isfinite(v[:, 1])
    if ok.sum() > 1:
        sp = np.hypot(v[ok, 0], v[ok, 1])
        r = _runs(t[ok], sp < max_speed_mps, max_step_s=1.5, min_len_s=min_duration_s)
        src["gps"] = len(r)
        found += r
    if odo_t_s is not None and np.size(odo_t_s) > 1:
        to = np.asarray(odo_t_s, dtype=float)
        r = _runs(to, np.asarray(odo_speed_mps, dtype=float) < max_speed_mps, max_step_s=1.0, min_len_s=min_duration_s)
        src["odometry"] = len(r)
        found += r
    iv = sorted((a + 0.5, b - 0.5) for a, b in found if b - a > 1.0)
    merged: list[list[float]] = []
    for a, b in iv:
        if merged and a <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], b)
        else:
            merged.append([a, b])
    return Stops(np.array(merged, dtype=float).reshape(-1, 2), src)


def stop_measurements(t_imu_s, gyro_b_rps, acc_b_mps2, stops: Stops, *, zupt_sigma_mps: float, block_s: float = 0.5,
                      min_gyro_sigma_rps: float = np.radians(0.005)) -> Measurements | None:
    """ZUPT and ZARU rows every block_s inside the stops.

    ZUPT: the vehicle's mean velocity over the block is 0, not the IMU's velocity at one instant:
    an idling engine shakes the IMU (tens of mg at 10-50 Hz, mm/s of velocity), and a row taken
    every block_s samples one phase of an engine line whose frequency is a multiple of 1/block_s,
    which the filter would read as a steady velocity error. z (body frame, m/s) is the IMU's
    velocity at the row's sample relative to the block's mean, from the block's own specific
    force: u_j = sum_{m <= j} f_m dt_m (the mechanization's interval convention; the attitude is
    constant at rest), z = u_last less the block's least-squares line through u (gravity and the
    bias make a ramp; a mean of f would carry a partial cycle of the vibration into it);
    `fusion.measurements` rotates z to NED.
    ZARU: z = the block's mean raw gyro; its SD is the sample scatter over sqrt(N), doubled for
    vibration correlated between samples, at least min_gyro_sigma_rps."""
    t = np.asarray(t_imu_s, dtype=float)
    gyro = np.asarray(gyro_b_rps, dtype=float)
    acc = np.asarray(acc_b_mps2, dtype=float)
    tz, zv, zz, Rz = [], [], [], []
    for a, b in stops.intervals_s:
        edges = np.arange(a, b + 1e-9, block_s)
        for lo, hi in zip(edges[:-1], edges[1:]):
            i0, i1 = np.searchsorted(t, [lo, hi])
            if i1 - i0 < 3 or i0 < 1:
                continue
            g = gyro[i0:i1]
            sd = np.maximum(2.0 * g.std(axis=0, ddof=1) / np.sqrt(i1 - i0), min_gyro_sigma_rps)
            u = np.cumsum(acc[i0:i1] * np.diff(t[i0 - 1:i1])[:, None], axis=0)  # the IMU's velocity change
            tc = t[i0:i1] - t[i0:i1].mean()
            u -= u.mean(axis=0)
            slope = tc @ u / (tc @ tc)  # gravity and the accelerometer bias: a ramp
            tz.append(t[i1 - 1])
            zv.append(u[-1] - slope * tc[-1])
            zz.append(g.mean(axis=0))
            Rz.append(np.diag(sd**2))
    if not tz:
        return None
    n = len(tz)
    zupt = Measurements.rows(tz, Kind.ZUPT, np.array(zv), np.broadcast_to(zupt_sigma_mps**2 * np.eye(3), (n, 3, 3)),
                             dim=3, gated=True, slot=_SLOT_ZUPT)
    zaru = Measurements.rows(tz, Kind.ZARU, np.array(zz), np.array(Rz), dim=3, gated=True, slot=_SLOT_ZARU)
    return Measurements.merge(zupt, zaru)


def nhc_measurements(t_imu_s, stops: Stops, *, rate_hz: float, sigma_mps: float, after_s: float = -np.inf) -> Measurements:
    """NHC rows at rate_hz over the log after `after_s`, outside the stops: z = 0 (2 dof), R =
    sigma^2 each (the mounting block, `fusion.layout.mounting_block`, carries the misalignment and
    the distance to the point where the constraint holds). `after_s`: the end of the initial yaw
    search; before it the yaw may be tens of degrees off, far outside the constraint's linear range."""
    t = np.asarray(t_imu_s, dtype=float)
    step = max(1, int(round((t.size - 1) / (t[-1] - t[0]) / rate_hz))) if t.size > 1 else 1
    tn = t[step::step]
    tn = tn[~stops.contains(tn) & (tn >= after_s)]
    n = tn.size
    return Measurements.rows(tn, Kind.NHC, np.zeros((n, 3)), np.broadcast_to(sigma_mps**2 * np.eye(2), (n, 2, 2)), dim=2,
                             gated=True, slot=_SLOT_NHC)


def odometer_measurements(odo_t_s, speed_mps, *, rate_hz: float, sigma_mps: float) -> Measurements:
    """Odometer rows (`Kind.ODOMETER`), at most rate_hz: z = speed (m/s), R = sigma^2."""
    t = np.asarray(odo_t_s, dtype=float)
    v = np.asarray(speed_mps, dtype=float)
    keep = np.ones(t.size, dtype=bool)
    if t.size > 1 and rate_hz > 0:
        step = max(1, int(round(1.0 / (rate_hz * float(np.median(np.diff(t)))))))
        keep[:] = False
        keep[::step] = True
    n = int(keep.sum())
    return Measurements.rows(t[keep], Kind.ODOMETER, v[keep], np.full(n, sigma_mps**2), dim=1, gated=True, slot=-1)


# consumer MEMS gyros: sensitivity (scale-factor) error and cross-axis sensitivity of about 1 % each
# (data sheets of the BMI/ICM/LSM families state 1-3 %); the lower figure is taken
GYRO_SCALE_ERROR = 0.01


def rotation_gyro_noise_dps(gyro_b_rps, scale_error: float = GYRO_SCALE_ERROR) -> float:
    """Per-sample gyro SD (deg/s) that the platform's own rotation makes through the gyro's
    scale-factor and cross-axis errors: scale_error x the RMS of |w - median w| over the log.

    A gyro with a 1 % scale error reads 0.4 deg/s wrong on a walker's 40 deg/s sway and turns,
    an error that first differences (`imu_noise.measured_white_noise`) do not see: it follows
    the rotation, which is smooth at IMU rates. A filter that counts only the white part holds
    the attitude too tightly between fixes (the shared walk: forward 0.4 m off its RTK fixes, its
    forward and backward runs apart at half of the epochs). On a car or a rover (2-9 deg/s) the
    term stays below their measured vibration noise (0.5-1.6 deg/s)."""
    w = np.asarray(gyro_b_rps, dtype=float)
    if w.shape[0] < 2:
        return 0.0
    r = w - np.median(w, axis=0)
    r *= r  # in place: the log's (N, 3) once, not twice
    return float(scale_error * np.degrees(np.sqrt(np.mean(np.sum(r, axis=1)))))


@dataclass(frozen=True)
class TravelDirection:
    """The IMU-to-vehicle rotation from the travel direction in body axes: roll_deg, pitch_deg,
    yaw_deg (the contract's `mounting_rpy_deg`), the SDs of pitch and yaw (the vehicle's axes
    about which the travel direction turns; roll comes from gravity: no SD), steadiness (|mean
    body-frame velocity| / mean speed, 1 = a fixed direction), moving_s (time used)."""

    roll_deg: float
    pitch_deg: float
    yaw_deg: float
    sigma_pitch_deg: float
    sigma_yaw_deg: float
    steadiness: float
    moving_s: float

    @property
    def C_vb(self) -> np.ndarray:
        """Body -> vehicle DCM (v_vehicle = C_vb v_body), the contract's mounting convention."""
        return euler_to_dcm(*np.radians([self.roll_deg, self.pitch_deg, self.yaw_deg]))

    def summary(self) -> dict:
        return {"mounting_rpy_deg": [round(self.roll_deg, 2), round(self.pitch_deg, 2), round(self.yaw_deg, 2)],
                "sigma_rpy_deg": [None, round(self.sigma_pitch_deg, 2), round(self.sigma_yaw_deg, 2)],
                "steadiness": round(self.steadiness, 4), "moving_s": round(self.moving_s, 1)}


def vehicle_axes(x_b, down_b, upright_within_deg: float = 20.0) -> np.ndarray:
    """C_vb (v_vehicle = C_vb v_body) whose rows are the vehicle's axes in body coordinates: x
    along the travel direction x_b, z (down) the body's own z axis made orthogonal to it (roll is
    not observable from the travel direction: an upright IMU is taken as not rolled), y = z x x.
    When that z is more than `upright_within_deg` from gravity (down_b, the mean body-frame
    direction of gravity: a unit on its side), gravity marks the vehicle's down axis instead (a
    vehicle's mean attitude over a drive is level). Any yaw, no gimbal lock (an Euler
    parametrization of the travel direction loses pitch at a yaw of 90 deg)."""
    x = np.asarray(x_b, dtype=float) / np.linalg.norm(x_b)

    def _down(z):
        z = np.asarray(z, dtype=float) - (np.asarray(z, dtype=float) @ x) * x
        return z / np.linalg.norm(z)

    g = _down(down_b)
    z = _down([0.0, 0.0, 1.0]) if abs(x[2]) < 0.99 else g
    if np.degrees(np.arccos(np.clip(z @ g, -1.0, 1.0))) > upright_within_deg:
        z = g
    return np.vstack([x, np.cross(z, x), z])


def travel_direction(t_s, vel_ned_mps, C_nb, *, min_speed_mps: float = 3.0, block_s: float = 10.0,
                     fix_t_s=None, max_fix_gap_s: float = 1.0, att_sd_rad=None) -> TravelDirection | None:
    """Mounting from the direction of a solution's velocity in body axes (t_s (K,), vel_ned_mps
    (K, 3), C_nb (K, 3, 3)) while faster than min_speed_mps: the vehicle's x axis along the mean of
    C_nb^T v (each sample weighted by its speed; steadiness = |mean| / mean speed), its down axis
    from gravity (`vehicle_axes`). With `fix_t_s` (a forward run's fixes), only samples at most
    max_fix_gap_s after a fix count: inside a GPS outage a filter's velocity and yaw drift apart,
    and that drift would read as mounting (2.7 deg of yaw on part 1 with two 30 s windows
    withheld). SDs: scatter of the 10 s block means' directions in the vehicle's axes over
    sqrt(number of blocks), and, with `att_sd_rad` ((K, 2): the run's level and heading SDs at
    each sample), the run's own attitude error, added in quadrature: that error turns every
    body-frame velocity alike, so no number of samples averages it out (its speed-weighted mean
    SD over the samples used). On a slow rover whose first run holds its heading to 8-19 deg,
    the scatter alone (4.6 deg) had claimed a mounting good to a quarter of its real error."""
    v = np.asarray(vel_ned_mps, dtype=float)
    t_all = np.asarray(t_s, dtype=float)
    sp = np.linalg.norm(v, axis=1)
    m = sp > min_speed_mps
    if fix_t_s is not None:
        tf = np.sort(np.asarray(fix_t_s, dtype=float))
        if tf.size == 0:
            return None
        j = np.searchsorted(tf, t_all, side="right") - 1  # the last fix at or before each sample
        m &= (j >= 0) & (t_all - tf[np.maximum(j, 0)] <= max_fix_gap_s)
    if m.sum() < 10:
        return None
    # the body-frame velocities themselves, not their unit vectors: a sample's direction is good to
    # sd_v / speed, so weighting it by its speed keeps the slow, noisy ones from steering the mean
    Cm = np.asarray(C_nb)[m]
    u = np.einsum("kji,kj->ki", Cm, v[m])
    mean = u.mean(axis=0)
    steadiness = float(np.linalg.norm(mean) / np.mean(sp[m]))
    C_vb = vehicle_axes(mean, Cm[:, 2, :].mean(axis=0))  # NED down in body axes: row 2 of C_nb
    roll, pitch, yaw = np.degrees(dcm_to_euler(C_vb))
    t = t_all[m]
    blk = np.floor((t - t[0]) / block_s).astype(np.int64)
    ids = np.unique(blk)
    dt = float(np.median(np.diff(t_all))) if t_all.size > 1 else 0.0
    if ids.size >= 3:
        starts = np.searchsorted(blk, ids)  # blk is sorted: block means by reduceat
        w = np.add.reduceat(u, starts, axis=0) @ C_vb.T  # block directions in the vehicle's axes
        by = np.degrees(np.arctan2(w[:, 1], w[:, 0]))
        bp = np.degrees(np.arctan2(-w[:, 2], np.hypot(w[:, 0], w[:, 1])))
        sp_, sy_ = (float(np.std(x, ddof=1) / np.sqrt(ids.size)) for x in (bp, by))
    else:
        sp_ = sy_ = float("nan")
    if att_sd_rad is not None:
        common = np.degrees(np.average(np.asarray(att_sd_rad, dtype=float)[m], axis=0, weights=sp[m]))
        sp_, sy_ = (float(np.hypot(s, c)) if np.isfinite(s) else float(c) for s, c in ((sp_, common[0]), (sy_, common[1])))
    return TravelDirection(float(roll), float(pitch), float(yaw), sp_, sy_, steadiness, float(m.sum() * dt))
