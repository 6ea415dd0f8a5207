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


def _gls(x, covs):
    """Generalised least squares of one point seen len(x) times, by stacking the whitened
    observations L_i^-1 x_i = L_i^-1 p + noise and solving with lstsq (an independent route)."""
    A, b = [], []
    for xi, ci in zip(x, covs):
        Li = np.linalg.cholesky(ci)
        A.append(linalg.solve_triangular(Li, np.eye(3), lower=True))
        b.append(linalg.solve_triangular(Li, xi, lower=True))
    p, *_ = np.linalg.lstsq(np.vstack(A), np.concatenate(b), rcond=None)
    return p, np.linalg.inv(np.vstack(A).T @ np.vstack(A))


def _combined(row):
    p = lla_to_enu(np.array([row.lat, row.lon, row.h]), ORIGIN)[[1, 0, 2]]
    P = np.array(
        [
            [row.sigma_n**2, row.cov_ne_m2, row.cov_nu_m2],
            [row.cov_ne_m2, row.sigma_e**2, row.cov_eu_m2],
            [row.cov_nu_m2, row.cov_eu_m2, row.sigma_u**2],
        ]
    )
    return p, P


def test_point_is_the_inverse_covariance_weighted_estimate():
    rng = np.random.default_rng(2)
    covs = np.stack([_random_cov(rng, s) for s in (0.01, 0.02, 0.005)])
    x = rng.normal(scale=0.01, size=(3, 3)) + [5.0, -3.0, 2.0]
    out = combine_shots(_shots(["T1"] * 3, x, covs))
    assert len(out) == 1 and out.loc[0, "n_shots"] == 3
    p, P_ind = _gls(x, covs)
    got, _ = _combined(out.iloc[0])
    np.testing.assert_allclose(got, p, atol=ATOL_M, rtol=0)
    f = sum((xi - p) @ np.linalg.solve(ci, xi - p) for xi, ci in zip(x, covs)) / 6.0
    np.testing.assert_allclose(out.loc[0, "shot_chi2_dof"], f, rtol=1e-6)


def test_independent_looking_shots_average_and_scattered_shots_scale_up():
    # four shots of equal covariance placed so that their scatter is exactly what the covariance
    # predicts (chi2/dof = 1): the independent model, sigma / sqrt(4)
    sd = np.array([0.01, 0.02, 0.03])
    cov = np.diag(sd**2)
    u = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=float)  # zero-mean, orthogonal columns
    x = u * sd * np.sqrt(9.0 / 12.0)  # chi2 = sum of (x/sd)^2 = 12 * 9/12 = 9 = dof (3 x 3): f = 1
    r = combine_shots(_shots(["T"] * 4, x, np.stack([cov] * 4))).iloc[0]
    assert r.shot_chi2_dof == pytest.approx(1.0, rel=1e-6)  # 1e-6: the shots go through lat/lon and back
    np.testing.assert_allclose([r.sigma_n, r.sigma_e, r.sigma_u], sd / 2.0, rtol=1e-6)
    # twice as far apart: chi2/dof = 4, sigmas scaled by sqrt(4)
    r = combine_shots(_shots(["T"] * 4, 2 * x, np.stack([cov] * 4))).iloc[0]
    assert r.shot_chi2_dof == pytest.approx(4.0, rel=1e-6)
    np.testing.assert_allclose([r.sigma_n, r.sigma_e, r.sigma_u], sd / 2.0 * 2.0, rtol=1e-6)


def test_agreeing_shots_keep_a_single_shots_sigma():
    # identical shots show no independent error: nothing averages out (full correlation)
    cov = np.diag([0.01, 0.02, 0.03]) ** 2
    r = combine_shots(_shots(["T"] * 5, np.zeros((5, 3)), np.stack([cov] * 5))).iloc[0]
    assert r.shot_chi2_dof == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose([r.sigma_n, r.sigma_e, r.sigma_u], [0.01, 0.02, 0.03], rtol=1e-9)


def test_partly_independent_shots_mix_the_two_models():
    # f < 1: P = (1 - f) P_cor + f P_ind, with P_cor of fully correlated errors e_i = L_i z
    rng = np.random.default_rng(7)
    covs = np.stack([_random_cov(rng, s) for s in (0.02, 0.03)])
    x = rng.normal(scale=0.002, size=(2, 3))  # far closer than their sigmas: f << 1
    r = combine_shots(_shots(["T"] * 2, x, covs)).iloc[0]
    p, P_ind = _gls(x, covs)
    f = sum((xi - p) @ np.linalg.solve(ci, xi - p) for xi, ci in zip(x, covs)) / 3.0
    assert 0.0 < f < 1.0
    A = [P_ind @ np.linalg.inv(c) for c in covs]  # the weights of the two shots
    M = sum(a @ np.linalg.cholesky(c) for a, c in zip(A, covs))
    _, P = _combined(r)
    np.testing.assert_allclose(P, (1 - f) * M @ M.T + f * P_ind, rtol=1e-6, atol=1e-12)


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
