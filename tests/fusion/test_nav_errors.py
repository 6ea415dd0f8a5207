"""15-state error model against nonlinear perturbation of the kernels."""

import numpy as np
from scipy.linalg import expm

from tpos_cli.frames.earth import G0_MPS2
from tpos_cli.frames.rotation import euler_to_dcm
from tpos_cli.fusion.nav_errors import (
    CLOCK_ACCELERATION_WINDOW_S,
    VIBRATION_WINDOW_S,
    apply_feedback,
    error_dynamics,
    vibration_velocities_b,
    vibration_velocity_cov_b,
    window_acceleration_ned,
    window_rate_b,
    window_vibration_velocity_b,
)
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


def _line(t, f_hz, amp, phase):
    """Rows of a sine line as the IMU gives it: the mean of amp sin(2 pi f t + phase) over (t_{j-1}, t_j]."""
    dt = t[1] - t[0]
    return amp * (np.cos(2 * np.pi * f_hz * (t - dt) + phase) - np.cos(2 * np.pi * f_hz * t + phase)) / (2 * np.pi * f_hz * dt)


def test_clock_column_acceleration_is_the_window_mean_not_one_vibrating_sample():
    """A car braking at 2 m/s^2 along its x axis (heading 30 deg, level) under a 0.3 m/s^2 engine
    line, IMU at 100 Hz: the Hann-weighted window (d = 0.08 s, widened to 1 s) passes at most 3 %
    of a line at 2-45 Hz whatever its phase (one sample: all of it; a plain 0.1 s mean: 14 % of a
    25 Hz line, in the same phase at every whole-second fix; the 0.2 s window of the lever-arm rate
    terms: 94 % of a 2 Hz body bounce, which attenuates the clock estimate as noise in its
    regressor); it is exact for the braking alone, a
    braking that changes linearly keeps its mean at the window's middle, and the bias is taken
    out. Also a negative offset and the log's end (window clamped)."""
    t = np.arange(2001) * 0.01
    C = euler_to_dcm(0.0, 0.0, np.radians(30.0))
    bias = np.array([0.05, -0.02, 0.01, 0.0, 0.0, 0.0])
    brake = np.array([-2.0, 0.0, -G0_MPS2])  # specific force of the braking car, body axes
    want = C @ brake + [0.0, 0.0, G0_MPS2]
    out = np.empty(3)
    acc = np.tile(brake + bias[:3], (t.size, 1))
    for k, d in ((500, 0.08), (733, -0.08), (1000, 0.0), (2000, 0.08), (1200, 0.5)):
        window_acceleration_ned(t, acc, k, C, bias, d, out)
        np.testing.assert_allclose(out, want, atol=1e-9)
    ramp = acc.copy()
    ramp[:, 0] += 0.8 * (t - 0.005)  # the braking changes at 0.8 m/s^3 (row j: the mean at t_j - dt / 2)
    window_acceleration_ned(t, ramp, 900, C, bias, 0.08, out)
    np.testing.assert_allclose(out, C @ (brake + [0.8 * (t[900] + 0.04), 0.0, 0.0]) + [0.0, 0.0, G0_MPS2], atol=1e-9)
    assert VIBRATION_WINDOW_S == 0.2 and CLOCK_ACCELERATION_WINDOW_S == 1.0
    for f_hz in (2.0, 2.6, 3.3, 5.0, 10.0, 12.5, 17.0, 25.0, 33.3, 45.0):
        worst = 0.0
        for phase in (0.0, 0.7, 2.1, 4.0):
            shaken = acc.copy()
            shaken[:, 0] += _line(t, f_hz, 0.3, phase)
            for k in range(100, 1900, 100):
                window_acceleration_ned(t, shaken, k, C, bias, 0.08, out)
                worst = max(worst, float(np.linalg.norm(out - want)))
        assert worst <= 0.03 * 0.3, f_hz


def test_lever_arm_rate_is_the_window_mean_not_one_vibrating_sample():
    """The GPS rows' body rate: a car turning at 0.3 rad/s with a gyro bias and a 0.3 deg/s gyro line
    (what 30 mg of engine vibration makes of the simulated real car's gyros) at 25 Hz: at the
    whole-second fix samples one sample reads the line in the same phase every time (up to 5 mrad/s,
    4.9 mm/s on a 0.94 m lever arm, every fix); the window passes at most 3 % of it, and a turn rate
    that changes linearly keeps its value at t_k."""
    t = np.arange(3001) * 0.01
    bias = np.array([0.0, 0.0, 0.0, 1e-3, -2e-3, 5e-4])
    rate = np.array([0.0, 0.0, 0.3]) + 0.05 * (t[:, None] - 0.005) * np.array([0.0, 0.0, 1.0])  # row j: the mean at t_j - dt / 2
    gyro = rate + bias[3:]
    out = np.empty(3)
    window_rate_b(t, gyro, 1500, bias, out)
    np.testing.assert_allclose(out, [0.0, 0.0, 0.3 + 0.05 * t[1500]], atol=1e-12)
    amp = np.radians(0.3)
    shaken = gyro.copy()
    shaken[:, 2] += _line(t, 25.0, amp, 2.36)  # its peak at the fix samples
    fixes = np.arange(100, 2900, 100)
    one = shaken[fixes, 2] - bias[5] - (0.3 + 0.05 * (t[fixes] - 0.005))
    assert np.ptp(one) < 1e-12 and abs(one[0]) > 0.8 * amp  # the same phase at every fix
    for k in fixes:
        window_rate_b(t, shaken, k, bias, out)
        assert abs(out[2] - (0.3 + 0.05 * t[k])) <= 0.03 * amp


def test_vibration_velocity_is_what_the_line_adds_to_the_ins_velocity():
    """The IMU's velocity about the trend of its motion: a car braking with a jerk of 1 m/s^3 plus a
    0.3 m/s^2 line at 25 Hz (its velocity 1.9 mm/s at most): the window finds the line's velocity at
    the sample within 10 % of its amplitude, and nothing for the braking alone (the quadratic in u
    holds gravity, bias, acceleration and jerk)."""
    t = np.arange(3001) * 0.01
    acc = np.zeros((t.size, 3))
    acc[:, 0] = -2.0 + 1.0 * (t - 0.005)
    acc[:, 2] = -G0_MPS2 + 0.02
    out = np.empty(3)
    window_vibration_velocity_b(t, acc, 1500, out)
    np.testing.assert_allclose(out, 0.0, atol=1e-9)
    amp = 0.3 / (2 * np.pi * 25.0)
    for phase in (0.0, 1.1, 2.5, 4.4):
        shaken = acc.copy()
        shaken[:, 1] += _line(t, 25.0, 0.3, phase)
        for k in range(200, 2800, 300):
            window_vibration_velocity_b(t, shaken, k, out)
            assert abs(out[1] - (-amp * np.cos(2 * np.pi * 25.0 * t[k] + phase))) <= 0.1 * amp
            assert abs(out[0]) < 1e-9 and abs(out[2]) < 1e-9


def test_vibration_velocity_covariance_is_the_lines_velocity_variance():
    """The vibration an INS velocity carries, as a covariance: a braking car (jerk 1 m/s^3) shaken by
    a 0.3 m/s^2 line at 25 Hz on the right axis only: variance (0.3 / (2 pi 25))^2 / 2 on that axis
    within 5 %, nothing elsewhere; the braking alone gives nothing (a consider variance that stays 0
    on an IMU that does not shake); per sample, the line's velocity within 10 % of its amplitude
    (`window_vibration_velocity_b`'s test) away from the log's first and last half window."""
    t = np.arange(6001) * 0.01
    acc = np.zeros((t.size, 3))
    acc[:, 0] = -2.0 + 1.0 * (t - 0.005)
    acc[:, 2] = -G0_MPS2 + 0.02
    idx = np.arange(100, 5900, 10)
    np.testing.assert_allclose(vibration_velocity_cov_b(t, acc, idx), 0.0, atol=1e-16)
    shaken = acc.copy()
    shaken[:, 1] += _line(t, 25.0, 0.3, 0.7)
    S = vibration_velocity_cov_b(t, shaken, idx)
    amp = 0.3 / (2 * np.pi * 25.0)
    u = vibration_velocities_b(t, shaken)
    np.testing.assert_allclose(u[idx, 1], -amp * np.cos(2 * np.pi * 25.0 * t[idx] + 0.7), atol=0.1 * amp)
    var = 0.5 * (0.3 / (2 * np.pi * 25.0)) ** 2
    np.testing.assert_allclose(S[:, 1, 1], var, rtol=0.05)
    S[:, 1, 1] = 0.0
    np.testing.assert_allclose(S, 0.0, atol=1e-3 * var)
