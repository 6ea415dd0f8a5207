"""15-state INS error model (paper 003 Eq. 6-10, 15) and its feedback into the nominal state.

Errors are estimate minus truth, position in NED metres (paper 003 uses lat/lon radians and
rescales in H, Eq. 11; metres make H = I and need no rescaling). The paper's F_INS (Eq. 15) is
partly garbled in the text; the blocks here follow the standard psi-angle NED model
(Titterton & Weston 2004, Eq. 12.47-12.49; Groves 2013, Eq. 14.64-14.71) that it transcribes:
    dp' = dv
    dv' = [f_n x] phi - C dba - [(2 w_ie + w_en) x] dv + [v x] M dv + (2 g / R) dp_d e_d
    phi' = -[w_in x] phi + M dv + C dbg
    dba' = -dba / tau_acc,   dbg' = -dbg / tau_gyro      (first-order Gauss-Markov)
with M = d(w_en)/d(v). Terms of order w_ie * v / R in position are dropped (below 1e-9 /s).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tpos_cli.frames._kernels import normal_gravity, radii_m, rotvec_to_dcm_into
from tpos_cli.frames.earth import G0_MPS2, OMEGA_IE_RPS
from tpos_cli.fusion.layout import ATT, BA, BG, N_NAV, POS, VEL


@njit(cache=True)
def corrected_increments(gyro_k, acc_k, bias, dt, dtheta, dv):
    """Bias-corrected increments over one IMU interval, in place: bias = [acc (3), gyro (3)]."""
    for i in range(3):
        dv[i] = (acc_k[i] - bias[i]) * dt
        dtheta[i] = (gyro_k[i] - bias[3 + i]) * dt


# the shortest window of `window_acceleration_ned`: a full cycle of 10 Hz, the low end of engine and
# road vibration, over which a car's own acceleration changes little
CLOCK_ACC_WINDOW_S = 0.1


@njit(cache=True)
def window_acceleration_ned(t_s, acc_b, k, C, bias, d_s, out):
    """The platform's mean NED acceleration (m/s^2, time-even) over the clock-offset window from
    t_k to t_k + d_s (the run's own time), widened about its middle to CLOCK_ACC_WINDOW_S:
    C (mean bias-corrected specific force of the samples whose intervals lie inside) + gravity.
    A velocity taken d later has gained its integral, v(t + d) - v(t) = a d (first order in the
    attitude change over d); one sample of a vibrating IMU instead puts tens of mg times d into
    the GPS-velocity clock column (`fusion.measurements.measure`). t_s (N,), acc_b (N, 3): the
    run's IMU (row j the mean over (t_{j-1}, t_j]); bias = [acc (3), gyro (3)]. Gravity is the
    standard one, as the filter loop had it: the local one differs by < 0.03 m/s^2, < 3 mm/s in a d."""
    half = 0.5 * max(abs(d_s), CLOCK_ACC_WINDOW_S)
    lo = t_s[k] + 0.5 * d_s - half
    hi = lo + 2.0 * half
    n = t_s.shape[0]
    j0 = k
    while j0 > 1 and t_s[j0 - 1] > lo:
        j0 -= 1
    j1 = k
    while j1 < n - 1 and t_s[j1 + 1] <= hi:
        j1 += 1
    f0 = f1 = f2 = 0.0
    w = 0.0
    for j in range(max(j0, 1), j1 + 1):
        dt = t_s[j] - t_s[j - 1]
        f0 += (acc_b[j, 0] - bias[0]) * dt
        f1 += (acc_b[j, 1] - bias[1]) * dt
        f2 += (acc_b[j, 2] - bias[2]) * dt
        w += dt
    f0, f1, f2 = f0 / w, f1 / w, f2 / w
    for i in range(3):
        out[i] = C[i, 0] * f0 + C[i, 1] * f1 + C[i, 2] * f2
    out[2] += G0_MPS2


@njit(cache=True)
def error_dynamics(nav, C, f_n, earth_sign, tau_acc_s, tau_gyro_s, F):
    """Write the 15x15 error dynamics into F[:15, :15] (other entries untouched).

    nav (6,), C (3, 3) nominal; f_n (3,) mean specific force in NED over the step;
    tau <= 0 means a random-walk bias (no decay).
    """
    lat, h = nav[0], nav[2]
    vn, ve = nav[3], nav[4]
    rn, re = radii_m(lat)
    rn += h
    re += h
    tl = np.tan(lat)
    w_ie = np.zeros(3)
    w_ie[0] = earth_sign * OMEGA_IE_RPS * np.cos(lat)
    w_ie[2] = -earth_sign * OMEGA_IE_RPS * np.sin(lat)
    w_en = np.empty(3)
    w_en[0] = ve / re
    w_en[1] = -vn / rn
    w_en[2] = -ve * tl / re
    M = np.zeros((3, 3))  # d(w_en)/d(v)
    M[0, 1] = 1.0 / re
    M[1, 0] = -1.0 / rn
    M[2, 1] = -tl / re
    for i in range(15):
        for j in range(15):
            F[i, j] = 0.0
    for i in range(3):
        F[POS + i, VEL + i] = 1.0
    a = np.empty(3)
    w_in = np.empty(3)
    for i in range(3):
        a[i] = 2.0 * w_ie[i] + w_en[i]
        w_in[i] = w_ie[i] + w_en[i]
    v = nav[3:6]
    vxM = np.empty((3, 3))  # [v x] M, column by column
    for j in range(3):
        vxM[0, j] = v[1] * M[2, j] - v[2] * M[1, j]
        vxM[1, j] = v[2] * M[0, j] - v[0] * M[2, j]
        vxM[2, j] = v[0] * M[1, j] - v[1] * M[0, j]
    for i in range(3):
        for j in range(3):
            F[VEL + i, BA + j] = -C[i, j]
            F[ATT + i, BG + j] = C[i, j]
            F[VEL + i, VEL + j] = vxM[i, j]
            F[ATT + i, VEL + j] = M[i, j]
    # [f_n x], -[a x], -[w_in x]
    F[VEL + 0, ATT + 1] += -f_n[2]
    F[VEL + 0, ATT + 2] += f_n[1]
    F[VEL + 1, ATT + 0] += f_n[2]
    F[VEL + 1, ATT + 2] += -f_n[0]
    F[VEL + 2, ATT + 0] += -f_n[1]
    F[VEL + 2, ATT + 1] += f_n[0]
    F[VEL + 0, VEL + 1] += a[2]
    F[VEL + 0, VEL + 2] += -a[1]
    F[VEL + 1, VEL + 0] += -a[2]
    F[VEL + 1, VEL + 2] += a[0]
    F[VEL + 2, VEL + 0] += a[1]
    F[VEL + 2, VEL + 1] += -a[0]
    F[ATT + 0, ATT + 1] = w_in[2]
    F[ATT + 0, ATT + 2] = -w_in[1]
    F[ATT + 1, ATT + 0] = -w_in[2]
    F[ATT + 1, ATT + 2] = w_in[0]
    F[ATT + 2, ATT + 0] = w_in[1]
    F[ATT + 2, ATT + 1] = -w_in[0]
    F[VEL + 2, POS + 2] = 2.0 * normal_gravity(lat, h) / np.sqrt(rn * re)  # gravity gradient
    for i in range(3):
        if tau_acc_s > 0.0:
            F[BA + i, BA + i] = -1.0 / tau_acc_s
        if tau_gyro_s > 0.0:
            F[BG + i, BG + i] = -1.0 / tau_gyro_s


@njit(cache=True)
def process_noise(q, Qc):
    """Continuous noise PSDs on the diagonal of Qc[:15, :15] (paper Eq. 9-10, isotropic sensors,
    so G Q G^T needs no C). q = [acc white (m/s^2)^2 s, gyro white rad^2/s, acc bias drive,
    gyro bias drive]."""
    for i in range(3):
        Qc[VEL + i, VEL + i] = q[0]
        Qc[ATT + i, ATT + i] = q[1]
        Qc[BA + i, BA + i] = q[2]
        Qc[BG + i, BG + i] = q[3]


@njit(cache=True)
def apply_feedback(nav, C, bias, x, R):
    """Feed the error estimate x back into the nominal state, the IMU biases bias[:6] and the
    nominal of the extra states bias[6:] (`fusion.layout`), in place (closed loop). R (3, 3):
    scratch for the attitude correction (the caller's, so that the per-measurement loop allocates nothing)."""
    lat, h = nav[0], nav[2]
    rn, re = radii_m(lat)
    nav[0] = lat - x[POS] / (rn + h)
    nav[1] = nav[1] - x[POS + 1] / ((re + h) * np.cos(lat))
    nav[2] = h + x[POS + 2]
    for i in range(3):
        nav[3 + i] -= x[VEL + i]
        bias[i] -= x[BA + i]
        bias[3 + i] -= x[BG + i]
    rotvec_to_dcm_into(x[ATT], x[ATT + 1], x[ATT + 2], R)
    for j in range(3):  # C <- R C: C_true = (I + [phi x]) C_est, exactly as a rotation (column by column)
        c0, c1, c2 = C[0, j], C[1, j], C[2, j]
        for i in range(3):
            C[i, j] = R[i, 0] * c0 + R[i, 1] * c1 + R[i, 2] * c2
    for i in range(x.shape[0] - N_NAV):  # states after the 15 (fusion.layout): nominal in bias[6:]
        bias[6 + i] -= x[N_NAV + i]
