"""Strapdown mechanization against exact truth: stationary Earth, noise-free simulated drive, time reversal."""

import numpy as np
import pytest

from tpos_cli.frames.earth import earth_rate_ned_rps, normal_gravity_mps2
from tpos_cli.frames.geodetic import lla_to_ned
from tpos_cli.frames.rotation import dcm_to_rotvec, euler_to_dcm
from tpos_cli.ins import integrate, reverse_imu
from tpos_cli.sim.drive import simulate_drive

# Issue 4's drift bounds for noise-free simulated IMU after 60 s
DRIFT_POS_M = 0.05
DRIFT_ATT_DEG = 0.01


def _att_err_deg(C_a, C_b):
    return np.degrees(np.linalg.norm(dcm_to_rotvec(C_a @ np.transpose(C_b, (0, 2, 1))), axis=1))


def test_stationary_stays_put():
    lat_deg, h = 45.0, 100.0
    rpy = np.radians([2.0, -3.0, 60.0])
    C = euler_to_dcm(*rpy)
    n = 60001  # 10 min at 100 Hz
    t = np.arange(n) * 0.01
    w_b = C.T @ earth_rate_ned_rps(np.radians(lat_deg))
    f_b = C.T @ np.array([0.0, 0.0, -normal_gravity_mps2(np.radians(lat_deg), h)])
    tr = integrate(t, np.tile(w_b, (n, 1)), np.tile(f_b, (n, 1)), [lat_deg, 10.0, h], [0, 0, 0], np.degrees(rpy))
    ned = lla_to_ned(tr.lla, [lat_deg, 10.0, h])
    # exact inputs: only rounding and the unstable vertical channel remain, 1e-5 m is ~1e5 x rounding
    np.testing.assert_allclose(ned, 0.0, rtol=0, atol=1e-5)
    np.testing.assert_allclose(tr.vel_ned_mps, 0.0, rtol=0, atol=1e-7)
    np.testing.assert_allclose(tr.rpy_deg, np.tile(np.degrees(rpy), (n, 1)), rtol=0, atol=1e-8)


@pytest.fixture(scope="module")
def noise_free_drive():
    return simulate_drive(70.0, seed=1, noise_free=True, static_s=5.0, outages=())


def test_noise_free_drive_drift_forward(noise_free_drive):
    sim = noise_free_drive
    tr, imu = sim.truth, sim.imu
    i = int(np.searchsorted(imu.t_s, 60.0)) + 1
    ins = integrate(imu.t_s[:i], imu.gyro_b_rps[:i], imu.acc_b_mps2[:i], tr.lla[0], tr.vel_ned_mps[0], tr.rpy_deg[0])
    err = lla_to_ned(ins.lla, tr.lla[0]) - lla_to_ned(tr.lla[:i], tr.lla[0])
    assert np.linalg.norm(err, axis=1).max() < DRIFT_POS_M
    assert _att_err_deg(ins.C_nb, tr.C_nb[:i]).max() < DRIFT_ATT_DEG
    assert np.linalg.norm(tr.vel_ned_mps[:i], axis=1).max() > 10.0  # the drive really moves


def test_noise_free_drive_drift_backward(noise_free_drive):
    """The reversed-time run (paper 003's backward filter) from the truth at the end."""
    sim = noise_free_drive
    tr, imu = sim.truth, sim.imu
    j = int(np.searchsorted(imu.t_s, imu.t_s[-1] - 60.0))
    ins = integrate(imu.t_s[j:], imu.gyro_b_rps[j:], imu.acc_b_mps2[j:], tr.lla[-1], tr.vel_ned_mps[-1],
                    tr.rpy_deg[-1], backward=True)
    err = lla_to_ned(ins.lla, tr.lla[0]) - lla_to_ned(tr.lla[j:], tr.lla[0])
    assert np.linalg.norm(err, axis=1).max() < DRIFT_POS_M
    assert _att_err_deg(ins.C_nb, tr.C_nb[j:]).max() < DRIFT_ATT_DEG
    np.testing.assert_allclose(ins.vel_ned_mps, tr.vel_ned_mps[j:], rtol=0, atol=1e-3)  # 1 mm/s: drift bound / 60 s


def test_reverse_imu_pairs_intervals():
    t = np.array([0.0, 0.1, 0.3, 0.6])
    g = np.arange(12.0).reshape(4, 3)
    a = g + 100.0
    tau, gr, ar = reverse_imu(t, g, a)
    np.testing.assert_array_equal(tau, [-0.6, -0.3, -0.1, 0.0])
    # reversed row j covers (tau[j-1], tau[j]] = forward interval (t[N-1-j], t[N-j]] = forward row N-j
    np.testing.assert_array_equal(gr[1:], -g[[3, 2, 1]])
    np.testing.assert_array_equal(ar[1:], a[[3, 2, 1]])
    # into the caller's arrays (whatever they held): the same numbers
    out = (np.full(4, np.nan), np.full((4, 3), np.nan), np.full((4, 3), np.nan))
    into = reverse_imu(t, g, a, out=out)
    assert all(x is y for x, y in zip(into, out))
    for x, y in zip(into, (tau, gr, ar)):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(gr[0], 0.0)


def test_mech_step_with_the_callers_scratch_is_the_same_step():
    """`mech_step(..., work)`: a loop's scratch for the rotations gives the same numbers as without."""
    from tpos_cli.ins._kernels import mech_step

    out = []
    for work in (None, np.full((3, 3, 3), np.nan)):
        nav = np.array([0.7, 0.1, 120.0, 3.0, -2.0, 0.1])
        C = np.eye(3)
        prev = (np.zeros(3), np.zeros(3))
        f_n = np.empty(3)
        r = np.random.default_rng(2)
        for _ in range(20):
            dth, dv = r.standard_normal(3) * 1e-3, r.standard_normal(3) * 1e-1
            if work is None:
                mech_step(nav, C, dth, dv, prev[0], prev[1], 0.01, 1.0, f_n)
            else:
                mech_step(nav, C, dth, dv, prev[0], prev[1], 0.01, 1.0, f_n, work)
            prev = (dth, dv)
        out.append((nav, C, f_n))
    for a, b in zip(*out):
        np.testing.assert_array_equal(a, b)
