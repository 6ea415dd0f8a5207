"""Measurement models of the INS error-state filter: one kind, one pair of @njit functions.

Every kind is a member of `Kind`, a `*_residual` (z = h(INS) - measured, the sign convention of
paper 003 Eq. 12, so that H x predicts z) and a `*_jacobian` (the rows of H for the 15
navigation errors), and one branch of `measure`, which the filter kernel calls for each
measurement and which adds the columns of the extra states (`fusion.layout`) the kind depends on.
To add a kind (issue 11: ZUPT of a vehicle, ZARU, non-holonomic constraints, odometer speed): one
`Kind` member, one residual/Jacobian pair with a finite-difference test, one branch in `measure`,
and a builder of its `fusion.engine.Measurements` rows.

Positions for the ranging kinds are NED metres in the local frame of the anchors' origin, reached
through ECEF exactly (`lla_to_local_ned`): a range is rotation invariant, and that frame's axes
differ from the vehicle's NED axes by (distance / Earth radius) ~ 1e-5 rad over a building,
negligible in the Jacobian rows.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np
from numba import njit

from tpos_cli.frames._kernels import earth_rate_ned, mat_mat3, mat_matT3, mat_vec3, matT_vec3, radii_m, skew
from tpos_cli.frames.earth import A_M, E2
from tpos_cli.fusion.layout import ATT, BG, N_NAV, POS, VEL, Block
from tpos_cli.ins._kernels import cross


class Kind(IntEnum):
    """Measurement kinds (the `kind` column of `fusion.engine.Measurements`)."""

    GPS_POSITION = 0  # z = fix lat, lon (rad), h (m); antenna at the lever arm (paper 003 Eq. 11-12)
    GPS_VELOCITY = 1  # z = fix NED velocity (m/s); dim 2 when the receiver gives no vertical velocity
    RANGE = 2  # z = calibrated range to anchor `par` (m) (paper 002 Eq. 21-24)
    FIX_NE = 3  # z = least-squares (north, east) fix in the local frame (paper 002 Eq. 7-12); sens row `par`
    FLOOR = 4  # z = down coordinate of the node in the local frame (floor constraint)
    ZUPT = 5  # z = 0: NED velocity of the IMU while it stands still
    NHC = 6  # z = 0: lateral and vertical velocity of a wheeled vehicle in its own axes (dim 2)
    ZARU = 7  # z = mean raw gyro rate over a stop (rad/s): the gyro bias plus the Earth's rate
    ODOMETER = 8  # z = odometer speed (m/s): the vehicle's forward speed times (1 + scale error)


@njit(cache=True)
def _put(H, row, col, M):
    """H[row:row+3, col:col+3] = M (3, 3)."""
    for i in range(3):
        for j in range(3):
            H[row + i, col + j] = M[i, j]


@njit(cache=True)
def gps_position_residual(nav, C, lever_b, lla_rad, lag_s, z):
    """z = INS antenna position at the fix time - fix, NED metres (paper Eq. 12, lever arm added).

    lag_s = t_nominal - t_fix: the nominal is moved back along its velocity to the fix time.
    """
    lat, h = nav[0], nav[2]
    rn, re = radii_m(lat)
    Cl = mat_vec3(C, lever_b)
    z[0] = (lat - lla_rad[0]) * (rn + h) + Cl[0] - nav[3] * lag_s
    z[1] = (nav[1] - lla_rad[1]) * (re + h) * np.cos(lat) + Cl[1] - nav[4] * lag_s
    z[2] = (lla_rad[2] - h) + Cl[2] - nav[5] * lag_s


@njit(cache=True)
def gps_position_jacobian(nav, C, lever_b, lag_s, H, row):
    """H rows row..row+2 for `gps_position_residual` (clears the first 15 columns of those rows)."""
    Cl = mat_vec3(C, lever_b)
    for i in range(3):
        for j in range(15):
            H[row + i, j] = 0.0
        H[row + i, POS + i] = 1.0
        H[row + i, VEL + i] = -lag_s
    _put(H, row, ATT, skew(Cl))  # C_est l - C_true l = [(C l) x] phi


@njit(cache=True)
def gps_velocity_residual(nav, C, lever_b, w_ib_b, vel_ned, z):
    """z = INS antenna velocity - GPS velocity, m/s (paper Eq. 12)."""
    u = mat_vec3(C, cross(w_ib_b, lever_b))
    for i in range(3):
        z[i] = nav[3 + i] + u[i] - vel_ned[i]


@njit(cache=True)
def gps_velocity_jacobian(C, lever_b, w_ib_b, H, row):
    """H rows row..row+2 for `gps_velocity_residual` (clears the first 15 columns of those rows)."""
    u = mat_vec3(C, cross(w_ib_b, lever_b))
    for i in range(3):
        for j in range(15):
            H[row + i, j] = 0.0
        H[row + i, VEL + i] = 1.0
    _put(H, row, BG, mat_mat3(C, skew(lever_b)))  # C [l x] dbg: the lever arm's rate error
    _put(H, row, ATT, skew(u))


@njit(cache=True)
def lla_rad_to_ecef(lat, lon, h):
    """ECEF position (m) of geodetic lat, lon (rad), h (m) (Groves Eq. 2.112)."""
    sl = np.sin(lat)
    re = A_M / np.sqrt(1.0 - E2 * sl * sl)
    out = np.empty(3)
    out[0] = (re + h) * np.cos(lat) * np.cos(lon)
    out[1] = (re + h) * np.cos(lat) * np.sin(lon)
    out[2] = (re * (1.0 - E2) + h) * sl
    return out


@njit(cache=True)
def lla_to_local_ned(lat, lon, h, r0_e, C_ne0):
    """NED position (m) relative to the origin with ECEF position r0_e and ECEF->NED DCM C_ne0."""
    return mat_vec3(C_ne0, lla_rad_to_ecef(lat, lon, h) - r0_e)


@njit(cache=True)
def node_position(nav, lag_s, r0_e, C_ne0):
    """Local-frame NED position (m) of the INS at the measurement time (moved back by lag_s along its velocity)."""
    p = lla_to_local_ned(nav[0], nav[1], nav[2], r0_e, C_ne0)
    for i in range(3):
        p[i] -= nav[3 + i] * lag_s
    return p


@njit(cache=True)
def range_residual(p_ned, anchor_ned, range_m, bias_m, cal_m):
    """z = |p - a| + eps_d + c_a - measured range (m): the INS range with the common bias eps_d
    and the anchor's calibration bias c_a, minus the measured one (Eq. 21-22, fusion's sign)."""
    d = p_ned - anchor_ned
    return np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) + bias_m + cal_m - range_m


@njit(cache=True)
def range_jacobian(p_ned, anchor_ned, lag_s, H, row):
    """Row `row` of H for `range_residual`: unit line of sight (Eq. 23) on the position and,
    through the lag, the velocity errors (clears the first 15 columns)."""
    d = p_ned - anchor_ned
    rho = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    for j in range(N_NAV):
        H[row, j] = 0.0
    for i in range(3):
        H[row, POS + i] = d[i] / rho
        H[row, VEL + i] = -lag_s * d[i] / rho


@njit(cache=True)
def zupt_residual(nav, z):
    """z = INS NED velocity - 0 (m/s) while the IMU stands still."""
    for i in range(3):
        z[i] = nav[3 + i]


@njit(cache=True)
def zupt_jacobian(H):
    """The 3 rows of H for `zupt_residual` (clears the first 15 columns)."""
    for i in range(3):
        for j in range(N_NAV):
            H[i, j] = 0.0
        H[i, VEL + i] = 1.0


@njit(cache=True)
def nhc_residual(nav, C, C_vb, z):
    """z = (lateral, vertical) velocity of the vehicle in its own axes, m/s: rows 1, 2 of
    C_vb C_nb^T v_ned (Groves 2013 Sec. 15.4.3 non-holonomic constraints; measured value 0)."""
    v_v = mat_vec3(C_vb, matT_vec3(C, nav[3:6]))
    z[0] = v_v[1]
    z[1] = v_v[2]


@njit(cache=True)
def nhc_jacobian(nav, C, C_vb, H):
    """The 2 rows of H for `nhc_residual` (clears the first 15 columns).

    With C_est = (I - [phi x]) C_true: v_b,est - v_b,true = C^T dv - C^T [v x] phi (first order),
    so H_vel = (C_vb C^T)[1:3] and H_att = -(C_vb C^T [v x])[1:3].
    """
    A = mat_matT3(C_vb, C)
    B = -mat_mat3(A, skew(nav[3:6]))
    for i in range(2):
        for j in range(N_NAV):
            H[i, j] = 0.0
        for j in range(3):
            H[i, VEL + j] = A[1 + i, j]
            H[i, ATT + j] = B[1 + i, j]


@njit(cache=True)
def odometer_residual(nav, C, C_vb, scale_err, speed_mps):
    """z = (1 + k) x forward velocity of the vehicle (row 0 of C_vb C_nb^T v_ned) - odometer speed, m/s."""
    return (1.0 + scale_err) * mat_vec3(C_vb, matT_vec3(C, nav[3:6]))[0] - speed_mps


@njit(cache=True)
def odometer_jacobian(nav, C, C_vb, scale_err, H):
    """Row 0 of H for `odometer_residual` on the navigation errors (as `nhc_jacobian`, row 0, times 1 + k)."""
    A = mat_matT3(C_vb, C)
    B = -mat_mat3(A, skew(nav[3:6]))
    for j in range(N_NAV):
        H[0, j] = 0.0
    for j in range(3):
        H[0, VEL + j] = (1.0 + scale_err) * A[0, j]
        H[0, ATT + j] = (1.0 + scale_err) * B[0, j]


@njit(cache=True)
def zaru_residual(nav, C, bias, earth_sign, gyro_mean_rps, z):
    """z = (gyro bias + Earth rate in body) - mean raw gyro rate over a stop, rad/s (the nominal's
    prediction of the standing gyro minus what it read); earth_sign -1 in reversed time."""
    w_ie_b = matT_vec3(C, earth_rate_ned(nav[0]))
    for i in range(3):
        z[i] = bias[3 + i] + earth_sign * w_ie_b[i] - gyro_mean_rps[i]


@njit(cache=True)
def zaru_jacobian(H):
    """The 3 rows of H for `zaru_residual`: the gyro-bias error with unit weight (the Earth-rate
    term's attitude sensitivity, 7e-5 rad/s x phi, is negligible)."""
    for i in range(3):
        for j in range(N_NAV):
            H[i, j] = 0.0
        H[i, BG + i] = 1.0


@njit(cache=True)
def measure(e, ev, aid, ranging, nav, C, bias, w_ib, acc_ned, lay, z, H, R):
    """Residual z (m,), rows H (m, n) and noise R (m, m) of measurement e about the nominal state.

    ev: the kernel's event arrays (`fusion._kernels.EventArrays`), aid: the per-kind parameters
    (`fusion._kernels.Aiding`), lay: `StateLayout.offsets()`, w_ib (3,) body rate at the sample,
    acc_ned (3,) the platform's NED acceleration there (m/s^2; the clock-offset columns).
    m = ev.dim[e] is the size of z, H and R, which the caller allocated; H is written whole.
    """
    kind = ev.kind[e]
    m = z.shape[0]
    lag = ev.lag[e]
    for i in range(m):
        for j in range(H.shape[1]):
            H[i, j] = 0.0
        for j in range(m):
            R[i, j] = ev.R[e, i, j]
    if kind == Kind.GPS_POSITION:
        gps_position_residual(nav, C, aid.lever_b, ev.z[e], lag, z)
        gps_position_jacobian(nav, C, aid.lever_b, lag, H, 0)
        o = lay[Block.GPS_ERROR]
        if o >= 0:  # z = INS - (fix - b_est) = dp + (b_est - b) - noise
            for i in range(3):
                z[i] += bias[6 + o - N_NAV + i]
                H[i, o + i] = 1.0
        oc = lay[Block.CLOCK]
        if oc >= 0:  # the fix was taken at IMU time t + d: the INS moved on by v d (`layout.clock_block`)
            d = bias[6 + oc - N_NAV]
            for i in range(3):
                z[i] += nav[3 + i] * d
                H[i, oc] = nav[3 + i]
    elif kind == Kind.GPS_VELOCITY:
        zv = np.empty(3)
        gps_velocity_residual(nav, C, aid.lever_b, w_ib, ev.z[e], zv)
        Hv = np.zeros((3, H.shape[1]))
        gps_velocity_jacobian(C, aid.lever_b, w_ib, Hv, 0)
        for i in range(m):
            z[i] = zv[i]
            for j in range(N_NAV):
                H[i, j] = Hv[i, j]
        oc = lay[Block.CLOCK]
        if oc >= 0:  # a velocity taken at IMU time t + d_vel: the INS velocity changed by a d_vel
            d = bias[6 + oc + 1 - N_NAV]
            for i in range(m):
                z[i] += acc_ned[i] * d
                H[i, oc + 1] = acc_ned[i]
    elif kind == Kind.NHC:
        nhc_residual(nav, C, aid.C_vb, z)
        nhc_jacobian(nav, C, aid.C_vb, H)
        om = lay[Block.MOUNTING]
        if om >= 0:  # the residual misalignment m = [pitch, yaw] turns the vehicle axes:
            # v_vehicle = (I - [(0, m_p, m_y) x]) C_vb v_b -> lateral - s m_y, vertical + s m_p; and
            # the constraint holds at a point d behind the IMU (the rear axle): + w x (-d, 0, 0)
            s = mat_vec3(aid.C_vb, matT_vec3(C, nav[3:6]))[0]
            w_v = mat_vec3(aid.C_vb, w_ib)
            mp, my, d = bias[6 + om - N_NAV], bias[6 + om - N_NAV + 1], bias[6 + om - N_NAV + 2]
            z[0] += -s * my - w_v[2] * d
            z[1] += s * mp + w_v[1] * d
            H[0, om + 1] = -s
            H[1, om] = s
            H[0, om + 2] = -w_v[2]
            H[1, om + 2] = w_v[1]
    elif kind == Kind.ODOMETER:
        ok = lay[Block.ODOMETER]
        k_s = bias[6 + ok - N_NAV] if ok >= 0 else 0.0
        z[0] = odometer_residual(nav, C, aid.C_vb, k_s, ev.z[e, 0])
        odometer_jacobian(nav, C, aid.C_vb, k_s, H)
        if ok >= 0:
            H[0, ok] = mat_vec3(aid.C_vb, matT_vec3(C, nav[3:6]))[0]
    elif kind == Kind.ZARU:
        zaru_residual(nav, C, bias, aid.earth_sign, ev.z[e], z)
        zaru_jacobian(H)
    elif kind == Kind.ZUPT:
        zupt_residual(nav, z)
        for i in range(3):
            z[i] -= ev.z[e, i]
        zupt_jacobian(H)
    elif ranging is not None:  # None: numba compiles no ranging branch (a drive has none)
        if kind == Kind.RANGE:
            a = ev.par[e]
            p = node_position(nav, lag, aid.r0_e, aid.C_ne0)
            ob = lay[Block.RANGE_BIAS]
            oc = lay[Block.CALIBRATION]
            z[0] = range_residual(p, aid.anchors_ned[a], ev.z[e, 0], bias[6 + ob - N_NAV], bias[6 + oc - N_NAV + a])
            range_jacobian(p, aid.anchors_ned[a], lag, H, 0)
            H[0, ob] = 1.0  # Eq. 24, last column (sign: error = estimate - truth)
            H[0, oc + a] = 1.0
        elif kind == Kind.FIX_NE:
            p = node_position(nav, lag, aid.r0_e, aid.C_ne0)
            H3 = np.zeros((3, H.shape[1]))
            gps_position_jacobian(nav, C, aid.zero3, lag, H3, 0)
            of = lay[Block.FLOOR]  # the fix's sensitivity to the floor and calibration errors (FLOOR, CALIBRATION follow)
            si = ev.par[e]
            for i in range(2):
                z[i] = p[i] - ev.z[e, i]
                for j in range(N_NAV):
                    H[i, j] = H3[i, j]
                if si >= 0:  # the fix corrected by the current floor and calibration estimates
                    for j in range(aid.sens.shape[2]):
                        H[i, of + j] = aid.sens[si, i, j]
                        z[i] += aid.sens[si, i, j] * bias[6 + of - N_NAV + j]
        elif kind == Kind.FLOOR:
            p = node_position(nav, lag, aid.r0_e, aid.C_ne0)
            H3 = np.zeros((3, H.shape[1]))
            gps_position_jacobian(nav, C, aid.zero3, lag, H3, 0)
            of = lay[Block.FLOOR]
            for j in range(N_NAV):
                H[0, j] = H3[2, j]
            H[0, of] = -1.0  # the floor used is z + its nominal correction; its error enters with -1
            z[0] = p[2] - (ev.z[e, 0] + bias[6 + of - N_NAV])
    return m
