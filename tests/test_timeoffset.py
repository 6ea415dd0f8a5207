"""IMU-GPS time offset recovered from a simulated drive (issue 8: within 20 ms)."""

import pytest

from tpos_cli.sim.drive import simulate_drive
from tpos_cli.timeoffset import estimate_gps_time_offset


@pytest.fixture(scope="module")
def drive():
    return simulate_drive(300.0, seed=3, gps_rate_hz=5.0, outages=())


@pytest.mark.parametrize("injected_s", [0.0, 0.2, -0.137])
def test_offset_recovered(drive, injected_s):
    g, imu = drive.gps, drive.imu
    # GPS stamps late by `injected_s` on the IMU clock: the offset to add is +injected_s
    r = estimate_gps_time_offset(imu.t_s, imu.gyro_b_rps, imu.acc_b_mps2, g.t_s - injected_s, g.vel_ned_mps)
    assert abs(r.offset_s - injected_s) < 0.02  # the bound
    assert abs(r.offset_s - injected_s) < 3 * r.sigma_s + 1e-3  # consistent with the reported SD
    assert 0.9 < r.gain < 1.1  # a consistent log: gyro and GPS course rate agree in scale


def test_noise_free_is_exact(drive):
    g, imu = drive.gps, drive.imu
    r = estimate_gps_time_offset(imu.t_s, imu.gyro_true_b_rps, imu.acc_true_b_mps2, g.t_s - 0.2, g.vel_true_ned_mps)
    assert r.offset_s == pytest.approx(0.2, abs=2e-3)  # exact data: limited by the grid/parabola only
