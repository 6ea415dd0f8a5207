"""15-state error model against nonlinear perturbation of the kernels."""

import numpy as np
from scipy.linalg import expm

from tpos_cli.frames.earth import G0_MPS2
from tpos_cli.frames.rotation import euler_to_dcm
from tpos_cli.fusion.nav_errors import CLOCK_ACC_WINDOW_S, apply_feedback, error_dynamics, window_acceleration_ned
from tpos_cli.ins._kernels import mech_step
from tpos_cli.smoothing import state_difference


def _nominal():
    nav = np.array([np.radians(48.0), np.radians(8.0), 500.0, 12.0, -7.0, 0.3])
    C = euler_to_dcm(*np.radians([3.0, -2.0, 130.0]))
    return nav, C


def _propagate(nav, C, f_b, w_b, bias, T, dt, earth_sign=1.0):
    nav, C = nav.copy(), C.copy()
    f_n = np.empty(3)
    dth_p, dv_p = np.zeros(3), np.zeros(3)
    for _ in range(int(round(T / dt))):
        dth = (w_b - bias[3:]) * dt
        dv = (f_b - bias[:3]) * dt
        mech_step(nav, C, dth, dv, dth_p, dv_p, dt, earth_sign, f_n)
        dth_p, dv_p = dth, dv
    return nav, C, f_n


def test_error_dynamics_against_nonlinear_propagation():
    nav, C = _nominal()
    f_b = np.array([0.8, 1.5, -9.6])  # accelerating and turning
    w_b = np.radians([1.0, -2.0, 8.0])
    dx0 = np.concatenate([[1.0, -2.0, 1.5], [0.1, -0.05, 0.08], [1e-3, -2e-3, 3e-3],
                          [0.02, -0.03, 0.01], np.radians([0.01, -0.02, 0.015])])
    # truth = nominal corrected by dx0; the nominal's biases are off by dx0's bias part
    nav_t, C_t, bias_t = nav.copy(), C.copy(), np.zeros(6)
    apply_feedback(nav_t, C_t, bias_t, dx0, np.empty((3, 3)))
    bias_true = bias_t  # sensors carry b_true = -dx0 bias part; the nominal assumes zero: db = 0 - b_true
    T, dt = 1.0, 0.01
    n_e, C_e, f_n = _propagate(nav, C, f_b + bias_true[:3], w_b + bias_true[3:], np.zeros(6), T, dt)
    n_t, C_tt, _ = _propagate(nav_t, C_t, f_b, w_b, np.zeros(6), T, dt)
    d = np.empty(15)
    state_difference(n_e, C_e, np.zeros(6), n_t, C_tt, bias_true, d)
    F = np.zeros((15, 15))
    # F at mid-interval: the model is linearized along the trajectory
    n_m, C_m, f_m = _propagate(nav, C, f_b + bias_true[:3], w_b + bias_true[3:], np.zeros(6), T / 2, dt)
    error_dynamics(n_m, C_m, f_m, 1.0, 0.0, 0.0, F)
    pred = expm(F * T) @ dx0
    # tolerance: second-order terms |phi| |f| T^2 ~ 3e-3 * 10 * 0.5 -> 1e-4 relative; 1 % of each
    # component's size plus the quadratic floor
    np.testing.assert_allclose(d[:9], pred[:9], rtol=0.01, atol=2e-3 * np.abs(pred[:9]).max() + 1e-6)
    # without the attitude and bias terms the prediction is clearly worse (the test has power)
    F0 = F.copy()
    F0[3:6, 6:9] = 0.0
    assert np.abs(expm(F0 * T) @ dx0 - d)[:6].max() > 10 * np.abs(pred - d)[:6].max()


def test_clock_column_acceleration_is_the_window_mean_not_one_vibrating_sample():
    """A car braking at 2 m/s^2 along its x axis (heading 30 deg, level) under a 25 Hz, 0.3 m/s^2
    engine line, IMU at 100 Hz: over the clock offset's window (d = 0.08 s, widened to 0.1 s:
    10 samples, 2.5 cycles) the line leaves two samples a quarter cycle apart, at most sqrt(2) A
    / 10 = 0.042 m/s^2 whatever the sample, while one sample is off by up to 0.3 m/s^2; the mean is exact for the braking alone, and
    the bias is taken out. Also a negative offset and the log's end (window clamped)."""
    t = np.arange(2001) * 0.01
    C = euler_to_dcm(0.0, 0.0, np.radians(30.0))
    bias = np.array([0.05, -0.02, 0.01, 0.0, 0.0, 0.0])
    brake = np.array([-2.0, 0.0, -G0_MPS2])  # specific force of the braking car, body axes
    want = C @ brake + [0.0, 0.0, G0_MPS2]
    out = np.empty(3)
    acc = np.tile(brake + bias[:3], (t.size, 1))
    for k, d in ((500, 0.08), (733, -0.08), (1000, 0.0), (2000, 0.08)):
        window_acceleration_ned(t, acc, k, C, bias, d, out)
        np.testing.assert_allclose(out, want, atol=1e-9)
    acc[:, 0] += 0.3 * np.sin(2 * np.pi * 25.0 * t + 0.7)
    worst = 0.0
    for k in range(100, 1900, 7):
        window_acceleration_ned(t, acc, k, C, bias, 0.08, out)
        worst = max(worst, float(np.linalg.norm(out - want)))
    assert CLOCK_ACC_WINDOW_S == 0.1 and worst <= np.sqrt(2.0) * 0.3 / 10 + 1e-9
