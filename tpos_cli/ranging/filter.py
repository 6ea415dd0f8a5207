"""INS/anchor-range filters: loosely coupled (paper 002 Eq. 1-12), tightly coupled (Eq. 17-24) and
the fuzzy adaptive tightly coupled one (FATCI, Eq. 31 / Algorithm 1) differ only in their events:

- `lc`: one least-squares (north, east) fix per epoch with enough anchors (`fix_events`);
- `tc`: every corrected range is a scalar measurement with a constant R (`range_events`);
- `fatci`: the same, with R = S^b R_ref from the fuzzy system (`fuzzy_range_variance`).

All three also take the floor constraint (`down_events`): the node's down coordinate in the local
frame is known to `floor_sd_m` (a vehicle in a corridor), since ranges from anchors near one plane
do not observe the vertical; and zero-velocity updates while the IMU says the node stands still
(`zupt_events`, beyond the paper). The compiled loop is `_kernels.ranging_filter_kernel`;
`run_filter` runs it forward or backward in time and returns a `FilterRun` that the smoothers of
`tpos_cli.smoothing` accept (same fields as `fusion.insgps.FilterRun`, 16 states).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tpos_cli.alignment import static_mask
from tpos_cli.errors import ProcessingError
from tpos_cli.filters.gating import chi2_threshold
from tpos_cli.frames import geodetic
from tpos_cli.frames.rotation import dcm_to_euler, euler_to_dcm
from tpos_cli.fusion.layout import ATT, POS, VEL
from tpos_cli.fusion.nav_errors import backward_sign
from tpos_cli.ins.mechanization import reverse_imu
from tpos_cli.ranging import _kernels as K
from tpos_cli.ranging.fuzzy import FuzzySystem, infer
from tpos_cli.ranging.multilateration import epoch_bounds, group_epochs, ls_fix

EV_RANGE, EV_FIX_NE, EV_DOWN, EV_ZUPT = K.EV_RANGE, K.EV_FIX_NE, K.EV_DOWN, K.EV_ZUPT
N_STATE, BIAS, FLOOR, CAL, n_states = K.N_STATE, K.BIAS, K.FLOOR, K.CAL, K.n_states


@dataclass(frozen=True)
class Events:
    """Aiding events, time sorted: t_s (E,), kind (E,), anchor (E,) (-1 if none), z (E, 3),
    R (E, 3) = [var_0, cov_01, var_1] (ZUPT: var_0 per axis), gated (E,) bool.
    sens (E, 2, 1 + A) or None: for a fix, d(fix north, east) / d[floor-height error, calibrated-range
    bias of each anchor] (`fix_events`); zeros for the other kinds."""

    t_s: np.ndarray
    kind: np.ndarray
    anchor: np.ndarray
    z: np.ndarray
    R: np.ndarray
    gated: np.ndarray
    sens: np.ndarray | None = None

    @staticmethod
    def merge(*parts: Events) -> Events:
        t = np.concatenate([p.t_s for p in parts])
        order = np.argsort(t, kind="stable")
        cols = [np.concatenate([getattr(p, f) for p in parts])[order]
                for f in ("t_s", "kind", "anchor", "z", "R", "gated")]
        with_sens = [p.sens for p in parts if p.sens is not None]
        sens = None
        if with_sens:
            shape = with_sens[0].shape[1:]
            sens = np.concatenate([p.sens if p.sens is not None else np.zeros((p.t_s.size, *shape))
                                   for p in parts])[order]
        return Events(*cols, sens)

    def select(self, mask: np.ndarray) -> Events:
        """The events where mask is True."""
        return Events(self.t_s[mask], self.kind[mask], self.anchor[mask], self.z[mask], self.R[mask],
                      self.gated[mask], None if self.sens is None else self.sens[mask])


@dataclass(frozen=True)
class FilterConfig:
    """Filter tuning in SI units. q = [acc white PSD (m/s^2)^2 s, gyro white PSD rad^2/s,
    acc bias drive PSD, gyro bias drive PSD]; sd0 = initial SDs of the 16 states (navigation and
    eps_d); output_every: IMU samples per output row; cov_step: IMU samples per covariance epoch
    between events. Random constants beyond the paper (0 = not estimated, as without them):
    floor_sd_m = SD of the error of the floor height given to `down_events` (common to all of
    them); cal_cov_m2 (A, A) = covariance of the anchors' calibrated-range biases
    (`RangeModel.bias_cov_m2`)."""

    q: np.ndarray
    tau_acc_s: float
    tau_gyro_s: float
    q_range_bias_m2ps: float
    sd0: np.ndarray
    gate_probability: float
    max_consecutive_rejects: int
    output_every: int
    cov_step: int = 10
    floor_sd_m: float = 0.0
    cal_cov_m2: np.ndarray | None = None


@dataclass(frozen=True)
class InitialState:
    """Start of the filter: IMU sample index k0 and the state there (lla deg/deg/m, NED velocity,
    roll/pitch/yaw rad, IMU biases [acc m/s^2 (3), gyro rad/s (3)], range bias m). For a backward
    run, the state at the last sample in forward-time signs."""

    k0: int
    lla: np.ndarray
    vel_ned_mps: np.ndarray
    rpy_rad: np.ndarray
    bias: np.ndarray = field(default_factory=lambda: np.zeros(6))
    range_bias_m: float = 0.0


@dataclass(frozen=True)
class FilterRun:
    """One run in forward time order over the IMU samples k0..N-1 (run-local index j = k - k0).

    Output rows (every `output_every` samples and the last): out_idx (K,) run-local indices, t_s,
    lla, vel_ned_mps, rpy_deg, sd_ned_m, sd_vel_mps, sd_att_deg (SD of the attitude error phi),
    range_bias_m, cov_ne_m2 (north-east position covariance). Per event (in the order of `events`): ev_nis (-1 if not reached), ev_accepted.
    floor_correction_m, cal_correction_m (A,): estimated floor-height and per-anchor calibrated-range
    corrections after the last event of the run (0 when their states are off).
    For `tpos_cli.smoothing` (field names of `fusion.insgps.FilterRun`): t_run_s (N-k0,), nav
    (N-k0, 6), C_nb, bias (N-k0, 6) nominal after feedback; ep_idx (E,) run-local; ep_P (E,16,16)
    in forward-time signs; forward runs also ep_Phi, ep_Ppred, ep_dx (RTS history).
    """

    t_s: np.ndarray
    lla: np.ndarray
    vel_ned_mps: np.ndarray
    rpy_deg: np.ndarray
    sd_ned_m: np.ndarray
    sd_vel_mps: np.ndarray
    sd_att_deg: np.ndarray
    range_bias_m: np.ndarray
    events: Events
    ev_nis: np.ndarray
    ev_accepted: np.ndarray
    backward: bool = False
    floor_correction_m: float = 0.0
    cal_correction_m: np.ndarray | None = None
    cov_ne_m2: np.ndarray | None = None
    k0: int = 0
    out_idx: np.ndarray | None = None
    t_run_s: np.ndarray | None = None
    nav: np.ndarray | None = None
    C_nb: np.ndarray | None = None
    bias: np.ndarray | None = None
    range_bias_all_m: np.ndarray | None = None
    ep_idx: np.ndarray | None = None
    ep_P: np.ndarray | None = None
    ep_Phi: np.ndarray | None = None
    ep_Ppred: np.ndarray | None = None
    ep_dx: np.ndarray | None = None


def range_events(t_s, anchor, range_m, var_m2) -> Events:
    """One scalar range event per measured (corrected) range (Eq. 21-24)."""
    n = t_s.size
    z = np.zeros((n, 3))
    z[:, 0] = range_m
    R = np.zeros((n, 3))
    R[:, 0] = var_m2
    return Events(np.asarray(t_s, float), np.full(n, EV_RANGE, np.int64), np.asarray(anchor, np.int64),
                  z, R, np.ones(n, bool))


def fuzzy_range_variance(fis: FuzzySystem, sd_fit_m, sd_ref_m: float, b: float):
    """R = S^b sd_ref^2 with S the fuzzy output for the input sd_fit / sd_ref (Eq. 31).

    The input is the fitted, distance-dependent range SD (paper Fig. 6) relative to the pooled
    SD, so that the breakpoints in the pipeline file do not depend on one sensor's noise level.
    Returns (R (K,), S (K,)).
    """
    s = infer(fis, np.asarray(sd_fit_m, float) / sd_ref_m)
    return s**b * sd_ref_m**2, s


def fix_events(t_s, anchor, range_m, sd_m, anchors_ned, down_m: float, min_anchors: int,
               window_s: float, gate_probability: float = 0.999) -> tuple[Events, int]:
    """Least-squares (north, east) fixes of the epochs with >= min_anchors ranges (Eq. 7-8).

    Returns the events and the number of epochs without a fix. Beyond the paper, each fix carries
    its sensitivity `sens` to the floor-height error (the fix holds down at `down_m`) and to the
    calibrated-range bias of each anchor, K = (H^T W H)^-1 H^T W of the final LS step: these
    errors are constant over a run, so the filter carries them as states (`FLOOR`, `CAL`) instead
    of white noise on each fix, which averaging over fixes would shrink.
    """
    ep = group_epochs(t_s, window_s)
    n_anchor = anchors_ned.shape[0]
    ts, zs, Rs, Ss = [], [], [], []
    n_missing = 0
    guess = np.array([*np.mean(anchors_ned[:, :2], axis=0), down_m])
    bounds = epoch_bounds(ep)
    for a, b in zip(bounds[:-1], bounds[1:]):
        # one range per anchor per epoch: keep the last if an anchor answered twice
        _, last = np.unique(anchor[a:b][::-1], return_index=True)
        idx = np.arange(a, b)[::-1][last]
        if idx.size < min_anchors:
            n_missing += 1
            continue
        fix = ls_fix(anchors_ned[anchor[idx]], range_m[idx], sd_m[idx], guess)
        # Beyond the paper: with a redundant range, drop the worst one while the weighted
        # residuals fail a chi-square test (an NLOS spike bends the whole fix).
        while fix.ok and idx.size > min_anchors:
            res = (range_m[idx] - np.linalg.norm(anchors_ned[anchor[idx]] - fix.pos_ned_m, axis=1)) / sd_m[idx]
            if res @ res <= chi2_threshold(gate_probability, idx.size - 2)[idx.size - 2]:
                break
            idx = np.delete(idx, np.argmax(np.abs(res)))
            fix = ls_fix(anchors_ned[anchor[idx]], range_m[idx], sd_m[idx], guess)
        if not fix.ok:
            n_missing += 1
            continue
        guess = fix.pos_ned_m
        ts.append(t_s[idx].max())
        zs.append(fix.pos_ned_m[:2])
        Rs.append([fix.cov_ne_m2[0, 0], fix.cov_ne_m2[0, 1], fix.cov_ne_m2[1, 1]])
        Ss.append(_fix_sensitivity(fix, anchors_ned, anchor[idx], sd_m[idx], n_anchor))
    n = len(ts)
    return Events(np.array(ts, float), np.full(n, EV_FIX_NE, np.int64), np.full(n, -1, np.int64),
                  np.column_stack([np.array(zs, float).reshape(n, 2), np.zeros(n)]), np.array(Rs, float).reshape(n, 3),
                  np.ones(n, bool), np.array(Ss, float).reshape(n, 2, 1 + n_anchor)), n_missing


def _fix_sensitivity(fix, anchors_ned, anchor, sd_m, n_anchor: int) -> np.ndarray:
    """(2, 1 + A): fix error = K (bias - h_d floor_error) + K noise with K = cov H^T W (Eq. 8 gain),
    h_d the down components of the unit vectors: columns [K h_d, K per anchor] as the filter's
    measurement rows for the FLOOR and CAL states (sign: z = INS - fix)."""
    d = fix.pos_ned_m[None, :] - anchors_ned[anchor]
    u = d / np.linalg.norm(d, axis=1)[:, None]
    K = fix.cov_ne_m2 @ (u[:, :2].T / np.asarray(sd_m, float) ** 2)
    out = np.zeros((2, 1 + n_anchor))
    out[:, 0] = K @ u[:, 2]
    np.add.at(out.T, 1 + anchor, K.T)
    return out


def zupt_events(t_s, sd_mps: float) -> Events:
    """Zero-velocity updates at the times t_s (the node stands still), v = 0 +- sd_mps per axis."""
    n = np.size(t_s)
    R = np.zeros((n, 3))
    R[:, 0] = sd_mps**2
    return Events(np.asarray(t_s, float), np.full(n, EV_ZUPT, np.int64), np.full(n, -1, np.int64),
                  np.zeros((n, 3)), R, np.zeros(n, bool))


def static_times(t_s, gyro_b_rps, acc_b_mps2, rate_hz: float, **static_kw) -> np.ndarray:
    """Times (at most rate_hz) inside stretches where `alignment.static_mask` says the IMU is still."""
    still = static_mask(t_s, gyro_b_rps, acc_b_mps2, **static_kw)
    dt = float(np.median(np.diff(t_s))) if np.size(t_s) > 1 else 0.01
    step = max(1, int(round(1.0 / (rate_hz * dt))))
    idx = np.flatnonzero(still)
    return np.asarray(t_s, float)[idx[idx % step == 0]]


def down_events(t_s, down_m: float, sd_m: float) -> Events:
    """Floor constraint: down coordinate of the node = down_m +- sd_m, never gated."""
    n = t_s.size
    z = np.zeros((n, 3))
    z[:, 0] = down_m
    R = np.zeros((n, 3))
    R[:, 0] = sd_m**2
    return Events(np.asarray(t_s, float), np.full(n, EV_DOWN, np.int64), np.full(n, -1, np.int64),
                  z, R, np.zeros(n, bool))


def run_filter(t_s, gyro_b_rps, acc_b_mps2, init: InitialState, events: Events, anchors_ned_m,
               origin_lla, cfg: FilterConfig, *, backward: bool = False, store_rts: bool = False) -> FilterRun:
    """Run the INS/range filter over the IMU samples init.k0..N-1 with the given events.

    Forward: `init` is the state at sample k0. Backward (`backward=True`, paper 003's reversed
    time): `init` is the state at the LAST sample in forward-time signs; the run goes from the
    end back to k0 and is returned in forward order, its covariances in forward-time signs.
    `store_rts` keeps the RTS history of a forward run.
    """
    k0 = int(init.k0)
    t = np.ascontiguousarray(t_s[k0:], dtype=float)
    gyro = np.ascontiguousarray(gyro_b_rps[k0:], dtype=float)
    acc = np.ascontiguousarray(acc_b_mps2[k0:], dtype=float)
    n = t.size
    if n < 2:
        raise ProcessingError("ranging filter: fewer than two IMU samples after the first position fix")
    n_anchor = int(np.shape(anchors_ned_m)[0])
    ns = n_states(n_anchor)
    sign = np.ones(ns)
    sign[:15] = backward_sign()
    nav0 = np.array([np.radians(init.lla[0]), np.radians(init.lla[1]), init.lla[2], *init.vel_ned_mps])
    C0 = euler_to_dcm(*init.rpy_rad)
    bias0 = np.array(init.bias, dtype=float)
    P0 = np.zeros((ns, ns))
    P0[:N_STATE, :N_STATE] = np.diag(np.asarray(cfg.sd0, float) ** 2)
    P0[FLOOR, FLOOR] = cfg.floor_sd_m**2
    if cfg.cal_cov_m2 is not None:
        P0[CAL:, CAL:] = cfg.cal_cov_m2
    t_ev = np.asarray(events.t_s, dtype=float)
    if backward:
        t, gyro, acc = reverse_imu(t, gyro, acc)
        nav0[3:] *= -1.0
        bias0[3:] *= -1.0
        t_ev = -t_ev
        earth_sign = -1.0
    else:
        earth_sign = 1.0
    ev_k = np.searchsorted(t, t_ev, side="left").astype(np.int64)
    inside = (ev_k < n) & (ev_k >= 1)
    ev_k = np.where(inside, ev_k, -1)  # never processed
    ev_lag = np.where(inside, t[np.clip(ev_k, 0, n - 1)] - t_ev, 0.0)
    order = np.argsort(ev_k, kind="stable")  # kernel walks events by sample index
    n_ev = t_ev.size
    n_ep = n // max(cfg.cov_step, 1) + np.unique(ev_k[inside]).size + 3
    nr = n_ep if store_rts else 1
    out_nav = np.empty((n, 6))
    out_C = np.empty((n, 3, 3))
    out_bias = np.empty((n, 6))
    out_rb = np.empty(n)
    out_aux = np.empty((n, 1 + n_anchor))
    ep_idx = np.zeros(n_ep, np.int64)
    ep_P = np.empty((n_ep, ns, ns))
    ep_dx = np.empty((n_ep, ns))
    ep_Phi = np.empty((nr, ns, ns))
    ep_Ppred = np.empty((nr, ns, ns))
    nis_o = np.full(n_ev, -1.0)
    acc_o = np.zeros(n_ev, np.bool_)
    r0_e = geodetic.lla_to_ecef(origin_lla)
    C_ne0 = geodetic.ecef_to_ned_dcm(origin_lla[0], origin_lla[1])
    gate = chi2_threshold(cfg.gate_probability, 2)
    z = np.zeros((n_ev, 3))
    z[:, : events.z.shape[1]] = events.z
    ev_sidx = np.full(n_ev, -1, np.int64)
    sens = np.zeros((1, 2, 1 + n_anchor))
    if events.sens is not None:  # only the fixes' rows are passed
        fx = np.flatnonzero(events.kind == EV_FIX_NE)
        ev_sidx[fx] = np.arange(fx.size)
        sens = np.ascontiguousarray(events.sens[fx], dtype=float) if fx.size else sens
    n_used, status = K.ranging_filter_kernel(
        t, gyro, acc, nav0, C0, bias0, float(init.range_bias_m), P0, np.asarray(cfg.q, float), cfg.tau_acc_s,
        cfg.tau_gyro_s, cfg.q_range_bias_m2ps, earth_sign, int(max(cfg.cov_step, 1)),
        ev_k[order], ev_lag[order], events.kind[order], events.anchor[order], np.ascontiguousarray(z[order]),
        np.ascontiguousarray(events.R[order]), events.gated[order], ev_sidx[order], sens,
        np.ascontiguousarray(anchors_ned_m, dtype=float),
        r0_e, C_ne0, gate, cfg.max_consecutive_rejects, bool(store_rts),
        out_nav, out_C, out_bias, out_rb, out_aux, ep_idx, ep_Phi, ep_Ppred, ep_P, ep_dx, nis_o, acc_o,
    )
    if status != 0:
        tk = t[status - 1] * (-1.0 if backward else 1.0)
        raise ProcessingError(f"ranging filter: innovation covariance not positive definite at t_s = {tk:.3f}")
    ev_nis = np.full(n_ev, -1.0)
    ev_acc = np.zeros(n_ev, bool)
    ev_nis[order] = nis_o
    ev_acc[order] = acc_o
    ep_idx, ep_P, ep_dx = ep_idx[:n_used], ep_P[:n_used], ep_dx[:n_used]
    if backward:
        out_nav = out_nav[::-1].copy()
        out_nav[:, 3:] *= -1.0
        out_C = out_C[::-1].copy()
        out_bias = out_bias[::-1].copy()
        out_bias[:, 3:] *= -1.0
        out_rb = out_rb[::-1].copy()
        ep_idx = (n - 1 - ep_idx)[::-1].copy()
        ep_P = ep_P[::-1] * np.outer(sign, sign)
        ep_dx = None
        t = -t[::-1]
    if not np.all(np.isfinite(out_nav)):
        bad = int(np.argmax(~np.all(np.isfinite(out_nav), axis=1)))
        raise ProcessingError(f"ranging filter diverged at t_s = {t[bad]:.3f} (session epoch removed)")
    out_idx = np.arange(0, n, max(1, cfg.output_every))
    if out_idx[-1] != n - 1:
        out_idx = np.append(out_idx, n - 1)
    # covariance of the nearest epoch on the data side (as smoothing.filter_solution)
    if backward:
        e = np.minimum(np.searchsorted(ep_idx, out_idx, side="left"), ep_idx.size - 1)
    else:
        e = np.maximum(np.searchsorted(ep_idx, out_idx, side="right") - 1, 0)
    sd = np.sqrt(np.clip(np.diagonal(ep_P[e], axis1=1, axis2=2), 0.0, None))
    nav_o = out_nav[out_idx]
    rpy = np.degrees(np.column_stack(dcm_to_euler(out_C[out_idx])))
    lla = np.column_stack([np.degrees(nav_o[:, 0]), np.degrees(nav_o[:, 1]), nav_o[:, 2]])
    rts = store_rts and not backward
    return FilterRun(
        t_s=t[out_idx], lla=lla, vel_ned_mps=nav_o[:, 3:6].copy(), rpy_deg=rpy,
        sd_ned_m=sd[:, POS:POS + 3], sd_vel_mps=sd[:, VEL:VEL + 3], sd_att_deg=np.degrees(sd[:, ATT:ATT + 3]),
        range_bias_m=out_rb[out_idx], events=events, ev_nis=ev_nis, ev_accepted=ev_acc,
        floor_correction_m=float(out_aux[-1, 0]), cov_ne_m2=ep_P[e, POS, POS + 1].copy(),
        cal_correction_m=out_aux[-1, 1:].copy(),
        backward=backward, k0=k0, out_idx=out_idx, t_run_s=t, nav=out_nav, C_nb=out_C, bias=out_bias,
        range_bias_all_m=out_rb, ep_idx=ep_idx, ep_P=ep_P, ep_Phi=ep_Phi[:n_used] if rts else None,
        ep_Ppred=ep_Ppred[:n_used] if rts else None, ep_dx=None if backward else ep_dx,
    )


def end_state(run: FilterRun) -> InitialState:
    """The run's state at its last sample (for starting a backward run), forward-time signs."""
    nav = run.nav[-1]
    return InitialState(run.k0, np.array([np.degrees(nav[0]), np.degrees(nav[1]), nav[2]]), nav[3:6].copy(),
                        np.array(dcm_to_euler(run.C_nb[-1]), dtype=float), run.bias[-1].copy(),
                        float(run.range_bias_all_m[-1]))


def coasting_intervals(run: FilterRun, gap_s: float, t_from_s: float = -np.inf) -> list[tuple[float, float]]:
    """Intervals (s) longer than gap_s without an accepted range or fix: the filter coasted on the INS.

    Counted from t_from_s (the end of a start window whose ranges are in the initial state).
    """
    ev = run.events
    m = run.ev_accepted & ((ev.kind == EV_RANGE) | (ev.kind == EV_FIX_NE))
    ta = np.sort(ev.t_s[m])
    if run.t_s.size == 0:
        return []
    t_start = max(float(run.t_s[0]), t_from_s)
    edges = np.concatenate([[t_start], ta[ta > t_start], [run.t_s[-1]]])
    gaps = np.diff(edges)
    idx = np.flatnonzero(gaps > gap_s)
    return [(float(edges[i]), float(edges[i + 1])) for i in idx]
