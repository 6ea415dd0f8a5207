"""Compiled per-sample loops of the attitude local filters (paper 000 Eq. 16-26).

Two models share this module:

- `marg_filter`: error-state DCM filter valid at any roll. Nominal `C_nb` (FRD->NED) propagated by
  Eq. 17-19 with the gyro; error state x = [phi (3, NED attitude error, C_true = exp(phi) C_hat), gyro
  bias (3), accelerometer bias (3), optionally the gyro's scale/misalignment matrix M (9) and the hand's
  NED velocity and displacement (6)]; measurements are gravity (Eq. 5), the magnetic field vector (Eq. 7-8
  as a vector model) and the exact three-beam range differences (contract geometry behind Eq. 10). The
  same kernel runs backward in time on reversed, negated gyro samples.
- `run_paper8`: the paper's 8-state linear DCM filter (Eq. 16, 21-22) in its own RFU/ENU frames.

Inputs are a few named tuples of float64 arrays and scalars (numba compiles them as tuples); the
documented wrapper that builds and checks them is `tpos_cli.attitude.local.run_full`.
Kalman algebra is `tpos_cli.filters.kalman` (Joseph form); nothing here re-implements it.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from tpos_cli.filters.kalman import cho_solve_into, cholesky_into, matmul_into, predict, symmetrize, update
from tpos_cli.frames._kernels import orthonormalize, rotvec_to_dcm, skew

# measurement kinds, bit flags in `Gates.use`
USE_ACC = 1
USE_MAG = 2
USE_RANGE = 4
USE_MOTION = 8  # hand-motion velocity/displacement states (hand-held device, standing observer)

# state offsets: phi, gyro bias and accelerometer bias always; the gyro matrix M and the hand states
# follow when present (`state_offsets`)
I_PHI, I_BG, I_BA, N_BASE = 0, 3, 6, 9
# first sensitivity column of the gyro's scale/misalignment dM (9 columns, row-major), `Init.S0`
S_GYRO = 7


class Samples(NamedTuple):
    """t (N,) s; gyro (N,3) rad/s, acc (N,3) m/s^2 body FRD interval means over (t_{k-1}, t_k];
    mag (N,3) uT (NaN row: none or rejected beforehand); rdiff (N,2) m d1-d2, d1-d3 (NaN: none);
    still (N,) bool detected still samples; grav_var (N,) (m/s^2)^2 variance of a direct gravity
    update at the sample (NaN: none; used without the hand model)."""

    t: np.ndarray
    gyro: np.ndarray
    acc: np.ndarray
    mag: np.ndarray
    rdiff: np.ndarray
    still: np.ndarray
    grav_var: np.ndarray


class Frame(NamedTuple):
    """NED vectors: Earth rate w_ie (rad/s; negated backward), gravity g (m/s^2, down), the Earth
    magnetic field m_ref (uT), the wall's unit normal; LR2/LR3 beam origins o2, o3 (m, body FRD)."""

    w_ie: np.ndarray
    g: np.ndarray
    m_ref: np.ndarray
    wall_n: np.ndarray
    o2: np.ndarray
    o3: np.ndarray
    wall_sens: np.ndarray  # (3,) rad per m/s^2: the wall azimuth's error per accelerometer bias (`Init.S0`)


class Noise(NamedTuple):
    """q_att rad^2 per sample (gyro white noise); q_sf relative variance of a sample's rotation angle
    (scale factor); q_bg (rad/s)^2/s and q_ba (m/s^2)^2/s bias random walks; q_m per s (random walk of
    each element of M); q_vel (m/s)^2 per sample (accelerometer white noise in the velocity); r_mag uT^2
    per axis; r_rng (2,2) m^2. var_ba (m/s^2)^2 the accelerometer bias's variance per axis, var_ba_prior the
    part of it the prior's bias state holds (var_ba / beta), var_gm the variance of each element of the gyro's
    constant scale/misalignment dM: the errors the filter carries as sensitivities (`Init.S0`), which the
    recorded NIS counts (`consider_innovation_cov`)."""

    q_att: float
    q_sf: float
    q_bg: float
    q_ba: float
    q_m: float
    q_vel: float
    r_mag: float
    r_rng: np.ndarray
    var_ba: float
    var_ba_prior: float
    var_gm: float


class Hand(NamedTuple):
    """Hand-motion model (USE_MOTION). omega > 0: damped oscillator p'' = -omega^2 p - 2 zeta omega p' + w,
    E[w w] = q delta (m^2/s^3), checked against the integrated specific force every `step` samples;
    omega = 0: independent v = 0 +- sd_vel, p = 0 +- sd_pos pseudo-measurements every `epoch` samples.
    zupt_sd m/s: velocity SD in detected still periods (applied every `step` samples, or with each epoch)."""

    omega: float
    zeta: float
    q: float
    step: int
    epoch: int
    sd_vel: float
    sd_pos: float
    zupt_sd: float


class Gates(NamedTuple):
    """use: USE_* flags; gyro_matrix: the gyro scale/misalignment matrix M is a state; acc_scale: the
    accelerometer's axis scale factors s are states (f_meas = (I + diag s) f + b_a); mag_consider: the
    magnetometer never corrects tilt, accelerometer bias or hand states (only considered); mag_norm_tol uT,
    mag_dip_tol rad (<= 0: no test) against m_ref; mag_nis_tau_s, mag_nis_ratio: reject the field while
    the mean NIS per dof (3) over ~tau exceeds ratio (<= 0: no test); rng_gate chi2(2) threshold (<= 0: none)."""

    use: int
    gyro_matrix: bool
    acc_scale: bool
    mag_consider: bool
    mag_norm_tol: float
    mag_dip_tol: float
    mag_nis_tau_s: float
    mag_nis_ratio: float
    rng_gate: float


class Init(NamedTuple):
    """C0 (3,3); bias (3,) rad/s; acc_bias (3,) m/s^2; M0 (3,3); P0 (n,n) with n from `state_offsets`;
    S0 (n,c) the initial error's sensitivity to the accelerometer bias b_a: columns 0-2 the total,
    d e0 / d b_a (the levelling error of the alignment, phi0 = M b_a, and the bias state's own error,
    I), columns 3-5 the part the filter's prior already holds (the bias state's I). Both are carried
    by the filter's closed loop (e <- (I - K H) Phi e, minus K times a measurement's own bias
    sensitivity), so that e(t) = a(t) + S(t) b_a with a(t) independent of b_a. Further columns (c > 6)
    carry another error of the initial state the same way, without a measurement sensitivity (the start
    alignment's heading error, `local.run_full`). With c = S_GYRO + 9, columns S_GYRO.. are the
    sensitivity to the gyro's constant scale/misalignment dM (omega_meas = (I + dM) omega + b, 9 elements
    row-major), never estimated: each prediction adds its forcing d(phi_dot)/d dM = -C_hat [omega^T]
    (the same term as the M states' Phi) to the closed loop's propagation."""

    C0: np.ndarray
    bias: np.ndarray
    acc_bias: np.ndarray
    M0: np.ndarray
    P0: np.ndarray
    S0: np.ndarray


class Outputs(NamedTuple):
    """Filled per sample (the posterior after it): C (N,3,3), P_att (N,3,3) rad^2, bias (N,3) rad/s,
    acc_bias (N,3) m/s^2, var_bias (N,6) variances of [gyro bias, acc bias], nis_acc, nis_mag, nis_rng
    (N,) (NaN: no update made), mag_ok (N,) bool, M (N or 1, 3, 3) (written only with the M states),
    S_att (N,3,c) the attitude rows of the sensitivities (`Init.S0`)."""

    C: np.ndarray
    P_att: np.ndarray
    bias: np.ndarray
    acc_bias: np.ndarray
    var_bias: np.ndarray
    nis_acc: np.ndarray
    nis_mag: np.ndarray
    nis_rng: np.ndarray
    mag_ok: np.ndarray
    M: np.ndarray
    S_att: np.ndarray


@njit(cache=True)
def state_offsets(use, with_m, with_s):
    """(n, i_m, i_v, i_s): state size and offsets of M, of the hand states v, p and of the
    accelerometer scale factors (0: none)."""
    n = N_BASE
    i_s = 0
    if with_s:
        i_s = n
        n += 3
    i_m = 0
    if with_m:
        i_m = n
        n += 9
    i_v = 0
    if (use & USE_MOTION) != 0:
        i_v = n
        n += 6
    return n, i_m, i_v, i_s


@njit(cache=True)
def _wrap(a):
    return (a + np.pi) % (2.0 * np.pi) - np.pi


@njit(cache=True)
def range_diff_model(C, n_wall, o2_b, o3_b):
    """Predicted (d1-d2, d1-d3) and their Jacobian w.r.t. phi (2x3); beams along body x.

    d_i = (D - n.C o_i) / (n.C e_x) for a plane n.p = D, so d1 - d_i = n.C o_i / n.C e_x.
    With C = exp(phi) C_hat, d(n.C o)/dphi = (C o x n)^T.
    """
    u = np.ascontiguousarray(C[:, 0])
    c = n_wall @ u
    p2 = C @ o2_b
    p3 = C @ o3_b
    a2 = n_wall @ p2
    a3 = n_wall @ p3
    h = np.empty(2)
    h[0] = a2 / c
    h[1] = a3 / c
    du = np.cross(u, n_wall)
    H = np.zeros((2, 3))
    H[0, :] = np.cross(p2, n_wall) / c - a2 * du / (c * c)
    H[1, :] = np.cross(p3, n_wall) / c - a3 * du / (c * c)
    return h, H, c


@njit(cache=True)
def _feedback(x, C, b, ba, M, v, p, i_m, i_v, sa, i_s):
    """Apply the error-state estimate to the nominal (C_true = exp(phi) C_hat) and zero it."""
    Cn = rotvec_to_dcm(x[0:3]) @ C
    b += x[I_BG:I_BG + 3]
    ba += x[I_BA:I_BA + 3]
    if i_m > 0:
        for r in range(3):
            for c in range(3):
                M[r, c] += x[i_m + 3 * r + c]
    if i_v > 0:
        v += x[i_v:i_v + 3]
        p += x[i_v + 3:i_v + 6]
    if i_s > 0:
        sa += x[i_s:i_s + 3]
    x[:] = 0.0
    return Cn


@njit(cache=True)
def _gain(P, H, R, K):
    """K (n, m) = P H^T (H P H^T + R)^-1, the gain `kalman.update` applies (Cholesky of S); False,
    K untouched, if S is not positive definite (`update` then makes no update either)."""
    m, n = H.shape
    PHt = np.empty((n, m))
    matmul_into(P, np.ascontiguousarray(H.T), PHt)
    S = np.empty((m, m))
    matmul_into(H, PHt, S)
    for i in range(m):
        for j in range(m):
            S[i, j] += R[i, j]
    symmetrize(S)
    L = np.empty((m, m))
    if not cholesky_into(S, L):
        return False
    for i in range(n):
        cho_solve_into(L, PHt[i], K[i])
    return True


@njit(cache=True)
def _sens_update(Sv, K, H, Z):
    """Sv <- (I - K H) Sv - K Z on the first three columns (Z (m,3) the measurement's own sensitivity
    to the bias), (I - K H) Sv on the others (`Init.S0`)."""
    n, c = Sv.shape
    HS = np.empty((H.shape[0], c))
    matmul_into(H, Sv, HS)
    for i in range(H.shape[0]):
        for j in range(3):
            HS[i, j] += Z[i, j]
    KHS = np.empty((n, c))
    matmul_into(K, HS, KHS)
    for i in range(n):
        for j in range(c):
            Sv[i, j] -= KHS[i, j]


@njit(cache=True)
def _sens_predict(Sv, Phi):
    """Sv <- Phi Sv."""
    T = np.empty(Sv.shape)
    matmul_into(Phi, Sv, T)
    for i in range(Sv.shape[0]):
        for j in range(Sv.shape[1]):
            Sv[i, j] = T[i, j]


@njit(cache=True)
def _tracked_update(x, P, z, H, R, Sv, Z):
    """`kalman.update` with the bias sensitivity carried through the same gain (`Init.S0`)."""
    K = np.empty((H.shape[1], H.shape[0]))
    ok = _gain(P, H, R, K)
    nis = update(x, P, z, H, R)
    if ok and nis >= 0.0:
        _sens_update(Sv, K, H, Z)
    return nis


@njit(cache=True)
def consider_innovation_cov(S, H, Sv, Z, nz):
    """(m,m) covariance of an innovation's error with the errors the filter carries as sensitivities: the
    state error is e = a + Sv[:, 0:3] b_a + Sv[:, S_GYRO:] vec(dM) with a independent of b_a and dM, of which
    the filter's P holds a plus Sv[:, 3:6] b_a (its bias prior, `Init.S0`), so
    S_e = S - var_ba_prior B B^T + var_ba A A^T + var_gm G G^T, A = H Sv[:, 0:3] + Z, B = H Sv[:, 3:6],
    G = H Sv[:, S_GYRO:] (`local.honest_covariance` for the innovation). S = H P H^T + R the filter's own."""
    m = H.shape[0]
    HS = np.empty((m, Sv.shape[1]))
    matmul_into(H, Sv, HS)
    out = S.copy()
    for i in range(m):
        for j in range(m):
            acc = 0.0
            for c in range(3):
                acc += nz.var_ba * (HS[i, c] + Z[i, c]) * (HS[j, c] + Z[j, c]) - nz.var_ba_prior * HS[i, 3 + c] * HS[j, 3 + c]
            if Sv.shape[1] >= S_GYRO + 9:
                for c in range(S_GYRO, S_GYRO + 9):
                    acc += nz.var_gm * HS[i, c] * HS[j, c]
            out[i, j] += acc
    return out


@njit(cache=True)
def _honest_nis(S, z, H, Sv, Z, nz):
    """NIS of the innovation z (error state zero) against `consider_innovation_cov` of the filter's own
    S = H P H^T + R (the caller's: the field update has it already); NaN if that is not PD."""
    Se = consider_innovation_cov(0.5 * (S + S.T), H, Sv, Z, nz)
    Se = 0.5 * (Se + Se.T)
    m = z.shape[0]
    L = np.empty((m, m))
    if not cholesky_into(Se, L):
        return np.nan
    y = np.empty(m)
    cho_solve_into(L, z, y)
    return float(z @ y)


@njit(cache=True)
def _consider_update(x, P, z, H, R, n_keep, keep):
    """Kalman update whose gain is zero outside the `keep` states (Schmidt consider update, Joseph
    form, valid for any gain): the others' uncertainty enters S but they are never corrected."""
    n = x.shape[0]
    nu = z - H @ x
    PHt = P @ H.T
    S = H @ PHt + R
    S = 0.5 * (S + S.T)
    K = np.linalg.solve(S, PHt.T).T
    for i in range(n):
        if not keep[i]:
            K[i, :] = 0.0
    x += K @ nu
    I_KH = np.eye(n) - K @ H
    Pn = I_KH @ P @ I_KH.T + K @ R @ K.T
    P[:, :] = 0.5 * (Pn + Pn.T)
    return K


@njit(cache=True)
def marg_filter(s, fr, nz, hand, gates, init, out):
    """Forward (or, on reversed inputs, backward) error-state attitude filter; see the named tuples.

    Accelerometer: without USE_MOTION, gravity is measured directly where `s.grav_var` is finite
    (f_b = C^T (-g) + b_a, Eq. 5); with USE_MOTION the specific force is integrated in NED and the
    hand model (`Hand`) is the measurement, so that linear accelerations average out and a tilt error
    (g phi t of velocity) does not; still samples add zero-velocity updates.
    Magnetometer: the field vector m_b = C^T m_ref (Eq. 7, the Earth field of the log's survey),
    noise r_mag per axis. With `mag_consider` it never corrects the tilt, the accelerometer bias or the
    hand states (Schmidt consider update: a disturbed or mis-modelled field must not tilt the solution;
    the accelerometer owns them), only heading, gyro bias and M.
    Samples failing the field-magnitude test, the dip test or the windowed NIS test (mean NIS per
    dof over ~tau above `mag_nis_ratio`: a disturbance that lasts) are not used (`out.mag_ok` False).
    """
    N = s.t.shape[0]
    use = gates.use
    motion = (use & USE_MOTION) != 0
    n, i_m, i_v, i_s = state_offsets(use, gates.gyro_matrix, gates.acc_scale)
    C = init.C0.copy()
    b = init.bias.copy()
    ba = init.acc_bias.copy()
    sa = np.zeros(3)  # accelerometer scale factors (with gates.acc_scale)
    M = init.M0.copy()
    v = np.zeros(3)
    p = np.zeros(3)
    P = init.P0.copy()
    Sv = init.S0.copy()
    z3 = np.zeros((3, 3))
    z6 = np.zeros((6, 3))
    x = np.zeros(n)
    Phi = np.eye(n)
    Qd = np.zeros((n, n))
    f_up = -fr.g
    keep = np.ones(n, dtype=np.bool_)
    if gates.mag_consider:
        keep[0] = False
        keep[1] = False
        for i in range(3):
            keep[I_BA + i] = False
            if i_s > 0:
                keep[i_s + i] = False
        if i_v > 0:
            for i in range(6):
                keep[i_v + i] = False
    m_norm = np.sqrt(fr.m_ref @ fr.m_ref)
    m_dip = np.arctan2(fr.m_ref[2], np.sqrt(fr.m_ref[0] ** 2 + fr.m_ref[1] ** 2))
    use_osc = motion and hand.omega > 0.0
    c_p = hand.omega * hand.omega
    c_v = 2.0 * hand.zeta * hand.omega
    acc_dv = np.zeros(3)  # sum of (f_n + g) dt over the current model interval
    acc_dvf = np.zeros(3)  # sum of f_n dt
    acc_C = np.zeros((3, 3))  # sum of C dt
    acc_Cf = np.zeros((3, 3))  # sum of C diag(f) dt
    acc_p = np.zeros(3)
    acc_v = np.zeros(3)
    acc_T = 0.0
    acc_k = 0
    nis_avg = 1.0
    for k in range(N):
        w0 = s.gyro[k] - b
        wg = w0 - M @ w0 if i_m > 0 else w0  # (I + M)^-1 to first order
        if k > 0:
            dt = s.t[k] - s.t[k - 1]
            adt = abs(dt)
            w = wg - C.T @ fr.w_ie  # Eq. 19: omega_nb = omega_ib - C_bn omega_ie
            Phi[:, :] = 0.0
            for i in range(n):
                Phi[i, i] = 1.0
            Phi[0:3, I_BG:I_BG + 3] = -C * dt  # phi_dot = -C_hat (db + noise)
            if i_m > 0:
                for r in range(3):
                    for c in range(3):
                        for j in range(3):
                            Phi[j, i_m + 3 * r + c] = -C[j, r] * wg[c] * dt  # phi_dot = -C_hat dM omega
            Qd[:, :] = 0.0
            wdt2 = (w @ w) * dt * dt
            for i in range(3):
                Qd[i, i] = nz.q_att + nz.q_sf * wdt2
                Qd[I_BG + i, I_BG + i] = nz.q_bg * adt
                Qd[I_BA + i, I_BA + i] = nz.q_ba * adt
            if i_m > 0:
                for i in range(9):
                    Qd[i_m + i, i_m + i] = nz.q_m * adt
            if motion:
                Cm = C @ rotvec_to_dcm(0.5 * dt * w)  # mid-interval attitude of the mean sample
                fb = s.acc[k] - ba
                if i_s > 0:
                    fb = fb - sa * s.acc[k]  # (I + diag s)^-1 to first order
                f_n = Cm @ fb
                Phi[i_v:i_v + 3, 0:3] = -skew(f_n) * dt  # dv_dot = -[f_n x] phi - C db_a - C diag(f) ds
                Phi[i_v:i_v + 3, I_BA:I_BA + 3] = -Cm * dt
                if i_s > 0:
                    for i in range(3):
                        for j in range(3):
                            Phi[i_v + i, i_s + j] = -Cm[i, j] * s.acc[k, j] * dt
                for i in range(3):
                    Phi[i_v + 3 + i, i_v + i] = dt
                    Qd[i_v + i, i_v + i] = nz.q_vel
                p += v * dt + 0.5 * (f_n + fr.g) * dt * dt
                v += (f_n + fr.g) * dt
                if use_osc:
                    acc_dv += (f_n + fr.g) * dt
                    acc_dvf += f_n * dt
                    acc_C += Cm * dt
                    if i_s > 0:
                        for i in range(3):
                            for j in range(3):
                                acc_Cf[i, j] += Cm[i, j] * s.acc[k, j] * dt
                    acc_p += p * dt
                    acc_v += v * dt
                    acc_T += dt
                    acc_k += 1
            predict(x, P, Phi, Qd)
            _sens_predict(Sv, Phi)
            if Sv.shape[1] >= S_GYRO + 9:
                for r in range(3):
                    for c in range(3):
                        for j in range(3):
                            Sv[j, S_GYRO + 3 * r + c] -= C[j, r] * wg[c] * dt  # phi_dot = -C_hat dM omega
            C = C @ rotvec_to_dcm(w * dt)  # Eq. 17 integrated over one sample
        out.nis_acc[k] = np.nan
        out.nis_mag[k] = np.nan
        out.nis_rng[k] = np.nan
        out.mag_ok[k] = True
        # ---- gravity (Eq. 5): f_b = C^T f_up + b_a, while quasi-static, without the hand model
        if (use & USE_ACC) != 0 and not motion and not np.isnan(s.grav_var[k]):
            Cm = C
            if k > 0:
                Cm = C @ rotvec_to_dcm(-0.5 * (s.t[k] - s.t[k - 1]) * wg)
            CmT = np.ascontiguousarray(Cm.T)
            H = np.zeros((3, n))
            H[:, 0:3] = CmT @ skew(f_up)
            for i in range(3):
                H[i, I_BA + i] = 1.0
            hf = CmT @ f_up
            if i_s > 0:
                for i in range(3):
                    H[i, i_s + i] = hf[i]
                hf = hf + sa * hf
            z = s.acc[k] - (hf + ba)
            nis_e = _honest_nis(H @ P @ H.T + np.eye(3) * s.grav_var[k], z, H, Sv, z3, nz)
            if _tracked_update(x, P, z, H, np.eye(3) * s.grav_var[k], Sv, z3) >= 0.0:
                out.nis_acc[k] = nis_e
            C = _feedback(x, C, b, ba, M, v, p, i_m, i_v, sa, i_s)
        # ---- hand model: the velocity change of the interval equals the model's integrated acceleration
        if (use & USE_ACC) != 0 and use_osc and acc_k >= hand.step:
            # 0 = dv_true + int(omega^2 p + 2 zeta omega v) dt - int w dt with the true values
            # v = v_hat + dv, p = p_hat + dp, C (f - b_a) = C_hat (f - b_a_hat) - [f_n x] phi - C db_a
            z = -(acc_dv + c_p * acc_p + c_v * acc_v)
            Ho = np.zeros((3, n))
            Ho[:, 0:3] = -skew(acc_dvf)
            Ho[:, I_BA:I_BA + 3] = -acc_C
            if i_s > 0:
                Ho[:, i_s:i_s + 3] = -acc_Cf
            Ro = np.zeros((3, 3))
            for i in range(3):
                Ho[i, i_v + i] = c_v * acc_T
                Ho[i, i_v + 3 + i] = c_p * acc_T
                Ro[i, i] = hand.q * acc_T + nz.q_vel * acc_k
            nis_e = _honest_nis(Ho @ P @ Ho.T + Ro, z, Ho, Sv, z3, nz)
            if _tracked_update(x, P, z, Ho, Ro, Sv, z3) >= 0.0:
                out.nis_acc[k] = nis_e
            C = _feedback(x, C, b, ba, M, v, p, i_m, i_v, sa, i_s)
            acc_dv[:] = 0.0
            acc_dvf[:] = 0.0
            acc_C[:, :] = 0.0
            acc_Cf[:, :] = 0.0
            acc_p[:] = 0.0
            acc_v[:] = 0.0
            acc_T = 0.0
            acc_k = 0
        if (use & USE_ACC) != 0 and use_osc and s.still[k] and k % hand.step == 0:
            Hz = np.zeros((3, n))
            for i in range(3):
                Hz[i, i_v + i] = 1.0
            _tracked_update(x, P, -v, Hz, np.eye(3) * hand.zupt_sd**2, Sv, z3)
            C = _feedback(x, C, b, ba, M, v, p, i_m, i_v, sa, i_s)
        if (use & USE_ACC) != 0 and motion and not use_osc and k % hand.epoch == 0:
            Hm = np.zeros((6, n))
            Rm = np.zeros((6, 6))
            zm = np.empty(6)
            for i in range(3):
                Hm[i, i_v + i] = 1.0
                Hm[3 + i, i_v + 3 + i] = 1.0
                Rm[i, i] = (hand.zupt_sd if s.still[k] else hand.sd_vel) ** 2
                Rm[3 + i, 3 + i] = hand.sd_pos**2
                zm[i] = -v[i]
                zm[3 + i] = -p[i]
            _tracked_update(x, P, zm, Hm, Rm, Sv, z6)  # (6 dof: not recorded with the 3-dof accelerometer NIS)
            C = _feedback(x, C, b, ba, M, v, p, i_m, i_v, sa, i_s)
        # ---- magnetic field vector (Eq. 7): m_b = C^T m_ref, tilt only considered (Schmidt)
        if (use & USE_MAG) != 0 and not np.isnan(s.mag[k, 0]):
            m = s.mag[k]
            ok = True
            if gates.mag_norm_tol > 0.0 and abs(np.sqrt(m @ m) - m_norm) > gates.mag_norm_tol:
                ok = False
            if gates.mag_dip_tol > 0.0:
                vm = C @ m
                if abs(np.arctan2(vm[2], np.sqrt(vm[0] * vm[0] + vm[1] * vm[1])) - m_dip) > gates.mag_dip_tol:
                    ok = False
            CT = np.ascontiguousarray(C.T)
            H = np.zeros((3, n))
            H[:, 0:3] = CT @ skew(fr.m_ref)  # C_true^T m = C_hat^T (I - [phi x]) m
            z = m - CT @ fr.m_ref
            R = np.eye(3) * nz.r_mag
            S = H @ P @ H.T + R
            nis = z @ np.linalg.solve(S, z)
            if gates.mag_nis_tau_s > 0.0 and k > 0:
                a = min(1.0, abs(s.t[k] - s.t[k - 1]) / gates.mag_nis_tau_s)
                nis_avg += a * (min(nis / 3.0, 100.0) - nis_avg)
                if nis_avg > gates.mag_nis_ratio:
                    ok = False
            out.mag_ok[k] = ok
            if ok:
                # the NIS of the updates made (a rejected field is no update), against the error's whole covariance
                out.nis_mag[k] = _honest_nis(S, z, H, Sv, z3, nz)
                if gates.mag_consider:
                    Km = _consider_update(x, P, z, H, R, n, keep)
                    _sens_update(Sv, Km, H, z3)
                else:
                    _tracked_update(x, P, z, H, R, Sv, z3)
                C = _feedback(x, C, b, ba, M, v, p, i_m, i_v, sa, i_s)
        # ---- three-beam range differences (exact plane geometry)
        if (use & USE_RANGE) != 0 and not (np.isnan(s.rdiff[k, 0]) or np.isnan(s.rdiff[k, 1])):
            hr, Hr, c = range_diff_model(C, fr.wall_n, fr.o2, fr.o3)
            if c > 0.2:
                H = np.zeros((2, n))
                H[:, 0:3] = Hr
                z = s.rdiff[k] - hr
                # the wall's azimuth error (from the levelled alignment) biases both differences
                # like a heading error of the device: dz = Hr[:, 2] d(azimuth)
                Zr = np.empty((2, 3))
                for i in range(2):
                    for j in range(3):
                        Zr[i, j] = Hr[i, 2] * fr.wall_sens[j]
                # gated on the NIS it records (the innovation's whole covariance), so that the innovations
                # table's `accepted` (recorded NIS below the gate) is the update's own decision
                S = H @ P @ H.T + nz.r_rng
                nis = _honest_nis(S, z, H, Sv, Zr, nz)
                if np.isnan(nis):
                    nis = z @ np.linalg.solve(S, z)
                out.nis_rng[k] = nis
                if gates.rng_gate <= 0.0 or nis < gates.rng_gate:
                    _tracked_update(x, P, z, H, nz.r_rng, Sv, Zr)
                    C = _feedback(x, C, b, ba, M, v, p, i_m, i_v, sa, i_s)
        C = orthonormalize(C)
        out.C[k] = C
        out.P_att[k] = P[0:3, 0:3]
        for i in range(3):
            for j in range(Sv.shape[1]):
                out.S_att[k, i, j] = Sv[i, j]
        out.bias[k] = b
        out.acc_bias[k] = ba
        for i in range(6):
            out.var_bias[k, i] = P[I_BG + i, I_BG + i]
        if i_m > 0:
            out.M[k] = M


@njit(cache=True)
def _paper8_F(w):
    """Eq. 21 system matrix: rows of C obey d(row)/dt = row x omega (from Eq. 17)."""
    F = np.zeros((8, 8))
    Wt = -skew(w)  # d(row)/dt = -[w x] row
    F[0:3, 0:3] = Wt
    F[3:6, 3:6] = Wt
    F[6, 7] = w[0]  # dC32/dt = w_x C33 (C31 = 0 without roll)
    F[7, 6] = -w[0]  # dC33/dt = -w_x C32
    return F


@njit(cache=True)
def paper8_obs(theta, psi):
    """Eq. 22 observation vector: the 8 DCM elements of Eq. 16 from pitch and yaw (ENU/RFU)."""
    z = np.empty(8)
    z[0] = np.cos(psi)
    z[1] = np.cos(theta) * np.sin(psi)
    z[2] = -np.sin(theta) * np.sin(psi)
    z[3] = -np.sin(psi)
    z[4] = np.cos(theta) * np.cos(psi)
    z[5] = -np.sin(theta) * np.cos(psi)
    z[6] = np.sin(theta)
    z[7] = np.cos(theta)
    return z


@njit(cache=True)
def paper8_obs_jac(theta, psi):
    """d z / d(theta, psi), (8, 2)."""
    J = np.zeros((8, 2))
    st, ct, sp, cp = np.sin(theta), np.cos(theta), np.sin(psi), np.cos(psi)
    J[0, 1] = -sp
    J[1, 0] = -st * sp
    J[1, 1] = ct * cp
    J[2, 0] = -ct * sp
    J[2, 1] = -st * cp
    J[3, 1] = -cp
    J[4, 0] = -st * cp
    J[4, 1] = -ct * sp
    J[5, 0] = -ct * cp
    J[5, 1] = st * sp
    J[6, 0] = ct
    J[7, 0] = -st
    return J


@njit(cache=True)
def run_paper8(t, gyro_rfu, obs, obs_var, x0, P0, w_ie_enu, q_elem, r_floor, gate,
               out_x, out_P, out_nis):
    """Paper 000 Eq. 21-26 with H = I8; obs (N,2) = (theta, psi) rad per sample (NaN = none).

    obs_var (N,2) rad^2; R = J diag(obs_var) J^T + r_floor I (the floor stands for the
    linearization of the rank-2 map (theta, psi) -> 8 elements, which the paper's R ignores).
    q_elem: process noise per element per sample. gate <= 0: no innovation gate.
    """
    N = t.shape[0]
    x = x0.copy()
    P = P0.copy()
    H = np.eye(8)
    Qd = np.eye(8) * q_elem
    for k in range(N):
        if k > 0:
            dt = t[k] - t[k - 1]
            C = np.zeros((3, 3))
            C[0, :] = x[0:3]
            C[1, :] = x[3:6]
            C[2, 1] = x[6]
            C[2, 2] = x[7]
            w = gyro_rfu[k] - np.ascontiguousarray(C.T) @ w_ie_enu  # Eq. 19
            F = _paper8_F(w)
            Fdt = F * dt
            Phi = np.eye(8) + Fdt + 0.5 * (Fdt @ Fdt)
            predict(x, P, Phi, Qd)
        out_nis[k] = np.nan
        if not (np.isnan(obs[k, 0]) or np.isnan(obs[k, 1])):
            z = paper8_obs(obs[k, 0], obs[k, 1])
            J = paper8_obs_jac(obs[k, 0], obs[k, 1])
            R = J @ np.diag(obs_var[k]) @ J.T + np.eye(8) * r_floor
            # NIS in the (pitch, yaw) space of the observation (2 dof): the 8-element R is rank 2
            st = min(1.0, max(-1.0, x[6]))
            th = np.arcsin(st)
            ps = np.arctan2(x[1], x[4])
            Jp = np.zeros((2, 8))
            Jp[0, 6] = 1.0 / max(np.sqrt(1.0 - st * st), 1e-6)
            h2 = x[1] * x[1] + x[4] * x[4]
            Jp[1, 1] = x[4] / h2
            Jp[1, 4] = -x[1] / h2
            nu2 = np.empty(2)
            nu2[0] = obs[k, 0] - th
            nu2[1] = _wrap(obs[k, 1] - ps)
            S2 = Jp @ P @ Jp.T + np.diag(obs_var[k])
            nis = nu2 @ np.linalg.solve(S2, nu2)
            out_nis[k] = nis
            if gate <= 0.0 or nis < gate:
                update(x, P, z, H, R)
        out_x[k] = x
        out_P[k] = P
