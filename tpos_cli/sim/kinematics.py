"""Exact strapdown inverse: truth trajectory on the WGS-84 ellipsoid -> ideal IMU samples.

A scenario supplies a *motion*: a function of time returning NED velocity, its time derivative,
Euler angles and their rates, all analytic. This module integrates the position on the ellipsoid
(Groves Eq. 2.111: lat' = vn/(R_N+h), lon' = ve/((R_E+h) cos lat), h' = -vd) by Gauss-Legendre
quadrature, and forms the continuous sensor outputs (Groves Eq. 5.19 and 5.54, NED form)

    w_ib^b = w_nb^b + C_bn (w_ie^n + w_en^n)
    f^b    = C_bn (dv^n/dt + (2 w_ie^n + w_en^n) x v^n - g^n)

with g^n from `frames.earth.gravity_ned_mps2`, the same model the mechanization uses. Each IMU
row k is the MEAN of these over (t_{k-1}, t_k] (docs/architecture.md, "IMU sample convention"),
computed by Gauss-Legendre quadrature on the interval, which is exact to rounding for the
smooth profiles of `profiles.py` at IMU rates.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tpos_cli.frames import earth
from tpos_cli.frames.rotation import euler_to_dcm, wrap_angle_rad

#: Gauss-Legendre nodes per IMU interval: exact for polynomials of degree 7; the quadrature error
#: for 100 Hz sampling of the scenarios' motions is below 1e-12 of the signal (tests/sim check it
#: against 8 nodes).
N_GAUSS = 4
_CHUNK = 65536  # samples per block when forming sensor outputs (bounds memory for 1 h runs)


@dataclass(frozen=True)
class MotionSample:
    """Kinematic state from a scenario's motion function, arrays of shape (..., 3)."""

    vel_ned_mps: np.ndarray
    acc_ned_mps2: np.ndarray  # dv^n/dt, the time derivative of the NED velocity components
    rpy_rad: np.ndarray  # roll, pitch, yaw
    rpy_rate_rps: np.ndarray  # their time derivatives


Motion = Callable[[np.ndarray], MotionSample]


@dataclass(frozen=True)
class TruthImu:
    """Exact truth at the IMU sample times and the ideal (error-free) IMU, body FRD."""

    t_s: np.ndarray  # (N,)
    lla: np.ndarray  # (N, 3) lat deg, lon deg, h m
    vel_ned_mps: np.ndarray  # (N, 3)
    rpy_rad: np.ndarray  # (N, 3), yaw wrapped to (-pi, pi]
    gyro_b_rps: np.ndarray  # (N, 3) mean w_ib^b over (t_{k-1}, t_k]
    acc_b_mps2: np.ndarray  # (N, 3) mean f^b over (t_{k-1}, t_k]


def euler_rates_to_body_rate(rpy_rad, rpy_rate_rps):
    """w_nb^b (rad/s) from Euler angles and their rates, for C_nb = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p = rpy_rad[..., 0], rpy_rad[..., 1]
    dr, dp, dy = rpy_rate_rps[..., 0], rpy_rate_rps[..., 1], rpy_rate_rps[..., 2]
    cr, sr, cp, sp = np.cos(r), np.sin(r), np.cos(p), np.sin(p)
    return np.stack([dr - dy * sp, dp * cr + dy * sr * cp, -dp * sr + dy * cr * cp], axis=-1)


def continuous_imu(lat_rad, h_m, m: MotionSample):
    """Instantaneous (w_ib^b rad/s, f^b m/s^2) in body FRD for positions and a motion sample."""
    w_ie = earth.earth_rate_ned_rps(lat_rad)
    w_en = earth.transport_rate_ned_rps(lat_rad, h_m, m.vel_ned_mps)
    g = earth.gravity_ned_mps2(lat_rad, h_m)
    C_nb = euler_to_dcm(m.rpy_rad[..., 0], m.rpy_rad[..., 1], m.rpy_rad[..., 2])
    w_in = w_ie + w_en
    f_n = m.acc_ned_mps2 + np.cross(w_ie + w_in, m.vel_ned_mps) - g  # Groves Eq. 5.54 solved for f
    w_ib = euler_rates_to_body_rate(m.rpy_rad, m.rpy_rate_rps) + np.einsum("...ji,...j->...i", C_nb, w_in)
    f_b = np.einsum("...ji,...j->...i", C_nb, f_n)
    return w_ib, f_b


def _hermite(x, p0, p1, d0, d1):
    """Cubic Hermite on x in [0, 1] with end values and end derivatives (already times the step)."""
    x2, x3 = x * x, x * x * x
    return (2 * x3 - 3 * x2 + 1) * p0 + (x3 - 2 * x2 + x) * d0 + (-2 * x3 + 3 * x2) * p1 + (x3 - x2) * d1


def _integrate(rate_nodes, w, dt, anchor):
    """Values on the extended grid from interval integrals; value at index 1 (= t_0) is `anchor`."""
    inc = (rate_nodes * w).sum(axis=1) * dt
    c = np.concatenate([[0.0], np.cumsum(inc)])
    return anchor + (c - c[1])


def simulate_truth_imu(motion: Motion, t_s, lla0, n_gauss: int = N_GAUSS) -> TruthImu:
    """Integrate the truth position and form the ideal IMU samples.

    Parameters
    ----------
    motion : callable
        `motion(t) -> MotionSample` for times t of any shape (s, same clock as `t_s`).
    t_s : ndarray (N,)
        IMU sample times, s, strictly increasing.
    lla0 : array (3,)
        Position at `t_s[0]` (lat deg, lon deg, h m).
    """
    t = np.asarray(t_s, dtype=float)
    if t.ndim != 1 or t.size < 2 or np.any(np.diff(t) <= 0):
        raise ValueError("`t_s` must be a strictly increasing 1-D array with at least 2 samples")
    te = np.concatenate([[t[0] - (t[1] - t[0])], t])  # row 0 integrates over (t_-1, t_0]
    dt = np.diff(te)  # (N,)
    xg, wg = np.polynomial.legendre.leggauss(n_gauss)
    xn = 0.5 * (xg + 1.0)  # node fractions in (0, 1)
    w = 0.5 * wg  # weights summing to 1: a weighted sum is the interval mean
    tau = te[:-1, None] + xn[None, :] * dt[:, None]  # (N, n)

    ms = motion(te)
    mn = motion(tau)
    vs, vn = ms.vel_ned_mps, mn.vel_ned_mps
    lat0, lon0, h0 = np.radians(lla0[0]), np.radians(lla0[1]), float(lla0[2])

    h_e = _integrate(-vn[..., 2], w, dt, h0)
    h_n = _hermite(xn, h_e[:-1, None], h_e[1:, None], -vs[:-1, 2:3] * dt[:, None], -vs[1:, 2:3] * dt[:, None])

    # Latitude: the meridian radius depends on latitude itself; fixed-point passes converge by a
    # factor ~3 e^2 |dlat| per pass, so four passes reach rounding even for a 1 h drive.
    lat_e = np.full(te.shape, lat0)
    lat_n = np.full(tau.shape, lat0)
    for _ in range(4):
        lat_e = _integrate(vn[..., 0] / (earth.meridian_radius_m(lat_n) + h_n), w, dt, lat0)
        dlat = vs[:, 0] / (earth.meridian_radius_m(lat_e) + h_e)  # rad/s at the extended samples
        lat_n = _hermite(xn, lat_e[:-1, None], lat_e[1:, None], (dlat[:-1] * dt)[:, None], (dlat[1:] * dt)[:, None])
    lon_e = _integrate(vn[..., 1] / ((earth.transverse_radius_m(lat_n) + h_n) * np.cos(lat_n)), w, dt, lon0)

    gyro = np.empty((t.size, 3))
    acc = np.empty((t.size, 3))
    for a in range(0, t.size, _CHUNK):
        b = min(t.size, a + _CHUNK)
        sub = MotionSample(mn.vel_ned_mps[a:b], mn.acc_ned_mps2[a:b], mn.rpy_rad[a:b], mn.rpy_rate_rps[a:b])
        w_ib, f_b = continuous_imu(lat_n[a:b], h_n[a:b], sub)
        gyro[a:b] = np.einsum("n,knj->kj", w, w_ib)
        acc[a:b] = np.einsum("n,knj->kj", w, f_b)

    lla = np.stack([np.degrees(lat_e[1:]), np.degrees(lon_e[1:]), h_e[1:]], axis=-1)
    rpy = ms.rpy_rad[1:].copy()
    rpy[:, 2] = wrap_angle_rad(rpy[:, 2])
    return TruthImu(t, lla, vs[1:].copy(), rpy, gyro, acc)
