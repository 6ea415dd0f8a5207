"""Truth interpolation: exact on linear motion, no extrapolation, no bridging of gaps, SLERP."""

from __future__ import annotations

import numpy as np
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

from tests.report import synth
from tpos_cli.frames.geodetic import lla_to_ned
from tpos_cli.frames.rotation import euler_to_dcm, wrap_angle_deg
from tpos_cli.report import truth as T

GEO_ATOL_M = 1e-6  # NED <-> lla round trips through pymap3d are good to ~1e-9 m


def test_positions_linear_motion_is_exact():
    t = np.arange(0.0, 11.0)
    q = np.array([0.0, 0.25, 5.5, 10.0])
    out = T.interpolate_positions(t, synth.truth_lla(t), q, 2.5)
    assert_allclose(lla_to_ned(out, synth.ORIGIN), synth.truth_ned(q), rtol=0, atol=GEO_ATOL_M)


def test_no_extrapolation_and_no_gap_bridging():
    t = np.arange(0.0, 11.0)
    lla = synth.truth_lla(t)
    lla[5:8] = np.nan  # a dropout: valid samples 4 and 8 are 4 s apart
    q = np.array([-0.1, 4.0, 5.5, 8.0, 10.0, 10.1])
    out = T.interpolate_positions(t, lla, q, 2.5)
    assert np.isnan(out[[0, 2, 5], 0]).all()
    assert np.isfinite(out[[1, 3, 4], 0]).all()


def test_gap_limit_is_median_based():
    t = np.array([0.0, 1.0, 2.0, 3.0, 10.0])
    assert T.median_gap_limit(t) == 2.5  # median interval 1 s (the 7 s gap does not inflate it)


def test_scipy_euler_sequence_matches_frames():
    r, p, y = 0.3, -0.2, 2.5
    C = Rotation.from_euler("ZYX", [y, p, r]).as_matrix()
    assert_allclose(C, euler_to_dcm(r, p, y), rtol=0, atol=1e-14)


def test_slerp_through_north_and_about_one_axis():
    t = np.array([0.0, 1.0, 2.0])
    rpy = np.array([[0.0, 0.0, 359.0], [0.0, 0.0, 1.0], [0.0, 0.0, 31.0]])
    out = T.interpolate_attitude(t, rpy, np.array([0.5, 1.5, 2.0]), 2.5)
    # the short way through north, not through south; rotations about one axis interpolate linearly
    assert_allclose(wrap_angle_deg(out[:, 2] - [0.0, 16.0, 31.0]), 0.0, atol=1e-9)
    assert_allclose(out[:, :2], 0.0, atol=1e-9)


def test_flag_needs_both_neighbours():
    t = np.arange(0.0, 5.0)
    f = np.array([0, 0, 1, 1, 1], float)
    out = T.interpolate_flag(t, f, np.array([1.5, 2.0, 2.5, 4.0, 4.5]), 2.5)
    assert out.tolist() == [False, True, True, True, False]
