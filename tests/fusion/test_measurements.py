"""Measurement models (`fusion.measurements`): Jacobians against finite differences or nonlinear
perturbation, local-frame positions against pymap3d, and the extra states' columns of `measure`."""

import numpy as np
from numpy.testing import assert_allclose

from tpos_cli.frames import geodetic
from tpos_cli.frames.rotation import euler_to_dcm
from tpos_cli.fusion._kernels import Aiding, EventArrays
from tpos_cli.fusion.layout import (
    Block,
    StateLayout,
    backward_sign,
    clock_block,
    float_offset_block,
    gps_error_block,
    lever_arm_block,
    ranging_blocks,
)
from tpos_cli.fusion.measurements import (
    Kind,
    gps_position_jacobian,
    gps_position_residual,
    gps_velocity_jacobian,
    gps_velocity_residual,
    lla_rad_to_ecef,
    lla_to_local_ned,
    measure,
    nhc_jacobian,
    nhc_residual,
    odometer_jacobian,
    odometer_residual,
    range_jacobian,
    range_residual,
    zaru_jacobian,
    zaru_residual,
)
from tpos_cli.fusion.nav_errors import apply_feedback


def _no_P(H):
    """A zero predicted covariance (n, n) for H (m, n): no second-order terms in R."""
    return np.zeros((H.shape[1], H.shape[1]))


def _nominal():
    nav = np.array([np.radians(48.0), np.radians(8.0), 500.0, 12.0, -7.0, 0.3])
    C = euler_to_dcm(*np.radians([3.0, -2.0, 130.0]))
    return nav, C


def test_ecef_and_local_ned_match_pymap3d():
    origin = np.array([45.0, 126.0, 100.0])
    lla = np.array([45.0003, 126.0004, 101.5])
    r_e = lla_rad_to_ecef(np.radians(lla[0]), np.radians(lla[1]), lla[2])
    assert_allclose(r_e, geodetic.lla_to_ecef(lla), rtol=0, atol=1e-6)  # 1 um: pymap3d's own tolerance
    r0 = geodetic.lla_to_ecef(origin)
    C = geodetic.ecef_to_ned_dcm(origin[0], origin[1])
    ned = lla_to_local_ned(np.radians(lla[0]), np.radians(lla[1]), lla[2], r0, C)
    assert_allclose(ned, geodetic.lla_to_ned(lla, origin), rtol=0, atol=1e-6)


def test_range_jacobian_matches_finite_differences():
    rng = np.random.default_rng(3)
    for _ in range(20):
        p = rng.uniform(-20, 20, 3)
        a = rng.uniform(-20, 20, 3)
        lag = 0.01
        H = np.zeros((1, 15))
        range_jacobian(p, a, lag, H, 0)
        fd = np.empty(3)
        for j in range(3):
            e = np.zeros(3)
            e[j] = 1e-6
            # residual = h(p) - z: d residual / dp = dh/dp
            fd[j] = (range_residual(p + e, a, 10.0, 0.0, 0.0) - range_residual(p - e, a, 10.0, 0.0, 0.0)) / 2e-6
        assert_allclose(H[0, :3], fd, rtol=0, atol=1e-8)  # central difference, h = 1e-6 m: error ~ h^2/rho + 1e-10 rounding
        assert_allclose(H[0, 3:6], -lag * fd, rtol=0, atol=1e-10)  # the node moved back by v lag
        # the biases enter with unit weight (last column of H_t, Eq. 24)
        assert_allclose(range_residual(p, a, 10.0, 0.3, 0.1) - range_residual(p, a, 10.0, 0.0, 0.0), 0.4, atol=1e-12)


def _events(kind, z, R, dim, par=0, float_row=False):
    return EventArrays(np.array([1]), np.array([0.0]), np.array([int(kind)]), np.array([dim]), np.array([z], float),
                       np.array([R], float), np.array([True]), np.array([0]), np.array([par]), np.ones(1),
                       np.array([float_row]), np.array([False]))


def test_measure_adds_the_extra_states_columns():
    nav, C = _nominal()
    aid = Aiding(np.array([0.5, -0.3, -1.2]), np.zeros(3), np.array([[10.0, 5.0, -2.0], [0.0, 30.0, -2.0]]),
                 geodetic.lla_to_ecef(np.array([48.0, 8.0, 480.0])), geodetic.ecef_to_ned_dcm(48.0, 8.0),
                 np.zeros((1, 2, 3)), np.eye(3), 1.0)
    # GPS error states: the fix's estimated error is subtracted from it, column 1 at the block
    lay = StateLayout((gps_error_block([0.5, 0.5, 1.0], 30.0),))
    bias = np.array([0, 0, 0, 0, 0, 0, 0.2, -0.1, 0.3])
    fix = np.array([nav[0] + 1e-6, nav[1] - 2e-6, nav[2] + 0.7])
    z, H, R = np.empty(3), np.zeros((3, 18)), np.zeros((3, 3))
    measure(0, _events(Kind.GPS_POSITION, fix, np.eye(3), 3), aid, None, nav, C, bias, np.zeros(3), np.zeros(3), np.zeros(3),
            lay.offsets(), _no_P(H), z, H, R)
    z0 = np.empty(3)
    gps_position_residual(nav, C, aid.lever_b, fix, 0.0, z0)
    assert_allclose(z - z0, bias[6:9], atol=0)
    assert_allclose(H[:, 15:18], np.eye(3), atol=0)
    # a range: eps_d and the anchor's calibration bias, each with unit weight
    lay = StateLayout(ranging_blocks(0.05, 1e-6, 0.02, np.eye(2) * 1e-4))
    bias = np.zeros(6 + lay.n_extra)
    bias[6 + lay.offset(Block.RANGE_BIAS) - 15] = 0.3
    bias[6 + lay.offset(Block.CALIBRATION) - 15 + 1] = -0.1
    z, H, R = np.empty(1), np.zeros((1, lay.n_states)), np.zeros((1, 1))
    measure(0, _events(Kind.RANGE, [25.0, 0, 0], np.eye(3) * 0.01, 1, par=1), aid, True, nav, C, bias, np.zeros(3),
            np.zeros(3), np.zeros(3), lay.offsets(), _no_P(H), z, H, R)
    p = lla_to_local_ned(nav[0], nav[1], nav[2], aid.r0_e, aid.C_ne0)
    assert_allclose(z[0], np.linalg.norm(p - aid.anchors_ned[1]) + 0.3 - 0.1 - 25.0, atol=1e-9)
    assert H[0, lay.offset(Block.RANGE_BIAS)] == 1.0 and H[0, lay.offset(Block.CALIBRATION) + 1] == 1.0
    assert H[0, lay.offset(Block.CALIBRATION)] == 0.0 and R[0, 0] == 0.01



def test_float_offset_columns_only_on_float_rows():
    """An RTK float epoch's fix = truth + b_float + white (`fusion.rtk_float`): its position row sees the float
    offset state with unit weight and its estimate subtracted from the fix; a fixed epoch's row does not."""
    nav, C = _nominal()
    aid = Aiding(np.zeros(3), np.zeros(3), np.zeros((2, 3)), geodetic.lla_to_ecef(np.array([48.0, 8.0, 480.0])),
                 geodetic.ecef_to_ned_dcm(48.0, 8.0), np.zeros((1, 2, 3)), np.eye(3), 1.0)
    lay = StateLayout((float_offset_block(0.15, 0.25, 5.0),))
    o = lay.offset(Block.FLOAT)
    bias = np.r_[np.zeros(6), 0.12, -0.05, 0.2]
    fix = np.array([nav[0] + 1e-6, nav[1] - 2e-6, nav[2] + 0.7])
    z0 = np.empty(3)
    gps_position_residual(nav, C, aid.lever_b, fix, 0.0, z0)
    for is_float in (True, False):
        z, H, R = np.empty(3), np.zeros((3, lay.n_states)), np.zeros((3, 3))
        measure(0, _events(Kind.GPS_POSITION, fix, np.eye(3), 3, float_row=is_float), aid, None, nav, C, bias, np.zeros(3),
                np.zeros(3), np.zeros(3), lay.offsets(), _no_P(H), z, H, R)
        assert_allclose(z - z0, bias[6:9] if is_float else 0.0, atol=0)
        assert_allclose(H[:, o:o + 3], np.eye(3) if is_float else 0.0, atol=0)


def test_clock_offset_columns():
    """A position stamped t taken at IMU time t + d: its rows see the displacement over d, v d +
    a d^2 / 2 (a: the mean acceleration over that window), with the column v + a d (the velocity at
    t + d); a velocity taken at t + d_vel: the acceleration times d_vel, column a; each a column of
    H at its clock state; the states are time-odd, so a backward run flips them (issue 11)."""
    nav, C = _nominal()
    aid = Aiding(np.zeros(3), np.zeros(3), np.zeros((2, 3)), geodetic.lla_to_ecef(np.array([48.0, 8.0, 480.0])),
                 geodetic.ecef_to_ned_dcm(48.0, 8.0), np.zeros((1, 2, 3)), np.eye(3), 1.0)
    lay = StateLayout((clock_block(0.2),))
    o = lay.offset(Block.CLOCK)
    d, d_vel = 0.15, -0.05
    bias = np.array([0, 0, 0, 0, 0, 0, d, d_vel])
    acc = np.array([1.5, -0.5, 0.2])
    fix = np.array([nav[0] + 1e-6, nav[1] - 2e-6, nav[2] + 0.7])
    z, H, R = np.empty(3), np.zeros((3, lay.n_states)), np.zeros((3, 3))
    measure(0, _events(Kind.GPS_POSITION, fix, np.eye(3), 3), aid, None, nav, C, bias, np.zeros(3), acc, np.zeros(3),
            lay.offsets(), _no_P(H), z, H, R)
    z0 = np.empty(3)
    gps_position_residual(nav, C, aid.lever_b, fix, 0.0, z0)
    assert_allclose(z - z0, nav[3:6] * d + 0.5 * acc * d**2, atol=1e-12)
    assert_allclose(H[:, o], nav[3:6] + acc * d, atol=1e-15)
    assert_allclose(H[:, o + 1], 0.0, atol=0)
    v_gps = nav[3:6] + np.array([0.1, 0.2, -0.1])
    measure(0, _events(Kind.GPS_VELOCITY, v_gps, np.eye(3), 3), aid, None, nav, C, bias, np.zeros(3), acc, np.zeros(3),
            lay.offsets(), _no_P(H), z, H, R)
    assert_allclose(z, nav[3:6] - v_gps + acc * d_vel, atol=1e-12)
    assert_allclose(H[:, o + 1], acc, atol=0)
    assert_allclose(H[:, o], 0.0, atol=0)
    # the INS velocity's vibration about its trend (`nav_errors.window_vibration_velocity_b`) is taken out;
    # H does not change
    vib, H0 = np.array([0.002, -0.001, 0.0005]), H.copy()
    measure(0, _events(Kind.GPS_VELOCITY, v_gps, np.eye(3), 3), aid, None, nav, C, bias, np.zeros(3), acc, vib,
            lay.offsets(), _no_P(H), z, H, R)
    assert_allclose(z, nav[3:6] - vib - v_gps + acc * d_vel, atol=1e-12)
    assert_allclose(H, H0, atol=0)
    sign = backward_sign(lay.n_states, lay)
    assert sign[o] == sign[o + 1] == -1.0 and sign[3] == -1.0 and sign[0] == 1.0
    # with a lever arm the fix is the antenna's: it moves on by the antenna's velocity v + C (w x l)
    lever, w_b = np.array([0.8, 0.5, -1.0]), np.radians([1.0, -2.0, 17.0])
    aid_l = aid._replace(lever_b=lever)
    measure(0, _events(Kind.GPS_POSITION, fix, np.eye(3), 3), aid_l, None, nav, C, bias, w_b, acc, np.zeros(3), lay.offsets(), _no_P(H),
            z, H, R)
    assert_allclose(H[:, o], nav[3:6] + C @ np.cross(w_b, lever) + acc * d, atol=1e-12)


def test_lever_arm_columns_are_the_residuals_exact_change():
    """The lever-arm correction (vehicle forward, right; `layout.lever_arm_block`) enters the GPS
    residuals linearly: with the nominal correction dl, z equals the residual of the lever arm
    l + C_vb^T (dl, 0) (to rounding), and H's columns are that change per metre of dl; a constant,
    so a backward run keeps its sign (issue 11)."""
    nav, C = _nominal()
    C_vb = euler_to_dcm(*np.radians([1.0, -2.0, 91.0]))  # an IMU turned 91 deg on the vehicle
    lever = np.array([0.5, -0.3, -1.2])
    aid = Aiding(lever, np.zeros(3), np.zeros((2, 3)), geodetic.lla_to_ecef(np.array([48.0, 8.0, 480.0])),
                 geodetic.ecef_to_ned_dcm(48.0, 8.0), np.zeros((1, 2, 3)), C_vb, 1.0)
    lay = StateLayout((lever_arm_block(0.3),))
    o = lay.offset(Block.LEVER)
    dl = np.array([0.4, -0.25])
    bias = np.concatenate([np.zeros(6), dl])
    lever_true = lever + C_vb.T @ np.array([dl[0], dl[1], 0.0])
    w_b = np.radians([2.0, -1.0, 20.0])
    fix = np.array([nav[0] + 1e-6, nav[1] - 2e-6, nav[2] + 0.7])
    v_gps = nav[3:6] + np.array([0.1, 0.2, -0.1])
    for kind, zin, resid in ((Kind.GPS_POSITION, fix, lambda lv, out: gps_position_residual(nav, C, lv, fix, 0.0, out)),
                             (Kind.GPS_VELOCITY, v_gps, lambda lv, out: gps_velocity_residual(nav, C, lv, w_b, v_gps, out))):
        z, H, R = np.empty(3), np.zeros((3, lay.n_states)), np.zeros((3, 3))
        measure(0, _events(kind, zin, np.eye(3), 3), aid, None, nav, C, bias, w_b, np.zeros(3), np.zeros(3),
                lay.offsets(), _no_P(H), z, H, R)
        z_true, z0 = np.empty(3), np.empty(3)
        resid(lever_true, z_true)
        resid(lever, z0)
        assert_allclose(z, z_true, rtol=0, atol=1e-9)
        assert_allclose(H[:, o:o + 2] @ dl, z_true - z0, rtol=0, atol=1e-9)
    assert backward_sign(lay.n_states, lay)[o] == backward_sign(lay.n_states, lay)[o + 1] == 1.0
    # the second-order term: yaw SD 0.2 rad, correction SDs 0.5 / 0.3 m: R gains P_yaw (A P_ll A^T)
    # on north from the east row and on east from the north row (A: H's lever columns)
    P = np.zeros((lay.n_states, lay.n_states))
    P[8, 8] = 0.2**2
    P[o:o + 2, o:o + 2] = np.diag([0.5**2, 0.3**2])
    z, H, R = np.empty(3), np.zeros((3, lay.n_states)), np.zeros((3, 3))
    measure(0, _events(Kind.GPS_POSITION, fix, np.eye(3), 3), aid, None, nav, C, bias, w_b, np.zeros(3), np.zeros(3),
            lay.offsets(), P, z, H, R)
    A = H[:, o:o + 2]
    V = A @ P[o:o + 2, o:o + 2] @ A.T
    assert_allclose(np.diag(R), [1.0 + 0.04 * V[1, 1], 1.0 + 0.04 * V[0, 0], 1.0], rtol=1e-12)
    assert R[0, 1] == R[1, 0] == 0.0


def test_gps_jacobians_against_perturbation():
    nav, C = _nominal()
    lever = np.array([0.5, -0.3, -1.2])
    w_b = np.radians([2.0, -1.0, 20.0])
    lag = 0.004
    fix = np.array([nav[0] + 1e-6, nav[1] - 2e-6, nav[2] + 0.7])
    v_gps = nav[3:6] + np.array([0.1, 0.2, -0.1])
    dx = np.concatenate([[0.3, -0.2, 0.1], [0.05, 0.02, -0.03], [2e-3, -1e-3, 3e-3], [0, 0, 0], [1e-3, 2e-3, -1e-3]])
    nav_t, C_t, b_t = nav.copy(), C.copy(), np.zeros(6)
    apply_feedback(nav_t, C_t, b_t, dx, np.empty((3, 3)))
    z_e, z_t = np.empty(3), np.empty(3)
    gps_position_residual(nav, C, lever, fix, lag, z_e)
    gps_position_residual(nav_t, C_t, lever, fix, lag, z_t)
    H = np.zeros((6, 15))
    gps_position_jacobian(nav, C, lever, lag, H, 0)
    np.testing.assert_allclose(z_e - z_t, H[:3] @ dx, rtol=0, atol=1e-5)  # quadratic: |phi|^2 |l| ~ 1e-5
    v_e, v_t = np.empty(3), np.empty(3)
    gps_velocity_residual(nav, C, lever, w_b, v_gps, v_e)
    gps_velocity_residual(nav_t, C_t, lever, w_b + dx[12:], v_gps, v_t)  # truth rate = est rate + dbg
    gps_velocity_jacobian(C, lever, w_b, H, 3)
    # quadratic: |phi| |dbg| |l| = 4e-3 * 2.4e-3 * 1.4 ~ 1.3e-5
    np.testing.assert_allclose(v_e - v_t, H[3:] @ dx, rtol=0, atol=3e-5)


def test_nhc_and_zaru_jacobians_against_perturbation():
    """NHC: rows 1, 2 of C_vb C^T v; ZARU: the gyro-bias error with unit weight (issue 11)."""
    nav, C = _nominal()
    C_vb = euler_to_dcm(*np.radians([0.5, -3.0, 4.0]))
    dx = np.concatenate([[0.3, -0.2, 0.1], [0.05, 0.02, -0.03], [2e-3, -1e-3, 3e-3], [0, 0, 0], [1e-3, 2e-3, -1e-3]])
    nav_t, C_t, b_t = nav.copy(), C.copy(), np.zeros(6)
    apply_feedback(nav_t, C_t, b_t, dx, np.empty((3, 3)))
    z_e, z_t = np.empty(2), np.empty(2)
    nhc_residual(nav, C, C_vb, z_e)
    nhc_residual(nav_t, C_t, C_vb, z_t)
    H = np.zeros((2, 15))
    nhc_jacobian(nav, C, C_vb, H)
    # quadratic: |phi| |dv| + |phi|^2 |v| = 4e-3 * 0.06 + 1.4e-5 * 14 ~ 4e-4
    np.testing.assert_allclose(z_e - z_t, H @ dx, rtol=0, atol=5e-4)
    # the body velocity of the nominal is along the vehicle's x axis when C_vb says so
    v_b = C.T @ nav[3:6]
    yaw = np.arctan2(v_b[1], v_b[0])
    pitch = -np.arctan2(v_b[2], np.hypot(v_b[0], v_b[1]))
    nhc_residual(nav, C, euler_to_dcm(0.0, pitch, yaw).T, z_e)
    np.testing.assert_allclose(z_e, 0.0, atol=1e-12)
    # ZARU: standing gyro = bias + Earth rate; the residual moves with the bias error one to one
    bias = np.array([0, 0, 0, 1e-3, -2e-3, 5e-4])
    w_ie_b = C.T @ np.array([7.292115e-5 * np.cos(nav[0]), 0.0, -7.292115e-5 * np.sin(nav[0])])
    z = np.empty(3)
    zaru_residual(nav, C, bias, 1.0, bias[3:] + w_ie_b, z)
    np.testing.assert_allclose(z, 0.0, atol=1e-12)
    zaru_residual(nav, C, bias + np.r_[0, 0, 0, dx[12:]], 1.0, bias[3:] + w_ie_b, z)
    Hz = np.zeros((3, 15))
    zaru_jacobian(Hz)
    np.testing.assert_allclose(z, Hz @ dx, atol=1e-15)


def test_odometer_jacobian_against_perturbation():
    """Odometer: (1 + k) x the vehicle's forward velocity; the scale error's column is that velocity."""
    nav, C = _nominal()
    C_vb = euler_to_dcm(*np.radians([0.5, -3.0, 4.0]))
    dx = np.concatenate([[0.3, -0.2, 0.1], [0.05, 0.02, -0.03], [2e-3, -1e-3, 3e-3], [0, 0, 0], [0, 0, 0]])
    nav_t, C_t, b_t = nav.copy(), C.copy(), np.zeros(6)
    apply_feedback(nav_t, C_t, b_t, dx, np.empty((3, 3)))
    k_est, dk = 0.02, 0.004
    H = np.zeros((1, 15))
    odometer_jacobian(nav, C, C_vb, k_est, H)
    v_fwd = (C_vb @ (C.T @ nav[3:6]))[0]
    z_e = odometer_residual(nav, C, C_vb, k_est, 10.0)
    z_t = odometer_residual(nav_t, C_t, C_vb, k_est - dk, 10.0)
    # quadratic: |phi| |dv| + |phi|^2 |v| + dk |dv| ~ 4e-4
    np.testing.assert_allclose(z_e - z_t, H[0] @ dx + v_fwd * dk, rtol=0, atol=5e-4)
