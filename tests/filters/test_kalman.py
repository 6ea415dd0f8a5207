"""Kalman kernels against closed forms and scipy."""

import numpy as np
from scipy.linalg import expm
from scipy.stats import chi2

from tpos_cli.filters.gating import chi2_threshold
from tpos_cli.filters.kalman import (
    cho_solve_matrix_into,
    cholesky_into,
    discretize,
    forward_substitute,
    innovation_statistics,
    nis_of,
    predict,
    predict_trapezoid,
    quadratic_form,
    sandwich_into,
    transition_into,
    update,
    update_holding,
)


def test_scalar_update_closed_form():
    x = np.array([1.0])
    P = np.array([[4.0]])
    nis_pred = nis_of(x, P, np.array([3.0]), np.array([[1.0]]), np.array([[1.0]]))
    nis = update(x, P, np.array([3.0]), np.array([[1.0]]), np.array([[1.0]]))
    # K = 4/5: x = 1 + 0.8 * 2, P = 4 * 1 / 5, NIS = 2^2 / 5
    np.testing.assert_allclose(x, [2.6], rtol=1e-14)
    np.testing.assert_allclose(P, [[0.8]], rtol=1e-14)
    np.testing.assert_allclose([nis, nis_pred], [0.8, 0.8], rtol=1e-14)


def test_update_matches_information_form():
    rng = np.random.default_rng(0)
    n, m = 15, 6
    A = rng.standard_normal((n, n))
    P = A @ A.T + n * np.eye(n)
    x = rng.standard_normal(n)
    H = rng.standard_normal((m, n))
    R = np.diag(rng.uniform(0.5, 2.0, m))
    z = rng.standard_normal(m)
    Pi = np.linalg.inv(np.linalg.inv(P) + H.T @ np.linalg.inv(R) @ H)
    xi = Pi @ (np.linalg.solve(P, x) + H.T @ np.linalg.solve(R, z))
    xk, Pk = x.copy(), P.copy()
    update(xk, Pk, z, H, R)
    np.testing.assert_allclose(xk, xi, rtol=1e-9, atol=1e-11)  # well-conditioned 15x15: ~1e-12 rounding
    np.testing.assert_allclose(Pk, Pi, rtol=1e-9, atol=1e-11)


def test_update_reports_non_pd():
    x = np.zeros(2)
    P = np.zeros((2, 2))
    assert update(x, P, np.zeros(1), np.array([[1.0, 0.0]]), np.array([[0.0]])) == -1.0


def test_nis_of_reports_non_pd():
    """An indefinite S (positive diagonal) gives -1 from both, not an exception: `update` reports it."""
    x, P = np.zeros(2), np.array([[1.0, 2.0], [2.0, 1.0]])
    H, R, z = np.eye(2), np.zeros((2, 2)), np.ones(2)
    assert nis_of(x, P, z, H, R) == -1.0
    assert update(x, P, z, H, R) == -1.0


def test_linear_algebra_kernels_against_numpy():
    rng = np.random.default_rng(4)
    n, m = 7, 3
    A = rng.standard_normal((n, n))
    S = A @ A.T + n * np.eye(n)
    L = np.empty((n, n))
    assert cholesky_into(S, L)
    np.testing.assert_allclose(L, np.linalg.cholesky(S), rtol=1e-13, atol=1e-13)
    b, w = rng.standard_normal(n), np.empty(n)
    forward_substitute(L, b, w)
    np.testing.assert_allclose(L @ w, b, rtol=1e-13, atol=1e-13)
    B, X = rng.standard_normal((n, 4)), np.empty((n, 4))
    cho_solve_matrix_into(L, B, X)
    np.testing.assert_allclose(X, np.linalg.solve(S, B), rtol=1e-12, atol=1e-14)
    M, out = rng.standard_normal((m, n)), np.empty((m, m))
    sandwich_into(M, S, out)
    np.testing.assert_allclose(out, M @ S @ M.T, rtol=1e-13, atol=1e-12)
    a, c = rng.standard_normal(n), rng.standard_normal(n)
    np.testing.assert_allclose(quadratic_form(S, a, c), a @ S @ c, rtol=1e-13)
    assert not cholesky_into(-S, L)


def test_predict():
    x = np.array([1.0, 2.0])
    P = np.eye(2)
    Phi = np.array([[1.0, 0.5], [0.0, 1.0]])
    Qd = np.diag([0.1, 0.2])
    predict(x, P, Phi, Qd)
    np.testing.assert_allclose(x, [2.0, 2.0])
    np.testing.assert_allclose(P, Phi @ Phi.T + Qd, rtol=1e-15)


def test_discretize_against_van_loan():
    """Phi and Qd of a damped oscillator against the exact Van Loan matrix exponential."""
    F = np.array([[0.0, 1.0], [-4.0, -0.3]])
    Qc = np.diag([0.0, 0.5])
    dt = 0.01
    Phi, Qd = np.empty((2, 2)), np.empty((2, 2))
    discretize(F, Qc, dt, Phi, Qd)
    M = expm(np.block([[-F, Qc], [np.zeros((2, 2)), F.T]]) * dt)
    Phi_x = M[2:, 2:].T
    Qd_x = Phi_x @ M[:2, 2:]
    # second-order series: truncation (|F| dt)^3 / 6 = 0.04^3 / 6 ~ 1.1e-5
    np.testing.assert_allclose(Phi, Phi_x, rtol=0, atol=1.1e-5)
    # trapezoidal Qd: error O((|F| dt)^2) = 1.6e-3 relative to its largest element
    np.testing.assert_allclose(Qd, Qd_x, rtol=0, atol=1.6e-3 * np.abs(Qd_x).max())


def test_chi2_threshold():
    g = chi2_threshold(0.95, 6)
    assert g[0] == np.inf
    np.testing.assert_allclose(g[1:], chi2.ppf(0.95, np.arange(1, 7)), rtol=1e-12)
    np.testing.assert_allclose(g[1], 3.841458820694124, rtol=1e-12)  # textbook value


def test_innovation_statistics_against_numpy():
    """NIS, log det S and diag(H P H^T) of a candidate update from one S, against numpy; the state is untouched."""
    rng = np.random.default_rng(8)
    n, m = 18, 3
    A = rng.standard_normal((n, n))
    P = A @ A.T / n + 0.1 * np.eye(n)
    H, x, z = rng.standard_normal((m, n)), rng.standard_normal(n), rng.standard_normal(m)
    R = np.diag(rng.uniform(0.1, 1.0, m))
    x0, P0 = x.copy(), P.copy()
    pvar = np.full(4, np.nan)
    nis, logdet = innovation_statistics(x, P, z, H, R, pvar)
    S = H @ P @ H.T + R
    nu = z - H @ x
    np.testing.assert_allclose(nis, nu @ np.linalg.solve(S, nu), rtol=1e-12)
    np.testing.assert_allclose(logdet, np.linalg.slogdet(S)[1], rtol=1e-12)
    np.testing.assert_allclose(pvar[:m], np.diag(H @ P @ H.T), rtol=1e-12)
    assert np.isnan(pvar[m])  # only the first m are written
    np.testing.assert_array_equal(x, x0)
    np.testing.assert_array_equal(P, P0)
    assert nis_of(x, P, z, H, R) == nis
    bad = innovation_statistics(x, np.array([[1.0, 2.0], [2.0, 1.0]]), np.ones(2), np.eye(2), np.zeros((2, 2)), pvar)
    assert bad[0] == -1.0 and np.isnan(bad[1])


def _joseph_reference(x, P, z, H, R):
    """The textbook update with the full n x n Joseph product, in numpy."""
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    I_KH = np.eye(P.shape[0]) - K @ H
    nu = z - H @ x
    return x + K @ nu, I_KH @ P @ I_KH.T + K @ R @ K.T, nu @ np.linalg.solve(S, nu)


def test_update_rows_one_at_a_time_match_the_joint_joseph_update():
    """m = 1, 2, 3 with a correlated R (decorrelated, then scalar rows) and sparse rows, 21 states."""
    rng = np.random.default_rng(21)
    n = 21
    A = rng.standard_normal((n, n))
    P = A @ A.T / n + 0.05 * np.eye(n)
    for m in (1, 2, 3):
        H = np.zeros((m, n))
        H[:, :6] = rng.standard_normal((m, 6))
        H[:, 15 + m] = 1.0
        B = rng.standard_normal((m, m))
        R = B @ B.T + 0.1 * np.eye(m)
        x, z = rng.standard_normal(n), rng.standard_normal(m)
        x_ref, P_ref, nis_ref = _joseph_reference(x, P, z, H, R)
        xk, Pk = x.copy(), P.copy()
        nis = update(xk, Pk, z, H, R)
        np.testing.assert_allclose(xk, x_ref, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(Pk, P_ref, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(nis, nis_ref, rtol=1e-10)
        np.testing.assert_array_equal(Pk, Pk.T)  # exactly symmetric


def test_update_with_a_singular_R_and_a_failed_update_leaves_the_state():
    """R = 0 (a perfect measurement: zero pivots of R = L D L^T); an S that is not PD changes nothing."""
    x, P = np.array([1.0, 2.0]), np.diag([4.0, 1.0])
    H, z = np.array([[1.0, 0.0], [1.0, 1.0]]), np.array([0.0, 0.0])
    x_ref, P_ref, nis_ref = _joseph_reference(x, P, z, H, np.zeros((2, 2)))
    xk, Pk = x.copy(), P.copy()
    np.testing.assert_allclose(update(xk, Pk, z, H, np.zeros((2, 2))), nis_ref, rtol=1e-12)
    np.testing.assert_allclose(xk, x_ref, atol=1e-12)
    np.testing.assert_allclose(Pk, P_ref, atol=1e-12)
    # an indefinite P: the second whitened row finds s <= 0 after the first was applied
    x, P = np.zeros(2), np.array([[1.0, 2.0], [2.0, 1.0]])
    xk, Pk = x.copy(), P.copy()
    assert update(xk, Pk, np.ones(2), np.eye(2), 1e-3 * np.eye(2)) == -1.0
    np.testing.assert_array_equal(xk, x)
    np.testing.assert_array_equal(Pk, P)


def test_sandwich_and_discretize_skip_zeros_exactly():
    """Sparse A (zeros skipped) and a diagonal Qc (column scaling) against the dense products."""
    rng = np.random.default_rng(5)
    n = 21
    F = np.where(rng.random((n, n)) < 0.15, rng.standard_normal((n, n)), 0.0)
    Qc = np.diag(rng.uniform(0.0, 1.0, n))
    Phi, Qd = np.empty((n, n)), np.empty((n, n))
    discretize(F, Qc, 0.1, Phi, Qd)
    Phi_ref = np.eye(n) + F * 0.1 + F @ F * 0.005
    np.testing.assert_allclose(Phi, Phi_ref, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(Qd, 0.05 * (Phi_ref @ Qc @ Phi_ref.T + Qc), rtol=1e-13, atol=1e-15)
    np.testing.assert_array_equal(Qd, Qd.T)
    Qc[0, 1] = Qc[1, 0] = 0.1  # not diagonal: the general sandwich
    discretize(F, Qc, 0.1, Phi, Qd)
    np.testing.assert_allclose(Qd, 0.05 * (Phi_ref @ Qc @ Phi_ref.T + Qc), rtol=1e-13, atol=1e-15)
    # predict: Phi P Phi^T + Qd of P's symmetric part, exactly symmetric
    A = rng.standard_normal((n, n))
    P = A @ A.T
    P[0, 1] += 1e-9  # a slightly asymmetric P
    P_ref = Phi_ref @ (0.5 * (P + P.T)) @ Phi_ref.T + Qd
    x = np.zeros(n)
    predict(x, P, Phi, Qd)
    np.testing.assert_allclose(P, 0.5 * (P_ref + P_ref.T), rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(P, P.T)



def test_predict_trapezoid_is_discretize_then_predict():
    """P <- Phi (P + Qc dt/2) Phi^T + Qc dt/2: the same equations as discretize's trapezoidal Qd and
    predict, to rounding; P exactly symmetric; x <- Phi x; the transition is discretize's, bit for bit."""
    rng = np.random.default_rng(11)
    n, dt = 20, 0.2
    F = np.where(rng.random((n, n)) < 0.15, rng.standard_normal((n, n)), 0.0)
    Qc = np.diag(rng.uniform(0.0, 1.0, n))
    Qc[2, 5] = Qc[5, 2] = 0.2  # symmetric, not diagonal
    A = rng.standard_normal((n, n))
    P0 = A @ A.T
    x0 = rng.standard_normal(n)
    Phi, Qd = np.empty((n, n)), np.empty((n, n))
    discretize(F, Qc, dt, Phi, Qd)
    x_ref, P_ref = x0.copy(), P0.copy()
    predict(x_ref, P_ref, Phi, Qd)
    Phi2 = np.empty((n, n))
    transition_into(F, dt, Phi2)
    np.testing.assert_array_equal(Phi2, Phi)
    x, P = x0.copy(), P0.copy()
    predict_trapezoid(x, P, Phi2, Qc, dt, np.empty((n, n)), np.empty((n, n)))
    np.testing.assert_allclose(x, x_ref, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(P, P_ref, rtol=1e-12, atol=1e-12 * np.abs(P_ref).max())
    np.testing.assert_array_equal(P, P.T)


def test_update_holding_a_state_is_the_joseph_form_of_the_gain_without_it():
    """`update_holding`: each (decorrelated) row's gain has the held state's entry zeroed; x and P
    are the dense Joseph form's, (I - k h) P (I - k h)^T + k r k^T, for that gain, row after row; the
    held state's estimate and variance are untouched."""
    rng = np.random.default_rng(5)
    n, held = 21, 8
    A = rng.standard_normal((n, n))
    P = A @ A.T / n + 0.05 * np.eye(n)
    for m in (1, 3):
        H = rng.standard_normal((m, n))
        R = np.diag(rng.uniform(0.1, 1.0, m))  # diagonal: the rows are processed as they are
        x, z = rng.standard_normal(n), rng.standard_normal(m)
        x_ref, P_ref = x.copy(), P.copy()
        for i in range(m):
            h = H[i]
            s = h @ P_ref @ h + R[i, i]
            k = P_ref @ h / s
            k[held] = 0.0
            x_ref = x_ref + k * (z[i] - h @ x_ref)
            IKH = np.eye(n) - np.outer(k, h)
            P_ref = IKH @ P_ref @ IKH.T + R[i, i] * np.outer(k, k)
        xk, Pk = x.copy(), P.copy()
        nis = update_holding(xk, Pk, z, H, R, held)
        np.testing.assert_allclose(xk, x_ref, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(Pk, P_ref, rtol=1e-10, atol=1e-12)
        assert xk[held] == x[held] and Pk[held, held] == P[held, held]
        if m == 1:  # one row: its NIS is the prior's (later rows' s use the P the held gain left)
            np.testing.assert_allclose(nis, update(x.copy(), P.copy(), z, H, R), rtol=1e-10)
