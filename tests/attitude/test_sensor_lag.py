"""Magnetometer delay behind the gyro (attitude.sensor_lag) against exactly simulated rotations."""

import numpy as np
import pytest

from tpos_cli.attitude.sensor_lag import advance, estimate_mag_lag
from tpos_cli.frames.rotation import dcm_to_rotvec, euler_to_dcm

RATE_HZ = 285.714
M_N_UT = np.array([18.0, 1.0, 46.0])  # a mid-latitude field (dip ~68 deg)


def _attitude(t):
    """Smooth hand-like rotation: yaw, pitch, roll sinusoids of 40-120 deg/s peak rate."""
    yaw = 1.2 * np.sin(2 * np.pi * 0.15 * t) + 0.4 * np.sin(2 * np.pi * 0.4 * t)
    pitch = 0.5 * np.sin(2 * np.pi * 0.23 * t + 0.3)
    roll = 0.6 * np.sin(2 * np.pi * 0.31 * t + 1.0)
    return euler_to_dcm(roll, pitch, yaw)


def _log(delay_s, noise_ut=0.0, seed=0, duration_s=60.0):
    dt = 1.0 / RATE_HZ
    t = np.arange(0.0, duration_s, dt)
    C = _attitude(t)
    gyro = np.zeros((t.size, 3))
    # interval-mean rate of row k: the rotation from t_{k-1} to t_k over dt (package IMU convention)
    gyro[1:] = dcm_to_rotvec(np.swapaxes(C[:-1], 1, 2) @ C[1:]) / dt
    Cd = _attitude(t - delay_s)
    mag = np.einsum("nji,j->ni", Cd, M_N_UT)
    mag += np.random.default_rng(seed).normal(0.0, noise_ut, mag.shape)
    return t, gyro, mag


@pytest.mark.parametrize("delay_s", [0.004, 0.012, -0.008])
def test_recovers_a_known_delay(delay_s):
    t, gyro, mag = _log(delay_s, noise_ut=0.3)
    lag = estimate_mag_lag(t, gyro, mag)
    assert lag.reason == ""
    # 0.3 ms: a tenth of the 3.5 ms sample interval (the estimate interpolates between samples)
    assert lag.lag_s == pytest.approx(delay_s, abs=3e-4)
    assert lag.rms_uts < lag.rms_zero_uts


def test_no_delay_keeps_the_samples():
    t, gyro, mag = _log(0.0, noise_ut=0.3, seed=3)
    lag = estimate_mag_lag(t, gyro, mag)
    # either not significant (0 exactly) or a residual delay below a tenth of a sample
    assert abs(lag.lag_s) < 3e-4


def test_still_device_gives_no_delay():
    t = np.arange(0.0, 30.0, 1.0 / RATE_HZ)
    gyro = np.zeros((t.size, 3))
    mag = np.tile(M_N_UT, (t.size, 1))
    lag = estimate_mag_lag(t, gyro, mag)
    assert lag.lag_s == 0.0 and lag.reason == "the device hardly turns"


def test_advance_removes_the_delay_exactly_for_linear_signals():
    t = np.arange(0.0, 1.0, 0.01)
    x = np.stack([2.0 * t + 1.0, -t], axis=1)
    x[40] = np.nan
    y = advance(t, x, 0.025)
    inner = (t + 0.025 <= t[-1]) & np.isfinite(x[:, 0])
    # linear interpolation of a linear signal is exact (rounding only)
    np.testing.assert_allclose(y[inner], np.stack([2.0 * (t + 0.025) + 1.0, -(t + 0.025)], axis=1)[inner], atol=1e-12)
    assert np.all(np.isnan(y[40]))


def test_removing_the_estimated_delay_restores_the_kinematics():
    t, gyro, mag = _log(0.012, noise_ut=0.0, seed=1)
    lag = estimate_mag_lag(t, gyro, mag)
    fixed = advance(t, mag, lag.lag_s)
    again = estimate_mag_lag(t, gyro, fixed)
    # the corrected log has no delay left (within a tenth of a sample)
    assert abs(again.lag_s) < 3e-4
