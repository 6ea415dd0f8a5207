"""A walker's accelerometer noise (`chains.drive_smooth.step_acc_noise`): the steps' impacts count while walking."""

import dataclasses

import numpy as np
import pytest

from tpos_cli.chains.drive_smooth import _Imu, filter_config, step_acc_noise
from tpos_cli.config import DriveSmoothParams
from tpos_cli.frames.earth import G0_MPS2
from tpos_cli.imu_noise import ImuNoiseFigures, measured_white_noise

RATE_HZ = 100.0
SD_MPS2 = 0.02  # the sensor's white noise (2 mg)
IMPACT_MPS2 = 5.0  # one sample per step (0.5 g over 10 ms), every 0.5 s


def _walker(n=120_000, stop=(200.0, 400.0), seed=5):
    """Gravity plus white noise; outside the stop one impact sample every 50 (two steps a second)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / RATE_HZ
    acc = np.array([0.0, 0.0, -G0_MPS2]) + rng.normal(0.0, SD_MPS2, (n, 3))
    k = np.arange(0, n, 50)
    k = k[(t[k] < stop[0]) | (t[k] > stop[1])]
    acc[k, 2] += IMPACT_MPS2
    return _Imu(t, np.zeros((n, 3)), acc), np.array([stop])


def _cfg(acc_mg):
    nz = ImuNoiseFigures({"acc_noise_mg": acc_mg, "gyro_noise_dps": 0.1, "acc_bias_mg": 10.0, "gyro_bias_dph": 100.0},
                         {"acc_noise_mg": "measured from the log", "gyro_noise_dps": "default", "acc_bias_mg": "default",
                          "gyro_bias_dph": "default"})
    return filter_config(DriveSmoothParams(), nz, np.zeros(3), RATE_HZ), {"imu_noise": nz.summary()}


def test_the_rms_figure_counts_every_impact_the_robust_one_none():
    imu, stops = _walker()
    moving = (imu.t < stops[0, 0]) | (imu.t > stops[0, 1])
    # each impact makes two first differences of +-5 m/s^2 on the down axis, one sample in 50: there the
    # differences' variance is 2 sd^2 + 2 x 25 / 50, halved (the white figure's sqrt(2)); the figure is
    # the mean over the three axes (the other two: the sensor's sd)
    expected = (2 * SD_MPS2 + np.sqrt(SD_MPS2**2 + IMPACT_MPS2**2 / 50)) / 3
    assert measured_white_noise(imu.acc[moving], robust=False) == pytest.approx(expected, rel=0.02)
    assert measured_white_noise(imu.acc[moving]) == pytest.approx(SD_MPS2, rel=0.05)  # robust: the sensor only


def test_a_walkers_acc_noise_is_the_rms_figure_while_walking_and_the_robust_one_at_stops():
    imu, stops = _walker()
    cfg, info = _cfg(SD_MPS2 / (1e-3 * G0_MPS2))
    out = {}
    new = step_acc_noise(cfg, imu, stops, info, out)
    sd = measured_white_noise(imu.acc[(imu.t < stops[0, 0]) | (imu.t > stops[0, 1])], robust=False)
    assert new.q[0] == pytest.approx(sd**2 / RATE_HZ, rel=1e-12)
    assert new.q[0] > 20 * cfg.q[0]  # the impacts, not the sensor, set it
    np.testing.assert_allclose(new.q[1:], cfg.q[1:], rtol=0, atol=0)  # gyro and bias drives untouched
    # inside the stop the robust figure: the PSD scaled back to cfg's, the gyro's left alone
    np.testing.assert_allclose(new.q_stops, [[stops[0, 0], stops[0, 1], cfg.q[0] / new.q[0], 1.0]], rtol=1e-12)
    assert out["step_acc_noise_mg"] == pytest.approx(sd / (1e-3 * G0_MPS2), abs=1e-3)


def test_a_given_or_larger_acc_figure_is_kept():
    imu, stops = _walker()
    cfg, info = _cfg(SD_MPS2 / (1e-3 * G0_MPS2))
    info["imu_noise"]["acc_noise_mg"]["source"] = "session"
    assert step_acc_noise(cfg, imu, stops, info, {}) is cfg
    big, info = _cfg(200.0)  # already above what the steps make
    assert step_acc_noise(big, imu, stops, info, {}) is big


def test_the_stops_own_noise_is_kept_one_row_per_stop():
    """With the stops' own noise already in (`imu_noise.stop_noise_factors` rows, relative to cfg.q) the
    walker's new q[0] leaves each stop's accelerometer PSD as it was: its acc factor rescaled, its gyro
    factor kept, no second row for that stop (the kernel adds the rows' factors); a stop without a row
    gets the log's figure."""
    imu, _ = _walker()
    stops = np.array([[200.0, 400.0], [600.0, 700.0]])
    cfg, info = _cfg(SD_MPS2 / (1e-3 * G0_MPS2))
    cfg = dataclasses.replace(cfg, q_stops=np.array([[200.0, 400.0, 0.1, 0.02]]))
    new = step_acc_noise(cfg, imu, stops, info, {})
    assert new.q[0] > 20 * cfg.q[0]
    np.testing.assert_allclose(new.q_stops[:, :2], stops, rtol=0, atol=0)
    # the PSDs inside the stops: the stop's own (0.1 of the old q[0]) and the log's (the old q[0])
    np.testing.assert_allclose(new.q[0] * new.q_stops[:, 2], [0.1 * cfg.q[0], cfg.q[0]], rtol=1e-12)
    np.testing.assert_allclose(new.q_stops[:, 3], [0.02, 1.0], rtol=0, atol=0)
