"""INS/anchor-range filters: loosely coupled (paper 002 Eq. 1-12), tightly coupled (Eq. 17-24) and
the fuzzy adaptive tightly coupled one (FATCI, Eq. 31 / Algorithm 1) differ only in their events:

- `lc`: one least-squares (north, east) fix per epoch with enough anchors (`fix_events`);
- `tc`: every corrected range is a scalar measurement with a constant R (`range_events`);
- `fatci`: the same, with R = S^b R_ref from the fuzzy system (`fuzzy_range_variance`).

All three also take the floor constraint (`down_events`): the node's down coordinate in the local
frame is known to `floor_sd_m` (a vehicle in a corridor), since ranges from anchors near one plane
do not observe the vertical. The compiled loop is `_kernels.ranging_filter_kernel`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli.errors import ProcessingError
from tpos_cli.filters.gating import chi2_threshold
from tpos_cli.frames import geodetic
from tpos_cli.frames.rotation import dcm_to_euler, euler_to_dcm
from tpos_cli.fusion.layout import ATT, POS, VEL
from tpos_cli.ranging import _kernels as K
from tpos_cli.ranging.fuzzy import FuzzySystem, infer
from tpos_cli.ranging.multilateration import group_epochs, ls_fix

EV_RANGE, EV_FIX_NE, EV_DOWN = K.EV_RANGE, K.EV_FIX_NE, K.EV_DOWN


@dataclass(frozen=True)
class Events:
    """Aiding events, time sorted: t_s (E,), kind (E,), anchor (E,) (-1 if none), z (E, 2),
    R (E, 3) = [var_0, cov_01, var_1], gated (E,) bool."""

    t_s: np.ndarray
    kind: np.ndarray
    anchor: np.ndarray
    z: np.ndarray
    R: np.ndarray
    gated: np.ndarray

    @staticmethod
    def merge(*parts: Events) -> Events:
        t = np.concatenate([p.t_s for p in parts])
        order = np.argsort(t, kind="stable")
        return Events(*(np.concatenate([getattr(p, f) for p in parts])[order]
                        for f in ("t_s", "kind", "anchor", "z", "R", "gated")))


@dataclass(frozen=True)
class FilterConfig:
    """Filter tuning in SI units. q = [acc white PSD (m/s^2)^2 s, gyro white PSD rad^2/s,
    acc bias drive PSD, gyro bias drive PSD]; sd0 = initial SDs of the 16 states."""

    q: np.ndarray
    tau_acc_s: float
    tau_gyro_s: float
    q_range_bias_m2ps: float
    sd0: np.ndarray
    gate_probability: float
    max_consecutive_rejects: int
    output_every: int


@dataclass(frozen=True)
class InitialState:
    """Start of the filter: IMU sample index k0 and the state there."""

    k0: int
    lla: np.ndarray
    vel_ned_mps: np.ndarray
    rpy_rad: np.ndarray


@dataclass(frozen=True)
class FilterRun:
    """Filter output at the output samples and per event."""

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


def range_events(t_s, anchor, range_m, var_m2) -> Events:
    """One scalar range event per measured (corrected) range (Eq. 21-24)."""
    n = t_s.size
    z = np.zeros((n, 2))
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

    Returns the events and the number of epochs without a fix.
    """
    ep = group_epochs(t_s, window_s)
    ts, zs, Rs = [], [], []
    n_missing = 0
    guess = np.array([*np.mean(anchors_ned[:, :2], axis=0), down_m])
    for e in range(ep.max() + 1 if ep.size else 0):
        m = ep == e
        # one range per anchor per epoch: keep the last if an anchor answered twice
        _, last = np.unique(anchor[m][::-1], return_index=True)
        idx = np.flatnonzero(m)[::-1][last]
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
    n = len(ts)
    return Events(np.array(ts, float), np.full(n, EV_FIX_NE, np.int64), np.full(n, -1, np.int64),
                  np.array(zs, float).reshape(n, 2), np.array(Rs, float).reshape(n, 3), np.ones(n, bool)), n_missing


def down_events(t_s, down_m: float, sd_m: float) -> Events:
    """Floor constraint: down coordinate of the node = down_m +- sd_m, never gated."""
    n = t_s.size
    z = np.zeros((n, 2))
    z[:, 0] = down_m
    R = np.zeros((n, 3))
    R[:, 0] = sd_m**2
    return Events(np.asarray(t_s, float), np.full(n, EV_DOWN, np.int64), np.full(n, -1, np.int64),
                  z, R, np.zeros(n, bool))


def run_filter(t_s, gyro_b_rps, acc_b_mps2, init: InitialState, events: Events, anchors_ned_m,
               origin_lla, cfg: FilterConfig) -> FilterRun:
    """Run the forward INS/range filter from `init.k0` with the given events."""
    t = np.ascontiguousarray(t_s, dtype=float)
    gyro = np.ascontiguousarray(gyro_b_rps, dtype=float)
    acc = np.ascontiguousarray(acc_b_mps2, dtype=float)
    ev_k = np.searchsorted(t, events.t_s, side="left").astype(np.int64)
    inside = (ev_k < t.size) & (ev_k >= init.k0)
    ev_k_c = np.minimum(ev_k, t.size - 1)
    ev_lag = np.where(inside, t[ev_k_c] - events.t_s, 0.0)
    ev_k = np.where(inside, ev_k, -1)  # never processed
    order = np.argsort(ev_k, kind="stable")  # kernel walks events by sample index
    nav0 = np.array([np.radians(init.lla[0]), np.radians(init.lla[1]), init.lla[2], *init.vel_ned_mps])
    C0 = euler_to_dcm(*init.rpy_rad)
    P0 = np.diag(np.asarray(cfg.sd0, float) ** 2)
    r0_e = geodetic.lla_to_ecef(origin_lla)
    C_ne0 = geodetic.ecef_to_ned_dcm(origin_lla[0], origin_lla[1])
    gate = chi2_threshold(cfg.gate_probability, 2)
    n_out = (t.size - init.k0 - 1) // cfg.output_every + 1
    out_k = np.zeros(n_out, np.int64)
    out_nav = np.zeros((n_out, 6))
    out_C = np.zeros((n_out, 3, 3))
    out_P = np.zeros((n_out, K.N_STATE))
    out_bias = np.zeros(n_out)
    n_ev = events.t_s.size
    ev_nis = np.full(n_ev, -1.0)
    ev_acc = np.zeros(n_ev, np.bool_)
    nis_o = np.full(n_ev, -1.0)
    acc_o = np.zeros(n_ev, np.bool_)
    rows = K.ranging_filter_kernel(
        t, gyro, acc, init.k0, nav0, C0, P0, np.asarray(cfg.q, float), cfg.tau_acc_s, cfg.tau_gyro_s,
        cfg.q_range_bias_m2ps, ev_k[order], ev_lag[order], events.kind[order], events.anchor[order],
        np.ascontiguousarray(events.z[order]), np.ascontiguousarray(events.R[order]), events.gated[order],
        np.ascontiguousarray(anchors_ned_m, dtype=float), r0_e, C_ne0, gate, cfg.max_consecutive_rejects,
        cfg.output_every, out_k, out_nav, out_C, out_P, out_bias, nis_o, acc_o,
    )
    ev_nis[order] = nis_o
    ev_acc[order] = acc_o
    if not np.all(np.isfinite(out_nav[:rows])) or np.any(out_P[:rows] < 0):
        bad = int(np.argmax(~np.all(np.isfinite(out_nav[:rows]), axis=1) | np.any(out_P[:rows] < 0, axis=1)))
        raise ProcessingError(f"ranging filter diverged at t = {t[out_k[bad]]:.3f} s (session clock offset removed)")
    rpy = np.degrees(np.column_stack(dcm_to_euler(out_C[:rows])))
    sd = np.sqrt(out_P[:rows])
    lla = np.column_stack([np.degrees(out_nav[:rows, 0]), np.degrees(out_nav[:rows, 1]), out_nav[:rows, 2]])
    return FilterRun(
        t_s=t[out_k[:rows]], lla=lla, vel_ned_mps=out_nav[:rows, 3:6].copy(), rpy_deg=rpy,
        sd_ned_m=sd[:, POS:POS + 3], sd_vel_mps=sd[:, VEL:VEL + 3], sd_att_deg=np.degrees(sd[:, ATT:ATT + 3]),
        range_bias_m=out_bias[:rows], events=events, ev_nis=ev_nis, ev_accepted=ev_acc,
    )


def coasting_intervals(run: FilterRun, gap_s: float) -> list[tuple[float, float]]:
    """Intervals (s) longer than gap_s without an accepted range or fix: the filter coasted on the INS."""
    ev = run.events
    m = run.ev_accepted & (ev.kind != EV_DOWN)
    ta = np.sort(ev.t_s[m])
    if run.t_s.size == 0:
        return []
    edges = np.concatenate([[run.t_s[0]], ta, [run.t_s[-1]]])
    gaps = np.diff(edges)
    idx = np.flatnonzero(gaps > gap_s)
    return [(float(edges[i]), float(edges[i + 1])) for i in idx]
