"""numba strapdown kernels on the WGS-84 ellipsoid (NED navigation frame, FRD body frame).

Navigation state layout shared with `tpos_cli.fusion`: `nav` (6,) = [lat_rad, lon_rad, h_m,
vn_mps, ve_mps, vd_mps] and `C` (3, 3) = C_nb, both updated in place by `mech_step`.

Time reversal (paper 003, Sec. 4.2, backward filter): running this same kernel over the
reversed log with the gyro increments negated, the velocity negated and `earth_sign = -1`
integrates the navigation equations backwards exactly (dv/dt and dC/dt keep their form
under t -> -t, v -> -v, w_ib -> -w_ib, w_ie -> -w_ie; see `reverse_imu`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tpos_cli.frames._kernels import normal_gravity, radii_m, rotvec_to_dcm
from tpos_cli.frames.earth import OMEGA_IE_RPS


@njit(cache=True)
def cross(a, b):
    """a x b for 3-vectors."""
    out = np.empty(3)
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
    return out


@njit(cache=True)
def nav_rates(nav, earth_sign, w_ie, w_en):
    """Earth rate (times `earth_sign`) and transport rate in NED at the state `nav`, in place."""
    lat, h = nav[0], nav[2]
    rn, re = radii_m(lat)
    w_ie[0] = earth_sign * OMEGA_IE_RPS * np.cos(lat)
    w_ie[1] = 0.0
    w_ie[2] = -earth_sign * OMEGA_IE_RPS * np.sin(lat)
    w_en[0] = nav[4] / (re + h)
    w_en[1] = -nav[3] / (rn + h)
    w_en[2] = -nav[4] * np.tan(lat) / (re + h)


@njit(cache=True)
def mech_step(nav, C, dtheta, dv, dtheta_prev, dv_prev, dt, earth_sign, f_n):
    """One strapdown update over an IMU interval of length dt, in place on `nav` and `C`.

    dtheta, dv (3,): bias-corrected body increments over the interval (rad, m/s);
    dtheta_prev, dv_prev: those of the previous interval, for the two-sample coning and
    sculling corrections (Savage 1998, Eq. 7.1.1.1-11 and 7.2.2.2.2-15; zeros at the start).
    Velocity: specific-force increment rotated to the mid-interval nav frame, Coriolis and
    normal gravity at the start of the interval (their change over 10 ms is below 1e-7 m/s).
    Position: trapezoidal in velocity. Attitude: C <- R(-zeta) C R(phi), with phi the
    coning-corrected body rotation vector and zeta the nav-frame rotation over dt.
    Writes the mean specific force in NED over the interval to `f_n` (for the error model).
    """
    lat, lon, h = nav[0], nav[1], nav[2]
    v0 = nav[3:6].copy()
    w_ie = np.empty(3)
    w_en = np.empty(3)
    nav_rates(nav, earth_sign, w_ie, w_en)
    rn, re = radii_m(lat)

    phi_b = dtheta + cross(dtheta_prev, dtheta) / 12.0  # coning
    dv_b = dv + 0.5 * cross(dtheta, dv) + (cross(dtheta_prev, dv) + cross(dv_prev, dtheta)) / 12.0  # rotation + sculling
    zeta = (w_ie + w_en) * dt
    Cdv = C @ dv_b
    dv_n = Cdv - 0.5 * cross(zeta, Cdv)  # resolve in the nav frame at mid-interval

    cor = cross(2.0 * w_ie + w_en, v0)
    g = normal_gravity(lat, h)
    v1 = np.empty(3)
    v1[0] = v0[0] + dv_n[0] - cor[0] * dt
    v1[1] = v0[1] + dv_n[1] - cor[1] * dt
    v1[2] = v0[2] + dv_n[2] + (g - cor[2]) * dt

    # trapezoidal position, radii at the mid-interval latitude and height
    vm0 = 0.5 * (v0[0] + v1[0])
    vm1 = 0.5 * (v0[1] + v1[1])
    vm2 = 0.5 * (v0[2] + v1[2])
    h_mid = h - 0.5 * vm2 * dt
    lat_mid = lat + 0.5 * vm0 / (rn + h) * dt
    rn, re = radii_m(lat_mid)
    nav[0] = lat + vm0 / (rn + h_mid) * dt
    nav[1] = lon + vm1 / ((re + h_mid) * np.cos(lat_mid)) * dt
    nav[2] = h - vm2 * dt
    nav[3] = v1[0]
    nav[4] = v1[1]
    nav[5] = v1[2]

    C[:, :] = rotvec_to_dcm(-zeta) @ C @ rotvec_to_dcm(phi_b)
    for i in range(3):
        f_n[i] = dv_n[i] / dt


@njit(cache=True)
def integrate_kernel(t, gyro, acc, nav0, C0, earth_sign, out_nav, out_C):
    """Free-inertial integration of a whole log: out_nav (N, 6), out_C (N, 3, 3); row 0 = initial."""
    n = t.shape[0]
    nav = nav0.copy()
    C = C0.copy()
    out_nav[0] = nav
    out_C[0] = C
    dth_prev = np.zeros(3)
    dv_prev = np.zeros(3)
    f_n = np.empty(3)
    for k in range(1, n):
        dt = t[k] - t[k - 1]
        dth = gyro[k] * dt
        dv = acc[k] * dt
        mech_step(nav, C, dth, dv, dth_prev, dv_prev, dt, earth_sign, f_n)
        if k % 1000 == 0:
            C[:, :] = 1.5 * C - 0.5 * (C @ C.T @ C)  # keep C orthonormal (rounding only)
        dth_prev = dth
        dv_prev = dv
        out_nav[k] = nav
        out_C[k] = C
