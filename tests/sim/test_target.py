"""Scenario `target`: exact beam ranges (ray-plane and the contract's Eq. 10 form), shots held on
the targets, magnetometer field and disturbance window, RFU logging axes."""

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.stats import chi2

from tpos_cli.frames.geodetic import lla_to_ned
from tpos_cli.frames.rotation import axes_to_dcm
from tpos_cli.sim import simulate_target
from tpos_cli.sim.target import beam_ranges


@pytest.fixture(scope="module")
def sim():
    return simulate_target(90.0, seed=3, noise_free=True)


def test_lr1_range_equals_distance_to_the_held_target(sim):
    tg = dict(zip(sim.targets.ids, lla_to_ned(sim.targets.lla, sim.truth.lla[0])))
    t = sim.ranges.t_s
    n = 0
    for tid, a, b in zip(sim.shots.ids, sim.shots.t_start_s, sim.shots.t_end_s):
        inside = (t >= a) & (t <= b)
        n += inside.sum()
        # ranges and targets are exact geometry in the observer's NED frame: 1e-9 m rounding
        assert_allclose(sim.ranges.range_m[inside, 0], np.linalg.norm(tg[tid]), atol=1e-9)
    assert n > 200


def test_ranges_satisfy_the_contract_wall_equations(sim):
    """dtheta = atan((d1-d3)/b13) exactly; dpsi = atan((d1-d2) cos(theta)/b12) (zero roll)."""
    i = np.searchsorted(sim.truth.t_s, sim.ranges.t_s)
    pitch, yaw = sim.truth.rpy_rad[i, 1], sim.truth.rpy_rad[i, 2]
    d = sim.ranges.range_m
    theta = np.arctan((d[:, 0] - d[:, 2]) / sim.ranges.baseline_13_m)
    psi = np.arctan((d[:, 0] - d[:, 1]) * np.cos(theta) / sim.ranges.baseline_12_m)
    assert_allclose(theta, pitch, atol=1e-8)  # d1-d3 carries ~1e-15 m rounding over 0.2 m baselines
    assert_allclose(psi, np.angle(np.exp(1j * (yaw - np.radians(30.0)))), atol=1e-8)


def test_beam_ranges_closed_form():
    """Facing the wall (yaw = wall azimuth), pitch up theta: d1 = D/cos, d3 = (D - b sin)/cos."""
    from tpos_cli.frames.rotation import euler_to_dcm

    th = np.radians(20.0)
    C = euler_to_dcm(0.0, th, np.radians(30.0))[None]
    d = beam_ranges(C, 12.0, np.radians(30.0), 0.2, 0.3)[0]
    assert_allclose(d, [12.0 / np.cos(th), 12.0 / np.cos(th), (12.0 - 0.3 * np.sin(th)) / np.cos(th)], rtol=1e-14)
    back = euler_to_dcm(0.0, 0.0, np.radians(210.0))[None]  # facing away: no return
    assert np.all(np.isnan(beam_ranges(back, 12.0, np.radians(30.0), 0.2, 0.3)))


def test_shots_hold_still_and_include_the_reference(sim):
    assert sim.targets.role[sim.targets.ids.index("REF")] == "reference"
    assert sim.shots.ids[0] == "REF"
    assert_allclose(sim.shots.t_end_s - sim.shots.t_start_s, 8.0)
    for a, b in zip(sim.shots.t_start_s, sim.shots.t_end_s):
        inside = (sim.truth.t_s > a) & (sim.truth.t_s <= b)
        assert np.ptp(sim.truth.rpy_rad[inside], axis=0).max() < 1e-12


def test_magnetometer_field_and_declination(sim):
    m_n = np.einsum("kij,kj->ki", sim.truth.C_nb, sim.imu.mag_true_b_ut)
    assert_allclose(np.linalg.norm(m_n, axis=1), 53.5, rtol=1e-12)
    assert_allclose(np.degrees(np.arctan2(m_n[:, 2], np.hypot(m_n[:, 0], m_n[:, 1]))), 70.0, atol=1e-9)
    assert_allclose(np.degrees(np.arctan2(m_n[:, 1], m_n[:, 0])), -14.6, atol=1e-9)


def test_magnetic_disturbance_window():
    s = simulate_target(40.0, seed=4, mag_disturbance_ut=50.0, mag_disturbance_start_s=10.0, mag_disturbance_end_s=30.0)
    e = s.imu.mag_b_ut - s.imu.mag_true_b_ut
    inside = (s.imu.t_s >= 10.0) & (s.imu.t_s < 30.0)
    # inside: 50 uT along body right plus noise SD hypot(0.5, 1.0); outside: noise SD 0.5 only
    assert_allclose(e[inside].mean(axis=0), [0.0, 50.0, 0.0], atol=0.05)
    sd = np.hypot(0.5, 1.0)
    q = np.sum(((e[inside] - [0.0, 50.0, 0.0]) / sd) ** 2)
    assert chi2.ppf(5e-5, e[inside].size) < q < chi2.ppf(1 - 5e-5, e[inside].size)
    assert np.abs(e[~inside].mean(axis=0)).max() < 0.05


def test_rfu_axes_are_written(tmp_path, sim):
    import pandas as pd

    sim.write(tmp_path / "t")
    imu = pd.read_parquet(tmp_path / "t" / "imu.parquet")
    C_bs = axes_to_dcm("RFU")
    gyro_s = imu[["gyro_x", "gyro_y", "gyro_z"]].to_numpy()
    assert_allclose(gyro_s @ C_bs.T, sim.imu.gyro_b_rps, atol=0)
    # level and still at the start: the sensor's z (up) reads +g
    assert imu["acc_z"].iloc[0] > 9.7


def test_sine_motion_of_paper_000():
    s = simulate_target(100.0, seed=0, motion="sine", noise_free=True)
    t = s.truth.t_s
    assert_allclose(s.truth.rpy_rad[:, 1], np.radians(54.0) * np.sin(2 * np.pi * t / 100.0), atol=1e-12)
    assert s.shots is None and np.isfinite(s.ranges.range_m).all()


def test_gyro_scale_misalignment_per_grade_leaves_the_other_draws():
    # omega_meas = (I + dM) omega + bias + noise, dM constant per session, its SD the grade's (GYRO_SCALE_PPM);
    # the draw comes from its own stream: without it (gyro_scale_ppm=0) every other sample of the seed is the same
    from tpos_cli.sim.target import GYRO_SCALE_PPM

    a = simulate_target(30.0, seed=7, grade="mems")
    b = simulate_target(30.0, seed=7, grade="mems", gyro_scale_ppm=0.0)
    dM = np.array(a.params["gyro_scale_misalignment"])
    assert a.params["gyro_scale_ppm"] == GYRO_SCALE_PPM["mems"] == 1000.0
    assert 1e-4 < np.sqrt(np.mean(dM**2)) < 3e-3
    assert np.array_equal(a.imu.acc_b_mps2, b.imu.acc_b_mps2) and np.array_equal(a.imu.mag_b_ut, b.imu.mag_b_ut)
    assert_allclose(a.imu.gyro_b_rps - b.imu.gyro_b_rps, a.imu.gyro_true_b_rps @ dM.T, rtol=0, atol=1e-15)
    assert not np.any(b.params["gyro_scale_misalignment"])
    t = simulate_target(30.0, seed=7, grade="tactical")
    assert_allclose(np.array(t.params["gyro_scale_misalignment"]), 0.1 * dM, rtol=1e-12)
    assert not np.any(simulate_target(30.0, seed=7, noise_free=True).params["gyro_scale_misalignment"])
    assert not np.any(simulate_target(30.0, seed=7).params["gyro_scale_misalignment"])  # paper 000's gyro
