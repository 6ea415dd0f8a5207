"""Vehicle motion constraints (issue 11): stops, mounting from the travel direction, GPS velocity lag."""

import numpy as np
import pytest

from tpos_cli.frames.earth import normal_gravity_mps2
from tpos_cli.frames.rotation import euler_to_dcm
from tpos_cli.fusion.constraints import (
    detect_stops,
    nhc_measurements,
    rotation_gyro_noise_dps,
    stop_measurements,
    travel_direction,
)
from tpos_cli.fusion.engine import FilterConfig, InitialState, backward_start, run_filter
from tpos_cli.fusion.insgps import GpsFixes, velocity_latency_s
from tpos_cli.fusion.measurements import Kind


def test_stops_from_gps_speed_and_odometer():
    t = np.arange(0.0, 60.0, 0.25)
    v = np.zeros((t.size, 3))
    v[:, 0] = 5.0
    v[(t >= 10.0) & (t < 20.0), 0] = 0.02  # a 10 s stop
    v[(t >= 30.0) & (t < 31.0), 0] = 0.0  # 1 s: too short
    odo_t = np.arange(0.0, 60.0, 0.1)
    odo = np.where((odo_t >= 40.0) & (odo_t < 45.0), 0.0, 5.0)
    st = detect_stops(t, v, odo_t, odo)
    # each stop trimmed by 0.5 s at both ends; the last slow sample of the GPS stop is 19.75 s
    np.testing.assert_allclose(st.intervals_s, [[10.5, 19.25], [40.5, 44.4]], atol=1e-9)
    assert st.sources == {"gps": 1, "odometry": 1}
    assert st.contains([15.0, 25.0, 42.0]).tolist() == [True, False, True]


def test_zaru_rows_are_the_mean_gyro_of_each_block():
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 20.0, 0.01)
    bias = np.array([1e-3, -2e-3, 5e-4])
    gyro = bias + 1e-3 * rng.standard_normal((t.size, 3))
    st = detect_stops(np.arange(0.0, 20.0, 0.25), np.zeros((80, 3)))
    m = stop_measurements(t, gyro, np.zeros_like(gyro), st, zupt_sigma_mps=0.02)
    zaru = m.kind == Kind.ZARU
    assert (m.kind == Kind.ZUPT).sum() == zaru.sum() > 30
    # 50-sample means: the scatter about the bias is 1e-3 / sqrt(50) per axis; the rows' SDs are
    # twice that (vibration allowance), so every row is within 5 of its own SDs
    sd = np.sqrt(np.diagonal(m.R[zaru], axis1=1, axis2=2))
    assert np.all(np.abs(m.z[zaru] - bias) < 5 * sd)
    assert np.allclose(sd, 2e-3 / np.sqrt(50), rtol=0.3)


def test_zupt_on_an_idling_engine_holds_the_block_mean_not_one_phase_of_the_vibration():
    """A car standing 60 s with its engine at 20 Hz (30 mg, IMU at 100 Hz): a ZUPT row every 0.5 s
    (10 engine cycles) samples the IMU's velocity wobble (A / omega = 2.3 mm/s) at one phase.
    Rows that say "this instant is still" make the INS creep at that phase's velocity (12 cm in
    60 s, the control below); rows that say "the block's mean is still" (the wobble from the
    block's own specific force) keep it within 1 cm (a tenth of that), forward and backward."""
    lat = np.radians(45.0)
    t = np.arange(6001) * 0.01
    w = 2 * np.pi * 20.0
    acc = np.tile([0.0, 0.0, -normal_gravity_mps2(lat, 100.0)], (t.size, 1))
    acc[:, 0] += 30e-3 * 9.80665 * np.sin(w * t)
    w_ie = 7.292115e-5
    gyro = np.tile([w_ie * np.cos(lat), 0.0, -w_ie * np.sin(lat)], (t.size, 1))  # body = NED, at rest
    nav = np.array([lat, np.radians(7.0), 100.0, 0.0, 0.0, 0.0])
    P0 = np.diag(np.r_[np.full(3, 1.0), np.full(3, 0.1), np.full(3, 1e-3), np.full(3, 1e-3), np.full(3, 1e-5)] ** 2)
    init = InitialState(nav, np.eye(3), np.zeros(6), P0)
    cfg = FilterConfig(np.array([1e-4, 1e-8, 1e-12, 1e-14]), 0.0, 0.0, cov_step=10)
    stops = detect_stops(np.arange(0.0, 61.0, 0.25), np.zeros((244, 3)))
    rows = stop_measurements(t, gyro, acc, stops, zupt_sigma_mps=0.02)
    zupt = rows.select(rows.kind == Kind.ZUPT)
    assert np.abs(zupt.z[:, 0]).max() > 1e-3  # the wobble at the rows' phase, mm/s

    def creep_m(m, backward):
        start = init if not backward else backward_start(run_filter(t, gyro, acc, init, cfg, m), init.P0)
        run = run_filter(t, gyro, acc, start, cfg, m, backward=backward)
        north_m = (run.nav[:, 0] - lat) * 6.37e6
        return float(np.abs(north_m[-1] - north_m[0]))

    for backward in (False, True):
        assert creep_m(zupt, backward) < 0.01
    still_instant = zupt.select(np.ones(len(zupt), dtype=bool))
    still_instant.z[:] = 0.0
    assert creep_m(still_instant, False) > 0.05 and creep_m(still_instant, True) > 0.05


def test_nhc_rows_skip_stops_and_the_yaw_search():
    t = np.arange(0.0, 30.0, 0.01)
    st = detect_stops(np.arange(0.0, 30.0, 0.25), np.where((np.arange(120) >= 40) & (np.arange(120) < 80), 0.0, 5.0)[:, None]
                      * np.array([1.0, 0.0, 0.0]))
    m = nhc_measurements(t, st, rate_hz=10.0, sigma_mps=0.1, after_s=5.0)
    assert m.t_s.min() >= 5.0 and not st.contains(m.t_s).any()
    assert np.all(m.dim == 2) and np.allclose(m.R[:, :2, :2], 0.01 * np.eye(2))


@pytest.mark.parametrize("rpy_deg", [(0.0, -3.0, 91.0), (0.0, 2.0, -45.0), (0.0, 0.0, 180.0), (0.0, 1.5, 4.0)])
def test_travel_direction_recovers_the_mounting(rpy_deg):
    """A vehicle moving along its own x axis, seen by an IMU turned by `rpy_deg`: the estimate's
    x axis is the exact travel direction in body axes (any yaw: at 91 deg the old Euler form lost
    the pitch), steadiness 1; a turn about the travel direction itself is not observable this way,
    so an upright IMU's z axis, made orthogonal to it, is the vehicle's down axis."""
    rng = np.random.default_rng(1)
    n = 3000
    t = np.arange(n) * 0.1
    yaw_v = np.cumsum(rng.normal(0, 0.02, n))  # the vehicle turning
    C_nv = euler_to_dcm(np.zeros(n), 0.02 * np.sin(t / 20), yaw_v)
    C_vb = euler_to_dcm(*np.radians(rpy_deg))
    C_nb = C_nv @ C_vb
    vel = 10.0 * C_nv[:, :, 0]
    td = travel_direction(t, vel, C_nb)
    np.testing.assert_allclose(td.C_vb[0], C_vb[0], atol=1e-9)
    z = np.array([0.0, 0.0, 1.0]) - C_vb[0, 2] * C_vb[0]
    np.testing.assert_allclose(td.C_vb[2], z / np.linalg.norm(z), atol=1e-9)
    assert td.steadiness == pytest.approx(1.0, abs=1e-12)
    if abs(rpy_deg[2]) < 10.0:  # a small mounting: the Euler angles themselves, to second order
        # (the upright convention and Euler roll 0 differ by about pitch x yaw: 0.026 x 0.070 rad = 0.1 deg)
        assert td.pitch_deg == pytest.approx(rpy_deg[1], abs=0.1) and td.yaw_deg == pytest.approx(rpy_deg[2], abs=0.1)
    # C_vb of the estimate takes the body-frame velocity onto the vehicle's x axis
    v_b = np.einsum("kji,kj->ki", C_nb, vel)
    v_v = v_b @ td.C_vb.T
    np.testing.assert_allclose(v_v[:, 1:], 0.0, atol=1e-9)


def test_travel_direction_of_an_imu_on_its_side():
    """An IMU rolled 90 deg on the vehicle (its z axis horizontal): gravity marks the vehicle's
    down axis, and the estimate is the whole mounting of a level-driving vehicle."""
    n = 3000
    t = np.arange(n) * 0.1
    C_nv = euler_to_dcm(np.zeros(n), np.zeros(n), 0.3 * np.sin(t / 30.0))
    C_vb = euler_to_dcm(*np.radians([90.0, 2.0, 10.0]))
    C_nb = C_nv @ C_vb
    td = travel_direction(t, 10.0 * C_nv[:, :, 0], C_nb)
    np.testing.assert_allclose(td.C_vb, C_vb, atol=1e-9)


def test_travel_direction_leaves_out_samples_far_from_fixes():
    """A yaw drift of 5 deg inside a 60 s stretch without fixes (a GPS outage of the first pass)
    biases the estimate when counted; with the fix times given only the samples up to 1 s after a
    fix count (a forward run is corrected at each fix) and the estimate is the exact mounting again."""
    n = 3000
    t = np.arange(n) * 0.1
    yaw_v = 0.3 * np.sin(t / 30.0)
    C_nv = euler_to_dcm(np.zeros(n), np.zeros(n), yaw_v)
    C_vb = euler_to_dcm(0.0, np.radians(1.0), np.radians(3.0))
    outage = (t >= 100.0) & (t < 160.0)
    drift = np.where(outage, np.radians(5.0) * (t - 100.0) / 60.0, 0.0)  # the INS yaw error grows
    C_nb = euler_to_dcm(np.zeros(n), np.zeros(n), drift) @ C_nv @ C_vb
    vel = 10.0 * C_nv[:, :, 0]
    fix_t = t[::10][~outage[::10]]  # 1 Hz fixes, none in the outage
    biased = travel_direction(t, vel, C_nb)
    td = travel_direction(t, vel, C_nb, fix_t_s=fix_t, max_fix_gap_s=1.0)
    assert abs(biased.yaw_deg - 3.0) > 0.3  # the drift leaks in when counted
    np.testing.assert_allclose(td.C_vb[0], C_vb[0], atol=1e-9)  # the exact travel direction again


def test_travel_direction_sigma_carries_the_runs_heading_error():
    """A first run whose heading is 8 deg off all along (a slow rover's GPS-only run): every
    body-frame velocity turns alike, so the estimate is 8 deg off while its 10 s blocks agree to a
    few hundredths of a degree. Given the run's heading SD (8 deg) the mounting's yaw SD covers
    that error; the block scatter alone claims it 100 times too well."""
    n = 3000
    t = np.arange(n) * 0.1
    C_nv = euler_to_dcm(np.zeros(n), np.zeros(n), 0.3 * np.sin(t / 30.0))
    C_vb = euler_to_dcm(0.0, np.radians(1.0), np.radians(3.0))
    C_nb = euler_to_dcm(0.0, 0.0, np.radians(8.0)) @ C_nv @ C_vb  # the run's heading error
    vel = 10.0 * C_nv[:, :, 0]
    scatter = travel_direction(t, vel, C_nb)
    att_sd = np.column_stack([np.full(n, np.radians(0.2)), np.full(n, np.radians(8.0))])
    td = travel_direction(t, vel, C_nb, att_sd_rad=att_sd)
    err = abs(td.yaw_deg - 3.0)
    assert err == pytest.approx(8.0, abs=0.2) and td.yaw_deg == scatter.yaw_deg  # the estimate itself is unchanged
    assert err / scatter.sigma_yaw_deg > 100.0
    assert td.sigma_yaw_deg == pytest.approx(np.hypot(scatter.sigma_yaw_deg, 8.0), rel=1e-9)
    assert td.sigma_pitch_deg == pytest.approx(np.hypot(scatter.sigma_pitch_deg, 0.2), rel=1e-9)


def test_rotation_gyro_noise_is_one_percent_of_the_rms_rate():
    """A walker's sway (40 deg/s amplitude at 1.8 Hz about x, 25 deg/s at 0.9 Hz about z) on a gyro
    with a constant bias: 1 % of the RMS rate about the bias, sqrt(40^2 + 25^2) / sqrt(2) deg/s,
    whatever the bias; a still gyro gives 0."""
    t = np.arange(0.0, 60.0, 1 / 160.0)
    w = np.column_stack([np.radians(40.0) * np.sin(2 * np.pi * 1.8 * t), np.zeros(t.size),
                         np.radians(25.0) * np.sin(2 * np.pi * 0.9 * t)]) + np.radians([0.3, -0.2, 0.5])
    assert rotation_gyro_noise_dps(w) == pytest.approx(0.01 * np.hypot(40.0, 25.0) / np.sqrt(2.0), rel=0.01)
    assert rotation_gyro_noise_dps(np.tile(np.radians([0.3, -0.2, 0.5]), (100, 1))) == 0.0


def test_velocity_latency_of_a_backward_difference_receiver():
    """Logged velocity = backward difference of the positions over one 0.25 s interval: the
    velocity of 0.125 s earlier; found on the 0.025 s grid."""
    t = np.arange(0.0, 300.0, 0.25)
    north_m = 50.0 * np.sin(t / 15.0) + 3.0 * t
    east_m = 40.0 * np.cos(t / 11.0)
    lla = np.column_stack([45.0 + np.degrees(north_m / 6378137.0),
                           7.0 + np.degrees(east_m / (6378137.0 * np.cos(np.radians(45.0)))), np.full(t.size, 100.0)])
    vel = np.full((t.size, 3), np.nan)
    vel[1:, 0] = np.diff(north_m) / 0.25
    vel[1:, 1] = np.diff(east_m) / 0.25
    f = GpsFixes(t, lla, vel, np.ones((t.size, 3)), np.ones((t.size, 3)))
    lag, fig = velocity_latency_s(f)
    assert lag == pytest.approx(0.125, abs=0.0126)  # the grid step over 2
    # a receiver with true velocities: no lag
    vel2 = vel.copy()
    vel2[:, 0] = 3.0 + 50.0 / 15.0 * np.cos(t / 15.0)
    vel2[:, 1] = -40.0 / 11.0 * np.sin(t / 11.0)
    lag2, _ = velocity_latency_s(GpsFixes(t, lla, vel2, np.ones((t.size, 3)), np.ones((t.size, 3))))
    assert lag2 == 0.0
