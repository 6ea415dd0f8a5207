"""Range measurement model (paper 002 Eq. 19-23): Jacobian vs finite differences, ECEF vs pymap3d."""

import numpy as np
from numpy.testing import assert_allclose

from tpos_cli.frames import geodetic
from tpos_cli.ranging.measurements import (
    lla_rad_to_ecef, lla_to_local_ned, range_jacobian, range_residual,
)


def test_ecef_and_local_ned_match_pymap3d():
    origin = np.array([45.0, 126.0, 100.0])
    lla = np.array([45.0003, 126.0004, 101.5])
    r_e = lla_rad_to_ecef(np.radians(lla[0]), np.radians(lla[1]), lla[2])
    assert_allclose(r_e, geodetic.lla_to_ecef(lla), rtol=0, atol=1e-6)  # 1 um: pymap3d's own tolerance
    r0 = geodetic.lla_to_ecef(origin)
    C = geodetic.ecef_to_ned_dcm(origin[0], origin[1])
    ned = lla_to_local_ned(np.radians(lla[0]), np.radians(lla[1]), lla[2], r0, C)
    assert_allclose(ned, geodetic.lla_to_ned(lla, origin), rtol=0, atol=1e-6)


def test_range_jacobian_matches_finite_differences():
    rng = np.random.default_rng(3)
    for _ in range(20):
        p = rng.uniform(-20, 20, 3)
        a = rng.uniform(-20, 20, 3)
        H = range_jacobian(p, a)
        fd = np.empty(3)
        for j in range(3):
            e = np.zeros(3)
            e[j] = 1e-6
            # residual = z - h(p): d residual / dp = -dh/dp
            fd[j] = -(range_residual(p + e, a, 10.0, 0.0) - range_residual(p - e, a, 10.0, 0.0)) / 2e-6
        assert_allclose(H, fd, rtol=0, atol=1e-8)  # central difference, h = 1e-6 m: error ~ h^2/rho + 1e-10 rounding
        # bias enters with unit weight (last column of H_t, Eq. 24, sign folded into the residual)
        assert_allclose(range_residual(p, a, 10.0, 0.3) - range_residual(p, a, 10.0, 0.0), -0.3, atol=1e-12)
