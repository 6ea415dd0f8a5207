"""The `ranging_fatci` chain (paper 002): IMU + ranges to anchors -> `lc`, `tc`, `fatci` solutions.

Stages: range error model (Eq. 13-16) from `range_calibration`; floor height, stationary intervals
(IMU confirmed by the fixes) and initial state from least-squares fixes; forward INS/range filters
(`tpos_cli.ranging.filter` rows for the one filter of `fusion.engine`) with innovation gating,
zero-velocity updates and coasting report; then the `smoothed` solution: the `smooth_source`
filter (default `fatci`) smoothed with `tpos_cli.smoothing` (RTS on its forward run, or the
two-filter combination with a backward run, as the INS/GPS pipeline); the trajectory table
(`tpos_cli.trajectory`). The ranging node is assumed at the IMU (zero lever arm).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import pandas as pd

from tpos_cli import smoothing
from tpos_cli.alignment import level_rad
from tpos_cli.chains.context import ChainOutput, RunContext
from tpos_cli.config import RangingParams
from tpos_cli.errors import InvalidInputError
from tpos_cli.frames import geodetic
from tpos_cli.frames.earth import G0_MPS2
from tpos_cli.frames.rotation import euler_to_dcm
from tpos_cli.fusion.engine import FilterConfig, FilterRun, InitialState, Measurements, backward_start, epoch_of
from tpos_cli.fusion.layout import Block
from tpos_cli.fusion.measurements import Kind
from tpos_cli.imu_noise import ImuNoiseFigures, resolve_imu_noise
from tpos_cli.ranging.calibration import RangeModel, fit_range_model, identity_model
from tpos_cli.ranging.filter import (
    anchor_of,
    coasting_intervals,
    down_events,
    fix_events,
    fuzzy_range_variance,
    initial_state,
    output_indices,
    range_events,
    ranging_layout,
    run_ranging,
    zupt_events,
)
from tpos_cli.ranging.fuzzy import fuzzy_system
from tpos_cli.ranging.multilateration import epoch_bounds, group_epochs, ls_fix
from tpos_cli.ranging.stillness import stationary_intervals
from tpos_cli.session import Session
from tpos_cli.timebase import true_runs
from tpos_cli.trajectory import Solution, solution_table


@dataclass(frozen=True)
class Ranges:
    """Corrected anchor ranges, time sorted: t_s, anchor, range_m (Eq. 14 inverted), sd_fit_m (the
    model's SD at that distance), and the range model."""

    t_s: np.ndarray
    anchor: np.ndarray
    range_m: np.ndarray
    sd_fit_m: np.ndarray
    model: RangeModel


@dataclass(frozen=True)
class Start:
    """Where the filters start: init, the settings, the LS fixes, the stationary intervals, the
    floor height, and the end of a static start window whose aiding is in the start already."""

    init: InitialState
    cfg: FilterConfig
    fixes: Measurements
    still: list
    floor_down_m: float
    t_used_s: float


def imu_figures(session: Session, p: RangingParams) -> ImuNoiseFigures:
    return resolve_imu_noise(p, session.meta.imu_noise)


def filter_config(nz: ImuNoiseFigures, p: RangingParams, imu_dt_s: float, cov_step: int, n_anchors: int) -> tuple[FilterConfig, np.ndarray]:
    """SI settings (white PSDs sigma^2 dt; biases that may wander by their own size over
    bias_drift_time_s) and the initial SDs (15,) of the navigation errors."""
    gb = np.radians(nz["gyro_bias_dph"] / 3600.0)
    ab = nz["acc_bias_mg"] * 1e-3 * G0_MPS2
    q = np.array([
        (nz["acc_noise_mg"] * 1e-3 * G0_MPS2) ** 2 * imu_dt_s,  # per-sample SD -> PSD: sigma^2 dt
        np.radians(nz["gyro_noise_dps"]) ** 2 * imu_dt_s,
        ab**2 / p.bias_drift_time_s,
        gb**2 / p.bias_drift_time_s,
    ])
    sd0 = np.concatenate([
        np.full(3, p.initial_position_sd_m), np.full(3, p.initial_velocity_sd_mps),
        np.radians([p.initial_level_sd_deg, p.initial_level_sd_deg, p.initial_yaw_sd_deg]),
        np.full(3, max(ab, 1e-6)), np.full(3, max(gb, 1e-9)),
    ])
    lay = ranging_layout(n_anchors, p.range_bias_sd_m, p.range_bias_rw_m_per_sqrt_s**2)
    return FilterConfig(q=q, tau_acc_s=0.0, tau_gyro_s=0.0, cov_step=cov_step, gate_probability=p.gate_probability,
                        max_consecutive_rejections=p.gate_max_consecutive, layout=lay), sd0


def corrected_ranges(session: Session, p: RangingParams, ctx: RunContext, results: dict) -> Ranges:
    """Stage `range_model`: fit Eq. 13-16 on the calibration table (or none) and correct the ranges."""
    anchors, ar = session.anchors, session.anchor_ranges
    A = len(anchors.ids)
    if session.range_calibration is not None:
        rc = session.range_calibration
        model = fit_range_model(rc.anchor, rc.true_m, rc.measured_m, A, scale=p.calibration_scale,
                                reject_sigma=p.calibration_reject_sigma, sd_poly_degree=p.sd_poly_degree)
    else:
        model = identity_model(A, p.range_sd_m)
        ctx.warn(f"ranging: no range_calibration table; ranges used uncorrected (f = 1, c = 0) with "
                 f"a constant SD of {p.range_sd_m} m")
    results["range_model"] = model.summary(anchors.ids)
    if model.fitted:
        # the range variances come from N calibration pairs: known to sqrt(2 / N) at best, which
        # the NIS band of a long log must allow for (`consistency.mean_chi2`); the LS fixes'
        # covariances are built from the same variances
        rel = float(np.sqrt(2.0 / max(int(np.sum(model.n_used)), 1)))
        results["noise_model_rel_sd"] = {"range": rel, "fix": rel}
    ok = np.isfinite(ar.range_m)
    order = np.argsort(ar.t_s[ok], kind="stable")
    t = ar.t_s[ok][order]
    a = ar.anchor[ok][order].astype(np.int64)
    r = model.correct(a, ar.range_m[ok][order])  # Eq. 14 inverted
    ctx.count("anchor_ranges_used", int(t.size))
    few = few_anchor_intervals(t, a, p.epoch_window_s, min_s=p.coast_gap_s)
    if few:
        # With one or two anchors the node is known only up to a mirror image about them: a
        # straight, steady leg cannot tell the two apart, and the filter may lock onto the wrong one.
        total = sum(b - a_ for a_, b in few)
        ctx.warn(f"ranging: {len(few)} stretch(es), {total:.1f} s in all, with fewer than 3 anchors answering: "
                 "there the position is ambiguous up to a mirror image about the anchors; check those stretches")
        results["few_anchor_intervals"] = [[a_ + session.t0_s, b + session.t0_s] for a_, b in few]
    return Ranges(t, a, r, model.range_sd_m(r), model)


def start(session: Session, p: RangingParams, rg: Ranges, ctx: RunContext, results: dict) -> Start:
    """Stage `initial_alignment`: floor height, LS fixes, stationary intervals, initial state and settings."""
    imu = session.imu
    anchors_ned = np.asarray(session.anchors.ned_m, dtype=float)
    origin = np.asarray(session.anchors.origin_lla, dtype=float)
    imu_dt = float(np.median(np.diff(imu.t_s)))
    cfg, sd0 = filter_config(imu_figures(session, p), p, imu_dt, max(1, int(round(p.cov_step_s / imu_dt))), len(session.anchors.ids))
    floor_d, floor_se = _floor_down(anchors_ned, rg.t_s, rg.anchor, rg.range_m, rg.sd_fit_m, p, ctx)
    fixes, n_nofix = fix_events(rg.t_s, rg.anchor, rg.range_m, rg.sd_fit_m, anchors_ned, floor_d, p.lc_min_anchors,
                                p.epoch_window_s, p.gate_probability)
    still = stationary_intervals(imu.t_s, imu.gyro_b_rps, imu.acc_b_mps2, rg.t_s, rg.anchor, rg.range_m,
                                 min_duration_s=p.zupt_min_duration_s, acc_step_mps2=p.zupt_acc_step_mps2,
                                 max_speed_mps=p.zupt_max_speed_mps)
    k0, vel0, rpy0 = _heading(session, fixes, still, p)
    # robust start: median of the fixes over the first second, or over the whole stationary
    # interval when the node starts at rest (the cross-corridor SD of one fix is ~0.4 m)
    rest = [b for a_, b in still if a_ <= fixes.t_s[0] + 0.5 and b > fixes.t_s[0]]
    zw = fixes.z[fixes.t_s <= (rest[0] if rest else fixes.t_s[0] + 1.0), :2]
    z0 = np.median(zw, axis=0)
    # At rest the start is the mean of the window's fixes (within 3 MAD-SDs of their median,
    # against NLOS fixes) with the SD of that mean, and the filters skip the window's
    # ranges and fixes: they are in the start already (processing them again double counted
    # them: static-start NEES ~4). Moving, the median is only a linearization point: it
    # carries one fix's SD and the ranges are processed.
    sd_fix = 1.4826 * np.median(np.abs(zw - z0), axis=0)
    sd_start = np.maximum(sd_fix, 0.02)
    if rest:  # mean of the fixes within 3 SD of the median: NLOS-robust, as efficient as a mean
        inl = np.all(np.abs(zw - z0) <= 3.0 * np.maximum(sd_fix, 1e-6), axis=1)
        z0 = zw[inl].mean(axis=0)
        sd_start = np.maximum(zw[inl].std(axis=0, ddof=1) / np.sqrt(inl.sum()), 0.02)
    t_used = rest[0] if rest else -np.inf
    sd0[:2] = np.minimum(sd_start, p.initial_position_sd_m)
    # beyond the paper: the floor height and the calibration are constant errors, estimated
    # as states rather than treated as white noise (their neglect raised the NEES)
    cfg = dataclasses.replace(cfg, layout=ranging_layout(len(session.anchors.ids), p.range_bias_sd_m,
                                                         p.range_bias_rw_m_per_sqrt_s**2, floor_se, rg.model.bias_cov_m2))
    lla0 = geodetic.ned_to_lla(np.array([z0[0], z0[1], floor_d]), origin)
    init = initial_state(k0, lla0, vel0, rpy0, sd0)
    results.update({
        "floor_down_m": floor_d, "floor_height_sd_m": floor_se,
        "start_window_end": float(t_used + session.t0_s) if rest else None,
        "initial_state": {"t": float(imu.t_s[k0] + session.t0_s), "lla": [float(v) for v in lla0],
                          "rpy_deg": [float(v) for v in np.degrees(rpy0)]},
        "lc_fixes": int(fixes.t_s.size), "lc_epochs_without_fix": int(n_nofix),
        "stationary_intervals": [[a_ + session.t0_s, b + session.t0_s] for a_, b in still]})
    return Start(init, cfg, fixes, still, floor_d, t_used)


def common_events(rg: Ranges, st: Start, p: RangingParams, ctx: RunContext) -> Measurements:
    """The rows every filter takes: the floor constraint at each range epoch, zero-velocity updates."""
    common = [down_events(np.unique(rg.t_s), st.floor_down_m, p.floor_sd_m)]
    if p.zupt and st.still:
        step = 1.0 / p.zupt_rate_hz
        tz = np.concatenate([np.arange(a_, b + 1e-9, step) for a_, b in st.still])
        common.append(zupt_events(tz, p.zupt_sd_mps))
        ctx.count("zero_velocity_updates", int(tz.size))
    return Measurements.merge(*common)


def solution_events(name: str, rg: Ranges, st: Start, p: RangingParams) -> tuple[Measurements, dict]:
    """The aiding of one solution: `lc` the LS fixes, `tc` the ranges with a constant R, `fatci`
    with the fuzzy R of Eq. 31; only those after a static start window."""
    extra: dict = {}
    if name == "lc":
        ev = st.fixes
    elif name == "tc":
        # constant R: the pooled calibration residual SD (the paper's baseline). It weighs the
        # calibration's distances (0.6-18.6 m), not the session's (to ~26 m): measured range NIS
        # 1.023 on clean 300 s sessions (seeds 0, 201, 202; band 0.964-1.013). One R for every
        # distance cannot match the distance law: the mean calibrated SD gave NIS 1.005 but more
        # pessimistic epochs at rest near the anchors (10-run NEES inside its band 0.79, pooled 0.80)
        sd_tc = rg.model.pooled_sd_m if p.tc_range_sd_m is None else p.tc_range_sd_m
        ev = range_events(rg.t_s, rg.anchor, rg.range_m, np.full(rg.t_s.size, sd_tc**2))
        extra["range_sd_m"] = float(sd_tc)
    else:
        R, S = fuzzy_range_variance(fuzzy_system(p.fuzzy), rg.sd_fit_m, rg.model.pooled_sd_m, p.fuzzy_exponent_b)
        ev = range_events(rg.t_s, rg.anchor, rg.range_m, R)
        extra["fuzzy_S"] = {"min": float(S.min()), "median": float(np.median(S)), "max": float(S.max())}
    return ev.select(ev.t_s > st.t_used_s), extra


def smoothed(session: Session, src: FilterRun, st: Start, p: RangingParams, out_idx, per_sol: dict) -> pd.DataFrame:
    """Stage `smoothing`: the smooth_source run RTS-smoothed, or combined with a backward run
    (from the forward end state with the initial SDs, as the INS/GPS chain)."""
    if p.smoother == "rts":
        sol = smoothing.rts(src, out_idx)
        per_sol["smoothed"] = {"source": p.smooth_source, "smoother": "rts"}
        rb = sol.bias[:, 6 + src.layout.offset(Block.RANGE_BIAS) - 15]
    else:
        anchors = session.anchors
        bwd = run_ranging(session.imu.t_s, session.imu.gyro_b_rps, session.imu.acc_b_mps2,
                          backward_start(src, st.init.P0), src.measurements, anchors.ned_m, anchors.origin_lla,
                          st.cfg, backward=True)
        sol, flag, _ = smoothing.two_filter(_nav15(src), _nav15(bwd), out_idx)
        per_sol["smoothed"] = {"source": p.smooth_source, "smoother": "two_filter",
                               "forward_backward_disagreements": int(flag.sum()),
                               "backward": _report(bwd, "backward", anchors.ids, session.t0_s, p, None, st.t_used_s)}
        rb = _combined_range_bias(src, bwd, out_idx)
    return _rows(sol.renamed("smoothed"), src, session.t0_s, rb)


def run(session: Session, p: RangingParams, ctx: RunContext) -> ChainOutput:
    if session.anchors is None or session.anchor_ranges is None:
        raise InvalidInputError(f"{session.path}: the ranging_fatci pipeline needs anchors.csv and anchor_ranges")
    imu, ids, results = session.imu, session.anchors.ids, {}
    with ctx.stage("range_model"):
        rg = corrected_ranges(session, p, ctx, results)
    with ctx.stage("initial_alignment"):
        st = start(session, p, rg, ctx, results)
    common = common_events(rg, st, p, ctx)
    out_idx = output_indices(imu.t_s.size - st.init.k0, max(1, int(round(1.0 / (p.output_rate_hz * float(np.median(np.diff(imu.t_s))))))))
    st = dataclasses.replace(st, cfg=dataclasses.replace(st.cfg, nominal_idx=out_idx))  # the runs' nominal at the output rows only
    rows, innov, per_sol, smooth_rows = {}, {}, {}, None
    source = p.smooth_source if p.smoothed else None
    # the smoothed solution's source runs first and is smoothed at once: its RTS history (the
    # largest arrays of the chain) is freed before the other filters run
    for name in sorted(p.solutions, key=lambda s: s != source):
        with ctx.stage(f"filter_{name}"):
            ev, extra = solution_events(name, rg, st, p)
            run_ = run_ranging(imu.t_s, imu.gyro_b_rps, imu.acc_b_mps2, st.init, Measurements.merge(ev, common),
                               session.anchors.ned_m, session.anchors.origin_lla, st.cfg,
                               store_rts=name == source and p.smoother == "rts")
            rb = run_.extra(Block.RANGE_BIAS, out_idx)[:, 0]
            rows[name] = _rows(smoothing.filter_solution(run_, out_idx, name), run_, session.t0_s, rb)
            per_sol[name] = _report(run_, name, ids, session.t0_s, p, ctx, st.t_used_s) | extra
            innov[name] = _innovations(run_, name, ids, session.t0_s)
        if name == source:
            with ctx.stage("smoothing"):
                smooth_rows = smoothed(session, run_, st, p, out_idx, per_sol)
        del run_  # a run holds every sample's nominal and every epoch's covariance
    trajs = [rows[n] for n in p.solutions] + ([smooth_rows] if smooth_rows is not None else [])
    per_sol = {n: per_sol[n] for n in (*p.solutions, "smoothed") if n in per_sol}
    results["solutions"] = per_sol
    return ChainOutput(trajectory=pd.concat(trajs, ignore_index=True),
                       tables={"innovations": pd.concat([innov[n] for n in p.solutions], ignore_index=True)},
                       summary=results)


def _rows(sol: Solution, run: FilterRun, t0_s: float, range_bias_m) -> pd.DataFrame:
    """Trajectory rows of a ranging solution: contract columns (vertical SD as `sigma_u`), the range
    bias eps_d and the north-east position covariance."""
    return solution_table(sol, run.t_s, t0_s, vertical_sigma="sigma_u",
                          extra={"range_bias_m": range_bias_m, "cov_ne_m2": sol.P9[:, 0, 1]})


def _combined_range_bias(src: FilterRun, bwd: FilterRun, out_idx) -> np.ndarray:
    """eps_d of the two-filter rows: the forward and backward estimates weighted by their inverse
    variances (the marginal Fraser-Potter combination; cross-covariances with the navigation
    states not used)."""
    o = src.layout.offset(Block.RANGE_BIAS)
    vf = src.ep_P[epoch_of(src, out_idx), o, o]
    vb = bwd.ep_P[epoch_of(bwd, out_idx), o, o]
    return (src.extra(Block.RANGE_BIAS, out_idx)[:, 0] * vb + bwd.extra(Block.RANGE_BIAS, out_idx)[:, 0] * vf) / (vf + vb)


def _nav15(run: FilterRun) -> FilterRun:
    """The run with its covariances reduced to the 15 navigation states (the two-filter smoother's layout)."""
    return dataclasses.replace(run, ep_P=run.ep_P.leading(15))


_FLOOR_UNKNOWN_SD_M = 1.0  # floor taken at the anchors' height: its error is metres, the ranges refine it


def _floor_down(anchors_ned, t, a, r, sd, p: RangingParams, ctx: RunContext) -> tuple[float, float]:
    """Down coordinate of the node and the SD of its (constant) error: given (SD floor_height_sd_m,
    default 0), or the median of 3-D fixes of epochs with >= 4 anchors (SD of that median)."""
    if p.floor_down_m is not None:
        return float(p.floor_down_m), float(p.floor_height_sd_m or 0.0)
    bounds = epoch_bounds(group_epochs(t, p.epoch_window_s))  # t sorted: an epoch's ranges are rows b[e]:b[e + 1]
    n_ep = bounds.size - 1
    downs, sds = [], []
    guess = np.array([*anchors_ned[:, :2].mean(axis=0), anchors_ned[:, 2].mean() + 2.0])  # start below the anchors
    for e in range(0, n_ep, max(1, n_ep // 200)):
        m = slice(bounds[e], bounds[e + 1])
        if np.unique(a[m]).size < 4:
            continue
        fix = ls_fix(anchors_ned[a[m]], r[m], sd[m], guess, solve_down=True)
        if fix.ok and fix.cov_ned_m2 is not None:
            downs.append(fix.pos_ned_m[2])
            sds.append(np.sqrt(fix.cov_ned_m2[2, 2]))
    if len(downs) < 5 or np.median(sds) > 1.0:
        d = float(anchors_ned[:, 2].mean())
        ctx.warn(f"ranging: the anchors do not observe the node height; floor taken at the anchors' mean "
                 f"down {d:.2f} m (set ranging_fatci.floor_down_m)")
        return d, float(p.floor_height_sd_m or _FLOOR_UNKNOWN_SD_M)
    downs = np.asarray(downs)
    med = float(np.median(downs))
    # SD of a median of n Gaussian values: 1.2533 SD / sqrt(n); the SD from the MAD (NLOS fixes)
    se = 1.2533 * 1.4826 * float(np.median(np.abs(downs - med))) / np.sqrt(downs.size)
    return med, float(p.floor_height_sd_m) if p.floor_height_sd_m is not None else se


def _heading(session: Session, fixes: Measurements, still, p: RangingParams) -> tuple[int, np.ndarray, np.ndarray]:
    """Position from the first fix; at rest (inside a stationary interval: v = 0, level over that
    interval) or moving (velocity from a line through 1 s of fixes, level over level_window_s);
    yaw from the track of the fixes once the node has moved align_distance_m. Returns (k0, NED
    velocity, roll/pitch/yaw rad)."""
    if fixes.t_s.size < 2:
        raise InvalidInputError("anchor_ranges: no epoch has enough anchors for a first position fix")
    t_imu = session.imu.t_s
    t_first = fixes.t_s[0]
    k0 = int(np.searchsorted(t_imu, t_first))
    if k0 >= t_imu.size - 1:
        raise InvalidInputError("anchor_ranges: the first position fix is after the end of the IMU log")
    # running median over ~1 s of fixes: the start and the track ignore single bad fixes
    z_med = _running_median(fixes.z[:, :2], half=5)
    rest = [(a, b) for a, b in still if a <= t_imu[k0] + 0.5 and b > t_imu[k0]]
    t_lvl = rest[0][1] if rest else t_imu[k0] + p.level_window_s
    lvl = (t_imu >= t_imu[k0]) & (t_imu <= t_lvl)
    roll, pitch = (float(v) for v in level_rad(session.imu.acc_b_mps2[lvl].mean(axis=0)))
    w = fixes.t_s <= t_first + 1.0
    vel_ne = np.zeros(2)
    if not rest and w.sum() >= 3:
        vel_ne = np.polyfit(fixes.t_s[w] - t_first, fixes.z[w, :2], 1)[0]
    # yaw: principal direction of the (median-filtered) fixes over a straight stretch, signed by
    # the displacement (the vehicle moves along its forward axis), carried back to k0 through the
    # gyros. The stretch runs from the start until the node has moved align_distance_m or has
    # turned by align_max_turn_deg (gyro heading), whichever comes first: the longer the
    # straight track, the smaller the yaw error from the cross-track fix noise.
    C_lvl = euler_to_dcm(roll, pitch, 0.0)
    w_down = (session.imu.gyro_b_rps[k0:] @ C_lvl.T)[:, 2]  # heading rate of a nearly level node
    psi = np.concatenate([[0.0], np.cumsum(w_down[1:] * np.diff(t_imu[k0:]))])  # gyro heading change since k0
    psi_fix = np.interp(fixes.t_s, t_imu[k0:], psi)
    dist = np.hypot(*(z_med - z_med[0]).T)
    turned = np.abs(psi_fix - psi_fix[0]) > np.radians(p.align_max_turn_deg)
    far = dist > p.align_distance_m
    yaw = 0.0
    stop = far | turned
    j = int(np.argmax(stop)) if stop.any() else fixes.t_s.size - 1
    if dist[: j + 1].max() > 0.5 * p.align_distance_m:  # enough track for a heading
        seg = z_med[: j + 1] - z_med[: j + 1].mean(axis=0)
        u = np.linalg.svd(seg, full_matrices=False)[2][0]
        d = z_med[j] - z_med[0]
        u = u if u @ d >= 0 else -u
        moving = dist[: j + 1] > 0.2 * p.align_distance_m  # where the track direction is the heading
        yaw = float(np.arctan2(u[1], u[0]) - np.mean(psi_fix[: j + 1][moving]))
    return k0, np.array([vel_ne[0], vel_ne[1], 0.0]), np.array([roll, pitch, yaw])


def _running_median(z: np.ndarray, half: int) -> np.ndarray:
    """Median of each column over rows i - half..i + half (fewer at the ends), (K, d) -> (K, d)."""
    K, w = z.shape[0], 2 * half + 1
    out = np.empty(z.shape)
    if K >= w:  # full windows: one vectorized median
        out[half: K - half] = np.median(np.lib.stride_tricks.sliding_window_view(z, w, axis=0), axis=-1)
    for i in [*range(min(half, K)), *range(max(K - half, min(half, K)), K)]:  # the partial windows at the ends
        out[i] = np.median(z[max(0, i - half): i + half + 1], axis=0)
    return out


def few_anchor_intervals(t_s: np.ndarray, anchor: np.ndarray, window_s: float, min_s: float) -> list[tuple[float, float]]:
    """Stretches of at least `min_s` whose range epochs (time-sorted `t_s`) each heard fewer than 3 anchors."""
    ep = group_epochs(t_s, window_s)
    t_ep = t_s[epoch_bounds(ep)[:-1]]
    pairs = np.unique(ep * (int(np.max(anchor, initial=0)) + 1) + anchor)  # distinct (epoch, anchor)
    n_ep = np.bincount(pairs // (int(np.max(anchor, initial=0)) + 1), minlength=t_ep.size)
    out = []
    for a_, b in zip(*true_runs(n_ep < 3)):
        t_start, t_end = t_ep[a_], t_ep[b] if b < t_ep.size else t_ep[-1]
        if t_end - t_start >= min_s:
            out.append((float(t_start), float(t_end)))
    return out


def _report(runf: FilterRun, name: str, ids, t0_s: float, p: RangingParams, ctx: RunContext | None,
            t_from_s: float = -np.inf) -> dict:
    """Summary of one filter run: aiding events, gating rejections, coasting; counts and warnings to ctx."""
    evs = runf.measurements
    aid = (evs.kind == Kind.RANGE) | (evs.kind == Kind.FIX_NE)
    rej = aid & ~runf.ev_accepted & np.isfinite(runf.ev_nis)
    if name == "lc":
        rejections = {"fix": int(rej.sum())}
    else:
        rejections = {ids[i]: int(np.sum(rej & (anchor_of(evs) == i))) for i in range(len(ids))}
    coast = coasting_intervals(runf, p.coast_gap_s, t_from_s)
    if ctx is not None:
        for k, v in rejections.items():
            ctx.count(f"{name}_gated_{k}", v)
        if coast:
            ctx.warn(f"ranging {name}: coasted on the INS alone for {len(coast)} interval(s), "
                     f"{sum(b - a_ for a_, b in coast):.1f} s in total")
    return {
        "aiding_events": int(aid.sum()), "accepted": int((aid & runf.ev_accepted).sum()),
        "gating_rejections": rejections,
        "coasting_intervals": [[a_ + t0_s, b + t0_s] for a_, b in coast],
        "final_range_bias_m": float(runf.extra(Block.RANGE_BIAS)[-1, 0]),
    }


def _innovations(runf: FilterRun, name: str, ids, t0_s: float) -> pd.DataFrame:
    evs = runf.measurements
    aid = (evs.kind == Kind.RANGE) | (evs.kind == Kind.FIX_NE)
    return pd.DataFrame({
        "t": evs.t_s[aid] + t0_s, "solution": name, "kind": np.where(evs.kind[aid] == Kind.RANGE, "range", "fix"),
        "anchor": np.array([*ids, ""], dtype=object)[anchor_of(evs)[aid]],  # index -1: "" (a fix)
        "nis": np.where(np.isfinite(runf.ev_nis[aid]), runf.ev_nis[aid], -1.0), "dof": evs.dim[aid],
        "accepted": runf.ev_accepted[aid],
    })
