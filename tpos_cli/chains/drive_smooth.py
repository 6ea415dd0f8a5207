"""The `drive_smooth` chain (issue 4, paper 003): INS/GPS forward and backward filters and smoothers.

Stages: alignment (levelling + GPS heading, yaw search), GPS noise (covariance matching on
decimated passes, `fusion.gps_noise`; GPS error states, `fusion.gps_error`), the forward 15-state
closed-loop filter, the same filter backward in reversed time (`fusion.engine.backward_start`:
from the forward end state with the initial SDs, so that the two runs stay nearly independent),
smoothing (`rts`, `two_filter`, `simplified`), targets of LR1 shots, and the trajectory table
with sigma, `outage` and `flag` columns (`tpos_cli.trajectory`); a mounting check (course over
ground against the smoothed yaw, `fusion.mounting`) warns in the summary.
"""

from __future__ import annotations

import contextlib
import dataclasses
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from tpos_cli import smoothing
from tpos_cli.chains.context import ChainOutput, RunContext, spare_cpu
from tpos_cli.config import DriveSmoothParams
from tpos_cli.consistency import mean_chi2
from tpos_cli.conventions import output_on_gps_clock
from tpos_cli.errors import InvalidInputError, ProcessingError
from tpos_cli.frames.earth import G0_MPS2
from tpos_cli.frames.geodetic import lla_to_ned, ned_to_lla
from tpos_cli.frames.rotation import dcm_to_euler, euler_to_dcm
from tpos_cli.fusion.constraints import (
    detect_stops,
    nhc_measurements,
    odometer_measurements,
    rotation_gyro_noise_dps,
    stop_measurements,
    travel_direction,
)
from tpos_cli.fusion.engine import ENDS_ONLY, FilterConfig, FilterRun, InitialState, Measurements, backward_start, epoch_of
from tpos_cli.fusion.gps_error import (
    STATED_SPLIT_TAU_S,
    TAU_GRID_S,
    fit_gps_error,
    matched_tau_bound_s,
    stated_split,
    unmodelled_error_sd_m,
    unmodelled_velocity_var,
    velocity_span_s,
    white_sds,
)
from tpos_cli.fusion.gps_noise import GpsNoise, estimate_gps_noise, median_sigmas, pass_window, rows_within, scaled_fixes
from tpos_cli.fusion.initial import InitialSigmas, align_vehicle, initial_covariance, search_yaw, with_yaw
from tpos_cli.fusion.insgps import GpsFixes, GpsInnovations, gps_error_layout, gps_innovations, run_insgps, velocity_latency_s
from tpos_cli.fusion.layout import (
    N_NAV,
    Block,
    StateLayout,
    clock_block,
    float_offset_block,
    lever_arm_block,
    mounting_block,
    odometer_block,
)
from tpos_cli.fusion.lever_arm import (
    at_stated_point,
    course_span_deg,
    lever_arm_summary,
    lever_arm_wanted,
    lever_axes,
    lever_correction_b,
)
from tpos_cli.fusion.measurements import Kind
from tpos_cli.fusion.mounting import course_minus_yaw, mounting_off, refined_mounting, vehicle_attitude
from tpos_cli.fusion.nav_errors import vibration_velocity_cov_b
from tpos_cli.fusion.rtk_float import float_fixes, float_intervals
from tpos_cli.fusion.screening import wild_fixes
from tpos_cli.imu_noise import ImuNoiseFigures, measured_white_noise, resolve_imu_noise, stop_noise_factors
from tpos_cli.io.columns import Columns, concat
from tpos_cli.io.tables import table_file_name
from tpos_cli.quality import mounting_text
from tpos_cli.ranging.filter import output_indices
from tpos_cli.session import Session
from tpos_cli.timebase import in_intervals
from tpos_cli.timeoffset import gps_velocity
from tpos_cli.trajectory import Solution, solution_columns

if TYPE_CHECKING:
    import pandas as pd

DEG = np.pi / 180.0
SMOOTHERS = ("rts", "two_filter", "simplified")
GPS_KINDS = ("gps_pos", "gps_vel")  # `innovations.parquet` kind of the position and velocity parts


def drive_imu_noise(p: DriveSmoothParams, session: Session) -> ImuNoiseFigures:
    """IMU figures (`tpos_cli.imu_noise`); the white noise measured from the log counts only where
    larger than the default: real platforms vibrate far above data-sheet noise. The gyro's is at
    least what the platform's rotation makes of the gyro's scale-factor error
    (`fusion.constraints.rotation_gyro_noise_dps`: a walker's sway and turns)."""
    default = {k: DriveSmoothParams.model_fields[k].default for k in ("gyro_noise_dps", "acc_noise_mg")}
    gyro = session.imu.gyro_b_rps
    measured = {"gyro_noise_dps": max(default["gyro_noise_dps"], float(np.degrees(measured_white_noise(gyro))),
                                      rotation_gyro_noise_dps(gyro)),
                "acc_noise_mg": max(default["acc_noise_mg"], float(measured_white_noise(session.imu.acc_b_mps2) / (1e-3 * G0_MPS2)))}
    return resolve_imu_noise(p, session.meta.imu_noise, measured=measured,
                             measured_label="measured from the log (gyro: or 1 % of its RMS rate; or default: the larger)")


def initial_sigmas(p: DriveSmoothParams, nz: ImuNoiseFigures) -> InitialSigmas:
    return InitialSigmas(p.init_sigma_pos_m, p.init_sigma_vel_mps, p.init_sigma_level_deg * DEG, p.init_sigma_yaw_deg * DEG,
                         nz["acc_bias_mg"] * 1e-3 * G0_MPS2, nz["gyro_bias_dph"] * DEG / 3600)


def filter_config(p: DriveSmoothParams, nz: ImuNoiseFigures, lever_b_m, rate_hz: float) -> FilterConfig:
    """SI filter settings: white-noise PSDs from the per-sample SDs (sigma^2 / rate), Gauss-Markov
    bias drive 2 sigma^2 / tau, covariance step in samples."""
    sb_a = p.acc_bias_inrun_mg * 1e-3 * G0_MPS2
    sb_g = p.gyro_bias_inrun_dph * DEG / 3600
    q = np.array([(nz["acc_noise_mg"] * 1e-3 * G0_MPS2) ** 2 / rate_hz, (nz["gyro_noise_dps"] * DEG) ** 2 / rate_hz,
                  2 * sb_a**2 / p.bias_tau_s, 2 * sb_g**2 / p.bias_tau_s])
    layout = StateLayout((clock_block(p.gps_clock_sigma_s, p.gps_clock_rw_s_per_sqrt_s),) if p.gps_clock_sigma_s > 0 else ())
    return FilterConfig(q, p.bias_tau_s, p.bias_tau_s, max(1, int(round(p.cov_step_s * rate_hz))), p.gate_probability,
                        p.max_consecutive_rejections, np.asarray(lever_b_m, dtype=float), p.outage_min_s, layout,
                        reacquire=False)  # the tuning passes keep the old rule; `tune_gps` returns the final runs' settings


def fixes_from_session(session: Session, p: DriveSmoothParams) -> GpsFixes:
    gps = session.gps
    if gps is None:
        raise ProcessingError("gps: the drive pipeline needs a gps table")
    ok = gps.valid.copy()
    if not ok.any():
        raise InvalidInputError(f"{table_file_name(session.path, 'gps')}: no row holds a position fix (lat, lon, h empty or "
                                f"fix = 0 in all {gps.t_s.size} rows left); the drive pipeline needs GPS fixes")
    t_imu = session.imu.t_s
    if not (ok & (gps.t_s >= t_imu[0]) & (gps.t_s <= t_imu[-1])).any():
        # GPS on another clock (or a wrong [time] gps_offset_s): without this the drive ran the whole
        # log as dead reckoning, exit 0 (the loader only warns: other chains may not need the GPS)
        # (`load_session` refuses it for a drive session: this is for library callers' sessions)
        from tpos_cli.session import gps_outside_imu_span_message  # here: the rest of this module is lever's
        raise InvalidInputError(f"{table_file_name(session.path, 'gps')}: column 't': " + gps_outside_imu_span_message(
            gps.t_s[ok][[0, -1]] + session.t0_s, t_imu[[0, -1]] + session.t0_s))
    wild = wild_fixes(gps.t_s[ok], gps.lla[ok], np.asarray(gps.sigma_neu_m[ok], dtype=float)[:, :2].max(axis=1))
    ok[np.flatnonzero(ok)[wild]] = False  # counted by the chain (`drive_summary`: gps_fixes_wild)
    sig = np.array(gps.sigma_neu_m[ok], dtype=float)
    default = np.array([p.gps_sigma_h_m, p.gps_sigma_h_m, p.gps_sigma_v_m])
    logged = np.isfinite(sig) & (sig > 0)
    sig = np.where(logged, np.maximum(sig, p.gps_sigma_floor_m), default)
    from_receiver = (bool(logged[:, :2].mean() > 0.5), bool(logged[:, 2].mean() > 0.5), False, False) if logged.size else (False,) * 4
    vel = np.array(gps.vel_ned_mps[ok], dtype=float)
    if not p.use_gps_velocity:
        vel[:] = np.nan
    vel[~np.isfinite(vel[:, :2]).all(axis=1)] = np.nan  # vd may be absent alone (speed/course receivers)
    t = np.array(gps.t_s[ok], dtype=float)
    # RTK float epochs (the receiver raised its SD off its centimetre floor): kept, with the float offset
    # state on their position rows (`float_offset_states`), from the stated SDs of every fix (4 Hz)
    is_float = float_fixes(np.asarray(gps.sigma_neu_m[ok], dtype=float)[:, :2].max(axis=1), p.gps_float_sd_factor)
    # (their velocity rows carry the offset's drift as variance: `fusion.rtk_float.float_velocity_var`)
    keep = decimate_times(t, p.gps_max_rate_hz)
    fixes = GpsFixes(t, np.array(gps.lla[ok], dtype=float), vel, sig, np.full((t.size, 3), p.gps_sigma_vel_mps), from_receiver)
    if p.gps_vel_latency_s is not None:
        lag = p.gps_vel_latency_s
    elif p.gps_clock_sigma_s > 0:  # the filter's velocity clock state measures it against the IMU
        lag = 0.0
    else:
        lag, _ = velocity_latency_s(fixes)
    return GpsFixes(t[keep], fixes.lla[keep], vel[keep], sig[keep], fixes.sigma_vel_mps[keep], from_receiver, lag,
                    int(wild.sum()), float_intervals(t, is_float), int(is_float.sum()))


def float_offset_states(p: DriveSmoothParams, fixes: GpsFixes, cfg: FilterConfig) -> FilterConfig:
    """`cfg` with the RTK float offset block (`layout.float_offset_block`) and the float stretches whose
    position rows see it (`fusion.rtk_float`), when the fixes hold any; else `cfg` unchanged."""
    if not fixes.float_intervals_s.shape[0]:
        return cfg
    block = float_offset_block(p.gps_float_sigma_h_m, p.gps_float_sigma_v_m, p.gps_float_tau_s)
    return dataclasses.replace(cfg, layout=StateLayout((*cfg.layout.blocks, block)),
                               float_intervals_s=np.asarray(fixes.float_intervals_s, dtype=float))


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


def solution_rows(sol: Solution, t_s, t0_s: float, outage, flag, P_att_rad2=None) -> Columns:
    """Contract trajectory rows of one solution, with sigma, outage and flag columns (P_att_rad2:
    the attitude-error covariance in place of sol.P9's, `trajectory.solution_columns`)."""
    return solution_columns(sol, t_s, t0_s, extra={"outage": outage, "flag": flag}, P_att_rad2=P_att_rad2)


@dataclass(frozen=True)
class DriveResult:
    """Everything `process_drive` computed (arrays in package units), for the chain and benchmarks."""

    t_s: np.ndarray
    out_idx: np.ndarray
    forward: FilterRun
    backward: FilterRun
    solutions: dict
    flag: np.ndarray
    nis_fb: np.ndarray
    outages_s: np.ndarray
    fixes: GpsFixes
    info: dict
    mounting: dict | None = None  # course - yaw check of the first solution in `names` after forward
    C_vb: np.ndarray | None = None  # IMU body to vehicle axes, when the run applied a mounting (NHC)
    stop_intervals_s: np.ndarray | None = None  # (K, 2) detected stops, session seconds (unrounded)

    def innovations(self, run: str = "forward") -> GpsInnovations:
        """Per-fix results of the forward or backward run."""
        return gps_innovations(self.forward if run == "forward" else self.backward, self.fixes.t_s.size)


@dataclass(frozen=True)
class _Imu:
    t: np.ndarray
    gyro: np.ndarray
    acc: np.ndarray

    @property
    def rate_hz(self) -> float:
        return (self.t.size - 1) / (self.t[-1] - self.t[0])


def align(imu: _Imu, session: Session, p: DriveSmoothParams, fixes: GpsFixes, cfg: FilterConfig,
          sig: InitialSigmas, nz: ImuNoiseFigures) -> tuple[InitialState, dict]:
    """Initial state (`fusion.initial.align_vehicle`) and, with `heading_hypotheses`, the yaw search."""
    init, info = align_vehicle(imu.t, imu.gyro, imu.acc, session.imu.mag_b_ut, fixes, cfg.lever_arm_b_m, sig,
                               min_speed_mps=p.heading_min_speed_mps,
                               declination_rad=(session.meta.declination_deg or 0.0) * DEG)
    info["imu_noise"] = nz.summary()
    if p.heading_hypotheses > 0:
        ys = search_yaw(imu.t, imu.gyro, imu.acc, fixes, init, cfg, n_hypotheses=p.heading_hypotheses,
                        motion_s=p.heading_search_s)
        init = with_yaw(init, ys.yaw_rad, ys.sigma_yaw_rad)
        if not ys.chose_prior:
            info["heading"] = (f"yaw search: {np.degrees(ys.yaw_rad):.0f} deg +- {np.degrees(ys.sigma_yaw_rad):.0f}, "
                               f"best of {ys.scores.size} hypotheses (the prior, {info['heading']}, lost)")
        else:
            info["heading"] += f"; confirmed against {ys.scores.size - 1} other yaws"
        info["yaw_search"] = {"t_s": list(ys.window_s), "yaw_deg": np.degrees(ys.hypotheses_rad).round(1).tolist(),
                              "score": [round(float(v), 1) for v in ys.scores], "prior_kept": bool(ys.chose_prior)}
    return init, info


def raise_only(gn: GpsNoise, fixes: GpsFixes) -> GpsNoise:
    """The matching's scales below 1 set to 1 where the receiver logged the SDs (they are a floor:
    a quiet stretch of fixes says little about the next multipath one); SDs recomputed."""
    stated = np.asarray(fixes.from_receiver, dtype=bool)
    scale = np.where(stated, np.maximum(gn.scale, 1.0), gn.scale)
    return dataclasses.replace(gn, scale=scale, sigma=median_sigmas(scaled_fixes(fixes, scale)),
                               scale_at_rest=np.where(stated, np.maximum(gn.scale_at_rest, 1.0), gn.scale_at_rest))


def tune_gps(imu: _Imu, p: DriveSmoothParams, fixes: GpsFixes, init: InitialState, cfg: FilterConfig, info: dict,
             t0_s: float, extra: Measurements | None = None, stop_intervals_s=None) -> tuple[GpsFixes, FilterConfig]:
    """GPS noise (covariance matching, `fusion.gps_noise`) and GPS error states (`fusion.gps_error`),
    on passes of the final filter (`cfg`, with the constraint rows `extra`); records what was
    found in `info`. Returns the fixes with their SDs scaled and the settings of the final runs
    (`final_settings`). `stop_intervals_s`: the detected stops (session s), where
    gps_error_model = "stated_split" measures the fixes' white scatter."""
    after = info["yaw_search"]["t_s"][1] if "yaw_search" in info else None
    gn = None
    if p.gps_noise == "estimate":
        gn = estimate_gps_noise(imu.t, imu.gyro, imu.acc, fixes, init, cfg, after_s=after, span_s=p.gps_noise_span_s,
                                extra=extra, rest_intervals_s=stop_intervals_s)
        gn = raise_only(gn, fixes)
        fixes = gn.scaled(fixes)
        info["gps_noise"] = {"method": "covariance matching on decimated filter passes; the receiver's own SDs only "
                                       "raised (fusion.gps_noise)", **gn.summary()}
        info["gps_noise"]["fixes_from_to_s"] = [round(float(v) + t0_s, 2) for v in gn.window_s]
    else:
        info["gps_noise"] = {"method": "given (log SDs or pipeline defaults)",
                             **{k: (None if not np.isfinite(v) else round(float(v), 4)) for k, v in zip(
                                 ("sigma_pos_h_m", "sigma_pos_v_m", "sigma_vel_h_mps", "sigma_vel_v_mps"),
                                 median_sigmas(fixes))}}
    if p.gps_error_model == "stated_split":
        # the receiver's SDs (before the matching's scales): the split keeps their variance; the
        # matching then starts again from the white part, with the error states on
        stated = gn.scaled(fixes, inverse=True) if gn is not None else fixes
        split = stated_split(stated.t_s, lla_to_ned(stated.lla, stated.lla[0]), stated.sigma_pos_ned_m,
                             np.zeros((0, 2)) if stop_intervals_s is None else stop_intervals_s,
                             np.asarray(stated.from_receiver[:2], dtype=bool), tau_s=p.gps_gm_tau_s or STATED_SPLIT_TAU_S)
        info["gps_error_states"] = split.summary()
        if not np.any(split.gm_m > 0):
            return fixes, final_settings(cfg, gn)
        fixes = dataclasses.replace(stated, sigma_pos_ned_m=white_sds(stated.sigma_pos_ned_m, split))
        # a group left white gets a state of a thousandth of its stated SD (numerically white; a zero-SD
        # state would leave the predicted covariance singular for the RTS smoother)
        gm = np.where(split.gm_m > 0, split.gm_m, 1e-3 * np.nan_to_num(split.stated_m, nan=1.0))
        cfg = dataclasses.replace(cfg, layout=gps_error_layout(gm[[0, 0, 1]], split.tau_s, cfg.layout))
        return rematched_white(imu, p, fixes, init, cfg, info, gn, after, extra, stop_intervals_s)
    if p.gps_error_model != "gauss_markov":
        return fixes, final_settings(cfg, gn)
    if p.gps_gm_sigma_h_m is None or p.gps_gm_sigma_v_m is None:
        taus = (p.gps_gm_tau_s,) if p.gps_gm_tau_s is not None else TAU_GRID_S
        fit = fit_gps_error(imu.t, imu.gyro, imu.acc, fixes, init, cfg, taus_s=taus, after_s=after, span_s=p.gps_noise_span_s,
                            extra=extra)
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
    cfg = dataclasses.replace(cfg, layout=gps_error_layout(sd, tau, cfg.layout))
    if gn is not None and cfg.layout.offset(Block.GPS_ERROR) >= 0:
        fixes = gn.scaled(fixes, inverse=True)
    return rematched_white(imu, p, fixes, init, cfg, info, gn, after, extra, stop_intervals_s)


def rematched_white(imu: _Imu, p: DriveSmoothParams, fixes: GpsFixes, init: InitialState, cfg: FilterConfig, info: dict,
                    gn: GpsNoise | None, after, extra: Measurements | None, stop_intervals_s=None) -> tuple[GpsFixes, FilterConfig]:
    """The white part matched again with the error states on (`fixes` with the SDs the matching
    starts from): the states now carry the share of the fix-to-fix scatter that the wander makes."""
    if gn is not None and cfg.layout.offset(Block.GPS_ERROR) >= 0:
        gn = estimate_gps_noise(imu.t, imu.gyro, imu.acc, fixes, init, cfg, after_s=after, span_s=p.gps_noise_span_s,
                                extra=extra, rest_intervals_s=stop_intervals_s)
        gn = raise_only(gn, fixes)
        fixes = gn.scaled(fixes)
        info["gps_noise"].update(gn.summary())
    return fixes, final_settings(cfg, gn)


def final_settings(cfg: FilterConfig, gn: GpsNoise | None) -> FilterConfig:
    """`cfg` for the final forward and backward runs: re-acquisition after rejections
    (`fusion.reacquire`) on, judged against the fixes' stated accuracy (the receiver's SDs, else the
    pipeline's `gps_sigma_*`): per group the stated SD over the matched one, 1 where matching raised
    it (`FilterConfig.stated_sd_factor`). The tuning passes keep the old rule (`filter_config`):
    their statistics match R to the innovations, and a re-acquired row's covariance is grown to fit
    its own innovation (on navego it moved the matched SDs, the clock and the start-up heading)."""
    f = np.ones(4)
    if gn is not None:
        sc = np.asarray(gn.scale, dtype=float)
        ok = np.isfinite(sc) & (sc > 0.0)
        f[ok] = np.maximum(1.0, 1.0 / sc[ok])
    return dataclasses.replace(cfg, reacquire=True, stated_sd_factor=f)


WHEELED = ("car", "rover")
COARSE_RATE_HZ = 25.0  # IMU rate of the first pass that finds the mounting


def motion_constraints(imu: _Imu, session: Session, p: DriveSmoothParams, fixes: GpsFixes, init: InitialState,
                       cfg: FilterConfig, info: dict) -> tuple[FilterConfig, Measurements | None, np.ndarray]:
    """The platform's motion constraints (`fusion.constraints`): stops from GPS / odometer speed
    (ZUPT, and ZARU on a wheeled vehicle), NHC in the vehicle axes of a wheeled one. The mounting
    comes from `[imu] mounting_rpy_deg`, else from the travel direction of a first forward run,
    which also decides an `auto` platform; there the trial pass's residual misalignment refines it
    (a slow rover's first run holds its heading only to 8-19 deg, and the travel direction inherits
    that). Records what was decided in info["constraints"]; also returns the detected stops
    ((K, 2) session seconds, unrounded: `DriveResult.stop_intervals_s`, which `drive_summary` writes)."""
    gps = session.gps
    odo = session.odometry
    stops = detect_stops(gps.t_s[gps.valid], gps.vel_ned_mps[gps.valid], None if odo is None else odo.t_s,
                         None if odo is None else odo.speed_mps, max_speed_mps=p.stop_max_speed_mps,
                         min_duration_s=p.stop_min_duration_s)
    platform, decided = p.platform, "pipeline"
    mounting = session.meta.mounting_rpy_deg
    out: dict = {"stops": int(stops.intervals_s.shape[0]), "stopped_s": round(stops.total_s, 1), "stops_from": stops.sources}
    C_vb = None
    if mounting is not None:
        C_vb = euler_to_dcm(*np.radians(np.asarray(mounting, dtype=float)))
        out["mounting"] = {"source": "session", "mounting_rpy_deg": [float(v) for v in mounting]}
    zu_rows = stop_measurements(imu.t, imu.gyro, imu.acc, stops, zupt_sigma_mps=p.zupt_sigma_mps)
    if platform == "auto" or (platform in WHEELED and C_vb is None):
        zu = zu_rows if platform in WHEELED else None
        # a coarse pass (IMU at about 25 Hz, 1 s covariance steps, as the GPS noise passes) serves
        # the travel direction, a degree-level figure, at a tenth of the cost of a full one; over the
        # stretch the GPS noise passes cover (`gps_noise_span_s` after the heading search): the
        # direction and the trial's mean NIS settle well within it, and an hour costs a quarter
        after = info["yaw_search"]["t_s"][1] if "yaw_search" in info else None
        td_, gd, ad, fixes_c, _, rate_c = pass_window(imu.t, imu.gyro, imu.acc, fixes, after, p.gps_noise_span_s,
                                                      COARSE_RATE_HZ)
        coarse = dataclasses.replace(cfg, cov_step=max(1, int(round(rate_c))))
        first = run_insgps(td_, gd, ad, fixes_c, init, coarse, store_rts=False, extra=rows_within(zu, td_[-1]))
        gap_s = max(1.0, 1.5 * float(np.median(np.diff(fixes.t_s)))) if fixes.t_s.size > 1 else 1.0
        # slow platforms count too: a sample's travel direction is good to sd_v / speed rad, so the
        # floor is a multiple of the run's horizontal velocity SD at its covariance epochs next to
        # fixes (the samples travel_direction keeps), not a fixed speed
        t_ep = first.t_s[first.ep_idx]
        j = np.clip(np.searchsorted(fixes.t_s, t_ep, side="right") - 1, 0, None)
        near = np.abs(t_ep - fixes.t_s[j]) <= gap_s
        var_h = first.ep_P[:, 3, 3] + first.ep_P[:, 4, 4]
        vel_sd = float(np.sqrt(np.median(var_h[near] if near.any() else var_h)))
        ep = epoch_of(first, np.arange(first.t_s.size))
        att_sd = np.sqrt(np.column_stack([0.5 * (first.ep_P[ep, 6, 6] + first.ep_P[ep, 7, 7]), first.ep_P[ep, 8, 8]]))
        td = travel_direction(first.t_s, first.nav[:, 3:6], first.C_nb, fix_t_s=fixes.t_s, max_fix_gap_s=gap_s,
                              min_speed_mps=p.travel_min_speed_sd * vel_sd, att_sd_rad=att_sd)
        if td is not None:
            if C_vb is None:
                C_vb = td.C_vb
                out["mounting"] = {"source": "travel direction of a first forward run", **td.summary()}
            else:
                out["travel_direction"] = td.summary()
        if platform == "auto":
            trial = None if td is None else nhc_trial((td_, gd, ad), fixes_c, init, coarse, stops, td.C_vb, p, info,
                                                      _mounting_sd_deg(td, p.mounting_sigma_assumed_deg))
            platform = "car" if trial is not None and trial["wheeled"] else "pedestrian"
            decided = (f"auto: {trial['why']}" if trial is not None
                       else "auto: too little motion to tell (no constraint of a wheeled vehicle)")
            if trial is not None and trial["wheeled"] and mounting is None and "misalignment_rad" in trial:
                C_vb, refined = refined_mounting(td.C_vb, trial["misalignment_rad"], trial["misalignment_sd_rad"])
                out["mounting"] = {"source": "travel direction of a first forward run, turned by the residual "
                                             "misalignment the trial pass found", **refined, "travel_direction": td.summary()}
    out["platform"] = platform
    out["decided_by"] = decided
    info["constraints"] = out
    parts = []
    if platform in WHEELED or platform == "pedestrian":
        zu = zu_rows
        if zu is not None and platform == "pedestrian":
            zu = zu.select(zu.kind == Kind.ZUPT)  # a standing walker still turns: no ZARU
        parts.append(zu)
    if platform in WHEELED:
        if C_vb is None:
            C_vb = np.eye(3)
            out["mounting"] = {"source": "assumed aligned (too little motion to estimate it)", "mounting_rpy_deg": [0.0, 0.0, 0.0]}
            sd_deg = p.mounting_sigma_assumed_deg
        elif mounting is not None:
            sd_deg = p.mounting_sigma_given_deg
        elif "sigma_py_deg" in out["mounting"]:  # refined by the trial pass: its misalignment's SD at its end
            sd_deg = max(p.mounting_sigma_given_deg, *out["mounting"]["sigma_py_deg"])
        else:  # the SDs carry the first run's own attitude error (`travel_direction`)
            sd_deg = _mounting_sd_deg(td, p.mounting_sigma_given_deg)
        out["mounting"]["residual_prior_sigma_deg"] = round(float(sd_deg), 3)
        # a wheeled vehicle's stops hold its attitude (its ZARU rows): there the fixes after a stop's first
        # carry no yaw x lever-arm second-order variance (`fusion.lever_arm.second_order_shares`)
        cfg = dataclasses.replace(cfg, C_vb=np.asarray(C_vb, dtype=float),
                                  layout=StateLayout((*cfg.layout.blocks, mounting_block(np.radians(sd_deg), p.nhc_axle_sigma_m))),
                                  rest_intervals_s=np.asarray(stops.intervals_s, dtype=float).reshape(-1, 2))
        after = nhc_start_s(info)
        out["nhc_from_s"] = None if not np.isfinite(after) else round(float(after) + session.t0_s, 2)
        parts.append(nhc_measurements(imu.t, stops, rate_hz=p.nhc_rate_hz, sigma_mps=p.nhc_sigma_mps, after_s=after))
    # every platform's stops: the IMU's white noise inside each as it integrates over a second
    # (`stop_noise_factors`): the whole log's figures are the moving vehicle's vibration (the default
    # figures are the floor). Without ZUPT rows (platform none) it is all that keeps the velocity
    # variance at a stop from growing with the moving car's vibration between fixes.
    q_stops = stop_noise_factors(imu.t, imu.gyro, imu.acc, stops.intervals_s, cfg.q, imu.rate_hz, floors=(
        DriveSmoothParams.model_fields["acc_noise_mg"].default * 1e-3 * G0_MPS2,
        DriveSmoothParams.model_fields["gyro_noise_dps"].default * DEG)) if p.stop_noise == "measured" else ()
    if len(q_stops):
        cfg = dataclasses.replace(cfg, q_stops=q_stops)
        out["stop_noise_factors"] = [[round(float(v), 3) for v in r[2:]] for r in q_stops]
        still = q_stops[np.all(q_stops[:, 2:] < 1.0, axis=1), :2]
        if platform not in WHEELED and len(still):
            # a still stop (`stop_noise_factors`: its IMU quieter than the run's on both sensors) holds the
            # attitude as a wheeled vehicle's does: the yaw x lever-arm second-order term is one constant there
            cfg = dataclasses.replace(cfg, rest_intervals_s=still)
    if platform == "pedestrian":  # after the stops' own noise: that compares each stop with the log's figures
        cfg = step_acc_noise(cfg, imu, stops.intervals_s, info, out)
    if platform in WHEELED and odo is not None and p.use_odometry and odo.t_s.size > 1:
        parts.append(odometer_measurements(odo.t_s, odo.speed_mps, rate_hz=p.odometer_rate_hz, sigma_mps=p.odometer_sigma_mps))
        cfg = dataclasses.replace(cfg, layout=StateLayout((*cfg.layout.blocks, odometer_block(p.odometer_scale_sigma))))
        out["odometry"] = {"samples": int(odo.t_s.size), "scale_prior_sigma": p.odometer_scale_sigma}
    parts = [m for m in parts if m is not None and len(m)]
    return cfg, (Measurements.merge(*parts) if parts else None), np.asarray(stops.intervals_s, dtype=float).reshape(-1, 2)


def step_acc_noise(cfg: FilterConfig, imu: _Imu, stop_intervals_s, info: dict, out: dict) -> FilterConfig:
    """A walker's accelerometer white noise while walking: the RMS of its first differences outside the
    stops (`imu_noise.measured_white_noise`, robust=False), where larger than the robust figure the log
    measured; a figure the pipeline or the session gave is kept. Every step lands as a g-level impact a
    few samples long; the robust scale treats those as bumps to ignore (right on a car, whose bumps are
    rare), but a walker takes one at every step, and the strapdown integration of a transient it samples
    a handful of times is off by about the sample-to-sample change it cannot resolve: noise the velocity
    feels at every step. With the sensor floor alone (the shared walk: 2.4 mg robust, 15 mg RMS while
    walking) the filter held its vertical velocity to 2 cm/s while it was 5-10 cm/s off, its forward and
    backward runs apart at 29 % of the epochs (on the vertical velocity), and the GPS noise matching put
    the excess on the fixes (their height SD raised 8.8x over the receiver's 1 cm). The rule (RMS instead
    of MAD, on a walker, while walking) was chosen after seeing the walk; it adds no constant.

    Inside the stops the accelerometer's PSD stays what it was: each `FilterConfig.q_stops` row's acc
    factor (relative to cfg.q) is rescaled to the new q[0] (the stop's own noise,
    `imu_noise.stop_noise_factors`, unchanged), and a stop without a row gets one holding the log's
    figure; one row per stop (the kernel adds the rows' factors)."""
    src = info.get("imu_noise", {}).get("acc_noise_mg", {}).get("source", "")
    stops = np.asarray(stop_intervals_s, dtype=float).reshape(-1, 2)
    moving = ~in_intervals(imu.t, stops, closed=True)
    if src in ("pipeline", "session") or moving.sum() < 2:
        return cfg
    sd = measured_white_noise(imu.acc[moving], robust=False)
    q = np.asarray(cfg.q, dtype=float)
    q_acc = sd**2 / imu.rate_hz
    if not q_acc > q[0]:
        return cfg
    out["step_acc_noise_mg"] = round(sd / (1e-3 * G0_MPS2), 3)
    back = q[0] / q_acc
    rows = np.array(cfg.q_stops if cfg.q_stops is not None else (), dtype=float).reshape(-1, 4)
    rows[:, 2] *= back
    bare = stops[[not np.any((rows[:, 0] == a) & (rows[:, 1] == b)) for a, b in stops]].reshape(-1, 2)
    rows = np.concatenate([rows, np.column_stack([bare, np.full(len(bare), back), np.ones(len(bare))])])
    return dataclasses.replace(cfg, q=np.concatenate([[q_acc], q[1:]]), q_stops=rows[np.argsort(rows[:, 0], kind="stable")])


def lever_arm_states(p: DriveSmoothParams, fixes: GpsFixes, init: InitialState, cfg: FilterConfig, info: dict) -> FilterConfig:
    """`cfg` with the lever-arm correction states (`fusion.layout.lever_arm_block`) when
    `fusion.lever_arm.lever_arm_wanted` says so for these fixes (in `lever_axes`: the vehicle's, or
    a level IMU's own): their median horizontal SD, and the span of their course (reported
    velocities, else differenced positions: `timeoffset.gps_velocity`) above ten times the
    velocity SD (a course good to about 6 deg). Records the decision in info["lever_arm"]."""
    sd = fixes.sigma_pos_ned_m
    sig_h = float(np.median(np.sqrt(0.5 * (sd[:, 0] ** 2 + sd[:, 1] ** 2)))) if sd.size else np.inf
    vel = gps_velocity(fixes.t_s, fixes.lla, fixes.vel_ned_mps) if fixes.t_s.size > 1 else fixes.vel_ned_mps
    sig_v = float(np.median(fixes.sigma_vel_mps[:, :2])) if fixes.sigma_vel_mps.size else p.gps_sigma_vel_mps
    span = course_span_deg(vel, 10.0 * sig_v) if fixes.t_s.size > 1 else 0.0
    axes = lever_axes(cfg.layout.offset(Block.MOUNTING) >= 0, init.C_nb)  # cfg.C_vb: the vehicle's, else identity
    on, why = lever_arm_wanted(p.lever_arm, axes, sig_h, span, p.lever_arm_sigma_m, p.lever_arm_min_turn_deg)
    info["lever_arm"] = {"decided_by": why, "stated_m": [float(v) for v in cfg.lever_arm_b_m],
                         "C_vb": np.asarray(cfg.C_vb, dtype=float).tolist()}
    if not on:
        return cfg
    return dataclasses.replace(cfg, layout=StateLayout((*cfg.layout.blocks, lever_arm_block(p.lever_arm_sigma_m))))


def at_stated_lever_arm(sol: Solution, cfg: FilterConfig) -> Solution:
    """`sol` at the point the stated lever arm refers to (`fusion.lever_arm.at_stated_point`) when
    the run estimated a correction to it; unchanged otherwise."""
    dl_b = lever_correction_b(sol.bias, cfg.layout, cfg.C_vb)
    if dl_b is None:
        return sol
    return Solution(sol.name, sol.idx, at_stated_point(sol.nav, sol.C_nb, dl_b), sol.C_nb, sol.P9, sol.bias)


def considered_fix_error(p: DriveSmoothParams, fixes: GpsFixes, info: dict) -> np.ndarray | None:
    """(3,) variance (m^2, NED) of the fixes' error the filter does not model, for the axes whose SDs
    come from the pipeline's stated accuracy (the log gives none): `gps_sigma_h_m` / `gps_sigma_v_m`
    less the matched white SD and the error states' SD (`fusion.gps_error.unmodelled_error_sd_m`).
    None when nothing is left or the receiver states its own SDs (those are its whole error).
    Records it in `info["gps_considered_error"]`."""
    white = median_sigmas(fixes)
    gm = info.get("gps_error_states", {})
    sd = unmodelled_error_sd_m([p.gps_sigma_h_m, p.gps_sigma_v_m], white[:2],
                               [gm.get("sigma_h_m", 0.0), gm.get("sigma_v_m", 0.0)])
    sd = np.where(np.asarray(fixes.from_receiver[:2], dtype=bool), 0.0, sd)
    if not np.any(sd > 0):
        return None
    info["gps_considered_error"] = {
        "method": "the log gives no position SDs: the part of the stated accuracy (gps_sigma_h_m, gps_sigma_v_m) that "
                  "the fix-to-fix scatter does not show is common to neighbouring fixes; it is added to every reported "
                  "position SD and moves no estimate (fusion.gps_error.unmodelled_error_sd_m)",
        "sigma_h_m": round(float(sd[0]), 4), "sigma_v_m": round(float(sd[1]), 4),
        "white_h_m": round(float(white[0]), 3), "white_v_m": round(float(white[1]), 3),
        "stated_h_m": float(p.gps_sigma_h_m), "stated_v_m": float(p.gps_sigma_v_m)}
    return np.array([sd[0], sd[0], sd[1]]) ** 2


def considered_velocity(pos_var_ned_m2, fixes: GpsFixes, fwd: FilterRun, info: dict):
    """(sigma_c, tau_s) (3,) NED and the fix interval (s) for `fusion.gps_error.unmodelled_velocity_var`:
    the SD-less fixes' common error (`considered_fix_error`), the least time constant the matching
    allows it (`matched_tau_bound_s`, over the forward run's median span, `velocity_span_s`), and the
    least span a slope from the fixes can have; None without a considered error. Records the span and
    the bound in `info["gps_considered_error"]["velocity"]`."""
    if pos_var_ned_m2 is None:
        return None
    sc = np.sqrt(pos_var_ned_m2)
    span = np.median(velocity_span_s(fwd.ep_P[:, :9, :9], two_sided=False), axis=0)
    tau = matched_tau_bound_s(sc, median_sigmas(fixes)[[0, 0, 1]], span)
    info["gps_considered_error"]["velocity"] = {
        "method": "the common error's slope over the span a solution takes its velocity from, its time constant at the "
                  "least the matching allows; added to every reported velocity SD, moves no estimate "
                  "(fusion.gps_error.unmodelled_velocity_var)",
        "forward_span_h_s": round(float(span[0]), 2), "forward_span_v_s": round(float(span[2]), 2),
        "tau_min_h_s": round(float(tau[0]), 1), "tau_min_v_s": round(float(tau[2]), 1)}
    return sc, tau, float(np.median(np.diff(fixes.t_s))) if fixes.t_s.size > 1 else 0.0


def with_unmodelled_errors(sol: Solution, pos_var_ned_m2, vel_cov_b, fix_vel=None, *, owned: bool = False) -> Solution:
    """`sol` with errors no state models added to its covariance (no estimate moves):
    pos_var_ned_m2 (3,) or None, the SD-less fixes' common error (`considered_fix_error`),
    to the position variances, and with fix_vel (`considered_velocity`) its slope over the span
    the solution takes its velocity from to the velocity variances (`fusion.gps_error.
    unmodelled_velocity_var`, the span from sol.P9 before any of this); vel_cov_b (K, 3, 3) at
    sol.idx or None, the IMU's vibration velocity (`fusion.nav_errors.vibration_velocity_cov_b`:
    the INS velocity carries the mount's shake, a few mm/s on a car), as C_nb S_b C_nb^T to the
    velocity covariance. On a copy of sol.P9, unless `owned`: the caller's sol.P9 is its own array,
    held by nothing else, and is added to in place (`owned_covariances`; the drive hour's P9 is
    23 MB per solution)."""
    if pos_var_ned_m2 is None and vel_cov_b is None:
        return sol
    P9 = sol.P9 if owned else sol.P9.copy()
    if fix_vel is not None:  # the span from sol.P9 as the solution made it: before anything is added
        span = np.maximum(velocity_span_s(sol.P9, two_sided=sol.name not in ("forward", "backward")), fix_vel[2])
        P9[:, (3, 4, 5), (3, 4, 5)] += unmodelled_velocity_var(fix_vel[0], fix_vel[1], span)
    if pos_var_ned_m2 is not None:
        P9[:, (0, 1, 2), (0, 1, 2)] += pos_var_ned_m2
    if vel_cov_b is not None:
        P9[:, 3:6, 3:6] += sol.C_nb @ vel_cov_b @ np.swapaxes(sol.C_nb, -1, -2)
    return Solution(sol.name, sol.idx, sol.nav, sol.C_nb, P9, sol.bias)


def owned_covariances(sols: dict) -> dict:
    """{name: whether the solution's P9 is an array of its own (no view of a run's arrays) that no
    other solution of `sols` shares} (`smoothed` is the `rts` or `two_filter` solution renamed: they
    share theirs)."""
    return {k: v.P9.base is None and sum(w.P9 is v.P9 for w in sols.values()) == 1 for k, v in sols.items()}


def nhc_start_s(info: dict) -> float:
    """Session time from which NHC rows apply: a yaw the search had to pick over the course may be
    tens of degrees off until the GPS has turned it, so NHC waits for the end of the search then
    (a confirmed course does not: -inf)."""
    ysr = info.get("yaw_search")
    return ysr["t_s"][1] if ysr is not None and not ysr["prior_kept"] else -np.inf


def nhc_trial(imu_coarse, fixes: GpsFixes, init: InitialState, coarse: FilterConfig, stops, C_vb, p: DriveSmoothParams,
              info: dict, sigma_deg: float | None = None) -> dict | None:
    """Is the platform wheeled? A coarse forward pass with the non-holonomic constraint in the
    travel direction's axes (and the residual-misalignment states): on wheels the constraint holds
    within its SD, so its rows' mean NIS stays at or below their d.o.f. (2); a walker's sway and
    bounce break it (the shared walk: 4.3, 11 % rejected; a car, a slow rover: 0.2-0.4). The
    steadiness of the travel direction cannot tell them apart at walking speeds (0.89-0.91 for
    both). sigma_deg: the prior SD of the residual misalignment (the travel direction's own SD).
    Returns {"wheeled", "why", "nhc": the rows' figures, "misalignment_rad", "misalignment_sd_rad":
    [pitch, yaw] at the pass's end} or None without NHC rows."""
    t, g, a = imu_coarse
    after = nhc_start_s(info)
    # rows at 1 Hz: the mean of a few thousand NIS values decides (to about 2/sqrt(n)), at a tenth of the cost
    rows = nhc_measurements(t, stops, rate_hz=min(p.nhc_rate_hz, 1.0), sigma_mps=p.nhc_sigma_mps, after_s=after)
    if rows is None or not len(rows):
        return None
    cfg = dataclasses.replace(coarse, C_vb=np.asarray(C_vb, dtype=float), layout=StateLayout(
        (*coarse.layout.blocks, mounting_block(np.radians(sigma_deg or p.mounting_sigma_assumed_deg), p.nhc_axle_sigma_m))),
        nominal_idx=ENDS_ONLY)  # the rows' NIS and the end state are read, not the nominal history
    run = run_insgps(t, g, a, fixes, init, cfg, store_rts=False, extra=rows)
    nhc = constraint_summary(run).get("nhc")
    if nhc is None or nhc["nis"] is None or not nhc["rows"]:
        return None
    mean, rej = float(nhc["nis"]["mean"]), nhc["rejected"] / nhc["rows"]
    wheeled = mean <= p.auto_nhc_nis_max and rej <= p.auto_nhc_reject_max
    m, sd = _block_at_end(run, Block.MOUNTING, 2)
    return {"wheeled": bool(wheeled), "nhc": {"mean_nis": round(mean, 3), "rejected_fraction": round(rej, 4)},
            "misalignment_rad": m, "misalignment_sd_rad": sd,
            "why": (f"non-holonomic constraint on a trial pass: mean NIS {mean:.2f} (at most {p.auto_nhc_nis_max:g}), "
                    f"{100 * rej:.1f} % rejected (at most {100 * p.auto_nhc_reject_max:g} %)")}


def _mounting_sd_deg(td, floor_deg: float) -> float:
    """Prior SD (deg) of the residual misalignment about a travel-direction mounting: its larger
    SD (pitch or yaw), at least floor_deg."""
    return max(floor_deg, *(v for v in (td.sigma_pitch_deg, td.sigma_yaw_deg) if np.isfinite(v)))


def constraint_summary(run: FilterRun) -> dict:
    """Per constraint kind of a run: rows, rejected, mean NIS of the accepted ones against its band."""
    out = {}
    meas = run.measurements
    for kind, name in ((Kind.NHC, "nhc"), (Kind.ZUPT, "zupt"), (Kind.ZARU, "zaru"), (Kind.ODOMETER, "odometer")):
        r = meas.kind == kind
        if not r.any():
            continue
        ok = r & np.isfinite(run.ev_nis)
        acc = ok & run.ev_accepted
        out[name] = {"rows": int(ok.sum()), "rejected": int((ok & ~run.ev_accepted).sum()),
                     "nis": nis_band(run.ev_nis[acc], run.ev_nu[acc])}
    m, sd = _block_at_end(run, Block.MOUNTING, 3)
    if m is not None:
        out["residual_misalignment_deg"] = {"pitch_yaw": [round(float(v), 3) for v in np.degrees(m[:2])],
                                            "sigma": [round(float(v), 3) for v in np.degrees(sd[:2])]}
        out["nhc_point_behind_imu_m"] = {"estimate": round(float(m[2]), 3), "sigma": round(float(sd[2]), 3)}
    m, sd = _block_at_end(run, Block.ODOMETER, 1)
    if m is not None:
        out["odometer_scale_error"] = {"estimate": round(float(m[0]), 5), "sigma": round(float(sd[0]), 5)}
    return out


def _block_at_end(run: FilterRun, block: Block, size: int):
    """(estimate, SD) of an extra block at the run's end in its own direction (where it has seen
    the whole log), or (None, None) when the run has no such block."""
    o = run.layout.offset(block)
    if o < 0:
        return None, None
    j = 0 if run.backward else -1
    return run.extra(block)[j], np.sqrt(np.diagonal(run.ep_P[j])[o:o + size])


def smooth(fwd: FilterRun, bwd: FilterRun, out_idx, outages_s, p: DriveSmoothParams, names, sols: dict, C_vb=None):
    """The requested solutions from the forward and backward runs (`sols` may hold `rts` already);
    returns (solutions, flag, forward/backward NIS) at out_idx. C_vb: the runs' mounting (the
    lever-arm states' axes in the disagreement test)."""
    wanted = set(names) | ({p.smoother} if "smoothed" in names else set())
    if "two_filter" in wanted:
        sols["two_filter"], flag, nis = smoothing.two_filter(fwd, bwd, out_idx, flag_probability=p.flag_probability, C_vb=C_vb)
    else:
        flag, nis = smoothing.disagreement(fwd, bwd, out_idx, flag_probability=p.flag_probability, C_vb=C_vb)
    if "forward" in wanted:
        sols["forward"] = smoothing.filter_solution(fwd, out_idx, "forward")
    if "backward" in wanted:
        sols["backward"] = smoothing.filter_solution(bwd, out_idx, "backward")
    if "simplified" in wanted:
        sols["simplified"] = smoothing.simplified(fwd, bwd, out_idx, outages_s)
    if "smoothed" in wanted:
        sols["smoothed"] = sols[p.smoother].renamed("smoothed")
    return {k: v for k, v in sols.items() if k in names}, flag, nis


def in_vehicle_axes(sol: Solution, C_vb, run: FilterRun, attitude_only: bool = False) -> Solution:
    """A solution's attitude in the vehicle's axes when the run applied a mounting C_vb (and its
    residual misalignment states, `fusion.mounting.vehicle_attitude`, their SD that of the forward
    run's end, the unobserved roll the states' prior SD); the IMU's otherwise. Targets keep the
    IMU's attitude: the rangefinders sit on the IMU.
    attitude_only: sol.P9 is passed on as it is, for checks that read the attitude only
    (`mounting_check`): the drive hour's P9 is 23 MB, not copied (`trajectory_rows` passes the
    attitude block to its table instead, `vehicle_axes_attitude`)."""
    if C_vb is None:
        return sol
    C_nv, P_att = vehicle_axes_attitude(sol, C_vb, run, attitude_only)
    if attitude_only:
        return Solution(sol.name, sol.idx, sol.nav, C_nv, sol.P9, sol.bias)
    P9 = np.array(sol.P9, copy=True)
    P9[:, 6:9, 6:9] = P_att
    return Solution(sol.name, sol.idx, sol.nav, C_nv, P9, sol.bias)


def vehicle_axes_attitude(sol: Solution, C_vb, run: FilterRun, attitude_only: bool = False):
    """(C_nv (K, 3, 3), P_att (K, 3, 3) rad^2): a solution's attitude and its NED attitude-error
    covariance in the vehicle's axes (`in_vehicle_axes`, which see), for a mounting C_vb;
    attitude_only: P_att None (not computed)."""
    o = run.layout.offset(Block.MOUNTING)
    m = sol.bias[:, 6 + o - N_NAV: 6 + o - N_NAV + 2] if (o >= 0 and sol.bias is not None) else None
    _, sd = _block_at_end(run, Block.MOUNTING, 2)
    prior = next((b for b in run.layout.blocks if b.block == Block.MOUNTING), None)
    roll_sd = float(np.sqrt(prior.P0[0, 0])) if prior is not None else 0.0
    return vehicle_attitude(sol.C_nb, None if attitude_only else sol.P9[:, 6:9, 6:9], C_vb, m, sd, roll_sd)


def mounting_check(sols: dict, t_s, p: DriveSmoothParams, axes=lambda s: s, stated: bool = False) -> dict | None:
    """Course over ground minus yaw of the best solution while moving (`fusion.mounting`), its
    attitude in the axes the output reports (`axes`: `in_vehicle_axes` when a mounting applies);
    stated: the session gives `[imu] mounting_rpy_deg` (the sentence then says check it, not set it)."""
    best = next((n for n in ("smoothed", "rts", "two_filter", "forward") if n in sols), None)
    if p.mounting_check_deg <= 0 or best is None:
        return None
    s = axes(sols[best])
    chk = course_minus_yaw(t_s[s.idx], s.nav[:, 3:6], dcm_to_euler(s.C_nb)[2], p.mounting_min_speed_mps)
    warn = mounting_off(chk, p.mounting_check_deg)
    out = {"solution": best, "threshold_deg": p.mounting_check_deg, "warning": warn,
           **(chk.summary() if chk is not None else {"moving_s": 0.0})}
    if warn:  # the verdict's own sentence (printed once)
        out["message"] = mounting_text(chk.median_deg, chk.spread_deg, chk.moving_s, chk.min_speed_mps, stated=stated)
    return out


def process_drive(session: Session, p: DriveSmoothParams, ctx: RunContext | None = None,
                  names=("forward", "backward", "smoothed"), extra_idx=None) -> DriveResult:
    """Align, filter forward and backward, smooth; `names` picks the solutions computed.

    Solutions are evaluated at the output rate plus the IMU sample indices `extra_idx` (e.g.
    range epochs for targeting); `DriveResult.out_idx` lists them all, sorted.
    """
    stage = ctx.stage if ctx is not None else (lambda name: contextlib.nullcontext())
    imu = _Imu(*(np.ascontiguousarray(a, dtype=float) for a in (session.imu.t_s, session.imu.gyro_b_rps, session.imu.acc_b_mps2)))
    nz = drive_imu_noise(p, session)
    sig = initial_sigmas(p, nz)
    fixes = fixes_from_session(session, p)
    cfg = float_offset_states(p, fixes, filter_config(p, nz, session.meta.lever_arm_b_m, imu.rate_hz))
    with stage("alignment"):
        init, info = align(imu, session, p, fixes, cfg, sig, nz)
    info["gps_vel_latency_s"] = {"value": fixes.vel_latency_s,
                                 "source": "pipeline" if p.gps_vel_latency_s is not None else
                                 ("the filter's velocity clock state" if p.gps_clock_sigma_s > 0 else "the log's positions")}
    with stage("constraints"):
        cfg, extra, stop_intervals_s = motion_constraints(imu, session, p, fixes, init, cfg, info)
        # at the stops velocity rows (GPS, ZUPT) do not correct yaw, unobservable there (`fusion.lever_arm.yaw_held_rows`)
        cfg = dataclasses.replace(cfg, standstill_intervals_s=stop_intervals_s)
        cfg = lever_arm_states(p, fixes, init, cfg, info)
    with stage("gps_noise"):
        fixes, cfg = tune_gps(imu, p, fixes, init, cfg, info, session.t0_s, extra, stop_intervals_s)
    out_idx = output_indices(imu.t.size, 1 if p.output_rate_hz <= 0 else max(1, int(round(imu.rate_hz / p.output_rate_hz))))
    if extra_idx is not None and len(extra_idx):
        out_idx = np.union1d(out_idx, np.asarray(extra_idx, dtype=np.int64))
    need_rts = "rts" in names or ("smoothed" in names and p.smoother == "rts")
    sols = {}
    cfg_out = dataclasses.replace(cfg, nominal_idx=out_idx)  # the runs' nominal at the output rows only
    spent = ()
    # With a second CPU, work that does not depend on the runs goes to a helper thread: the vibration
    # covariance (during the forward run) and the RTS smoother (during the backward run; both numba
    # kernels release the GIL). Each task reads arrays nobody writes while it runs and returns new
    # ones: the same bits as in sequence. The backward run then takes fresh memory for its history
    # (the RTS smoother is still reading the forward one); on one CPU it writes into the spent history.
    with contextlib.ExitStack() as stack:
        helper = stack.enter_context(ThreadPoolExecutor(1, thread_name_prefix="tpos-drive")) if spare_cpu() else None
        vib = helper.submit(vibration_velocity_cov_b, imu.t, imu.acc, out_idx) if helper is not None else None
        with stage("forward"):
            fwd = run_insgps(imu.t, imu.gyro, imu.acc, fixes, init, cfg_out, store_rts=need_rts, extra=extra)
        rts_sol = None
        if need_rts and helper is not None:
            rts_sol = helper.submit(_timed, stage, "smoothing_rts_beside", smoothing.rts, fwd, out_idx)  # beside backward
            fwd = dataclasses.replace(fwd, ep_Phi=None, ep_phi_extra=None, ep_Ppred=None)  # the helper holds its own
        elif need_rts:
            with stage("smoothing_rts"):
                sols["rts"] = smoothing.rts(fwd, out_idx)
                # drop the RTS history before the backward run: it is the largest array of the run;
                # the backward run writes its own history into that memory (no fresh pages to touch)
                spent = (fwd.ep_Phi, fwd.ep_Ppred)
                fwd = dataclasses.replace(fwd, ep_Phi=None, ep_phi_extra=None, ep_Ppred=None)
        with stage("backward"):
            bwd = run_insgps(imu.t, imu.gyro, imu.acc, fixes, backward_start(fwd, initial_covariance(sig)), cfg_out,
                             backward=True, extra=extra, reuse=spent)
            del spent
        if rts_sol is not None:
            sols["rts"] = rts_sol.result()
        S_vib_b = vib.result() if vib is not None else None
    with stage("smoothing"):
        outages = fix_outages(fixes.t_s, imu.t[-1], p.outage_min_s)
        sols, flag, nis = smooth(fwd, bwd, out_idx, outages, p, names, sols, cfg.C_vb)
    considered = considered_fix_error(p, fixes, info)
    fix_vel = considered_velocity(considered, fixes, fwd, info)
    if S_vib_b is None:
        S_vib_b = vibration_velocity_cov_b(imu.t, imu.acc, out_idx)
    owned = owned_covariances(sols)  # added to in place: the copies were the process's peak (+70 MB on the hour)
    sols = {k: with_unmodelled_errors(at_stated_lever_arm(v, cfg), considered, S_vib_b[np.searchsorted(out_idx, v.idx)],
                                      fix_vel, owned=owned[k])
            for k, v in sols.items()}
    C_vb = cfg.C_vb if cfg.layout.offset(Block.MOUNTING) >= 0 else None
    return DriveResult(imu.t, out_idx, fwd, bwd, sols, flag, nis, outages, fixes, info,
                       mounting_check(sols, imu.t, p, lambda s: in_vehicle_axes(s, C_vb, fwd, attitude_only=True),
                                      stated=session.meta.mounting_rpy_deg is not None), C_vb, stop_intervals_s)


def _timed(stage, name: str, fn, *args):
    """fn(*args) timed as stage `name` (in a helper thread: the stage overlaps the caller's)."""
    with stage(name):
        return fn(*args)


def nis_band(nis, innovation) -> dict | None:
    """Mean NIS of the applied fixes against its two-sided 95% band (`consistency.mean_chi2`, each fix
    with its own d.o.f., the finite components of its innovation; the verdict's check is the same
    test at 99.9 % with the gate's truncation, `quality.nis_findings`)."""
    if len(nis) == 0:
        return None
    dof = np.isfinite(innovation).sum(axis=1).astype(float)
    m = mean_chi2(nis, dof, prob=0.95)
    return {"mean": round(m.mean, 3), "dof": round(float(np.mean(dof)), 2), "band95": [round(m.lo, 3), round(m.hi, 3)],
            "inside": m.inside, "fixes": int(len(nis))}


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


def geolocate_shots(session: Session, sol: Solution, epochs, sigma_range_m: float) -> pd.DataFrame:
    """Targets of the shots from a solution at the range epochs (paper 001 with `targeting.geolocate`).

    Each range epoch is geolocated with the solution's position and attitude covariances; a
    shot's target is the mean over its epochs. Its covariance is the mean of the epochs'
    covariances, not divided by their number: within a shot of a few seconds the trajectory
    errors that dominate are the same at every epoch (only the range noise would average out).
    """
    import pandas as pd  # here, as targeting's: a drive without shots runs without pandas

    from tpos_cli.targeting import geolocate

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


def innovations_table(res: DriveResult, t0_s: float) -> Columns:
    """`innovations.parquet`: one row per fix, run and kind: t, solution (forward | backward), kind
    (gps_pos | gps_vel), nis, dof, accepted, and the residual components nu_0..nu_2 (NED m or m/s);
    sorted by solution, kind and t (stable: rows of equal keys keep the order of the runs)."""
    parts = []
    for run_name in ("forward", "backward"):
        gi = res.innovations(run_name)
        for j, kind in enumerate(GPS_KINDS):
            m = np.isfinite(gi.nis[:, j])
            nu = gi.innovation[m, 3 * j: 3 * j + 3]
            n = int(m.sum())
            parts.append(Columns({
                "t": res.fixes.t_s[m] + t0_s, "solution": np.full(n, run_name, dtype=object),
                "kind": np.full(n, kind, dtype=object), "nis": gi.nis[m, j],
                "dof": np.isfinite(nu).sum(axis=1).astype(np.int64), "accepted": gi.accepted[m, j],
                "nu_0": nu[:, 0], "nu_1": nu[:, 1], "nu_2": nu[:, 2]}, n))
    inn = concat(parts)
    sol_code = np.searchsorted(np.array(["backward", "forward"]), inn["solution"].astype(str))
    kind_code = np.searchsorted(np.array(sorted(GPS_KINDS)), inn["kind"].astype(str))
    return inn.take(np.lexsort((inn["t"], kind_code, sol_code)))  # lexsort is stable


def drive_summary(res: DriveResult, p: DriveSmoothParams, names, t0_s: float, ctx: RunContext) -> dict:
    """`summary.json` results: alignment, fixes and rejections, forward NIS against its band,
    outages, flagged fraction, mounting check; counts and the mounting warning go to ctx."""
    ctx.count("gps_fixes_used", int(res.fixes.t_s.size))
    if res.fixes.n_wild:
        ctx.count("gps_fixes_wild", res.fixes.n_wild)
        ctx.warn(f"{res.fixes.n_wild} GPS fix(es) far from where their neighbours place them were left out (fusion.screening)")
    if res.fixes.n_float:
        ctx.count("gps_fixes_float", res.fixes.n_float)
        ctx.count("gps_float_stretches", int(res.fixes.float_intervals_s.shape[0]))
    rejected, reacquired = {}, {}
    for run_name in ("forward", "backward"):
        gi = res.innovations(run_name)
        for j, kind in enumerate(GPS_KINDS):
            n_rej = int(np.sum(~gi.accepted[:, j] & np.isfinite(gi.nis[:, j])))
            rejected[f"{run_name}_{kind}"] = n_rej
            ctx.count(f"{kind}_rejected_{run_name}", n_rej)
        for kind, r in gps_reacquisitions(getattr(res, run_name)).items():
            reacquired[f"{run_name}_{kind}"] = r
            ctx.count(f"{kind}_reacquired_{run_name}", r["count"])
            ctx.count(f"{kind}_downweighted_{run_name}", r["downweighted"])
    ctx.count("flagged_rows", int(res.flag.sum()))
    ce = res.info.get("gps_considered_error")
    if ce is not None:
        ctx.warn(f"gps: the log gives no position SDs, so the reported position and velocity SDs carry the pipeline's stated accuracy "
                 f"(gps_sigma_h_m = {p.gps_sigma_h_m:g} m, gps_sigma_v_m = {p.gps_sigma_v_m:g} m) beyond the fixes' "
                 f"{ce['white_h_m']:g} m fix-to-fix scatter; set them to your receiver's accuracy "
                 f"(--set drive_smooth.gps_sigma_h_m=...)")
    mounting = dict(res.mounting) if res.mounting is not None else None
    if mounting is not None and "message" in mounting:
        ctx.warn(mounting.pop("message"))  # into summary.json warnings, once
    gi = res.innovations("forward")
    standing = _at_stops(res.fixes.t_s, res.stop_intervals_s)
    constraints = _with_stop_intervals(res.info.get("constraints", {}), res.stop_intervals_s, t0_s)
    mean_nis, nis_check = {}, {}
    for j, kind in enumerate(GPS_KINDS):
        used = gi.accepted[:, j]
        a = gi.nis[used, j]
        mean_nis[kind] = float(np.mean(a)) if a.size else None
        nis_check[kind] = nis_band(a, gi.innovation[used, 3 * j: 3 * j + 3])
        if nis_check[kind] is not None and standing is not None and (used & standing).any() and (used & ~standing).any():
            # the same check on the fixes at stops and while moving: one noise figure serves both, and the mean of
            # the whole run is a mixture whose value moves with the share of each (notes diag13.md)
            nis_check[kind]["by_regime"] = {name: nis_band(gi.nis[used & sel, j], gi.innovation[used & sel, 3 * j: 3 * j + 3])
                                            for name, sel in (("standing", standing), ("moving", ~standing))}
    return {
        "alignment": {k: constraints if k == "constraints" else v for k, v in res.info.items()
                      if k != "lever_arm"},  # that one: "lever_arm" below
        "smoothed_method": p.smoother,
        "solutions": list(names),
        "gps_fixes": int(res.fixes.t_s.size),
        "gps_rejected": rejected,
        "gps_reacquired": reacquired,  # rejected fixes re-acquired (covariance grown) or down-weighted (`fusion.reacquire`)
        "forward_mean_nis": mean_nis,  # 3 d.o.f. each (2 for speed/course velocity): about that when R fits
        "forward_nis_check": nis_check,
        "outages_s": (res.outages_s + t0_s).tolist(),
        "flagged_fraction": float(np.mean(res.flag)) if res.flag.size else 0.0,
        "mounting_check": mounting,
        "gps_clock_offset": clock_offset(res, p),
        "lever_arm": lever_arm_report(res),
        "constraints": {**constraints, "forward": constraint_summary(res.forward),
                        "backward": constraint_summary(res.backward)},
    }


def _with_stop_intervals(constraints: dict, intervals_s, t0_s: float) -> dict:
    """info["constraints"] (`motion_constraints`) with the detected stops (`intervals_s`:
    `DriveResult.stop_intervals_s`, session seconds) on the logger clock, as outages_s, rounded to
    0.01 s, after "stops_from" (summary.json's order); as it is without stops or constraints."""
    if intervals_s is None or "stops_from" not in constraints:
        return constraints
    out = {}
    for k, v in constraints.items():
        out[k] = v
        if k == "stops_from":
            out["stop_intervals_s"] = [[round(float(a) + t0_s, 2), round(float(b) + t0_s, 2)] for a, b in intervals_s]
    return out


def _at_stops(t_s, intervals_s) -> np.ndarray | None:
    """(M,) bool: the fixes at times t_s inside a detected stop (`intervals_s` (K, 2) on the same
    clock: `DriveResult.stop_intervals_s`, session seconds; not the summary's copy, rounded to
    0.01 s on the logger clock, which can move a fix near a stop's end to the other regime); None
    without stops."""
    if intervals_s is None or not len(intervals_s):
        return None
    return in_intervals(t_s, intervals_s, closed=True)


def gps_reacquisitions(run: FilterRun) -> dict:
    """Per GPS kind of a run (`fusion.reacquire`): re-acquisitions (rejected fixes applied because
    they continued the filter's error from the last accepted fix, beyond their stated accuracy)
    with the largest factor the position/velocity covariance was grown by and how many of them were
    read as a jump of the filter (its position/velocity alone grown; the others as a drift, with
    their cross terms), and down-weighted fixes (applied after a long run of rejections beyond their
    stated accuracy that were no drift, R grown to the gate's edge) with the largest factor of R."""
    infl = run.ev_inflation if run.ev_inflation is not None else np.ones((len(run.measurements), 2))
    jump = run.ev_jump if run.ev_jump is not None else np.zeros(len(run.measurements), dtype=bool)
    out = {}
    for kind, k in zip(GPS_KINDS, (Kind.GPS_POSITION, Kind.GPS_VELOCITY), strict=True):
        r = (run.measurements.kind == k) & (infl[:, 0] != 1.0)
        d = (run.measurements.kind == k) & (infl[:, 1] != 1.0)
        out[kind] = {"count": int(r.sum()), "read_as_jump": int((r & jump).sum()),
                     "max_factor": round(float(infl[r, 0].max()), 3) if r.any() else 1.0,
                     "downweighted": int(d.sum()), "max_r_factor": round(float(infl[d, 1].max()), 3) if d.any() else 1.0}
    return out


def lever_arm_report(res: DriveResult) -> dict | None:
    """The lever arm stated and, when estimated, the forward run's correction at its end (it has
    seen every turn) with its SD (`fusion.lever_arm.lever_arm_summary`)."""
    la = res.info.get("lever_arm")
    if la is None:
        return None
    est, sd = _block_at_end(res.forward, Block.LEVER, 2)
    return lever_arm_summary(est, sd, la["stated_m"], np.asarray(la["C_vb"]), la["decided_by"])


def clock_track(res: DriveResult, idx) -> tuple[np.ndarray, np.ndarray] | None:
    """(d (K, 2), sd (K, 2)): the IMU-GPS clock offsets [positions, velocities] (s) at run-local
    samples idx, the forward and backward runs' estimates combined by their inverse variances (two
    independent runs: `layout.clock_block`); None without clock states."""
    o = res.forward.layout.offset(Block.CLOCK)
    if o < 0:
        return None
    parts = []
    for run in (res.forward, res.backward):
        e = epoch_of(run, idx)
        parts.append((run.extra(Block.CLOCK, idx), np.stack([run.ep_P[e, o, o], run.ep_P[e, o + 1, o + 1]], axis=1)))
    (df, vf), (db, vb) = parts
    w = vb / (vf + vb)
    return w * df + (1.0 - w) * db, np.sqrt(vf * vb / (vf + vb))


def clock_offset(res: DriveResult, p: DriveSmoothParams) -> dict | None:
    """Summary of the IMU-GPS clock offsets (`clock_track` at the output samples): a position
    stamped t was taken at IMU time t + d. The output moves to the GPS clock (times t - d(t)) when
    the offset is significant: |median d| > `clock_apply_sd` of its median SD."""
    tr = clock_track(res, res.out_idx)
    if tr is None:
        return None
    d, sd = tr
    med, med_sd = np.median(d, axis=0), np.median(sd, axis=0)
    return {"estimate_s": round(float(med[0]), 4), "sigma_s": round(float(med_sd[0]), 4),
            "range_s": [round(float(d[:, 0].min()), 4), round(float(d[:, 0].max()), 4)],
            "velocity_estimate_s": round(float(med[1]), 4), "velocity_sigma_s": round(float(med_sd[1]), 4),
            "prior_sigma_s": p.gps_clock_sigma_s, "random_walk_s_per_sqrt_s": p.gps_clock_rw_s_per_sqrt_s,
            "output_clock": "gps" if abs(med[0]) > p.clock_apply_sd * med_sd[0] else "imu"}


def on_gps_clock(rows: Columns, d_s, sd_s: float) -> Columns:
    """One solution's trajectory rows moved to the GPS clock: t - d (its own clock estimate per
    row), and the offset's SD carried into the position sigmas along the velocity (an error of e
    seconds in d puts a row v e metres off)."""
    cols = {k: rows[k] for k in rows.columns}
    cols["t"] = rows["t"] - d_s
    for sig, vel in (("sigma_n", "vn"), ("sigma_e", "ve"), ("sigma_d", "vd")):
        if sig in rows and vel in rows:
            cols[sig] = np.hypot(rows[sig], rows[vel] * sd_s)
    return Columns(cols, len(rows))


def trajectory_rows(res: DriveResult, session: Session, p: DriveSmoothParams, names, with_shots: bool,
                    clock: dict | None) -> Columns:
    """`trajectory.parquet` of the solutions `names` at the output rate (the extra rows of range
    epochs for targeting dropped), with `outage` and `flag`, on the GPS clock when the estimated
    clock offset is significant (`clock`: `clock_offset`'s summary, taken before the runs'
    histories are cut by `without_histories`)."""
    t = res.t_s
    keep = np.ones(res.out_idx.size, dtype=bool)
    if with_shots:
        step = 1 if p.output_rate_hz <= 0 else max(1, int(round((t.size - 1) / (t[-1] - t[0]) / p.output_rate_hz)))
        keep = (res.out_idx % step == 0) | (res.out_idx == t.size - 1)
    tt = t[res.out_idx[keep]]
    outage = np.zeros(tt.size, dtype=bool)
    for a, b in res.outages_s:
        outage |= (tt >= a) & (tt < b)
    flag = res.flag[keep]
    o = res.forward.layout.offset(Block.CLOCK) - N_NAV + 6  # the position clock in a solution's bias row
    frames = []
    for n in names:
        # the rows kept, without copying a solution that keeps them all; its attitude in the
        # vehicle's axes, the covariance's attitude block passed on (P9 not copied to hold it)
        sol = res.solutions[n] if keep.all() else res.solutions[n].rows(keep)
        P_att = None
        if res.C_vb is not None:
            C_nv, P_att = vehicle_axes_attitude(sol, res.C_vb, res.forward)
            sol = Solution(sol.name, sol.idx, sol.nav, C_nv, sol.P9, sol.bias)
        rows = solution_rows(sol, t, session.t0_s, outage, flag, P_att)
        if output_on_gps_clock(clock):
            # each solution's own clock estimate: the one its positions were fitted with
            rows = on_gps_clock(rows, sol.bias[:, o], clock["sigma_s"])
        frames.append(rows)
    return concat(frames)


def run(session: Session, p: DriveSmoothParams, ctx: RunContext) -> ChainOutput:
    names = ["forward", "backward", "smoothed"] + (list(SMOOTHERS) if p.compare else [])
    epochs = range_epochs(session)
    res = process_drive(session, p, ctx, names, extra_idx=None if epochs is None else epochs[0])
    targets = None
    if epochs is not None:
        with ctx.stage("targeting"):
            rf = session.meta.rangefinders
            sig_r = float(rf.sigma_m) if rf is not None and rf.sigma_m is not None else 0.0
            targets = geolocate_shots(session, res.solutions["smoothed"], epochs, sig_r)
        ctx.count("targets", len(targets))
    with ctx.stage("outputs"):
        summary = drive_summary(res, p, names, session.t0_s, ctx)
        res = without_histories(res)  # the tables below read the solutions and the runs' ends only
        traj = trajectory_rows(res, session, p, names, epochs is not None, summary["gps_clock_offset"])
        innov = innovations_table(res, session.t0_s)
    return ChainOutput(trajectory=traj, targets=targets, tables={"innovations": innov}, summary=summary)


def without_histories(res: DriveResult) -> DriveResult:
    """`res` with each run's per-sample nominal and covariance history cut to its first and last
    rows (what `_block_at_end` reads); the measurement results stay. On the drive hour the two runs'
    histories are 250 MB that the output tables do not read."""
    def slim(run: FilterRun) -> FilterRun:
        ends = np.array([0, run.ep_idx.size - 1])
        return dataclasses.replace(run, nav=run.nav[[0, -1]], C_nb=run.C_nb[[0, -1]], bias=run.bias[[0, -1]],
                                   idx=np.array([0, run.t_s.size - 1]), ep_idx=run.ep_idx[ends], ep_P=run.ep_P.take(ends),
                                   ep_Phi=None, ep_Ppred=None, ep_dx=None, ep_phi_extra=None)
    return dataclasses.replace(res, forward=slim(res.forward), backward=slim(res.backward))
