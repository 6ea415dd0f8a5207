"""Compiled per-sample loops of the attitude local filters (paper 000 Eq. 16-26).

Two models share this module:

- `run_full`: error-state DCM filter valid at any roll. Nominal `C_nb` (FRD->NED) propagated by
  Eq. 17-19 with the gyro; error state x = [phi (3, NED attitude error, C_true = exp(phi) C_hat),
  gyro bias error (3)]; measurements are gravity (Eq. 5), magnetic heading (Eq. 8) and the exact
  three-beam range differences (contract geometry behind Eq. 10). The same kernel runs backward in
  time on reversed, negated gyro samples.
- `run_paper8`: the paper's 8-state linear DCM filter (Eq. 16, 21-22) in its own RFU/ENU frames.

Kalman algebra is `tpos_cli.filters.kalman` (Joseph form); nothing here re-implements it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tpos_cli.filters.kalman import predict, update
from tpos_cli.frames._kernels import orthonormalize, rotvec_to_dcm, skew

# measurement kinds, bit flags in `use`
USE_ACC = 1
USE_MAG = 2
USE_RANGE = 4
USE_MOTION = 8  # bounded-motion velocity/position states (hand-held device, standing observer)


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
def _feedback(x, C, b, v, p, i_v, M, i_m, u, i_u):
    """Apply an error-state estimate to the nominal (C_true = exp(phi) C_hat) and zero it."""
    Cn = rotvec_to_dcm(x[0:3]) @ C
    b += x[3:6]
    if i_m > 0:
        for r in range(3):
            for c in range(3):
                M[r, c] += x[i_m + 3 * r + c]
    if i_v > 0:
        v += x[i_v:i_v + 3]
        p += x[i_v + 3:i_v + 6]
    if i_u > 0:
        u += x[i_u:i_u + 3]
    x[:] = 0.0
    return Cn


@njit(cache=True)
def run_full(t, gyro, acc, mag, rdiff, use, C0, bias0, P0, w_ie_n, g_n, q_att, q_bias,
             q_sf, r_grav, r_mag_ut, decl, mag_ref, mag_norm_tol, mag_dip_tol,
             n_wall, o2_b, o3_b, r_rng, rng_gate, q_vel, motion_sd, motion_every, rec_nis, rec_tau_s,
             still, zupt_sd, M0, gyro_err_sd, q_gyro_err, osc, osc_every,
             out_C, out_P, out_bias, out_nis_acc, out_nis_mag, out_nis_rng, out_mag_ok, out_ll, out_M):
    """Forward (or, on reversed inputs, backward) error-state attitude filter.

    t (N,) s; gyro, acc, mag (N,3) FRD; rdiff (N,2) d1-d2, d1-d3 m (NaN = none);
    `use` bit flags; C0 (3,3), bias0 (3,), P0 (6,6); w_ie_n, g_n (3,) NED Earth rate and
    gravity; q_att rad^2 per sample, q_bias (rad/s)^2 per second; q_sf the relative variance of
    the rotation angle of a sample (scale-factor and integration errors); r_grav (N,) (m/s^2)^2
    variance of the gravity update at each sample (NaN: no update there);
    r_mag_ut uT^2; decl rad; mag_ref (norm uT, dip rad); tolerances uT and rad
    (mag_norm_tol <= 0 disables the check); n_wall (3,) NED unit wall normal; o2_b, o3_b (3,)
    LR2/LR3 offsets FRD m; r_rng (2,2) m^2; rng_gate chi2(2) gate (<= 0: none).
    USE_MOTION: the error state grows by velocity and position (12 states); the specific force
    is integrated in NED and a hand-held device of a standing observer is held to v = 0, p = 0
    with SDs motion_sd (2,) (m/s, m) every `motion_every` samples: linear accelerations average
    out, a tilt error does not (g phi t^2 / 2 of position). q_vel (m/s)^2 per sample.
    rec_nis > 0: when the mean magnetic NIS over ~rec_tau_s exceeds it, the heading variance is
    re-opened by the innovation squared (the filter was over-confident about a wrong heading).
    still (N,) bool: samples in a detected still period; only there is gravity measured directly
    (and, with USE_MOTION, the velocity held to zero with SD zupt_sd m/s at each motion epoch).
    gyro_err_sd > 0: nine more states, the gyro's scale-factor and misalignment matrix M
    (omega_meas = (I + M) omega + b; prior SD gyro_err_sd, random walk q_gyro_err per second,
    initial value M0 (3,3)), observable whenever the device turns; out_M (N,3,3) is written only then.
    osc = (omega rad/s, zeta, q (m/s^2)^2/Hz) with omega > 0 replaces the independent v = 0, p = 0
    pseudo-measurements by a correlated model of the hand's displacement about its mean position:
    a damped oscillator p'' = -omega^2 p - 2 zeta omega p' + w, w white with PSD q (stationary SDs
    sqrt(q / (4 zeta omega^3)) m and omega times that in m/s). Every `osc_every` samples the
    strapdown velocity change (specific force rotated by C plus gravity) must equal the model's
    integrated acceleration within the integral of w (variance q T): the accelerometer itself is
    the tilt measurement in motion, with a noise that is honest about the correlation of the motion.
    In still periods the zero-velocity update is still applied every `motion_every` samples.
    osc[3] = omega_c > 0 makes the driving force itself a first-order Gauss-Markov process
    (u' = -omega_c u + w, three more states): a band-pass acceleration spectrum, flat between omega and
    omega_c and falling above, as a hand's; the integral of u over a model interval is then a state
    (H = -T) and only its within-interval change (variance q T^3 / 3) is measurement noise.
    Outputs are filled for each sample (the posterior after that sample; out_P is 6x6);
    out_ll (N,2): Gaussian log-likelihood of the magnetic and the motion-model innovations of the
    sample (NaN: none), from which noise levels are estimated by maximum likelihood.
    """
    N = t.shape[0]
    motion = (use & USE_MOTION) != 0
    n = 6
    i_m = 0
    if gyro_err_sd > 0.0:
        i_m = n
        n += 9
    i_v = 0
    if motion:
        i_v = n
        n += 6
    om_c = osc[3] if osc.shape[0] > 3 else 0.0
    i_u = 0
    if motion and osc[0] > 0.0 and om_c > 0.0:
        i_u = n
        n += 3
    C = C0.copy()
    b = bias0.copy()
    v = np.zeros(3)
    p = np.zeros(3)
    u = np.zeros(3)  # driving force of the band-pass hand model (m/s^2)
    M = M0.copy()
    P = np.zeros((n, n))
    P[0:6, 0:6] = P0
    for i in range(9 if i_m > 0 else 0):
        P[i_m + i, i_m + i] = gyro_err_sd**2
    for i in range(3):
        if motion:
            P[i_v + i, i_v + i] = motion_sd[0] ** 2
            P[i_v + 3 + i, i_v + 3 + i] = motion_sd[1] ** 2
        if i_u > 0:
            P[i_u + i, i_u + i] = osc[2] / (2.0 * om_c)  # stationary variance of u
    x = np.zeros(n)
    Phi = np.eye(n)
    Qd = np.zeros((n, n))
    f_n_down = -g_n
    nis_avg = 0.0
    Hm = np.zeros((6, n))
    if motion:
        for i in range(6):
            Hm[i, i_v + i] = 1.0
    Rm = np.zeros((6, 6))
    for i in range(3):
        Rm[i, i] = motion_sd[0] ** 2
        Rm[3 + i, 3 + i] = motion_sd[1] ** 2
    om = osc[0]
    use_osc = motion and om > 0.0
    c_p = om * om
    c_v = 2.0 * osc[1] * om
    acc_dv = np.zeros(3)  # sum of (f_n + g) dt over the current model interval
    acc_dvf = np.zeros(3)  # sum of f_n dt
    acc_p = np.zeros(3)  # sum of p dt
    acc_v = np.zeros(3)  # sum of v dt
    acc_T = 0.0
    acc_k = 0
    Ho = np.zeros((3, n))
    Ro = np.zeros((3, 3))
    for k in range(N):
        wg = gyro[k] - b
        if i_m > 0:
            wg = wg - M @ wg  # (I + M)^-1 to first order
        if k > 0:
            dt = t[k] - t[k - 1]
            Ct = np.ascontiguousarray(C.T)
            w = wg - Ct @ w_ie_n  # Eq. 19: omega_nb = omega_ib - C_bn omega_ie
            Phi[:, :] = 0.0
            for i in range(n):
                Phi[i, i] = 1.0
            Phi[0:3, 3:6] = -C * dt  # phi_dot = -C_hat (db + noise)
            if i_m > 0:
                for r in range(3):
                    for c in range(3):
                        for j in range(3):
                            Phi[j, i_m + 3 * r + c] = -C[j, r] * wg[c] * dt  # phi_dot = -C_hat dM omega
            Qd[:, :] = 0.0
            wdt2 = (w @ w) * dt * dt
            for i in range(3):
                Qd[i, i] = q_att + q_sf * wdt2
                Qd[3 + i, 3 + i] = q_bias * abs(dt)
            for i in range(9 if i_m > 0 else 0):
                Qd[i_m + i, i_m + i] = q_gyro_err * abs(dt)
            Cm = C @ rotvec_to_dcm(0.5 * dt * w)  # mid-interval attitude of the mean sample
            if motion:
                f_n = Cm @ acc[k]
                Phi[i_v:i_v + 3, 0:3] = -skew(f_n) * dt  # dv_dot = -[f_n x] phi
                for i in range(3):
                    Phi[i_v + 3 + i, i_v + i] = dt
                    Qd[i_v + i, i_v + i] = q_vel
                p += v * dt + 0.5 * (f_n + g_n) * dt * dt
                v += (f_n + g_n) * dt
                if i_u > 0:
                    eu = np.exp(-om_c * abs(dt))
                    u *= eu
                    for i in range(3):
                        Phi[i_u + i, i_u + i] = eu
                        Qd[i_u + i, i_u + i] = osc[2] / (2.0 * om_c) * (1.0 - eu * eu)
                if use_osc:
                    acc_dv += (f_n + g_n) * dt
                    acc_dvf += f_n * dt
                    acc_p += p * dt
                    acc_v += v * dt
                    acc_T += dt
                    acc_k += 1
            predict(x, P, Phi, Qd)
            C = C @ rotvec_to_dcm(w * dt)  # Eq. 17 integrated over one sample
        out_nis_acc[k] = np.nan
        out_nis_mag[k] = np.nan
        out_nis_rng[k] = np.nan
        out_mag_ok[k] = True
        out_ll[k, 0] = np.nan
        out_ll[k, 1] = np.nan
        # gravity: f_b = C^T f_n with f_n = -g_n (Eq. 5), only while quasi-static
        if use & USE_ACC:
            f = acc[k]
            if not np.isnan(r_grav[k]):
                # an IMU row is the mean over (t_{k-1}, t_k]: compare with the mid-interval attitude
                Cm = C
                if k > 0:
                    Cm = C @ rotvec_to_dcm(-0.5 * (t[k] - t[k - 1]) * wg)
                CmT = np.ascontiguousarray(Cm.T)
                h = CmT @ f_n_down
                H = np.zeros((3, n))
                H[:, 0:3] = CmT @ skew(f_n_down)
                z = f - h
                R = np.eye(3) * r_grav[k]
                out_nis_acc[k] = update(x, P, z, H, R)
                C = _feedback(x, C, b, v, p, i_v, M, i_m, u, i_u)
        if use_osc and acc_k >= osc_every:
            # 0 = dv_true + int(omega^2 p + 2 zeta omega v) dt - int w dt, with the true values
            # v = v_hat + dv, p = p_hat + dp and C f = C_hat f - [f_n x] phi (phi at the epoch)
            z = -(acc_dv + c_p * acc_p + c_v * acc_v)
            Ho[:, :] = 0.0
            Ho[:, 0:3] = -skew(acc_dvf)
            for i in range(3):
                Ho[i, i_v + i] = c_v * acc_T
                Ho[i, i_v + 3 + i] = c_p * acc_T
                Ro[i, i] = osc[2] * acc_T + q_vel * acc_k
            if i_u > 0:
                # ... with the force a state: int u dt = T u(epoch) + (within-interval change)
                z += acc_T * u
                for i in range(3):
                    Ho[i, i_u + i] = -acc_T
                    Ro[i, i] = osc[2] * acc_T**3 / 3.0 + q_vel * acc_k
            So = Ho @ P @ Ho.T + Ro
            nis_o = update(x, P, z, Ho, Ro)
            out_ll[k, 1] = -0.5 * (nis_o + np.log(np.linalg.det(So)) + 3.0 * np.log(2.0 * np.pi))
            C = _feedback(x, C, b, v, p, i_v, M, i_m, u, i_u)
            acc_dv[:] = 0.0
            acc_dvf[:] = 0.0
            acc_p[:] = 0.0
            acc_v[:] = 0.0
            acc_T = 0.0
            acc_k = 0
        if use_osc and still[k] and motion_every > 0 and k % motion_every == 0:
            z3 = -v
            Hz = np.zeros((3, n))
            Rz = np.zeros((3, 3))
            for i in range(3):
                Hz[i, i_v + i] = 1.0
                Rz[i, i] = zupt_sd**2
            update(x, P, z3, Hz, Rz)
            C = _feedback(x, C, b, v, p, i_v, M, i_m, u, i_u)
        if motion and (not use_osc) and motion_every > 0 and k % motion_every == 0:
            z = np.empty(6)
            z[0:3] = -v
            z[3:6] = -p
            if still[k]:
                for i in range(3):
                    Rm[i, i] = zupt_sd**2
            else:
                for i in range(3):
                    Rm[i, i] = motion_sd[0] ** 2
            Sm = P[i_v:i_v + 6, i_v:i_v + 6] + Rm
            nis_m = update(x, P, z, Hm, Rm)
            out_ll[k, 1] = -0.5 * (nis_m + np.log(np.linalg.det(Sm)) + 6.0 * np.log(2.0 * np.pi))
            C = _feedback(x, C, b, v, p, i_v, M, i_m, u, i_u)
        # magnetic heading (Eq. 8): azimuth of the levelled field is the declination
        if use & USE_MAG:
            m = mag[k]
            if not np.isnan(m[0]):
                vm = C @ m
                hn2 = vm[0] * vm[0] + vm[1] * vm[1]
                mn = np.sqrt(m @ m)
                dip = np.arctan2(vm[2], np.sqrt(hn2))
                ok = True
                if mag_norm_tol > 0.0:
                    if abs(mn - mag_ref[0]) > mag_norm_tol or abs(dip - mag_ref[1]) > mag_dip_tol:
                        ok = False
                out_mag_ok[k] = ok
                if ok and hn2 > 1e-6:
                    az = np.arctan2(vm[1], vm[0])
                    H = np.zeros((1, n))
                    H[0, 0] = -vm[0] * vm[2] / hn2
                    H[0, 1] = -vm[1] * vm[2] / hn2
                    H[0, 2] = 1.0
                    z = np.empty(1)
                    z[0] = _wrap(decl - az)
                    R = np.empty((1, 1))
                    R[0, 0] = r_mag_ut / hn2
                    s_mag = (H @ P @ H.T)[0, 0] + R[0, 0]
                    nis = update(x, P, z, H, R)
                    out_nis_mag[k] = nis
                    out_ll[k, 0] = -0.5 * (nis + np.log(s_mag) + np.log(2.0 * np.pi))
                    C = _feedback(x, C, b, v, p, i_v, M, i_m, u, i_u)
                    if rec_nis > 0.0 and k > 0:
                        a = min(1.0, (t[k] - t[k - 1]) / rec_tau_s)
                        nis_avg += a * (nis - nis_avg)
                        if nis_avg > rec_nis:
                            # persistent heading inconsistency: re-open the heading variance
                            P[2, 2] += z[0] * z[0]
                            nis_avg = 0.0
        # three-beam range differences (exact plane geometry)
        if use & USE_RANGE:
            if not (np.isnan(rdiff[k, 0]) or np.isnan(rdiff[k, 1])):
                hr, Hr, c = range_diff_model(C, n_wall, o2_b, o3_b)
                if c > 0.2:
                    H = np.zeros((2, n))
                    H[:, 0:3] = Hr
                    z = rdiff[k] - hr
                    Patt = np.ascontiguousarray(P[0:3, 0:3])
                    S = Hr @ Patt @ np.ascontiguousarray(Hr.T) + r_rng
                    nis = z @ np.linalg.solve(S, z)
                    out_nis_rng[k] = nis
                    if rng_gate <= 0.0 or nis < rng_gate:
                        update(x, P, z, H, r_rng)
                        C = _feedback(x, C, b, v, p, i_v, M, i_m, u, i_u)
        C = orthonormalize(C)
        out_C[k] = C
        out_P[k] = P[0:6, 0:6]
        out_bias[k] = b
        if i_m > 0:
            out_M[k] = M


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
