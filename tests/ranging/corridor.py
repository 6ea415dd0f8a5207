"""Small corridor scenario for the ranging tests: exact IMU from `sim.kinematics`, four anchors.

A vehicle waits 3 s, drives north along a corridor at up to 1 m/s, turns round and comes back.
Not a test module (no `test_` prefix): imported by the tests.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli.frames import geodetic
from tpos_cli.sim.kinematics import MotionSample, simulate_truth_imu
from tpos_cli.sim.profiles import RampProfile

ORIGIN_LLA = np.array([45.0, 126.0, 100.0])
# anchors (north, east, down) in the local frame: two each side of a 3 m wide corridor, 2.5 m up
ANCHORS_NED = np.array([[-2.0, -1.5, -2.5], [12.0, 1.5, -2.0], [26.0, -1.5, -2.5], [5.0, 1.5, -2.2]])
NODE_DOWN_M = 0.0  # the node rides at the origin's height


@dataclass(frozen=True)
class Corridor:
    t_s: np.ndarray
    lla: np.ndarray
    ned_m: np.ndarray
    rpy_rad: np.ndarray
    gyro_b_rps: np.ndarray
    acc_b_mps2: np.ndarray


def corridor(duration_s: float = 40.0, rate_hz: float = 100.0) -> Corridor:
    speed = RampProfile.from_ramps(0.0, [(3.0, 3.0, 1.0), (14.0, 2.0, -0.6), (20.0, 2.0, 0.6), (34.0, 3.0, -1.0)])
    yaw = RampProfile.from_ramps(0.0, [(15.0, 6.0, np.pi)])

    def motion(t):
        s, ds, _ = speed.eval(t)
        y, dy, _ = yaw.eval(t)
        c, sn = np.cos(y), np.sin(y)
        z = np.zeros_like(s)
        vel = np.stack([s * c, s * sn, z], axis=-1)
        acc = np.stack([ds * c - s * dy * sn, ds * sn + s * dy * c, z], axis=-1)
        return MotionSample(vel, acc, np.stack([z, z, y], axis=-1), np.stack([z, z, dy], axis=-1))

    t = np.arange(0.0, duration_s + 1e-9, 1.0 / rate_hz)
    tr = simulate_truth_imu(motion, t, ORIGIN_LLA)
    ned = geodetic.lla_to_ned(tr.lla, ORIGIN_LLA)
    return Corridor(t, tr.lla, ned, tr.rpy_rad, tr.gyro_b_rps, tr.acc_b_mps2)


def noisy_imu(c: Corridor, rng, gyro_bias_dph=10.0, acc_bias_mg=2.0, gyro_noise_dps=0.02, acc_noise_mg=2.0):
    """IMU with constant biases and white noise (per-sample SDs)."""
    n = c.t_s.size
    gb = np.radians(gyro_bias_dph / 3600.0) * np.array([1.0, -0.7, 0.8])
    ab = acc_bias_mg * 9.80665e-3 * np.array([0.6, -1.0, 0.5])
    gyro = c.gyro_b_rps + gb + rng.normal(0, np.radians(gyro_noise_dps), (n, 3))
    acc = c.acc_b_mps2 + ab + rng.normal(0, acc_noise_mg * 9.80665e-3, (n, 3))
    return gyro, acc


def ranges(c: Corridor, rng, rate_hz=10.0, sd0=0.05, sd_rel=0.01, anchors=(0, 1, 2, 3)):
    """True-geometry ranges at rate_hz with noise sd0 + sd_rel * d; long format (t, anchor, range, true)."""
    step = int(round((c.t_s.size - 1) / (c.t_s[-1] - c.t_s[0]) / rate_hz))
    idx = np.arange(0, c.t_s.size, step)
    t, a, r, d = [], [], [], []
    for i in anchors:
        dist = np.linalg.norm(c.ned_m[idx] - ANCHORS_NED[i], axis=1)
        t.append(c.t_s[idx])
        a.append(np.full(idx.size, i))
        d.append(dist)
        r.append(dist + rng.normal(0, 1, idx.size) * (sd0 + sd_rel * dist))
    t, a, r, d = (np.concatenate(v) for v in (t, a, r, d))
    o = np.argsort(t, kind="stable")
    return t[o], a[o], r[o], d[o]
