"""Compiled INS/GPS loop: mechanize every IMU sample, predict at covariance epochs, update at fixes.

The same kernel serves the forward run and the backward run (reversed arrays, earth_sign = -1).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tpos_cli.filters.kalman import discretize, nis_of, predict, update
from tpos_cli.fusion.nav_errors import (
    apply_feedback,
    corrected_increments,
    error_dynamics,
    position_jacobian,
    position_residual,
    process_noise,
    velocity_jacobian,
    velocity_residual,
)
from tpos_cli.ins._kernels import mech_step


@njit(cache=True)
def mechanize_sample(k, t, gyro, acc, nav, C, bias, earth_sign, dth, dv, dth_prev, dv_prev, f_n, f_sum):
    """Advance the nominal over IMU interval k (bias-corrected increments, coning/sculling memory)
    and accumulate the navigation-frame specific force over the current covariance interval.

    The per-sample half of every error-state loop (INS/GPS here, INS/range in `ranging`); returns dt.
    """
    dt = t[k] - t[k - 1]
    corrected_increments(gyro[k], acc[k], bias, dt, dth, dv)
    mech_step(nav, C, dth, dv, dth_prev, dv_prev, dt, earth_sign, f_n)
    for i in range(3):
        dth_prev[i] = dth[i]
        dv_prev[i] = dv[i]
        f_sum[i] += f_n[i] * dt
    return dt


@njit(cache=True)
def start_epochs(P, ep_idx, ep_P, ep_dx, ep_Phi, ep_Ppred, store_rts):
    """Covariance epoch 0 is the prior at sample 0 (what the smoothers start from); returns 0."""
    ep_idx[0] = 0
    ep_P[0] = P
    ep_dx[0] = 0.0
    if store_rts:
        ep_Phi[0] = np.eye(P.shape[0])
        ep_Ppred[0] = P
    return 0


@njit(cache=True)
def predict_epoch(nav, C, f_sum, dt_sum, earth_sign, tau_acc_s, tau_gyro_s, F, Qc, Phi, Qd, x, P,
                  ep, k, ep_idx, ep_Phi, ep_Ppred, store_rts):
    """Open covariance epoch ep + 1 at sample k: F from the mean specific force, Van Loan Phi/Qd,
    predict (x, P), and store what RTS needs. Returns the new epoch index."""
    error_dynamics(nav, C, f_sum / dt_sum, earth_sign, tau_acc_s, tau_gyro_s, F)
    discretize(F, Qc, dt_sum, Phi, Qd)
    predict(x, P, Phi, Qd)
    ep += 1
    ep_idx[ep] = k
    if store_rts:
        ep_Phi[ep] = Phi
        ep_Ppred[ep] = P
    return ep


@njit(cache=True)
def _log_det(S):
    """log det of a symmetric positive definite matrix (NaN if it is not)."""
    Ss = 0.5 * (S + S.T)
    for i in range(Ss.shape[0]):
        if not Ss[i, i] > 0.0:
            return np.nan
    L = np.linalg.cholesky(Ss)
    v = 0.0
    for i in range(L.shape[0]):
        v += 2.0 * np.log(L[i, i])
    return v


@njit(cache=True)
def _row_dot(H, PHt, i):
    """(H P H^T)_ii from H (m, n) and P H^T (n, m)."""
    v = 0.0
    for j in range(H.shape[1]):
        v += H[i, j] * PHt[j, i]
    return v


@njit(cache=True)
def insgps_kernel(
    t, gyro, acc, nav0, C0, bias0, P0, q, tau_acc_s, tau_gyro_s, earth_sign, cov_step,
    gps_idx, gps_lag, gps_pos, gps_vel, gps_var, lever_b, gate, max_reject, gap_s, gm_tau_s, gm_q,
    out_nav, out_C, out_bias,
    ep_idx, ep_Phi, ep_Ppred, ep_Pfilt, ep_dx, store_rts,
    innov, innov_pvar, nis, accepted, innov_ldet,
):
    """Closed-loop INS/GPS filter over a whole log (forward or reversed): 15 navigation states,
    plus, when P0 is 18 x 18, three GPS position-error states (NED m, estimate minus truth of the
    fixes' own error) as first-order Gauss-Markov processes with time constant gm_tau_s and
    driving PSDs gm_q (3,) = 2 sigma^2 / tau (time-correlated receiver errors: multipath, the
    receiver's own filter, SBAS corrections). Their nominal (the estimated fix error) is
    bias0[6:9], subtracted from each fix, decaying by exp(-dt / tau) between epochs and fed back
    like the sensor biases; the process is stationary, so it runs unchanged in reversed time.

    gps_* are sorted by gps_idx, the IMU sample at which each fix is processed; gps_var (M, 6)
    position and velocity variances; NaN velocity -> position-only update; NaN vd -> horizontal velocity update. Per fix, innov (M, 6)
    gets the residuals, nis (M, 2) and accepted (M, 2) the position and velocity NIS (3 d.o.f.
    each, NaN when absent) and whether each was applied; innov_pvar (M, 6) the diagonal of
    H P- H^T (the filter's own share of each residual's variance, R excluded) for covariance
    matching of the GPS noise (`fusion.gps_noise`); innov_ldet (M, 2) log det S of each part, so
    that -(ldet + nis) / 2 summed over the fixes is the log-likelihood of the innovations up to a
    constant (prediction-error decomposition, used to fit the GPS error model). Gate: NIS above gate[3] rejects that
    part of the fix, except after `max_reject` consecutive rejections of that kind (the nominal
    has left the fixes for good: locking it out would diverge; 0 = no gating), and except the
    first fix after a gap of more than `gap_s` between fixes (an outage: the INS has then drifted
    by more than a MEMS error model predicts, and refusing the returning fixes prolongs the
    outage; gap_s <= 0: no exception). Epochs (covariance steps) every
    `cov_step` samples and at every fix; per epoch e: ep_idx[e], P_filt, dx (correction fed
    back), and when store_rts also Phi (from epoch e-1) and P_pred. Returns (n_epochs, status):
    status 0 ok, else 1 + sample index where an innovation covariance lost positive definiteness.
    """
    n = t.shape[0]
    m_gps = gps_idx.shape[0]
    nav = nav0.copy()
    C = C0.copy()
    bias = bias0.copy()
    ns = P0.shape[0]
    n_gm = ns - 15
    x = np.zeros(ns)
    P = P0.copy()
    F = np.zeros((ns, ns))
    Qc = np.zeros((ns, ns))
    process_noise(q, Qc)
    for i in range(n_gm):
        F[15 + i, 15 + i] = -1.0 / gm_tau_s  # error_dynamics writes only F[:15, :15]
        Qc[15 + i, 15 + i] = gm_q[i]
    Phi = np.empty((ns, ns))
    Qd = np.empty((ns, ns))
    H3 = np.zeros((3, ns))
    for i in range(n_gm):
        H3[i, 15 + i] = 1.0  # z = INS - (fix - b_est) = dp + (b_est - b) - noise
    Hv = np.zeros((3, ns))
    R3 = np.zeros((3, 3))
    zp = np.empty(3)
    zv = np.empty(3)
    f_n = np.empty(3)
    f_sum = np.zeros(3)
    dth = np.empty(3)
    dv = np.empty(3)
    dth_prev = np.zeros(3)
    dv_prev = np.zeros(3)
    w_ib = np.zeros(3)
    g = 0
    while g < m_gps and gps_idx[g] < 1:  # fixes at or before the first sample are not used
        g += 1
    ep = start_epochs(P, ep_idx, ep_Pfilt, ep_dx, ep_Phi, ep_Ppred, store_rts)
    out_nav[0] = nav
    out_C[0] = C
    out_bias[0] = bias
    last = 0
    dt_sum = 0.0
    status = 0
    n_rej = 0
    n_rej_v = 0
    t_prev_fix = t[0]
    for k in range(1, n):
        dt = mechanize_sample(k, t, gyro, acc, nav, C, bias, earth_sign, dth, dv, dth_prev, dv_prev, f_n, f_sum)
        for i in range(3):
            w_ib[i] = dth[i] / dt
        dt_sum += dt
        is_fix = g < m_gps and gps_idx[g] == k
        if is_fix or k - last >= cov_step or k == n - 1:
            ep = predict_epoch(nav, C, f_sum, dt_sum, earth_sign, tau_acc_s, tau_gyro_s, F, Qc, Phi, Qd, x, P,
                               ep, k, ep_idx, ep_Phi, ep_Ppred, store_rts)
            if n_gm > 0:
                decay = np.exp(-dt_sum / gm_tau_s)  # the nominal fix error follows its mean
                for i in range(n_gm):
                    bias[6 + i] *= decay
            while g < m_gps and gps_idx[g] == k:
                if gap_s > 0.0 and t[k] - t_prev_fix > gap_s:
                    n_rej = max_reject  # the first fix after an outage is applied ungated
                    n_rej_v = max_reject
                t_prev_fix = t[k]
                # position and velocity are processed as two sequential 3-dim updates (exact for
                # their diagonal R): each kind has its own NIS (3 d.o.f.) and its own gate, so a
                # bad velocity does not throw away a good position
                position_residual(nav, C, lever_b, gps_pos[g], gps_lag[g], zp)
                position_jacobian(nav, C, lever_b, gps_lag[g], H3, 0)
                for i in range(n_gm):
                    zp[i] += bias[6 + i]
                PHt = P @ H3.T
                for i in range(3):
                    innov[g, i] = zp[i]
                    R3[i, i] = gps_var[g, i]
                    innov_pvar[g, i] = _row_dot(H3, PHt, i)
                s = nis_of(x, P, zp, H3, R3)
                nis[g, 0] = s
                innov_ldet[g, 0] = _log_det(H3 @ PHt + R3)
                if s <= gate[3] or n_rej >= max_reject:
                    n_rej = 0
                    if update(x, P, zp, H3, R3) < 0.0:
                        return ep + 1, 1 + k
                    accepted[g, 0] = True
                else:
                    n_rej += 1
                if not np.isnan(gps_vel[g, 0]):
                    # receivers that log speed and course give no vertical velocity: 2-dim update
                    mv = 2 if np.isnan(gps_vel[g, 2]) else 3
                    velocity_residual(nav, C, lever_b, w_ib, gps_vel[g], zv)
                    velocity_jacobian(C, lever_b, w_ib, Hv, 0)
                    R3[:, :] = 0.0
                    PHt = P @ Hv.T
                    for i in range(mv):
                        innov[g, 3 + i] = zv[i]
                        R3[i, i] = gps_var[g, 3 + i]
                        innov_pvar[g, 3 + i] = _row_dot(Hv, PHt, i)
                    Rv = np.ascontiguousarray(R3[:mv, :mv])
                    s = nis_of(x, P, zv[:mv], Hv[:mv], Rv)
                    nis[g, 1] = s
                    innov_ldet[g, 1] = _log_det(np.ascontiguousarray((Hv @ PHt)[:mv, :mv]) + Rv)
                    if s <= gate[mv] or n_rej_v >= max_reject:
                        n_rej_v = 0
                        if update(x, P, zv[:mv], Hv[:mv], Rv) < 0.0:
                            return ep + 1, 1 + k
                        accepted[g, 1] = True
                    else:
                        n_rej_v += 1
                g += 1
            apply_feedback(nav, C, bias, x)
            for i in range(n_gm):
                bias[6 + i] -= x[15 + i]
            ep_dx[ep] = x
            x[:] = 0.0
            ep_Pfilt[ep] = P
            last = k
            f_sum[:] = 0.0
            dt_sum = 0.0
        out_nav[k] = nav
        out_C[k] = C
        out_bias[k] = bias
    return ep + 1, status
