import numpy as np
import pymap3d
import pytest

from tpos_cli import targeting as T
from tpos_cli.frames import geodetic
from tpos_cli.frames.rotation import euler_to_dcm, rotvec_to_dcm

OBS = np.array([45.4946, -73.5622, 40.0])


def test_geolocate_matches_pymap3d_aer():
    rng = np.random.default_rng(1)
    az, el, d = rng.uniform(0, 360, 20), rng.uniform(-60, 60, 20), rng.uniform(5, 500, 20)
    fx = T.geolocate_rpy(OBS, rng.uniform(-90, 90, 20), el, az, d)
    ref = np.stack(pymap3d.aer2geodetic(az, el, d, *OBS), axis=-1)
    np.testing.assert_allclose(fx.lla[:, :2], ref[:, :2], rtol=0, atol=1e-9)  # 0.1 mm in deg
    np.testing.assert_allclose(fx.lla[:, 2], ref[:, 2], rtol=0, atol=1e-6)  # 1 um


def test_covariance_matches_monte_carlo():
    rng = np.random.default_rng(2)
    C = euler_to_dcm(0.1, 0.3, 1.0)
    P = np.diag(np.radians([0.2, 0.1, 0.3]) ** 2)
    fx = T.geolocate(OBS, C[None], np.array([50.0]), P_att_rad2=P[None], sigma_range_m=0.01)
    phi = rng.multivariate_normal(np.zeros(3), P, 20000)
    d = 50.0 + rng.normal(0, 0.01, 20000)
    p = d[:, None] * (rotvec_to_dcm(phi) @ C)[:, :, 0]
    emp = np.cov(p.T)
    # sampling SD of element ij is about sqrt(Pii Pjj / N): allow 4 of them (one seeded draw)
    s = np.sqrt(np.diag(fx.cov_ned_m2[0]))
    tol = 4.0 * np.outer(s, s) / np.sqrt(20000)
    assert np.all(np.abs(fx.cov_ned_m2[0] - emp) < tol)


def test_along_beam_second_moment_matches_monte_carlo():
    # degree-level attitude errors at 12 m: the beam's end falls short by d (1 - cos theta), which the
    # linear covariance does not hold; its second moment about the true point is the added variance
    rng = np.random.default_rng(5)
    C = euler_to_dcm(0.2, -0.1, 0.7)
    P = np.array([[1.0, 0.3, 0.2], [0.3, 0.8, -0.4], [0.2, -0.4, 2.5]]) * np.radians(1.0) ** 2
    d = 12.0
    u = C[:, 0]
    phi = rng.multivariate_normal(np.zeros(3), P, 200000)
    along = d * ((rotvec_to_dcm(phi) @ C)[:, :, 0] @ u - 1.0)  # exact, no range noise
    v = T.beam_second_order_var(P[None], u[None], np.array([d]))[0]
    # (theta^T theta)^2 has a heavy tail: its relative sampling SD over 200000 draws is about 0.01
    assert v == pytest.approx(np.mean(along**2), rel=0.05)
    fx = T.geolocate(OBS, C[None], np.array([d]), P_att_rad2=P[None])
    assert u @ fx.cov_ned_m2[0] @ u == pytest.approx(v, rel=1e-9)  # the beam direction holds only this term


def test_calibration_recovers_offsets_and_pairs():
    th = np.radians([10.0, 25.0, -5.0])
    ps = np.radians([30.0, 80.0, 200.0])
    d = np.array([12.0, 14.0, 9.0])
    p = d[:, None] * np.stack([np.cos(th) * np.cos(ps), np.cos(th) * np.sin(ps), -np.sin(th)], axis=-1)
    ref = geodetic.ned_to_lla(p, OBS)
    cal = T.calibrate_offsets(OBS, th + np.radians(0.1), ps - np.radians(0.2), d, ref)
    np.testing.assert_allclose(np.degrees([cal.dpitch_rad, cal.dyaw_rad]), [0.1, -0.2], rtol=0, atol=1e-8)
    pairs = T.target_pairs(["a", "b", "c"], ref, "x")
    np.testing.assert_allclose(pairs.slant_range_m[0], np.linalg.norm(p[1] - p[0]), rtol=0, atol=1e-6)
    np.testing.assert_allclose(pairs.dh_m[0], ref[1, 2] - ref[0, 2], rtol=0, atol=1e-9)
