"""The exact strapdown inverse: oracles are closed forms (static, pole), an ECEF derivation of the
specific force, and an independent RK4 integration of the continuous navigation equations."""

import numpy as np
from numpy.testing import assert_allclose

from tpos_cli.frames import earth
from tpos_cli.frames.geodetic import ecef_to_ned_dcm, lla_to_ecef
from tpos_cli.frames.rotation import euler_to_dcm
from tpos_cli.sim.drive import drive_motion
from tpos_cli.sim.kinematics import MotionSample, continuous_imu, simulate_truth_imu
from tpos_cli.sim.profiles import RampProfile
from tpos_cli.sim.target import AimMotion

LLA0 = np.array([48.05, 8.21, 870.0])


def _static_motion(roll, pitch, yaw):
    def motion(t):
        z = np.zeros(np.shape(t) + (3,))
        rpy = np.broadcast_to(np.array([roll, pitch, yaw]), z.shape).copy()
        return MotionSample(z, z.copy(), rpy, z.copy())

    return motion


def test_static_imu_is_minus_gravity_and_earth_rate_in_body():
    rpy = (0.1, -0.2, 2.0)
    t = np.arange(200) / 100.0
    ti = simulate_truth_imu(_static_motion(*rpy), t, LLA0)
    C_bn = euler_to_dcm(*rpy).T
    lat = np.radians(LLA0[0])
    g = earth.normal_gravity_mps2(lat, LLA0[2])
    # a static body senses exactly -g and the Earth rate: rounding only
    assert_allclose(ti.acc_b_mps2, np.tile(C_bn @ [0.0, 0.0, -g], (200, 1)), atol=1e-12)
    assert_allclose(ti.gyro_b_rps, np.tile(C_bn @ earth.earth_rate_ned_rps(lat), (200, 1)), atol=1e-17)
    assert_allclose(ti.lla, np.tile(LLA0, (200, 1)), atol=1e-12)


def test_sample_is_the_mean_rate_over_the_preceding_interval():
    """Yaw-only rotation near the pole: w_ib_z = dyaw/dt - Omega sin(lat) independent of yaw, so the
    mean over (t_{k-1}, t_k] is (yaw_k - yaw_{k-1})/dt - Omega sin(lat) in closed form."""
    yaw = RampProfile.from_ramps(0.3, [(0.05, 0.5, 2.0)])
    motion = AimMotion(yaw, RampProfile.from_ramps(0.0, []))
    t = np.arange(100) / 100.0
    lla0 = np.array([89.9999, 0.0, 0.0])
    ti = simulate_truth_imu(motion, t, lla0)
    y = yaw.eval(np.concatenate([[t[0] - 0.01], t]))[0]
    expect = np.diff(y) / 0.01 - earth.OMEGA_IE_RPS * np.sin(np.radians(lla0[0]))
    # the horizontal Earth rate at 89.9999 deg is 1.3e-10 rad/s and leaks into x/y only
    assert_allclose(ti.gyro_b_rps[:, 2], expect, atol=1e-13)
    assert np.abs(ti.gyro_b_rps[:, :2]).max() < 2e-10


def test_gauss_legendre_quadrature_has_converged():
    motion = drive_motion(60.0, 2.0, np.random.default_rng([5, 3]))
    t = np.arange(6001) / 100.0
    a = simulate_truth_imu(motion, t, LLA0, n_gauss=4)
    b = simulate_truth_imu(motion, t, LLA0, n_gauss=8)
    # 4 vs 8 nodes agree to rounding except on the few intervals straddling a ramp end, where a
    # higher derivative of the rates jumps (2e-11 rad/s measured there: 2e-13 rad per sample)
    assert_allclose(a.gyro_b_rps, b.gyro_b_rps, atol=1e-10)
    assert_allclose(a.acc_b_mps2, b.acc_b_mps2, atol=1e-9)
    assert (np.abs(a.gyro_b_rps - b.gyro_b_rps).max(axis=1) > 1e-14).sum() <= 6
    assert_allclose(a.lla[:, 2], b.lla[:, 2], atol=1e-9)


def test_velocity_is_the_derivative_of_position():
    motion = drive_motion(60.0, 2.0, np.random.default_rng([6, 3]))
    t = np.arange(6001) / 100.0
    ti = simulate_truth_imu(motion, t, LLA0)
    r = lla_to_ecef(ti.lla)
    v_e = (r[2:] - r[:-2]) / 0.02
    v_n = np.einsum("kij,kj->ki", ecef_to_ned_dcm(ti.lla[1:-1, 0], ti.lla[1:-1, 1]), v_e)
    # central difference: truncation h^2 |jerk| / 6 < 1e-4 m/s for jerk < 1.5 m/s^3; rounding 1e-9/0.02
    assert_allclose(v_n, ti.vel_ned_mps[1:-1], atol=2e-4)


def test_specific_force_matches_an_ecef_derivation():
    """f^b = C_bn C_ne (r_e'' + 2 Omega x r_e') - C_bn g^n (normal gravity includes the centrifugal
    term), with r_e'' from a 5-point difference of ECEF positions: independent of the NED
    Coriolis/transport-rate formulation used by the simulator."""
    motion = drive_motion(40.0, 2.0, np.random.default_rng([7, 3]))
    h = 0.05
    t = np.arange(0.0, 40.0, h / 2.0)  # fine grid: positions every h/2
    ti = simulate_truth_imu(motion, t, LLA0)
    r = lla_to_ecef(ti.lla)
    s = 2  # index step for h
    k = np.arange(2 * s, t.size - 2 * s)
    acc_e = (-r[k + 2 * s] + 16 * r[k + s] - 30 * r[k] + 16 * r[k - s] - r[k - 2 * s]) / (12 * h * h)
    vel_e = (r[k - 2 * s] - 8 * r[k - s] + 8 * r[k + s] - r[k + 2 * s]) / (12 * h)
    om = np.array([0.0, 0.0, earth.OMEGA_IE_RPS])
    C_ne = ecef_to_ned_dcm(ti.lla[k, 0], ti.lla[k, 1])
    lat = np.radians(ti.lla[k, 0])
    f_n = np.einsum("kij,kj->ki", C_ne, acc_e + 2 * np.cross(om, vel_e)) - earth.gravity_ned_mps2(lat, ti.lla[k, 2])
    m = motion(t[k])
    _, f_b = continuous_imu(lat, ti.lla[k, 2], m)
    C_nb = euler_to_dcm(m.rpy_rad[:, 0], m.rpy_rad[:, 1], m.rpy_rad[:, 2])
    # 5-point stencil: truncation h^4 |a''''| / 30 ~ 2e-5 for the sharpest manoeuvres, rounding
    # 5 * 1e-9 m / h^2 ~ 2e-6; Coriolis here is up to 3e-3 m/s^2, so the check has teeth
    assert_allclose(np.einsum("kij,kj->ki", C_nb, f_b), f_n, atol=5e-5)


def _qmul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def _q_to_dcm(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _nav_derivative(state, w_ib, f_b):
    lat, lon, h = state[:3]
    v = state[3:6]
    q = state[6:]
    C_nb = _q_to_dcm(q)
    rn = earth.meridian_radius_m(lat) + h
    re = earth.transverse_radius_m(lat) + h
    w_ie = earth.earth_rate_ned_rps(lat)
    w_en = np.array([v[1] / re, -v[0] / rn, -v[1] * np.tan(lat) / re])
    g = np.array([0.0, 0.0, earth.normal_gravity_mps2(lat, h)])
    dv = C_nb @ f_b - np.cross(2 * w_ie + w_en, v) + g
    w_nb = w_ib - C_nb.T @ (w_ie + w_en)
    dq = 0.5 * _qmul(q, np.array([0.0, *w_nb]))
    return np.concatenate([[v[0] / rn, v[1] / (re * np.cos(lat)), -v[2]], dv, dq])


def test_rk4_of_continuous_rates_returns_onto_the_truth_after_60_s():
    """Independent check of truth/IMU consistency: RK4 at 100 Hz of the continuous navigation
    equations driven by the simulator's instantaneous w_ib^b and f^b, over 60 s of driving."""
    motion = drive_motion(70.0, 2.0, np.random.default_rng([8, 3]))
    t = np.arange(0.0, 62.0 + 1e-9, 0.005)
    ti = simulate_truth_imu(motion, t, LLA0)
    w, f = continuous_imu(np.radians(ti.lla[:, 0]), ti.lla[:, 2], motion(t))
    from tpos_cli.frames.rotation import dcm_to_quat

    x = np.concatenate([np.radians(ti.lla[0, :2]), [ti.lla[0, 2]], ti.vel_ned_mps[0],
                        dcm_to_quat(euler_to_dcm(*ti.rpy_rad[0]))])
    dt = 0.01
    for k in range(0, t.size - 2, 2):
        k1 = _nav_derivative(x, w[k], f[k])
        k2 = _nav_derivative(x + 0.5 * dt * k1, w[k + 1], f[k + 1])
        k3 = _nav_derivative(x + 0.5 * dt * k2, w[k + 1], f[k + 1])
        k4 = _nav_derivative(x + dt * k3, w[k + 2], f[k + 2])
        x = x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    end = t.size - 1
    rn = earth.meridian_radius_m(x[0]) + x[2]
    re = earth.transverse_radius_m(x[0]) + x[2]
    dpos = np.array([(x[0] - np.radians(ti.lla[end, 0])) * rn,
                     (x[1] - np.radians(ti.lla[end, 1])) * re * np.cos(x[0]), x[2] - ti.lla[end, 2]])
    from tpos_cli.frames.rotation import dcm_to_rotvec

    att_err_deg = np.degrees(np.linalg.norm(dcm_to_rotvec(_q_to_dcm(x[6:]) @ euler_to_dcm(*ti.rpy_rad[end]).T)))
    # the budget is 0.05 m and 0.01 deg after 60 s; RK4 at 100 Hz errs ~3e-8 m here, so
    # 1e-4 m and 1e-5 deg catch any inconsistency far below that budget
    assert np.linalg.norm(dpos) < 1e-4
    assert att_err_deg < 1e-5
    assert np.abs(x[3:6] - ti.vel_ned_mps[end]).max() < 1e-5
