"""INS/anchor-range filters: loosely coupled (paper 002 Eq. 1-12), tightly coupled (Eq. 17-24) and
the fuzzy adaptive tightly coupled one (FATCI, Eq. 31 / Algorithm 1) differ only in their events:

- `lc`: one least-squares (north, east) fix per epoch with enough anchors (`fix_events`);
- `tc`: every corrected range is a scalar measurement with a constant R (`range_events`);
- `fatci`: the same, with R = S^b R_ref from the fuzzy system (`fuzzy_range_variance`).

All three also take the floor constraint (`down_events`): the node's down coordinate in the local
frame is known to `floor_sd_m` (a vehicle in a corridor), since ranges from anchors near one plane
do not observe the vertical; and zero-velocity updates while the IMU says the node stands still
(`zupt_events`, beyond the paper). These are measurement rows (`fusion.engine.Measurements`,
kinds of `fusion.measurements.Kind`) of the one INS error-state filter (`fusion.engine.run_filter`),
whose state carries, after the 15 navigation errors, the range bias eps_d of Eq. 17-18 (a random
walk) and, beyond the paper, two random constants that the filter would otherwise treat as white
noise: the error of the floor height used by the floor constraint and, per anchor, the residual
bias of the calibrated range (the least-squares fit's error, Eq. 15-16); `ranging_layout`.
`run_ranging` returns the one `fusion.engine.FilterRun` that the smoothers of `tpos_cli.smoothing`
accept.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from tpos_cli.alignment import static_mask
from tpos_cli.errors import ProcessingError
from tpos_cli.filters.gating import chi2_threshold
from tpos_cli.frames.rotation import euler_to_dcm
from tpos_cli.fusion.engine import FilterConfig, FilterRun, InitialState, Measurements, run_filter
from tpos_cli.fusion.layout import StateLayout, ranging_blocks
from tpos_cli.fusion.measurements import Kind
from tpos_cli.ranging._kernels import fix_epochs
from tpos_cli.ranging.fuzzy import FuzzySystem, infer
from tpos_cli.ranging.multilateration import epoch_bounds, group_epochs

_LS_MAX_ITER, _LS_TOL_M, _LS_MAX_PDOP = 50, 1e-6, 10.0  # the defaults of `multilateration.ls_fix`


def ranging_layout(n_anchors: int, range_bias_sd_m: float, range_bias_q_m2ps: float, floor_sd_m: float = 0.0,
                   cal_cov_m2=None) -> StateLayout:
    """The extra states of the INS/range filter (`fusion.layout.ranging_blocks`); floor_sd_m and
    cal_cov_m2 (A, A) 0 / None: those constants are not estimated (zero prior variance)."""
    cal = np.zeros((n_anchors, n_anchors)) if cal_cov_m2 is None else np.asarray(cal_cov_m2, dtype=float)
    return StateLayout(ranging_blocks(range_bias_sd_m, range_bias_q_m2ps, floor_sd_m, cal))


def initial_state(k0: int, lla_deg, vel_ned_mps, rpy_rad, sd0) -> InitialState:
    """Filter start at IMU sample k0: position lla (deg, deg, m), NED velocity, roll/pitch/yaw (rad),
    zero IMU biases, prior SDs sd0 (15,) of the navigation errors."""
    lla = np.asarray(lla_deg, dtype=float)
    nav = np.array([np.radians(lla[0]), np.radians(lla[1]), lla[2], *np.asarray(vel_ned_mps, dtype=float)])
    return InitialState(nav, euler_to_dcm(*rpy_rad), np.zeros(6), np.diag(np.asarray(sd0, dtype=float)[:15] ** 2), int(k0))


def run_ranging(t_s, gyro_b_rps, acc_b_mps2, init: InitialState, events: Measurements, anchors_ned_m, origin_lla,
                cfg: FilterConfig, *, backward: bool = False, store_rts: bool = False) -> FilterRun:
    """Run the INS/range filter over the IMU samples init.k0..N-1 with the given events; ranges and
    fixes are in the local NED frame of `origin_lla` where the anchors `anchors_ned_m` (A, 3) are."""
    meas = dataclasses.replace(events, anchors_ned_m=np.asarray(anchors_ned_m, dtype=float), origin_lla=np.asarray(origin_lla, dtype=float))
    try:
        return run_filter(t_s, gyro_b_rps, acc_b_mps2, init, cfg, meas, backward=backward, store_rts=store_rts)
    except ProcessingError as exc:
        raise ProcessingError(f"ranging {exc}") from None


def output_indices(n: int, every: int) -> np.ndarray:
    """Run-local indices of the output rows: every `every` samples and the last."""
    out = np.arange(0, n, max(1, every))
    return out if out[-1] == n - 1 else np.append(out, n - 1)


def anchor_of(meas: Measurements) -> np.ndarray:
    """(E,) anchor index of each range row, -1 for the other kinds."""
    return np.where(meas.kind == Kind.RANGE, meas.par, -1)


def range_events(t_s, anchor, range_m, var_m2) -> Measurements:
    """One scalar range row per measured (corrected) range (Eq. 21-24), gated, one rejection
    counter per anchor."""
    a = np.asarray(anchor, dtype=np.int64)
    return Measurements.rows(t_s, Kind.RANGE, np.asarray(range_m, dtype=float), np.asarray(var_m2, dtype=float),
                             dim=1, gated=True, slot=a, par=a)


def fuzzy_range_variance(fis: FuzzySystem, sd_fit_m, sd_ref_m: float, b: float):
    """R = S^b sd_ref^2 with S the fuzzy output for the input sd_fit / sd_ref (Eq. 31).

    The input is the fitted, distance-dependent range SD (paper Fig. 6) relative to the pooled
    SD, so that the breakpoints in the pipeline file do not depend on one sensor's noise level.
    Returns (R (K,), S (K,)).
    """
    s = infer(fis, np.asarray(sd_fit_m, float) / sd_ref_m)
    return s**b * sd_ref_m**2, s


def fix_events(t_s, anchor, range_m, sd_m, anchors_ned, down_m: float, min_anchors: int,
               window_s: float, gate_probability: float = 0.999) -> tuple[Measurements, int]:
    """Least-squares (north, east) fixes of the epochs with >= min_anchors ranges (Eq. 7-8).

    Returns the events and the number of epochs without a fix. Beyond the paper, each fix carries
    its sensitivity `sens` to the floor-height error (the fix holds down at `down_m`) and to the
    calibrated-range bias of each anchor, K = (H^T W H)^-1 H^T W of the final LS step: these
    errors are constant over a run, so the filter carries them as states (`FLOOR`, `CAL`) instead
    of white noise on each fix, which averaging over fixes would shrink. Also beyond the paper: an
    epoch whose weighted range residuals fail a chi-square test at `gate_probability` loses the
    range whose omission fits best, down to three ranges; a fix that still fails is not used
    (NLOS ranges would bend it beyond its covariance). Compiled: `_kernels.fix_epochs`.
    """
    t = np.ascontiguousarray(t_s, dtype=float)
    a = np.ascontiguousarray(anchor, dtype=np.int64)
    anchors = np.ascontiguousarray(anchors_ned, dtype=float)
    n_anchor = anchors.shape[0]
    bounds = epoch_bounds(group_epochs(t, window_s))
    n_ep = bounds.size - 1
    o_t, o_z = np.empty(n_ep), np.empty((n_ep, 2))
    o_R, o_sens = np.empty((n_ep, 2, 2)), np.empty((n_ep, 2, 1 + n_anchor))
    guess = np.array([*np.mean(anchors[:, :2], axis=0), down_m])
    n = fix_epochs(t, a, np.ascontiguousarray(range_m, dtype=float), np.ascontiguousarray(sd_m, dtype=float), anchors,
                   bounds, guess, int(min_anchors), chi2_threshold(gate_probability, max(n_anchor, 1)),
                   _LS_MAX_ITER, _LS_TOL_M, _LS_MAX_PDOP, o_t, o_z, o_R, o_sens)
    # one rejection counter for all fixes (slot A, after the anchors'); par: the row of `sens`
    return Measurements.rows(o_t[:n], Kind.FIX_NE, o_z[:n], o_R[:n], dim=2, gated=True, slot=n_anchor,
                             par=np.arange(n), sens=o_sens[:n].copy()), n_ep - n


def zupt_events(t_s, sd_mps: float) -> Measurements:
    """Zero-velocity updates at the times t_s (the node stands still), v = 0 +- sd_mps per axis, never gated."""
    n = np.size(t_s)
    return Measurements.rows(t_s, Kind.ZUPT, np.zeros((n, 3)), np.broadcast_to(sd_mps**2 * np.eye(3), (n, 3, 3)),
                             dim=3, gated=False)


def static_times(t_s, gyro_b_rps, acc_b_mps2, rate_hz: float, **static_kw) -> np.ndarray:
    """Times (at most rate_hz) inside stretches where `alignment.static_mask` says the IMU is still."""
    still = static_mask(t_s, gyro_b_rps, acc_b_mps2, **static_kw)
    dt = float(np.median(np.diff(t_s))) if np.size(t_s) > 1 else 0.01
    step = max(1, int(round(1.0 / (rate_hz * dt))))
    idx = np.flatnonzero(still)
    return np.asarray(t_s, float)[idx[idx % step == 0]]


def down_events(t_s, down_m: float, sd_m: float) -> Measurements:
    """Floor constraint: down coordinate of the node = down_m +- sd_m, never gated."""
    n = np.size(t_s)
    return Measurements.rows(t_s, Kind.FLOOR, np.full(n, float(down_m)), np.full(n, sd_m**2), dim=1, gated=False)


def coasting_intervals(run: FilterRun, gap_s: float, t_from_s: float = -np.inf) -> list[tuple[float, float]]:
    """Intervals (s) longer than gap_s without an accepted range or fix: the filter coasted on the INS.

    Counted from t_from_s (the end of a start window whose ranges are in the initial state).
    """
    ev = run.measurements
    m = run.ev_accepted & ((ev.kind == Kind.RANGE) | (ev.kind == Kind.FIX_NE))
    ta = np.sort(ev.t_s[m])
    if run.t_s.size == 0:
        return []
    t_start = max(float(run.t_s[0]), t_from_s)
    edges = np.concatenate([[t_start], ta[ta > t_start], [run.t_s[-1]]])
    gaps = np.diff(edges)
    idx = np.flatnonzero(gaps > gap_s)
    return [(float(edges[i]), float(edges[i + 1])) for i in idx]
