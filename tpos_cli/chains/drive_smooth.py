"""The `drive_smooth` chain (issue 4, paper 003): INS/GPS forward and backward filters and smoothers.

Stages: alignment (levelling + GPS heading), GPS noise (covariance matching on decimated
passes, `fusion.gps_noise`), forward 15-state closed-loop filter, the same
filter backward in reversed time (initialized from the forward end state with the initial
SDs, so that the two runs stay nearly independent), smoothing (`rts`, `two_filter`,
`simplified`), and the trajectory table with sigma, `outage` and `flag` columns; a mounting
check (course over ground against the smoothed yaw, `fusion.mounting`) warns in the summary.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import pandas as pd

from tpos_cli import smoothing
from tpos_cli.chains.context import ChainOutput, RunContext
from tpos_cli.config import DriveSmoothParams
from tpos_cli.errors import InvalidInputError, ProcessingError
from tpos_cli.frames.earth import G0_MPS2
from tpos_cli.frames.geodetic import lla_to_ned, ned_to_lla
from tpos_cli.frames.rotation import dcm_to_euler, euler_sigmas_deg
from tpos_cli.fusion.gps_error import TAU_GRID_S, fit_gps_error
from tpos_cli.fusion.gps_noise import estimate_gps_noise, median_sigmas, scaled_fixes
from tpos_cli.fusion.initial import (
    InitialSigmas,
    align_vehicle,
    initial_covariance,
    measured_white_noise,
    search_yaw,
    with_yaw,
)
from tpos_cli.fusion.insgps import FilterConfig, GpsFixes, InitialState, run_insgps
from tpos_cli.fusion.mounting import course_minus_yaw, mounting_warning
from tpos_cli.session import Session
from tpos_cli.targeting import geolocate

DEG = np.pi / 180.0
SMOOTHERS = ("rts", "two_filter", "simplified")


_DEFAULT_NOISE = {"gyro_noise_dps": 0.01, "acc_noise_mg": 2.0, "gyro_bias_dph": 20.0, "acc_bias_mg": 10.0}


def _noise(p: DriveSmoothParams, session: Session) -> tuple[dict, dict]:
    """Noise figures (contract units) and where each came from: pipeline, session, or, for the
    white noise when neither gives it, the larger of the MEMS default and the log's own
    sample-to-sample scatter (real platforms vibrate far above data-sheet noise)."""
    out, src = {}, {}
    measured = {"gyro_noise_dps": np.degrees(measured_white_noise(session.imu.gyro_b_rps)),
                "acc_noise_mg": measured_white_noise(session.imu.acc_b_mps2) / (1e-3 * G0_MPS2)}
    for key, default in _DEFAULT_NOISE.items():
        v, where = getattr(p, key), "pipeline"
        if v is None:
            v, where = getattr(session.meta.imu_noise, key, None), "session"
        if v is None and key in measured:
            v, where = max(default, float(measured[key])), "measured from the log (or default, the larger)"
        if v is None:
            v, where = default, "default"
        out[key] = float(v)
        src[key] = where
    return out, src


def fixes_from_session(session: Session, p: DriveSmoothParams) -> GpsFixes:
    gps = session.gps
    if gps is None:
        raise ProcessingError("gps: the drive pipeline needs a gps table")
    ok = gps.valid
    sig = np.array(gps.sigma_neu_m[ok], dtype=float)
    default = np.array([p.gps_sigma_h_m, p.gps_sigma_h_m, p.gps_sigma_v_m])
    sig = np.where(np.isfinite(sig) & (sig > 0), np.maximum(sig, p.gps_sigma_floor_m), default)
    vel = np.array(gps.vel_ned_mps[ok], dtype=float)
    if not p.use_gps_velocity:
        vel[:] = np.nan
    vel[~np.isfinite(vel[:, :2]).all(axis=1)] = np.nan  # vd may be absent alone (speed/course receivers)
    t = np.array(gps.t_s[ok], dtype=float)
    keep = decimate_times(t, p.gps_max_rate_hz)
    return GpsFixes(t[keep], np.array(gps.lla[ok], dtype=float)[keep], vel[keep], sig[keep],
                    np.full((int(keep.size), 3), p.gps_sigma_vel_mps))


def decimate_times(t_s, max_rate_hz) -> np.ndarray:
    """Indices of the times kept so that consecutive kept times are >= 1 / max_rate_hz apart
    (less a quarter of the median interval, so that a 1 Hz log with jitter stays whole)."""
    t = np.asarray(t_s, dtype=float)
    if max_rate_hz <= 0 or t.size < 2:
        return np.arange(t.size)
    step = 1.0 / max_rate_hz - 0.25 * float(np.median(np.diff(t)))
    keep = []
    last = -np.inf
    for i, ti in enumerate(t):
        if ti - last >= step:
            keep.append(i)
            last = ti
    return np.asarray(keep, dtype=np.int64)


def fix_outages(t_fix, t_end_s, min_gap_s) -> np.ndarray:
    """(K, 2) outage intervals [last fix, next fix) where fixes are more than `min_gap_s` apart
    (and more than 2.5 nominal intervals), plus a stretch without fixes before the end."""
    if t_fix.size < 2:
        return np.zeros((0, 2))
    dt = np.diff(t_fix)
    thr = max(min_gap_s, 2.5 * float(np.median(dt)))
    i = np.flatnonzero(dt > thr)
    out = [[t_fix[k], t_fix[k + 1]] for k in i]
    if t_end_s - t_fix[-1] > thr:
        out.append([t_fix[-1], t_end_s])
    return np.array(out, dtype=float).reshape(-1, 2)


def solution_frame(sol: smoothing.Solution, t0_s, t_s, outage, flag) -> pd.DataFrame:
    """Contract trajectory rows of one solution, with sigma, outage and flag columns."""
    r, p, y = dcm_to_euler(sol.C_nb)
    sd = np.sqrt(np.clip(np.diagonal(sol.P9, axis1=1, axis2=2), 0.0, None))
    se = euler_sigmas_deg(sol.C_nb, sol.P9[:, 6:9, 6:9])
    n = sol.idx.size
    return pd.DataFrame({
        "t": t_s[sol.idx] + t0_s,
        "lat": np.degrees(sol.nav[:, 0]), "lon": np.degrees(sol.nav[:, 1]), "h": sol.nav[:, 2],
        "vn": sol.nav[:, 3], "ve": sol.nav[:, 4], "vd": sol.nav[:, 5],
        "roll": np.degrees(r), "pitch": np.degrees(p), "yaw": np.degrees(y),
        "solution": np.full(n, sol.name, dtype=object),
        "sigma_n": sd[:, 0], "sigma_e": sd[:, 1], "sigma_d": sd[:, 2],
        "sigma_vn": sd[:, 3], "sigma_ve": sd[:, 4], "sigma_vd": sd[:, 5],
        "sigma_roll": se[:, 0], "sigma_pitch": se[:, 1], "sigma_yaw": se[:, 2],
        "outage": outage, "flag": flag,
    })


@dataclass(frozen=True)
class DriveResult:
    """Everything `process_drive` computed (arrays in package units), for the chain and benchmarks."""

    t_s: np.ndarray
    out_idx: np.ndarray
    forward: object
    backward: object
    solutions: dict
    flag: np.ndarray
    nis_fb: np.ndarray
    outages_s: np.ndarray
    fixes: GpsFixes
    info: dict
    mounting: dict | None = None  # course - yaw check of the first solution in `names` after forward


def process_drive(session: Session, p: DriveSmoothParams, ctx: RunContext | None = None,
                  names=("forward", "backward", "smoothed"), extra_idx=None) -> DriveResult:
    """Align, filter forward and backward, smooth; `names` picks the solutions computed.

    Solutions are evaluated at the output rate plus the IMU sample indices `extra_idx` (e.g.
    range epochs for targeting); `DriveResult.out_idx` lists them all, sorted.
    """
    stage = ctx.stage if ctx is not None else _nostage
    imu = session.imu
    t = np.ascontiguousarray(imu.t_s, dtype=float)
    gyro = np.ascontiguousarray(imu.gyro_b_rps, dtype=float)
    acc = np.ascontiguousarray(imu.acc_b_mps2, dtype=float)
    rate = (t.size - 1) / (t[-1] - t[0])
    nz, nz_src = _noise(p, session)
    lever = np.asarray(session.meta.lever_arm_b_m, dtype=float)
    fixes = fixes_from_session(session, p)
    sig = InitialSigmas(p.init_sigma_pos_m, p.init_sigma_vel_mps, p.init_sigma_level_deg * DEG,
                        p.init_sigma_yaw_deg * DEG, nz["acc_bias_mg"] * 1e-3 * G0_MPS2, nz["gyro_bias_dph"] * DEG / 3600)
    with stage("alignment"):
        init, info = align_vehicle(t, gyro, acc, imu.mag_b_ut, fixes, lever, sig, min_speed_mps=p.heading_min_speed_mps,
                                   declination_rad=(session.meta.declination_deg or 0.0) * DEG)
    sb_a = p.acc_bias_inrun_mg * 1e-3 * G0_MPS2
    sb_g = p.gyro_bias_inrun_dph * DEG / 3600
    q = np.array([(nz["acc_noise_mg"] * 1e-3 * G0_MPS2) ** 2 / rate, (nz["gyro_noise_dps"] * DEG) ** 2 / rate,
                  2 * sb_a**2 / p.bias_tau_s, 2 * sb_g**2 / p.bias_tau_s])
    cfg = FilterConfig(q, p.bias_tau_s, p.bias_tau_s, lever, max(1, int(round(p.cov_step_s * rate))), p.gate_probability,
                       p.max_consecutive_rejections, p.outage_min_s)
    with stage("alignment"):
        info["imu_noise"] = {k: {"value": round(v, 6), "source": nz_src[k]} for k, v in nz.items()}
        if p.heading_hypotheses > 0:
            ys = search_yaw(t, gyro, acc, fixes, init, cfg, n_hypotheses=p.heading_hypotheses, motion_s=p.heading_search_s)
            init = with_yaw(init, ys.yaw_rad, ys.sigma_yaw_rad)
            if not ys.chose_prior:
                info["heading"] = (f"yaw search: {np.degrees(ys.yaw_rad):.0f} deg +- {np.degrees(ys.sigma_yaw_rad):.0f}, "
                                   f"best of {ys.scores.size} hypotheses (the prior, {info['heading']}, lost)")
            else:
                info["heading"] += f"; confirmed against {ys.scores.size - 1} other yaws"
            info["yaw_search"] = {"t_s": list(ys.window_s), "yaw_deg": np.degrees(ys.hypotheses_rad).round(1).tolist(),
                                  "score": [round(float(v), 1) for v in ys.scores]}
    with stage("gps_noise"):
        if p.gps_noise == "estimate":
            after = info["yaw_search"]["t_s"][1] if "yaw_search" in info else None
            gn = estimate_gps_noise(t, gyro, acc, fixes, init, cfg, after_s=after, span_s=p.gps_noise_span_s)
            fixes = scaled_fixes(fixes, gn.scale)
            info["gps_noise"] = {"method": "covariance matching on decimated filter passes (fusion.gps_noise)",
                                 **gn.summary()}
            info["gps_noise"]["fixes_from_to_s"] = [round(float(v) + session.t0_s, 2) for v in gn.window_s]
        else:
            info["gps_noise"] = {"method": "given (log SDs or pipeline defaults)",
                                 **{k: (None if not np.isfinite(v) else round(float(v), 4)) for k, v in zip(
                                     ("sigma_pos_h_m", "sigma_pos_v_m", "sigma_vel_h_mps", "sigma_vel_v_mps"),
                                     median_sigmas(fixes))}}
    with stage("gps_noise"):
        if p.gps_error_model == "gauss_markov":
            after = info["yaw_search"]["t_s"][1] if "yaw_search" in info else None
            if p.gps_gm_sigma_h_m is None or p.gps_gm_sigma_v_m is None:
                taus = (p.gps_gm_tau_s,) if p.gps_gm_tau_s is not None else TAU_GRID_S
                fit = fit_gps_error(t, gyro, acc, fixes, init, cfg, taus_s=taus, after_s=after,
                                    span_s=p.gps_noise_span_s)
                sd, tau = fit.sigma_gm_ned_m.copy(), fit.tau_s
                info["gps_error_states"] = fit.summary()
            else:
                sd, tau = np.zeros(3), p.gps_gm_tau_s or 30.0
                info["gps_error_states"] = {"method": "set by the pipeline", "tau_s": tau}
            if p.gps_gm_sigma_h_m is not None:
                sd[:2] = p.gps_gm_sigma_h_m
            if p.gps_gm_sigma_v_m is not None:
                sd[2] = p.gps_gm_sigma_v_m
            info["gps_error_states"].update(sigma_h_m=round(float(sd[0]), 4), sigma_v_m=round(float(sd[2]), 4))
            cfg = dataclasses.replace(cfg, gps_gm_sigma_ned_m=sd, gps_gm_tau_s=tau)
            if p.gps_noise == "estimate" and cfg.n_states > 15:
                # the white part again, with the error states on: they now carry the share of
                # the fix-to-fix scatter that the wander makes
                fixes = scaled_fixes(fixes, 1.0 / gn.scale)
                gn = estimate_gps_noise(t, gyro, acc, fixes, init, cfg, after_s=after, span_s=p.gps_noise_span_s)
                fixes = scaled_fixes(fixes, gn.scale)
                info["gps_noise"].update(gn.summary())
    need_rts = "rts" in names or ("smoothed" in names and p.smoother == "rts")
    step = 1 if p.output_rate_hz <= 0 else max(1, int(round(rate / p.output_rate_hz)))
    out_idx = np.arange(0, t.size, step)
    if out_idx[-1] != t.size - 1:
        out_idx = np.append(out_idx, t.size - 1)
    if extra_idx is not None and len(extra_idx):
        out_idx = np.union1d(out_idx, np.asarray(extra_idx, dtype=np.int64))
    sols = {}
    with stage("forward"):
        fwd = run_insgps(t, gyro, acc, fixes, init, cfg, store_rts=need_rts)
    if need_rts:
        with stage("smoothing_rts"):
            sols["rts"] = smoothing.rts(fwd, t, out_idx)
            # drop the RTS history before the backward run: it is the largest array of the run
            fwd = dataclasses.replace(fwd, ep_Phi=None, ep_Ppred=None)
    with stage("backward"):
        # backward starts from the forward end state but with the initial SDs (not the forward
        # covariance): the two runs then share no information beyond that rough start
        init_b = InitialState(fwd.nav[-1].copy(), fwd.C_nb[-1].copy(), fwd.bias[-1, :6].copy(),
                              initial_covariance(InitialSigmas(p.init_sigma_pos_m, p.init_sigma_vel_mps,
                                                               sig.level_rad, sig.yaw_rad, sig.acc_bias_mps2,
                                                               sig.gyro_bias_rps)))
        bwd = run_insgps(t, gyro, acc, fixes, init_b, cfg, backward=True)
    with stage("smoothing"):
        outages = fix_outages(fixes.t_s, t[-1], p.outage_min_s)
        wanted = set(names)
        if "smoothed" in wanted:
            wanted.add(p.smoother)
        if "two_filter" in wanted:
            sols["two_filter"], flag, nis = smoothing.two_filter(fwd, bwd, t, out_idx, flag_probability=p.flag_probability)
        else:
            flag, nis = smoothing.disagreement(fwd, bwd, t, out_idx, flag_probability=p.flag_probability)
        for name in wanted:
            if name == "forward":
                sols[name] = smoothing.filter_solution(fwd, out_idx, "forward")
            elif name == "backward":
                sols[name] = smoothing.filter_solution(bwd, out_idx, "backward")
            elif name == "simplified":
                sols[name] = smoothing.simplified(fwd, bwd, t, out_idx, outages)
        if "smoothed" in wanted:
            s = sols[p.smoother]
            sols["smoothed"] = smoothing.Solution("smoothed", s.idx, s.nav, s.C_nb, s.P9)
        sols = {k: v for k, v in sols.items() if k in names}
    mounting = None
    if p.mounting_check_deg > 0:
        best = next((n for n in ("smoothed", "rts", "two_filter", "forward") if n in sols), None)
        if best is not None:
            s = sols[best]
            chk = course_minus_yaw(t[s.idx], s.nav[:, 3:6], dcm_to_euler(s.C_nb)[2], p.mounting_min_speed_mps)
            warn = mounting_warning(chk, p.mounting_check_deg)
            mounting = {"solution": best, "threshold_deg": p.mounting_check_deg, "warning": warn is not None,
                        **(chk.summary() if chk is not None else {"moving_s": 0.0})}
            if warn is not None:
                mounting["message"] = warn
    return DriveResult(t, out_idx, fwd, bwd, sols, flag, nis, outages, fixes, info, mounting)


def nis_band(nis, innovation) -> dict | None:
    """Mean NIS of the applied fixes against its 95% band: a mean of M chi-square(d) values has SD
    sqrt(2 d / M) (d = the fixes' mean d.o.f.), so the band is d +- 1.96 sqrt(2 d / M)."""
    if len(nis) == 0:
        return None
    dof = float(np.mean(np.isfinite(innovation).sum(axis=1)))
    half = 1.96 * np.sqrt(2.0 * dof / len(nis))
    mean = float(np.mean(nis))
    return {"mean": round(mean, 3), "dof": round(dof, 2), "band95": [round(float(dof - half), 3), round(float(dof + half), 3)],
            "inside": bool(abs(mean - dof) <= half), "fixes": int(len(nis))}


def range_epochs(session: Session):
    """(idx (K,), range_m (K,), shot (K,)): IMU sample nearest each LR1 return inside a shot window."""
    if session.ranges is None or session.shots is None:
        return None
    t = session.imu.t_s
    tr, d1 = session.ranges.t_s, session.ranges.range_m[:, 0]
    idx, rng, shot = [], [], []
    for k in range(len(session.shots.ids)):
        m = (tr >= session.shots.t_start_s[k]) & (tr <= session.shots.t_end_s[k]) & np.isfinite(d1)
        i = np.clip(np.searchsorted(t, tr[m]), 0, t.size - 1)
        i0 = np.clip(i - 1, 0, t.size - 1)
        i = np.where(np.abs(t[i0] - tr[m]) < np.abs(t[i] - tr[m]), i0, i)
        idx.append(i)
        rng.append(d1[m])
        shot.append(np.full(i.size, k))
    if not idx:
        return None
    return np.concatenate(idx), np.concatenate(rng), np.concatenate(shot)


def geolocate_shots(session: Session, sol: smoothing.Solution, epochs, sigma_range_m: float) -> pd.DataFrame:
    """Targets of the shots from a solution at the range epochs (paper 001 with `targeting.geolocate`).

    Each range epoch is geolocated with the solution's position and attitude covariances; a
    shot's target is the mean over its epochs. Its covariance is the mean of the epochs'
    covariances, not divided by their number: within a shot of a few seconds the trajectory
    errors that dominate are the same at every epoch (only the range noise would average out).
    """
    idx, rng, shot = epochs
    k = np.searchsorted(sol.idx, idx)
    lla = np.column_stack([np.degrees(sol.nav[k, 0]), np.degrees(sol.nav[k, 1]), sol.nav[k, 2]])
    fix = geolocate(lla, sol.C_nb[k], rng, P_att_rad2=sol.P9[k, 6:9, 6:9], sigma_range_m=sigma_range_m,
                    P_obs_ned_m2=sol.P9[k, 0:3, 0:3])
    rows = []
    t0 = session.t0_s
    for s_i in np.unique(shot):
        m = shot == s_i
        ref = fix.lla[m][0]
        mean_ned = lla_to_ned(fix.lla[m], ref).mean(axis=0)
        pos = ned_to_lla(mean_ned, ref)
        sd = np.sqrt(np.clip(np.diagonal(fix.cov_ned_m2[m].mean(axis=0)), 0.0, None))
        rows.append({"id": session.shots.ids[s_i], "t_start": session.shots.t_start_s[s_i] + t0,
                     "t_end": session.shots.t_end_s[s_i] + t0, "range_m": float(np.mean(rng[m])),
                     "lat": float(pos[0]), "lon": float(pos[1]), "h": float(pos[2]), "solution": sol.name,
                     "sigma_n": sd[0], "sigma_e": sd[1], "sigma_u": sd[2], "n_ranges": int(m.sum())})
    return pd.DataFrame(rows)


def innovations_table(res: DriveResult, t0_s: float) -> pd.DataFrame:
    """`innovations.parquet`: one row per fix, run and kind: t, solution (forward | backward), kind
    (gps_pos | gps_vel), nis, dof, accepted, and the residual components nu_0..nu_2 (NED m or m/s)."""
    frames = []
    for run_name, r in (("forward", res.forward), ("backward", res.backward)):
        for j, kind in enumerate(("gps_pos", "gps_vel")):
            m = np.isfinite(r.nis[:, j])
            nu = r.innovation[m, 3 * j: 3 * j + 3]
            frames.append(pd.DataFrame({
                "t": res.fixes.t_s[m] + t0_s, "solution": run_name, "kind": kind, "nis": r.nis[m, j],
                "dof": np.isfinite(nu).sum(axis=1).astype(np.int64), "accepted": r.accepted[m, j],
                "nu_0": nu[:, 0], "nu_1": nu[:, 1], "nu_2": nu[:, 2]}))
    return pd.concat(frames, ignore_index=True).sort_values(["solution", "kind", "t"], kind="stable", ignore_index=True)


class _nostage:
    def __init__(self, name):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *a):
        return False


def run(session: Session, p: DriveSmoothParams, ctx: RunContext) -> ChainOutput:
    names = ["forward", "backward", "smoothed"] + (list(SMOOTHERS) if p.compare else [])
    epochs = range_epochs(session)
    res = process_drive(session, p, ctx, names, extra_idx=None if epochs is None else epochs[0])
    t = res.t_s
    targets = None
    if epochs is not None:
        with ctx.stage("targeting"):
            rf = session.meta.rangefinders
            sig_r = float(rf.sigma_m) if rf is not None and rf.sigma_m is not None else 0.0
            targets = geolocate_shots(session, res.solutions["smoothed"], epochs, sig_r)
        ctx.count("targets", len(targets))
    with ctx.stage("outputs"):
        step = 1 if p.output_rate_hz <= 0 else max(1, int(round((t.size - 1) / (t[-1] - t[0]) / p.output_rate_hz)))
        keep = (res.out_idx % step == 0) | (res.out_idx == t.size - 1)
        if epochs is not None:
            res = dataclasses.replace(res, out_idx=res.out_idx[keep], flag=res.flag[keep], solutions={
                k: smoothing.Solution(v.name, v.idx[keep], v.nav[keep], v.C_nb[keep], v.P9[keep])
                for k, v in res.solutions.items()})
        tt = t[res.out_idx]
        outage = np.zeros(tt.size, dtype=bool)
        for a, b in res.outages_s:
            outage |= (tt >= a) & (tt < b)
        frames = [solution_frame(res.solutions[n], session.t0_s, t, outage, res.flag) for n in names]
        traj = pd.concat(frames, ignore_index=True)
        innov = innovations_table(res, session.t0_s)
    n_fix = int(res.fixes.t_s.size)
    ctx.count("gps_fixes_used", n_fix)
    rejected = {}
    for run_name, r in (("forward", res.forward), ("backward", res.backward)):
        for j, kind in enumerate(("gps_pos", "gps_vel")):
            n_rej = int(np.sum(~r.accepted[:, j] & np.isfinite(r.nis[:, j])))
            rejected[f"{run_name}_{kind}"] = n_rej
            ctx.count(f"{kind}_rejected_{run_name}", n_rej)
    ctx.count("flagged_rows", int(res.flag.sum()))
    mounting = dict(res.mounting) if res.mounting is not None else None
    if mounting is not None and "message" in mounting:
        ctx.warn(mounting.pop("message"))  # into summary.json warnings, once
    mean_nis = {}
    nis_check = {}
    for j, kind in enumerate(("gps_pos", "gps_vel")):
        a = res.forward.nis[res.forward.accepted[:, j], j]
        mean_nis[kind] = float(np.mean(a)) if a.size else None
        nis_check[kind] = nis_band(a, res.forward.innovation[res.forward.accepted[:, j], 3 * j: 3 * j + 3])
    summary = {
        "alignment": res.info,
        "smoothed_method": p.smoother,
        "solutions": names,
        "gps_fixes": n_fix,
        "gps_rejected": rejected,
        "forward_mean_nis": mean_nis,  # 3 d.o.f. each (2 for speed/course velocity): about that when R fits
        "forward_nis_check": nis_check,
        "outages_s": (res.outages_s + session.t0_s).tolist(),
        "flagged_fraction": float(np.mean(res.flag)) if res.flag.size else 0.0,
        "mounting_check": mounting,
    }
    return ChainOutput(trajectory=traj, targets=targets, tables={"innovations": innov}, summary=summary)
