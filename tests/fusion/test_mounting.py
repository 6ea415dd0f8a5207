"""Course-over-ground minus yaw check for land vehicles (`fusion.mounting`)."""

import numpy as np

from tpos_cli.fusion.mounting import course_minus_yaw, mounting_warning


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
    assert "check [imu] axes" in mounting_warning(c, 20.0)
    assert "walking person" in mounting_warning(c, 20.0)


def test_backwards_mounting_does_not_split_across_the_wrap():
    t, v, yaw = _track(180.0)
    yaw = yaw + np.where(np.arange(t.size) % 2 == 0, 0.01, -0.01)  # +-0.6 deg about 180
    c = course_minus_yaw(t, v, yaw, 1.0)
    assert abs(abs(c.median_deg) - 180.0) < 0.7 and c.spread_deg < 1.0


def test_no_warning_when_aligned_or_standing():
    t, v, yaw = _track(3.0)
    assert mounting_warning(course_minus_yaw(t, v, yaw, 1.0), 20.0) is None
    assert course_minus_yaw(t, v * 0.01, yaw, 1.0) is None  # never faster than 1 m/s
    # too little motion to judge: 5 s
    c = course_minus_yaw(t[:50], v[:50], yaw[:50] - 1.0, 1.0)
    assert mounting_warning(c, 20.0) is None
