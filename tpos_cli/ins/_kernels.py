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

from tpos_cli.frames._kernels import normal_gravity, radii_m, rotvec_to_dcm_into
from tpos_cli.frames.earth import OMEGA_IE_RPS

# error_model="numpy" on every kernel: no zero-divisor test at each division (`tpos_cli.filters.kalman`).


@njit(cache=True, error_model="numpy")
def cross(a, b):
    """a x b for 3-vectors."""
    out = np.empty(3)
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
    return out


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def mech_step(nav, C, dtheta, dv, dtheta_prev, dv_prev, dt, earth_sign, f_n, work=None):
    """One strapdown update over an IMU interval of length dt, in place on `nav` and `C`.

    dtheta, dv (3,): bias-corrected body increments over the interval (rad, m/s);
    dtheta_prev, dv_prev: those of the previous interval, for the two-sample coning and
    sculling corrections (Savage 1998, Eq. 7.1.1.1-11 and 7.2.2.2.2-15; zeros at the start).
    Velocity: specific-force increment rotated to the mid-interval nav frame, Coriolis and
    normal gravity at the start of the interval (their change over 10 ms is below 1e-7 m/s).
    Position: trapezoidal in velocity. Attitude: C <- R(-zeta) C R(phi), with phi the
    coning-corrected body rotation vector and zeta the nav-frame rotation over dt.
    Writes the mean specific force in NED over the interval to `f_n` (for the error model).
    work (3, 3, 3): scratch for the two rotations and their product, which a loop over samples
    allocates once (None: allocated here). Scalar code, no temporaries: this runs at every IMU sample.
    """
    lat, lon, h = nav[0], nav[1], nav[2]
    v0, v1_, v2 = nav[3], nav[4], nav[5]
    rn, re = radii_m(lat)
    sl, cl = np.sin(lat), np.cos(lat)
    wie0 = earth_sign * OMEGA_IE_RPS * cl
    wie2 = -earth_sign * OMEGA_IE_RPS * sl
    wen0 = v1_ / (re + h)
    wen1 = -v0 / (rn + h)
    wen2 = -v1_ * sl / cl / (re + h)
    a0, a1, a2 = dtheta[0], dtheta[1], dtheta[2]
    p0, p1, p2 = dtheta_prev[0], dtheta_prev[1], dtheta_prev[2]
    b0, b1, b2 = dv[0], dv[1], dv[2]
    q0, q1, q2 = dv_prev[0], dv_prev[1], dv_prev[2]
    # coning: phi = a + (p x a) / 12
    f0 = a0 + (p1 * a2 - p2 * a1) / 12.0
    f1 = a1 + (p2 * a0 - p0 * a2) / 12.0
    f2 = a2 + (p0 * a1 - p1 * a0) / 12.0
    # rotation + sculling: dv + (a x dv) / 2 + (p x dv + q x a) / 12
    u0 = b0 + 0.5 * (a1 * b2 - a2 * b1) + ((p1 * b2 - p2 * b1) + (q1 * a2 - q2 * a1)) / 12.0
    u1 = b1 + 0.5 * (a2 * b0 - a0 * b2) + ((p2 * b0 - p0 * b2) + (q2 * a0 - q0 * a2)) / 12.0
    u2 = b2 + 0.5 * (a0 * b1 - a1 * b0) + ((p0 * b1 - p1 * b0) + (q0 * a1 - q1 * a0)) / 12.0
    z0 = (wie0 + wen0) * dt
    z1 = wen1 * dt
    z2 = (wie2 + wen2) * dt
    c0 = C[0, 0] * u0 + C[0, 1] * u1 + C[0, 2] * u2
    c1 = C[1, 0] * u0 + C[1, 1] * u1 + C[1, 2] * u2
    c2 = C[2, 0] * u0 + C[2, 1] * u1 + C[2, 2] * u2
    # resolve in the nav frame at mid-interval: dv_n = c - (zeta x c) / 2
    d0 = c0 - 0.5 * (z1 * c2 - z2 * c1)
    d1 = c1 - 0.5 * (z2 * c0 - z0 * c2)
    d2 = c2 - 0.5 * (z0 * c1 - z1 * c0)
    # Coriolis + transport: (2 w_ie + w_en) x v
    k0 = 2.0 * wie0 + wen0
    k1 = wen1
    k2 = 2.0 * wie2 + wen2
    g = normal_gravity(lat, h)
    n0 = v0 + d0 - (k1 * v2 - k2 * v1_) * dt
    n1 = v1_ + d1 - (k2 * v0 - k0 * v2) * dt
    n2 = v2 + d2 + (g - (k0 * v1_ - k1 * v0)) * dt
    # trapezoidal position, radii at the mid-interval latitude and height
    vm0 = 0.5 * (v0 + n0)
    vm1 = 0.5 * (v1_ + n1)
    vm2 = 0.5 * (v2 + n2)
    h_mid = h - 0.5 * vm2 * dt
    lat_mid = lat + 0.5 * vm0 / (rn + h) * dt
    rn, re = radii_m(lat_mid)
    nav[0] = lat + vm0 / (rn + h_mid) * dt
    nav[1] = lon + vm1 / ((re + h_mid) * np.cos(lat_mid)) * dt
    nav[2] = h - vm2 * dt
    nav[3] = n0
    nav[4] = n1
    nav[5] = n2
    # C <- R(-zeta) C R(phi)
    if work is None:
        work = np.empty((3, 3, 3))
    Rb, Rn, T = work[0], work[1], work[2]
    rotvec_to_dcm_into(f0, f1, f2, Rb)
    rotvec_to_dcm_into(-z0, -z1, -z2, Rn)
    for i in range(3):
        for j in range(3):
            T[i, j] = C[i, 0] * Rb[0, j] + C[i, 1] * Rb[1, j] + C[i, 2] * Rb[2, j]
    for i in range(3):
        for j in range(3):
            C[i, j] = Rn[i, 0] * T[0, j] + Rn[i, 1] * T[1, j] + Rn[i, 2] * T[2, j]
    f_n[0] = d0 / dt
    f_n[1] = d1 / dt
    f_n[2] = d2 / dt


@njit(cache=True, error_model="numpy")
def integrate_kernel(t, gyro, acc, nav0, C0, earth_sign, out_nav, out_C):
    """Free-inertial integration of a whole log: out_nav (N, 6), out_C (N, 3, 3); row 0 = initial.

    Element loops only (no array assignment, no matrix product): numba compiles array-level
    copies with a formatted shape-mismatch error and `@` with BLAS dispatch, 4 of the 5 s this
    kernel took to compile.
    """
    n = t.shape[0]
    nav = np.empty(6)
    C = np.empty((3, 3))
    T = np.empty((3, 3))
    dth = np.empty(3)
    dv = np.empty(3)
    dth_prev = np.zeros(3)
    dv_prev = np.zeros(3)
    f_n = np.empty(3)
    work = np.empty((3, 3, 3))
    for i in range(6):
        nav[i] = nav0[i]
        out_nav[0, i] = nav[i]
    for i in range(3):
        for j in range(3):
            C[i, j] = C0[i, j]
            out_C[0, i, j] = C[i, j]
    for k in range(1, n):
        dt = t[k] - t[k - 1]
        for i in range(3):
            dth[i] = gyro[k, i] * dt
            dv[i] = acc[k, i] * dt
        mech_step(nav, C, dth, dv, dth_prev, dv_prev, dt, earth_sign, f_n, work)
        if k % 1000 == 0:  # keep C orthonormal (rounding only): C <- 1.5 C - 0.5 C C^T C
            for i in range(3):
                for j in range(3):
                    T[i, j] = C[0, i] * C[0, j] + C[1, i] * C[1, j] + C[2, i] * C[2, j]  # C^T C
            for i in range(3):
                c0, c1, c2 = C[i, 0], C[i, 1], C[i, 2]
                for j in range(3):
                    C[i, j] = 1.5 * C[i, j] - 0.5 * (c0 * T[0, j] + c1 * T[1, j] + c2 * T[2, j])
        for i in range(3):
            dth_prev[i] = dth[i]
            dv_prev[i] = dv[i]
        for i in range(6):
            out_nav[k, i] = nav[i]
        for i in range(3):
            for j in range(3):
                out_C[k, i, j] = C[i, j]
