"""Smoothers over a forward and a backward INS/GPS run (paper 003 Sec. 4.2 and beyond).

- `rts`: Rauch-Tung-Striebel on the closed-loop error state about the forward nominal
  (Rauch, Tung, Striebel 1965). The forward filter fed its estimate dx_e back at every epoch,
  so the nominal jumps there: the smoothed error about the PRE-update nominal at epoch e+1 is
  the smoothed error about the post-update nominal plus dx_{e+1}; with that bookkeeping the
  recursion is the textbook one with filtered error 0:
      A_e = P_e Phi_{e+1}^T (P^-_{e+1})^-1,  x^s_e = A_e (x^s_{e+1} + dx_{e+1}),
      P^s_e = P_e + A_e (P^s_{e+1} - P^-_{e+1}) A_e^T.
  Between epochs the smoothed error is interpolated linearly in time.
- `two_filter`: the optimal combination of the forward and backward estimates with their full
  covariances (Fraser-Potter; 15 states, or 18 with GPS error states: their forward and backward
  estimates must be combined too, since both runs saw the same slowly varying fix errors), blended
  about the forward nominal, attitude on SO(3):
      x = K d,  K = P_f (P_f + P_b)^-1,  P = P_f - K P_f,
  d = the backward estimate expressed as an error of the forward nominal.
- `simplified`: paper 003's simplified two-filter smoother (Fig. 2): inside each GPS outage
  the weight of the backward solution grows linearly from 0 at the outage start to 1 at its
  end; outside outages each component is weighted by the inverse of its own variance
  (diagonals only, no matrix inverse, as the paper intends).
Each returns a `Solution` at the requested sample indices. `flag` marks samples where the
forward and backward navigation states disagree beyond the chi-square bound (9 d.o.f.).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tpos_cli.filters.gating import (
    chi2_threshold,  # scipy.special: scipy.stats costs 0.3 s to import
)
from tpos_cli.filters.kalman import (
    cho_solve_matrix_into,
    cholesky_into,
    forward_substitute,
    matmul_into,
)
from tpos_cli.frames import earth, rotation
from tpos_cli.fusion.engine import FilterRun, epoch_of
from tpos_cli.fusion.layout import Block
from tpos_cli.fusion.nav_errors import apply_feedback
from tpos_cli.trajectory import Solution

# error_model="numpy" on every kernel: no zero-divisor test at each division (`tpos_cli.filters.kalman`).

# What runs once per epoch or per output row without a recursion is numpy over all rows at once;
# numba kernels are kept for the recursions (issue 15: each kernel compiles on a fresh install).


@njit(cache=True, error_model="numpy")
def unpack_tril(tril, e, S):
    """S (n, n) = the symmetric matrix whose lower triangle by rows is tril[e] (numpy's
    `tril_indices` order, `fusion.engine.SymmetricStack`)."""
    c = 0
    for i in range(S.shape[0]):
        for j in range(i + 1):
            S[i, j] = tril[e, c]
            S[j, i] = tril[e, c]
            c += 1


@njit(cache=True, error_model="numpy", nogil=True)
def rts_closed_loop(Phi_nav, phi_extra, Ppred_tril, Pfilt_tril, dx):
    """Smoothed errors about the post-feedback nominal at each epoch: (xs_post (E,n), xs_pre (E,n),
    Ps9 (E,m,m)), Ps9 the leading m = min(n, 9) block (navigation) of the smoothed covariance: the
    recursion keeps the full one of the next epoch only (the full history would be the largest array
    of a run).

    Of the forward run's covariance epochs: the transitions, block diagonal, as Phi_nav (E, p, p)
    (p <= n) and phi_extra (E, n - p) the diagonal beyond (`FilterRun.ep_Phi`, `ep_phi_extra`),
    the predicted covariances Ppred_tril (E, n (n + 1) / 2) as lower triangles by rows
    (`FilterRun.ep_Ppred`, numpy's `tril_indices` order), the filtered ones Pfilt_tril likewise
    (`FilterRun.ep_P.tril`) and dx (E, n).
    xs_pre[e] = xs_post[e] + dx[e] is the smoothed error about the pre-update nominal.
    Element loops and Cholesky solves (`filters.kalman`): see there for why.
    """
    E, n = dx.shape
    p = Phi_nav.shape[1]
    m = min(n, 9)
    xs_post = np.zeros((E, n))
    xs_pre = np.zeros((E, n))
    Ps9 = np.empty((E, m, m))
    Ps = np.empty((n, n))  # smoothed covariance of epoch e + 1, then of e
    D = np.empty((n, n))
    T = np.empty((n, n))
    L = np.empty((n, n))
    X = np.empty((n, n))  # A^T
    Phi = np.zeros((n, n))  # the transition of epoch e + 1 (its off-diagonal blocks stay 0)
    Pp = np.empty((n, n))  # the predicted covariance of epoch e + 1
    Pf = np.empty((n, n))  # the filtered covariance of epoch e
    for i in range(n):
        xs_pre[E - 1, i] = dx[E - 1, i]
    unpack_tril(Pfilt_tril, E - 1, Ps)
    for i in range(m):
        for j in range(m):
            Ps9[E - 1, i, j] = Ps[i, j]
    for e in range(E - 2, -1, -1):
        unpack_tril(Ppred_tril, e + 1, Pp)
        unpack_tril(Pfilt_tril, e, Pf)
        for i in range(p):
            for j in range(p):
                Phi[i, j] = Phi_nav[e + 1, i, j]
        for i in range(n - p):
            Phi[p + i, p + i] = phi_extra[e + 1, i]
        # A = P_e Phi_{e+1}^T (P^-_{e+1})^-1: row i solves P^- a = (P_e Phi^T)[i] (both symmetric)
        if not cholesky_into(Pp, L):
            raise ValueError("rts: a predicted covariance is not positive definite")
        # (P_e Phi^T)^T = Phi P_e (P_e symmetric; matmul_into skips Phi's zeros), then
        # X = A^T = (P^-)^-1 Phi P_e for all columns at once
        matmul_into(Phi, Pf, X)
        cho_solve_matrix_into(L, X, X)
        for i in range(n):
            s = 0.0
            for k in range(n):
                s += X[k, i] * xs_pre[e + 1, k]
            xs_post[e, i] = s
            xs_pre[e, i] = s + dx[e, i]
            for j in range(n):
                D[i, j] = Ps[i, j] - Pp[i, j]
        # P^s_e = P_e + A D A^T: T = A D, then the lower triangle of T A^T = T X (rows of D and X
        # contiguous in the inner loops), mirrored: exactly symmetric
        for i in range(n):
            for j in range(n):
                T[i, j] = 0.0
            for k in range(n):
                a = X[k, i]
                for j in range(n):
                    T[i, j] += a * D[k, j]
        for i in range(n):
            for j in range(i + 1):
                Ps[i, j] = 0.0
            for k in range(n):
                a = T[i, k]
                for j in range(i + 1):
                    Ps[i, j] += a * X[k, j]
            for j in range(i + 1):
                Ps[i, j] += Pf[i, j]
                Ps[j, i] = Ps[i, j]
        for i in range(m):
            for j in range(m):
                Ps9[e, i, j] = Ps[i, j]
    return xs_post, xs_pre, Ps9


@njit(cache=True, error_model="numpy", nogil=True)
def _corrected_rows(out_idx, nav, C, bias, xs, o_nav, o_C, o_bias):
    """Row k of o_*: the nominal (nav, C, bias) at sample out_idx[k] corrected by the error estimate xs[k]."""
    R = np.empty((3, 3))
    for k in range(out_idx.shape[0]):
        j = out_idx[k]
        for i in range(6):
            o_nav[k, i] = nav[j, i]
        for i in range(3):
            for m in range(3):
                o_C[k, i, m] = C[j, i, m]
        for i in range(bias.shape[1]):
            o_bias[k, i] = bias[j, i]
        apply_feedback(o_nav[k], o_C[k], o_bias[k], xs[k], R)


def _corrected(run: FilterRun, out_idx, xs):
    """(nav, C, bias) of `run` at `out_idx` corrected by the error estimates xs (K, n)."""
    K = out_idx.size
    o_nav, o_C, o_bias = np.empty((K, 6)), np.empty((K, 3, 3)), np.empty((K, run.bias.shape[1]))
    _corrected_rows(np.ascontiguousarray(run.rows(out_idx), dtype=np.int64), run.nav, run.C_nb, run.bias,
                    np.ascontiguousarray(xs, dtype=float), o_nav, o_C, o_bias)
    return o_nav, o_C, o_bias


def rts(run: FilterRun, out_idx) -> Solution:
    """RTS-smoothed forward run (needs a forward `FilterRun` stored with `store_rts`) at the
    run-local sample indices `out_idx`; `Solution.bias` holds the smoothed IMU biases and extra states.
    Between epochs the smoothed error is interpolated linearly in time."""
    if run.ep_Phi is None:
        raise ValueError("`run` holds no RTS history (run the forward filter with store_rts=True)")
    xs_post, xs_pre, Ps9 = rts_closed_loop(run.ep_Phi, run.ep_phi_extra, run.ep_Ppred, run.ep_P.tril, run.ep_dx)
    ep = run.ep_idx
    E = ep.size
    e = np.clip(np.searchsorted(ep, out_idx, side="right") - 1, 0, E - 1)  # the last epoch at or before
    nxt = np.minimum(e + 1, E - 1)
    t_s = run.t_s
    on_epoch = (ep[e] == out_idx) | (e + 1 >= E)
    span = np.where(on_epoch, 1.0, t_s[ep[nxt]] - t_s[ep[e]])
    a = np.where(on_epoch, 0.0, (t_s[out_idx] - t_s[ep[e]]) / span)[:, None]
    xs = xs_post[e]  # (1 - a) xs_post[e] + a xs_pre[nxt], in place (the hour's (K, n) temporaries)
    xs *= 1.0 - a
    xn = xs_pre[nxt]
    xn *= a
    xs += xn
    xs[on_epoch] = xs_post[e[on_epoch]]
    o_nav, o_C, o_bias = _corrected(run, out_idx, xs)
    return Solution("rts", out_idx, o_nav, o_C, Ps9[e], o_bias)


def state_difference(nav_f, C_f, bias_f, nav_b, C_b, bias_b, d):
    """d (..., n) = state b expressed as an error of nominal f (f minus b, attitude on SO(3)), for
    one row or stacks of rows (nav (..., 6), C (..., 3, 3), bias (..., 6 + extra)); n > 15: the
    extra states are the differences of the extra bias entries (bias[6:], e.g. GPS errors). Returns d."""
    lat = nav_f[..., 0]
    h = nav_f[..., 2]
    d[..., 0] = (nav_f[..., 0] - nav_b[..., 0]) * (earth.meridian_radius_m(lat) + h)
    d[..., 1] = (nav_f[..., 1] - nav_b[..., 1]) * (earth.transverse_radius_m(lat) + h) * np.cos(lat)
    d[..., 2] = -(nav_f[..., 2] - nav_b[..., 2])
    d[..., 3:6] = nav_f[..., 3:6] - nav_b[..., 3:6]
    d[..., 6:9] = rotation.dcm_to_rotvec(C_b @ np.swapaxes(C_f, -1, -2))  # C_f = (I - [phi x]) C_b
    d[..., 9:15] = bias_f[..., :6] - bias_b[..., :6]
    n_extra = d.shape[-1] - 15
    d[..., 15:] = bias_f[..., 6 : 6 + n_extra] - bias_b[..., 6 : 6 + n_extra]
    return d


def _pairs(fwd: FilterRun, bwd: FilterRun, out_idx):
    """For each output sample: (the forward epoch at or before it, the backward epoch at or after it,
    the backward state as an error of the forward nominal (K, n))."""
    ef = np.clip(np.searchsorted(fwd.ep_idx, out_idx, side="right") - 1, 0, fwd.ep_idx.size - 1)
    eb = np.minimum(np.searchsorted(bwd.ep_idx, out_idx, side="left"), bwd.ep_idx.size - 1)
    rf, rb = fwd.rows(out_idx), bwd.rows(out_idx)
    d = state_difference(fwd.nav[rf], fwd.C_nb[rf], fwd.bias[rf], bwd.nav[rb], bwd.C_nb[rb], bwd.bias[rb],
                         np.empty((out_idx.size, fwd.ep_P.shape[1])))
    return ef, eb, d


def delivered_position_rows(fwd: FilterRun, out_idx, C_vb=None) -> tuple[np.ndarray, np.ndarray]:
    """(cols (m,), G (K, 3, m)): the extra states that move the position the fixes measure, and how
    (the position rows of `fusion.measurements.measure`): an IMU-GPS clock offset by +v (a fix
    stamped t holds at IMU time t + d: p + v d; `layout.clock_block`) and a lever-arm correction by
    C_nb C_vb^T (`layout.lever_arm_block`), from the forward run's nominal at out_idx; C_vb: the
    runs' IMU-to-vehicle rotation (identity: the IMU's own axes)."""
    rows = fwd.rows(out_idx)
    cols, parts = [], []
    oc = fwd.layout.offset(Block.CLOCK)
    if oc >= 0:
        cols.append(oc)
        parts.append(fwd.nav[rows, 3:6][:, :, None])
    ol = fwd.layout.offset(Block.LEVER)
    if ol >= 0:
        C_vb = np.eye(3) if C_vb is None else np.asarray(C_vb, dtype=float)
        cols += [ol, ol + 1]
        parts.append(fwd.C_nb[rows] @ C_vb[:2].T)
    if not cols:
        return np.zeros(0, dtype=np.int64), np.zeros((rows.size, 3, 0))
    return np.asarray(cols, dtype=np.int64), np.ascontiguousarray(np.concatenate(parts, axis=2))


def _disagreement(fwd: FilterRun, bwd: FilterRun, ef, eb, d, flag_probability, delivered=None):
    """(flag (K,), nis (K,)): d9^T S^-1 d9 of the two runs' difference against chi-square (9 d.o.f.).

    d9 is the difference of what the runs deliver: velocity and attitude, and the position the
    fixes measure (`delivered_position_rows`: (cols, G)), d9 = T d and S = T (P_f + P_b) T^T with
    T = [I_9 | G on the position rows at cols]. Two runs that split a fix between the IMU's
    position, the clock offset and the lever arm differently still agree on where the antenna
    was when the fix was taken; their IMU positions alone would be tested on a split the fixes
    cannot tell (d = f - b: the delivered difference is dp + v dd_clock + C C_vb^T dd_lever)."""
    cols, G = delivered if delivered is not None else (np.zeros(0, dtype=np.int64), np.zeros((d.shape[0], 3, 0)))
    nis = _disagreement_nis(np.asarray(ef, dtype=np.int64), np.asarray(eb, dtype=np.int64), fwd.ep_P.tril, bwd.ep_P.tril,
                            np.ascontiguousarray(d, dtype=float), np.asarray(cols, dtype=np.int64),
                            np.ascontiguousarray(G, dtype=float))
    return nis > float(chi2_threshold(flag_probability, 9)[9]), nis


@njit(cache=True, error_model="numpy")
def _tri(P, e, i, j):
    """Entry (i, j) of the covariance triangle P[e] (lower, by rows)."""
    if i < j:
        i, j = j, i
    return P[e, i * (i + 1) // 2 + j]


@njit(cache=True, error_model="numpy")
def _disagreement_nis(ef, eb, f_P, b_P, d, cols, G):
    """nis (K,) of `_disagreement` by a Cholesky solve per row: S9 = (P_f + P_b)[:9, :9] from the
    runs' covariance triangles f_P, b_P (E, n (n + 1) / 2) at epochs ef, eb, d9 = d[:, :9]; with
    extra columns cols (m,) on the position rows G (K, 3, m): T S T^T = S9 + E c^T + c E^T + E s E^T
    (E (9, m): G on rows 0-2; c = S[:9, cols], s = S[cols, cols]) and d9 + E d[cols]. NaN where
    the result is not positive definite."""
    K = ef.shape[0]
    m = cols.shape[0]
    nis = np.empty(K)
    S, L = np.empty((9, 9)), np.empty((9, 9))  # T S T^T and its Cholesky factor
    c, s = np.empty((9, m)), np.empty((m, m))
    dd, w = np.empty(9), np.empty(9)  # d9 and L^-1 d9
    for k in range(K):
        for i in range(9):
            for j in range(i + 1):
                S[i, j] = _tri(f_P, ef[k], i, j) + _tri(b_P, eb[k], i, j)
                S[j, i] = S[i, j]
            dd[i] = d[k, i]
        if m > 0:
            for j in range(m):
                for i in range(9):
                    c[i, j] = _tri(f_P, ef[k], cols[j], i) + _tri(b_P, eb[k], cols[j], i)
                for q in range(m):
                    s[j, q] = _tri(f_P, ef[k], cols[j], cols[q]) + _tri(b_P, eb[k], cols[j], cols[q])
            for i in range(3):
                for j in range(m):
                    dd[i] += G[k, i, j] * d[k, cols[j]]
            for a in range(9):
                for b in range(9):
                    add = 0.0
                    for j in range(m):
                        if a < 3:
                            add += G[k, a, j] * c[b, j]
                        if b < 3:
                            add += c[a, j] * G[k, b, j]
                    if a < 3 and b < 3:
                        for j in range(m):
                            for q in range(m):
                                add += G[k, a, j] * s[j, q] * G[k, b, q]
                    S[a, b] += add
        if not cholesky_into(S, L):
            nis[k] = np.nan
            continue
        forward_substitute(L, dd, w)
        acc = 0.0
        for i in range(9):
            acc += w[i] * w[i]
        nis[k] = acc
    return nis


@njit(cache=True, error_model="numpy")
def _combine(ef, eb, f_P, b_P, d, out_w, o_xs, o_P9, mode):
    """Error estimates o_xs (K, n) about the forward nominal and their covariances o_P9 (K, 9, 9).
    f_P, b_P: the runs' covariances as lower triangles (`fusion.engine.SymmetricStack.tril`).
    mode 0: two-filter (full covariances); 1: simplified (paper 003). out_w (K,): weight of the
    backward solution inside outages, NaN outside."""
    last_f = -1
    last_b = -1
    n = d.shape[1]
    K = np.zeros((n, n))
    Pc = np.zeros((n, n))
    Pf = np.empty((n, n))
    Pb = np.empty((n, n))
    for k in range(ef.shape[0]):
        new = ef[k] != last_f or eb[k] != last_b
        if new:
            unpack_tril(f_P, ef[k], Pf)
            unpack_tril(b_P, eb[k], Pb)
            last_f = ef[k]
            last_b = eb[k]
        if mode == 0:
            if new:
                S = Pf + Pb
                K = np.ascontiguousarray(np.linalg.solve(S, Pf).T)  # P_f S^-1 (both symmetric)
                Pc = Pf - K @ Pf
                Pc = 0.5 * (Pc + Pc.T)
            o_xs[k] = K @ d[k]
            o_P9[k] = Pc[:9, :9]
        else:
            w = out_w[k]
            o_P9[k] = 0.0
            for i in range(n):
                if np.isnan(w):
                    wi = Pf[i, i] / (Pf[i, i] + Pb[i, i])
                    var = Pf[i, i] * Pb[i, i] / (Pf[i, i] + Pb[i, i])
                else:
                    wi = w
                    var = (1.0 - w) ** 2 * Pf[i, i] + w * w * Pb[i, i]
                o_xs[k, i] = wi * d[k, i]
                if i < 9:
                    o_P9[k, i, i] = var


def _run_combine(fwd: FilterRun, bwd: FilterRun, out_idx, outages_s, mode):
    ef, eb, d = _pairs(fwd, bwd, out_idx)
    Kn = out_idx.size
    o_xs, o_P9 = np.empty((Kn, d.shape[1])), np.empty((Kn, 9, 9))
    w = outage_weight(fwd.t_s[out_idx], outages_s)
    _combine(ef, eb, fwd.ep_P.tril, bwd.ep_P.tril, d, w, o_xs, o_P9, mode)
    o_nav, o_C, o_bias = _corrected(fwd, out_idx, o_xs)
    return o_nav, o_C, o_P9, o_bias, (ef, eb, d)


def outage_weight(t_s, outages_s) -> np.ndarray:
    """Backward weight of paper 003 Fig. 2: (t - t0) / (t1 - t0) inside an outage [t0, t1), NaN outside."""
    w = np.full(np.shape(t_s), np.nan)
    for t0, t1 in np.asarray(outages_s, dtype=float).reshape(-1, 2):
        m = (t_s >= t0) & (t_s < t1)
        w[m] = (t_s[m] - t0) / (t1 - t0)
    return w


def two_filter(fwd: FilterRun, bwd: FilterRun, out_idx, *, flag_probability=0.999, C_vb=None):
    """Optimal forward/backward combination; returns (Solution, flag (K,), nis (K,)) (`disagreement`)."""
    nav, C, P9, bias, pairs = _run_combine(fwd, bwd, out_idx, np.zeros((0, 2)), 0)
    flag, nis = _disagreement(fwd, bwd, *pairs, flag_probability, delivered_position_rows(fwd, out_idx, C_vb))
    return Solution("two_filter", out_idx, nav, C, P9, bias), flag, nis


def disagreement(fwd: FilterRun, bwd: FilterRun, out_idx, *, flag_probability=0.999, C_vb=None):
    """(flag (K,), nis (K,)): forward/backward NIS of the 9 delivered navigation states (position
    where the fixes measure it: `delivered_position_rows`, C_vb the runs' mounting) against chi-square."""
    return _disagreement(fwd, bwd, *_pairs(fwd, bwd, out_idx), flag_probability, delivered_position_rows(fwd, out_idx, C_vb))


def simplified(fwd: FilterRun, bwd: FilterRun, out_idx, outages_s) -> Solution:
    """Paper 003's simplified two-filter smoother (graded weights in outages, variance weights elsewhere)."""
    nav, C, P9, bias, _ = _run_combine(fwd, bwd, out_idx, outages_s, 1)
    return Solution("simplified", out_idx, nav, C, P9, bias)


def filter_solution(run: FilterRun, out_idx, name) -> Solution:
    """A filter run itself as a `Solution` (covariance of the nearest epoch on the data side)."""
    e = epoch_of(run, out_idx)
    r = run.rows(out_idx)
    return Solution(name, out_idx, run.nav[r], run.C_nb[r], run.ep_P[e, :9, :9], run.bias[r])
