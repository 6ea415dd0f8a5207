"""Scenario `drive`: static start, vehicle kinematics, GPS outages and noise statistics, seeding."""

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.stats import chi2

from tpos_cli.frames import earth
from tpos_cli.sim import simulate_drive
from tpos_cli.sim.sensor_errors import DEG, G0_MPS2, MEMS


@pytest.fixture(scope="module")
def drive():
    return simulate_drive(600.0, seed=11)


def _chi2_ok(x, sd, p=1e-4):
    """Sample variance of zero-mean x (all entries) consistent with sd^2 at two-sided level p."""
    x = np.ravel(x)
    q = np.sum((x / sd) ** 2)
    return chi2.ppf(p / 2, x.size) < q < chi2.ppf(1 - p / 2, x.size)


def test_static_start_senses_gravity_and_earth_rate():
    sim = simulate_drive(30.0, seed=1, noise_free=True)
    st = sim.truth.t_s < 15.0
    C_bn = np.transpose(sim.truth.C_nb[st], (0, 2, 1))
    lat = np.radians(sim.truth.lla[st, 0])
    g = earth.gravity_ned_mps2(lat, sim.truth.lla[st, 2])
    assert_allclose(sim.imu.acc_b_mps2[st], np.einsum("kij,kj->ki", C_bn, -g), atol=1e-12)  # rounding
    assert_allclose(sim.imu.gyro_b_rps[st], np.einsum("kij,kj->ki", C_bn, earth.earth_rate_ned_rps(lat)), atol=1e-17)
    assert np.abs(sim.truth.vel_ned_mps[st]).max() == 0.0


def test_vehicle_kinematics_are_plausible(drive):
    v = drive.truth.vel_ned_mps
    speed = np.linalg.norm(v, axis=1)
    assert speed.max() <= 20.0 + 1e-9 and speed[drive.truth.t_s > 40].mean() > 5.0
    moving = speed > 0.5
    course = np.arctan2(v[moving, 1], v[moving, 0])
    yaw = drive.truth.rpy_rad[moving, 2]
    # yaw is the course (no side slip): rounding only
    assert_allclose(np.angle(np.exp(1j * (course - yaw))), 0.0, atol=1e-9)
    assert np.abs(np.degrees(drive.truth.rpy_rad[:, 0])).max() < 3.0  # roll 0.6 deg per m/s^2
    acc_h = np.diff(v[:, :2], axis=0) * 100.0
    assert np.linalg.norm(acc_h, axis=1).max() < 3.5  # lateral 2.5 and longitudinal 1.5 m/s^2 limits


def test_gps_outage_is_missing_rows_and_rate_is_1hz():
    sim = simulate_drive(120.0, seed=2)
    t = sim.gps.t_s
    assert not np.any((t >= 40.0) & (t < 70.0))
    assert_allclose(np.setdiff1d(np.arange(121.0), t), np.arange(40.0, 70.0))
    assert np.all(sim.gps.fix == 2)
    assert_allclose(sim.gps_outages_s, [[40.0, 70.0]])
    sim2 = simulate_drive(120.0, seed=2, outages=((10.0, 5.0), (90.0, 10.0)))
    assert len(sim2.gps.t_s) == 121 - 15


def test_gps_noise_matches_requested_sd(drive):
    g = drive.gps
    lat = np.radians(g.lla_true[:, 0])
    dn = np.radians(g.lla[:, 0] - g.lla_true[:, 0]) * (earth.meridian_radius_m(lat) + g.lla_true[:, 2])
    de = np.radians(g.lla[:, 1] - g.lla_true[:, 1]) * (earth.transverse_radius_m(lat) + g.lla_true[:, 2]) * np.cos(lat)
    du = g.lla[:, 2] - g.lla_true[:, 2]
    assert _chi2_ok(np.r_[dn, de], 1.5) and _chi2_ok(du, 2.5)
    assert _chi2_ok(g.vel_ned_mps - g.vel_true_ned_mps, 0.05)
    assert_allclose(g.sigma_neu_m[0], [1.5, 1.5, 2.5])


def test_imu_noise_matches_grade(drive):
    imu = drive.imu
    assert imu.grade == MEMS
    white_g = imu.gyro_b_rps - imu.gyro_true_b_rps - imu.errors.gyro_bias_rps
    white_a = imu.acc_b_mps2 - imu.acc_true_b_mps2 - imu.errors.acc_bias_mps2
    assert _chi2_ok(white_g, MEMS.gyro_noise_dps * DEG)
    assert _chi2_ok(white_a, MEMS.acc_noise_mg * 1e-3 * G0_MPS2)
    # bias: constant +-20 deg/h per axis plus a Gauss-Markov part of SD 10 deg/h (|GM| < 6 sd)
    b = imu.errors.gyro_bias_rps / (DEG / 3600.0)
    assert np.all(np.abs(np.abs(b.mean(axis=0)) - 20.0) < 60.0)
    assert np.abs(np.diff(b, axis=0)).max() < 10.0 * np.sqrt(2 * 0.01 / 300.0) * 6


def test_seeded_reproducibility():
    a = simulate_drive(60.0, seed=4)
    b = simulate_drive(60.0, seed=4)
    c = simulate_drive(60.0, seed=5, trajectory_seed=4)
    assert np.array_equal(a.imu.gyro_b_rps, b.imu.gyro_b_rps) and np.array_equal(a.gps.lla, b.gps.lla)
    assert np.array_equal(a.truth.lla, c.truth.lla)  # same manoeuvres
    assert not np.array_equal(a.imu.gyro_b_rps, c.imu.gyro_b_rps)  # different noise


def test_one_hour_drive_has_exact_sample_count():
    sim = simulate_drive(3600.0, seed=0, noise_free=True)
    assert sim.imu.t_s.size == 360001 and np.all(np.isfinite(sim.imu.acc_b_mps2))


def test_realism_options_mounting_lever_arm_vibration_odometry(tmp_path):
    """Issue 11 item 7: the IMU turned on the car (its samples are the car's rotated by C^T), the
    antenna displaced by C_nb l, vibration of the requested RMS in the 10-50 Hz band, an odometer
    reading the forward speed times (1 + k), all written as contract tables."""
    from tpos_cli.frames.geodetic import lla_to_ned
    from tpos_cli.frames.rotation import euler_to_dcm
    from tpos_cli.session import load_session

    base = simulate_drive(60.0, seed=3, outages=(), noise_free=True)
    sim = simulate_drive(60.0, seed=3, outages=(), noise_free=True, mounting_rpy_deg=(1.0, 2.0, 90.0),
                         lever_arm_m=(1.0, 0.5, -1.5), odometry_rate_hz=50.0, odometry_scale_error=0.03,
                         odometry_sigma_mps=0.0)
    C = euler_to_dcm(*np.radians([1.0, 2.0, 90.0]))
    np.testing.assert_allclose(sim.imu.acc_b_mps2, base.imu.acc_b_mps2 @ C, atol=1e-12)
    d = lla_to_ned(sim.gps.lla_true, base.gps.lla_true[0]) - lla_to_ned(base.gps.lla_true, base.gps.lla_true[0])
    i = np.searchsorted(base.truth.t_s, base.gps.t_s)
    # atol: the tangent plane at the first fix against the local one at each fix, |l| x 1 km / 6400 km < 1e-3 m
    np.testing.assert_allclose(d, np.einsum("kij,j->ki", base.truth.C_nb[i], [1.0, 0.5, -1.5]), atol=1e-3)
    fwd = np.einsum("ki,ki->k", sim.truth.C_nb[::2][:, :, 0], sim.truth.vel_ned_mps[::2])
    np.testing.assert_allclose(sim.odometry.speed_mps, np.maximum(1.03 * fwd, 0.0), atol=1e-12)
    s = load_session(sim.write(tmp_path / "s"))
    assert s.odometry is not None and s.odometry.t_s.size == sim.odometry.t_s.size
    np.testing.assert_allclose(s.meta.lever_arm_b_m, C.T @ [1.0, 0.5, -1.5], atol=1e-12)  # the IMU's axes
    vib = simulate_drive(60.0, seed=3, outages=(), noise_free=True, vibration_mg=30.0)
    v = vib.imu.acc_b_mps2 - base.imu.acc_b_mps2
    np.testing.assert_allclose(np.sqrt(np.mean(v**2, axis=0)), 30e-3 * 9.80665, rtol=1e-9)
    spec = np.abs(np.fft.rfft(v[:, 0])) ** 2
    f = np.fft.rfftfreq(v.shape[0], 0.01)
    assert spec[(f >= 10.0) & (f <= 50.0)].sum() > 0.99 * spec.sum()
