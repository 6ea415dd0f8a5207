"""Geodetic wrappers: known points and round trips (pymap3d does the work)."""

import numpy as np
from numpy.testing import assert_allclose

from tpos_cli.frames import earth, geodetic


def test_known_points():
    assert_allclose(geodetic.lla_to_ecef([0.0, 0.0, 0.0]), [earth.A_M, 0, 0], atol=1e-6)
    assert_allclose(geodetic.lla_to_ecef([90.0, 0.0, 0.0]), [0, 0, earth.B_M], atol=1e-6)


def test_round_trips_and_local_frames():
    lla = np.array([[45.0, -73.0, 40.0], [-33.9, 151.2, 5.0], [89.9, 10.0, 1000.0]])
    assert_allclose(geodetic.ecef_to_lla(geodetic.lla_to_ecef(lla)), lla, atol=1e-8)
    origin = lla[0]
    ned = np.array([[100.0, -50.0, 2.0], [0.0, 0.0, 0.0], [-3.0, 7.0, -10.0]])
    back = geodetic.lla_to_ned(geodetic.ned_to_lla(ned, origin), origin)
    assert_allclose(back, ned, atol=1e-6)
    enu = geodetic.lla_to_enu(geodetic.ned_to_lla(ned, origin), origin)
    assert_allclose(enu, ned[:, [1, 0, 2]] * [1, 1, -1], atol=1e-6)


def test_ecef_to_ned_dcm_matches_pymap3d_vectors():
    origin = np.array([45.0, -73.0, 40.0])
    C_ne = geodetic.ecef_to_ned_dcm(origin[0], origin[1])
    r0 = geodetic.lla_to_ecef(origin)
    p = geodetic.ned_to_lla(np.array([5.0, -3.0, 1.0]), origin)
    assert_allclose(C_ne @ (geodetic.lla_to_ecef(p) - r0), [5.0, -3.0, 1.0], atol=1e-6)
    assert_allclose(C_ne @ C_ne.T, np.eye(3), atol=1e-15)
