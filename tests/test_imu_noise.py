"""IMU noise figures (`tpos_cli.imu_noise`): pipeline key set > session [imu] > measured > model default."""

import numpy as np
import pytest

from tpos_cli.config import DriveSmoothParams, RangingParams
from tpos_cli.imu_noise import _row_medians, measured_white_noise, resolve_imu_noise
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
