"""`inspect`'s timing figures: the mean rate and the jitter, not the median interval."""

import numpy as np
import pandas as pd
from numpy.testing import assert_allclose
from typer.testing import CliRunner

from tests.helpers.sessions import write_minimal_session
from tpos_cli.cli import app
from tpos_cli.inspection import describe_session, sample_timing
from tpos_cli.session import load_session


def test_mean_rate_and_jitter_of_an_irregular_logger():
    # Intervals cycling 6, 6, 6, 7, 9 ms (a logger stamping at 1 ms resolution): the median interval
    # says 166.67 Hz, the samples arrive at 1 / 6.8 ms = 147.06 Hz; SD of the intervals sqrt(1.36) ms.
    dt = np.tile([6e-3, 6e-3, 6e-3, 7e-3, 9e-3], 400)
    t = np.concatenate([[0.0], np.cumsum(dt)])
    timing = sample_timing(t)
    assert_allclose(timing["rate_hz"], 1.0 / 6.8e-3, rtol=1e-9)
    assert_allclose(timing["jitter_ms"], np.sqrt(1.36), rtol=1e-6)
    assert_allclose([timing["dt_min_ms"], timing["dt_max_ms"]], [6.0, 9.0], rtol=1e-6)


def test_gaps_are_not_jitter():
    t = np.concatenate([np.arange(100) * 0.01, 5.0 + np.arange(100) * 0.01])  # a 4 s gap
    timing = sample_timing(t)
    assert_allclose(timing["rate_hz"], 100.0, rtol=1e-9)
    assert timing["jitter_ms"] < 1e-6


def test_inspect_prints_rate_and_jitter(tmp_path):
    d = write_minimal_session(tmp_path / "s", rate_hz=100.0)
    imu = pd.read_csv(d / "imu.csv")
    dt = np.tile([6e-3, 6e-3, 6e-3, 7e-3, 9e-3], len(imu) // 5)[: len(imu) - 1]
    imu["t"] = 1000.0 + np.concatenate([[0.0], np.cumsum(dt)])
    imu.to_csv(d / "imu.csv", index=False)
    info = describe_session(load_session(d))
    assert_allclose(info["tables"]["imu"]["rate_hz"], 1.0 / dt.mean(), rtol=1e-6)  # 147.11 Hz, not 166.67
    res = CliRunner().invoke(app, ["inspect", str(d)])
    assert res.exit_code == 0, res.output
    imu_line = next(ln for ln in res.stdout.splitlines() if ln.strip().startswith("imu"))
    assert f"{1.0 / dt.mean():.2f}" in imu_line and f"{dt.std() * 1e3:.2f}" in imu_line and "dt 6.0-9.0 ms" in imu_line
