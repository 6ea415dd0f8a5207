"""Strapdown mechanization wrapper: free-inertial integration of an IMU log, and time reversal.

IMU convention (docs/architecture.md): row k holds the mean rate / specific force over
(t[k-1], t[k]]; row 0 only marks the start. Kernels in `_kernels.py`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli.frames.rotation import dcm_to_euler, euler_to_dcm
from tpos_cli.ins._kernels import integrate_kernel


@dataclass(frozen=True)
class InsTrajectory:
    """Free-inertial solution at every IMU sample: t_s (N,), lla (N,3) deg/m, vel_ned_mps (N,3),
    C_nb (N,3,3), rpy_deg (N,3)."""

    t_s: np.ndarray
    lla: np.ndarray
    vel_ned_mps: np.ndarray
    C_nb: np.ndarray
    rpy_deg: np.ndarray


def nav_vector(lla, vel_ned_mps) -> np.ndarray:
    """Kernel navigation state [lat_rad, lon_rad, h_m, vn, ve, vd] from lla (deg, deg, m) and NED velocity."""
    lla = np.asarray(lla, dtype=float)
    return np.array([np.radians(lla[0]), np.radians(lla[1]), lla[2], *np.asarray(vel_ned_mps, dtype=float)])


def reverse_imu(t_s, gyro_b_rps, acc_b_mps2, out=None):
    """Arrays for integrating a log backwards in time with the forward kernel (`earth_sign=-1`).

    Returns (tau_s, gyro, acc): tau = -t reversed; row j of the reversed log must hold the
    mean over (tau[j-1], tau[j]], which is forward row N-j; gyro negated (inverted rotations,
    paper 003 Sec. 4.2), specific force unchanged. The navigation velocity must be negated
    on entry and on exit. `out`: (N,), (N, 3), (N, 3) float64 arrays to write them into (None: new ones).
    """
    t = np.asarray(t_s, dtype=float)
    gyro = np.asarray(gyro_b_rps, dtype=float)
    acc = np.asarray(acc_b_mps2, dtype=float)
    tau, g, a = out if out is not None else (np.empty(t.shape), np.empty(gyro.shape), np.empty(acc.shape))
    np.negative(t[::-1], out=tau)
    g[0] = 0.0
    a[0] = 0.0
    np.negative(gyro[:0:-1], out=g[1:])
    a[1:] = acc[:0:-1]
    return tau, g, a


def decimate_imu(t_s, gyro_b_rps, acc_b_mps2, factor: int):
    """(t, gyro, acc) keeping every `factor`-th sample time, each row the mean over the merged
    intervals (interval-weighted): exact under the mean-over-interval convention, so a decimated
    log integrates onto the same trajectory up to the coning/sculling of the longer interval.
    Sample 0 is kept; a tail shorter than `factor` intervals ends at the last sample."""
    t = np.asarray(t_s, dtype=float)
    if factor <= 1 or t.size < 3:
        return t, np.asarray(gyro_b_rps, dtype=float), np.asarray(acc_b_mps2, dtype=float)
    keep = np.arange(0, t.size, factor)
    if keep[-1] != t.size - 1:
        keep = np.append(keep, t.size - 1)
    dt = np.diff(t)
    out = []
    for x in (gyro_b_rps, acc_b_mps2):
        # cumulative increments at the kept samples, differenced: interval-weighted means
        inc = np.zeros((t.size, 3))
        np.cumsum(np.asarray(x, dtype=float)[1:] * dt[:, None], axis=0, out=inc[1:])
        m = np.zeros((keep.size, 3))
        m[1:] = np.diff(inc[keep], axis=0) / np.diff(t[keep])[:, None]
        out.append(m)
    return np.ascontiguousarray(t[keep]), out[0], out[1]


def decimate_to_rate(t_s, gyro_b_rps, acc_b_mps2, rate_hz: float):
    """(t, gyro, acc, rate) of `decimate_imu` with the factor that brings the log's mean rate to
    about `rate_hz` (the tuning passes' and the yaw search's cheap runs); rate the decimated log's
    mean rate (Hz; the log's own, or `rate_hz`, when it has fewer than two samples)."""
    t = np.asarray(t_s, dtype=float)
    rate = (t.size - 1) / (t[-1] - t[0]) if t.size > 1 else rate_hz
    td, gd, ad = decimate_imu(t, gyro_b_rps, acc_b_mps2, max(1, int(round(rate / rate_hz))))
    return td, gd, ad, (td.size - 1) / (td[-1] - td[0]) if td.size > 1 else rate


def integrate(t_s, gyro_b_rps, acc_b_mps2, lla0, vel0_ned_mps, rpy0_deg, *, backward: bool = False) -> InsTrajectory:
    """Integrate an IMU log from an initial state (free inertial, no aiding).

    Parameters
    ----------
    t_s : (N,) increasing sample times, s
    gyro_b_rps, acc_b_mps2 : (N, 3) FRD mean rates / specific forces over each preceding interval
    lla0, vel0_ned_mps, rpy0_deg : initial state at t_s[0] (or at t_s[-1] when `backward`)
    backward : integrate from the last sample to the first (reversed time); the result is
        returned in forward time order.
    """
    t = np.ascontiguousarray(t_s, dtype=float)
    gyro = np.ascontiguousarray(gyro_b_rps, dtype=float)
    acc = np.ascontiguousarray(acc_b_mps2, dtype=float)
    if t.ndim != 1 or gyro.shape != (t.size, 3) or acc.shape != (t.size, 3):
        raise ValueError(f"`t_s` (N,), `gyro_b_rps`, `acc_b_mps2` (N, 3) expected, got {t.shape}, {gyro.shape}, {acc.shape}")
    if t.size < 2 or np.any(np.diff(t) <= 0):
        raise ValueError("`t_s` must hold at least two strictly increasing times")
    nav0 = nav_vector(lla0, vel0_ned_mps)
    C0 = euler_to_dcm(*np.radians(rpy0_deg))
    sign = 1.0
    if backward:
        t, gyro, acc = reverse_imu(t, gyro, acc)
        nav0[3:] *= -1.0
        sign = -1.0
    out_nav = np.empty((t.size, 6))
    out_C = np.empty((t.size, 3, 3))
    integrate_kernel(t, gyro, acc, nav0, np.ascontiguousarray(C0), sign, out_nav, out_C)
    if backward:
        out_nav = out_nav[::-1].copy()
        out_nav[:, 3:] *= -1.0
        out_C = out_C[::-1].copy()
        t = -t[::-1]
    lla = np.column_stack([np.degrees(out_nav[:, 0]), np.degrees(out_nav[:, 1]), out_nav[:, 2]])
    rpy = np.degrees(np.column_stack(dcm_to_euler(out_C)))
    return InsTrajectory(t, lla, out_nav[:, 3:].copy(), out_C, rpy)
