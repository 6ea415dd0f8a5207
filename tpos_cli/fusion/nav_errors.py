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
def corrected_increments(gyro_b, acc_b, k, bias, dt, dtheta, dv):
    """Bias-corrected increments over IMU interval k, in place: gyro_b, acc_b (N, 3) the run's IMU,
    bias = [acc (3), gyro (3)]. Row k is indexed where it lies (no row view per sample)."""
    for i in range(3):
        dv[i] = (acc_b[k, i] - bias[i]) * dt
        dtheta[i] = (gyro_b[k, i] - bias[3 + i]) * dt


# the GPS rows' windows over the IMU (`window_acceleration_ned`, `window_rate_b`,
# `window_vibration_velocity_b`): engine and road vibration lies at 10 Hz and above, and a Hann
# (raised-cosine) weighting this long has its first null at 10 Hz and passes at most 3 % of any
# frequency beyond, whatever its phase at the fix; a car's own acceleration and turn rate change
# little over it, and a symmetric weighting keeps a linear change exactly
VIBRATION_WINDOW_S = 0.2
# the clock columns' acceleration (`window_acceleration_ned`) is a regressor: vibration left in it
# attenuates the clock estimate (errors in variables: a 0.3 s late clock on the real car read as
# 0.21-0.22 s with the 0.2 s window, its SD 5 ms), while a smoother regressor only drops signal
# (the window mean it misses is independent of it). A car's body bounce and pitch (1-2 Hz) and a
# walker's steps (~2 Hz) are vibration here; a driver's or walker's own acceleration changes over
# seconds. A Hann window of 1 s has its first null at 2 Hz and passes at most 3 % of any frequency beyond.
CLOCK_ACCELERATION_WINDOW_S = 1.0


@njit(cache=True)
def _hann_mean_b(t_s, x_b, k, centre_s, length_s, b0, out):
    """out = the Hann-weighted mean of x_b - b0 (body axes) over the samples whose intervals'
    middles lie within length_s / 2 of centre_s (searched from sample k; sample k's own when
    none). Weights dt_j (1 + cos(2 pi (c_j - centre) / length)) / 2, c_j the middle of (t_{j-1},
    t_j]. t_s (N,), x_b (N, 3): the run's IMU (row j the mean over (t_{j-1}, t_j]); b0 (3,) the
    bias to take out."""
    n = t_s.shape[0]
    half = 0.5 * length_s
    j0 = max(k, 1)
    while j0 > 1 and 0.5 * (t_s[j0 - 2] + t_s[j0 - 1]) > centre_s - half:
        j0 -= 1
    j1 = max(k, 1)
    while j1 < n - 1 and 0.5 * (t_s[j1] + t_s[j1 + 1]) < centre_s + half:
        j1 += 1
    f0 = f1 = f2 = 0.0
    w = 0.0
    for j in range(j0, j1 + 1):
        dt = t_s[j] - t_s[j - 1]
        wj = dt * 0.5 * (1.0 + np.cos(2.0 * np.pi * (0.5 * (t_s[j] + t_s[j - 1]) - centre_s) / length_s))
        f0 += (x_b[j, 0] - b0[0]) * wj
        f1 += (x_b[j, 1] - b0[1]) * wj
        f2 += (x_b[j, 2] - b0[2]) * wj
        w += wj
    if w <= 0.0:  # a window inside one long interval: that sample
        j = max(k, 1)
        for i in range(3):
            out[i] = x_b[j, i] - b0[i]
        return
    out[0] = f0 / w
    out[1] = f1 / w
    out[2] = f2 / w


@njit(cache=True)
def window_acceleration_ned(t_s, acc_b, k, C, bias, d_s, out):
    """The platform's mean NED acceleration (m/s^2, time-even) over the clock-offset window from
    t_k to t_k + d_s (the run's own time), widened about its middle to CLOCK_ACCELERATION_WINDOW_S and
    Hann-weighted (`_hann_mean_b`): C (mean bias-corrected specific force) + gravity.
    A velocity taken d later has gained its integral, v(t + d) - v(t) = a d (first order in the
    attitude change over d; a linear change of a is kept by the symmetric weights); one sample of
    a vibrating IMU instead puts tens of mg times d into the GPS-velocity clock column
    (`fusion.measurements.measure`), and so does a plain mean over 2.5 cycles of a 25 Hz engine
    line, in the same phase at every fix taken at whole seconds. t_s (N,), acc_b (N, 3): the
    run's IMU (row j the mean over (t_{j-1}, t_j]); bias = [acc (3), gyro (3)]. Gravity is the
    standard one, as the filter loop had it: the local one differs by < 0.03 m/s^2, < 3 mm/s in a d."""
    f = np.empty(3)
    _hann_mean_b(t_s, acc_b, k, t_s[k] + 0.5 * d_s, max(abs(d_s), CLOCK_ACCELERATION_WINDOW_S), bias[:3], f)
    for i in range(3):
        out[i] = C[i, 0] * f[0] + C[i, 1] * f[1] + C[i, 2] * f[2]
    out[2] += G0_MPS2


@njit(cache=True)
def window_rate_b(t_s, gyro_b, k, bias, out):
    """The body rate (rad/s) the GPS lever-arm terms use at sample k: the Hann-weighted mean of the
    bias-corrected gyro over VIBRATION_WINDOW_S centred on t_k (`_hann_mean_b`), not sample k's
    own rate. The antenna's velocity v + C (w x l) (paper 003 Eq. 12 with the lever arm) holds
    for the platform's rotation; a vibrating IMU's one sample adds its vibration, and fixes at
    whole seconds sample an engine line at a multiple of 1 Hz in the same phase every time: on
    the simulated real car, 3-5 mrad/s on every fix of a drive, 4-5 mm/s on a 0.9 m lever arm
    against 0.02 m/s fixes, and a lever-arm column on straight roads (w x l with w the vibration)
    that told the filter it saw the lever arm where it saw none. t_s (N,), gyro_b (N, 3): the
    run's IMU; bias = [acc (3), gyro (3)]."""
    _hann_mean_b(t_s, gyro_b, k, t_s[k], VIBRATION_WINDOW_S, bias[3:6], out)


@njit(cache=True)
def window_vibration_velocity_b(t_s, acc_b, k, out):
    """The IMU's velocity at sample k about the trend of its motion (m/s, body axes): over the
    samples whose intervals lie inside VIBRATION_WINDOW_S centred on t_k, u_j = sum_{m <= j} f_m
    dt_m (the mechanization's interval convention), less u's least-squares quadratic, at sample k
    (the ZUPT's `fusion.constraints.stop_measurements` form, about a moving vehicle's trend).
    Gravity, the bias and the vehicle's own acceleration and jerk make the quadratic; what is left
    is vibration. The GPS velocity row compares the fix with the INS velocity less this
    (`fusion.measurements.measure`): a receiver reports the antenna's motion, not the IMU mount's
    shake, and fixes at whole seconds sample an engine line at a multiple of 1 Hz in the same
    phase every time. t_s (N,), acc_b (N, 3): the run's IMU (row j the mean over (t_{j-1}, t_j])."""
    half = 0.5 * VIBRATION_WINDOW_S
    n = t_s.shape[0]
    j0 = k
    while j0 > 1 and t_s[j0 - 1] > t_s[k] - half:
        j0 -= 1
    j1 = k
    while j1 < n - 1 and t_s[j1 + 1] <= t_s[k] + half:
        j1 += 1
    j0 = max(j0, 1)
    m = j1 - j0 + 1
    if m < 5:
        for i in range(3):
            out[i] = 0.0
        return
    A = np.zeros((3, 3))
    B = np.zeros((3, 3))  # column i: the normal equations' right side of axis i
    u = np.zeros(3)
    for j in range(j0, j1 + 1):
        tau = t_s[j] - t_s[k]
        p = (1.0, tau, tau * tau)
        for i in range(3):
            u[i] += acc_b[j, i] * (t_s[j] - t_s[j - 1])
        for r in range(3):
            for c in range(3):
                A[r, c] += p[r] * p[c]
            for i in range(3):
                B[r, i] += p[r] * u[i]
        if j == k:
            uk0, uk1, uk2 = u[0], u[1], u[2]
    coef = np.linalg.solve(A, B)  # row 0: the quadratic at tau = 0, sample k
    out[0] = uk0 - coef[0, 0]
    out[1] = uk1 - coef[0, 1]
    out[2] = uk2 - coef[0, 2]


def vibration_velocities_b(t_s, acc_b) -> np.ndarray:
    """(N, 3) m/s: the IMU's velocity about the trend of its motion at every sample (body axes), as
    `window_vibration_velocity_b` with the fit Hann-weighted on the median sample interval:
    u = U - sum_j w_j U_{k+j}, U_k = sum_{m <= k} f_m dt_m, w the weights of the least-squares
    quadratic's value at the centre of a VIBRATION_WINDOW_S window. u keeps 0.7 % of the power at
    5 Hz, 44 % at 10 Hz and 90-110 % from 15 Hz on (an unweighted fit's side lobes pass 75-150 %);
    0 in the first and last half window (no centred fit). t_s (N,), acc_b (N, 3): the run's IMU
    (row j the mean over (t_{j-1}, t_j])."""
    t = np.asarray(t_s, dtype=float)
    dt = np.diff(t, prepend=t[0])
    U = np.cumsum(np.asarray(acc_b, dtype=float) * dt[:, None], axis=0)
    # the GPS rows' Hann weights (`_hann_mean_b`); scipy.signal's Savitzky-Golay costs 0.5 s to import
    half = int(round(0.5 * VIBRATION_WINDOW_S / np.median(np.diff(t)))) if t.size > 1 else 0
    u = np.zeros_like(U)
    if half >= 3 and t.size > 2 * half:
        tau = np.arange(-half, half + 1, dtype=float)
        h = 0.5 * (1.0 + np.cos(np.pi * tau / half))
        V = np.vander(tau, 3, increasing=True)
        w = np.linalg.solve(V.T @ (h[:, None] * V), (h[:, None] * V).T)[0]  # the fit's value at tau = 0
        win = np.lib.stride_tricks.sliding_window_view(U, 2 * half + 1, axis=0)  # (N - 2 half, 3, 2 half + 1)
        u[half:-half] = U[half:-half] - win @ w
    return u


# the span over which the vibration's velocity variance is measured around an output row: tens of
# cycles of a 10-50 Hz vibration, short beside how an engine's load and a road's surface change
VIBRATION_VARIANCE_SPAN_S = 1.0


def vibration_velocity_cov_b(t_s, acc_b, idx, span_s: float = VIBRATION_VARIANCE_SPAN_S) -> np.ndarray:
    """(K, 3, 3) m^2/s^2: covariance S_b of the vibration an INS velocity carries at samples idx (K,),
    in the IMU's axes (in NED: C_nb S_b C_nb^T): the mean of u u^T over the samples within span_s
    centred on each, u the IMU's velocity about the trend of its motion (as `window_vibration_velocity_b`,
    `vibration_velocities_b`).

    A vibrating IMU's accelerometers integrate engine and road vibration into a 10-50 Hz velocity
    of a few mm/s (30 mg at 25 Hz: 1.9 mm/s) which no filter state holds: the error model's white
    accelerometer noise, at the IMU's stated figure, makes a random walk instead. The filter's
    velocity SD is right for the velocity about that shake; a smoother that pins the velocity to a
    few mm/s then reports less than its error, by the shake (what the output velocity is compared
    with, fixes or a reference, is the vehicle's motion, not the mount's). The result is a consider
    variance for the reported velocity (no estimate moves). t_s (N,), acc_b (N, 3): the run's IMU
    (IMU axes, row j the mean over (t_{j-1}, t_j])."""
    t = np.asarray(t_s, dtype=float)
    u = vibration_velocities_b(t, acc_b)
    iu, ju = np.triu_indices(3)
    cs = np.zeros((t.size + 1, iu.size))
    for c, (i, j) in enumerate(zip(iu, ju)):  # one product column at a time: the hour's (N, 6) temporaries were its peak
        np.cumsum(u[:, i] * u[:, j], out=cs[1:, c])
    idx = np.asarray(idx, dtype=np.int64)
    lo = np.searchsorted(t, t[idx] - 0.5 * span_s, side="left")
    hi = np.searchsorted(t, t[idx] + 0.5 * span_s, side="right")
    m = (cs[hi] - cs[lo]) / np.maximum(hi - lo, 1)[:, None]
    S_b = np.empty((idx.size, 3, 3))
    S_b[:, iu, ju] = m
    S_b[:, ju, iu] = m
    return S_b


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
