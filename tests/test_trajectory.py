"""Contract trajectory rows (`tpos_cli.trajectory`): Euler-angle sigmas, column layout."""

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.stats import chi2

from tpos_cli.frames.rotation import euler_to_dcm
from tpos_cli.trajectory import Solution, solution_table, trajectory_table


def test_attitude_sigmas_are_euler_sigmas_not_ned_error_sds():
    # level, heading east: roll turns about the east axis, pitch about south, yaw about down, so
    # the Euler SDs are (sigma_E, sigma_N, sigma_D) of the NED attitude error, exactly
    C = euler_to_dcm(0.0, 0.0, np.pi / 2)[None]
    P = np.diag(np.radians([1.0, 2.0, 3.0]) ** 2)[None]
    df = trajectory_table("x", [10.0], [45.0, 7.0, 100.0], None, C, P_att_rad2=P)
    assert_allclose(df[["sigma_roll", "sigma_pitch", "sigma_yaw"]].to_numpy()[0], [2.0, 1.0, 3.0], atol=1e-9)
    assert_allclose(df[["vn", "ve", "vd", "yaw"]].to_numpy()[0], [0, 0, 0, 90.0], atol=1e-9)


def test_solution_rows_have_the_contract_columns_in_order():
    k = 3
    P9 = np.tile(np.diag([1.0, 4.0, 9.0, 0.01, 0.04, 0.09, 1e-4, 1e-4, 1e-4]), (k, 1, 1))
    nav = np.column_stack([np.radians([45.0] * k), np.radians([7.0] * k), [100.0] * k, np.ones((k, 3))])
    sol = Solution("smoothed", np.arange(k), nav, np.tile(np.eye(3), (k, 1, 1)), P9)
    df = solution_table(sol, np.arange(k) * 0.1, 1000.0, vertical_sigma="sigma_u", extra={"flag": np.zeros(k, bool)})
    assert list(df.columns) == ["t", "lat", "lon", "h", "vn", "ve", "vd", "roll", "pitch", "yaw", "solution",
                                "sigma_n", "sigma_e", "sigma_u", "sigma_vn", "sigma_ve", "sigma_vd",
                                "sigma_roll", "sigma_pitch", "sigma_yaw",
                                "sigma_tilt_n", "sigma_tilt_e", "sigma_heading", "att95_deg", "flag"]
    assert_allclose(df["t"], [1000.0, 1000.1, 1000.2])
    assert_allclose(df[["sigma_n", "sigma_e", "sigma_u"]].to_numpy()[0], [1.0, 2.0, 3.0])
    assert_allclose(df["lat"], 45.0, atol=1e-12)


def test_solution_table_takes_an_attitude_covariance_in_place_of_p9s():
    """`P_att_rad2`: the attitude sigmas from it (e.g. the vehicle's axes), P9 not copied nor read there."""
    k = 4
    rng = np.random.default_rng(3)
    A = rng.standard_normal((k, 9, 9)) * 1e-2
    P9 = A @ np.swapaxes(A, 1, 2)
    nav = np.column_stack([np.radians([45.0] * k), np.radians([7.0] * k), [100.0] * k, np.ones((k, 3))])
    C = euler_to_dcm(rng.uniform(-0.2, 0.2, k), rng.uniform(-0.2, 0.2, k), rng.uniform(-3, 3, k))
    B = rng.standard_normal((k, 3, 3)) * 1e-3
    P_att = B @ np.swapaxes(B, 1, 2)
    P9_att = P9.copy()
    P9_att[:, 6:9, 6:9] = P_att
    sol = Solution("x", np.arange(k), nav, C, P9)
    a = solution_table(sol, np.arange(k) * 0.1, 0.0, P_att_rad2=P_att)
    b = solution_table(Solution("x", np.arange(k), nav, C, P9_att), np.arange(k) * 0.1, 0.0)
    assert a.equals(b) and not np.shares_memory(P9, P_att)


def test_solution_column_of_an_empty_table():
    df = trajectory_table("x", np.zeros(0), np.zeros((0, 3)), None, np.zeros((0, 3, 3)))
    assert len(df) == 0 and "solution" in df


def test_navigation_frame_attitude_sigmas_stay_finite_where_euler_yaw_is_singular():
    # audit (session 25): BROAD 02's page 1 drew a 95 % heading bound from the Euler yaw SD, 204 deg near pitch
    # -90 deg for a total attitude error of ~0.5 deg; the SDs about north/east/down and the total-angle bound
    # come from the same covariance and do not depend on the attitude
    from tpos_cli.trajectory import CHI2_3DOF_95, attitude_error_sigmas

    P = np.diag(np.radians([0.2, 0.3, 0.5]) ** 2)
    C = euler_to_dcm(np.array([0.3, 0.3]), np.radians([0.0, -89.9]), np.array([1.0, 1.0]))
    df = trajectory_table("x", [0.0, 1.0], [45.0, 7.0, 100.0], None, C, P_att_rad2=np.stack([P, P]))
    assert df["sigma_yaw"].iloc[1] > 50 * df["sigma_yaw"].iloc[0]  # the Euler SD blows up near pitch -90
    assert_allclose(df[["sigma_tilt_n", "sigma_tilt_e", "sigma_heading"]].to_numpy(), [[0.2, 0.3, 0.5]] * 2, rtol=1e-12)
    assert CHI2_3DOF_95 == pytest.approx(chi2.ppf(0.95, 3), rel=1e-12)  # the constant is scipy's quantile
    assert_allclose(df["att95_deg"], np.sqrt(CHI2_3DOF_95) * 0.5, rtol=1e-12)
    # the total-angle bound holds with at least 95 % (exactly for an isotropic P): 2e5 draws, 3 binomial SDs ~0.15 %
    rng = np.random.default_rng(0)
    for P_test in (P, np.diag(np.radians([0.4, 0.4, 0.4]) ** 2)):
        phi = rng.multivariate_normal(np.zeros(3), P_test, 200_000)
        _, b = attitude_error_sigmas(P_test[None])
        assert np.mean(np.degrees(np.linalg.norm(phi, axis=1)) <= b[0]) > 0.95 - 0.0015
    _, b = attitude_error_sigmas(np.full((1, 3, 3), np.nan))
    assert np.isnan(b).all()
