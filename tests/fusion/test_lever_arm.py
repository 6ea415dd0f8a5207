"""The lever-arm correction's decision, output point and summary (`fusion.lever_arm`)."""

import numpy as np
from numpy.testing import assert_allclose

from tpos_cli.frames.geodetic import lla_to_ned
from tpos_cli.frames.rotation import euler_to_dcm
from tpos_cli.fusion import lever_arm as la
from tpos_cli.fusion.layout import Block, StateLayout, clock_block, lever_arm_block


def test_course_span_counts_the_turns_of_moving_rows_only():
    """Three quarters of a circle at 10 m/s span 270 deg (unwrapped across north); rows slower
    than the floor, however they point, do not count; a straight line spans 0."""
    course = np.radians(np.linspace(-45.0, 225.0, 271))  # crosses +-180 on the way
    v = np.column_stack([10.0 * np.cos(course), 10.0 * np.sin(course), np.zeros(course.size)])
    assert_allclose(la.course_span_deg(v, 1.0), 270.0, atol=1e-9)
    slow = np.array([[0.1, -0.05, 0.0], [-0.1, 0.02, 0.0]])
    assert_allclose(la.course_span_deg(np.vstack([v[:1], slow, v[:1]]), 1.0), 0.0, atol=1e-9)
    assert la.course_span_deg(slow, 1.0) == 0.0
    assert la.course_span_deg(np.full((3, 3), np.nan), 1.0) == 0.0


def test_auto_decision_rules():
    """auto wants horizontal axes (a vehicle's, or a level IMU's), fixes under a third of the
    prior SD and a course that turns."""
    assert la.lever_arm_wanted("auto", "vehicle", 0.01, 180.0, 0.5, 90.0)[0]
    assert la.lever_arm_wanted("auto", "imu", 0.01, 180.0, 0.5, 90.0)[0]
    assert not la.lever_arm_wanted("auto", None, 0.01, 180.0, 0.5, 90.0)[0]
    assert not la.lever_arm_wanted("auto", "vehicle", 0.2, 180.0, 0.5, 90.0)[0]  # 0.2 m fixes bury a lever arm
    assert not la.lever_arm_wanted("auto", "vehicle", 0.01, 60.0, 0.5, 90.0)[0]
    assert not la.lever_arm_wanted("auto", "vehicle", np.inf, 180.0, 0.5, 90.0)[0]
    assert la.lever_arm_wanted("on", None, 5.0, 0.0, 0.5, 90.0)[0] and not la.lever_arm_wanted("off", "vehicle", 0.01, 360.0, 0.5, 90.0)[0]


def test_axes_of_the_correction():
    """A wheeled platform's vehicle axes; else a level IMU's own (tilt 15.0 deg: yes, 25 deg: no)."""
    assert la.lever_axes(True, euler_to_dcm(0.0, np.radians(80.0), 0.0)) == "vehicle"
    assert la.lever_axes(False, euler_to_dcm(np.radians(9.0), np.radians(12.0), 1.0)) == "imu"  # tilt 14.96 deg
    assert la.lever_axes(False, euler_to_dcm(np.radians(25.0), 0.0, 2.0)) is None


def test_the_output_point_moves_by_the_rotated_correction():
    """A correction dl = (0.6 forward, -0.4 right) on an IMU turned 90 deg on the car (its x to the
    car's right): the point moves by C_nb C_vb^T (dl, 0), which with the car heading east
    (IMU yaw 180) is 0.6 m east and 0.4 m north, to pymap3d's round trip (1e-6 m)."""
    C_vb = euler_to_dcm(0.0, 0.0, np.radians(90.0))  # v_vehicle = C_vb v_imu: the IMU's x is the car's right
    assert_allclose(C_vb @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)
    lay = StateLayout((clock_block(0.2), lever_arm_block(0.5)))
    bias = np.zeros((1, 6 + lay.n_extra))
    o = 6 + lay.offset(Block.LEVER) - 15
    bias[0, o:o + 2] = [0.6, -0.4]
    dl_b = la.lever_correction_b(bias, lay, C_vb)
    assert_allclose(dl_b[0], C_vb.T @ [0.6, -0.4, 0.0], atol=1e-15)
    C_nb = euler_to_dcm(0.0, 0.0, np.radians(180.0))[None]  # IMU x south = car forward east
    nav = np.array([[np.radians(45.0), np.radians(7.0), 300.0, 0.0, 12.0, 0.0]])
    moved = la.at_stated_point(nav, C_nb, dl_b)
    d = lla_to_ned(np.array([[*np.degrees(moved[0, :2]), moved[0, 2]]]), np.array([*np.degrees(nav[0, :2]), nav[0, 2]]))[0]
    assert_allclose(d, [0.4, 0.6, 0.0], atol=1e-6)
    assert_allclose(moved[0, 3:], nav[0, 3:], atol=0)
    assert la.lever_correction_b(bias[:, :8], StateLayout((clock_block(0.2),)), C_vb) is None


def test_summary_reports_the_estimate_in_the_imu_axes():
    C_vb = euler_to_dcm(0.0, 0.0, np.radians(-90.0))
    out = la.lever_arm_summary(np.array([0.6, -0.4]), np.array([0.02, 0.03]), [0.1, 0.2, -1.0], C_vb, "auto: ...")
    assert out["estimated"] and out["correction_forward_right_m"] == [0.6, -0.4] and out["sigma_forward_right_m"] == [0.02, 0.03]
    assert_allclose(out["estimate_m"], np.array([0.1, 0.2, -1.0]) + C_vb.T @ [0.6, -0.4, 0.0], atol=1e-3)
    off = la.lever_arm_summary(None, None, [0.0, 0.0, 0.0], C_vb, "auto: no")
    assert not off["estimated"] and "estimate_m" not in off


def test_second_order_shares_leave_the_term_to_each_stops_first_gps_row_in_the_runs_order():
    """Inside a rest interval only the first GPS row of each kind (in the order the run meets them:
    a backward run from the stop's end) carries the yaw x lever second-order variance; rows outside,
    other kinds and a run without intervals keep all of it."""
    from tpos_cli.fusion.measurements import Kind

    P, V, Z = Kind.GPS_POSITION, Kind.GPS_VELOCITY, Kind.ZUPT
    t = np.array([1.0, 1.0, 2.0, 2.0, 2.5, 3.0, 5.0, 6.0, 7.0, 7.0])
    kind = np.array([V, P, V, P, Z, P, P, P, V, P])
    stops = np.array([[6.5, 8.0], [0.5, 3.0]])  # unsorted on purpose
    fwd = la.second_order_shares(t, kind, stops)
    assert fwd.tolist() == [1, 1, 0, 0, 1, 0, 1, 1, 1, 1]
    bwd = la.second_order_shares(t[::-1], kind[::-1], stops)[::-1]  # the backward run's order
    assert bwd.tolist() == [0, 0, 1, 0, 1, 1, 1, 1, 1, 1]
    assert np.all(la.second_order_shares(t, kind, None) == 1.0)


def test_yaw_held_rows_are_the_velocity_and_zupt_rows_inside_stops():
    """`yaw_held_rows`: GPS velocity and ZUPT rows inside a stop (ends included); position rows and
    rows outside every stop are updated as usual; no stops: none."""
    from tpos_cli.fusion.measurements import Kind

    t = np.array([0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 5.0])
    kind = np.array([Kind.GPS_VELOCITY, Kind.GPS_VELOCITY, Kind.GPS_POSITION, Kind.ZUPT, Kind.GPS_VELOCITY,
                     Kind.ZUPT, Kind.GPS_VELOCITY])
    stops = np.array([[1.0, 2.0], [4.0, 4.5]])
    np.testing.assert_array_equal(la.yaw_held_rows(t, kind, stops), [False, True, False, True, False, True, False])
    assert not la.yaw_held_rows(t, kind, None).any()
