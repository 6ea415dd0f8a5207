"""Combining repeat shots and the 95 % ellipse, against independent solutions."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import linalg, stats

from tpos_cli.frames.geodetic import enu_to_lla, lla_to_enu
from tpos_cli.report.targets import combine_shots, covariance_neu, horizontal_ellipse

ORIGIN = np.array([45.5, -73.6, 40.0])
ATOL_M = 1e-6  # 1 µm: far below any sigma, far above the geodetic round trip (~1e-9 m)


def _shots(ids, neu_m, cov_neu):
    neu_m = np.asarray(neu_m, float)
    lla = enu_to_lla(neu_m[:, [1, 0, 2]], ORIGIN)
    cov = np.asarray(cov_neu, float)
    return pd.DataFrame(
        {
            "id": ids,
            "t_start": 10.0 * np.arange(len(ids)),
            "t_end": 10.0 * np.arange(len(ids)) + 5.0,
            "lat": lla[:, 0],
            "lon": lla[:, 1],
            "h": lla[:, 2],
            "sigma_n": np.sqrt(cov[:, 0, 0]),
            "sigma_e": np.sqrt(cov[:, 1, 1]),
            "sigma_u": np.sqrt(cov[:, 2, 2]),
            "cov_ne_m2": cov[:, 0, 1],
            "cov_nu_m2": cov[:, 0, 2],
            "cov_eu_m2": cov[:, 1, 2],
            "solution": "fkf",
        }
    )


def _random_cov(rng, scale):
    a = rng.normal(size=(3, 3)) * scale
    return a @ a.T + np.eye(3) * scale**2 * 0.1


def test_covariance_neu_reads_sigmas_and_cross_terms():
    rng = np.random.default_rng(1)
    covs = np.stack([_random_cov(rng, 0.01) for _ in range(4)])
    df = _shots(["A"] * 4, rng.normal(size=(4, 3)), covs)
    np.testing.assert_allclose(covariance_neu(df), covs, rtol=1e-12, atol=0)
    diag = covariance_neu(df.drop(columns=["cov_ne_m2", "cov_nu_m2", "cov_eu_m2"]))
    np.testing.assert_allclose(diag, covs * np.eye(3), rtol=1e-12, atol=0)  # absent cross terms are zero


def test_combination_equals_whitened_least_squares():
    # generalised least squares of one point seen three times: stack the whitened observations
    # L_i^-1 x_i = L_i^-1 p + noise and solve by lstsq (an independent route to the same estimate)
    rng = np.random.default_rng(2)
    covs = np.stack([_random_cov(rng, s) for s in (0.01, 0.02, 0.005)])
    x = rng.normal(scale=0.01, size=(3, 3)) + [5.0, -3.0, 2.0]
    df = _shots(["T1"] * 3, x, covs)
    out = combine_shots(df)
    assert len(out) == 1 and out.loc[0, "n_shots"] == 3
    A, b = [], []
    for xi, ci in zip(x, covs):
        Li = np.linalg.cholesky(ci)
        A.append(linalg.solve_triangular(Li, np.eye(3), lower=True))
        b.append(linalg.solve_triangular(Li, xi, lower=True))
    p, *_ = np.linalg.lstsq(np.vstack(A), np.concatenate(b), rcond=None)
    P = np.linalg.inv(np.vstack(A).T @ np.vstack(A))
    r = out.iloc[0]
    got = lla_to_enu(np.array([r.lat, r.lon, r.h]), ORIGIN)[[1, 0, 2]]
    np.testing.assert_allclose(got, p, atol=ATOL_M, rtol=0)
    chi2_dof = sum((xi - p) @ np.linalg.solve(ci, xi - p) for xi, ci in zip(x, covs)) / 6.0
    np.testing.assert_allclose(r.shot_chi2_dof, chi2_dof, rtol=1e-6)
    scale = max(chi2_dof, 1.0)
    np.testing.assert_allclose([r.sigma_n**2, r.sigma_e**2, r.sigma_u**2], np.diag(P) * scale, rtol=1e-6)
    np.testing.assert_allclose([r.cov_ne_m2, r.cov_nu_m2, r.cov_eu_m2], [P[0, 1] * scale, P[0, 2] * scale, P[1, 2] * scale], rtol=1e-6)


def test_agreeing_shots_shrink_sigma_by_root_n_and_scattered_shots_do_not():
    cov = np.diag([0.01, 0.02, 0.03]) ** 2
    agree = _shots(["T"] * 4, np.zeros((4, 3)), np.stack([cov] * 4))
    r = combine_shots(agree).iloc[0]
    np.testing.assert_allclose([r.sigma_n, r.sigma_e, r.sigma_u], np.array([0.01, 0.02, 0.03]) / 2.0, rtol=1e-9)
    assert r.shot_chi2_dof == pytest.approx(0.0, abs=1e-9)
    # shots 10 SD apart in north: chi2/dof = sum((+-5)^2)/dof, sigmas scaled by it
    x = np.array([[0.05, 0, 0], [-0.05, 0, 0]])
    r = combine_shots(_shots(["T"] * 2, x, np.stack([cov] * 2))).iloc[0]
    assert r.shot_chi2_dof == pytest.approx(50.0 / 3.0, rel=1e-6)
    assert r.sigma_n == pytest.approx(0.01 / np.sqrt(2) * np.sqrt(50.0 / 3.0), rel=1e-6)


def test_one_row_per_target_in_order_of_appearance_and_failed_shots():
    cov = np.stack([np.eye(3) * 1e-4] * 5)
    df = _shots(["B", "A", "B", "C", "A"], np.zeros((5, 3)), cov)
    df.loc[3, ["lat", "lon", "h"]] = np.nan  # C's only shot failed
    out = combine_shots(df)
    assert list(out["id"]) == ["B", "A", "C"]
    assert list(out["n_shots"]) == [2, 2, 0] and np.isnan(out.loc[2, "lat"])
    assert out.loc[0, "t_first"] == 0.0 and out.loc[0, "t_last"] == 25.0


def test_shots_without_sigmas_average_with_nan_sigmas():
    df = _shots(["A", "A"], [[1.0, 0, 0], [3.0, 0, 0]], np.stack([np.eye(3)] * 2)).drop(columns=["sigma_n"])
    r = combine_shots(df).iloc[0]
    assert lla_to_enu(np.array([r.lat, r.lon, r.h]), ORIGIN)[1] == pytest.approx(2.0, abs=ATOL_M)
    assert np.isnan(r.sigma_n) and np.isnan(r.ell95_major_m)


def test_ellipse_of_a_rotated_covariance():
    k = np.sqrt(stats.chi2.ppf(0.95, 2))
    for az in (0.0, 30.0, 100.0, 179.0):
        t = np.radians(az)
        u = np.array([np.cos(t), np.sin(t)])  # major axis direction (north, east)
        v = np.array([-np.sin(t), np.cos(t)])
        C = 0.3**2 * np.outer(u, u) + 0.1**2 * np.outer(v, v)
        e = horizontal_ellipse(C)
        np.testing.assert_allclose([e.semi_major_m[0], e.semi_minor_m[0]], [k * 0.3, k * 0.1], rtol=1e-12)
        assert e.azimuth_deg[0] == pytest.approx(az, abs=1e-9)


def test_ellipse_holds_95_percent_of_samples():
    rng = np.random.default_rng(5)
    C = np.array([[0.04, 0.015], [0.015, 0.01]])
    e = horizontal_ellipse(C)
    x = rng.multivariate_normal([0, 0], C, size=20000)
    t = np.radians(e.azimuth_deg[0])
    u = np.array([np.cos(t), np.sin(t)])
    v = np.array([-np.sin(t), np.cos(t)])
    inside = (x @ u / e.semi_major_m[0]) ** 2 + (x @ v / e.semi_minor_m[0]) ** 2 <= 1.0
    # binomial SD of the fraction: sqrt(0.95 * 0.05 / 20000) = 0.0015; 4 SD
    assert abs(inside.mean() - 0.95) < 0.006
