"""Allan-deviation noise identification on simulated static logs (issue 8: within 20 %)."""

import numpy as np
import pytest

from tpos_cli.noise import identify_noise
from tpos_cli.sim.sensor_errors import MEMS, corrupt_imu


def test_mems_static_white_noise():
    f = 100.0
    n = int(600 * f)
    rng = np.random.default_rng(7)
    gyro_true = np.tile([1e-5, 0.0, 4e-5], (n, 1))
    acc_true = np.tile([0.0, 0.0, -9.81], (n, 1))
    gyro, acc, _ = corrupt_imu(gyro_true, acc_true, MEMS, f, rng)
    keys = identify_noise(np.arange(n) / f, gyro, acc).toml_keys()
    assert keys["gyro_noise_dps"] == pytest.approx(MEMS.gyro_noise_dps, rel=0.2)  # the 20 %
    assert keys["acc_noise_mg"] == pytest.approx(MEMS.acc_noise_mg, rel=0.2)


def test_random_walk_and_rate_random_walk():
    f = 100.0
    n = int(1200 * f)
    rng = np.random.default_rng(3)
    N = np.radians(0.05) / np.sqrt(f)  # rad/s/√Hz
    K = np.radians(5.0 / 3600.0)  # rad/s/√s
    y = rng.standard_normal(n) * N * np.sqrt(f) + np.cumsum(rng.standard_normal(n)) * K / np.sqrt(f)
    from tpos_cli.noise import analyse_axis

    a = analyse_axis(y, f)
    assert a.random_walk == pytest.approx(N, rel=0.2)
    assert a.rate_random_walk == pytest.approx(K, rel=0.5)  # few long clusters in 20 min: ~30 % scatter
