"""The `ranging_fatci` chain (paper 002): IMU + ranges to anchors -> `lc`, `tc`, `fatci` solutions.

Stages: range error model (Eq. 13-16) from `range_calibration`; floor height, stationary intervals
(IMU confirmed by the fixes) and initial state from least-squares fixes; forward INS/range filters
(`tpos_cli.ranging.filter`) with innovation gating, zero-velocity updates and coasting report;
then the `smoothed` solution: the `smooth_source` filter (default `fatci`) smoothed with
`tpos_cli.smoothing` (RTS on its forward run, or the two-filter combination with a backward run,
as the INS/GPS pipeline). The ranging node is assumed at the IMU (zero lever arm).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd

from tpos_cli import smoothing
from tpos_cli.alignment import level_rad
from tpos_cli.chains.context import ChainOutput, RunContext
from tpos_cli.config import RangingParams
from tpos_cli.errors import InvalidInputError
from tpos_cli.frames import geodetic
from tpos_cli.frames.earth import G0_MPS2
from tpos_cli.frames.rotation import dcm_to_euler, euler_to_dcm
from tpos_cli.ranging.calibration import fit_range_model, identity_model
from tpos_cli.ranging.filter import (
    BIAS,
    EV_FIX_NE,
    EV_RANGE,
    Events,
    FilterConfig,
    FilterRun,
    InitialState,
    coasting_intervals,
    down_events,
    end_state,
    fix_events,
    fuzzy_range_variance,
    range_events,
    run_filter,
    zupt_events,
)
from tpos_cli.ranging.fuzzy import fuzzy_system
from tpos_cli.ranging.multilateration import epoch_bounds, group_epochs, ls_fix
from tpos_cli.ranging.stillness import stationary_intervals
from tpos_cli.session import Session


def _filter_config(session: Session, p: RangingParams, imu_dt_s: float, output_every: int, cov_step: int) -> FilterConfig:
    n = session.meta.imu_noise
    gyro_noise = n.gyro_noise_dps if n.gyro_noise_dps is not None else p.gyro_noise_dps
    acc_noise = n.acc_noise_mg if n.acc_noise_mg is not None else p.acc_noise_mg
    gyro_bias = n.gyro_bias_dph if n.gyro_bias_dph is not None else p.gyro_bias_dph
    acc_bias = n.acc_bias_mg if n.acc_bias_mg is not None else p.acc_bias_mg
    gb = np.radians(gyro_bias / 3600.0)
    ab = acc_bias * 1e-3 * G0_MPS2
    q = np.array([
        (acc_noise * 1e-3 * G0_MPS2) ** 2 * imu_dt_s,  # per-sample SD -> PSD: sigma^2 dt
        np.radians(gyro_noise) ** 2 * imu_dt_s,
        ab**2 / p.bias_drift_time_s,  # bias may wander by its own size over bias_drift_time_s
        gb**2 / p.bias_drift_time_s,
    ])
    sd0 = np.concatenate([
        np.full(3, p.initial_position_sd_m), np.full(3, p.initial_velocity_sd_mps),
        np.radians([p.initial_level_sd_deg, p.initial_level_sd_deg, p.initial_yaw_sd_deg]),
        np.full(3, max(ab, 1e-6)), np.full(3, max(gb, 1e-9)), [p.range_bias_sd_m],
    ])
    return FilterConfig(q=q, tau_acc_s=0.0, tau_gyro_s=0.0, q_range_bias_m2ps=p.range_bias_rw_m_per_sqrt_s**2,
                        sd0=sd0, gate_probability=p.gate_probability,
                        max_consecutive_rejects=p.gate_max_consecutive, output_every=output_every, cov_step=cov_step)


_FLOOR_UNKNOWN_SD_M = 1.0  # floor taken at the anchors' height: its error is metres, the ranges refine it


def _floor_down(anchors_ned, t, a, r, sd, p: RangingParams, ctx: RunContext) -> tuple[float, float]:
    """Down coordinate of the node and the SD of its (constant) error: given (SD floor_height_sd_m,
    default 0), or the median of 3-D fixes of epochs with >= 4 anchors (SD of that median)."""
    if p.floor_down_m is not None:
        return float(p.floor_down_m), float(p.floor_height_sd_m or 0.0)
    ep = group_epochs(t, p.epoch_window_s)
    downs, sds = [], []
    guess = np.array([*anchors_ned[:, :2].mean(axis=0), anchors_ned[:, 2].mean() + 2.0])  # start below the anchors
    for e in range(0, ep.max() + 1, max(1, (ep.max() + 1) // 200)):
        m = ep == e
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


def _initial_state(session: Session, fixes: Events, still, p: RangingParams) -> InitialState:
    """Position from the first fix; at rest (inside a stationary interval: v = 0, level over that
    interval) or moving (velocity from a line through 1 s of fixes, level over level_window_s);
    yaw from the track of the fixes once the node has moved align_distance_m."""
    if fixes.t_s.size < 2:
        raise InvalidInputError("anchor_ranges: no epoch has enough anchors for a first position fix")
    t_imu = session.imu.t_s
    t_first = fixes.t_s[0]
    k0 = int(np.searchsorted(t_imu, t_first))
    if k0 >= t_imu.size - 1:
        raise InvalidInputError("anchor_ranges: the first position fix is after the end of the IMU log")
    # running median over ~1 s of fixes: the start and the track ignore single bad fixes
    half = 5
    z_med = np.array([np.median(fixes.z[max(0, i - half):i + half + 1, :2], axis=0) for i in range(fixes.t_s.size)])
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
    return InitialState(k0=k0, lla=np.zeros(3), vel_ned_mps=np.array([vel_ne[0], vel_ne[1], 0.0]),
                        rpy_rad=np.array([roll, pitch, yaw]))


def _epoch_of(run: FilterRun, idx) -> np.ndarray:
    """Covariance epoch of each run-local sample index (the nearest on the data side, as `run_filter`)."""
    if run.backward:
        return np.minimum(np.searchsorted(run.ep_idx, idx, side="left"), run.ep_idx.size - 1)
    return np.maximum(np.searchsorted(run.ep_idx, idx, side="right") - 1, 0)


def _smoothed_range_bias(src: FilterRun, bwd: FilterRun | None) -> np.ndarray:
    """eps_d (Eq. 17-18) of the `smoothed` rows at src.out_idx.

    RTS: the smoothed error of the BIAS state (the same recursion as `smoothing.rts`, which keeps
    the navigation states only), interpolated between epochs as there. Two-filter: the forward
    and backward estimates weighted by their inverse variances (the marginal Fraser-Potter
    combination; the cross-covariances with the navigation states are not used).
    """
    j = src.out_idx
    if bwd is None:
        xs_post, xs_pre, _ = smoothing.rts_closed_loop(src.ep_Phi, src.ep_Ppred, src.ep_P, src.ep_dx)
        ep_t = src.t_run_s[src.ep_idx]
        e = _epoch_of(src, j)
        nxt = np.minimum(e + 1, src.ep_idx.size - 1)
        at = (src.ep_idx[e] == j) | (nxt == e)
        a = np.where(at, 0.0, (src.t_run_s[j] - ep_t[e]) / np.where(at, 1.0, ep_t[nxt] - ep_t[e]))
        xs = (1.0 - a) * xs_post[e, BIAS] + a * np.where(at, 0.0, xs_pre[nxt, BIAS])
        return src.range_bias_all_m[j] - xs  # error = estimate - truth
    vf = src.ep_P[_epoch_of(src, j), BIAS, BIAS]
    vb = bwd.ep_P[_epoch_of(bwd, j), BIAS, BIAS]
    return (src.range_bias_all_m[j] * vb + bwd.range_bias_all_m[j] * vf) / (vf + vb)


def _solution_frame(sol: smoothing.Solution, name: str, t_run_s, t0_s: float, range_bias_m) -> pd.DataFrame:
    """Trajectory rows of a smoothed `Solution` (attitude SDs: of the nav-frame error phi, as the filters)."""
    r, pt, y = dcm_to_euler(sol.C_nb)
    sd = np.sqrt(np.clip(np.diagonal(sol.P9, axis1=1, axis2=2), 0.0, None))
    return pd.DataFrame({
        "t": t_run_s[sol.idx] + t0_s, "lat": np.degrees(sol.nav[:, 0]), "lon": np.degrees(sol.nav[:, 1]),
        "h": sol.nav[:, 2], "vn": sol.nav[:, 3], "ve": sol.nav[:, 4], "vd": sol.nav[:, 5],
        "roll": np.degrees(r), "pitch": np.degrees(pt), "yaw": np.degrees(y), "solution": name,
        "sigma_n": sd[:, 0], "sigma_e": sd[:, 1], "sigma_u": sd[:, 2],
        "sigma_vn": sd[:, 3], "sigma_ve": sd[:, 4], "sigma_vd": sd[:, 5],
        "sigma_roll": np.degrees(sd[:, 6]), "sigma_pitch": np.degrees(sd[:, 7]), "sigma_yaw": np.degrees(sd[:, 8]),
        "range_bias_m": range_bias_m, "cov_ne_m2": sol.P9[:, 0, 1],
    })


def _trajectory(run: FilterRun, name: str, t0_s: float) -> pd.DataFrame:
    return pd.DataFrame({
        "t": run.t_s + t0_s, "lat": run.lla[:, 0], "lon": run.lla[:, 1], "h": run.lla[:, 2],
        "vn": run.vel_ned_mps[:, 0], "ve": run.vel_ned_mps[:, 1], "vd": run.vel_ned_mps[:, 2],
        "roll": run.rpy_deg[:, 0], "pitch": run.rpy_deg[:, 1], "yaw": run.rpy_deg[:, 2],
        "solution": name,
        "sigma_n": run.sd_ned_m[:, 0], "sigma_e": run.sd_ned_m[:, 1], "sigma_u": run.sd_ned_m[:, 2],
        "sigma_vn": run.sd_vel_mps[:, 0], "sigma_ve": run.sd_vel_mps[:, 1], "sigma_vd": run.sd_vel_mps[:, 2],
        "sigma_roll": run.sd_att_deg[:, 0], "sigma_pitch": run.sd_att_deg[:, 1], "sigma_yaw": run.sd_att_deg[:, 2],
        "range_bias_m": run.range_bias_m, "cov_ne_m2": run.cov_ne_m2,
    })


def run(session: Session, p: RangingParams, ctx: RunContext) -> ChainOutput:
    fis = fuzzy_system(p.fuzzy) if "fatci" in p.solutions else None
    if session.anchors is None or session.anchor_ranges is None:
        raise InvalidInputError(f"{session.path}: the ranging_fatci pipeline needs anchors.csv and anchor_ranges")
    anchors = session.anchors
    ar = session.anchor_ranges
    A = len(anchors.ids)
    anchors_ned = np.asarray(anchors.ned_m, dtype=float)
    origin = np.asarray(anchors.origin_lla, dtype=float)
    results: dict = {}

    with ctx.stage("range_model"):
        if session.range_calibration is not None:
            rc = session.range_calibration
            model = fit_range_model(rc.anchor, rc.true_m, rc.measured_m, A, scale=p.calibration_scale,
                                    reject_sigma=p.calibration_reject_sigma, sd_poly_degree=p.sd_poly_degree)
        else:
            model = identity_model(A, p.range_sd_m)
            ctx.warn(f"ranging: no range_calibration table; ranges used uncorrected (f = 1, c = 0) with "
                     f"a constant SD of {p.range_sd_m} m")
        results["range_model"] = model.summary(anchors.ids)
        ok = np.isfinite(ar.range_m)
        order = np.argsort(ar.t_s[ok], kind="stable")
        t = ar.t_s[ok][order]
        a = ar.anchor[ok][order].astype(np.int64)
        r = model.correct(a, ar.range_m[ok][order])  # Eq. 14 inverted
        sd_fit = model.range_sd_m(r)
        ctx.count("anchor_ranges_used", int(t.size))
        few = few_anchor_intervals(t, a, p.epoch_window_s, min_s=p.coast_gap_s)
        if few:
            # With one or two anchors the node is known only up to a mirror image about them: a
            # straight, steady leg cannot tell the two apart, and the filter may lock onto the wrong one.
            total = sum(b - a_ for a_, b in few)
            ctx.warn(f"ranging: {len(few)} stretch(es), {total:.1f} s in all, with fewer than 3 anchors answering: "
                     "there the position is ambiguous up to a mirror image about the anchors; check those stretches")
            results["few_anchor_intervals"] = [[a_ + session.t0_s, b + session.t0_s] for a_, b in few]

    imu = session.imu
    imu_dt = float(np.median(np.diff(imu.t_s)))
    out_every = max(1, int(round(1.0 / (p.output_rate_hz * imu_dt))))
    cfg = _filter_config(session, p, imu_dt, out_every, max(1, int(round(p.cov_step_s / imu_dt))))

    with ctx.stage("initial_alignment"):
        floor_d, floor_se = _floor_down(anchors_ned, t, a, r, sd_fit, p, ctx)
        fixes, n_nofix = fix_events(t, a, r, sd_fit, anchors_ned, floor_d, p.lc_min_anchors, p.epoch_window_s,
                                    p.gate_probability)
        still = stationary_intervals(imu.t_s, imu.gyro_b_rps, imu.acc_b_mps2, t, a, r,
                                      min_duration_s=p.zupt_min_duration_s, acc_step_mps2=p.zupt_acc_step_mps2,
                                      max_speed_mps=p.zupt_max_speed_mps)
        init = _initial_state(session, fixes, still, p)
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
        sd0 = cfg.sd0.copy()
        sd0[:2] = np.minimum(sd_start, p.initial_position_sd_m)
        # beyond the paper: the floor height and the calibration are constant errors, estimated
        # as states rather than treated as white noise (their neglect raised the NEES)
        cfg = replace(cfg, sd0=sd0, floor_sd_m=floor_se, cal_cov_m2=model.bias_cov_m2)
        p0 = np.array([z0[0], z0[1], floor_d])
        init = InitialState(init.k0, geodetic.ned_to_lla(p0, origin), init.vel_ned_mps, init.rpy_rad)
        results["floor_down_m"] = floor_d
        results["floor_height_sd_m"] = floor_se
        results["start_window_end"] = float(t_used + session.t0_s) if rest else None
        results["initial_state"] = {"t": float(imu.t_s[init.k0] + session.t0_s),
                                    "lla": [float(v) for v in init.lla],
                                    "rpy_deg": [float(v) for v in np.degrees(init.rpy_rad)]}
        results["lc_fixes"] = int(fixes.t_s.size)
        results["lc_epochs_without_fix"] = int(n_nofix)
        results["stationary_intervals"] = [[a_ + session.t0_s, b + session.t0_s] for a_, b in still]

    common = [down_events(np.unique(t), floor_d, p.floor_sd_m)]
    if p.zupt and still:
        step = 1.0 / p.zupt_rate_hz
        tz = np.concatenate([np.arange(a_, b + 1e-9, step) for a_, b in still])
        common.append(zupt_events(tz, p.zupt_sd_mps))
        ctx.count("zero_velocity_updates", int(tz.size))
    pooled = model.pooled_sd_m
    trajs, innov, per_sol, runs = [], [], {}, {}
    for name in p.solutions:
        with ctx.stage(f"filter_{name}"):
            extra: dict = {}
            if name == "lc":
                ev = fixes
            elif name == "tc":
                sd_tc = pooled if p.tc_range_sd_m is None else p.tc_range_sd_m  # constant R: pooled residual SD
                ev = range_events(t, a, r, np.full(t.size, sd_tc**2))
                extra["range_sd_m"] = float(sd_tc)
            else:
                R, S = fuzzy_range_variance(fis, sd_fit, pooled, p.fuzzy_exponent_b)
                ev = range_events(t, a, r, R)
                extra["fuzzy_S"] = {"min": float(S.min()), "median": float(np.median(S)), "max": float(S.max())}
            store = p.smoothed and name == p.smooth_source and p.smoother == "rts"
            ev = _after(ev, t_used)
            runf = run_filter(imu.t_s, imu.gyro_b_rps, imu.acc_b_mps2, init, Events.merge(ev, *common),
                              anchors_ned, origin, cfg, store_rts=store)
        runs[name] = runf
        trajs.append(_trajectory(runf, name, session.t0_s))
        per_sol[name] = _report(runf, name, anchors.ids, session.t0_s, p, ctx, t_used) | extra
        innov.append(_innovations(runf, name, anchors.ids, session.t0_s))
    if p.smoothed:
        src = runs[p.smooth_source]
        with ctx.stage("smoothing"):
            bwd = None
            if p.smoother == "rts":
                sol = smoothing.rts(src, src.t_run_s, src.out_idx)
                per_sol["smoothed"] = {"source": p.smooth_source, "smoother": "rts"}
            else:
                # backward from the forward end state with the initial SDs (as the INS/GPS chain),
                # so that the two runs share nothing but that rough start
                bwd = run_filter(imu.t_s, imu.gyro_b_rps, imu.acc_b_mps2, end_state(src), src.events, anchors_ned,
                                 origin, cfg, backward=True)
                fwd15 = _nav15(src)
                sol, flag, _ = smoothing.two_filter(fwd15, _nav15(bwd), src.t_run_s, src.out_idx)
                per_sol["smoothed"] = {"source": p.smooth_source, "smoother": "two_filter",
                                       "forward_backward_disagreements": int(flag.sum())}
                per_sol["smoothed"]["backward"] = _report(bwd, "backward", anchors.ids, session.t0_s, p, None, t_used)
            rb = _smoothed_range_bias(src, bwd)
        trajs.append(_solution_frame(sol, "smoothed", src.t_run_s, session.t0_s, rb))
    results["solutions"] = per_sol
    return ChainOutput(trajectory=pd.concat(trajs, ignore_index=True), tables={"innovations": pd.concat(innov, ignore_index=True)},
                       summary=results)


def few_anchor_intervals(t_s: np.ndarray, anchor: np.ndarray, window_s: float, min_s: float) -> list[tuple[float, float]]:
    """Stretches of at least `min_s` whose range epochs (time-sorted `t_s`) each heard fewer than 3 anchors."""
    bounds = epoch_bounds(group_epochs(t_s, window_s))
    t_ep = t_s[bounds[:-1]]
    n_ep = np.array([np.unique(anchor[a_:b]).size for a_, b in zip(bounds[:-1], bounds[1:])])
    out = []
    edges = np.flatnonzero(np.diff(np.concatenate([[0], (n_ep < 3).astype(np.int8), [0]])))
    for a_, b in zip(edges[::2], edges[1::2]):
        t_start, t_end = t_ep[a_], t_ep[b] if b < t_ep.size else t_ep[-1]
        if t_end - t_start >= min_s:
            out.append((float(t_start), float(t_end)))
    return out


def _after(ev: Events, t_s: float) -> Events:
    """The events after t_s."""
    return ev.select(ev.t_s > t_s)


def _nav15(run: FilterRun) -> FilterRun:
    """The run with its covariances reduced to the 15 navigation states (the smoothers' layout)."""
    return replace(run, ep_P=np.ascontiguousarray(run.ep_P[:, :15, :15]))


def _report(runf: FilterRun, name: str, ids, t0_s: float, p: RangingParams, ctx: RunContext | None,
            t_from_s: float = -np.inf) -> dict:
    """Summary of one filter run: aiding events, gating rejections, coasting; counts and warnings to ctx."""
    evs = runf.events
    aid = (evs.kind == EV_RANGE) | (evs.kind == EV_FIX_NE)
    rej = aid & ~runf.ev_accepted & (runf.ev_nis >= 0)
    if name == "lc":
        rejections = {"fix": int(rej.sum())}
    else:
        rejections = {ids[i]: int(np.sum(rej & (evs.anchor == i) & (evs.kind == EV_RANGE))) for i in range(len(ids))}
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
        "final_range_bias_m": float(runf.range_bias_m[-1]),
    }


def _innovations(runf: FilterRun, name: str, ids, t0_s: float) -> pd.DataFrame:
    evs = runf.events
    aid = (evs.kind == EV_RANGE) | (evs.kind == EV_FIX_NE)
    return pd.DataFrame({
        "t": evs.t_s[aid] + t0_s, "solution": name, "kind": np.where(evs.kind[aid] == EV_RANGE, "range", "fix"),
        "anchor": [ids[i] if i >= 0 else "" for i in evs.anchor[aid]],
        "nis": runf.ev_nis[aid], "accepted": runf.ev_accepted[aid],
    })
