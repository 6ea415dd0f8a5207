"""Rotations against scipy and closed forms."""

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

from tpos_cli.frames import _kernels as k
from tpos_cli.frames import rotation as r


def test_euler_matches_scipy_intrinsic_zyx():
    rng = np.random.default_rng(1)
    rpy = rng.uniform([-np.pi, -1.5, -np.pi], [np.pi, 1.5, np.pi], size=(50, 3))
    C = r.euler_to_dcm(rpy[:, 0], rpy[:, 1], rpy[:, 2])
    ref = Rotation.from_euler("ZYX", rpy[:, ::-1]).as_matrix()
    assert_allclose(C, ref, atol=1e-14)
    back = np.column_stack(r.dcm_to_euler(C))
    assert_allclose(back, rpy, atol=1e-12)
    for i in range(5):
        assert_allclose(k.euler_to_dcm(*rpy[i]), C[i], atol=1e-15)
        assert_allclose(k.dcm_to_euler(C[i]), rpy[i], atol=1e-12)


def test_rotvec_and_quaternion_round_trips():
    rng = np.random.default_rng(2)
    rv = rng.normal(size=(20, 3))
    rv *= (rng.uniform(0, 3.0, 20) / np.linalg.norm(rv, axis=1))[:, None]
    C = r.rotvec_to_dcm(rv)
    assert_allclose(r.dcm_to_rotvec(C), rv, atol=1e-12)
    assert_allclose(r.quat_to_dcm(r.dcm_to_quat(C)), C, atol=1e-14)
    for i in range(5):
        assert_allclose(k.rotvec_to_dcm(rv[i]), C[i], atol=1e-14)
        assert_allclose(k.dcm_to_rotvec(C[i]), rv[i], atol=1e-10)
    tiny = np.array([1e-9, -2e-9, 3e-9])
    assert_allclose(k.rotvec_to_dcm(tiny), np.eye(3) + r.skew(tiny), atol=1e-17)


def test_rotvec_to_dcm_kernel_small_angles_to_rounding():
    """The kernel's series branch (below 0.01 rad) and its trigonometric one, either side of the
    switch, against Rodrigues in extended precision (np.longdouble)."""
    rng = np.random.default_rng(4)
    for angle in (1e-7, 3e-4, 0.0099, 0.0101, 0.05, 1.0):
        v = rng.normal(size=3)
        v *= angle / np.linalg.norm(v)
        x = v.astype(np.longdouble)
        a2 = np.sum(x * x)
        a = np.sqrt(a2)
        K = np.array([[0, -x[2], x[1]], [x[2], 0, -x[0]], [-x[1], x[0], 0]], dtype=np.longdouble)
        exact = np.eye(3, dtype=np.longdouble) + np.sin(a) / a * K + (1 - np.cos(a)) / a2 * (K @ K)
        assert np.abs(k.rotvec_to_dcm(v) - exact).max() < 3e-16, angle


def test_skew_is_cross_product():
    a, b = np.array([1.0, -2.0, 0.5]), np.array([0.3, 4.0, -1.0])
    assert_allclose(r.skew(a) @ b, np.cross(a, b), atol=1e-15)
    assert_allclose(k.skew(a) @ b, np.cross(a, b), atol=1e-15)


@pytest.mark.parametrize("axes,sensor,body", [
    ("FRD", [1, 2, 3], [1, 2, 3]),
    ("RFU", [1, 2, 3], [2, 1, -3]),     # x right, y forward, z up
    ("FLU", [1, 2, 3], [1, -2, -3]),
    ("BLD", [1, 2, 3], [-1, -2, 3]),
])
def test_axes_letters_map_sensor_to_frd(axes, sensor, body):
    assert_allclose(r.axes_to_dcm(axes) @ np.array(sensor, float), body, atol=0)


@pytest.mark.parametrize("axes", ["FRU", "FFD", "XYZ", "FR", "frdd"])
def test_invalid_axes(axes):
    with pytest.raises(ValueError):
        r.axes_to_dcm(axes)


def test_wrap():
    assert_allclose(r.wrap_angle_deg([181.0, -181.0, 360.0, 180.0]), [-179.0, 179.0, 0.0, 180.0])


def test_3x3_products_match_numpy():
    """The element-loop products of `_kernels` against `@`, on non-symmetric operands."""
    rng = np.random.default_rng(3)
    A, B, v = rng.normal(size=(3, 3)), rng.normal(size=(3, 3)), rng.normal(size=3)
    assert_allclose(k.mat_vec3(A, v), A @ v, rtol=0, atol=1e-15)
    assert_allclose(k.matT_vec3(A, v), A.T @ v, rtol=0, atol=1e-15)
    assert_allclose(k.mat_mat3(A, B), A @ B, rtol=0, atol=1e-15)
    assert_allclose(k.mat_matT3(A, B), A @ B.T, rtol=0, atol=1e-15)


def test_euler_sigmas_match_the_full_inverse_and_round_trip():
    """euler_sigmas_deg (a closed-form M^-1) against sqrt(diag(M^-1 P M^-T)) with numpy's inverse, on
    a stack of random attitudes and covariances (not only symmetric ones); and its inverse,
    attitude_cov_from_euler_sigmas, comes back to the SDs it was given."""
    rng = np.random.default_rng(5)
    K = 200
    rpy = np.column_stack([rng.normal(0, 0.5, K), rng.uniform(-1.4, 1.4, K), rng.uniform(-np.pi, np.pi, K)])
    C = r.euler_to_dcm(rpy[:, 0], rpy[:, 1], rpy[:, 2])
    A = rng.normal(size=(K, 3, 3)) * 1e-2
    P = A @ np.swapaxes(A, -1, -2) + 0.1 * rng.normal(size=(K, 3, 3)) * 1e-4  # not exactly symmetric
    P = P + 1e-3 * np.eye(3)
    Mi = np.linalg.inv(r.euler_error_map(C))
    ref = np.degrees(np.sqrt(np.clip(np.diagonal(Mi @ P @ np.swapaxes(Mi, -1, -2), axis1=-2, axis2=-1), 0.0, None)))
    assert_allclose(r.euler_sigmas_deg(C, P), ref, rtol=1e-12)
    assert_allclose(r.euler_sigmas_deg(C[0], P[0]), ref[0], rtol=1e-12)  # one matrix
    sig = rng.uniform(0.1, 5.0, (K, 3))
    assert_allclose(r.euler_sigmas_deg(C, r.attitude_cov_from_euler_sigmas(C, sig)), sig, rtol=1e-9)
