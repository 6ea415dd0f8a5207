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
from tpos_cli.frames._kernels import dcm_to_rotvec, radii_m
from tpos_cli.fusion.engine import FilterRun, epoch_of
from tpos_cli.fusion.nav_errors import apply_feedback
from tpos_cli.trajectory import Solution


@njit(cache=True)
def rts_closed_loop(Phi, Ppred, Pfilt, dx):
    """Smoothed errors about the post-feedback nominal at each epoch: (xs_post (E,n), xs_pre (E,n),
    Ps9 (E,9,9)), Ps9 the navigation block (all of it below 9 states) of the smoothed covariance (the recursion keeps the
    full one of the next epoch only: the full history would be the largest array of a run).

    xs_pre[e] = xs_post[e] + dx[e] is the smoothed error about the pre-update nominal.
    """
    E, n = dx.shape
    xs_post = np.zeros((E, n))
    xs_pre = np.zeros((E, n))
    m = min(n, 9)
    Ps9 = np.empty((E, m, m))
    Ps = Pfilt[E - 1].copy()
    Ps9[E - 1] = Ps[:m, :m]
    xs_pre[E - 1] = dx[E - 1]
    for e in range(E - 2, -1, -1):
        # A^T = (P^-_{e+1})^-1 Phi_{e+1} P_e, by a solve (P^- symmetric)
        At = np.linalg.solve(Ppred[e + 1], Phi[e + 1] @ Pfilt[e])
        A = At.T
        xs_post[e] = A @ xs_pre[e + 1]
        Pn = Pfilt[e] + A @ (Ps - Ppred[e + 1]) @ At
        Ps = 0.5 * (Pn + Pn.T)
        Ps9[e] = Ps[:m, :m]
        xs_pre[e] = xs_post[e] + dx[e]
    return xs_post, xs_pre, Ps9


@njit(cache=True)
def _corrected_into(nav, C, bias, x, o_nav, o_C, o_bias):
    """The nominal (nav, C, bias) corrected by the error estimate x, written to o_* (inputs kept)."""
    o_nav[:] = nav
    o_C[:, :] = C
    o_bias[:] = bias
    apply_feedback(o_nav, o_C, o_bias, x)


@njit(cache=True)
def _rts_apply(out_idx, ep_idx, ep_t, t, nav, C, bias, xs_post, xs_pre, Ps9, o_nav, o_C, o_bias, o_P9):
    e = 0
    E = ep_idx.shape[0]
    for k in range(out_idx.shape[0]):
        j = out_idx[k]
        while e + 1 < E and ep_idx[e + 1] <= j:
            e += 1
        if ep_idx[e] == j or e + 1 >= E:
            xs = xs_post[e].copy()
        else:
            a = (t[j] - ep_t[e]) / (ep_t[e + 1] - ep_t[e])
            xs = (1.0 - a) * xs_post[e] + a * xs_pre[e + 1]
        _corrected_into(nav[j], C[j], bias[j], xs, o_nav[k], o_C[k], o_bias[k])
        o_P9[k] = Ps9[e]


def rts(run: FilterRun, out_idx) -> Solution:
    """RTS-smoothed forward run (needs a forward `FilterRun` stored with `store_rts`) at the
    run-local sample indices `out_idx`; `Solution.bias` holds the smoothed IMU biases and extra states."""
    if run.ep_Phi is None:
        raise ValueError("`run` holds no RTS history (run the forward filter with store_rts=True)")
    xs_post, xs_pre, Ps9 = rts_closed_loop(run.ep_Phi, run.ep_Ppred, run.ep_P, run.ep_dx)
    K = out_idx.size
    o_nav, o_C, o_P9 = np.empty((K, 6)), np.empty((K, 3, 3)), np.empty((K, 9, 9))
    o_bias = np.empty((K, run.bias.shape[1]))
    t_s = run.t_s
    _rts_apply(out_idx, run.ep_idx, t_s[run.ep_idx], t_s, run.nav, run.C_nb, run.bias, xs_post, xs_pre, Ps9,
               o_nav, o_C, o_bias, o_P9)
    return Solution("rts", out_idx, o_nav, o_C, o_P9, o_bias)


@njit(cache=True)
def state_difference(nav_f, C_f, bias_f, nav_b, C_b, bias_b, d):
    """d (n,) = state b expressed as an error of nominal f (f minus b, attitude on SO(3)); n > 15:
    the extra states are the differences of the extra bias entries (bias[6:], e.g. GPS errors)."""
    lat = nav_f[0]
    h = nav_f[2]
    rn, re = radii_m(lat)
    d[0] = (nav_f[0] - nav_b[0]) * (rn + h)
    d[1] = (nav_f[1] - nav_b[1]) * (re + h) * np.cos(lat)
    d[2] = -(nav_f[2] - nav_b[2])
    for i in range(3):
        d[3 + i] = nav_f[3 + i] - nav_b[3 + i]
    phi = dcm_to_rotvec(C_b @ C_f.T)  # C_f = (I - [phi x]) C_b
    for i in range(3):
        d[6 + i] = phi[i]
    for i in range(6):
        d[9 + i] = bias_f[i] - bias_b[i]
    for i in range(d.shape[0] - 15):
        d[15 + i] = bias_f[6 + i] - bias_b[6 + i]


@njit(cache=True)
def _quadratic_form(d, A):
    """d[:m]^T A d[:m] for A (m, m), by loops (no temporary, any memory layout)."""
    m = A.shape[0]
    v = 0.0
    for i in range(m):
        a = 0.0
        for j in range(m):
            a += A[i, j] * d[j]
        v += d[i] * a
    return v


@njit(cache=True)
def _combine(out_idx, t, f_nav, f_C, f_bias, f_ep, f_P, b_nav, b_C, b_bias, b_ep, b_P,
             out_w, flag_thr, o_nav, o_C, o_P9, o_flag, o_nis, mode):
    """mode 0: two-filter (full covariances); 1: simplified (paper 003); 2: flag and NIS only.
    out_w (K,): weight of the backward solution inside outages, NaN outside."""
    ef = 0
    eb = 0
    Ef = f_ep.shape[0]
    Eb = b_ep.shape[0]
    last_f = -1
    last_b = -1
    n = f_P.shape[1]
    K = np.zeros((n, n))
    Pc = np.zeros((n, n))
    S9i = np.zeros((9, 9))
    d = np.empty(n)
    for k in range(out_idx.shape[0]):
        j = out_idx[k]
        while ef + 1 < Ef and f_ep[ef + 1] <= j:
            ef += 1
        while eb < Eb - 1 and b_ep[eb] < j:
            eb += 1
        Pf = f_P[ef]
        Pb = b_P[eb]
        if ef != last_f or eb != last_b:
            S = Pf + Pb
            if mode == 0:
                K = np.ascontiguousarray(np.linalg.solve(S, Pf).T)  # P_f S^-1 (both symmetric)
                Pc = Pf - K @ Pf
                Pc = 0.5 * (Pc + Pc.T)
            S9i = np.linalg.inv(np.ascontiguousarray(S[:9, :9]))
            last_f = ef
            last_b = eb
        state_difference(f_nav[j], f_C[j], f_bias[j], b_nav[j], b_C[j], b_bias[j], d)
        nis = _quadratic_form(d, S9i)
        o_nis[k] = nis
        o_flag[k] = nis > flag_thr
        if mode == 2:  # flag only
            continue
        if mode == 0:
            xs = K @ d
            o_P9[k] = Pc[:9, :9]
        else:
            xs = np.empty(n)
            w = out_w[k]
            o_P9[k] = 0.0
            for i in range(n):
                if np.isnan(w):
                    wi = Pf[i, i] / (Pf[i, i] + Pb[i, i])
                    var = Pf[i, i] * Pb[i, i] / (Pf[i, i] + Pb[i, i])
                else:
                    wi = w
                    var = (1.0 - w) ** 2 * Pf[i, i] + w * w * Pb[i, i]
                xs[i] = wi * d[i]
                if i < 9:
                    o_P9[k, i, i] = var
        _corrected_into(f_nav[j], f_C[j], f_bias[j], xs, o_nav[k], o_C[k], np.empty(f_bias.shape[1]))


def _run_combine(fwd: FilterRun, bwd: FilterRun, out_idx, outages_s, flag_probability, mode):
    Kn = out_idx.size
    o_nav, o_C, o_P9 = np.empty((Kn, 6)), np.empty((Kn, 3, 3)), np.empty((Kn, 9, 9))
    o_flag = np.zeros(Kn, dtype=np.bool_)
    o_nis = np.empty(Kn)
    t_s = fwd.t_s
    w = outage_weight(t_s[out_idx], outages_s)
    _combine(out_idx, t_s, fwd.nav, fwd.C_nb, fwd.bias, fwd.ep_idx, fwd.ep_P, bwd.nav, bwd.C_nb, bwd.bias,
             bwd.ep_idx, bwd.ep_P, w, float(chi2_threshold(flag_probability, 9)[9]), o_nav, o_C, o_P9, o_flag, o_nis, mode)
    return o_nav, o_C, o_P9, o_flag, o_nis


def outage_weight(t_s, outages_s) -> np.ndarray:
    """Backward weight of paper 003 Fig. 2: (t - t0) / (t1 - t0) inside an outage [t0, t1), NaN outside."""
    w = np.full(np.shape(t_s), np.nan)
    for t0, t1 in np.asarray(outages_s, dtype=float).reshape(-1, 2):
        m = (t_s >= t0) & (t_s < t1)
        w[m] = (t_s[m] - t0) / (t1 - t0)
    return w


def two_filter(fwd: FilterRun, bwd: FilterRun, out_idx, *, flag_probability=0.999):
    """Optimal forward/backward combination; returns (Solution, flag (K,), nis (K,))."""
    nav, C, P9, flag, nis = _run_combine(fwd, bwd, out_idx, np.zeros((0, 2)), flag_probability, 0)
    return Solution("two_filter", out_idx, nav, C, P9), flag, nis


def disagreement(fwd: FilterRun, bwd: FilterRun, out_idx, *, flag_probability=0.999):
    """(flag (K,), nis (K,)): forward/backward NIS of the 9 navigation states against chi-square."""
    _, _, _, flag, nis = _run_combine(fwd, bwd, out_idx, np.zeros((0, 2)), flag_probability, 2)
    return flag, nis


def simplified(fwd: FilterRun, bwd: FilterRun, out_idx, outages_s) -> Solution:
    """Paper 003's simplified two-filter smoother (graded weights in outages, variance weights elsewhere)."""
    nav, C, P9, _, _ = _run_combine(fwd, bwd, out_idx, outages_s, 0.999, 1)
    return Solution("simplified", out_idx, nav, C, P9)


def filter_solution(run: FilterRun, out_idx, name) -> Solution:
    """A filter run itself as a `Solution` (covariance of the nearest epoch on the data side)."""
    e = epoch_of(run, out_idx)
    return Solution(name, out_idx, run.nav[out_idx], run.C_nb[out_idx], run.ep_P[e, :9, :9])
