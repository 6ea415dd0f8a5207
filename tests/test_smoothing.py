"""Smoothers: closed-loop RTS against the batch (joint Gaussian) solution; the combination rules."""

import numpy as np
import pytest

from tpos_cli.frames import rotation
from tpos_cli.smoothing import outage_weight, rts_closed_loop, state_difference


def _linear_problem(seed=0, n=4, m=2, K=30):
    rng = np.random.default_rng(seed)
    Phi = np.eye(n) + 0.2 / np.sqrt(n) * rng.standard_normal((n, n))  # spectral spread independent of n
    Q = np.diag(rng.uniform(0.01, 0.1, n))
    H = rng.standard_normal((m, n))
    R = np.diag(rng.uniform(0.1, 1.0, m))
    P0 = np.eye(n)
    x = rng.standard_normal(n)
    zs = []
    for _ in range(K):
        zs.append(H @ x + rng.multivariate_normal(np.zeros(m), R))
        x = Phi @ x + rng.multivariate_normal(np.zeros(n), Q)
    return Phi, Q, H, R, P0, np.array(zs)


def _batch_smoother(Phi, Q, H, R, P0, zs):
    """Posterior mean and marginal covariances of x_0..x_{K-1} by the information form."""
    K, n = zs.shape[0], Phi.shape[0]
    N = K * n
    Lam = np.zeros((N, N))
    eta = np.zeros(N)
    Qi, Ri = np.linalg.inv(Q), np.linalg.inv(R)
    Lam[:n, :n] += np.linalg.inv(P0)
    for k in range(K):
        s = slice(k * n, (k + 1) * n)
        Lam[s, s] += H.T @ Ri @ H
        eta[s] += H.T @ Ri @ zs[k]
        if k + 1 < K:
            s1 = slice((k + 1) * n, (k + 2) * n)
            Lam[s, s] += Phi.T @ Qi @ Phi
            Lam[s1, s1] += Qi
            Lam[s, s1] -= Phi.T @ Qi
            Lam[s1, s] -= Qi @ Phi
    cov = np.linalg.inv(Lam)
    mean = cov @ eta
    return mean.reshape(K, n), np.array([cov[k * n:(k + 1) * n, k * n:(k + 1) * n] for k in range(K)])


def _tril(P):
    """Lower triangles by rows (E, n (n + 1) / 2), the RTS history's storage of symmetric P (E, n, n)."""
    i, j = np.tril_indices(P.shape[1])
    return np.ascontiguousarray(P[:, i, j])


@pytest.mark.parametrize("n", [4, 12])
def test_closed_loop_rts_equals_batch_solution(n):
    """n = 12: the smoother returns the covariance's leading 9 x 9 (navigation) block only."""
    Phi, Q, H, R, P0, zs = _linear_problem(n=n)
    K = zs.shape[0]
    # Kalman filter written as a closed-loop (feedback) filter: the nominal is the estimate,
    # the correction dx fed back at each epoch is x_pred - x_filt (errors are nominal - truth)
    ePhi, ePpred, ePfilt, edx, xf = (np.empty((K, n, n)), np.empty((K, n, n)), np.empty((K, n, n)),
                                      np.empty((K, n)), np.empty((K, n)))
    x, P = np.zeros(n), P0.copy()
    for k in range(K):
        if k > 0:
            x, P = Phi @ x, Phi @ P @ Phi.T + Q
        ePhi[k], ePpred[k] = Phi, 0.5 * (P + P.T)  # stored symmetric, as the filter kernel's (a triangle)
        S = H @ P @ H.T + R
        G = P @ H.T @ np.linalg.inv(S)
        x_new = x + G @ (zs[k] - H @ x)
        edx[k] = x - x_new
        x, P = x_new, (np.eye(n) - G @ H) @ P
        ePfilt[k], xf[k] = 0.5 * (P + P.T), x  # stored symmetric too (`SymmetricStack`: a triangle)
    xs_post, xs_pre, Ps = rts_closed_loop(ePhi, np.zeros((K, 0)), _tril(ePpred), _tril(ePfilt), edx)
    mean, cov = _batch_smoother(Phi, Q, H, R, P0, zs)
    # both exact; differences are rounding of a 120x120 inverse (~1e-12)
    np.testing.assert_allclose(xf - xs_post, mean, rtol=0, atol=1e-9)
    m = min(n, 9)
    np.testing.assert_allclose(Ps, cov[:, :m, :m], rtol=0, atol=1e-9)
    # the smoother at the last epoch is the filter; smoothed covariance never exceeds filtered
    np.testing.assert_allclose(xs_post[-1], 0.0, atol=0)
    assert all(np.linalg.eigvalsh(ePfilt[k, :m, :m] - Ps[k]).min() > -1e-12 for k in range(K))


def test_rts_block_diagonal_transition_equals_full():
    """The filter's RTS history stores Phi as its leading block and the diagonal beyond: the same
    smoothed errors and covariances as the full Phi."""
    Phi, Q, H, R, P0, zs = _linear_problem(seed=2, n=6)
    K, n, p = zs.shape[0], 6, 4
    Phi[:p, p:] = 0.0
    Phi[p:, :p] = 0.0
    Phi[p:, p:] = np.diag([0.99, 1.0])
    rng = np.random.default_rng(3)
    ePhi = np.repeat(Phi[None], K, 0)
    ePfilt = np.array([P0 * (0.5 + 0.1 * k) for k in range(K)])
    ePpred = ePfilt + np.diag(np.diag(Q))[None]
    dx = 0.1 * rng.standard_normal((K, n))
    full = rts_closed_loop(ePhi, np.zeros((K, 0)), _tril(ePpred), _tril(ePfilt), dx)
    block = rts_closed_loop(np.ascontiguousarray(ePhi[:, :p, :p]), np.ascontiguousarray(ePhi[:, [4, 5], [4, 5]]),
                            _tril(ePpred), _tril(ePfilt), dx)
    for a, b in zip(full, block):
        np.testing.assert_array_equal(a, b)


def test_rts_without_feedback_bookkeeping_is_wrong():
    """Dropping dx (the issue's pitfall) returns the forward solution: the test above has power."""
    Phi, Q, H, R, P0, zs = _linear_problem(seed=1)
    K, n = zs.shape[0], Phi.shape[0]
    ePhi = np.repeat(Phi[None], K, 0)
    ePpred = np.repeat(P0[None], K, 0)
    ePfilt = np.repeat(0.5 * P0[None], K, 0)
    xs_post, _, _ = rts_closed_loop(ePhi, np.zeros((K, 0)), _tril(ePpred), _tril(ePfilt), np.zeros((K, n)))
    np.testing.assert_array_equal(xs_post, 0.0)


def test_outage_weight_grades_linearly():
    t = np.array([0.0, 10.0, 12.5, 15.0, 17.5, 20.0, 25.0])
    w = outage_weight(t, np.array([[10.0, 20.0]]))
    np.testing.assert_allclose(w[1:5], [0.0, 0.25, 0.5, 0.75])
    assert np.isnan(w[[0, 5, 6]]).all()


@pytest.mark.slow
def test_smoothed_nees_inside_outages_is_consistent(tmp_path):
    """Monte Carlo: RTS and two-filter NEES inside a 30 s outage average to their 9 d.o.f.

    The rows of one outage are nearly one draw (the smoothed error is a smooth curve across it),
    so the mean over n drives is judged as a mean of n chi-square(9) values: SD sqrt(18 / n),
    95% band 9 +- 1.96 sqrt(18 / n) (conservative: rows are not fully correlated).
    """
    from tpos_cli.chains.drive_smooth import process_drive
    from tpos_cli.config import DriveSmoothParams
    from tpos_cli.frames.geodetic import lla_to_ned
    from tpos_cli.frames.rotation import dcm_to_rotvec
    from tpos_cli.session import load_session
    from tpos_cli.sim.drive import simulate_drive

    seeds = range(101, 125)
    nees = {"rts": [], "two_filter": []}
    for seed in seeds:
        sim = simulate_drive(420.0, seed=seed, outages=((200.0, 30.0),))
        session = load_session(sim.write(tmp_path / f"s{seed}"))
        res = process_drive(session, DriveSmoothParams(gps_sigma_vel_mps=0.05), None, names=tuple(nees))
        tr = sim.truth
        for name in nees:
            sol = res.solutions[name]
            t = tr.t_s[sol.idx]
            m = (t >= 200.0) & (t < 230.0)
            idx = sol.idx[m]
            lla = np.column_stack([np.degrees(sol.nav[m, 0]), np.degrees(sol.nav[m, 1]), sol.nav[m, 2]])
            e = np.column_stack([lla_to_ned(lla, tr.lla[0]) - lla_to_ned(tr.lla[idx], tr.lla[0]),
                                 sol.nav[m, 3:] - tr.vel_ned_mps[idx],
                                 -dcm_to_rotvec(sol.C_nb[m] @ np.transpose(tr.C_nb[idx], (0, 2, 1)))])
            nees[name].append(np.mean(np.einsum("ki,ki->k", e, np.linalg.solve(sol.P9[m], e[..., None])[..., 0])))
    half = 1.96 * np.sqrt(18.0 / len(seeds))
    for name, v in nees.items():
        assert abs(np.mean(v) - 9.0) < half, (name, np.mean(v), half)


def test_state_difference_of_stacks_is_that_of_each_row():
    """The vectorized difference over rows against one row at a time, and its attitude part exact."""
    rng = np.random.default_rng(5)
    K = 4
    nav_f = np.column_stack([np.radians(45.0 + rng.normal(0, 1, K)), np.radians(7.0 + rng.normal(0, 1, K)),
                             rng.normal(100, 10, K), rng.normal(0, 5, (K, 3))])
    nav_b = nav_f + np.column_stack([rng.normal(0, 1e-6, (K, 2)), rng.normal(0, 1, K), rng.normal(0, 0.1, (K, 3))])
    C_b = rotation.euler_to_dcm(*rng.uniform(-1, 1, (3, K)))
    phi = rng.normal(0, 0.01, (K, 3))
    C_f = np.swapaxes(rotation.rotvec_to_dcm(phi), 1, 2) @ C_b  # C_b C_f^T = R(phi)
    bias_f, bias_b = rng.normal(size=(K, 9)), rng.normal(size=(K, 9))
    d = state_difference(nav_f, C_f, bias_f, nav_b, C_b, bias_b, np.empty((K, 18)))
    for i in range(K):
        np.testing.assert_array_equal(d[i], state_difference(nav_f[i], C_f[i], bias_f[i], nav_b[i], C_b[i], bias_b[i],
                                                             np.empty(18)))
    np.testing.assert_allclose(d[:, 6:9], phi, rtol=0, atol=1e-15)
    np.testing.assert_allclose(d[:, 15:], bias_f[:, 6:] - bias_b[:, 6:], rtol=0, atol=0)
    np.testing.assert_allclose(d[:, 2], nav_b[:, 2] - nav_f[:, 2], rtol=0, atol=0)


def test_disagreement_tests_the_delivered_position():
    """The forward/backward NIS with a clock state and lever-arm states equals the dense
    d9' = T d, S' = T (P_f + P_b) T^T, T = [I_9 | G on the position rows at the extra columns]
    (the position the fixes measure: p + v d_clock + A d_lever), row by row; without extra columns
    it is the 9-state NIS; two runs whose difference is all in that split read ~0."""
    from tpos_cli.smoothing import _disagreement_nis

    rng = np.random.default_rng(5)
    n, K = 19, 4  # 15 + clock (2) + lever (2)
    cols = np.array([15, 17, 18], dtype=np.int64)
    tri = np.tril_indices(n)
    f_P, b_P, P_full = [], [], []
    for _ in range(K):
        A, B = rng.normal(size=(n, n)), rng.normal(size=(n, n))
        Pf, Pb = A @ A.T / n + 0.1 * np.eye(n), B @ B.T / n + 0.1 * np.eye(n)
        f_P.append(Pf[tri])
        b_P.append(Pb[tri])
        P_full.append(Pf + Pb)
    d = rng.normal(size=(K, n))
    G = rng.normal(size=(K, 3, cols.size))
    ek = np.arange(K, dtype=np.int64)
    nis = _disagreement_nis(ek, ek, np.array(f_P), np.array(b_P), d, cols, G)
    for k in range(K):
        T = np.zeros((9, n))
        T[:, :9] = np.eye(9)
        T[:3, cols] = G[k]
        d9, S = T @ d[k], T @ P_full[k] @ T.T
        np.testing.assert_allclose(nis[k], d9 @ np.linalg.solve(S, d9), rtol=1e-10)
    plain = _disagreement_nis(ek, ek, np.array(f_P), np.array(b_P), d, np.zeros(0, dtype=np.int64), np.zeros((K, 3, 0)))
    for k in range(K):
        np.testing.assert_allclose(plain[k], d[k, :9] @ np.linalg.solve(P_full[k][:9, :9], d[k, :9]), rtol=1e-10)
    split = np.zeros((1, n))
    split[0, 15], split[0, 17] = 0.05, 0.2  # runs differing by 0.05 s of clock and 0.2 m of lever ...
    split[0, :3] = -(G[0] @ split[0, cols])  # ... and the IMU positions that put the antenna at the same fix
    zero = _disagreement_nis(ek[:1], ek[:1], np.array(f_P[:1]), np.array(b_P[:1]), split, cols, G[:1])
    assert zero[0] < 1e-20
