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

from tpos_cli.frames._kernels import earth_rate_ned, mat_mat3, mat_vec3, matT_vec3, radii_m, skew
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
def _ecef(lat, lon, h):
    """ECEF position (m) of geodetic lat, lon (rad), h (m) as a tuple (Groves Eq. 2.112)."""
    sl = np.sin(lat)
    re = A_M / np.sqrt(1.0 - E2 * sl * sl)
    return ((re + h) * np.cos(lat) * np.cos(lon), (re + h) * np.cos(lat) * np.sin(lon), (re * (1.0 - E2) + h) * sl)


@njit(cache=True)
def lla_rad_to_ecef(lat, lon, h):
    """ECEF position (m) of geodetic lat, lon (rad), h (m) (Groves Eq. 2.112)."""
    x, y, z = _ecef(lat, lon, h)
    out = np.empty(3)
    out[0] = x
    out[1] = y
    out[2] = z
    return out


@njit(cache=True)
def lla_to_local_ned(lat, lon, h, r0_e, C_ne0):
    """NED position (m) relative to the origin with ECEF position r0_e and ECEF->NED DCM C_ne0."""
    return mat_vec3(C_ne0, lla_rad_to_ecef(lat, lon, h) - r0_e)


@njit(cache=True)
def node_position_ned(nav, lag_s, r0_e, C_ne0):
    """Local-frame NED position (m) of the INS at the measurement time (moved back by lag_s along
    its velocity), as a tuple: C_ne0 (r_e - r0_e) - v lag_s (no allocation: once per range row)."""
    x, y, z = _ecef(nav[0], nav[1], nav[2])
    d0, d1, d2 = x - r0_e[0], y - r0_e[1], z - r0_e[2]
    return (C_ne0[0, 0] * d0 + C_ne0[0, 1] * d1 + C_ne0[0, 2] * d2 - nav[3] * lag_s,
            C_ne0[1, 0] * d0 + C_ne0[1, 1] * d1 + C_ne0[1, 2] * d2 - nav[4] * lag_s,
            C_ne0[2, 0] * d0 + C_ne0[2, 1] * d1 + C_ne0[2, 2] * d2 - nav[5] * lag_s)


@njit(cache=True)
def node_position(nav, lag_s, r0_e, C_ne0):
    """`node_position_ned` as a new array (3,)."""
    p = np.empty(3)
    p[0], p[1], p[2] = node_position_ned(nav, lag_s, r0_e, C_ne0)
    return p


@njit(cache=True)
def range_residual(p_ned, anchor_ned, range_m, bias_m, cal_m):
    """z = |p - a| + eps_d + c_a - measured range (m): the INS range with the common bias eps_d
    and the anchor's calibration bias c_a, minus the measured one (Eq. 21-22, fusion's sign).
    p_ned: an array (3,) or a tuple (`node_position_ned`)."""
    d0, d1, d2 = p_ned[0] - anchor_ned[0], p_ned[1] - anchor_ned[1], p_ned[2] - anchor_ned[2]
    return np.sqrt(d0 * d0 + d1 * d1 + d2 * d2) + bias_m + cal_m - range_m


@njit(cache=True)
def range_jacobian(p_ned, anchor_ned, lag_s, H, row):
    """Row `row` of H for `range_residual`: unit line of sight (Eq. 23) on the position and,
    through the lag, the velocity errors (clears the first 15 columns)."""
    d0, d1, d2 = p_ned[0] - anchor_ned[0], p_ned[1] - anchor_ned[1], p_ned[2] - anchor_ned[2]
    rho = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    for j in range(N_NAV):
        H[row, j] = 0.0
    H[row, POS] = d0 / rho
    H[row, POS + 1] = d1 / rho
    H[row, POS + 2] = d2 / rho
    H[row, VEL] = -lag_s * d0 / rho
    H[row, VEL + 1] = -lag_s * d1 / rho
    H[row, VEL + 2] = -lag_s * d2 / rho


@njit(cache=True)
def zupt_residual(nav, C, vel_rel_b, z):
    """z = INS NED velocity - the IMU's velocity while the vehicle stands (m/s): C vel_rel_b, the
    IMU's vibration about the stop block's mean (`fusion.constraints.stop_measurements`; negated
    with the run's velocity in reversed time by `fusion.engine`)."""
    v = mat_vec3(C, vel_rel_b)
    for i in range(3):
        z[i] = nav[3 + i] - v[i]


@njit(cache=True)
def zupt_jacobian(H):
    """The 3 rows of H for `zupt_residual` (clears the first 15 columns)."""
    for i in range(3):
        for j in range(N_NAV):
            H[i, j] = 0.0
        H[i, VEL + i] = 1.0


@njit(cache=True)
def vehicle_velocity(nav, C, C_vb, i):
    """Component i of the vehicle-axes velocity C_vb C_nb^T v_ned (m/s), without allocating."""
    u0 = C[0, 0] * nav[3] + C[1, 0] * nav[4] + C[2, 0] * nav[5]
    u1 = C[0, 1] * nav[3] + C[1, 1] * nav[4] + C[2, 1] * nav[5]
    u2 = C[0, 2] * nav[3] + C[1, 2] * nav[4] + C[2, 2] * nav[5]
    return C_vb[i, 0] * u0 + C_vb[i, 1] * u1 + C_vb[i, 2] * u2


@njit(cache=True)
def _vehicle_velocity_row(nav, C, C_vb, i, scale, H, row):
    """H[row, vel] = scale a and H[row, att] = -scale (a [v x]) for a = row i of C_vb C^T (the
    first-order sensitivity of `vehicle_velocity` i to the velocity and attitude errors)."""
    a0 = C_vb[i, 0] * C[0, 0] + C_vb[i, 1] * C[0, 1] + C_vb[i, 2] * C[0, 2]
    a1 = C_vb[i, 0] * C[1, 0] + C_vb[i, 1] * C[1, 1] + C_vb[i, 2] * C[1, 2]
    a2 = C_vb[i, 0] * C[2, 0] + C_vb[i, 1] * C[2, 1] + C_vb[i, 2] * C[2, 2]
    v0, v1, v2 = nav[3], nav[4], nav[5]
    H[row, VEL] = scale * a0
    H[row, VEL + 1] = scale * a1
    H[row, VEL + 2] = scale * a2
    H[row, ATT] = scale * -(a1 * v2 - a2 * v1)  # a [v x] by columns
    H[row, ATT + 1] = scale * -(a2 * v0 - a0 * v2)
    H[row, ATT + 2] = scale * -(a0 * v1 - a1 * v0)


@njit(cache=True)
def nhc_residual(nav, C, C_vb, z):
    """z = (lateral, vertical) velocity of the vehicle in its own axes, m/s: rows 1, 2 of
    C_vb C_nb^T v_ned (Groves 2013 Sec. 15.4.3 non-holonomic constraints; measured value 0)."""
    z[0] = vehicle_velocity(nav, C, C_vb, 1)
    z[1] = vehicle_velocity(nav, C, C_vb, 2)


@njit(cache=True)
def nhc_jacobian(nav, C, C_vb, H):
    """The 2 rows of H for `nhc_residual` (clears the first 15 columns).

    With C_est = (I - [phi x]) C_true: v_b,est - v_b,true = C^T dv - C^T [v x] phi (first order),
    so H_vel = (C_vb C^T)[1:3] and H_att = -(C_vb C^T [v x])[1:3].
    """
    for i in range(2):
        for j in range(N_NAV):
            H[i, j] = 0.0
        _vehicle_velocity_row(nav, C, C_vb, 1 + i, 1.0, H, i)


@njit(cache=True)
def odometer_residual(nav, C, C_vb, scale_err, speed_mps):
    """z = (1 + k) x forward velocity of the vehicle (row 0 of C_vb C_nb^T v_ned) - odometer speed, m/s."""
    return (1.0 + scale_err) * vehicle_velocity(nav, C, C_vb, 0) - speed_mps


@njit(cache=True)
def odometer_jacobian(nav, C, C_vb, scale_err, H):
    """Row 0 of H for `odometer_residual` on the navigation errors (as `nhc_jacobian`, row 0, times 1 + k)."""
    for j in range(N_NAV):
        H[0, j] = 0.0
    _vehicle_velocity_row(nav, C, C_vb, 0, 1.0 + scale_err, H, 0)


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
def antenna_velocity(nav, C, aid, bias, w_ib, lay):
    """NED velocity (3,) of the GPS antenna: v + C (w_ib x l), l the stated lever arm aid.lever_b
    plus the lever-arm correction's nominal C_vb^T (dl, 0) when the layout has it (m/s)."""
    lb = np.empty(3)
    for i in range(3):
        lb[i] = aid.lever_b[i]
    ol = lay[Block.LEVER]
    if ol >= 0:
        for j in range(2):
            dl = bias[6 + ol - N_NAV + j]
            for i in range(3):
                lb[i] += aid.C_vb[j, i] * dl
    u = mat_vec3(C, cross(w_ib, lb))
    for i in range(3):
        u[i] += nav[3 + i]
    return u


@njit(cache=True)
def _lever_second_order(P, ol, H, R, m, share):
    """R[:2, :2] += the variance of the second-order term -phi x (A dl) that the linear rows
    (A = H's lever-arm columns, dl the correction's error) leave out, for the yaw error phi_D:
    its north and east parts -phi_D u_E and phi_D u_N, u = A dl, have variances P_yaw (A P_ll
    A^T)_EE and P_yaw (A P_ll A^T)_NN (independent zero-mean Gaussians: E[a^2 b^2] = s_a^2 s_b^2;
    Bar-Shalom et al. 2001 Sec. 10.3, the second-order filter's trace term). While the heading is
    still tens of degrees uncertain (a static start, the yaw search) and the lever arm a metre,
    this is decimetres against centimetre fixes: without it the filter reads the yaw's own
    corrections as turns and takes a lever arm from them it has not seen.

    share (0..1) scales it: at rest the attitude does not turn, so the term is one constant over a
    stop (A dl does not rotate; phi_D only drifts: part 1's yaw SD went 3.00 -> 3.12 deg over its 37 s
    starting stop), which the position states take up at the stop's first fix; counted again at every
    later fix as independent noise it made those 4 mm fixes 5 cm ones (79 % of S there, standing NIS
    0.2 of 3). `fusion.lever_arm.second_order_shares` gives 0 to those rows."""
    s_yaw = P[ATT + 2, ATT + 2] * share
    for i in range(min(m, 2)):
        r = 1 - i  # north's term comes from u_E, east's from u_N
        v = 0.0
        for a in range(2):
            for b in range(2):
                v += H[r, ol + a] * P[ol + a, ol + b] * H[r, ol + b]
        R[i, i] += s_yaw * v


@njit(cache=True)
def measure(e, ev, aid, ranging, nav, C, bias, w_ib, acc_ned, vib_ned, lay, P, z, H, R):
    """Residual z (m,), rows H (m, n) and noise R (m, m) of measurement e about the nominal state.

    ev: the kernel's event arrays (`fusion._kernels.EventArrays`), aid: the per-kind parameters
    (`fusion._kernels.Aiding`), lay: `StateLayout.offsets()`, w_ib (3,) body rate at the sample (GPS
    rows: its window mean, `fusion.nav_errors.window_rate_b`),
    acc_ned (3,) the platform's mean NED acceleration over the window of the measurement's clock
    offset (m/s^2; the clock columns, `fusion.nav_errors.window_acceleration_ned`), P (n, n)
    the predicted covariance (the lever arm's second-order term, `_lever_second_order`), vib_ned
    (3,) the IMU's vibration velocity at a GPS velocity row (m/s, taken out of the INS velocity:
    `fusion.nav_errors.window_vibration_velocity_b`).
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
        of = lay[Block.FLOAT]
        if of >= 0 and ev.float_row[e]:  # an RTK float epoch's fix = truth + b_float + white (`fusion.rtk_float`)
            for i in range(3):
                z[i] += bias[6 + of - N_NAV + i]
                H[i, of + i] = 1.0
        oc = lay[Block.CLOCK]
        if oc >= 0:  # the fix was taken at IMU time t + d: the antenna moved on by v_ant d (`layout.clock_block`),
            # v_ant = v + C (w x l) with the lever arm l in use (a car turning at 0.3 rad/s moves a 1 m lever
            # arm's antenna 2 cm in 0.08 s beyond the IMU's own motion)
            # (and on by a d^2 / 2: 2 cm for a car braking at 3 m/s^2 with d = 0.12 s, an RTK fix's own SD)
            d = bias[6 + oc - N_NAV]
            v_ant = antenna_velocity(nav, C, aid, bias, w_ib, lay)
            for i in range(3):
                z[i] += (v_ant[i] + 0.5 * acc_ned[i] * d) * d
                H[i, oc] = v_ant[i] + acc_ned[i] * d
        ol = lay[Block.LEVER]
        if ol >= 0:  # the antenna at l + C_vb^T (dl, 0) (`layout.lever_arm_block`): + C C_vb^T (dl, 0)
            for j in range(2):
                dl = bias[6 + ol - N_NAV + j]
                for i in range(3):
                    a = C[i, 0] * aid.C_vb[j, 0] + C[i, 1] * aid.C_vb[j, 1] + C[i, 2] * aid.C_vb[j, 2]
                    H[i, ol + j] = a
                    z[i] += a * dl
            _lever_second_order(P, ol, H, R, 3, ev.second_order[e])
    elif kind == Kind.GPS_VELOCITY:
        zv = np.empty(3)
        gps_velocity_residual(nav, C, aid.lever_b, w_ib, ev.z[e], zv)
        for i in range(3):  # the fix holds the antenna's motion, not the IMU mount's vibration
            zv[i] -= vib_ned[i]
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
        ol = lay[Block.LEVER]
        if ol >= 0:  # the antenna's rate term C (w x C_vb^T (dl, 0)): column j is C (w x row j of C_vb)
            for j in range(2):
                u = mat_vec3(C, cross(w_ib, aid.C_vb[j]))
                dl = bias[6 + ol - N_NAV + j]
                for i in range(m):
                    H[i, ol + j] = u[i]
                    z[i] += u[i] * dl
            _lever_second_order(P, ol, H, R, m, ev.second_order[e])
    elif kind == Kind.NHC:
        nhc_residual(nav, C, aid.C_vb, z)
        nhc_jacobian(nav, C, aid.C_vb, H)
        om = lay[Block.MOUNTING]
        if om >= 0:  # the residual misalignment m = [pitch, yaw] turns the vehicle axes:
            # v_vehicle = (I - [(0, m_p, m_y) x]) C_vb v_b -> lateral - s m_y, vertical + s m_p; and
            # the constraint holds at a point d behind the IMU (the rear axle): + w x (-d, 0, 0)
            s = vehicle_velocity(nav, C, aid.C_vb, 0)
            w_v1 = aid.C_vb[1, 0] * w_ib[0] + aid.C_vb[1, 1] * w_ib[1] + aid.C_vb[1, 2] * w_ib[2]
            w_v2 = aid.C_vb[2, 0] * w_ib[0] + aid.C_vb[2, 1] * w_ib[1] + aid.C_vb[2, 2] * w_ib[2]
            mp, my, d = bias[6 + om - N_NAV], bias[6 + om - N_NAV + 1], bias[6 + om - N_NAV + 2]
            z[0] += -s * my - w_v2 * d
            z[1] += s * mp + w_v1 * d
            H[0, om + 1] = -s
            H[1, om] = s
            H[0, om + 2] = -w_v2
            H[1, om + 2] = w_v1
    elif kind == Kind.ODOMETER:
        ok = lay[Block.ODOMETER]
        k_s = bias[6 + ok - N_NAV] if ok >= 0 else 0.0
        z[0] = odometer_residual(nav, C, aid.C_vb, k_s, ev.z[e, 0])
        odometer_jacobian(nav, C, aid.C_vb, k_s, H)
        if ok >= 0:
            H[0, ok] = vehicle_velocity(nav, C, aid.C_vb, 0)
    elif kind == Kind.ZARU:
        zaru_residual(nav, C, bias, aid.earth_sign, ev.z[e], z)
        zaru_jacobian(H)
    elif kind == Kind.ZUPT:
        zupt_residual(nav, C, ev.z[e], z)
        zupt_jacobian(H)
    elif ranging is not None:  # None: numba compiles no ranging branch (a drive has none)
        if kind == Kind.RANGE:
            a = ev.par[e]
            p = node_position_ned(nav, lag, aid.r0_e, aid.C_ne0)
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
