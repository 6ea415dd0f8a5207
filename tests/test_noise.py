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


def _static_then_moving(f=100.0, static_s=150.0, moving_s=20.0, seed=5):
    """MEMS noise at rest for `static_s`, then a 0.5 rad/s turn: the longest static stretch is known."""
    n_s, n_m = int(static_s * f), int(moving_s * f)
    rng = np.random.default_rng(seed)
    gyro_true = np.zeros((n_s + n_m, 3))
    gyro_true[n_s:, 2] = 0.5
    acc_true = np.tile([0.0, 0.0, -9.81], (n_s + n_m, 1))
    gyro, acc, _ = corrupt_imu(gyro_true, acc_true, MEMS, f, rng)
    return np.arange(n_s + n_m) / f, gyro, acc


def test_longest_static_window_and_session_noise():
    from types import SimpleNamespace

    from tpos_cli.noise import longest_static_window, session_noise

    t, gyro, acc = _static_then_moving()
    i0, i1 = longest_static_window(t, gyro, acc)
    assert i0 == 0 and abs(t[i1 - 1] - 150.0) < 0.5  # the turn starts at 150 s; the 0.5 s detection window blurs it
    s = SimpleNamespace(imu=SimpleNamespace(t_s=t, gyro_b_rps=gyro, acc_b_mps2=acc), t0_s=1000.0)
    nf, (w0, w1) = session_noise(s)
    assert w0 == 1000.0 and abs(w1 - 1150.0) < 0.5
    assert nf.toml_keys()["gyro_noise_dps"] == pytest.approx(MEMS.gyro_noise_dps, rel=0.2)  # the 20 %
    short = SimpleNamespace(imu=SimpleNamespace(t_s=t[:5000], gyro_b_rps=gyro[:5000], acc_b_mps2=acc[:5000]), t0_s=0.0)
    assert session_noise(short) is None  # 50 s at rest: too short for an Allan analysis


def test_report_has_allan_page_for_a_static_log(tmp_path):
    import pandas as pd

    from tests.report import synth
    from tpos_cli.report.build import make_report

    s = synth.write_session(tmp_path / "s")
    t, gyro, acc = _static_then_moving(moving_s=0.0)
    imu = pd.DataFrame({"t": synth.T0 + t, **{f"gyro_{a}": gyro[:, i] for i, a in enumerate("xyz")},
                        **{f"acc_{a}": acc[:, i] for i, a in enumerate("xyz")}})
    imu.to_parquet(s / "imu.parquet")
    (s / "imu.csv").unlink()
    (s / "session.toml").write_text((s / "session.toml").read_text().replace("rate_hz = 10.0", "rate_hz = 100.0"))
    # the solution stands still over the IMU's 150 s at rest (the report takes the Allan window
    # where the solution's speed says so, `report.rest`)
    traj = synth.trajectory_rows("forward", np.arange(0.0, 150.0 + 1e-9, 0.1), [1.0, 0.0, 0.0])
    traj[["vn", "ve", "vd"]] = 0.0
    r = synth.write_run(tmp_path / "r", s, traj)
    pages = make_report(r).pages
    assert pages.count("allan") == 1
    # the 20 s synthetic session of the report tests is not static long enough: no Allan page
    s2 = synth.write_session(tmp_path / "s2")
    assert "allan" not in make_report(synth.write_run(tmp_path / "r2", s2, traj[traj["t"] <= synth.T0 + 20.0])).pages
