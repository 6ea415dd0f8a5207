"""Stretches at rest by the solution's velocity, and the Allan page's window (report/rest.py, pdf._static_noise)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd

from tpos_cli.report.pdf import _static_noise
from tpos_cli.report.rest import REST_SPEED_MPS, rest_stretches, solution_velocity


def test_rest_stretches_runs_gaps_and_length():
    t = np.arange(0.0, 100.0, 0.1)
    v = np.zeros((t.size, 3))
    v[(t >= 20.0) & (t < 30.0), 0] = 5.0  # driving
    v[(t >= 60.0) & (t < 60.05), 1] = np.nan  # one epoch without a solution ends a stretch
    v[(t >= 80.0) & (t < 80.05), 2] = 2 * REST_SPEED_MPS
    got = rest_stretches(t, v, 5.0)
    np.testing.assert_allclose(got, [[0.0, 19.9], [30.0, 59.9], [60.1, 79.9], [80.1, 99.9]], atol=1e-9)
    np.testing.assert_allclose(rest_stretches(t, v, 25.0), [[30.0, 59.9]], atol=1e-9)
    tg = np.concatenate([t[:200], t[200:] + 10.0])  # a 10 s gap between epochs also ends one
    assert rest_stretches(tg, np.zeros((t.size, 3)), 5.0).shape == (2, 2)
    assert rest_stretches(np.empty(0), np.empty((0, 3)), 1.0).shape == (0, 2)


def _ctx(t_imu, vel_rows, best="smoothed"):
    rng = np.random.default_rng(4)
    n = t_imu.size
    gyro = 1e-3 * rng.standard_normal((n, 3))
    acc = np.array([0.0, 0.0, -9.81]) + 1e-2 * rng.standard_normal((n, 3))
    imu = SimpleNamespace(t_s=t_imu, gyro_b_rps=gyro, acc_b_mps2=acc)
    traj = pd.DataFrame({"t": vel_rows[0], "vn": vel_rows[1], "ve": 0.0, "vd": 0.0, "solution": best})
    return SimpleNamespace(run=SimpleNamespace(trajectory=traj), best=best, session=SimpleNamespace(imu=imu, t0_s=1000.0))


def test_allan_window_is_where_the_solution_stands_still():
    """An IMU that looks still throughout (a straight drive at constant speed looks so) while the
    solution drives at 9 m/s for 200 s, then stands for 150 s: the window is the standing part."""
    t_imu = np.arange(0.0, 350.0, 0.01)
    t_sol = np.arange(0.0, 350.0, 0.1)
    ctx = _ctx(t_imu, (1000.0 + t_sol, np.where(t_sol < 200.0, 9.0, 0.0)))
    nf, (w0, w1) = _static_noise(ctx)
    assert 1200.0 <= w0 < 1201.0 and w1 > 1349.0
    assert abs(nf.rate_hz - 100.0) < 1e-6


def test_no_allan_window_when_the_solution_never_stands_long_enough():
    t_imu = np.arange(0.0, 350.0, 0.01)
    t_sol = np.arange(0.0, 350.0, 0.1)
    moving = np.where((t_sol > 90.0) & (t_sol < 95.0), 0.0, 9.0)  # a 5 s stop only
    assert _static_noise(_ctx(t_imu, (1000.0 + t_sol, moving))) is None


def test_without_solution_velocity_the_imu_alone_decides():
    t_imu = np.arange(0.0, 150.0, 0.01)
    ctx = _ctx(t_imu, (1000.0 + np.arange(0.0, 150.0, 0.1), np.zeros(1500)))
    ctx.run.trajectory = ctx.run.trajectory.drop(columns=["vn", "ve", "vd"])
    assert solution_velocity(ctx.run.trajectory, "smoothed") is None
    assert ctx.session.imu.t_s[0] == 0.0
    nf, (w0, w1) = _static_noise(ctx)
    assert w0 == 1000.0 and w1 > 1149.0


def test_a_drive_report_reads_no_imu_rows(tmp_path, monkeypatch):
    """A run that recorded its inputs' hashes: the report reads the IMU's time column only (no page of
    a drive without a long stop draws the IMU); the pages that do load it on demand."""
    import shutil

    from tests.helpers.paths import REPO
    from tpos_cli import session as session_module
    from tpos_cli.pipeline import process_session
    from tpos_cli.report.build import make_report

    s = shutil.copytree(REPO / "sample_logs" / "drive_outage", tmp_path / "s")
    run = process_session(s, None, tmp_path / "run").run_dir

    def no_imu_rows(*_args, **_kwargs):
        raise AssertionError("the IMU rows were read")

    with monkeypatch.context() as m:
        m.setattr(session_module, "_load_imu", no_imu_rows)
        res = make_report(run)
    assert res.pages and (run / "report.pdf").exists()
    full = session_module.load_session(s)
    lazy = session_module.load_session(s, with_imu=False)
    assert lazy.imu is None and lazy.t0_s == full.t0_s and lazy.file_hashes == full.file_hashes
    np.testing.assert_array_equal(session_module.load_imu(lazy).gyro_b_rps, full.imu.gyro_b_rps)
