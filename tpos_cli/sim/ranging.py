"""Scenario `ranging` (paper 002): a vehicle in a corridor ranging to four anchors.

The mobile node (on the IMU) starts at the `[local]` origin, stands still for `static_s`, then
drives out-and-back legs along the corridor (west first, right U-turns) at `speed_mps`, and stops.
Every `1/range_rate_hz` s (paper: 0.1 s) each anchor reports a range following the paper's model
(Eq. 13): d~ = f d + c_i + e_NLOS + n, with scale f, per-anchor bias c_i, white noise of SD
0.05 m + 1 % of the range, and positive NLOS spikes (uniform 0.5-3 m) on a fraction of the ranges.
Anchor dropouts are missing rows (paper section 5.4: anchor 2 from 18 to 23 s and 40 to 45 s).
`range_calibration.csv` repeats the paper's calibration (section 3.3): the node at 0.6 m steps up
to 18.6 m from each anchor, 20 line-of-sight measurements per step, for the LS fit of Eq. 14-16.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli.errors import InvalidInputError
from tpos_cli.frames.geodetic import enu_to_lla, lla_to_ecef
from tpos_cli.sim.kinematics import MotionSample, simulate_truth_imu
from tpos_cli.sim.profiles import SMOOTHSTEP_PEAK_RATE as PEAK
from tpos_cli.sim.profiles import RampProfile
from tpos_cli.sim.result import (
    SimAnchorRanges,
    SimAnchors,
    SimImu,
    SimRangeCalibration,
    SimResult,
    SimTruth,
)
from tpos_cli.sim.sensor_errors import corrupt_imu, imu_grade

DEFAULT_ORIGIN_LLA = (45.0, 126.0, 100.0)  # Harbin, as in the contract's [local] example
DEFAULT_ANCHORS = (  # id, e, n, u (m) in the [local] frame: on both walls of a 4 m corridor
    ("A1", 3.0, -1.0, 2.0),
    ("A2", -6.0, 3.0, 2.0),
    ("A3", -14.0, -1.0, 2.0),
    ("A4", -23.0, 3.0, 2.0),
)
DEFAULT_BIAS_M = (0.35, 0.25, 0.40, 0.30)
DEFAULT_DROPOUTS = (("A2", 18.0, 5.0), ("A2", 40.0, 5.0))
MIN_TURN_RADIUS_M = 0.8


@dataclass(frozen=True)
class PlanarMotion:
    """Level motion from speed and course profiles (yaw = course, zero roll and pitch)."""

    speed: RampProfile
    yaw: RampProfile

    def __call__(self, t) -> MotionSample:
        s, s1, _ = self.speed.eval(t)
        y, y1, _ = self.yaw.eval(t)
        cy, sy = np.cos(y), np.sin(y)
        z = np.zeros(np.shape(t))
        vel = np.stack([s * cy, s * sy, z], axis=-1)
        acc = np.stack([s1 * cy - s * sy * y1, s1 * sy + s * cy * y1, z], axis=-1)
        return MotionSample(vel, acc, np.stack([z, z, y], axis=-1), np.stack([z, z, y1], axis=-1))


def corridor_motion(duration_s: float, static_s: float, speed_mps: float, leg_s: float) -> PlanarMotion:
    """Out-and-back legs with right U-turns, ending at rest before `duration_s`."""
    T_acc = max(2.0, PEAK * speed_mps / 0.5)  # <= 0.5 m/s^2, an electric cart
    T_turn = max(3.0, PEAK * np.pi * MIN_TURN_RADIUS_M / speed_mps)
    speed = [(static_s, T_acc, speed_mps)]
    yaw = []
    t = static_s + T_acc + leg_s
    while t + T_turn + leg_s + T_acc + 1.0 <= duration_s:
        yaw.append((t, T_turn, np.pi))
        t += T_turn + leg_s
    speed.append((t, T_acc, -speed_mps))
    return PlanarMotion(RampProfile.from_ramps(0.0, speed), RampProfile.from_ramps(-np.pi / 2.0, yaw))


def range_sigma_m(d_m, sigma0_m: float = 0.05, sigma_rel: float = 0.01):
    """Noise SD of a range: sigma0 + sigma_rel * d."""
    return sigma0_m + sigma_rel * np.asarray(d_m, dtype=float)


def simulate_ranging(
    duration_s: float = 60.0,
    *,
    seed: int = 0,
    grade: str = "paper",
    noise_free: bool = False,
    rate_hz: float = 100.0,
    static_s: float = 5.0,
    speed_mps: float = 1.0,
    leg_s: float = 18.0,
    origin_lla=DEFAULT_ORIGIN_LLA,
    anchors=DEFAULT_ANCHORS,
    scale: float = 1.025,
    bias_m=DEFAULT_BIAS_M,
    sigma0_m: float = 0.05,
    sigma_rel: float = 0.01,
    nlos_prob: float = 0.03,
    nlos_range_m=(0.5, 3.0),
    dropouts=DEFAULT_DROPOUTS,
    range_rate_hz: float = 10.0,
    calibration_step_m: float = 0.6,
    calibration_max_m: float = 18.6,
    calibration_repeats: int = 20,
    t0_s: float = 0.0,
    name: str = "ranging",
) -> SimResult:
    """Simulate the `ranging` scenario; see the module docstring.

    `dropouts` are (anchor id, start_s, length_s) windows with no rows from that anchor.
    `noise_free` gives an error-free IMU and ranges with neither noise nor NLOS spikes (scale and
    biases stay: they are the model, not noise).
    """
    if duration_s <= 0 or rate_hz <= 0 or speed_mps <= 0:
        raise InvalidInputError("duration, rate and speed must be > 0")
    ids = tuple(str(a[0]) for a in anchors)
    if len(bias_m) != len(ids):
        raise InvalidInputError(f"bias_m: {len(bias_m)} values for {len(ids)} anchors")
    for a_id, _, _ in dropouts:
        if a_id not in ids:
            raise InvalidInputError(f"dropout: unknown anchor {a_id!r} (anchors: {', '.join(ids)})")
    stride = rate_hz / range_rate_hz
    if abs(stride - round(stride)) > 1e-9 or round(stride) < 1:
        raise InvalidInputError(f"range rate: {range_rate_hz} Hz must divide the IMU rate {rate_hz} Hz")
    imu_rng, rng_rng, cal_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(3))
    origin = np.asarray(origin_lla, dtype=float)
    mot = corridor_motion(duration_s, static_s, speed_mps, leg_s)
    n = int(round(duration_s * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    ti = simulate_truth_imu(mot, t, origin)
    g = imu_grade("perfect" if noise_free else grade, "ranging")
    gyro, acc, err = corrupt_imu(ti.gyro_b_rps, ti.acc_b_mps2, g, rate_hz, imu_rng)
    truth = SimTruth(ti.t_s, ti.lla, ti.vel_ned_mps, ti.rpy_rad)
    imu = SimImu(t, gyro, acc, None, ti.gyro_b_rps, ti.acc_b_mps2, None, err, g, "FRD", float(rate_hz))

    enu = np.array([[a[1], a[2], a[3]] for a in anchors], dtype=float)
    a_lla = enu_to_lla(enu, origin)
    a_ecef = lla_to_ecef(a_lla)
    ri = np.arange(0, n, int(round(stride)))
    node_ecef = lla_to_ecef(truth.lla[ri])
    A = len(ids)
    d_true = np.linalg.norm(node_ecef[:, None, :] - a_ecef[None, :, :], axis=-1)  # (K, A) exact
    bias = np.asarray(bias_m, dtype=float)
    noise = rng_rng.standard_normal(d_true.shape) * range_sigma_m(d_true, sigma0_m, sigma_rel)
    spikes = (rng_rng.random(d_true.shape) < nlos_prob) * rng_rng.uniform(*nlos_range_m, size=d_true.shape)
    if noise_free:
        noise = np.zeros_like(d_true)
        spikes = np.zeros_like(d_true)
    meas = scale * d_true + bias[None, :] + spikes + noise  # Eq. 13
    keep = np.ones(d_true.shape, dtype=bool)
    for a_id, start, length in dropouts:
        keep[(t[ri] >= start) & (t[ri] < start + length), ids.index(a_id)] = False
    kk, aa = np.nonzero(keep)  # row-major: time order, then anchor order
    anchor_ranges = SimAnchorRanges(t[ri][kk], aa.astype(np.int64), meas[kk, aa], d_true[kk, aa], spikes[kk, aa])

    steps = np.arange(1, int(round(calibration_max_m / calibration_step_m)) + 1) * calibration_step_m
    cal_true = np.tile(np.repeat(steps, calibration_repeats), A)
    cal_anchor = np.repeat(np.arange(A), steps.size * calibration_repeats)
    cal_noise = 0.0 if noise_free else cal_rng.standard_normal(cal_true.shape) * range_sigma_m(cal_true, sigma0_m, sigma_rel)
    cal_meas = scale * cal_true + bias[cal_anchor] + cal_noise  # Eq. 14: line of sight, no NLOS
    calib = SimRangeCalibration(cal_anchor.astype(np.int64), cal_true, cal_meas, float(scale), bias.copy())

    params = {
        "scenario": "ranging",
        "duration_s": duration_s,
        "seed": seed,
        "grade": g.name,
        "scale": scale,
        "bias_m": list(map(float, bias)),
        "sigma_m": f"{sigma0_m} + {sigma_rel} * range",
        "nlos_prob": nlos_prob,
        "dropouts": [list(d) for d in dropouts],
    }
    return SimResult(
        kind="ranging",
        name=name,
        t0_s=float(t0_s),
        truth=truth,
        imu=imu,
        anchors=SimAnchors(ids, enu, a_lla, origin),
        anchor_ranges=anchor_ranges,
        range_calibration=calib,
        toml={"local": {"lat": float(origin[0]), "lon": float(origin[1]), "h": float(origin[2])}},
        params=params,
    )
