"""Compiled INS/range filter loop (paper 002 Eq. 1-12 loosely, Eq. 17-24 tightly coupled).

Composes the shared kernels: `ins._kernels.mech_step` (nominal state), `fusion.nav_errors`
(15-state error model, feedback, position rows), `filters.kalman` (discretize, predict, gated
Joseph update). The state is the 15 navigation errors, the common range bias / NLOS state eps_d
of Eq. 17-18 at index `BIAS` (a random walk), and beyond the paper two random constants that the
filter would otherwise treat as white noise: the error of the floor height used by the floor
constraint (`FLOOR`) and, per anchor i, the residual bias of the calibrated range (`CAL + i`,
the least-squares fit's error, Eq. 15-16). A state with zero initial variance stays exactly 0.
Measurements follow `fusion`'s sign convention z = h(INS) - measured, so H x predicts z.

The loop shares its propagation (`fusion._kernels.mechanize_sample`, `predict_epoch`) with
`fusion._kernels.insgps_kernel`, so that the same kernel runs
forward and backward (reversed arrays from `ins.reverse_imu`, negated velocity, earth_sign = -1)
and stores what `tpos_cli.smoothing` needs: the nominal at every sample and, per covariance
epoch, P, the correction fed back, and (for RTS) Phi and the predicted P. Covariance epochs are
every `cov_step` samples and at every sample with an event. Events are processed at the first
sample at or after their time, with the nominal moved back along its velocity by the lag
(`ev_lag`, in the run's own time direction), as `fusion.nav_errors.position_residual`; all the
events of one sample update one error state about one nominal (a batch update), which is then
fed back once (closed loop, paper Fig. 1).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tpos_cli.filters.kalman import nis_of, update
from tpos_cli.fusion._kernels import mechanize_sample, predict_epoch, start_epochs
from tpos_cli.fusion.layout import N_NAV, POS, VEL
from tpos_cli.fusion.nav_errors import apply_feedback, position_jacobian, process_noise
from tpos_cli.ranging.measurements import lla_to_local_ned

BIAS = N_NAV  # index of eps_d (Eq. 17-18)
FLOOR = N_NAV + 1  # error of the floor height (estimate - truth), m
CAL = N_NAV + 2  # first per-anchor calibration residual bias, m
N_STATE = N_NAV + 1  # navigation + eps_d (the paper's state); the run has CAL + n_anchors states


def n_states(n_anchors: int) -> int:
    """Size of the filter state for n_anchors anchors."""
    return CAL + n_anchors

EV_RANGE = 0  # z = corrected range to anchor ev_anchor (Eq. 21-24)
EV_FIX_NE = 1  # z = least-squares fix (north, east) in the local frame (Eq. 7-12)
EV_DOWN = 2  # z = down coordinate of the node in the local frame (floor constraint)
EV_ZUPT = 3  # z = nominal NED velocity - 0 while the IMU says the node stands still


@njit(cache=True)
def ranging_filter_kernel(
    t, gyro, acc, nav0, C0, bias0, range_bias0, P0, q, tau_acc_s, tau_gyro_s, q_bias, earth_sign, cov_step,
    ev_k, ev_lag, ev_kind, ev_anchor, ev_z, ev_R, ev_gated, ev_sidx, sens,
    anchors_ned, r0_e, C_ne0, gate, max_consecutive_rejects, store_rts,
    out_nav, out_C, out_bias, out_rb, out_aux, ep_idx, ep_Phi, ep_Ppred, ep_P, ep_dx, ev_nis, ev_accepted,
):
    """Closed-loop INS/range filter over the whole (possibly reversed) arrays, from sample 0.

    ev_* (E,) sorted by ev_k (sample index of processing, >= 1), ev_z (E, 3), ev_R (E, 3) =
    [var_0, cov_01, var_1] (ZUPT: the variance of each axis in var_0); a fix with ev_sidx[e] >= 0
    has sens[ev_sidx[e]] (2, 1 + A), its rows for the FLOOR and CAL states; anchors_ned (A, 3) local
    NED; gate[m] = chi2 threshold for m dof. Writes the nominal after feedback at every sample
    (out_*), the epochs (ep_*; Phi and P_pred only when store_rts) and per event the NIS (-1 if
    never reached) and acceptance; out_aux (N, 1 + A) the floor and calibration corrections
    (nominal of the FLOOR and CAL states). P0 is (n_states(A), n_states(A)). Returns (n_epochs,
    status): status 0 ok, else 1 + the sample index where an innovation covariance lost positive
    definiteness.
    """
    n = P0.shape[0]
    n_t = t.shape[0]
    nav = nav0.copy()
    C = C0.copy()
    bias = bias0.copy()
    range_bias = range_bias0
    aux = np.zeros(out_aux.shape[1])  # [floor correction, calibration correction per anchor], m
    P = P0.copy()
    x = np.zeros(n)
    F = np.zeros((n, n))
    Qc = np.zeros((n, n))
    Phi = np.empty((n, n))
    Qd = np.empty((n, n))
    process_noise(q, Qc)
    Qc[BIAS, BIAS] = q_bias
    dth = np.zeros(3)
    dv = np.zeros(3)
    dth_prev = np.zeros(3)
    dv_prev = np.zeros(3)
    f_n = np.zeros(3)
    f_sum = np.zeros(3)
    zero3 = np.zeros(3)
    n_anchor = anchors_ned.shape[0]
    consecutive = np.zeros(n_anchor + 1, np.int64)  # per anchor; last slot for position fixes
    H1 = np.zeros((1, n))
    H2 = np.zeros((2, n))
    H3 = np.zeros((3, n))
    z1 = np.zeros(1)
    z2 = np.zeros(2)
    z3 = np.zeros(3)
    R1 = np.zeros((1, 1))
    R2 = np.zeros((2, 2))
    R3 = np.zeros((3, 3))
    e = 0
    n_ev = ev_k.shape[0]
    while e < n_ev and ev_k[e] < 1:  # events at or before the first sample are not used
        e += 1
    ep = start_epochs(P, ep_idx, ep_P, ep_dx, ep_Phi, ep_Ppred, store_rts)
    out_nav[0] = nav
    out_C[0] = C
    out_bias[0] = bias
    out_rb[0] = range_bias
    out_aux[0] = aux
    last = 0
    dt_sum = 0.0
    dx_sum = np.zeros(n)
    for k in range(1, n_t):
        dt_sum += mechanize_sample(k, t, gyro, acc, nav, C, bias, earth_sign, dth, dv, dth_prev, dv_prev, f_n, f_sum)
        has_ev = e < n_ev and ev_k[e] == k
        if has_ev or k - last >= cov_step or k == n_t - 1:
            ep = predict_epoch(nav, C, f_sum, dt_sum, earth_sign, tau_acc_s, tau_gyro_s, F, Qc, Phi, Qd, x, P,
                               ep, k, ep_idx, ep_Phi, ep_Ppred, store_rts)
            while e < n_ev and ev_k[e] == k:
                lag = ev_lag[e]
                kind = ev_kind[e]
                # node position at the event time, in the local frame of the anchors
                p = lla_to_local_ned(nav[0], nav[1], nav[2], r0_e, C_ne0)
                for i in range(3):
                    p[i] -= nav[3 + i] * lag
                slot = n_anchor
                accept = True
                if kind == EV_RANGE:
                    a = ev_anchor[e]
                    slot = a
                    d = p - anchors_ned[a]
                    rho = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
                    z1[0] = rho + range_bias + aux[1 + a] - ev_z[e, 0]  # Eq. 22, fusion's sign: h(INS) - measured
                    for j in range(n):
                        H1[0, j] = 0.0
                    for i in range(3):
                        H1[0, POS + i] = d[i] / rho  # Eq. 23
                        H1[0, VEL + i] = -lag * d[i] / rho
                    H1[0, BIAS] = 1.0  # Eq. 24, last column (sign: error = estimate - truth)
                    H1[0, CAL + a] = 1.0
                    R1[0, 0] = ev_R[e, 0]
                    nis = nis_of(x, P, z1, H1, R1)
                    accept = (not ev_gated[e]) or nis <= gate[1] or consecutive[slot] >= max_consecutive_rejects
                    if accept and update(x, P, z1, H1, R1) < 0.0:
                        return ep + 1, 1 + k
                elif kind == EV_FIX_NE:
                    position_jacobian(nav, C, zero3, lag, H3, 0)
                    for j in range(n):
                        H2[0, j] = H3[0, j] if j < N_NAV else 0.0
                        H2[1, j] = H3[1, j] if j < N_NAV else 0.0
                    z2[0] = p[0] - ev_z[e, 0]
                    z2[1] = p[1] - ev_z[e, 1]
                    si = ev_sidx[e]
                    if si >= 0:  # the fix corrected by the current floor and calibration estimates
                        for i in range(2):
                            for j in range(aux.shape[0]):
                                H2[i, FLOOR + j] = sens[si, i, j]
                                z2[i] += sens[si, i, j] * aux[j]
                    R2[0, 0] = ev_R[e, 0]
                    R2[0, 1] = ev_R[e, 1]
                    R2[1, 0] = ev_R[e, 1]
                    R2[1, 1] = ev_R[e, 2]
                    nis = nis_of(x, P, z2, H2, R2)
                    accept = (not ev_gated[e]) or nis <= gate[2] or consecutive[slot] >= max_consecutive_rejects
                    if accept and update(x, P, z2, H2, R2) < 0.0:
                        return ep + 1, 1 + k
                elif kind == EV_DOWN:
                    position_jacobian(nav, C, zero3, lag, H3, 0)
                    for j in range(n):
                        H1[0, j] = H3[2, j] if j < N_NAV else 0.0
                    H1[0, FLOOR] = -1.0  # the floor used is ev_z + aux[0]; its error enters with -1
                    z1[0] = p[2] - (ev_z[e, 0] + aux[0])
                    R1[0, 0] = ev_R[e, 0]
                    nis = update(x, P, z1, H1, R1)
                    if nis < 0.0:
                        return ep + 1, 1 + k
                else:  # EV_ZUPT: the node stands still, v = 0 (velocity at sample k; no lag)
                    for i in range(3):
                        for j in range(n):
                            H3[i, j] = 0.0
                        H3[i, VEL + i] = 1.0
                        z3[i] = nav[3 + i] - ev_z[e, i]
                        for j in range(3):
                            R3[i, j] = 0.0
                        R3[i, i] = ev_R[e, 0]
                    nis = update(x, P, z3, H3, R3)
                    if nis < 0.0:
                        return ep + 1, 1 + k
                ev_nis[e] = nis
                ev_accepted[e] = accept
                if kind == EV_RANGE or kind == EV_FIX_NE:
                    consecutive[slot] = 0 if accept else consecutive[slot] + 1
                if accept:  # closed loop: feed back and reset (paper Fig. 1, Algorithm 1 step 10)
                    apply_feedback(nav, C, bias, x)
                    range_bias -= x[BIAS]
                    for i in range(aux.shape[0]):
                        aux[i] -= x[FLOOR + i]
                    dx_sum += x
                    x[:] = 0.0
                e += 1
            ep_dx[ep] = dx_sum  # x stays 0 between epochs (closed loop: Phi 0 = 0)
            dx_sum[:] = 0.0
            x[:] = 0.0
            ep_P[ep] = P
            last = k
            f_sum[:] = 0.0
            dt_sum = 0.0
        out_nav[k] = nav
        out_C[k] = C
        out_bias[k] = bias
        out_rb[k] = range_bias
        out_aux[k] = aux
    return ep + 1, 0
