"""Compiled INS/range filter loop (paper 002 Eq. 1-12 loosely, Eq. 17-24 tightly coupled).

Composes the shared kernels: `ins._kernels.mech_step` (nominal state), `fusion.nav_errors`
(15-state error model, feedback, position rows), `filters.kalman` (discretize, predict, gated
Joseph update). The state is the 15 navigation errors plus the common range bias / NLOS state
eps_d of Eq. 17-18 at index `BIAS` (a random walk). Measurements follow `fusion`'s sign
convention z = h(INS) - measured, so H x predicts z.

Events are processed at the first IMU sample at or after their time, with the nominal state
moved back along its velocity by the lag (`ev_lag`), as `fusion.nav_errors.position_residual`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tpos_cli.filters.kalman import discretize, nis_of, predict, update
from tpos_cli.fusion.layout import N_NAV, POS, VEL
from tpos_cli.fusion.nav_errors import (
    apply_feedback, corrected_increments, error_dynamics, position_jacobian, process_noise,
)
from tpos_cli.ins._kernels import mech_step
from tpos_cli.ranging.measurements import lla_to_local_ned

BIAS = N_NAV  # index of eps_d (Eq. 17-18)
N_STATE = N_NAV + 1

EV_RANGE = 0  # z = corrected range to anchor ev_anchor (Eq. 21-24)
EV_FIX_NE = 1  # z = least-squares fix (north, east) in the local frame (Eq. 7-12)
EV_DOWN = 2  # z = down coordinate of the node in the local frame (floor constraint)


@njit(cache=True)
def ranging_filter_kernel(
    t, gyro, acc, k0, nav0, C0, P0, q, tau_acc_s, tau_gyro_s, q_bias,
    ev_k, ev_lag, ev_kind, ev_anchor, ev_z, ev_R, ev_gated,
    anchors_ned, r0_e, C_ne0, gate, max_consecutive_rejects, out_every,
    out_k, out_nav, out_C, out_P, out_bias, ev_nis, ev_accepted,
):
    """Forward filter from IMU sample k0 to the end.

    ev_* (E,) sorted by ev_k (IMU sample index of processing), ev_z (E, 2), ev_R (E, 3) =
    [var_0, cov_01, var_1]; anchors_ned (A, 3) local NED; gate[m] = chi2 threshold for m dof.
    Writes out_* every `out_every` samples (and at k0) into preallocated rows, returns the
    number of rows written; ev_nis / ev_accepted per event (NIS -1 for events never reached).
    """
    n = N_STATE
    nav = nav0.copy()
    C = C0.copy()
    P = P0.copy()
    x = np.zeros(n)
    bias = np.zeros(6)
    range_bias = 0.0
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
    e = 0
    n_ev = ev_k.shape[0]
    while e < n_ev and ev_k[e] < k0:
        e += 1
    row = 0
    for k in range(k0, t.shape[0]):
        if k > k0:
            dt = t[k] - t[k - 1]
            corrected_increments(gyro[k], acc[k], bias, dt, dth, dv)
            mech_step(nav, C, dth, dv, dth_prev, dv_prev, dt, 1.0, f_n)
            dth_prev[:] = dth
            dv_prev[:] = dv
            error_dynamics(nav, C, f_n, 1.0, tau_acc_s, tau_gyro_s, F)
            discretize(F, Qc, dt, Phi, Qd)
            predict(x, P, Phi, Qd)
        while e < n_ev and ev_k[e] == k:
            lag = ev_lag[e]
            kind = ev_kind[e]
            # node position at the event time, in the local frame of the anchors
            p = lla_to_local_ned(nav[0], nav[1], nav[2], r0_e, C_ne0)
            for i in range(3):
                p[i] -= nav[3 + i] * lag
            slot = n_anchor
            if kind == EV_RANGE:
                a = ev_anchor[e]
                slot = a
                d = p - anchors_ned[a]
                rho = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
                z1[0] = rho + range_bias - ev_z[e, 0]  # Eq. 22 with fusion's sign: h(INS) - measured
                for j in range(n):
                    H1[0, j] = 0.0
                for i in range(3):
                    H1[0, POS + i] = d[i] / rho  # Eq. 23
                    H1[0, VEL + i] = -lag * d[i] / rho
                H1[0, BIAS] = 1.0  # Eq. 24, last column (sign: error = estimate - truth)
                R1[0, 0] = ev_R[e, 0]
                nis = nis_of(x, P, z1, H1, R1)
                accept = (not ev_gated[e]) or nis <= gate[1] or consecutive[slot] >= max_consecutive_rejects
                if accept:
                    update(x, P, z1, H1, R1)
            elif kind == EV_FIX_NE:
                position_jacobian(nav, C, zero3, lag, H3, 0)
                for j in range(n):
                    H2[0, j] = H3[0, j] if j < N_NAV else 0.0
                    H2[1, j] = H3[1, j] if j < N_NAV else 0.0
                z2[0] = p[0] - ev_z[e, 0]
                z2[1] = p[1] - ev_z[e, 1]
                R2[0, 0] = ev_R[e, 0]
                R2[0, 1] = ev_R[e, 1]
                R2[1, 0] = ev_R[e, 1]
                R2[1, 1] = ev_R[e, 2]
                nis = nis_of(x, P, z2, H2, R2)
                accept = (not ev_gated[e]) or nis <= gate[2] or consecutive[slot] >= max_consecutive_rejects
                if accept:
                    update(x, P, z2, H2, R2)
            else:  # EV_DOWN
                position_jacobian(nav, C, zero3, lag, H3, 0)
                for j in range(n):
                    H1[0, j] = H3[2, j] if j < N_NAV else 0.0
                z1[0] = p[2] - ev_z[e, 0]
                R1[0, 0] = ev_R[e, 0]
                nis = nis_of(x, P, z1, H1, R1)
                accept = True
                update(x, P, z1, H1, R1)
            ev_nis[e] = nis
            ev_accepted[e] = accept
            if kind != EV_DOWN:
                consecutive[slot] = 0 if accept else consecutive[slot] + 1
            if accept:  # closed loop: feed back and reset (paper Fig. 1, Algorithm 1 step 10)
                apply_feedback(nav, C, bias, x)
                range_bias -= x[BIAS]
                for j in range(n):
                    x[j] = 0.0
            e += 1
        if (k - k0) % out_every == 0:
            out_k[row] = k
            out_nav[row] = nav
            out_C[row] = C
            for j in range(n):
                out_P[row, j] = P[j, j]
            out_bias[row] = range_bias
            row += 1
    return row
