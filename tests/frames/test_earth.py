"""Earth model against closed forms and known values."""

import numpy as np
from numpy.testing import assert_allclose

from tpos_cli.frames import _kernels as k
from tpos_cli.frames import earth


def test_radii_at_equator_and_pole():
    # Closed forms: R_N(0) = a(1-e2), R_E(0) = a; at the pole both equal a / sqrt(1-e2).
    assert_allclose(earth.meridian_radius_m(0.0), earth.A_M * (1 - earth.E2), rtol=0, atol=1e-6)
    assert_allclose(earth.transverse_radius_m(0.0), earth.A_M, rtol=0, atol=1e-6)
    pole = earth.A_M / np.sqrt(1 - earth.E2)
    assert_allclose(earth.meridian_radius_m(np.pi / 2), pole, rtol=0, atol=1e-6)
    assert_allclose(earth.transverse_radius_m(np.pi / 2), pole, rtol=0, atol=1e-6)


def test_normal_gravity_reference_values():
    # WGS-84 defining values on the ellipsoid (equator, pole), and the free-air gradient ~3.086e-6 /s^2.
    assert_allclose(earth.normal_gravity_mps2(0.0, 0.0), earth.GAMMA_E_MPS2, rtol=0, atol=1e-9)
    assert_allclose(earth.normal_gravity_mps2(np.pi / 2, 0.0), earth.GAMMA_P_MPS2, rtol=0, atol=1e-9)
    grad = (earth.normal_gravity_mps2(np.radians(45), 0.0) - earth.normal_gravity_mps2(np.radians(45), 1000.0)) / 1000.0
    assert_allclose(grad, 3.086e-6, rtol=2e-3)


def test_rates():
    lat = np.radians(30.0)
    w = earth.earth_rate_ned_rps(lat)
    assert_allclose(np.linalg.norm(w), earth.OMEGA_IE_RPS, rtol=1e-15)
    assert_allclose(w[2], -earth.OMEGA_IE_RPS * 0.5, rtol=1e-12)
    # Moving east at v on the equator turns the frame about north at v / (R_E + h).
    rho = earth.transport_rate_ned_rps(0.0, 0.0, np.array([0.0, 10.0, 0.0]))
    assert_allclose(rho, [10.0 / earth.A_M, 0.0, 0.0], rtol=1e-12, atol=0)


def test_kernels_match_numpy():
    for lat in np.radians([-80.0, -10.0, 0.0, 37.0, 89.0]):
        h = 123.0
        v = np.array([3.0, -7.0, 0.5])
        assert_allclose(k.radii_m(lat), (earth.meridian_radius_m(lat), earth.transverse_radius_m(lat)), rtol=1e-14)
        assert_allclose(k.normal_gravity(lat, h), earth.normal_gravity_mps2(lat, h), rtol=1e-14)
        assert_allclose(k.earth_rate_ned(lat), earth.earth_rate_ned_rps(lat), rtol=1e-14, atol=1e-20)
        assert_allclose(k.transport_rate_ned(lat, h, v), earth.transport_rate_ned_rps(lat, h, v), rtol=1e-14, atol=1e-20)
