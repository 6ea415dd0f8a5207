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
from tpos_cli.frames.geodetic import ned_to_lla
from tpos_cli.sim.gps import simulate_gps
from tpos_cli.sim.kinematics import MotionSample, simulate_truth_imu
from tpos_cli.sim.profiles import SMOOTHSTEP_PEAK_RATE as PEAK
from tpos_cli.sim.profiles import RampProfile
from tpos_cli.sim.result import (
    SimImu,
    SimRanges,
    SimResult,
    SimShots,
    SimTargets,
    SimTruth,
)
from tpos_cli.sim.sensor_errors import corrupt_imu, imu_grade

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
    gyro, acc, err = corrupt_imu(ti.gyro_b_rps, ti.acc_b_mps2, g, rate_hz, imu_rng)
    truth = SimTruth(ti.t_s, ti.lla, ti.vel_ned_mps, ti.rpy_rad)
    imu = SimImu(t, gyro, acc, None, ti.gyro_b_rps, ti.acc_b_mps2, None, err, g, "FRD", float(rate_hz))
    outages_arr = np.asarray(outages, dtype=float).reshape(-1, 2)
    gps = simulate_gps(
        truth,
        rate_hz,
        rate_hz=gps_rate_hz,
        sigma_h_m=gps_sigma_h_m,
        sigma_v_m=gps_sigma_v_m,
        sigma_vel_mps=gps_sigma_vel_mps,
        outages_s=outages_arr,
        rng=gps_rng,
        correlated_sigma_neu_m=gps_correlated_sigma_neu_m,
        correlated_tau_s=gps_correlated_tau_s,
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
    if gps_clock_offset_s != 0.0:
        params["gps_clock_offset_s"] = float(gps_clock_offset_s)
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
        toml={"gps": {"lever_arm_m": [0.0, 0.0, 0.0]}},
        params=params,
        **extra,
    )


def _roadside_shots(truth: SimTruth, n: int, static_s: float, duration_s: float, range_m: float, sigma_m: float,
                    rng: np.random.Generator) -> dict:
    """Ranges, shots and truth targets for `n` single-return shots along the body x axis."""
    t_shot = np.linspace(static_s + 10.0, duration_s - 5.0, n) if n > 1 else np.array([0.5 * (static_s + duration_s)])
    i = np.clip(np.searchsorted(truth.t_s, t_shot), 0, truth.t_s.size - 1)
    t_r = truth.t_s[i]
    C = truth.C_nb[i]
    lla = np.array([ned_to_lla(C[k] @ np.array([range_m, 0.0, 0.0]), truth.lla[i[k]]) for k in range(i.size)]).reshape(-1, 3)
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
