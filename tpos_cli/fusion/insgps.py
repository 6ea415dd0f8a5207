"""Loosely coupled INS/GPS filter runs (paper 003): forward, and backward in reversed time.

`run_insgps` wraps the compiled loop `_kernels.insgps_kernel` and returns a `FilterRun` in
forward time order whatever the direction, with the backward run's velocity, gyro bias and
covariances converted to forward-time signs (`nav_errors.backward_sign`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli.errors import ProcessingError
from tpos_cli.filters.gating import chi2_threshold
from tpos_cli.fusion._kernels import insgps_kernel
from tpos_cli.fusion.nav_errors import backward_sign
from tpos_cli.ins.mechanization import reverse_imu


@dataclass(frozen=True)
class GpsFixes:
    """Fixes used by the filter: t_s (M,), lla (M,3) deg/m, vel_ned_mps (M,3) NaN if absent,
    sigma_pos_ned_m (M,3), sigma_vel_mps (M,3)."""

    t_s: np.ndarray
    lla: np.ndarray
    vel_ned_mps: np.ndarray
    sigma_pos_ned_m: np.ndarray
    sigma_vel_mps: np.ndarray


@dataclass(frozen=True)
class FilterConfig:
    """SI filter settings. q: white-noise PSDs [acc (m/s^2)^2 s, gyro rad^2/s, acc-bias drive
    (m/s^3)^2 s, gyro-bias drive (rad/s^2)^2 s]; tau <= 0: random-walk bias; cov_step: IMU
    samples per covariance epoch; gate_probability: chi-square gate on each fix."""

    q: np.ndarray
    tau_acc_s: float
    tau_gyro_s: float
    lever_arm_b_m: np.ndarray
    cov_step: int = 10
    gate_probability: float = 0.9999
    max_consecutive_rejections: int = 5
    ungated_after_gap_s: float = 0.0  # > 0: the first fix after a longer gap between fixes is not gated
    # time-correlated GPS position error: three first-order Gauss-Markov states (NED) with these
    # stationary SDs (m) and time constant; None or all zero = white fixes only (15 states)
    gps_gm_sigma_ned_m: np.ndarray | None = None
    gps_gm_tau_s: float = 30.0

    @property
    def n_states(self) -> int:
        """15, or 18 with the GPS error states."""
        s = self.gps_gm_sigma_ned_m
        return 18 if s is not None and np.any(np.asarray(s) > 0) else 15


@dataclass(frozen=True)
class InitialState:
    """Nominal state at the run's first sample (forward time signs): nav (6,) [lat_rad, lon_rad,
    h_m, vn, ve, vd], C_nb (3,3), bias (6,) [acc m/s^2, gyro rad/s], P0 (15,15). With GPS error
    states (`FilterConfig.n_states` 18) `run_insgps` appends them: estimate 0 (or bias[6:9] when
    given), covariance the stationary one of the process, uncorrelated with the rest."""

    nav: np.ndarray
    C_nb: np.ndarray
    bias: np.ndarray
    P0: np.ndarray


@dataclass(frozen=True)
class FilterRun:
    """One filter run in forward time order.

    nav (N,6), C_nb (N,3,3), bias (N,6): nominal after feedback at every IMU sample (N,9 with
    the GPS error states: bias[:, 6:9] the estimated error of the fixes, NED m).
    ep_idx (E,): sample index of each covariance epoch, increasing; ep_P (E,n,n) (n = 15 or 18):
    covariance after the update at that epoch. Forward runs also hold ep_Phi (E,n,n) (transition
    from epoch e-1 to e), ep_Ppred (E,n,n) and ep_dx (E,n) (correction fed back at e) for RTS.
    Per fix (in the order of `GpsFixes`): innovation (M,6) [pos NED m, vel NED m/s] NaN where
    absent; innovation_pvar (M,6) the filter's predicted variance of each component (diagonal
    of H P- H^T, without R); nis (M,2) and accepted (M,2): [position, velocity] NIS (3 d.o.f. each, NaN where
    not processed, e.g. fixes before the first sample) and whether each part was applied.
    """

    backward: bool
    nav: np.ndarray
    C_nb: np.ndarray
    bias: np.ndarray
    ep_idx: np.ndarray
    ep_P: np.ndarray
    ep_Phi: np.ndarray | None
    ep_Ppred: np.ndarray | None
    ep_dx: np.ndarray | None
    innovation: np.ndarray
    nis: np.ndarray
    accepted: np.ndarray
    innovation_pvar: np.ndarray | None = None
    innovation_logdet: np.ndarray | None = None  # (M,2) log det S per part (NaN where not processed)


def run_insgps(t_s, gyro_b_rps, acc_b_mps2, fixes: GpsFixes, init: InitialState, cfg: FilterConfig,
               *, backward: bool = False, store_rts: bool | None = None) -> FilterRun:
    """Run the closed-loop 15-state filter over the log, forward or backward in time.

    For `backward`, `init` is the state at the LAST sample (forward-time signs).
    """
    t = np.ascontiguousarray(t_s, dtype=float)
    gyro = np.ascontiguousarray(gyro_b_rps, dtype=float)
    acc = np.ascontiguousarray(acc_b_mps2, dtype=float)
    n = t.size
    if store_rts is None:
        store_rts = not backward
    ns = cfg.n_states
    gm_sd = np.zeros(3) if ns == 15 else np.asarray(cfg.gps_gm_sigma_ned_m, dtype=float) * np.ones(3)
    if ns > 15 and not cfg.gps_gm_tau_s > 0:
        raise ValueError("`gps_gm_tau_s` must be > 0 with GPS error states")
    sign15 = np.ones(ns)  # GPS position errors keep their sign in reversed time
    sign15[:15] = backward_sign()
    nav0 = np.array(init.nav, dtype=float)
    bias0 = np.zeros(6 + ns - 15)
    nb = min(bias0.size, np.size(init.bias))
    bias0[:nb] = np.asarray(init.bias, dtype=float)[:nb]
    P0 = np.zeros((ns, ns))
    P0[:15, :15] = np.asarray(init.P0, dtype=float)[:15, :15]
    P0[15:, 15:] = np.diag(gm_sd[: ns - 15] ** 2)  # stationary: the error is there from the start
    t_fix = np.asarray(fixes.t_s, dtype=float)
    vel = np.array(fixes.vel_ned_mps, dtype=float)
    if backward:
        t, gyro, acc = reverse_imu(t, gyro, acc)
        nav0[3:] *= -1.0
        bias0[3:6] *= -1.0
        P0 = P0 * np.outer(sign15, sign15)
        t_fix = -t_fix
        vel = -vel
        earth_sign = -1.0
    else:
        earth_sign = 1.0
    idx = np.searchsorted(t, t_fix, side="left")
    order = np.argsort(idx, kind="stable")
    idx_s = idx[order]
    keep = (idx_s >= 1) & (idx_s < n)
    order, idx_s = order[keep], idx_s[keep]
    lag = t[idx_s] - t_fix[order]
    pos = np.column_stack([np.radians(fixes.lla[:, 0]), np.radians(fixes.lla[:, 1]), fixes.lla[:, 2]])[order]
    var = np.column_stack([fixes.sigma_pos_ned_m, fixes.sigma_vel_mps])[order] ** 2
    vel_o = vel[order]
    m = order.size
    n_ep = n // max(cfg.cov_step, 1) + m + 3
    ep_idx = np.zeros(n_ep, dtype=np.int64)
    ep_P = np.empty((n_ep, ns, ns))
    ep_dx = np.empty((n_ep, ns))
    nr = n_ep if store_rts else 1
    ep_Phi = np.empty((nr, ns, ns))
    ep_Ppred = np.empty((nr, ns, ns))
    out_nav = np.empty((n, 6))
    out_C = np.empty((n, 3, 3))
    out_bias = np.empty((n, bias0.size))
    innov = np.full((m, 6), np.nan)
    innov_pvar = np.full((m, 6), np.nan)
    innov_ldet = np.full((m, 2), np.nan)
    nis = np.full((m, 2), np.nan)
    acc_flag = np.zeros((m, 2), dtype=np.bool_)
    gate = chi2_threshold(cfg.gate_probability, 6)
    n_used, status = insgps_kernel(
        t, gyro, acc, nav0, np.ascontiguousarray(init.C_nb, dtype=float), bias0, P0,
        np.asarray(cfg.q, dtype=float), float(cfg.tau_acc_s), float(cfg.tau_gyro_s), earth_sign,
        int(max(cfg.cov_step, 1)), idx_s.astype(np.int64), lag, np.ascontiguousarray(pos),
        np.ascontiguousarray(vel_o), np.ascontiguousarray(var), np.asarray(cfg.lever_arm_b_m, dtype=float),
        gate, int(cfg.max_consecutive_rejections), float(cfg.ungated_after_gap_s),
        float(cfg.gps_gm_tau_s), 2.0 * gm_sd**2 / max(float(cfg.gps_gm_tau_s), 1e-300), out_nav, out_C, out_bias, ep_idx, ep_Phi, ep_Ppred, ep_P, ep_dx, bool(store_rts),
        innov, innov_pvar, nis, acc_flag, innov_ldet,
    )
    if status != 0:
        k = status - 1
        tk = -t[k] if backward else t[k]
        raise ProcessingError(f"INS/GPS filter: innovation covariance not positive definite at t_s = {tk:.3f}")
    # back to the caller's fix order
    innovation = np.full((len(t_fix), 6), np.nan)
    nis_all = np.full((len(t_fix), 2), np.nan)
    acc_all = np.zeros((len(t_fix), 2), dtype=bool)
    innovation[order] = innov
    pvar = np.full((len(t_fix), 6), np.nan)
    pvar[order] = innov_pvar
    nis_all[order] = nis
    ldet = np.full((len(t_fix), 2), np.nan)
    ldet[order] = innov_ldet
    acc_all[order] = acc_flag
    ep_idx = ep_idx[:n_used]
    ep_P = ep_P[:n_used]
    ep_dx = ep_dx[:n_used]
    if backward:
        out_nav = out_nav[::-1]
        out_nav[:, 3:] *= -1.0
        out_C = out_C[::-1]
        out_bias = out_bias[::-1]
        out_bias[:, 3:6] *= -1.0
        ep_idx = (n - 1 - ep_idx)[::-1]
        ep_P = ep_P[::-1]
        ep_P *= np.outer(sign15, sign15)  # in place: this array is the run's largest
        innovation[:, 3:] *= -1.0
        return FilterRun(True, out_nav, out_C, out_bias, ep_idx, ep_P, None, None, None, innovation, nis_all, acc_all,
                         pvar, ldet)
    if store_rts:
        return FilterRun(False, out_nav, out_C, out_bias, ep_idx, ep_P, ep_Phi[:n_used], ep_Ppred[:n_used],
                         ep_dx, innovation, nis_all, acc_all, pvar, ldet)
    return FilterRun(False, out_nav, out_C, out_bias, ep_idx, ep_P, None, None, ep_dx, innovation, nis_all, acc_all, pvar, ldet)
