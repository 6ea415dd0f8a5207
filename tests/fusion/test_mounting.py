"""Course-over-ground minus yaw check for land vehicles (`fusion.mounting`)."""

import numpy as np

from tpos_cli.frames.rotation import euler_to_dcm, skew
from tpos_cli.fusion.mounting import course_minus_yaw, mounting_off, refined_mounting, vehicle_attitude
from tpos_cli.quality import mounting_findings, mounting_text


def _track(offset_deg, n=600, speed=5.0, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.1
    course = np.cumsum(rng.normal(0.0, 0.05, n))  # a winding road
    v = np.column_stack([speed * np.cos(course), speed * np.sin(course), np.zeros(n)])
    return t, v, course - np.radians(offset_deg)


def test_offset_recovered_exactly():
    t, v, yaw = _track(30.0)
    c = course_minus_yaw(t, v, yaw, 1.0)
    assert abs(c.median_deg - 30.0) < 1e-9 and c.spread_deg < 1e-9
    assert c.moving_s == np.float64(59.9) or abs(c.moving_s - 59.9) < 1e-9
    assert mounting_off(c, 20.0)
    text = mounting_text(c.median_deg, c.spread_deg, c.moving_s, c.min_speed_mps)
    assert "check [imu] axes" in text and "walker" in text and "faster than 1 m/s (60 s)" in text
    # the verdict's reason, from what the chain records, is the chain's warning (printed once)
    assert [f.reason for f in mounting_findings({"mounting_check": {"warning": True, **c.summary()}})] == [text]


def test_backwards_mounting_does_not_split_across_the_wrap():
    t, v, yaw = _track(180.0)
    yaw = yaw + np.where(np.arange(t.size) % 2 == 0, 0.01, -0.01)  # +-0.6 deg about 180
    c = course_minus_yaw(t, v, yaw, 1.0)
    assert abs(abs(c.median_deg) - 180.0) < 0.7 and c.spread_deg < 1.0


def test_no_warning_when_aligned_or_standing():
    t, v, yaw = _track(3.0)
    assert not mounting_off(course_minus_yaw(t, v, yaw, 1.0), 20.0)
    assert course_minus_yaw(t, v * 0.01, yaw, 1.0) is None  # never faster than 1 m/s
    # too little motion to judge: 5 s
    c = course_minus_yaw(t[:50], v[:50], yaw[:50] - 1.0, 1.0)
    assert not mounting_off(c, 20.0)


def test_refined_mounting_turns_the_axes_as_the_misalignment_states_do():
    """A travel direction 6.3 deg short in yaw (a slow rover's GPS-only first run) and the residual
    misalignment a trial pass found: the refined C_vb is the exact rotation the states describe to
    first order ((I - [(0, m_p, m_y) x]) C_vb, `vehicle_attitude`), the true mounting again, so a
    run given it starts with no residual; its summary carries the trial's SDs."""
    true = euler_to_dcm(0.0, np.radians(0.5), np.radians(89.0))
    first = euler_to_dcm(0.0, np.radians(0.5), np.radians(82.7))
    m = np.array([0.0, np.radians(-6.3)])  # v_vehicle = (I - [m x]) C_vb v_b: a residual m_y turns the axes by -m_y
    C, summ = refined_mounting(first, m, np.radians([0.8, 3.1]))
    np.testing.assert_allclose(C, true, atol=1e-12)
    small = np.radians([0.0, 0.2, -0.4])
    C2, _ = refined_mounting(true, small[1:], np.zeros(2))
    np.testing.assert_allclose(C2, (np.eye(3) - skew(small)) @ true, atol=1e-4)  # equal to second order: |m|^2 = 6e-5
    C_nv, _ = vehicle_attitude(np.eye(3)[None], np.zeros((1, 3, 3)), true, small[None, 1:])
    np.testing.assert_allclose(C_nv[0], C2.T, atol=1e-4)
    assert summ["mounting_rpy_deg"][2] == 89.0 and summ["sigma_py_deg"] == [0.8, 3.1]


def test_vehicle_roll_carries_the_unobserved_mounting_roll():
    """roll_sd_rad adds its variance about the vehicle's forward axis only (in NED: along C_nv e_x),
    exactly, on top of the IMU's attitude covariance and the pitch/yaw misalignment SDs."""
    C_nb = euler_to_dcm(np.radians(3.0), np.radians(-2.0), np.radians(40.0))[None]
    C_vb = euler_to_dcm(0.0, np.radians(2.0), np.radians(-4.0))
    P0 = np.diag([1e-6, 2e-6, 3e-6])[None]
    C_nv, P_a = vehicle_attitude(C_nb, P0, C_vb, np.zeros((1, 2)), np.array([0.01, 0.02]))
    _, P_b = vehicle_attitude(C_nb, P0, C_vb, np.zeros((1, 2)), np.array([0.01, 0.02]), roll_sd_rad=0.05)
    x = C_nv[0] @ [1.0, 0.0, 0.0]
    np.testing.assert_allclose(P_b[0] - P_a[0], 0.05**2 * np.outer(x, x), atol=1e-15)


def test_vehicle_attitude_without_a_covariance_gives_the_same_attitude():
    """P_att_rad2 None (the mounting check reads the attitude only): the same C_nv, no covariance."""
    C_nb = euler_to_dcm(np.radians(3.0), np.radians(-2.0), np.radians(40.0))[None]
    C_vb = euler_to_dcm(0.0, np.radians(2.0), np.radians(-4.0))
    m = np.array([[0.01, -0.02]])
    C_a, _ = vehicle_attitude(C_nb, np.diag([1e-6, 2e-6, 3e-6])[None], C_vb, m, np.array([0.01, 0.02]), roll_sd_rad=0.05)
    C_b, P_b = vehicle_attitude(C_nb, None, C_vb, m, np.array([0.01, 0.02]), roll_sd_rad=0.05)
    np.testing.assert_array_equal(C_a, C_b)
    assert P_b is None
