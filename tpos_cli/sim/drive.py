"""Scenario `drive` (paper 003): a land vehicle with a 100 Hz IMU and 1 Hz GPS with outages.

The vehicle stands still for `static_s` (for levelling), then drives a seeded random sequence of
manoeuvres: turns of 30-120 deg (lateral acceleration <= 2.5 m/s^2), speed changes within
5-20 m/s (<= 1.5 m/s^2), hills of 1-3 deg grade, and stop-and-go. Attitude follows the velocity:
yaw = course, pitch = road grade, and a small roll outwards in turns (0.6 deg per m/s^2 of lateral
acceleration). Paper 003 shades the GPS for 30 s starting at 40 s: the default outage.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from tpos_cli.errors import InvalidInputError
from tpos_cli.frames.earth import G0_MPS2
from tpos_cli.frames.geodetic import ned_to_lla
from tpos_cli.frames.rotation import euler_to_dcm
from tpos_cli.sim.gps import simulate_gps
from tpos_cli.sim.kinematics import MotionSample, simulate_truth_imu
from tpos_cli.sim.profiles import SMOOTHSTEP_PEAK_RATE as PEAK
from tpos_cli.sim.profiles import RampProfile
from tpos_cli.sim.result import (
    SimImu,
    SimOdometry,
    SimRanges,
    SimResult,
    SimShots,
    SimTargets,
    SimTruth,
)
from tpos_cli.sim.rtk import RtkModel
from tpos_cli.sim.sensor_errors import corrupt_imu, imu_grade

RTK = RtkModel()  # the real RTK log's figures (rtk.py), the defaults of the gps_rtk_* arguments
DEFAULT_START_LLA = (48.0496, 8.2076, 870.0)  # Furtwangen (paper 003's university), ellipsoidal h
ROLL_PER_LAT_ACC_RAD = np.radians(0.6)  # body roll per m/s^2 of lateral acceleration
MAX_LAT_ACC_MPS2 = 2.5
MAX_LON_ACC_MPS2 = 1.5


@dataclass(frozen=True)
class DriveMotion:
    """Vehicle motion from speed, course and grade profiles (all analytic)."""

    speed: RampProfile  # m/s
    yaw: RampProfile  # rad, course = heading (no side slip)
    grade: RampProfile  # rad, road pitch

    def __call__(self, t) -> MotionSample:
        s, s1, _ = self.speed.eval(t)
        y, y1, y2 = self.yaw.eval(t)
        g, g1, _ = self.grade.eval(t)
        cg, sg, cy, sy = np.cos(g), np.sin(g), np.cos(y), np.sin(y)
        vel = np.stack([s * cg * cy, s * cg * sy, -s * sg], axis=-1)
        acc = np.stack(
            [
                s1 * cg * cy - s * sg * g1 * cy - s * cg * sy * y1,
                s1 * cg * sy - s * sg * g1 * sy + s * cg * cy * y1,
                -s1 * sg - s * cg * g1,
            ],
            axis=-1,
        )
        roll = -ROLL_PER_LAT_ACC_RAD * s * y1  # right turn: centripetal acc to the right, body rolls left
        roll1 = -ROLL_PER_LAT_ACC_RAD * (s1 * y1 + s * y2)
        rpy = np.stack([roll, g, y], axis=-1)
        rates = np.stack([roll1, g1, y1], axis=-1)
        return MotionSample(vel, acc, rpy, rates)


def drive_motion(duration_s: float, static_s: float, rng: np.random.Generator) -> DriveMotion:
    """A seeded manoeuvre sequence covering [0, duration_s]."""
    speed, yaw, grade = [], [], []
    t = static_s
    s = rng.uniform(8.0, 12.0)
    T = max(4.0, PEAK * s / MAX_LON_ACC_MPS2)
    speed.append((t, T, s))
    t += T
    while t < duration_s:
        t += rng.uniform(3.0, 8.0)
        r = rng.random()
        if r < 0.45:  # turn
            d = np.radians(rng.uniform(30.0, 120.0)) * rng.choice([-1.0, 1.0])
            T = max(3.0, s * PEAK * abs(d) / MAX_LAT_ACC_MPS2)
            yaw.append((t, T, d))
        elif r < 0.75:  # speed change
            new = rng.uniform(5.0, 20.0)
            T = max(3.0, PEAK * abs(new - s) / MAX_LON_ACC_MPS2)
            speed.append((t, T, new - s))
            s = new
        elif r < 0.9:  # hill: up (or down), hold, back to level
            d = np.radians(rng.uniform(1.0, 3.0)) * rng.choice([-1.0, 1.0])
            hold = rng.uniform(5.0, 10.0)
            grade.append((t, 4.0, d))
            grade.append((t + 4.0 + hold, 4.0, -d))
            T = 8.0 + hold
        else:  # stop and go
            T1 = max(3.0, PEAK * s / MAX_LON_ACC_MPS2)
            new = rng.uniform(8.0, 15.0)
            T2 = max(3.0, PEAK * new / MAX_LON_ACC_MPS2)
            hold = rng.uniform(3.0, 8.0)
            speed.append((t, T1, -s))
            speed.append((t + T1 + hold, T2, new))
            s = new
            T = T1 + hold + T2
        t += T
    yaw0 = rng.uniform(-np.pi, np.pi)
    return DriveMotion(RampProfile.from_ramps(0.0, speed), RampProfile.from_ramps(yaw0, yaw), RampProfile.from_ramps(0.0, grade))


def simulate_drive(
    duration_s: float = 120.0,
    *,
    seed: int = 0,
    trajectory_seed: int | None = None,
    grade: str = "mems",
    noise_free: bool = False,
    rate_hz: float = 100.0,
    static_s: float = 15.0,
    outages=((40.0, 30.0),),
    gps_rate_hz: float = 1.0,
    gps_sigma_h_m: float = 1.5,
    gps_sigma_v_m: float = 2.5,
    gps_sigma_vel_mps: float = 0.05,
    start_lla=DEFAULT_START_LLA,
    t0_s: float = 0.0,
    name: str = "drive",
    shots: int = 0,
    shot_range_m: float = 40.0,
    range_sigma_m: float = 0.05,
    gps_correlated_sigma_neu_m=(0.0, 0.0, 0.0),
    gps_correlated_tau_s: float = 30.0,
    gps_clock_offset_s: float = 0.0,
    mounting_rpy_deg=(0.0, 0.0, 0.0),
    lever_arm_m=(0.0, 0.0, 0.0),
    vibration_mg: float = 0.0,
    odometry_rate_hz: float = 0.0,
    odometry_scale_error: float = 0.0,
    odometry_sigma_mps: float = 0.02,
    gps_rtk: bool = False,
    gps_rtk_floor_sigma_neu_m=RTK.floor_sigma_neu_m,
    gps_rtk_float_per_min: float = RTK.float_per_min,
    gps_rtk_float_duration_s=RTK.float_duration_s,
    gps_rtk_float_sd_factor=RTK.float_sd_factor,
    gps_rtk_float_offset_m=RTK.float_offset_m,
    gps_rtk_float_tau_s: float = RTK.float_tau_s,
    gps_rtk_multipath_per_min: float = RTK.multipath_per_min,
    gps_rtk_multipath_duration_s=RTK.multipath_duration_s,
    gps_rtk_multipath_offset_m=RTK.multipath_offset_m,
) -> SimResult:
    """Simulate the `drive` scenario; see the module docstring.

    `seed` draws the sensor noise; `trajectory_seed` (default: `seed`) the manoeuvres. `outages` are
    (start_s, length_s) pairs relative to the first IMU sample. `noise_free` gives an error-free IMU
    (grade `perfect`); GPS noise is set by the `gps_sigma_*` arguments alone.
    `shots` > 0 adds that many laser shots (paper 001: the LR1 beam along the body forward axis)
    on targets ahead of the vehicle, spread over the drive after the static start: one LR1 return
    per shot (`range_sigma_m` noise, LR2/LR3 no return), the target exactly `shot_range_m` along the
    beam at the return's time, written as targets with role "truth".
    `gps_clock_offset_s` d: a GPS record taken at IMU time t is stamped t - d (a logger's late or
    early GPS time tags, the IMU-GPS clock offset of issue 11); the truth stays on the IMU clock.
    What real car logs hold (issue 11 item 7), each off by default: `mounting_rpy_deg`, the IMU's
    attitude on the vehicle (the contract's convention, v_vehicle = C v_imu; session.toml does not
    state it, as a user's log would not); `lever_arm_m`, the GPS antenna in the vehicle's axes
    (session.toml states it in the IMU's); `vibration_mg`, engine and road vibration on the
    accelerometers (a 25 Hz engine line and its 50 Hz harmonic plus 10-40 Hz road noise, that RMS
    per axis, with 0.01 deg/s per mg on the gyros); an odometer at `odometry_rate_hz` reading
    the forward speed times (1 + `odometry_scale_error`) plus `odometry_sigma_mps` noise. The
    truth is the vehicle's attitude at the IMU point.
    `gps_rtk` (issue 11 item 7, off by default) makes the fixes RTK-like (`rtk.py`): white at a
    centimetre floor `gps_rtk_floor_sigma_neu_m` (replacing `gps_sigma_h_m`/`gps_sigma_v_m`), float
    stretches (`gps_rtk_float_per_min` starts per minute, lengths in `gps_rtk_float_duration_s`)
    whose stated SD is the floor times a factor in `gps_rtk_float_sd_factor` while their error is a
    Gauss-Markov offset (horizontal RMS in `gps_rtk_float_offset_m`, time constant
    `gps_rtk_float_tau_s`), and multipath steps at the floor SD (`gps_rtk_multipath_*`: a constant
    offset the receiver does not state). Defaults: the real RTK car log's figures (rtk.py cites
    them). The `sigma_*` columns are the stated SDs; fix stays 2; `sim.gps.rtk` holds the draws.
    """
    if duration_s <= 0 or rate_hz <= 0:
        raise InvalidInputError("duration and rate must be > 0")
    tseed = seed if trajectory_seed is None else trajectory_seed
    traj_rng = np.random.default_rng([tseed, 3])
    imu_rng, gps_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    motion = drive_motion(duration_s, static_s, traj_rng)
    n = int(round(duration_s * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    ti = simulate_truth_imu(motion, t, np.asarray(start_lla, dtype=float))
    g = imu_grade("perfect" if noise_free else grade, "drive")
    C_vb = euler_to_dcm(*np.radians(np.asarray(mounting_rpy_deg, dtype=float)))
    gyro_s, acc_s = ti.gyro_b_rps @ C_vb, ti.acc_b_mps2 @ C_vb  # in the IMU's axes: C_vb^T x per row
    if vibration_mg > 0:
        vib = vibration(t, rate_hz, vibration_mg, np.random.default_rng([seed, 7]))
        acc_s = acc_s + vib
        gyro_s = gyro_s + np.radians(vib / (1e-3 * G0_MPS2) / 100.0)  # 1 mg of it with 0.01 deg/s
    gyro, acc, err = corrupt_imu(gyro_s, acc_s, g, rate_hz, imu_rng)
    truth = SimTruth(ti.t_s, ti.lla, ti.vel_ned_mps, ti.rpy_rad)
    imu = SimImu(t, gyro, acc, None, gyro_s, acc_s, None, err, g, "FRD", float(rate_hz))
    lever_v = np.asarray(lever_arm_m, dtype=float)
    outages_arr = np.asarray(outages, dtype=float).reshape(-1, 2)
    rtk = None
    if gps_rtk:
        floats = lambda x: tuple(float(v) for v in x)  # noqa: E731  (plain floats for the toml comment)
        rtk = RtkModel(floor_sigma_neu_m=floats(np.broadcast_to(np.asarray(gps_rtk_floor_sigma_neu_m, dtype=float), 3)),
                       float_per_min=float(gps_rtk_float_per_min), float_duration_s=floats(gps_rtk_float_duration_s),
                       float_sd_factor=floats(gps_rtk_float_sd_factor), float_offset_m=floats(gps_rtk_float_offset_m),
                       float_tau_s=float(gps_rtk_float_tau_s), multipath_per_min=float(gps_rtk_multipath_per_min),
                       multipath_duration_s=floats(gps_rtk_multipath_duration_s),
                       multipath_offset_m=floats(gps_rtk_multipath_offset_m))
    gps = simulate_gps(
        antenna_truth(truth, ti.gyro_b_rps, lever_v) if np.any(lever_v) else truth,
        rate_hz,
        rate_hz=gps_rate_hz,
        sigma_h_m=gps_sigma_h_m,
        sigma_v_m=gps_sigma_v_m,
        sigma_vel_mps=gps_sigma_vel_mps,
        outages_s=outages_arr,
        rng=gps_rng,
        correlated_sigma_neu_m=gps_correlated_sigma_neu_m,
        correlated_tau_s=gps_correlated_tau_s,
        rtk=rtk,
    )
    if gps_clock_offset_s != 0.0:
        gps = dataclasses.replace(gps, t_s=gps.t_s - float(gps_clock_offset_s))
    params = {
        "scenario": "drive",
        "duration_s": duration_s,
        "seed": seed,
        "trajectory_seed": tseed,
        "grade": g.name,
        "gps_outages_s": outages_arr.tolist(),
        "gps_sigma_h_m": gps_sigma_h_m,
        "gps_sigma_v_m": gps_sigma_v_m,
        "gps_sigma_vel_mps": gps_sigma_vel_mps,
    }
    if rtk is not None:  # the floor replaces the position SDs: record what was drawn
        del params["gps_sigma_h_m"], params["gps_sigma_v_m"]
        params["gps_rtk"] = {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(rtk).items()}
    if gps_clock_offset_s != 0.0:
        params["gps_clock_offset_s"] = float(gps_clock_offset_s)
    if np.any(np.asarray(mounting_rpy_deg, dtype=float)):
        params["mounting_rpy_deg"] = [float(v) for v in mounting_rpy_deg]
    if np.any(lever_v):
        params["lever_arm_vehicle_m"] = lever_v.tolist()
    if vibration_mg > 0:
        params["vibration_mg"] = float(vibration_mg)
    odometry = None
    if odometry_rate_hz > 0:
        odometry = simulate_odometry(truth, rate_hz, odometry_rate_hz, odometry_scale_error, odometry_sigma_mps,
                                     np.random.default_rng([seed, 8]))
        params.update({"odometry_rate_hz": float(odometry_rate_hz), "odometry_scale_error": float(odometry_scale_error),
                       "odometry_sigma_mps": float(odometry_sigma_mps)})
    if np.any(np.asarray(gps_correlated_sigma_neu_m, dtype=float) > 0):
        params.update({"gps_correlated_sigma_neu_m": np.broadcast_to(np.asarray(gps_correlated_sigma_neu_m, dtype=float), 3).tolist(),
                       "gps_correlated_tau_s": gps_correlated_tau_s})
    win = np.column_stack([outages_arr[:, 0], outages_arr.sum(axis=1)])
    extra = {}
    if shots > 0:
        extra = _roadside_shots(truth, shots, static_s, duration_s, shot_range_m, range_sigma_m,
                                np.random.default_rng([seed, 5]))
        params.update({"shots": shots, "shot_range_m": shot_range_m, "range_sigma_m": range_sigma_m})
    return SimResult(
        kind="drive",
        name=name,
        t0_s=float(t0_s),
        truth=truth,
        imu=imu,
        gps=gps,
        gps_outages_s=win,
        odometry=odometry,
        toml={"gps": {"lever_arm_m": [float(v) for v in C_vb.T @ lever_v]}},  # in the IMU's axes
        params=params,
        **extra,
    )


def vibration(t_s, rate_hz: float, rms_mg: float, rng: np.random.Generator) -> np.ndarray:
    """(N, 3) engine and road vibration, m/s^2: a 25 Hz engine line and its 50 Hz harmonic (below
    Nyquist only) with random phases and slowly varying amplitude, plus 10-40 Hz band noise (FFT
    band-limited white noise), scaled to `rms_mg` per axis."""
    t = np.asarray(t_s, dtype=float)
    n = t.size
    out = np.zeros((n, 3))
    env = 1.0 + 0.3 * np.sin(2 * np.pi * t / rng.uniform(20.0, 40.0))  # engine load changes
    for f in (25.0, 50.0):
        if f < 0.5 * rate_hz:
            out += env[:, None] * np.sin(2 * np.pi * f * t[:, None] + rng.uniform(0, 2 * np.pi, 3)) / (f / 25.0)
    w = np.fft.rfft(rng.standard_normal((n, 3)), axis=0)
    fr = np.fft.rfftfreq(n, 1.0 / rate_hz)
    w[(fr < 10.0) | (fr > 40.0)] = 0.0
    out += np.fft.irfft(w, n=n, axis=0)
    out -= out.mean(axis=0)
    return out * (rms_mg * 1e-3 * G0_MPS2 / np.sqrt(np.mean(out**2, axis=0)))


def antenna_truth(truth: SimTruth, gyro_b_rps, lever_v_m) -> SimTruth:
    """The truth moved to a GPS antenna at `lever_v_m` in the vehicle's axes: position + C_nb l,
    velocity + C_nb (w x l) (the Earth's rate in the body rate is 7e-5 rad/s: negligible at metres)."""
    C = truth.C_nb
    ned = np.einsum("kij,j->ki", C, lever_v_m)
    lla = ned_to_lla(ned, truth.lla)  # each row from its own truth point
    vel = truth.vel_ned_mps + np.einsum("kij,kj->ki", C, np.cross(gyro_b_rps, lever_v_m))
    return SimTruth(truth.t_s, lla, vel, truth.rpy_rad)


def simulate_odometry(truth: SimTruth, imu_rate_hz: float, rate_hz: float, scale_error: float, sigma_mps: float,
                      rng: np.random.Generator) -> SimOdometry:
    """An odometer at `rate_hz` (a divisor of the IMU rate): the vehicle's forward speed (its
    velocity along the body x axis, >= 0) times (1 + scale_error) plus white noise, clipped at 0."""
    idx = np.arange(0, truth.t_s.size, max(1, int(round(imu_rate_hz / rate_hz))))
    fwd = np.einsum("ki,ki->k", truth.C_nb[idx][:, :, 0], truth.vel_ned_mps[idx])
    speed = np.maximum(fwd * (1.0 + scale_error) + sigma_mps * rng.standard_normal(idx.size), 0.0)
    return SimOdometry(truth.t_s[idx].copy(), speed, float(scale_error), float(sigma_mps))


def _roadside_shots(truth: SimTruth, n: int, static_s: float, duration_s: float, range_m: float, sigma_m: float,
                    rng: np.random.Generator) -> dict:
    """Ranges, shots and truth targets for `n` single-return shots along the body x axis."""
    t_shot = np.linspace(static_s + 10.0, duration_s - 5.0, n) if n > 1 else np.array([0.5 * (static_s + duration_s)])
    i = np.clip(np.searchsorted(truth.t_s, t_shot), 0, truth.t_s.size - 1)
    t_r = truth.t_s[i]
    C = truth.C_nb[i]
    lla = ned_to_lla(C[:, :, 0] * range_m, truth.lla[i]).reshape(-1, 3)  # C x (range, 0, 0) from each shot's point
    r = np.full((i.size, 3), np.nan)
    r[:, 0] = range_m + sigma_m * rng.standard_normal(i.size)
    r_true = np.full((i.size, 3), np.nan)
    r_true[:, 0] = range_m
    ids = tuple(f"T{k + 1}" for k in range(i.size))
    return {
        "ranges": SimRanges(t_r, r, r_true, 0.3, 0.2, float(sigma_m)),  # LR2/LR3 baselines: no returns
        "targets": SimTargets(ids, lla, ("truth",) * i.size),
        "shots": SimShots(ids, t_r - 0.05, t_r + 0.05),
    }
