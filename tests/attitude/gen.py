"""Small exact generator of a static observer turning a three-LR MARG device (test oracle).

Truth attitude from smooth roll/pitch/yaw functions; gyro rows are the exact mean rates
(C_{k-1}^T C_k = exp(w dt)) plus Earth rate; acc, mag are exact projections; ranges follow the
exact plane geometry d_i = (D - n.C o_i) / (n.C e_x). `pos_fn` adds a bounded hand motion (the
specific force then carries its acceleration; the ranges ignore it, as they do for LF2's wall
at 12 m). Noise is added with a seeded generator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli.frames import earth
from tpos_cli.frames.rotation import dcm_to_rotvec, euler_to_dcm, rotvec_to_dcm

LAT_DEG, H_M = 45.5, 40.0
MAG_NED_UT = np.array([17.0, -4.5, 50.0])  # a mid-latitude field, dip ~71 deg


@dataclass
class Gen:
    t: np.ndarray
    C: np.ndarray
    gyro: np.ndarray
    acc: np.ndarray
    mag: np.ndarray
    ranges: np.ndarray
    wall_n: np.ndarray
    bias: np.ndarray
    pos: np.ndarray  # (N,3) NED m, displacement of the device (bounded hand motion); 0 if none


def make(rpy_fn, duration_s=60.0, rate_hz=100.0, seed=1, gyro_sd=1e-4, bias_rps=(2e-5, -1e-5, 1.5e-5),
         acc_sd=0.0098, mag_sd=0.3, rng_sd=0.0015, wall_az_deg=30.0, wall_dist_m=12.0,
         b12=0.2, b13=0.2, mag_dist_ut=None, pos_fn=None):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s + 1e-9, 1.0 / rate_hz)
    rpy = np.array([rpy_fn(tt) for tt in t])
    C = euler_to_dcm(rpy[:, 0], rpy[:, 1], rpy[:, 2])
    lat = np.radians(LAT_DEG)
    w_ie = earth.earth_rate_ned_rps(lat)
    g_n = earth.gravity_ned_mps2(lat, H_M)
    n = t.size
    gyro = np.zeros((n, 3))
    rv = dcm_to_rotvec(np.swapaxes(C[:-1], 1, 2) @ C[1:])
    dt = np.diff(t)[:, None]
    Cm = C[1:]
    gyro[1:] = rv / dt + np.einsum("nji,j->ni", Cm, w_ie)
    gyro[0] = C[0].T @ w_ie
    bias = np.asarray(bias_rps, dtype=float)
    gyro = gyro + bias + rng.normal(0, gyro_sd, (n, 3))
    # an IMU row is the mean over (t_{k-1}, t_k]: project gravity with the mid-interval attitude
    C_mid = C.copy()
    C_mid[1:] = C[:-1] @ rotvec_to_dcm(0.5 * rv)
    f_n = np.broadcast_to(-g_n, (n, 3)).copy()
    pos = np.zeros((n, 3)) if pos_fn is None else np.array([pos_fn(tt) for tt in t])
    if pos_fn is not None:
        # the mean acceleration over (t_{k-1}, t_k] is the velocity change over it (exact)
        v = np.array([(pos_fn(tt + 1e-4) - pos_fn(tt - 1e-4)) / 2e-4 for tt in t])
        f_n[1:] += np.diff(v, axis=0) / dt
    acc = np.einsum("nji,nj->ni", C_mid, f_n) + rng.normal(0, acc_sd, (n, 3))
    m_n = np.broadcast_to(MAG_NED_UT, (n, 3)).copy()
    if mag_dist_ut is not None:
        m_n = m_n + mag_dist_ut(t)
    mag = np.einsum("nji,nj->ni", C, m_n) + rng.normal(0, mag_sd, (n, 3))
    az = np.radians(wall_az_deg)
    wall_n = np.array([np.cos(az), np.sin(az), 0.0])
    o = [np.zeros(3), np.array([0, -b12, 0.0]), np.array([0, 0, b13])]
    c = C[:, :, 0] @ wall_n
    ranges = np.stack([(wall_dist_m - (C @ oi) @ wall_n) / c for oi in o], axis=-1)
    ranges += rng.normal(0, rng_sd, ranges.shape)
    return Gen(t, C, gyro, acc, mag, ranges, wall_n, bias, pos)
