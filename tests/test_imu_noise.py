"""IMU noise figures (`tpos_cli.imu_noise`): pipeline key set > session [imu] > measured > model default."""

import numpy as np
import pytest

from tpos_cli.config import DriveSmoothParams, RangingParams
from tpos_cli.fusion.constraints import detect_stops
from tpos_cli.imu_noise import _row_medians, measured_white_noise, resolve_imu_noise, stop_noise_factors
from tpos_cli.session import ImuNoise


def test_each_figure_comes_from_the_first_source_that_has_it():
    p = DriveSmoothParams(gyro_noise_dps=0.05)  # set explicitly
    session = ImuNoise(gyro_noise_dps=0.2, acc_noise_mg=3.0)
    nz = resolve_imu_noise(p, session, measured={"acc_noise_mg": 9.0, "gyro_bias_dph": 7.0}, measured_label="log")
    assert nz.values == {"gyro_noise_dps": 0.05, "acc_noise_mg": 3.0, "gyro_bias_dph": 7.0,
                         "acc_bias_mg": DriveSmoothParams.model_fields["acc_bias_mg"].default}
    assert nz.sources == {"gyro_noise_dps": "pipeline", "acc_noise_mg": "session", "gyro_bias_dph": "log",
                          "acc_bias_mg": "default"}
    assert nz.summary()["acc_noise_mg"] == {"value": 3.0, "source": "session"}


def test_a_default_in_the_model_does_not_outrank_the_session():
    # the model holds a default for every key; only a key the user set counts as "pipeline"
    nz = resolve_imu_noise(RangingParams(), ImuNoise(gyro_noise_dps=0.3))
    assert nz["gyro_noise_dps"] == 0.3 and nz.sources["gyro_noise_dps"] == "session"
    assert nz["acc_noise_mg"] == RangingParams.model_fields["acc_noise_mg"].default


def test_measured_white_noise_of_white_noise():
    rng = np.random.default_rng(7)
    x = 0.5 + rng.normal(0.0, 0.02, (200_000, 3))
    # 1.4826 MAD of 2e5 differences: relative SD about 0.2 %, so 1 % is > 4 SD
    assert measured_white_noise(x) == pytest.approx(0.02, rel=0.01)


def test_row_medians_are_numpys_medians():
    # the same values as np.median, for even and odd lengths, ties, and a row holding a NaN
    rng = np.random.default_rng(3)
    for n in (1, 2, 3, 4, 11, 1000, 1001):
        for d in (rng.normal(size=(3, n)), np.round(rng.normal(size=(3, n)), 1)):
            want = np.median(d, axis=1)
            assert np.array_equal(_row_medians(d.copy()), want)
    d = rng.normal(size=(3, 10))
    d[1, 4] = np.nan
    assert np.array_equal(_row_medians(d.copy()), np.median(d, axis=1), equal_nan=True)


def test_stop_noise_of_an_idling_engine_is_what_integrates_over_a_second():
    """A stop with a 20 Hz engine wobble (30 mg, 3 deg/s) over white noise (2 mg, 0.05 deg/s per
    sample at 100 Hz): the white PSDs inside it are scaled to the white part (the wobble averages
    out over a second), not to the per-sample scatter the wobble dominates (21 mg: factor 0.44)."""
    rng = np.random.default_rng(1)
    rate = 100.0
    t = np.arange(0.0, 60.0, 1.0 / rate)
    g0 = 9.80665
    wob = np.sin(2 * np.pi * 20.0 * t)[:, None]
    acc = 30e-3 * g0 * wob + 2e-3 * g0 * rng.standard_normal((t.size, 3))
    gyro = np.radians(3.0) * wob + np.radians(0.05) * rng.standard_normal((t.size, 3))
    q = np.array([(26e-3 * g0) ** 2 / rate, np.radians(1.6) ** 2 / rate, 0.0, 0.0])  # the moving run's figures
    stops = detect_stops(np.arange(0.0, 60.0, 0.25), np.zeros((240, 3)))
    f = stop_noise_factors(t, gyro, acc, stops.intervals_s, q, rate)
    assert f.shape == (1, 4)
    # 58 one-second blocks: the white SD to about 10 % (factor to 20 %, 0.0059 and 0.00098)
    np.testing.assert_allclose(f[0, 2:], [(2.0 / 26.0) ** 2, (0.05 / 1.6) ** 2], rtol=0.25)
    # the floors (the pipeline's default figures) hold a quieter stop up; a stop never gets more than the run
    fl = stop_noise_factors(t, gyro, acc, stops.intervals_s, q, rate, floors=(4e-3 * g0, np.radians(0.1)))
    np.testing.assert_allclose(fl[0, 2:], [(4.0 / 26.0) ** 2, (0.1 / 1.6) ** 2], rtol=1e-9)
    assert np.all(stop_noise_factors(t, gyro, acc, stops.intervals_s, q / 1e4, rate)[0, 2:] == 1.0)


def test_a_stop_whose_accelerometer_is_as_lively_as_the_run_is_not_still():
    """A standing walker shifting his weight: inside the stop the accelerometer's scatter over a second
    is the run's (factor capped at 1) while the gyro is quiet. The stop is not still in the IMU's sense:
    both factors stay 1 (lowering the gyro's alone left the walk's filter lagging a steady 2-3 cm/s
    velocity residual there); the same stop with a quiet accelerometer gets both lowered."""
    rng = np.random.default_rng(2)
    rate = 100.0
    t = np.arange(0.0, 60.0, 1.0 / rate)
    g0 = 9.80665
    q = np.array([(26e-3 * g0) ** 2 / rate, np.radians(1.6) ** 2 / rate, 0.0, 0.0])  # the moving run's figures
    gyro = np.radians(0.05) * rng.standard_normal((t.size, 3))
    # weight shifts: a 0.05 m/s^2 random walk of 1 s steps, whose 1 s means scatter more than the run's 26 mg per sample
    lively = np.repeat(np.cumsum(0.5 * rng.standard_normal((60, 3)), axis=0), int(rate), axis=0)
    quiet = 2e-3 * g0 * rng.standard_normal((t.size, 3))
    stops = detect_stops(np.arange(0.0, 60.0, 0.25), np.zeros((240, 3)))
    f = stop_noise_factors(t, gyro, lively + quiet, stops.intervals_s, q, rate)
    assert np.all(f[0, 2:] == 1.0), f
    f = stop_noise_factors(t, gyro, quiet, stops.intervals_s, q, rate)
    assert np.all(f[0, 2:] < 0.05), f
